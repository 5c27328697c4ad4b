"""Where the model fails and which physical effect is missing (DESIGN.md, steps 2 and 3).

:func:`analyse_channel` puts together four parts, each in its own module:

* :mod:`gap_validation.core.evidence`: the statistics. epsilon(w) of the model against the averaged
  measured response, compared per frequency with what the estimate's errors can explain; the confident
  frequencies; the model- and data-limited bands. Measured: model-limited on 0.3 % of the channels of 240
  simulated flights whose truth is the model (``benchmarks/false_alarms.py``).
* :mod:`gap_validation.core.fitting`: each effect of the vocabulary (:mod:`gap_validation.core.effects`),
  the pairs and the model's own parameters, fitted to the data with the CIFER cost.
* :mod:`gap_validation.core.ranking`: which fits bring a real improvement against the data's errors, and
  their order (parsimony: an information criterion).
* :mod:`gap_validation.core.wording`: the sentences (the message, each candidate's sentence, the band
  reasons and the warnings), from plain values.

Here: the channel's verdict (:class:`ChannelDiagnosis`), the JSON candidates, the conventions checked before
any physics (a sign, units, a clock: :mod:`gap_validation.core.conventions`), a constant factor inside the
tolerance (:func:`constant_factor`), the band-edge and winding-number warnings, and the amplitude dependence
(:mod:`gap_validation.core.nonlinearity`). The names the diagnosis always offered (``SIGMA_FACTOR``,
``confident_points``, ``fit_effects``, ...) are importable from here too; their home is the part's module.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import brentq

from gap_validation.core import metrics, wording
from gap_validation.core.effects import backlash_df
from gap_validation.core.errors import GapValidationError
from gap_validation.core.evidence import (
    BIAS_ERROR,
    SIGMA_FACTOR,
    Evidence,
    Fit,
    bendat_piersol_random_error,
    confident_mask,
    confident_points,
    effective_random_error,
    epsilon_noise_scale,
    evidence_of,
    find_bands,
    frequency_flags,
    masked_sup,
    minimum_averages,
    normalised_mismatch,
)
from gap_validation.core.fitting import (
    FAMILIES,
    MIN_POINTS,
    NONLINEAR_FAMILIES,
    PAIRS,
    FittedCandidate,
    cifer_cost,
    cifer_weight,
    fit_candidates,
    fit_effects,
    moves_own_mode,
    pace,
    paced,
)
from gap_validation.core.models import LinearModel
from gap_validation.core.ranking import INDISTINGUISHABLE, information_criteria, select_candidates
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
    "NONLINEAR_FAMILIES",
    "SIGMA_FACTOR",
    "BIAS_ERROR",
    "band_edge_warning",
    "information_criteria",
    "confident_points",
    "confident_mask",
    "INDISTINGUISHABLE",
    "constant_factor",
    "FACTOR_SPAN",
    "flown_model",
    "paced",
]

#: A constant factor within the tolerance (:func:`constant_factor`) is said only over confident frequencies
#: that span at least this ratio: a decade, the span over which Bode's gain-phase relation ties a linear
#: element's phase to its gain slope (a delay of 10 ms is a constant 4 +- 2 deg over 5-12 rad/s).
FACTOR_SPAN = 10.0


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


def _candidate(c: FittedCandidate, ev: Evidence, base: Fit, p_model: np.ndarray, sweeps: Sequence,
               coherence_threshold: float) -> Candidate:
    conf = ev.confident
    p_fit = c.model.freqresp(ev.w)
    score = c.score
    replacement = {}
    if c.replacement:
        replacement = {"model": c.model.to_spec(), "note": wording.REFIT_NOTE}
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


def _sentence(c: FittedCandidate, base: Fit, ev: Evidence) -> str:
    """The candidate's sentence (:func:`~gap_validation.core.wording.diagnosis_sentence`)."""
    after, before = c.score, base
    worst = int(np.argmax(np.where(ev.confident, after.k, -np.inf)))
    return wording.diagnosis_sentence(
        c.effects, replacement=c.replacement, detail=c.detail, epsilon_before=before.eps,
        epsilon_after=after.eps, explains=after.k_max <= ev.sigma_factor, noise_scales_left=after.k_max,
        worst_rad_s=float(ev.w[worst]), indistinguishable=c.indistinguishable,
        indistinguishable_within=INDISTINGUISHABLE,
    )


