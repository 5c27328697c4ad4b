"""Trends over date across a fleet's flights: is a quantity (epsilon, a diagnosed delay) really drifting?

numpy/scipy only, like the rest of the core: the statistics behind the words of a campaign's index
(:mod:`gap_validation.campaign.findings`).

Per aircraft, channel and quantity the values of the flights are regressed on their date, ``y = a + b t``
(ordinary least squares, or weighted with ``1/sigma^2`` when per-flight standard errors are given). The
flights' random error is what the line leaves: the residual scatter ``s^2 = sum w r^2 / (n - 2)`` (so a known
sigma that understates the scatter does not make a trend look more certain than the flights agree). The
slope's standard error is ``s / sqrt(sum w (t - t_w)^2)`` and ``T = b / se`` follows Student's t with ``n -
2`` degrees of freedom under "no drift" (Draper & Smith, *Applied Regression Analysis*, 3rd ed., ch. 1 and 9).
A trend needs :data:`MIN_FLIGHTS` flights (two degrees of freedom for the scatter).

A campaign tests many trends (aircraft x channels x quantities); :func:`holm_significant` keeps the chance of
calling *any* stable quantity drifting below ``alpha`` (Holm's step-down Bonferroni, 1979).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import stats

__all__ = ["Trend", "linear_trend", "holm_significant", "MIN_FLIGHTS", "FAMILY_ALPHA", "DAYS_PER_WEEK"]

#: Fewest flights for a trend (n - 2 >= 2 degrees of freedom for the scatter).
MIN_FLIGHTS = 4
#: Family-wise false-alarm probability over all the trends of a campaign (Holm).
FAMILY_ALPHA = 0.01
DAYS_PER_WEEK = 7.0


@dataclass(frozen=True)
class Trend:
    """Straight line through one quantity's values over date, with its significance.

    Attributes
    ----------
    n : int
        Flights used.
    slope_per_day : float
        Change per day [quantity units / day].
    slope_error_per_day : float
        Standard error of the slope from the residual scatter [units / day].
    intercept : float
        Fitted value at ``t = 0`` (the time origin of the caller's days).
    scatter : float
        Residual standard deviation (the flights' random error about the line; weighted RMS with weights).
    t_statistic, p_value : float
        ``slope / error`` and its two-sided probability under no drift (Student t, n - 2 dof).
    first_day, last_day : float
        Earliest and latest date [days].
    start_value, end_value : float
        The line at the first and last date.
    """

    n: int
    slope_per_day: float
    slope_error_per_day: float
    intercept: float
    scatter: float
    t_statistic: float
    p_value: float
    first_day: float
    last_day: float
    start_value: float
    end_value: float

    @property
    def slope_per_week(self) -> float:
        """Change per week [quantity units / week]."""
        return self.slope_per_day * DAYS_PER_WEEK

    def to_json_dict(self) -> dict:
        """The trend as ``campaign.json`` holds it (per week; a non-finite ``t_statistic`` as None)."""
        return {
            "flights": self.n,
            "slope_per_week": self.slope_per_week,
            "slope_error_per_week": self.slope_error_per_day * DAYS_PER_WEEK,
            "scatter": self.scatter,
            "t_statistic": _finite(self.t_statistic),
            "p_value": self.p_value,
            "start_value": self.start_value,
            "end_value": self.end_value,
        }


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def linear_trend(days: Sequence[float], values: Sequence[float],
                 sigma: Sequence[float] | None = None) -> Trend | None:
    """Least-squares line through ``values`` over ``days`` and the slope's significance against the scatter.

    Parameters
    ----------
    days : sequence of float
        Date of each flight [days, any origin].
    values : sequence of float
        The quantity per flight; non-finite values (and their days) are left out.
    sigma : sequence of float, optional
        Per-flight standard errors: weights ``1/sigma^2`` (weighted least squares). The slope's error still
        comes from the residual scatter (see the module docstring).

    Returns
    -------
    Trend or None
        None with fewer than :data:`MIN_FLIGHTS` usable flights or all on one date.
    """
    t = np.asarray(days, dtype=float)
    y = np.asarray(values, dtype=float)
    w = np.ones_like(y) if sigma is None else 1.0 / np.square(np.asarray(sigma, dtype=float))
    ok = np.isfinite(t) & np.isfinite(y) & np.isfinite(w) & (w > 0)
    t, y, w = t[ok], y[ok], w[ok]
    n = int(t.size)
    if n < MIN_FLIGHTS or np.ptp(t) <= 0:
        return None
    t_mean = float(np.sum(w * t) / np.sum(w))
    y_mean = float(np.sum(w * y) / np.sum(w))
    sxx = float(np.sum(w * (t - t_mean) ** 2))
    slope = float(np.sum(w * (t - t_mean) * (y - y_mean)) / sxx)
    intercept = y_mean - slope * t_mean
    residual = y - (intercept + slope * t)
    dof = n - 2
    scatter = math.sqrt(float(np.sum(w * residual ** 2)) / dof)
    error = scatter / math.sqrt(sxx)
    if error > 0:
        t_stat = slope / error
        p_value = float(2.0 * stats.t.sf(abs(t_stat), dof))
    else:  # the values lie exactly on a line: a drift if it slopes at all
        t_stat = math.inf if slope else 0.0
        p_value = 0.0 if slope else 1.0
    first, last = float(np.min(t)), float(np.max(t))
    return Trend(n=n, slope_per_day=slope, slope_error_per_day=error, intercept=intercept, scatter=scatter,
                 t_statistic=t_stat, p_value=p_value, first_day=first, last_day=last,
                 start_value=intercept + slope * first, end_value=intercept + slope * last)


def holm_significant(p_values: Sequence[float], alpha: float = FAMILY_ALPHA) -> list[bool]:
    """Which of several tests reject "no drift" with a family-wise error rate of ``alpha`` (Holm, 1979).

    The smallest p-value is compared with ``alpha/m``, the next with ``alpha/(m-1)``, and so on until one
    fails.

    Parameters
    ----------
    p_values : sequence of float
        Two-sided p-values of the ``m`` tests (e.g. :attr:`Trend.p_value` of every trend of a campaign).
    alpha : float, optional
        Family-wise false-alarm probability (default :data:`FAMILY_ALPHA`).

    Returns
    -------
    list of bool
        Per test, in the given order: True where "no drift" is rejected.
    """
    p = np.asarray(p_values, dtype=float)
    m = p.size
    keep = [False] * m
    for rank, index in enumerate(np.argsort(p, kind="stable")):
        if not p[index] <= alpha / (m - rank):
            break
        keep[int(index)] = True
    return keep
