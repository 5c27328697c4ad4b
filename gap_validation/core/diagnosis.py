"""Where the model fails and which physical effect is missing (DESIGN.md, steps 2 and 3).

Where it fails
--------------
Per frequency the overbounding-disk distance ``epsilon(w) = |P2-P1|/|P2+P1|`` (paper eq. 14) between the model
P1 and the averaged measured response P2 is compared with what the estimate's errors can explain. The estimate
is the local polynomial fit of :mod:`gap_validation.core.spectra`: its variance comes from the fit's residuals
on ``d`` degrees of freedom (bins minus every fitted coefficient, summed over manoeuvres), so the normalised
squared error of the response is exactly F(2, 2d) distributed; :func:`normalised_mismatch` turns ``epsilon /
sigma`` into the equivalent Rayleigh ``k``. The model is compared *as the estimator sees it*: its response
expanded over the same band (:meth:`SpectralEstimate.expected`), so the estimator's own smoothing of a sharp
feature is not a mismatch (the expansion's error widens sigma).

``sigma`` is the estimate's random error, or the scatter between manoeuvres where three or more are confident
(a Birge ratio above one raises it), combined with a small systematic floor :data:`BIAS_ERROR` (1 %). A
frequency is *confident* (:func:`confident_points`, the one definition the validator uses too) when its
coherence passes the threshold and pure noise would reach that coherence with probability at most
:data:`COHERENCE_FALSE_ALARM` (a Beta law in the fit's coefficients and degrees of freedom,
:func:`minimum_averages`); only confident frequencies count for epsilon, the nu-gap and the fits. Frequencies
the flight did not excite are ``not_excited`` and never model-limited; a coherent frequency with too few
degrees of freedom is data-limited where epsilon passes the threshold.

Bands where ``epsilon(w)`` passes the threshold are **model-limited** when at a usable frequency of the band
the mismatch exceeds ``k = SIGMA_FACTOR`` (4), and **data-limited** otherwise: low coherence, too few degrees
of freedom or random error comparable to the mismatch (fly the manoeuvre again there rather than change the
model). Measured: model-limited on 0.3 % of the channels of 240 simulated flights whose truth is the model
(``benchmarks/false_alarms.py``).

Which effect is missing
-----------------------
Each effect of the vocabulary (:mod:`gap_validation.core.effects`) is fitted in series with the current model
to the averaged measured response with the CIFER cost (Tischler & Remple, *Aircraft and Rotorcraft System
Identification*, 2nd ed., ch. 11)::

    J = 20/n sum_w W_g [ (|T_m| - |T_c|)^2  +  0.01745 (angle T_m - angle T_c)^2 ],   W_g = [1.58 (1 -
    exp(-g^2))]^2

(magnitudes in dB, phases in deg, ``g^2`` the coherence) over the usable frequencies: a grid over physically
sensible parameter ranges, then a bounded local refinement (:func:`scipy.optimize.least_squares`) from the
best distinct grid points. Pairs of effects are fitted when no single effect explains the mismatch, and the
model's own coefficients are refitted as ``parameter_error``.

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

Candidates that leave the data within their errors everywhere come first, the simplest (fewest parameters)
first; then those as good as the best one, simplest first; the rest follow by epsilon.

No fit at its bounds: a fit whose parameter sits on an edge of its search range (:data:`BOUND_TOLERANCE` of
the range; the ranges are the registry's, e.g. a structural mode inside the confident band with damping up to
1, a gain within +-20 dB of either sign) is *beyond the search range*: it is never offered as a fix, and said
so in the message when no offered candidate explains the mismatch. ``parameter_error`` searches each
coefficient within x10 of the model's and, when it lands on that bound, once more within x100
(:data:`COEFFICIENT_RANGES`). Each sentence says the epsilon the candidate leaves and whether it *explains*
the mismatch (the JSON's ``explains``: the data within their errors at every confident frequency), or how many
noise scales it leaves.
"""
from __future__ import annotations

import contextvars
import itertools
import math
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Callable, Iterator, Sequence

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import brentq
from scipy.special import betainc

from gap_validation.core import metrics
from gap_validation.core.effects import (
    EFFECTS,
    AmplitudeFitRange,
    EffectFit,
    EffectType,
    FitRange,
    backlash_df,
    describe_effect,
    validate_effect,
)
from gap_validation.core.errors import GapValidationError
from gap_validation.core.models import LinearModel
from gap_validation.core.numbers import significant
from gap_validation.core.results import Band, Candidate, ConstantFactor
from gap_validation.core.spectra import sweep_points

if TYPE_CHECKING:  # pragma: no cover
    from gap_validation.core.estimator import SpectralEstimate

__all__ = [
    "ChannelDiagnosis",
    "analyse_channel",
    "fit_effects",
    "FittedCandidate",
    "cifer_weight",
    "cifer_cost",
    "bendat_piersol_random_error",
    "effective_random_error",
    "epsilon_noise_scale",
    "minimum_averages",
    "normalised_mismatch",
    "frequency_flags",
    "find_bands",
    "FAMILIES",
    "PAIRS",
    "SIGMA_FACTOR",
    "BIAS_ERROR",
    "band_edge_warning",
    "information_criteria",
    "confident_mask",
    "INDISTINGUISHABLE",
    "constant_factor",
    "FACTOR_SPAN",
]

#: Noise-only epsilon is Rayleigh with scale ``sigma = e/2``; ``P(eps > k sigma) = exp(-k^2/2)``: k = 4 gives
#: 3.4e-4 per frequency, about 1 % over 40 frequencies.
SIGMA_FACTOR = 4.0
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
#: A noise scale more than this many times wider than the coherence allows (the classical random error with
#: the systematic floor) is no random error: :func:`find_bands` says so rather than "the random error explains
#: it".
BOUND_CHECK = 10.0
#: Systematic error floor of a measured response, relative (1 % of |H|, 0.6 deg): interpolation of the
#: streams onto the grid and timestamp offsets between them. The estimator's own smoothing bias is not in it:
#: the decisions compare the data with the model seen through the estimator (``estimate.expected``).
BIAS_ERROR = 0.01
#: Probability that noise alone (zero true coherence) gives a coherence estimate above the threshold, used to
#: set the minimum number of averages of a usable frequency (:func:`minimum_averages`).
COHERENCE_FALSE_ALARM = 1e-3
#: CIFER phase weight per deg^2 (1 dB ~ 7.6 deg).
_PHASE_WEIGHT = 0.01745
_DB_PER_NEPER = 20.0 / math.log(10.0)
_DEG_PER_RAD = 180.0 / math.pi
_N_STARTS = 3          # local refinements per candidate, from distinct grid points
#: A fitted parameter within this fraction of its search box (fit coordinates) from an edge sits on the bound.
BOUND_TOLERANCE = 1e-3
#: ``parameter_error`` searches each coefficient within x10 of the model's, then once within x100 (widened)
#: when the fit sits on a bound; still on it, the refit is beyond the search range.
COEFFICIENT_RANGES = (10.0, 100.0)
_MIN_POINTS = 4        # fewer confident points: no fitting
#: A constant factor within the tolerance (:func:`constant_factor`) is said only over confident frequencies
#: that span at least this ratio: a decade, the span over which Bode's gain-phase relation ties a linear
#: element's phase to its gain slope (a delay of 10 ms is a constant 4 +- 2 deg over 5-12 rad/s).
FACTOR_SPAN = 10.0
_MAX_CANDIDATES = 6    # reported at most


@dataclass
class ChannelDiagnosis:
    """Where one channel's model fails and which effects would explain it.

    Attributes
    ----------
    limited_by : str
        ``"model"``, ``"data"`` or ``"none"`` (JSON ``limited_by``): ``"model"`` when any band is
        model-limited (the model must change there, whatever better data would show elsewhere), else
        ``"data"`` when any band is data-limited or no frequency has enough coherence, else ``"none"``
        (epsilon within the threshold everywhere).
    frequency_flags : list of str
        Per frequency: ``"ok"`` (epsilon within the threshold), ``"model"``, ``"data"`` or ``"excluded"``
        (coherence below its threshold).
    bands : list of Band
        Runs of frequencies flagged ``model`` or ``data`` (:class:`~gap_validation.core.results.Band`: edges,
        peak, epsilon at the peak, verdict, reason, lowest coherence, largest normalised mismatch, fewest
        averages).
    candidates : list of Candidate
        JSON ``diagnosis``, best first (:class:`~gap_validation.core.results.Candidate`). ``parameter_error``
        has empty ``effects`` and the refitted ``model`` mapping (replace the model's airframe; nothing to
        append) with a ``note`` saying so.
    message : str
        One plain sentence for the terminal.
    beyond_range : list of str
        Fits that would have been candidates but sit on a bound of their search range (never offered as a
        fix), one phrase each (``"gain (factor at -10 (lower bound))"``), listed when no offered candidate
        explains the mismatch.
    warnings : list of str
        What the data-path numbers may not show (:func:`band_edge_warning`, a failed winding-number condition
        between the model and the top candidate's model), one line each (``ChannelResult.warnings``).
    margins_caveat : str
        Why the margins from epsilon are not guaranteed although epsilon < 1 (empty: nothing known against
        them).
    nonlinearity : str or None
        :data:`~gap_validation.core.nonlinearity.NONLINEARITY` when sweeps flown at different amplitudes
        disagree beyond their errors (JSON ``nonlinearity``), else None.
    nonlinearity_evidence : str or None
        The comparison in words (JSON ``nonlinearity_evidence``), also when nothing was detected; None when
        the sweeps do not span different amplitudes.
    amplitude : ndarray or None
        Input amplitude flown per frequency (:func:`~gap_validation.core.nonlinearity.flown_amplitude`).
    convention : ConventionFit or None
        The sign, units or clock factor the data are the model times (:mod:`gap_validation.core.conventions`),
        leaving them within their errors: no physical diagnosis then.
    within_tolerance : ConstantFactor or None
        A channel within the tolerance whose data still resolve a difference that one constant complex factor
        explains (:func:`constant_factor`; JSON ``within_tolerance``); None otherwise.
    """

    limited_by: str = "none"
    frequency_flags: list[str] = field(default_factory=list)
    bands: list[Band] = field(default_factory=list)
    candidates: list[Candidate] = field(default_factory=list)
    message: str = ""
    beyond_range: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    margins_caveat: str = ""
    nonlinearity: str | None = None
    nonlinearity_evidence: str | None = None
    amplitude: np.ndarray | None = None
    convention: object = None
    within_tolerance: ConstantFactor | None = None


# ------------------------------------------------------------------------------------------------ statistics


def cifer_weight(coherence: ArrayLike) -> np.ndarray:
    """CIFER coherence weighting ``W_g = [1.58 (1 - exp(-g^2))]^2`` (Tischler & Remple, ch. 11).

    Parameters
    ----------
    coherence : array_like
        Squared coherence ``g^2`` in [0, 1].

    Returns
    -------
    ndarray
        Weights, 0 at zero coherence and 1.0 at ``g^2 = 1``.
    """
    g2 = np.clip(np.asarray(coherence, dtype=float), 0.0, 1.0)
    return (1.58 * (1.0 - np.exp(-g2))) ** 2


