"""Measured frequency responses as arguments of the metrics: :func:`~gap_validation.core.metrics.nugap` and
:func:`~gap_validation.core.metrics.epsilon` take a model or measured data, as python-control's
``stability_margins`` takes "an LTI system or (mag, phase, omega)".

Measured data is any of:

- a :class:`FrequencyData` (frequencies [rad/s] and the complex response, SISO values or ``(F, p, m)``
  matrices);
- a ``(w_rad_s, response)`` pair;
- an estimate of this package (``SpectralEstimate``, ``LocalEstimate``: ``w_rad_s`` and ``response``) or a
  ``ChannelResult`` (``frequency_rad_s`` and ``measured``);
- a python-control ``FrequencyResponseData`` (``omega`` and ``fresp`` of shape ``(p, m, F)``), read by its
  attributes (python-control is not imported).

A model against data is compared at the data's frequencies; data against data needs the same frequencies.
Over frequency points the winding-number condition cannot be checked: it is assumed (as by
:func:`~gap_validation.core.metrics.nugap_frequency_data`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["FrequencyData", "as_frequency_data", "paired_responses"]


@dataclass(frozen=True)
class FrequencyData:
    """A measured frequency response.

    Attributes
    ----------
    w_rad_s : ndarray
        Frequencies [rad/s], (F,).
    response : ndarray of complex
        The response at them: (F,) SISO, or (F, p, m) matrices.
    """

    w_rad_s: np.ndarray
    response: np.ndarray


def as_frequency_data(value: Any) -> FrequencyData | None:
    """``value`` as :class:`FrequencyData` when it is measured data (module docstring), else None (a model).

    Parameters
    ----------
    value : object
        A model, or measured data in one of the accepted forms.

    Returns
    -------
    FrequencyData or None
        None for anything with a ``freqresp`` method (a model).

    Raises
    ------
    ValueError
        Data whose frequencies and response do not match in length, or a frequency that is negative or not
        finite.
    """
    if isinstance(value, FrequencyData):
        w, h = value.w_rad_s, value.response
    elif hasattr(value, "freqresp"):
        return None
    elif isinstance(value, tuple) and len(value) == 2:
        w, h = value
    elif hasattr(value, "omega") and hasattr(value, "fresp"):          # python-control FRD: (p, m, F)
        w, h = value.omega, np.moveaxis(np.asarray(value.fresp, dtype=complex), -1, 0)
        if h.shape[1:] == (1, 1):
            h = h[:, 0, 0]
    elif hasattr(value, "frequency_rad_s") and hasattr(value, "measured"):
        w, h = value.frequency_rad_s, value.measured
    elif hasattr(value, "w_rad_s") and hasattr(value, "response"):
        w, h = value.w_rad_s, value.response
    else:
        return None
    w = np.asarray(w, dtype=float).ravel()
    h = np.asarray(h, dtype=complex)
    if h.shape[0] != w.size:
        raise ValueError(f"measured data: {w.size} frequencies but {h.shape[0]} response values")
    bad = np.flatnonzero(~np.isfinite(w) | (w < 0.0))
    if bad.size:
        raise ValueError(f"measured data: frequency {float(w[bad[0]]):g} rad/s (index {int(bad[0])}): "
                         f"frequencies must be finite and non-negative")
    return FrequencyData(w, h)


def paired_responses(m1: Any, m2: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Both arguments as responses on one set of frequencies, when at least one is measured data.

    Parameters
    ----------
    m1, m2 : model or measured data
        A model (``freqresp``) or data in an accepted form.

    Returns
    -------
    (w_rad_s, p1, p2) or None
        None when both are models.

    Raises
    ------
    ValueError
        Two data sets on different frequencies.
    """
    d1, d2 = as_frequency_data(m1), as_frequency_data(m2)
    if d1 is None and d2 is None:
        return None
    if d1 is not None and d2 is not None:
        if d1.w_rad_s.shape != d2.w_rad_s.shape or not np.allclose(
            d1.w_rad_s, d2.w_rad_s, rtol=1e-12, atol=0.0
        ):
            raise ValueError(
                "measured data against measured data: the frequencies differ (compare them on the "
                "same frequencies)"
            )
        return d1.w_rad_s, d1.response, d2.response
    w = (d1 or d2).w_rad_s
    p1 = d1.response if d1 is not None else np.asarray(m1.freqresp(w), dtype=complex)
    p2 = d2.response if d2 is not None else np.asarray(m2.freqresp(w), dtype=complex)
    return w, p1, p2
