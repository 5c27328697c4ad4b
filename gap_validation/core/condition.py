"""The flight condition of a channel: its inputs brought to the model's dynamic pressure (an airspeed stream).

Control power scales with the dynamic pressure, so an input flown at another airspeed than the model's trim
acts as if scaled by ``(V / V_trim)^2``. :class:`DynamicPressureScaling` multiplies each input's deviation
from its trim by that ratio on the grid, so gusts and small drifts of the condition do not read as a model
error, and keeps how far the flight strayed (:meth:`DynamicPressureScaling.summary`).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["DynamicPressureScaling", "DYNAMIC_PRESSURE_RANGE", "TRIM_FOLLOW_S"]

#: Dynamic pressure ratios an airspeed stream may scale the inputs by (airspeed 50-200 % of the model's trim);
#: samples beyond are clipped and counted (:attr:`FrequencyResponseEstimator.dynamic_pressure_ratio`).
DYNAMIC_PRESSURE_RANGE = (0.25, 4.0)
#: Time constant of the input's trim level followed outside the manoeuvres [s] (the airspeed scaling leaves
#: it).
TRIM_FOLLOW_S = 2.0


class DynamicPressureScaling:
    """Each input's deviation from its trim, scaled by the dynamic pressure ratio of an airspeed stream.

    Holds the trim airspeed, each input's trim level (followed outside the manoeuvres, held in them) and the
    statistics of the ratio over the flight's grid samples (count, sum, min, max, samples clipped).

    Parameters
    ----------
    inputs : int
        Inputs (the first rows of the grid samples).
    trim_airspeed : float
        The model's airspeed [m/s] (> 0).
    dt : float
        Grid step [s].
    """

    def __init__(self, inputs: int, trim_airspeed: float, dt: float) -> None:
        self.inputs = int(inputs)
        self.trim_airspeed = float(trim_airspeed)
        self.dt = float(dt)
        #: dynamic pressure ratio over the flight's grid samples: count, sum, min, max, and samples clipped
        self.stats = np.array([0.0, 0.0, np.inf, -np.inf, 0.0])
        #: each input's trim level (followed outside the manoeuvres, held in them): what is not scaled
        self.u_trim = np.full(self.inputs, np.nan)

    def scale(self, vals: np.ndarray, hold_trim: bool) -> np.ndarray:
        """The data streams with each input's deviation from its trim scaled by ``(V / V_trim)^2``.

        ``V`` is the last row, the airspeed (within :data:`DYNAMIC_PRESSURE_RANGE`: beyond it the sample is
        clipped and counted, a flight that far from the model's condition is not a test of it). Only the
        deviation: the model is about trim, where the surface's moment at the trim deflection balances the
        rest of the airframe's, all of them scaling with the dynamic pressure together. The trim level is
        followed outside the manoeuvres (time constant :data:`TRIM_FOLLOW_S`) and held while one is recorded;
        the manoeuvres are found on the logged surface, before scaling.

        Parameters
        ----------
        vals : ndarray
            Grid samples (streams x n), the airspeed last.
        hold_trim : bool
            A manoeuvre is being recorded: the trim level is held (unless still unknown).

        Returns
        -------
        ndarray
            The samples without the airspeed row, the inputs scaled.
        """
        m = self.inputs
        if not hold_trim or np.isnan(self.u_trim).any():
            first = np.isnan(self.u_trim)
            self.u_trim[first] = vals[:m, 0][first]
            alpha = 1.0 - math.exp(-vals.shape[1] * self.dt / TRIM_FOLLOW_S)
            self.u_trim += alpha * (np.mean(vals[:m], axis=1) - self.u_trim)
        ratio = (vals[-1] / self.trim_airspeed) ** 2
        low, high = DYNAMIC_PRESSURE_RANGE
        clipped = np.clip(ratio, low, high)
        st = self.stats
        st[0] += ratio.size
        st[1] += float(np.sum(clipped))
        st[2] = min(st[2], float(np.min(clipped)))
        st[3] = max(st[3], float(np.max(clipped)))
        st[4] += float(np.count_nonzero(clipped != ratio))
        out = vals[:-1].copy()
        trim = self.u_trim[:, None]
        out[:m] = trim + (out[:m] - trim) * clipped
        return out

    def summary(self) -> dict | None:
        """``mean``, ``min``, ``max`` of the ratio over the grid samples so far and ``clipped`` (samples
        beyond
        :data:`DYNAMIC_PRESSURE_RANGE`); None before a sample."""
        n, total, low, high, clipped = self.stats
        if not n:
            return None
        return {"mean": total / n, "min": low, "max": high, "clipped": int(clipped)}

    def state_dict(self) -> dict:
        """``trim_airspeed``, ``q_stats`` and ``u_trim`` (the estimator's checkpoint keys)."""
        return {
            "trim_airspeed": self.trim_airspeed,
            "q_stats": self.stats.copy(),
            "u_trim": self.u_trim.copy(),
        }

    def load_state(self, st: dict) -> None:
        """Inverse of :meth:`state_dict`.

        Parameters
        ----------
        st : dict
            Holds ``q_stats`` and ``u_trim`` (``trim_airspeed`` is the constructor's).
        """
        self.stats[:] = np.asarray(st["q_stats"], float)
        self.u_trim[:] = np.asarray(st["u_trim"], float)
