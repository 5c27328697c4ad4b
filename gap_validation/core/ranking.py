"""Which fits are offered as a fix, and in which order.

Candidates are ranked by the epsilon they would leave (averaged data, confident frequencies). A candidate is
reported only when its improvement is real against the data's errors, at the usable frequencies:

* the current mismatch is outside the errors (some usable frequency beyond ``k``), else the diagnosis is
  empty;
* epsilon falls by at least :data:`MIN_RELATIVE_IMPROVEMENT` of its value;
* it falls by more than :data:`IMPROVEMENT_SIGMA_FACTOR` sigma, or the candidate leaves a mismatch within
  ``k`` where the model was beyond ``k + 1``;
* it removes at least half of the excess chi-square ``sum |ln(P_fit/P_meas)|^2 / e^2 - 2 n`` (a fitted noise
  spike lowers the sup of epsilon but not the aggregate);
* a pair must be, by the same tests, clearly better than its best single member.

The candidates kept are ranked by parsimony (:func:`information_criteria`): among those the data cannot tell
from the lowest criterion (within :data:`INDISTINGUISHABLE`), the one with the fewest parameters first, then
the rest by their criterion; at most six are reported.

Part of the diagnosis (:mod:`gap_validation.core.diagnosis`): the fits are
:mod:`gap_validation.core.fitting`'s, the statistics :mod:`gap_validation.core.evidence`'s.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from gap_validation.core.evidence import Evidence, Fit
from gap_validation.core.fitting import FittedCandidate

__all__ = [
    "IMPROVEMENT_SIGMA_FACTOR",
    "MIN_RELATIVE_IMPROVEMENT",
    "PAIR_RELATIVE_IMPROVEMENT",
    "INDISTINGUISHABLE",
    "chi2_improvement",
    "real_improvement",
    "select_candidates",
    "information_criteria",
]

#: An improvement of the sup of epsilon must exceed this many sigma at the frequencies involved ...
IMPROVEMENT_SIGMA_FACTOR = 3.0
#: ... and remove at least this fraction of epsilon (a 10 % improvement is no explanation).
MIN_RELATIVE_IMPROVEMENT = 0.25
#: A pair must remove at least this fraction of its best single member's epsilon.
PAIR_RELATIVE_IMPROVEMENT = 0.25
#: Candidates whose information criterion (:func:`information_criteria`) lies within this of the lowest are
#: indistinguishable by the data (a Bayes factor below e, "not worth more than a bare mention"; Kass and
#: Raftery 1995): the one with the fewest parameters is named first, and the sentence says which others fit as
#: well.
INDISTINGUISHABLE = 2.0
_MAX_CANDIDATES = 6    # reported at most


def chi2_improvement(before: Fit, after: Fit, extra_parameters: int, n_usable: int) -> bool:
    """Whether ``after`` removes enough of ``before``'s chi-square.

    At least half of ``before``'s excess over its expectation (2 per frequency), and more than fitting noise
    with the extra parameters could (``10 + 3 p``).

    Parameters
    ----------
    before, after : Fit
        The model's fit and the candidate's.
    extra_parameters : int
        Parameters the candidate adds.
    n_usable : int
        Confident frequencies.

    Returns
    -------
    bool
    """
    gain = before.chi2 - after.chi2
    return gain >= max(0.5 * (before.chi2 - 2.0 * n_usable), 10.0 + 3.0 * max(extra_parameters, 1))


def real_improvement(ev: Evidence, before: Fit, after: Fit, extra_parameters: int,
                      min_relative: float) -> bool:
    """True when ``after`` leaves an epsilon clearly below ``before``'s, beyond what the errors explain.

    Parameters
    ----------
    ev : Evidence
        The averaged estimate and its statistics.
    before, after : Fit
        The fit improved on and the candidate's.
    extra_parameters : int
        Parameters the candidate adds.
    min_relative : float
        The fraction of epsilon it must remove (:data:`MIN_RELATIVE_IMPROVEMENT`,
        :data:`PAIR_RELATIVE_IMPROVEMENT`).

    Returns
    -------
    bool
    """
    e0, e1 = before.eps, after.eps
    if not (math.isfinite(e0) and math.isfinite(e1)) or e1 > (1.0 - min_relative) * e0:
        return False
    if not chi2_improvement(before, after, extra_parameters, int(np.count_nonzero(ev.confident))):
        return False
    s = max(ev.sigma[before.worst], ev.sigma[after.worst])
    if e0 - e1 > IMPROVEMENT_SIGMA_FACTOR * s:
        return True
    return before.k_max > ev.sigma_factor + 1.0 and after.k_max <= ev.sigma_factor


def select_candidates(ev: Evidence, base: Fit, fitted: list[FittedCandidate]) -> list[FittedCandidate]:
    """Keep the candidates with a real improvement (pairs only when clearly better than their best member) and
    rank them by parsimony (:func:`information_criteria`): the lowest criterion first, and among the
    candidates the data cannot tell from it (within :data:`INDISTINGUISHABLE`) the one with the fewest
    parameters.

    Parameters
    ----------
    ev : Evidence
        The averaged estimate and its statistics.
    base : Fit
        The model's fit.
    fitted : list of FittedCandidate
        Scored candidates (:func:`~gap_validation.core.fitting.fit_candidates`).

    Returns
    -------
    list of FittedCandidate
        At most six, best first, with their ``criterion`` and the top's ``indistinguishable``.
    """
    singles = {c.name: c for c in fitted if not c.members and not c.replacement}
    kept = []
    for cand in fitted:
        if not real_improvement(ev, base, cand.score, cand.complexity, MIN_RELATIVE_IMPROVEMENT):
            continue
        if cand.members:
            best = min((singles[m] for m in cand.members if m in singles), key=lambda c: c.score.eps,
                       default=None)
            if best is not None and not real_improvement(ev, best.score, cand.score,
                                                          cand.complexity - best.complexity,
                                                          PAIR_RELATIVE_IMPROVEMENT):
                continue
        kept.append(cand)
    if not kept:
        return []
    n = 2 * int(np.count_nonzero(ev.confident))
    criteria = information_criteria([c.score.chi2 for c in kept], [c.complexity for c in kept], n)
    for cand, value in zip(kept, criteria):
        cand.criterion = float(value)
    lowest = min(c.criterion for c in kept)
    close = [c for c in kept if c.criterion <= lowest + INDISTINGUISHABLE]
    top = min(close, key=lambda c: (c.complexity, c.criterion))
    top.indistinguishable = [c.name for c in sorted(close, key=lambda c: c.criterion) if c is not top]
    ranked = [top] + sorted((c for c in kept if c is not top), key=lambda c: c.criterion)
    return ranked[:_MAX_CANDIDATES]


def information_criteria(chi2: Sequence[float], parameters: Sequence[int], residuals: int) -> np.ndarray:
    """Schwarz's criterion of each candidate on the weighted residuals, corrected for overdispersion.

    The chi-square of a fit, ``sum |ln(P_fit / P_meas)|^2 / e^2`` over the confident frequencies, is ``-2 ln
    L`` up to a constant when the errors ``e`` are right, on ``N = 2 n`` real residuals. A model that is a
    little wrong everywhere (real models are off by 5-10 %) leaves a misfit the errors do not cover, and every
    extra parameter soaks some of it up: the chi-squares are therefore divided by ``c = max(1, min chi2 / (N -
    p))``, the smallest reduced chi-square among the candidates (quasi-likelihood), before the penalty ``p ln
    N`` is added (``QBIC = chi2 / c + p ln N``). An extra parameter must then remove more misfit than ``ln N``
    times what is left per residual. Nested or not, candidates compare on the same scale.

    Parameters
    ----------
    chi2 : sequence of float
        Each candidate's chi-square.
    parameters : sequence of int
        Each candidate's fitted parameters.
    residuals : int
        ``N``: real residuals (two per confident frequency).
    """
    chi2 = np.asarray(chi2, float)
    p = np.asarray(parameters, float)
    n = max(int(residuals), 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        reduced = np.where(n - p > 0, chi2 / np.maximum(n - p, 1.0), np.inf)
    c = max(1.0, float(np.min(reduced))) if reduced.size and np.isfinite(np.min(reduced)) else 1.0
    return chi2 / c + p * math.log(n)
