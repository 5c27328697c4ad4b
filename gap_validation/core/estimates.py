"""Frequency-response estimates: one record's (raw) or pooled over records, solved from local polynomial sums.

:class:`SpectralEstimate` is what :class:`~gap_validation.core.estimator.FrequencyResponseEstimator` reports
(the light and dark curves of the paper's Fig. 4); :func:`record_amplitude` is the input amplitude it dates
each raw estimate with; :data:`NOT_ESTIMABLE_REASONS` names why a frequency of a record gave nothing.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike

from gap_validation.core.spectra import SPECTRA_DEFAULTS, BandSums, expected_estimate, solve_bands

__all__ = ["SpectralEstimate", "record_amplitude", "NOT_ESTIMABLE_REASONS"]

#: Why a frequency has no estimate (:attr:`SpectralEstimate.reasons` counts records per reason).
NOT_ESTIMABLE_REASONS = ("not_excited", "too_short", "above_grid", "too_few_bins", "below_trim")


@dataclass(frozen=True)
class SpectralEstimate:
    """Frequency response at the channel's frequencies: one record (raw), or pooled over records.

    Attributes
    ----------
    w_rad_s : ndarray
        Frequencies [rad/s].
    gxx, gyy : ndarray
        One-sided auto-spectral densities of input and output near each frequency (mean over the band's bins
        after the transient is removed) [unit^2/Hz].
    gxy : ndarray
        ``H gxx`` (complex) [unit_x unit_y/Hz].
    n_averages : ndarray
        Degrees of freedom of the noise estimate per frequency (bins minus every fitted coefficient); 0 where
        nothing was estimated.
    response : ndarray
        ``H(w)`` (complex; NaN where nothing was estimated).
    coherence : ndarray
        Multiple coherence of the local fit, ``1 - residual / output power`` in [0, 1]; 0 where nothing was
        estimated.
    random_error : ndarray
        Normalised random error of ``|H|`` (and the phase error in rad): ``sqrt(variance / 2) / |H|``; inf
        where nothing was estimated.
    start_s, end_s : float
        Time span (pooled: first start, last end) [s].
    n_sweeps : int
        Records pooled (1 for a raw estimate).
    variance : ndarray
        ``E |H_est - H|^2`` [unit_y^2/unit_x^2] (both components together).
    kind : str
        A raw estimate's manoeuvre kind (:data:`gap_validation.core.records.KINDS`); ``""`` when pooled.
    reasons : dict
        Per reason in :data:`NOT_ESTIMABLE_REASONS`: how many records did not count, per frequency (arrays).
    sums : BandSums or None
        The sufficient statistics (for :meth:`expected`); None for a raw estimate.
    band_fraction : float
        The estimator's ``band_fraction``.
    coefficients : int
        Complex coefficients of the response polynomial (``order + 1``).
    amplitude : float
        A raw estimate's input amplitude: ``sqrt(2)`` times the RMS of the first input over the manoeuvre's
        own span, its trim (linear trend) removed (the amplitude of a sinusoid of the same power; exactly the
        amplitude of a constant-amplitude chirp) [input units]; NaN when unknown or pooled
        (:func:`record_amplitude`).
    """

    w_rad_s: np.ndarray
    gxx: np.ndarray
    gyy: np.ndarray
    gxy: np.ndarray
    n_averages: np.ndarray
    response: np.ndarray
    coherence: np.ndarray
    random_error: np.ndarray
    start_s: float = float("nan")
    end_s: float = float("nan")
    n_sweeps: int = 1
    variance: np.ndarray | None = None
    kind: str = ""
    reasons: dict = field(default_factory=dict)
    sums: BandSums | None = None
    band_fraction: float = SPECTRA_DEFAULTS["band_fraction"]
    coefficients: int = SPECTRA_DEFAULTS["order"] + 1
    amplitude: float = float("nan")

    @classmethod
    def from_sums(
        cls,
        w_rad_s: ArrayLike,
        sums: BandSums,
        dt: float,
        band_fraction: float,
        start_s: float = float("nan"),
        end_s: float = float("nan"),
        n_sweeps: int = 1,
        kind: str = "",
        reasons: dict | None = None,
    ) -> "SpectralEstimate":
        """Solve :class:`~gap_validation.core.spectra.BandSums` into an estimate.

        Parameters
        ----------
        w_rad_s : array_like
            Frequencies [rad/s].
        sums : BandSums
            Local polynomial sums (one record or pooled).
        dt : float
            Grid step [s] (densities).
        band_fraction : float
            The estimator's ``band_fraction``.
        start_s, end_s : float
            Time span [s].
        n_sweeps : int
            Records in ``sums``.
        kind : str
            Manoeuvre kind of a raw estimate.
        reasons : dict, optional
            Records not counted, per reason and frequency.
        """
        local = solve_bands(sums)
        bins = np.maximum(sums.bins, 1)
        ok = np.isfinite(local.response)
        gxx = np.where(ok, 2.0 * dt * sums.input_power / bins, 0.0)
        gyy = np.where(ok, 2.0 * dt * sums.yy[:, 0, 0].real / bins, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            err = np.sqrt(local.variance / 2.0) / np.abs(local.response)
        err = np.where(ok & np.isfinite(err), err, np.inf)
        return cls(np.asarray(w_rad_s, float).copy(), gxx, gyy, np.where(ok, local.response * gxx, 0.0),
                   np.where(ok, local.dof, 0), local.response, np.where(ok, local.coherence, 0.0), err,
                   float(start_s), float(end_s), int(n_sweeps), np.where(ok, local.variance, np.inf), kind,
                   dict(reasons or {}), sums, float(band_fraction), sums.order + 1)

    #: Rows of :meth:`rows` (a raw estimate kept in fixed-size arrays).
    ROWS = ("response_re", "response_im", "variance", "n_averages", "coherence", "gxx", "gyy")

    def rows(self) -> np.ndarray:
        """The estimate as a (7, F) array (:data:`ROWS`): what a raw estimate keeps and checkpoints."""
        return np.stack([self.response.real, self.response.imag, self.variance, self.n_averages,
                         self.coherence, self.gxx, self.gyy]).astype(float)

    @classmethod
    def from_rows(
        cls,
        w_rad_s: ArrayLike,
        rows: np.ndarray,
        start_s: float,
        end_s: float,
        kind: str,
        band_fraction: float,
        coefficients: int,
        amplitude: float = float("nan"),
    ) -> "SpectralEstimate":
        """Inverse of :meth:`rows` (a raw estimate).

        Parameters
        ----------
        w_rad_s : array_like
            Frequencies [rad/s].
        rows : ndarray, (7, F)
            From :meth:`rows`.
        start_s, end_s : float
            Time span [s].
        kind : str
            Manoeuvre kind.
        band_fraction : float
            The estimator's ``band_fraction``.
        coefficients : int
            ``order + 1``.
        amplitude : float, optional
            The record's input amplitude (:attr:`amplitude`).
        """
        response = rows[0] + 1j * rows[1]
        variance, n, coherence, gxx, gyy = rows[2], rows[3].astype(np.int64), rows[4], rows[5], rows[6]
        ok = np.isfinite(response)
        with np.errstate(divide="ignore", invalid="ignore"):
            err = np.where(ok, np.sqrt(variance / 2.0) / np.abs(response), np.inf)
        return cls(
            np.asarray(w_rad_s, float).copy(),
            gxx,
            gyy,
            np.where(ok, response * gxx, 0.0),
            n,
            response,
            coherence,
            np.where(np.isfinite(err), err, np.inf),
            float(start_s),
            float(end_s),
            1,
            variance,
            kind,
            {},
            None,
            float(band_fraction),
            int(coefficients),
            float(amplitude),
        )

    @property
    def excited(self) -> np.ndarray:
        """Frequencies at which at least one record counted."""
        return np.isfinite(self.response)

    def select(self, index: slice | ArrayLike) -> "SpectralEstimate":
        """The estimate at the frequencies ``index`` only (a slice or index array).

        Parameters
        ----------
        index : slice or array_like
            Frequencies to keep.
        """
        arrays = {name: np.asarray(getattr(self, name))[index]
                  for name in ("w_rad_s", "gxx", "gyy", "gxy", "n_averages", "response", "coherence",
                               "random_error")}
        variance = None if self.variance is None else np.asarray(self.variance)[index]
        reasons = {k: np.asarray(v)[index] for k, v in self.reasons.items()}
        sums = None if self.sums is None else self.sums.take(index)
        return SpectralEstimate(**arrays, start_s=self.start_s, end_s=self.end_s, n_sweeps=self.n_sweeps,
                                variance=variance, kind=self.kind, reasons=reasons, sums=sums,
                                band_fraction=self.band_fraction, coefficients=self.coefficients,
                                amplitude=self.amplitude)

    def expected(self, model_response: Callable[[np.ndarray], ArrayLike]) -> tuple[np.ndarray, np.ndarray]:
        """The estimate a model would give through this estimator (see
        :func:`~gap_validation.core.spectra.expected_estimate`): ``(expected, expansion_error)``.

        Parameters
        ----------
        model_response : callable
            ``model_response(w_rad_s) -> complex array``.
        """
        if self.sums is None:
            return np.asarray(model_response(self.w_rad_s), complex), np.zeros(self.w_rad_s.shape)
        expected, error = expected_estimate(self.sums, self.w_rad_s, self.band_fraction, model_response)
        return np.where(self.excited, expected, np.nan + 0j), error


def record_amplitude(u: np.ndarray) -> float:
    """Input amplitude of one manoeuvre: ``sqrt(2)`` times the RMS of ``u`` about its least-squares line.

    The line removes the trim and a slow re-trim; ``sqrt(2) RMS`` is the amplitude of a sinusoid of the same
    power, so a constant-amplitude chirp gives its amplitude at every frequency it passes (what a describing
    function needs); for a multisine or a multistep it is the amplitude of the equivalent sinusoid.

    Parameters
    ----------
    u : ndarray
        Samples of the input over the manoeuvre's own span (uniform grid).

    Returns
    -------
    float
        The amplitude [input units]; NaN for fewer than 3 samples or non-finite data.
    """
    u = np.asarray(u, float).ravel()
    if u.size < 3 or not np.all(np.isfinite(u)):
        return float("nan")
    x = np.arange(u.size, dtype=float)
    coef = np.polyfit(x, u, 1)
    return float(math.sqrt(2.0) * np.std(u - np.polyval(coef, x)))