def _log_ratio(p_fit, p_meas) -> np.ndarray:
    """Complex log of ``p_fit / p_meas``: real part in nepers, imaginary part the wrapped phase [rad]."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log(p_fit / p_meas)


def cifer_cost(p_fit: ArrayLike, p_meas: ArrayLike, coherence: ArrayLike) -> float:
    """CIFER cost ``J = 20/n sum W_g [dB error^2 + 0.01745 deg error^2]`` (Tischler & Remple, ch. 11).

    Parameters
    ----------
    p_fit, p_meas : array_like of complex
        Model and measured responses at the same n frequencies.
    coherence : array_like
        Squared coherence at those frequencies.

    Returns
    -------
    float
        J (about 100 or less: acceptable fit; 50 or less: nearly indistinguishable).
    """
    log_q = _log_ratio(np.asarray(p_fit, dtype=complex), np.asarray(p_meas, dtype=complex))
    w_g = cifer_weight(coherence)
    err = (_DB_PER_NEPER * log_q.real) ** 2 + _PHASE_WEIGHT * (_DEG_PER_RAD * log_q.imag) ** 2
    return float(20.0 / max(len(w_g), 1) * np.sum(w_g * err))


def bendat_piersol_random_error(coherence: ArrayLike, n_averages: ArrayLike) -> np.ndarray:
    """Normalised random error of |H|: ``e_r = sqrt(1 - g^2) / (|g| sqrt(2 n_d))`` (Bendat & Piersol, ch. 9).

    The phase error is about ``e_r`` rad. Infinite where the coherence is zero.

    Parameters
    ----------
    coherence : array_like
        Squared coherence ``g^2``.
    n_averages : array_like
        Number of averaged segments ``n_d``.
    """
    g2 = np.clip(np.asarray(coherence, dtype=float), 0.0, 1.0)
    n = np.maximum(np.asarray(n_averages, dtype=float), 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        e_r = np.sqrt(1.0 - g2) / (np.sqrt(g2) * np.sqrt(2.0 * n))
    return np.where(g2 > 0.0, e_r, np.inf)


def _n_averages(estimate) -> np.ndarray:
    """Averages per frequency (inf when the estimate does not say)."""
    shape = np.shape(estimate.coherence)
    n = getattr(estimate, "n_averages", None)
    if n is None:
        return np.full(shape, np.inf)
    return np.broadcast_to(np.asarray(n, dtype=float), shape).copy()


def _random_error_of(estimate) -> np.ndarray:
    """The estimate's random error; Bendat & Piersol's formula where it carries none (or a non-finite one)."""
    computed = bendat_piersol_random_error(estimate.coherence, np.minimum(_n_averages(estimate), 1e12))
    given = getattr(estimate, "random_error", None)
    if given is None:
        return computed
    given = np.asarray(given, dtype=float)
    return np.where(np.isfinite(given), given, computed)


def _sweep_scatter_error(estimate, sweeps: Sequence, coherence_threshold: float) -> np.ndarray:
    """Relative random error of the average from the scatter between manoeuvres (NaN with fewer than 3).

    Per frequency, over the m manoeuvres whose own estimate is coherent there and has a variance: the
    inverse-variance weighted mean and ``chi^2 = sum |H_i - mean|^2 / var_i`` (about m - 1 when the manoeuvres
    agree within their errors, Birge); the average's error is its own scaled by ``sqrt(chi^2 / (m - 1))``. A
    flight whose manoeuvres disagree more than their noise says (turbulence that changed, a nonlinear
    response to different amplitudes) widens the error instead of calling the difference model-limited.
    """
    w = np.asarray(estimate.w_rad_s, dtype=float)
    out = np.full(w.shape, np.nan)
    usable = [
        s for s in sweeps if np.shape(s.response) == w.shape and getattr(s, "variance", None) is not None
    ]
    if len(usable) < 3:
        return out
    h = np.array([np.asarray(s.response, dtype=complex) for s in usable])
    var = np.array([np.asarray(s.variance, dtype=float) for s in usable])
    ok = (np.array([np.asarray(s.coherence, dtype=float) >= coherence_threshold for s in usable])
          & np.isfinite(h) & np.isfinite(var) & (var > 0))
    m = ok.sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = np.where(ok, 1.0 / np.where(ok, var, 1.0), 0.0)
        mean = np.sum(weight * np.where(ok, h, 0.0), axis=0) / np.sum(weight, axis=0)
        chi2 = np.sum(weight * np.abs(np.where(ok, h - mean, 0.0)) ** 2, axis=0)
        birge = np.sqrt(np.maximum(chi2 / (m - 1), 1.0))
        e = birge * _random_error_of(estimate)
    return np.where(m >= 3, e, out)


def effective_random_error(estimate: SpectralEstimate, sweeps: Sequence[SpectralEstimate] = (),
                           coherence_threshold: float = 0.0, bias_error: float = 0.0) -> np.ndarray:
    """Relative error of the averaged response the diagnosis allows for.

    The larger of the estimate's random error (Bendat & Piersol) and the scatter between sweeps (where at
    least three sweeps are confident), combined with a systematic floor as ``sqrt(e_r^2 + bias_error^2)``.

    Parameters
    ----------
    estimate : SpectralEstimate
        Averaged estimate (``w_rad_s``, ``response``, ``coherence``, ``random_error``, ``n_averages``).
    sweeps : sequence of SpectralEstimate
        Per-sweep estimates on the same frequencies.
    coherence_threshold : float
        Sweeps count at a frequency only where their coherence passes it.
    bias_error : float
        Relative systematic error of any spectral estimate (:data:`BIAS_ERROR` in :func:`analyse_channel`).

    Returns
    -------
    ndarray
        Relative error per frequency (magnitude fraction; phase in rad).
    """
    e_bp = _random_error_of(estimate)
    e_sc = _sweep_scatter_error(estimate, sweeps, coherence_threshold)
    e_r = np.where(np.isfinite(e_sc), np.maximum(e_bp, e_sc), e_bp)
    return np.hypot(e_r, bias_error)


def epsilon_noise_scale(relative_error: ArrayLike) -> np.ndarray:
    """Scale ``sigma = e / 2`` of epsilon(w) between a model and noisy data that equal it.

    With ``P2 = P1 (1 + d)``, ``d`` complex with components of standard deviation ``e``,
    ``epsilon = |d| / |2 + d| ~ |d| / 2`` (eq. 14): Rayleigh with scale ``e / 2``.

    Parameters
    ----------
    relative_error : array_like
        Relative error ``e`` of the measured response per frequency (:func:`effective_random_error`).
    """
    return 0.5 * np.asarray(relative_error, dtype=float)


def minimum_averages(coherence_threshold: float, false_alarm: float = COHERENCE_FALSE_ALARM,
                     coefficients: int = 2) -> int:
    """Fewest degrees of freedom for which a coherence above the threshold is not plausibly noise.

    The coherence of a local polynomial fit with ``nh`` complex coefficients and ``d`` residual degrees of
    freedom is, for pure noise, Beta(nh, d) distributed (the share of the output a random regression
    explains); the result is the smallest ``d`` making ``P(coherence > c)`` at most ``false_alarm`` (10 for c
    = 0.6 and the default first-order polynomial, nh = 2), within [4, 64].

    Parameters
    ----------
    coherence_threshold : float
        Coherence a confident frequency must reach.
    false_alarm : float
        Allowed probability that noise alone passes.
    coefficients : int
        Complex coefficients of the response polynomial (``order + 1``).
    """
    c = min(max(float(coherence_threshold), 1e-6), 0.999)
    for d in range(4, 65):
        if 1.0 - betainc(coefficients, d, c) <= false_alarm:
            return d
    return 64


def confident_points(estimate: SpectralEstimate, coherence_threshold: float) -> np.ndarray:
    """Frequencies whose estimate counts for epsilon, the nu-gap and the diagnosis (the one definition).

    A point is confident when its coherence passes the threshold *and* means something: pure noise would reach
    the coherence it has with probability at most :data:`COHERENCE_FALSE_ALARM` (a Beta(nh, d) law for ``nh``
    response coefficients and ``d`` degrees of freedom, see :func:`minimum_averages`); and its response is
    finite and nonzero. At the threshold (0.6) that takes 12 degrees of freedom; a coherence of 0.99 needs
    three (one clean 8 s record).

    Parameters
    ----------
    estimate : SpectralEstimate
        Averaged estimate (``response``, ``coherence``, ``n_averages``: degrees of freedom).
    coherence_threshold : float
        The channel's coherence threshold.
    """
    return confident_mask(
        estimate.response,
        estimate.coherence,
        _n_averages(estimate),
        _coefficients(estimate),
        coherence_threshold,
    )


def confident_mask(response: ArrayLike, coherence: ArrayLike, dof: ArrayLike, coefficients: int,
                   coherence_threshold: float) -> np.ndarray:
    """:func:`confident_points` on arrays (a MIMO matrix's worst output, for instance).

    Parameters
    ----------
    response : array_like, complex
        The response per frequency (a point needs it finite and nonzero).
    coherence : array_like
        Coherence per frequency.
    dof : array_like
        Degrees of freedom per frequency (inf: not limited).
    coefficients : int
        Complex coefficients of the response polynomial per frequency (the Beta law's ``nh``).
    coherence_threshold : float
        The channel's coherence threshold.
    """
    p_meas = np.asarray(response, complex)
    coherence = np.asarray(coherence, float)
    dof = np.broadcast_to(np.asarray(dof, float), coherence.shape)
    nh = int(coefficients)
    with np.errstate(invalid="ignore"):
        chance = np.where(np.isfinite(dof) & (dof >= 1), 1.0 - betainc(nh, np.maximum(dof, 1.0),
                                                                         np.clip(coherence, 0.0, 1.0)), 0.0)
    return ((coherence >= coherence_threshold) & np.isfinite(p_meas) & (np.abs(p_meas) > 0)
            & (dof >= 1) & (chance <= COHERENCE_FALSE_ALARM))


def _coefficients(estimate) -> int:
    """Complex coefficients of the estimate's response polynomial (2 when it does not say)."""
    return int(getattr(estimate, "coefficients", 2))


def normalised_mismatch(eps_w: ArrayLike, sigma: ArrayLike, dof: ArrayLike = np.inf) -> np.ndarray:
    """How many noise scales the mismatch is: the Rayleigh-equivalent ``k`` of ``epsilon / sigma``.

    With the noise variance estimated on ``d`` (complex) degrees of freedom the normalised squared error of
    the response is ``F(2, 2 d)`` distributed: ``P = (1 + r^2 / (2 d))^-d`` for ``r = epsilon / sigma``, and
    ``k = sqrt(-2 ln P) = sqrt(2 d ln(1 + r^2 / (2 d)))``, which tends to ``r`` (Rayleigh) for many degrees of
    freedom.

    Parameters
    ----------
    eps_w, sigma : array_like
        epsilon(w) and its noise scale.
    dof : array_like
        Degrees of freedom per frequency (inf: the Rayleigh limit).
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.asarray(eps_w, float) / np.asarray(sigma, float)
        d = np.maximum(np.asarray(dof, float), 0.5)
        k = np.sqrt(2.0 * d * np.log1p(r ** 2 / (2.0 * d)))
        k = np.where(np.isfinite(d), k, r)
    return np.where(np.isfinite(r), k, np.where(np.isnan(r), 0.0, np.inf))


# ------------------------------------------------------------------------------------------------ where it
# fails


def frequency_flags(eps_w: ArrayLike, mismatch: ArrayLike, coherent: ArrayLike, confident: ArrayLike,
                    epsilon_threshold: float,
                    sigma_factor: float = SIGMA_FACTOR) -> list[str]:
    """Per-frequency verdict.

    ``coherent``: coherence passes the threshold; ``confident``: also enough degrees of freedom
    (:func:`confident_points`). Returns ``"not_excited"`` (no estimate: the input is not excited there, or the
    manoeuvres cannot resolve the frequency; never model-limited), ``"excluded"`` (coherence below the
    threshold and epsilon within it), ``"ok"``
    (epsilon within the threshold), ``"model"`` (epsilon above it and the normalised mismatch beyond
    ``sigma_factor`` at a confident frequency) or ``"data"`` (above it, but low coherence, too few averages or
    within the errors: the data cannot tell, fly better sweeps there). Only confident frequencies count for
    epsilon; a ``"data"`` flag at low coherence marks where a mismatch may hide in the noise.

    Parameters
    ----------
    eps_w : array_like
        epsilon(w) of the model against the averaged data (eq. 14).
    mismatch : array_like
        Normalised mismatch k per frequency (:func:`normalised_mismatch`).
    coherent : array_like of bool
        Coherence passes the threshold.
    confident : array_like of bool
        Also enough averages (:func:`confident_points`).
    epsilon_threshold : float
        epsilon(w) above it is flagged ``model`` or ``data``.
    sigma_factor : float
        Normalised mismatch beyond which a confident frequency is model-limited.
    """
    flags = []
    for e, k, c, u in zip(np.asarray(eps_w, float), np.asarray(mismatch, float), np.asarray(coherent, bool),
                          np.asarray(confident, bool)):
        if not np.isfinite(e):
            flags.append("not_excited")
        elif not c and e <= epsilon_threshold:
            flags.append("excluded")
        elif not c:
            flags.append("data")
        elif e <= epsilon_threshold:
            flags.append("ok")
        elif u and k > sigma_factor:
            flags.append("model")
        else:
            flags.append("data")
    return flags


def find_bands(
    w_rad_s: ArrayLike,
    eps_w: ArrayLike,
    mismatch: ArrayLike,
    coherence: ArrayLike,
    n_averages: ArrayLike,
    flags: Sequence[str],
    coherence_threshold: float,
    min_averages: int = 0,
    sigma_factor: float = SIGMA_FACTOR,
    sigma: ArrayLike | None = None,
) -> list[Band]:
    """Runs of adjacent frequencies flagged ``model`` or ``data``, each with its verdict and reason.

    A band is model-limited when at least one of its frequencies is; otherwise data-limited. Excluded and
    not-excited frequencies end a band.

    Parameters
    ----------
    w_rad_s : array_like
        Frequencies [rad/s].
    eps_w, mismatch : array_like
        epsilon(w) and the normalised mismatch k per frequency.
    coherence, n_averages : array_like
        Coherence and degrees of freedom per frequency.
    flags : sequence of str
        Per-frequency verdicts (:func:`frequency_flags`).
    coherence_threshold : float
        The channel's coherence threshold (for the reasons).
    min_averages : int
        Degrees of freedom a usable frequency needs (:func:`minimum_averages`).
    sigma_factor : float
        As for :func:`frequency_flags`.
    sigma : array_like, optional
        The noise scale of epsilon(w) each point was judged with: where it is far wider than the coherence
        allows (:data:`BOUND_CHECK` times the classical bound with the systematic floor) and the classical
        bound alone puts the mismatch beyond ``sigma_factor``, a data-limited band says it is a bias
        allowance, not random error.
    """
    bands, start = [], None
    for i, flag in enumerate(list(flags) + ["ok"]):
        inside = flag in ("model", "data")
        if inside and start is None:
            start = i
        elif not inside and start is not None:
            bands.append(_band(np.arange(start, i), w_rad_s, eps_w, mismatch, coherence, n_averages, flags,
                               coherence_threshold, min_averages, sigma_factor, sigma))
            start = None
    return bands


def _band(idx, w_rad_s, eps_w, mismatch, coherence, n_averages, flags, coherence_threshold, min_averages,
          sigma_factor, sigma=None) -> Band:
    w, eps = np.asarray(w_rad_s, float), np.asarray(eps_w, float)
    peak = idx[int(np.argmax(eps[idx]))]
    k_max = float(np.max(np.asarray(mismatch, float)[idx]))
    coh_min = float(np.min(np.asarray(coherence, float)[idx]))
    n_min = float(np.min(np.asarray(n_averages, float)[idx]))
    model = any(flags[i] == "model" for i in idx)
    if model:
        reason = (f"confident data disagree with the model: the mismatch is {k_max:.0f} noise scales "
                  f"(coherence >= {coherence_threshold:g}, random error included)")
    elif coh_min < coherence_threshold:
        reason = (f"low coherence (down to {coh_min:.2f} < {coherence_threshold:g}): noise or disturbances "
                  f"dominate; fly better sweeps there (more amplitude, longer, calmer air)")
    elif n_min < min_averages:
        reason = (
            f"too few degrees of freedom ({n_min:.0f} < {min_averages}) for the coherence to mean much; "
            f"fly the manoeuvre again, or longer, there"
        )
    elif sigma is not None and (k_coherence := _coherence_mismatch(
            eps[idx], np.asarray(coherence, float)[idx], np.asarray(n_averages, float)[idx],
            np.asarray(sigma, float)[idx])) > sigma_factor:
        reason = (
            f"the coherence (down to {coh_min:.2f}) and degrees of freedom put the mismatch at "
            f"{k_coherence:.0f} noise scales: the larger error allowed there is no random error but a bias "
            f"allowance (feedback, or another surface moving with the input: see the warnings); not "
            f"validated there"
        )
    else:
        reason = (f"the random error explains the mismatch (at most {k_max:.1f} noise scales, coherence down "
                  f"to {coh_min:.2f}); fly better sweeps there")
    return Band(min_rad_s=float(w[idx[0]]), max_rad_s=float(w[idx[-1]]), peak_rad_s=float(w[peak]),
                epsilon=float(eps[peak]), limited_by="model" if model else "data", reason=reason,
                coherence_min=coh_min, mismatch_sigma=k_max if math.isfinite(k_max) else None,
                min_averages=n_min if math.isfinite(n_min) else None)


def _coherence_mismatch(
    eps_w: np.ndarray, coherence: np.ndarray, dof: np.ndarray, sigma: np.ndarray
) -> float:
    """The largest normalised mismatch, by the classical coherence bound (Bendat and Piersol's random error of
    a response with this coherence on these degrees of freedom, :func:`bendat_piersol_random_error`, with the
    systematic floor :data:`BIAS_ERROR`; half of it the noise scale of epsilon), at the points whose noise
    scale ``sigma`` is more than :data:`BOUND_CHECK` times wider: a check on an error a point was given beyond
    what its coherence allows (a bias allowance). 0 where none is."""
    classical = epsilon_noise_scale(
        np.hypot(bendat_piersol_random_error(coherence, np.maximum(dof, 1.0)), BIAS_ERROR)
    )
    wide = np.asarray(sigma, float) > BOUND_CHECK * classical
    k = normalised_mismatch(eps_w, classical, dof)
    k = np.where(wide & np.isfinite(k), k, 0.0)
    return float(np.max(k)) if k.size else 0.0


# ------------------------------------------------------------------------------------------------ effect
# families


#: Effect type -> how it is fitted (:class:`~gap_validation.core.effects.EffectFit`), a view of the registry.
FAMILIES: dict[str, EffectFit] = {name: e.fit for name, e in EFFECTS.items() if e.fit is not None}

#: Pairs fitted when no single effect explains the mismatch, named by their sorted types joined with "+".
PAIRS: tuple[tuple[str, str], ...] = tuple(itertools.combinations(sorted(FAMILIES), 2))


# ------------------------------------------------------------------------------------------------ fitting


@dataclass
class _FitData:
    """Usable points of the averaged estimate, ready for the CIFER residuals."""

    w: np.ndarray
    p_meas: np.ndarray
    p_model: np.ndarray
    sqrt_w: np.ndarray        # sqrt of the CIFER weight
    coherence: np.ndarray
    ctx: FitRange

    def residuals(self, factor: np.ndarray) -> np.ndarray:
        """CIFER residuals for factors (M, N) -> (M, 2N): sqrt(W) dB error and sqrt(W 0.01745) deg error."""
        log_q = _log_ratio(self.p_model * factor, self.p_meas)
        mag = self.sqrt_w * _DB_PER_NEPER * log_q.real
        phase = self.sqrt_w * math.sqrt(_PHASE_WEIGHT) * _DEG_PER_RAD * log_q.imag
        out = np.concatenate([mag, phase], axis=-1)
        return np.where(np.isfinite(out), out, 1e6)

    def cost(self, factor: np.ndarray) -> np.ndarray:
        """CIFER J for factors (M, N) -> (M,)."""
        return 20.0 / self.w.size * np.sum(self.residuals(factor) ** 2, axis=-1)


@dataclass
class _Combo:
    """A set of effects fitted together (one effect, or a pair)."""

    families: tuple[EffectType, ...]

    @property
    def name(self) -> str:
        return "+".join(sorted(f.name for f in self.families))

    @property
    def complexity(self) -> int:
        return sum(f.complexity for f in self.families)

    def _split(self, x: np.ndarray) -> list[np.ndarray]:
        sizes = np.cumsum([f.complexity for f in self.families])[:-1]
        return np.split(x, sizes, axis=-1)

    def response(self, x: np.ndarray, w: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(x)
        out = np.ones((x.shape[0], w.size), dtype=complex)
        for fam, part in zip(self.families, self._split(x)):
            out = out * fam.fit.response(part, w)
        return out

    def grid(self, ctx: FitRange) -> np.ndarray:
        if len(self.families) == 1:
            return self.families[0].fit.grid(ctx, False)
        grids = [f.fit.grid(ctx, True) for f in self.families]
        rows = [np.concatenate(parts) for parts in itertools.product(*grids)]
        return np.array(rows)

    def bounds(self, x0: np.ndarray, ctx: FitRange) -> tuple[np.ndarray, np.ndarray]:
        parts = [f.fit.bounds(p, ctx) for f, p in zip(self.families, self._split(x0))]
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])

    def specs(self, x: np.ndarray) -> list[dict]:
        return [
            validate_effect(f.fit.spec(p)) for f, p in zip(self.families, self._split(np.asarray(x, float)))
        ]


def _distinct_starts(grid: np.ndarray, costs: np.ndarray, span: np.ndarray, count: int) -> list[np.ndarray]:
    """The best ``count`` grid points that differ by more than 5 % of the parameter range from each other."""
    chosen: list[np.ndarray] = []
    for i in np.argsort(costs):
        if not np.isfinite(costs[i]):
            break
        x = grid[i]
        if all(np.max(np.abs(x - c) / span) > 0.05 for c in chosen):
            chosen.append(x)
        if len(chosen) == count:
            break
    return chosen


def _fit_combo(combo: _Combo, data: _FitData) -> np.ndarray:
    """Coarse grid, then bounded least squares from distinct grid points; returns the best parameters."""
    grid = combo.grid(data.ctx)
    costs = np.concatenate([data.cost(combo.response(chunk, data.w))
                            for chunk in np.array_split(grid, max(1, grid.shape[0] // 2000))])
    lo_all, hi_all = combo.bounds(grid[int(np.argmin(costs))], data.ctx)
    span = np.where(np.isfinite(hi_all - lo_all), hi_all - lo_all, 1.0)
    best_x, best_cost = None, np.inf
    for x0 in _distinct_starts(grid, costs, span, _N_STARTS):
        lo, hi = combo.bounds(x0, data.ctx)
        x0 = np.clip(x0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        from scipy.optimize import least_squares  # scipy.optimize costs 0.6 s at import: only when used
        sol = least_squares(lambda x: data.residuals(combo.response(x, data.w))[0], x0, bounds=(lo, hi),
                            x_scale=(hi - lo) / 10.0, method="trf", max_nfev=200)
        cost = data.cost(combo.response(sol.x, data.w))[0]
        if cost < best_cost:
            best_x, best_cost = sol.x, cost
    return best_x


def _coefficient_fit(model: LinearModel, data: _FitData, factor: float = COEFFICIENT_RANGES[0],
                     start: LinearModel | None = None) -> tuple[LinearModel, str] | None:
    """Refit the airframe's numerator/denominator coefficients (same structure, monic denominator), each as
    ``c = c0 exp(x)`` within ``|x| <= ln(factor)``, started at the current values (x = 0) or at ``start``,
    effects kept: the ``parameter_error`` candidate, and which coefficients sit on the bound (empty: none)."""
    air = model.airframe
    num0, den0 = np.array(air.num, float), np.array(air.den, float)
    free_num = np.flatnonzero(num0 != 0.0)
    free_den = np.flatnonzero(den0[1:] != 0.0) + 1
    n_free = free_num.size + free_den.size
    if n_free == 0:
        return None
    s = 1j * data.w
    others = LinearModel([1.0], [1.0], air.delay_s, model.effects).freqresp(data.w)

    def build(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        num, den = num0.copy(), den0.copy()
        num[free_num] *= np.exp(x[:free_num.size])
        den[free_den] *= np.exp(x[free_num.size:])
        return num, den

    def residuals(x: np.ndarray) -> np.ndarray:
        num, den = build(x)
        p = np.polyval(num, s) / np.polyval(den, s) * others
        return data.residuals((p / data.p_model)[None, :])[0]

    bound = np.full(n_free, math.log(factor))
    x0 = np.zeros(n_free)
    if start is not None and len(start.airframe.num) == len(num0) and len(start.airframe.den) == len(den0):
        with np.errstate(divide="ignore", invalid="ignore"):
            x0 = np.log(np.concatenate([np.asarray(start.airframe.num, float)[free_num] / num0[free_num],
                                        np.asarray(start.airframe.den, float)[free_den] / den0[free_den]]))
        x0 = np.clip(np.where(np.isfinite(x0), x0, 0.0), -0.999 * bound, 0.999 * bound)
    from scipy.optimize import least_squares  # scipy.optimize costs 0.6 s at import: only when used
    sol = least_squares(residuals, x0, bounds=(-bound, bound), method="trf", max_nfev=100 * n_free)
    num, den = build(sol.x)
    num = np.array([significant(v, 6) for v in num])
    den = np.array([significant(v, 6) for v in den])
    names = [f"numerator[{i}]" for i in free_num] + [f"denominator[{i}]" for i in free_den]
    ratios = [f"x{math.exp(v):.3g}" for v in sol.x]
    edge = [f"{n} {r}" for n, r, v in zip(names, ratios, sol.x)
            if abs(abs(v) - bound[0]) <= BOUND_TOLERANCE * 2.0 * bound[0]]
    return LinearModel(num, den, air.delay_s, model.effects), ", ".join(edge)


# ------------------------------------------------------------------------------------------------ evidence


@dataclass
class _Evidence:
    """The averaged estimate with the statistics the decisions need."""

    w: np.ndarray
    p_meas: np.ndarray
    coherence: np.ndarray
    n_averages: np.ndarray     # degrees of freedom of the noise estimate per frequency
    confident: np.ndarray      # counts for epsilon (as in the validator)
    sigma: np.ndarray          # noise scale of epsilon(w): random error, scatter and the systematic floor
    sigma_factor: float
    estimate: object = None    # for ``expected``: the model seen through the estimator
    min_dof: int = 10          # degrees of freedom a confident frequency needs (:func:`minimum_averages`)

    def mismatch(self, eps_w: ArrayLike, expansion_error: ArrayLike = 0.0) -> np.ndarray:
        """Normalised mismatch k per frequency (:func:`normalised_mismatch`); ``expansion_error`` (relative)
        widens the noise scale where the model's expansion over a band is inexact."""
        sigma = np.hypot(self.sigma, 0.5 * np.asarray(expansion_error, float))
        return normalised_mismatch(eps_w, sigma, self.n_averages)

    def expected(self, response: Callable[[np.ndarray], ArrayLike]) -> tuple[np.ndarray, np.ndarray]:
        """A model's response through the estimator, and the expansion error
        (:meth:`SpectralEstimate.expected`); the plain response where the estimate cannot say."""
        direct = np.asarray(response(self.w), complex)
        method = getattr(self.estimate, "expected", None)
        if method is None:
            return direct, np.zeros(self.w.shape)
        through, error = method(response)
        through = np.asarray(through, complex)
        return np.where(np.isfinite(through), through, direct), np.where(np.isfinite(error), error, 0.0)

    def fit(self, response: Callable[[np.ndarray], ArrayLike]) -> "_Fit":
        """epsilon(w) of a model (``response(w) -> complex``) against the data, with its sups and statistics.

        epsilon(w) is the paper's (the model at w against the estimate); the mismatch ``k`` and the
        chi-square, which decide, compare the estimate with the model seen through the estimator, so the
        estimator's own smoothing does not count as a mismatch.
        """
        p_fit = np.asarray(response(self.w), complex)
        eps_w = np.asarray(metrics.epsilon_per_frequency(p_fit, self.p_meas), float)
        eps, worst = _sup(eps_w, self.confident)
        through, error = self.expected(response)
        k = self.mismatch(metrics.epsilon_per_frequency(through, self.p_meas), error)
        k_max = float(np.max(np.where(self.confident, k, 0.0))) if self.confident.any() else 0.0
        return _Fit(eps_w, eps, worst, k_max, self._chi2(through, error), k)

    def _chi2(self, p_fit, expansion_error) -> float:
        """``sum |ln(P_fit / P_meas)|^2 / e^2`` over the usable frequencies (about 2 per frequency when the
        fit equals the truth: chi-square with 2 n degrees of freedom)."""
        u = self.confident
        log_q = _log_ratio(np.asarray(p_fit, complex)[u], self.p_meas[u])
        e2 = (2.0 * self.sigma[u]) ** 2 + np.asarray(expansion_error, float)[u] ** 2
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            terms = np.abs(log_q) ** 2 / e2
        return float(np.sum(np.where(np.isfinite(terms), terms, 1e12)))


def _sup(values: np.ndarray, mask: np.ndarray) -> tuple[float, int]:
    masked = np.where(mask & np.isfinite(values), values, -np.inf)
    if not np.any(np.isfinite(masked)):
        return math.nan, -1
    k = int(np.argmax(masked))
    return float(values[k]), k


@dataclass
class _Fit:
    eps_w: np.ndarray
    eps: float             # sup over confident frequencies (what a replay reports)
    worst: int
    k_max: float           # largest normalised mismatch at a usable frequency
    chi2: float
    k: np.ndarray          # normalised mismatch per frequency


def _evidence(estimate, sweeps, coherence_threshold, bias_error, sigma_factor) -> _Evidence:
    w = np.asarray(estimate.w_rad_s, float)
    p_meas = np.asarray(estimate.response, complex)
    coherence = np.asarray(estimate.coherence, float)
    n_avg = _n_averages(estimate)
    confident = confident_points(estimate, coherence_threshold)
    sigma = epsilon_noise_scale(effective_random_error(estimate, sweeps, coherence_threshold, bias_error))
    min_dof = minimum_averages(coherence_threshold, coefficients=_coefficients(estimate))
    return _Evidence(w, p_meas, coherence, n_avg, confident, sigma, sigma_factor, estimate, min_dof)


# ------------------------------------------------------------------------------------------------ candidates


@dataclass
class FittedCandidate:
    """A fitted explanation: effects in series with the model (or a refitted model), scored on the data.

    Attributes
    ----------
    name : str
        Effect type, ``"a+b"`` for a pair (sorted names) or ``"parameter_error"``.
    complexity : int
        Number of fitted parameters.
    effects : list of dict
        Effects to append to the model (empty for ``parameter_error``).
    model : LinearModel
        The model with the candidate applied.
    members : tuple of str
        The two effect types of a pair (empty otherwise).
    replacement : bool
        True for ``parameter_error`` (the model's coefficients changed; nothing to append).
    at_bound : str
        Which parameter sits on which edge of its search range (``"damping at 1 (upper bound)"``), empty when
        none does: such a fit is beyond the search range and never offered as a fix.
    criterion : float or None
        Its information criterion among the candidates ranked with it (:func:`information_criteria`).
    indistinguishable : list of str
        For the top-ranked candidate: the others the data cannot tell from it (:data:`INDISTINGUISHABLE`).
    detail : str
        ``parameter_error`` refitted by its modes: the moves in words (``gain x1.3, mode 4.24 -> 5.1 rad/s
        ...``).
    """

    name: str
    complexity: int
    effects: list[dict]
    model: LinearModel
    members: tuple[str, ...] = ()
    replacement: bool = False
    score: _Fit | None = None
    at_bound: str = ""
    # information criterion (:func:`information_criteria`), when ranked
    criterion: float | None = None
    indistinguishable: list[str] = field(default_factory=list)   # the ranked top's equals
    detail: str = ""                        # a refit's changes in words


def _fit_data(model: LinearModel, ev: _Evidence) -> _FitData | None:
    if np.count_nonzero(ev.confident) < _MIN_POINTS:
        return None
    u = ev.confident
    wc = ev.w[u]
    return _FitData(w=wc, p_meas=ev.p_meas[u], p_model=model.freqresp(wc),
                    sqrt_w=np.sqrt(cifer_weight(ev.coherence[u])), coherence=ev.coherence[u],
                    ctx=FitRange(float(wc.min()), float(wc.max())))


def _fit_combo_candidate(combo: _Combo, model: LinearModel, data: _FitData) -> FittedCandidate:
    x = _fit_combo(combo, data)
    effects = combo.specs(x)
    members = tuple(f.name for f in combo.families)
    lo, hi = combo.bounds(x, data.ctx)
    names = [
        f"{f.name}.{p.name}" if len(members) > 1 else p.name for f in combo.families for p in f.parameters
    ]
    values = [v for e in effects for k, v in e.items() if k != "type"]
    return FittedCandidate(combo.name, combo.complexity, effects, model.with_effects(effects),
                           members if len(members) > 1 else (),
                           at_bound=_on_bound(x, lo, hi, names, values))


def _on_bound(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, names: Sequence[str], values: Sequence) -> str:
    """Words for the parameters of ``x`` that sit on an edge of the box ``[lo, hi]`` (empty when none
    does)."""
    x, lo, hi = (np.asarray(v, float) for v in (x, lo, hi))
    tol = BOUND_TOLERANCE * np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    words = []
    for i in range(x.size):
        edge = "lower" if x[i] <= lo[i] + tol[i] else "upper" if x[i] >= hi[i] - tol[i] else None
        if edge is not None:
            name = names[i] if i < len(names) else f"parameter {i}"
            value = f" {values[i]:.3g}" if i < len(values) else ""
            words.append(f"{name} at{value} ({edge} bound)")
    return ", ".join(words)


def _fit_parameter_error(model: LinearModel, data: _FitData) -> FittedCandidate | None:
    """The model's own parameters refitted as a flight condition or a mis-estimated derivative moves them: its
    modes near the band moved and its gain scaled (:func:`_mode_fit`, each within :data:`MODE_RANGE` and
    :data:`MODE_DAMPING_RANGE`). A free refit of every coefficient (:func:`_coefficient_fit`) can reshape the
    response as it likes (on a rate-limited elevator it dropped the high-frequency gain by 63 % while moving
    the short period up 29 %, which no condition change does) and so soaks up dynamics the model lacks: it is
    the candidate only where the mode fit cannot reach (the model has no mode near the band, or a mode or the
    gain sits on its range's bound; the coefficients are searched within x10, then x100)."""
    modes = _mode_fit(model, data)
    candidate = None
    if modes is not None:
        moved, words, free, bound = modes
        candidate = FittedCandidate("parameter_error", free, [], moved, replacement=True, at_bound=bound,
                                    detail=words)
        if not bound:
            return candidate
    refit, at_bound = None, ""
    for factor in COEFFICIENT_RANGES:       # widened once when the fit sits on the bound
        fitted = _coefficient_fit(model, data, factor, start=refit)
        if fitted is None:
            break
        refit, at_bound = fitted
        if not at_bound:
            break
    air = model.airframe
    n_free = int(np.count_nonzero(air.num) + np.count_nonzero(air.den[1:]))
    if refit is not None and not at_bound:
        beyond = _modes_beyond_range(model, refit, data)
        at_bound = f"{beyond}: beyond what a parameter error moves" if beyond else ""
    elif at_bound:
        at_bound = f"{at_bound} of the model's, after widening the search to x{COEFFICIENT_RANGES[-1]:g}"
    coefficients = None if refit is None else FittedCandidate("parameter_error", n_free, [], refit,
                                                              replacement=True, at_bound=at_bound)
    return coefficients if coefficients is not None else candidate


def _modes_beyond_range(model: LinearModel, refit: LinearModel, data: _FitData) -> str:
    """Which of the model's modes near the band (poles and zeros within :data:`MODE_REACH` of it) a
    coefficient refit moved beyond the ranges of :func:`_mode_fit` (frequency x :data:`MODE_RANGE`, damping
    :data:`MODE_DAMPING_RANGE`), or turned from a pair into real roots or back: in words, empty when none."""
    lo, hi = data.ctx.w_lo / MODE_REACH, data.ctx.w_hi * MODE_REACH
    words = []
    for kind, before, after in (("zero", model.airframe.num, refit.airframe.num),
                                ("mode", model.airframe.den, refit.airframe.den)):
        old = _roots_as_modes(np.roots(np.trim_zeros(np.asarray(before, float), "f")))
        new = _roots_as_modes(np.roots(np.trim_zeros(np.asarray(after, float), "f")))
        for w, zeta in old:
            if not lo <= abs(w) <= hi:
                continue
            same = [(w1, z1) for w1, z1 in new if (z1 is None) == (zeta is None) and w1 > 0]
            if not same:
                words.append(f"{kind} {abs(w):.3g} rad/s changed its kind")
                continue
            w1, z1 = min(same, key=lambda m: abs(math.log(m[0] / abs(w))))
            if max(w1 / abs(w), abs(w) / w1) > MODE_RANGE or (
                zeta is not None and abs(z1 - zeta) > MODE_DAMPING_RANGE
            ):
                words.append(f"{kind} {abs(w):.3g} -> {w1:.3g} rad/s" + (
                    "" if zeta is None else f" (damping {zeta:.2g} -> {z1:.2g})"))
    return ", ".join(words)


#: A structural mode whose zeros lie this close to one of the model's own pole pairs (relative frequency, and
#: damping) cancels that pole and puts it where its own poles are: the model's mode moved, not a new mode
#: (:func:`_moves_own_mode`).
MODE_MATCH = 0.25


def _moves_own_mode(candidate: FittedCandidate, model: LinearModel) -> bool:
    """Whether a candidate's structural mode only moves one of the model's own modes: its zeros on a pole pair
    of the model (within :data:`MODE_MATCH`). A linearisation at another speed has the same modes, moved; a
    structural mode fitted there is that move, and ``parameter_error`` (:func:`_mode_fit`) says it as such."""
    poles = [
        (w, z) for w, z in _roots_as_modes(np.roots(np.asarray(model.airframe.den, float))) if z is not None
    ]
    for effect in candidate.effects:
        if effect.get("type") != "structural_mode":
            continue
        wz, zz = float(effect["zero_frequency_rad_s"]), float(effect["zero_damping"])
        if any(abs(wz / w - 1.0) <= MODE_MATCH and abs(zz - z) <= MODE_MATCH for w, z in poles if w > 0):
            return True
    return False


#: A mode of the model (a pole or zero, a complex pair or a real root) is refitted by :func:`_mode_fit` when
#: its natural frequency lies within this factor of the confident band ...
MODE_REACH = 3.0
#: ... each frequency and the gain within this factor of the model's, each damping within this of the model's.
MODE_RANGE = 3.0
MODE_DAMPING_RANGE = 0.5
#: A pole and a zero closer than this (relative frequency, and damping) cancel: they are left as they are.
CANCEL = 0.02


def _roots_as_modes(roots: np.ndarray) -> list[tuple[float, float | None]]:
    """Roots as modes: ``(w, zeta)`` per complex pair (upper half-plane root), ``(a, None)`` per real root
    -a."""
    out = []
    for r in roots:
        if abs(r.imag) > 1e-9 * max(abs(r), 1e-300):
            if r.imag > 0:
                w = abs(r)
                out.append((w, -r.real / w))
        else:
            out.append((-r.real, None))
    return out


def _modes_poly(modes: list[tuple[float, float | None]]) -> np.ndarray:
    poly = np.array([1.0])
    for w, zeta in modes:
        factor = [1.0, w] if zeta is None else [1.0, 2.0 * zeta * w, w * w]
        poly = np.polymul(poly, factor)
    return poly


def _mode_fit(model: LinearModel, data: _FitData) -> tuple[LinearModel, str, int, str] | None:
    """Refit the model's gain and the modes near the confident band: each pole and zero whose natural
    frequency lies within :data:`MODE_REACH` of the band, a complex pair by its frequency and damping, a real
    root by its corner (within :data:`MODE_RANGE` and :data:`MODE_DAMPING_RANGE`); the effects kept. What a
    linearisation at another speed or weight gives: the same modes, moved, and the gains scaled -- not new
    modes. Returns the refitted model, the moves in words, the parameters fitted, and which sit on their bound
    (empty: none); None when no mode is near the band."""
    air = model.airframe
    num, den = np.asarray(air.num, float), np.asarray(air.den, float)
    if not np.any(num):
        return None
    lead = num[np.flatnonzero(num)[0]]
    zeros, poles = _roots_as_modes(np.roots(num)), _roots_as_modes(np.roots(den))
    lo, hi = data.ctx.w_lo / MODE_REACH, data.ctx.w_hi * MODE_REACH

    def near(w: float) -> bool:
        return lo <= abs(w) <= hi

    # a pole and a zero that (nearly) cancel carry no response (a mode of another axis, barely coupled): they
    # stay
    def cancels(a: tuple, b: tuple) -> bool:
        (wa, za), (wb, zb) = a, b
        return (za is None) == (zb is None) and abs(wa - wb) <= CANCEL * max(abs(wb), 1e-12) and \
            (za is None or abs(za - zb) <= CANCEL)

    cancelled = {("z", i) for i, z in enumerate(zeros) if any(cancels(z, p) for p in poles)}
    cancelled |= {("p", i) for i, p in enumerate(poles) if any(cancels(z, p) for z in zeros)}
    free = [(kind, i) for kind, modes in (("z", zeros), ("p", poles)) for i, (w, _) in enumerate(modes)
            if near(w) and (kind, i) not in cancelled]
    if not free:
        return None
    x0, lo_b, hi_b, names = [0.0], [-math.log(MODE_RANGE)], [math.log(MODE_RANGE)], ["gain"]
    for kind, i in free:
        w, zeta = (zeros if kind == "z" else poles)[i]
        x0.append(0.0)
        lo_b.append(-math.log(MODE_RANGE))
        hi_b.append(math.log(MODE_RANGE))
        names.append(f"{'zero' if kind == 'z' else 'pole'} at {abs(w):.3g} rad/s")
        if zeta is not None:
            x0.append(zeta)
            lo_b.append(max(-1.0, zeta - MODE_DAMPING_RANGE))
            hi_b.append(min(2.0, zeta + MODE_DAMPING_RANGE))
            names.append(f"damping of the {'zero' if kind == 'z' else 'pole'} at {abs(w):.3g} rad/s")
    x0, lo_b, hi_b = np.array(x0), np.array(lo_b), np.array(hi_b)
    x0 = np.clip(x0, lo_b + 1e-9 * (hi_b - lo_b), hi_b - 1e-9 * (hi_b - lo_b))
    s = 1j * data.w
    others = LinearModel([1.0], [1.0], air.delay_s, model.effects).freqresp(data.w)

    def build(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        z, p = list(zeros), list(poles)
        pos = 1
        for kind, i in free:
            target = z if kind == "z" else p
            w, zeta = target[i]
            w = w * math.exp(x[pos])
            pos += 1
            if zeta is not None:
                zeta = x[pos]
                pos += 1
            target[i] = (w, zeta)
        num_new = _modes_poly(z)
        gain = (
            lead
            * math.exp(x[0])
            * np.prod([w * w if zt is not None else w for w, zt in zeros] or [1.0])
            / np.prod([w * w if zt is not None else w for w, zt in z] or [1.0])
        )
        return gain * num_new, _modes_poly(p)

    def residuals(x: np.ndarray) -> np.ndarray:
        n_new, d_new = build(x)
        p = np.polyval(n_new, s) / np.polyval(d_new, s) * others
        return data.residuals((p / data.p_model)[None, :])[0]

    from scipy.optimize import least_squares  # scipy.optimize costs 0.6 s at import: only when used
    sol = least_squares(residuals, x0, bounds=(lo_b, hi_b), method="trf", max_nfev=100 * x0.size)
    n_new, d_new = build(sol.x)
    refit = LinearModel(
        np.array([significant(v, 6) for v in n_new]),
        np.array([significant(v, 6) for v in d_new]),
        air.delay_s,
        model.effects,
    )
    tol = BOUND_TOLERANCE * (hi_b - lo_b)
    edge = [
        f"{n} ({'lower' if v <= a + t else 'upper'} bound)"
        for n, v, a, b_, t in zip(names, sol.x, lo_b, hi_b, tol)
        if v <= a + t or v >= b_ - t
    ]
    words = [f"gain x{math.exp(sol.x[0]):.3g}"]
    pos = 1
    for kind, i in free:
        w, zeta = (zeros if kind == "z" else poles)[i]
        w_new = w * math.exp(sol.x[pos])
        pos += 1
        what = f"{'zero' if kind == 'z' else 'mode'} {abs(w):.3g} -> {abs(w_new):.3g} rad/s"
        if zeta is not None:
            what += f" (damping {zeta:.2f} -> {sol.x[pos]:.2f})"
            pos += 1
        words.append(what)
    return refit, ", ".join(words), int(x0.size), ", ".join(edge)


def fit_effects(model: LinearModel, estimate: SpectralEstimate, coherence_threshold: float = 0.6, *,
                sweeps: Sequence[SpectralEstimate] = (),
                pairs: bool = False, parameter_error: bool = True,
                bias_error: float = BIAS_ERROR) -> list[FittedCandidate]:
    """Fit every effect of the vocabulary (optionally all pairs, and the coefficient refit) to the data.

    Parameters
    ----------
    model : LinearModel
        Current model; effects are fitted in series with it.
    estimate : SpectralEstimate
        Averaged measured response (``w_rad_s``, ``response``, ``coherence``, ``n_averages``).
    coherence_threshold : float
        Only usable frequencies (coherence and averages, :func:`minimum_averages`) enter the fit.
    sweeps : sequence of SpectralEstimate
        Per-sweep estimates (random error from their scatter).
    pairs : bool
        Fit every pair of effects too.
    parameter_error : bool
        Refit the model's own coefficients as well.
    bias_error : float
        Systematic error floor (scores only).

    Returns
    -------
    list of FittedCandidate
        Unranked and unfiltered, each with its ``score`` on the data (empty with fewer than 4 usable points).
    """
    ev = _evidence(estimate, sweeps, coherence_threshold, bias_error, SIGMA_FACTOR)
    return _fit_all(model, ev, pairs=pairs, parameter_error=parameter_error)


#: Called between two candidate fits, when set (:func:`paced`; per thread: a context variable).
_PACE: contextvars.ContextVar[Callable[[], None] | None] = contextvars.ContextVar("gap_validation_pace",
                                                                                  default=None)


@contextmanager
def paced(callback: Callable[[], None]) -> Iterator[None]:
    """Within this block (in this thread), the diagnosis calls ``callback`` between two candidate fits: the
    node's diagnosis worker sleeps there to hold the fitting to a share of a core. The results are the same.

    Parameters
    ----------
    callback : callable
        Called with no argument; may sleep, or raise to abandon the diagnosis.
    """
    token = _PACE.set(callback)
    try:
        yield
    finally:
        _PACE.reset(token)


def _pace() -> None:
    callback = _PACE.get()
    if callback is not None:
        callback()


def _fit_all(model, ev: _Evidence, *, pairs: bool, parameter_error: bool, singles: bool = True):
    data = _fit_data(model, ev)
    if data is None:
        return []
    combos = [(EFFECTS[name],) for name in FAMILIES] if singles else []
    if pairs:
        combos += [(EFFECTS[a], EFFECTS[b]) for a, b in PAIRS]
    out = []
    for combo in combos:
        _pace()
        out.append(_fit_combo_candidate(_Combo(combo), model, data))
    if parameter_error:
        _pace()
        refit = _fit_parameter_error(model, data)
        if refit is not None:
            out.append(refit)
    for cand in out:
        cand.score = ev.fit(cand.model.freqresp)
    return out


def _chi2_improvement(before: _Fit, after: _Fit, extra_parameters: int, n_usable: int) -> bool:
    """``after`` removes at least half of ``before``'s chi-square excess over its expectation (2 per
    frequency) and more than fitting noise with the extra parameters could (``10 + 3 p``)."""
    gain = before.chi2 - after.chi2
    return gain >= max(0.5 * (before.chi2 - 2.0 * n_usable), 10.0 + 3.0 * max(extra_parameters, 1))


def _real_improvement(ev: _Evidence, before: _Fit, after: _Fit, extra_parameters: int,
                      min_relative: float) -> bool:
    """True when ``after`` leaves an epsilon clearly below ``before``'s, beyond what the errors explain."""
    e0, e1 = before.eps, after.eps
    if not (math.isfinite(e0) and math.isfinite(e1)) or e1 > (1.0 - min_relative) * e0:
        return False
    if not _chi2_improvement(before, after, extra_parameters, int(np.count_nonzero(ev.confident))):
        return False
    s = max(ev.sigma[before.worst], ev.sigma[after.worst])
    if e0 - e1 > IMPROVEMENT_SIGMA_FACTOR * s:
        return True
    return before.k_max > ev.sigma_factor + 1.0 and after.k_max <= ev.sigma_factor


def _select(ev: _Evidence, base: _Fit, fitted: list[FittedCandidate]) -> list[FittedCandidate]:
    """Keep the candidates with a real improvement (pairs only when clearly better than their best member) and
    rank them by parsimony (:func:`information_criteria`): the lowest criterion first, and among the
    candidates the data cannot tell from it (within :data:`INDISTINGUISHABLE`) the one with the fewest
    parameters."""
    singles = {c.name: c for c in fitted if not c.members and not c.replacement}
    kept = []
    for cand in fitted:
        if not _real_improvement(ev, base, cand.score, cand.complexity, MIN_RELATIVE_IMPROVEMENT):
            continue
        if cand.members:
            best = min((singles[m] for m in cand.members if m in singles), key=lambda c: c.score.eps,
                       default=None)
            if best is not None and not _real_improvement(ev, best.score, cand.score,
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


def _candidate(c: FittedCandidate, ev: _Evidence, base: _Fit, p_model: np.ndarray, sweeps: Sequence,
               coherence_threshold: float) -> Candidate:
    conf = ev.confident
    p_fit = c.model.freqresp(ev.w)
    score = c.score
    replacement = {}
    if c.replacement:
        replacement = {
            "model": c.model.to_spec(),
            "note": (
                "parameter error: the model's own coefficients refitted (same structure); nothing "
                "to append to effects: replace the model by 'model'"
            ),
        }
    return Candidate(
        effect=c.name,
        parameters=_parameters(c),
        effects=[dict(e) for e in c.effects],
        epsilon=score.eps,
        nu_gap=float(np.max(metrics.chordal_distance(p_fit[conf], ev.p_meas[conf]))),
        sentence=_sentence(c, base, ev),
        improvement=base.eps - score.eps,
        epsilon_before=base.eps,
        epsilon_raw=_raw_epsilon(c.model, sweeps, coherence_threshold, ev.confident),
        worst_frequency_rad_s=float(ev.w[score.worst]),
        complexity=c.complexity,
        explains=bool(score.k_max <= ev.sigma_factor),
        criterion=c.criterion,
        indistinguishable_from=list(c.indistinguishable),
        cost=cifer_cost(p_fit[conf], ev.p_meas[conf], ev.coherence[conf]),
        cost_before=cifer_cost(p_model[conf], ev.p_meas[conf], ev.coherence[conf]),
        **replacement,
    )


def _parameters(c: FittedCandidate) -> dict:
    if c.replacement:
        air = c.model.airframe
        return {"numerator": [float(v) for v in air.num], "denominator": [float(v) for v in air.den]}
    names = [k for e in c.effects for k in e if k != "type"]
    clash = len(names) != len(set(names))
    return {(f"{e['type']}.{k}" if clash else k): v for e in c.effects for k, v in e.items() if k != "type"}


def _sentence(c: FittedCandidate, base: _Fit, ev: _Evidence) -> str:
    """What the candidate is, the epsilon it leaves, and whether it explains the mismatch (the data within
    their errors at every confident frequency, JSON ``explains``)."""
    after = c.score
    if c.replacement and c.detail:
        text = (
            "parameter error (a model of another flight condition?): the model's own modes moved and its "
            "gain "
            f"scaled ({c.detail}) bring epsilon from {base.eps:.2f} to {after.eps:.2f}"
        )
    elif c.replacement:
        text = (f"parameter error: refitting the model's coefficients (same structure) brings epsilon from "
                f"{base.eps:.2f} to {after.eps:.2f}")
    else:
        what = " and ".join(describe_effect(e) for e in c.effects)
        verb = "adding it" if len(c.effects) == 1 else "adding both"
        text = f"missing: {what}; {verb} brings epsilon from {base.eps:.2f} to {after.eps:.2f}"
    if after.k_max <= ev.sigma_factor:
        text += ", which explains the mismatch (the rest is within the data's errors)"
    else:
        worst = int(np.argmax(np.where(ev.confident, after.k, -np.inf)))
        text += (f", but does not explain the mismatch ({after.k_max:.0f} noise scales left at "
                 f"{ev.w[worst]:.3g} rad/s)")
    if c.indistinguishable:
        text += (
            f"; the data cannot tell it from {' or '.join(_NAMES.get(n, n) for n in c.indistinguishable)} "
            f"(information criterion within {INDISTINGUISHABLE:g}): it is named for having the fewest "
            "parameters"
        )
    return text


#: Effect types in words, for the sentences that compare candidates.
_NAMES = {"parameter_error": "a refit of the model's coefficients"}


def _raw_epsilon(model: LinearModel, sweeps: Sequence, coherence_threshold: float,
                 average_confident: np.ndarray) -> float | None:
    """Sup of epsilon over every sweep's points (:func:`~gap_validation.core.spectra.sweep_points`) for
    ``model`` (raw epsilon, Table 1)."""
    best = None
    for s in sweeps:
        ok = sweep_points(s, average_confident, coherence_threshold)
        if np.any(ok):
            w = np.asarray(s.w_rad_s, float)[ok]
            m = _at_sweep_amplitude(model, s)
            e = float(
                np.max(metrics.epsilon_per_frequency(m.freqresp(w), np.asarray(s.response, complex)[ok]))
            )
            best = e if best is None else max(best, e)
    return best


# ------------------------------------------------------------------------------------------------ analysis


def analyse_channel(model: LinearModel, estimate: SpectralEstimate, sweeps: Sequence[SpectralEstimate],
                    coherence_threshold: float, *, fit: bool = True,
                    epsilon_threshold: float = 0.15, sigma_factor: float = SIGMA_FACTOR,
                    bias_error: float = BIAS_ERROR, channel: str = "") -> ChannelDiagnosis:
    """Where the model fails (model- or data-limited bands) and which effects would explain it.

    Parameters
    ----------
    model : LinearModel
        The channel's current model (airframe plus effects).
    estimate : SpectralEstimate
        Averaged estimate: ``w_rad_s``, complex ``response``, ``coherence`` (squared), ``random_error``
        (relative, Bendat & Piersol), ``n_averages``.
    sweeps : list of SpectralEstimate
        Per-sweep estimates on the same frequencies (raw epsilon, scatter-based random error).
    coherence_threshold : float
        Frequencies with lower coherence are excluded.
    fit : bool
        Fit the effect candidates; ``False`` gives only where it fails (cheap, for the live node).
    epsilon_threshold : float
        epsilon(w) above it makes a band.
    sigma_factor : float
        Normalised mismatch (noise scales, :func:`normalised_mismatch`) beyond which a frequency is
        model-limited, and beyond which the current model needs a diagnosis at all.
    bias_error : float
        Systematic error floor of the estimate, relative (:data:`BIAS_ERROR`).
    channel : str
        Channel name to start the message with (optional).

    Returns
    -------
    ChannelDiagnosis
    """
    ev = _evidence(estimate, sweeps, coherence_threshold, bias_error, sigma_factor)
    model, amplitude = flown_model(model, estimate, sweeps)
    p_model = model.freqresp(ev.w)
    base = ev.fit(model.freqresp)
    mismatch = base.k
    # coherent points with too few averages do not count for epsilon, but a mismatch there is data-limited
    coherent = (ev.coherence >= coherence_threshold) & np.isfinite(ev.p_meas) & (np.abs(ev.p_meas) > 0)
    flags = frequency_flags(base.eps_w, mismatch, coherent, ev.confident, epsilon_threshold, sigma_factor)
    bands = find_bands(ev.w, base.eps_w, mismatch, ev.coherence, ev.n_averages, flags, coherence_threshold,
                       ev.min_dof, sigma_factor, ev.sigma)
    result = ChannelDiagnosis(limited_by=_limited_by(ev, base, bands), frequency_flags=flags, bands=bands)
    from gap_validation.core.nonlinearity import amplitude_dependence

    dependence = amplitude_dependence(sweeps, ev.confident, coherence_threshold, bias_error)
    # a sign, units or a clock (issue 23) before any physics: checked on the cheap path too (the node warns at
    # once)
    result.convention = _convention(model, ev, base) if result.limited_by == "model" else None
    if fit and result.limited_by == "model" and result.convention is None:
        # an amplitude-dependent effect is fitted only where amplitude dependence was seen: one amplitude's
        # mismatch is no evidence of it (a rate limit or free play fits any lag at a single amplitude)
        nonlinear = dependence is not None and dependence.detected
        fitted = [
            c for c in _diagnose(model, ev, amplitude if nonlinear else None) if not _moves_own_mode(c, model)
        ]
        chosen = _select(ev, base, [c for c in fitted if not c.at_bound])
        result.candidates = [_candidate(c, ev, base, p_model, sweeps, coherence_threshold) for c in chosen]
        if not any(c.explains for c in result.candidates):  # said only when no offered fix explains it
            result.beyond_range = [
                f"{c.name} ({c.at_bound})" for c in _select(ev, base, fitted) if c.at_bound
            ]
        if chosen:
            _winding_warning(model, chosen[0], result)
    if fit and result.limited_by != "model" and result.convention is None:
        result.within_tolerance = constant_factor(model, ev, base, amplitude, bias_error)
    edge = None if result.convention is not None else band_edge_warning(
        ev.w, base.eps_w, metrics.chordal_distance(p_model, ev.p_meas), base.k, ev.confident, sigma_factor)
    if edge:
        result.warnings.insert(0, edge)
        result.margins_caveat = result.margins_caveat or (
            "the mismatch peaks at the edge of the measured band and "
            "may continue outside it: the margins then do not hold"
        )
    result.message = _message(ev, base, result, coherence_threshold, epsilon_threshold, channel)
    _call_nonlinearity(result, ev, dependence, amplitude)
    return result


def _convention(model: LinearModel, ev: _Evidence, base: _Fit):
    """The convention factor (:mod:`gap_validation.core.conventions`: a sign, units, a clock) that leaves the
    data within their errors where the model alone does not, the one with the smallest chi-square; None when
    none does. A lead (the rate ahead of the surface) is fitted; a lag is physics (a delay), not a clock."""
    from gap_validation.core.conventions import candidates, clock, fit_clock

    if base.worst < 0 or base.k_max <= ev.sigma_factor or np.count_nonzero(ev.confident) < _MIN_POINTS:
        return None
    p = model.freqresp
    tried = candidates()
    u = ev.confident
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = ev.p_meas[u] / p(ev.w[u])
        weight = 1.0 / np.maximum((2.0 * ev.sigma[u]) ** 2, 1e-12)
    lead = fit_clock(ev.w[u], ratio, np.where(np.isfinite(ratio), weight, 0.0))
    if lead > 0.0:
        tried.append(clock(lead))
    best, best_chi2 = None, math.inf
    for candidate in tried:
        _pace()
        score = ev.fit(lambda w, c=candidate: c.response(w) * p(w))
        if score.k_max <= ev.sigma_factor and score.chi2 < best_chi2:
            best, best_chi2 = candidate, score.chi2
    return best


def band_edge_warning(w_rad_s: ArrayLike, eps_w: ArrayLike, kappa: ArrayLike, mismatch: ArrayLike,
                      confident: ArrayLike, sigma_factor: float = SIGMA_FACTOR) -> str:
    """A warning when epsilon's or the nu-gap's sup (eqs. 13-14) sits at the lowest or highest confident
    frequency with a mismatch there beyond the errors (``k > sigma_factor``), else an empty string.

    The data-path numbers are sups over the measured band: a mismatch that peaks at an edge of it may grow
    outside, where nothing was measured, and then neither epsilon nor the margins from it (eqs. 15-17) hold. A
    sup at an edge within the errors (noise) is no such evidence and gives no warning.

    Parameters
    ----------
    w_rad_s : array_like
        Frequencies [rad/s].
    eps_w, kappa : array_like
        epsilon(w) and the chordal distance kappa(w) of the model against the averaged data.
    mismatch : array_like
        Normalised mismatch k per frequency (:func:`normalised_mismatch`).
    confident : array_like of bool
        Frequencies that count (:func:`confident_points`).
    sigma_factor : float
        k beyond which the mismatch is real.
    """
    w = np.asarray(w_rad_s, float)
    confident = np.asarray(confident, bool)
    idx = np.flatnonzero(confident)
    if idx.size < 2:
        return ""
    k = np.asarray(mismatch, float)
    found = {}
    for label, values in (("epsilon", eps_w), ("sup kappa (the nu-gap)", kappa)):
        _, worst = _sup(np.asarray(values, float), confident)
        if worst in (idx[0], idx[-1]) and k[worst] > sigma_factor:
            found.setdefault(worst, []).append(label)
    if not found:
        return ""
    parts = [f"{' and '.join(labels)} {'peaks' if len(labels) == 1 else 'peak'} at the "
             f"{'lowest' if i == idx[0] else 'highest'} confident frequency ({w[i]:.3g} rad/s)"
             for i, labels in found.items()]
    return ("; ".join(parts) + ", beyond the data's errors: the mismatch may continue outside the band; the "
            "margins then do not hold")


def _winding_warning(model: LinearModel, top: FittedCandidate, result: ChannelDiagnosis) -> None:
    """The exact winding-number condition between the model and the top candidate's model (the data-path
    nu-gap assumes it holds between the model and the aircraft): a warning and a margins caveat when it
    fails."""
    try:
        check = metrics.winding_condition(model, top.model)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError, GapValidationError):   # a degenerate model
        return
    if check.satisfied:
        return
    result.warnings.append(
        f"the model and the diagnosed model ({top.name}) fail the winding-number condition "
        f"({check.reason}): if the diagnosis is right, the nu-gap between the model and the "
        f"aircraft is 1, not the sup over the measured band, and the margins do not hold"
    )
    result.margins_caveat = (
        "the model and the diagnosed model fail the winding-number condition: the margins "
        "do not hold if the diagnosis is right"
    )


def _diagnose(model: LinearModel, ev: _Evidence, amplitude=None) -> list[FittedCandidate]:
    """Singles and the coefficient refit (and the amplitude-dependent effects when ``amplitude``, the flown
    amplitude, is given: only where amplitude dependence was seen); pairs too when no single effect leaves a
    mismatch within the errors."""
    fitted = _fit_all(model, ev, pairs=False, parameter_error=True)
    if amplitude is not None:
        fitted += _fit_nonlinear(model, ev, amplitude)
    explained = any(c.score.k_max <= ev.sigma_factor for c in fitted if not c.replacement and not c.at_bound)
    if fitted and not explained:
        fitted += _fit_all(model, ev, pairs=True, parameter_error=False, singles=False)
    return fitted


def _limited_by(ev: _Evidence, base: _Fit, bands: list[Band]) -> str:
    """``model`` when any band is model-limited (the model must change there whatever else the data say),
    else ``data`` when any band is data-limited or nothing is confident, else ``none``."""
    if base.worst < 0:
        return "data"
    verdicts = {band.limited_by for band in bands}
    return "model" if "model" in verdicts else "data" if verdicts else "none"


def _lead_band(bands: list[Band]) -> Band | None:
    """The band the message leads with: the worst model-limited band, else the worst band."""
    model = [b for b in bands if b.limited_by == "model"]
    return max(model or bands, key=lambda b: b.epsilon, default=None)


def _range(lo: float, hi: float) -> str:
    return f"{lo:.3g} rad/s" if lo == hi else f"{lo:.3g}-{hi:.3g} rad/s"


def _message(ev: _Evidence, base: _Fit, result: ChannelDiagnosis, coherence_threshold: float,
             epsilon_threshold: float, channel: str) -> str:
    prefix = f"{channel}: " if channel else ""
    estimated = np.isfinite(ev.p_meas)
    if base.worst < 0:
        coherent = estimated & (ev.coherence >= coherence_threshold)
        if coherent.any():
            why = (
                f"too few degrees of freedom (at most {np.max(ev.n_averages[coherent]):.0f} < {ev.min_dof}): "
                f"fly the manoeuvre again, or longer"
            )
        elif estimated.any():
            why = (f"coherence below {coherence_threshold:g} everywhere (at most "
                   f"{np.max(ev.coherence[estimated]):.2f}): fly with more excitation, or in calmer air")
        else:
            why = "nothing estimated"
        return f"{prefix}data-limited: no confident frequency: {why}"
    band = _lead_band(result.bands)
    if band is None:
        text = (f"{prefix}model fits: epsilon {base.eps:.2f} at {ev.w[base.worst]:.3g} rad/s, within "
                f"{epsilon_threshold:g} at every confident frequency")
    elif band.limited_by == "model":
        text = (f"{prefix}model-limited at {_range(band.min_rad_s, band.max_rad_s)}: epsilon "
                f"{band.epsilon:.2f} at {band.peak_rad_s:.3g} rad/s is well outside the random error")
    else:
        text = (f"{prefix}data-limited at {_range(band.min_rad_s, band.max_rad_s)}: epsilon "
                f"{band.epsilon:.2f} at {band.peak_rad_s:.3g} rad/s; {band.reason}")
    others = [b for b in result.bands if b is not band]
    if others:
        text += "; also " + ", ".join(f"{b.limited_by}-limited at {_range(b.min_rad_s, b.max_rad_s)}"
                                      for b in others)
    if result.candidates:
        text += ("; " if band is not None else "; the data still resolve a difference: ") + \
            result.candidates[0].sentence
    if result.beyond_range:
        text += ("; beyond the search range (not offered as a fix): " + "; ".join(result.beyond_range))
    if result.within_tolerance is not None:
        text += "; " + _factor_sentence(result.within_tolerance)
    excluded = int(np.count_nonzero(~ev.confident))
    if excluded:
        missing = int(np.count_nonzero(~estimated))
        low = int(np.count_nonzero(estimated & (ev.coherence < coherence_threshold)))
        parts = [f"{missing} not excited"] if missing else []
        parts += [f"{low} with coherence < {coherence_threshold:g}"] if low else []
        rest = excluded - missing - low
        parts += [f"{rest} with fewer than {ev.min_dof} degrees of freedom"] if rest else []
        text += f" ({excluded} of {ev.w.size} frequencies excluded: {', '.join(parts)})"
    return text


# ------------------------------------------------------------------------------------------------ within the
# tolerance


def _factor_sentence(found: ConstantFactor) -> str:
    """A :class:`ConstantFactor` in words, for the channel's message."""
    text = (
        f"within the tolerance, the data still resolve a constant factor ({found.noise_scales:.0f} noise "
        f"scales): the response is {found.gain:.3g} x the model's, {abs(found.phase_deg):.0f} deg "
        f"{'behind' if found.phase_deg < 0 else 'ahead'} at every confident frequency "
        f"({_range(found.min_rad_s, found.max_rad_s)}, +-{found.error:.2g}), which no linear element gives "
        f"(Bode's gain-phase relation)"
    )
    if found.free_play_rad is not None:
        text += (
            f": free play of {found.free_play_rad:.2g} rad does at the flown amplitude {found.amplitude:.2g} "
            f"(not named from one amplitude: sweeps at two amplitudes would tell)"
        )
    return text


def constant_factor(model: LinearModel, ev: _Evidence, base: _Fit,
                    amplitude: Callable[[np.ndarray], np.ndarray] | None = None,
                    bias_error: float = BIAS_ERROR) -> ConstantFactor | None:
    """A resolved difference inside the tolerance, when one constant complex factor explains it.

    A channel whose epsilon stays within the threshold may still differ from the model by more than the data's
    errors (a free play's 0.92 x gain and 10 deg lag at every frequency: epsilon 0.1 against a random error of
    0.01). Naming an effect there would name the few per cent every real model is off, so only the simplest
    statement is made, and only when it is resolved, sufficient and more than a gain:

    * some confident frequency is beyond ``SIGMA_FACTOR`` noise scales (the model alone is not within the
      errors);
    * ``c``, the inverse-variance mean of ``P_meas / P_model`` over the confident frequencies, differs from 1
      by more than ``SIGMA_FACTOR`` standard errors, the error of ``c`` never below ``bias_error``: a
      systematic error (interpolation, a timestamp offset) is common to all frequencies and does not average
      down;
    * ``c`` times the model leaves every confident frequency within ``SIGMA_FACTOR`` noise scales;
    * the confident frequencies span at least :data:`FACTOR_SPAN` (a decade): over less, a delay or a lag is a
      constant factor within the errors too, and "the same at every frequency" would say nothing;
    * its phase differs from 0 by more than ``SIGMA_FACTOR`` errors. A real gain a few per cent off is what
      every real model is (a mass, an inertia, the dynamic pressure: JSBSim's linearisations are 4-9 % off in
      gain on 14 % of their channels), inside the tolerance by design; a constant phase over a decade with a
      flat gain is no linear element's (Bode's gain-phase relation ties a linear element's phase to its gain
      slope).

    Parameters
    ----------
    model : LinearModel
        The channel's model (bound to the flown amplitude).
    ev : _Evidence
        The averaged estimate and its statistics.
    base : _Fit
        The model's fit to it.
    amplitude : callable or None
        Input amplitude flown per frequency (:func:`flown_model`), for the free-play reading.
    bias_error : float
        Systematic error floor, relative.

    Returns
    -------
    ConstantFactor or None
    """
    u = ev.confident & np.isfinite(ev.p_meas)
    if base.worst < 0 or np.count_nonzero(u) < _MIN_POINTS or base.k_max <= ev.sigma_factor or \
            ev.w[u].max() < FACTOR_SPAN * ev.w[u].min():
        return None
    through, expansion = ev.expected(model.freqresp)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = ev.p_meas[u] / through[u]
    weight = 1.0 / np.maximum((2.0 * ev.sigma[u]) ** 2, 1e-12)
    if not np.all(np.isfinite(ratio)):
        return None
    c = complex(np.sum(weight * ratio) / np.sum(weight))
    error = math.hypot(1.0 / math.sqrt(float(np.sum(weight))), bias_error)
    scales = abs(c - 1.0) / error
    phase = math.atan2(c.imag, c.real)
    if scales <= ev.sigma_factor or abs(phase) <= ev.sigma_factor * error:
        return None
    # c times the model, seen through the estimator: c times its view (the expansion error is relative)
    left = ev.mismatch(metrics.epsilon_per_frequency(c * through, ev.p_meas), expansion)
    if np.max(left[u]) > ev.sigma_factor:
        return None
    w = ev.w[u]
    found = ConstantFactor(gain=abs(c), phase_deg=math.degrees(phase), error=error,
                           noise_scales=scales, min_rad_s=float(w.min()), max_rad_s=float(w.max()))
    flown = None if amplitude is None else np.asarray(amplitude(w), float)
    if flown is not None and np.all(np.isfinite(flown) & (flown > 0)) and 0.0 < abs(c) < 1.0:
        a = float(np.mean(flown))
        ratio_b = brentq(lambda r: abs(complex(backlash_df(r))) - abs(c), 1e-9, 2.0 - 1e-9)
        if abs(complex(backlash_df(ratio_b)) - c) <= ev.sigma_factor * error:
            found.free_play_rad, found.amplitude = ratio_b * a, a
    return found


# ------------------------------------------------------------------------------------------------ nonlinear
# effects


#: Amplitude-dependent effects the diagnosis fits through their describing functions (a view of the registry).
NONLINEAR_FAMILIES: dict[str, EffectType] = {
    name: e for name, e in EFFECTS.items() if e.describing_fit is not None
}


def flown_model(
    model: LinearModel, estimate: SpectralEstimate, sweeps: Sequence
) -> tuple[LinearModel, object]:
    """The model bound to the input amplitude flown per frequency, and that amplitude as ``amplitude(w)``.

    The amplitude comes from the records (:func:`~gap_validation.core.nonlinearity.flown_amplitude`); without
    it, a model with an amplitude-dependent effect is bound to an unknown amplitude (the effect then counts as
    absent: its describing function is 1) and the amplitude returned is None.

    Parameters
    ----------
    model : LinearModel
        The channel's model.
    estimate : SpectralEstimate
        The pooled estimate (its frequencies).
    sweeps : sequence of SpectralEstimate
        The raw estimates with their ``amplitude``.
    """
    from gap_validation.core.nonlinearity import amplitude_function, flown_amplitude

    w = np.asarray(estimate.w_rad_s, float)
    amp = flown_amplitude(w, sweeps)
    if amp is None or w.size == 0:
        return model.at_amplitude(lambda x: np.full(np.shape(x), np.nan)), None
    at = amplitude_function(w, amp)
    return model.at_amplitude(at), at


def _at_sweep_amplitude(model: LinearModel, sweep) -> LinearModel:
    """``model`` at one record's own amplitude (amplitude-dependent models only)."""
    a = float(getattr(sweep, "amplitude", math.nan))
    if not model.nonlinear or not math.isfinite(a):
        return model
    return model.at_amplitude(a)


@dataclass
class _DescribingCombo(_Combo):
    """One amplitude-dependent effect, fitted through its describing function at the flown amplitude."""

    amplitude: object = None          # amplitude(w) -> array

    def response(self, x: np.ndarray, w: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(x)
        out = np.ones((x.shape[0], w.size), dtype=complex)
        for fam, part in zip(self.families, self._split(x)):
            out = out * fam.describing_fit.response(part, w, self.amplitude(w))
        return out

    def grid(self, ctx: FitRange) -> np.ndarray:
        return self.families[0].describing_fit.grid(ctx, False)

    def bounds(self, x0: np.ndarray, ctx: FitRange) -> tuple[np.ndarray, np.ndarray]:
        return self.families[0].describing_fit.bounds(x0, ctx)

    def specs(self, x: np.ndarray) -> list[dict]:
        return [validate_effect(self.families[0].describing_fit.spec(np.asarray(x, float)))]


def _fit_nonlinear(model: LinearModel, ev: _Evidence, amplitude) -> list[FittedCandidate]:
    """``rate_limit`` and ``backlash`` fitted in series with the model (describing functions at the flown
    amplitude), scored like the others."""
    data = _fit_data(model, ev)
    if data is None:
        return []
    a = np.asarray(amplitude(data.w), float)
    if not np.all(np.isfinite(a) & (a > 0)):
        return []
    data = replace(data, ctx=AmplitudeFitRange(data.ctx.w_lo, data.ctx.w_hi, float(a.min()), float(a.max())))
    out = []
    for family in NONLINEAR_FAMILIES.values():
        combo = _DescribingCombo((family,), amplitude)
        x = _fit_combo(combo, data)
        effects = combo.specs(x)
        lo, hi = combo.bounds(x, data.ctx)
        values = [v for e in effects for k, v in e.items() if k != "type"]
        cand = FittedCandidate(
            combo.name,
            combo.complexity,
            effects,
            model.with_effects(effects).at_amplitude(amplitude),
            at_bound=_on_bound(x, lo, hi, [k for e in effects for k in e if k != "type"], values),
        )
        cand.score = ev.fit(cand.model.freqresp)
        out.append(cand)
    return out


def _call_nonlinearity(result: ChannelDiagnosis, ev: _Evidence, found, amplitude) -> None:
    """The sweeps flown at different amplitudes compared (``found``: :func:`~gap_validation.core.nonlinearity.
    amplitude_dependence`, None when they do not span different amplitudes); when they disagree beyond their
    errors, say :data:`~gap_validation.core.nonlinearity.NONLINEARITY` in the result and the message."""
    from gap_validation.core.nonlinearity import NONLINEARITY

    result.amplitude = None if amplitude is None else np.asarray(amplitude(ev.w), float)
    if found is None:
        return
    result.nonlinearity_evidence = found.sentence()
    if found.detected:
        result.nonlinearity = NONLINEARITY
        result.message += f"; {NONLINEARITY}: {found.sentence()}"