def _message(ev: Evidence, base: Fit, result: ChannelDiagnosis, coherence_threshold: float,
             epsilon_threshold: float, channel: str) -> str:
    """The channel's message (:func:`~gap_validation.core.wording.channel_message`)."""
    estimated = np.isfinite(ev.p_meas)
    if base.worst < 0:
        coherent = estimated & (ev.coherence >= coherence_threshold)
        return wording.no_confident_sentence(
            channel, coherence_threshold=coherence_threshold, min_dof=ev.min_dof,
            max_dof=float(np.max(ev.n_averages[coherent])) if coherent.any() else None,
            max_coherence=float(np.max(ev.coherence[estimated])) if estimated.any() else None,
        )
    excluded = int(np.count_nonzero(~ev.confident))
    not_excited = int(np.count_nonzero(~estimated)) if excluded else 0
    low = int(np.count_nonzero(estimated & (ev.coherence < coherence_threshold))) if excluded else 0
    return wording.channel_message(
        channel, bands=result.bands, epsilon=base.eps, worst_rad_s=float(ev.w[base.worst]),
        epsilon_threshold=epsilon_threshold,
        top_sentence=result.candidates[0].sentence if result.candidates else None,
        beyond_range=result.beyond_range, within_tolerance=result.within_tolerance,
        frequencies=int(ev.w.size), not_excited=not_excited, low_coherence=low,
        few_dof=excluded - not_excited - low, coherence_threshold=coherence_threshold, min_dof=ev.min_dof,
    )


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
    ev = evidence_of(estimate, sweeps, coherence_threshold, bias_error, sigma_factor)
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
            c for c in fit_candidates(model, ev, amplitude if nonlinear else None)
            if not moves_own_mode(c, model)
        ]
        chosen = select_candidates(ev, base, [c for c in fitted if not c.at_bound])
        result.candidates = [_candidate(c, ev, base, p_model, sweeps, coherence_threshold) for c in chosen]
        if not any(c.explains for c in result.candidates):  # said only when no offered fix explains it
            result.beyond_range = [
                f"{c.name} ({c.at_bound})" for c in select_candidates(ev, base, fitted) if c.at_bound
            ]
        if chosen:
            _winding_warning(model, chosen[0], result)
    if fit and result.limited_by != "model" and result.convention is None:
        result.within_tolerance = constant_factor(model, ev, base, amplitude, bias_error)
    edge = None if result.convention is not None else band_edge_warning(
        ev.w, base.eps_w, metrics.chordal_distance(p_model, ev.p_meas), base.k, ev.confident, sigma_factor)
    if edge:
        result.warnings.insert(0, edge)
        result.margins_caveat = result.margins_caveat or wording.EDGE_CAVEAT
    result.message = _message(ev, base, result, coherence_threshold, epsilon_threshold, channel)
    _call_nonlinearity(result, ev, dependence, amplitude)
    return result


def _convention(model: LinearModel, ev: Evidence, base: Fit):
    """The convention factor (:mod:`gap_validation.core.conventions`: a sign, units, a clock) that leaves the
    data within their errors where the model alone does not, the one with the smallest chi-square; None when
    none does. A lead (the rate ahead of the surface) is fitted; a lag is physics (a delay), not a clock."""
    from gap_validation.core.conventions import candidates, clock, fit_clock

    if base.worst < 0 or base.k_max <= ev.sigma_factor or np.count_nonzero(ev.confident) < MIN_POINTS:
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
        pace()
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
        _, worst = masked_sup(np.asarray(values, float), confident)
        if worst in (idx[0], idx[-1]) and k[worst] > sigma_factor:
            found.setdefault(worst, []).append(label)
    if not found:
        return ""
    return wording.band_edge_sentence(
        [(labels, "lowest" if i == idx[0] else "highest", float(w[i])) for i, labels in found.items()]
    )


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
    result.warnings.append(wording.winding_warning(top.name, check.reason))
    result.margins_caveat = wording.WINDING_CAVEAT


def _limited_by(ev: Evidence, base: Fit, bands: list[Band]) -> str:
    """``model`` when any band is model-limited (the model must change there whatever else the data say),
    else ``data`` when any band is data-limited or nothing is confident, else ``none``."""
    if base.worst < 0:
        return "data"
    verdicts = {band.limited_by for band in bands}
    return "model" if "model" in verdicts else "data" if verdicts else "none"


def constant_factor(model: LinearModel, ev: Evidence, base: Fit,
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
    ev : Evidence
        The averaged estimate and its statistics.
    base : Fit
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
    if base.worst < 0 or np.count_nonzero(u) < MIN_POINTS or base.k_max <= ev.sigma_factor or \
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


def _call_nonlinearity(result: ChannelDiagnosis, ev: Evidence, found, amplitude) -> None:
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
