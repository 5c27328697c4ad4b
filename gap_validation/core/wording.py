"""The verdicts in words: every sentence the diagnosis says, from plain values.

The statistics (:mod:`~gap_validation.core.evidence`), the fits (:mod:`~gap_validation.core.fitting`) and
the ranking (:mod:`~gap_validation.core.ranking`) decide; this module only says what they decided, so a
sentence changes in one place and reads the same in the terminal, the JSON ``message`` and ``sentence``
fields, the HTML report and the node's diagnostics. Nothing here computes a verdict: each function takes the
numbers it prints (no estimate, no fit object), and the front ends (:mod:`gap_validation.report.html`,
:mod:`gap_validation.ros.status`, ``gap-validate replay --apply-diagnosis``) take their verdict phrases from
here too.
"""
from __future__ import annotations

import math
from typing import Sequence

from gap_validation.core.effects import describe_effect
from gap_validation.core.results import Band, Candidate, ChannelResult, ConstantFactor

__all__ = [
    "frequency_range",
    "diagnosis_sentence",
    "no_confident_sentence",
    "channel_message",
    "lead_band",
    "factor_sentence",
    "model_band_reason",
    "low_coherence_reason",
    "few_dof_reason",
    "bias_allowance_reason",
    "random_error_reason",
    "band_edge_sentence",
    "winding_warning",
    "limited_sentence",
    "no_fix_reason",
    "mimo_band_reason",
    "mimo_column_sentence",
    "mimo_message",
    "candidate_line",
    "status_summary",
    "amplitude_sentence",
    "clock_sentence",
    "sign_sentence",
    "units_sentence",
    "units_words",
    "body_frame_sentence",
    "reversed_imu_sentence",
    "dropped_lag_warning",
    "sparse_stream_sentence",
    "REFIT_NOTE",
    "EDGE_CAVEAT",
    "WINDING_CAVEAT",
    "MODEL_LIMITED",
    "DATA_LIMITED",
]

#: Effect types in words, for the sentences that compare candidates.
_NAMES = {"parameter_error": "a refit of the model's coefficients"}

#: The JSON ``note`` of a ``parameter_error`` candidate.
REFIT_NOTE = (
    "parameter error: the model's own coefficients refitted (same structure); nothing "
    "to append to effects: replace the model by 'model'"
)
#: The margins caveat of a mismatch that peaks at an edge of the measured band.
EDGE_CAVEAT = (
    "the mismatch peaks at the edge of the measured band and "
    "may continue outside it: the margins then do not hold"
)
#: The margins caveat of a diagnosed model that fails the winding-number condition with the model.
WINDING_CAVEAT = (
    "the model and the diagnosed model fail the winding-number condition: the margins "
    "do not hold if the diagnosis is right"
)
#: A model-limited channel with no candidate, in the report.
MODEL_LIMITED = "Model-limited: confident data disagree with the model."
#: A data-limited channel, in the report.
DATA_LIMITED = "Data-limited: fly better sweeps where the coherence is low before changing the model."


def frequency_range(lo: float, hi: float) -> str:
    """``"4.2 rad/s"`` or ``"4.2-12 rad/s"``.

    Parameters
    ----------
    lo, hi : float
        Edges [rad/s].

    Returns
    -------
    str

    Examples
    --------
    >>> frequency_range(4.2, 12.0), frequency_range(14.9, 14.9)
    ('4.2-12 rad/s', '14.9 rad/s')
    """
    return f"{lo:.3g} rad/s" if lo == hi else f"{lo:.3g}-{hi:.3g} rad/s"


def diagnosis_sentence(effects: Sequence[dict], *, replacement: bool, detail: str, epsilon_before: float,
                       epsilon_after: float, explains: bool, noise_scales_left: float, worst_rad_s: float,
                       indistinguishable: Sequence[str], indistinguishable_within: float) -> str:
    """What a candidate is, the epsilon it leaves, and whether it explains the mismatch (JSON ``sentence``).

    Parameters
    ----------
    effects : sequence of dict
        The effects it appends (empty for a refit of the model).
    replacement : bool
        The model's own coefficients refitted (``parameter_error``).
    detail : str
        A refit by its modes, in words (empty: a refit of every coefficient).
    epsilon_before, epsilon_after : float
        epsilon of the model, and with the candidate.
    explains : bool
        The candidate leaves the data within their errors at every confident frequency.
    noise_scales_left : float
        The largest normalised mismatch it leaves, at ``worst_rad_s`` [rad/s].
    worst_rad_s : float
        Where.
    indistinguishable : sequence of str
        Candidates the data cannot tell from it.
    indistinguishable_within : float
        The information-criterion difference that makes them so.

    Returns
    -------
    str

    Examples
    --------
    >>> delay = {"type": "time_delay", "seconds": 0.045}
    >>> print(diagnosis_sentence([delay], replacement=False, detail="", epsilon_before=0.62,
    ...                          epsilon_after=0.06, explains=True, noise_scales_left=2.1, worst_rad_s=20.0,
    ...                          indistinguishable=(), indistinguishable_within=2.0))
    missing: time delay of 45 ms; adding it brings epsilon from 0.62 to 0.06, which explains the mismatch
    (the rest is within the data's errors)
    """
    before, after = epsilon_before, epsilon_after
    if replacement and detail:
        text = (
            "parameter error (a model of another flight condition?): the model's own modes moved and its "
            "gain "
            f"scaled ({detail}) bring epsilon from {before:.2f} to {after:.2f}"
        )
    elif replacement:
        text = (f"parameter error: refitting the model's coefficients (same structure) brings epsilon from "
                f"{before:.2f} to {after:.2f}")
    else:
        what = " and ".join(describe_effect(e) for e in effects)
        verb = "adding it" if len(effects) == 1 else "adding both"
        text = f"missing: {what}; {verb} brings epsilon from {before:.2f} to {after:.2f}"
    if explains:
        text += ", which explains the mismatch (the rest is within the data's errors)"
    else:
        text += (f", but does not explain the mismatch ({noise_scales_left:.0f} noise scales left at "
                 f"{worst_rad_s:.3g} rad/s)")
    if indistinguishable:
        text += (
            f"; the data cannot tell it from {' or '.join(_NAMES.get(n, n) for n in indistinguishable)} "
            f"(information criterion within {indistinguishable_within:g}): it is named for having the fewest "
            "parameters"
        )
    return text


def no_confident_sentence(channel: str, *, coherence_threshold: float, min_dof: int,
                          max_dof: float | None, max_coherence: float | None) -> str:
    """The message of a channel with no confident frequency, and what to fly.

    Parameters
    ----------
    channel : str
        Channel name to start with (empty: none).
    coherence_threshold : float
        The channel's coherence threshold.
    min_dof : int
        Degrees of freedom a confident frequency needs.
    max_dof : float or None
        The most degrees of freedom at a coherent frequency (None: no frequency is coherent).
    max_coherence : float or None
        The highest coherence estimated (None: nothing estimated).

    Returns
    -------
    str
    """
    prefix = f"{channel}: " if channel else ""
    if max_dof is not None:
        why = (
            f"too few degrees of freedom (at most {max_dof:.0f} < {min_dof}): "
            f"fly the manoeuvre again, or longer"
        )
    elif max_coherence is not None:
        why = (f"coherence below {coherence_threshold:g} everywhere (at most "
               f"{max_coherence:.2f}): fly with more excitation, or in calmer air")
    else:
        why = "nothing estimated"
    return f"{prefix}data-limited: no confident frequency: {why}"


def lead_band(bands: Sequence[Band]) -> Band | None:
    """The band a message leads with: the worst model-limited band, else the worst band.

    Parameters
    ----------
    bands : sequence of Band
        The channel's bands.

    Returns
    -------
    Band or None
    """
    model = [b for b in bands if b.limited_by == "model"]
    return max(model or bands, key=lambda b: b.epsilon, default=None)


def channel_message(channel: str, *, bands: Sequence[Band], epsilon: float, worst_rad_s: float,
                    epsilon_threshold: float, top_sentence: str | None, beyond_range: Sequence[str],
                    within_tolerance: ConstantFactor | None, frequencies: int, not_excited: int,
                    low_coherence: int, few_dof: int, coherence_threshold: float, min_dof: int) -> str:
    """One plain sentence for the terminal: the verdict, where, the top candidate, what was left out.

    Parameters
    ----------
    channel : str
        Channel name to start with (empty: none).
    bands : sequence of Band
        The model- and data-limited bands (the worst model-limited one leads).
    epsilon, worst_rad_s : float
        The model's epsilon over the confident frequencies and where it peaks [rad/s].
    epsilon_threshold : float
        The channel's epsilon threshold.
    top_sentence : str or None
        The top candidate's sentence (:func:`diagnosis_sentence`), None when there is none.
    beyond_range : sequence of str
        Fits beyond their search range, one phrase each.
    within_tolerance : ConstantFactor or None
        A resolved constant factor inside the tolerance.
    frequencies : int
        Frequencies of the grid.
    not_excited, low_coherence, few_dof : int
        Frequencies left out: not estimated, coherence below the threshold, too few degrees of freedom.
    coherence_threshold : float
        The channel's coherence threshold.
    min_dof : int
        Degrees of freedom a confident frequency needs.

    Returns
    -------
    str
    """
    prefix = f"{channel}: " if channel else ""
    band = lead_band(bands)
    if band is None:
        text = (f"{prefix}model fits: epsilon {epsilon:.2f} at {worst_rad_s:.3g} rad/s, within "
                f"{epsilon_threshold:g} at every confident frequency")
    elif band.limited_by == "model":
        text = (f"{prefix}model-limited at {frequency_range(band.min_rad_s, band.max_rad_s)}: epsilon "
                f"{band.epsilon:.2f} at {band.peak_rad_s:.3g} rad/s is well outside the random error")
    else:
        text = (f"{prefix}data-limited at {frequency_range(band.min_rad_s, band.max_rad_s)}: epsilon "
                f"{band.epsilon:.2f} at {band.peak_rad_s:.3g} rad/s; {band.reason}")
    others = [b for b in bands if b is not band]
    if others:
        text += "; also " + ", ".join(
            f"{b.limited_by}-limited at {frequency_range(b.min_rad_s, b.max_rad_s)}" for b in others
        )
    if top_sentence is not None:
        text += ("; " if band is not None else "; the data still resolve a difference: ") + top_sentence
    if beyond_range:
        text += ("; beyond the search range (not offered as a fix): " + "; ".join(beyond_range))
    if within_tolerance is not None:
        text += "; " + factor_sentence(within_tolerance)
    excluded = not_excited + low_coherence + few_dof
    if excluded:
        parts = [f"{not_excited} not excited"] if not_excited else []
        parts += [f"{low_coherence} with coherence < {coherence_threshold:g}"] if low_coherence else []
        parts += [f"{few_dof} with fewer than {min_dof} degrees of freedom"] if few_dof else []
        text += f" ({excluded} of {frequencies} frequencies excluded: {', '.join(parts)})"
    return text


def factor_sentence(found: ConstantFactor) -> str:
    """A constant factor inside the tolerance (JSON ``within_tolerance``) in words, for the channel's message.

    Parameters
    ----------
    found : ConstantFactor
        The factor, its error, its span and the free-play reading.

    Returns
    -------
    str
    """
    text = (
        f"within the tolerance, the data still resolve a constant factor ({found.noise_scales:.0f} noise "
        f"scales): the response is {found.gain:.3g} x the model's, {abs(found.phase_deg):.0f} deg "
        f"{'behind' if found.phase_deg < 0 else 'ahead'} at every confident frequency "
        f"({frequency_range(found.min_rad_s, found.max_rad_s)}, +-{found.error:.2g}), which no linear "
        f"element gives (Bode's gain-phase relation)"
    )
    if found.free_play_rad is not None:
        text += (
            f": free play of {found.free_play_rad:.2g} rad does at the flown amplitude {found.amplitude:.2g} "
            f"(not named from one amplitude: sweeps at two amplitudes would tell)"
        )
    return text


def model_band_reason(noise_scales: float, coherence_threshold: float) -> str:
    """Why a band is model-limited (a :class:`Band`'s ``reason``).

    Parameters
    ----------
    noise_scales : float
        The largest normalised mismatch in the band.
    coherence_threshold : float
        The channel's coherence threshold.

    Returns
    -------
    str
    """
    return (f"confident data disagree with the model: the mismatch is {noise_scales:.0f} noise scales "
            f"(coherence >= {coherence_threshold:g}, random error included)")


def low_coherence_reason(coherence_min: float, coherence_threshold: float) -> str:
    """Why a band is data-limited: its coherence falls below the threshold.

    Parameters
    ----------
    coherence_min : float
        The band's lowest coherence.
    coherence_threshold : float
        The channel's coherence threshold.

    Returns
    -------
    str
    """
    return (f"low coherence (down to {coherence_min:.2f} < {coherence_threshold:g}): noise or disturbances "
            f"dominate; fly better sweeps there (more amplitude, longer, calmer air)")


def few_dof_reason(dof_min: float, min_dof: int) -> str:
    """Why a band is data-limited: too few degrees of freedom for its coherence to mean much.

    Parameters
    ----------
    dof_min : float
        The band's fewest degrees of freedom.
    min_dof : int
        Degrees of freedom a confident frequency needs.

    Returns
    -------
    str
    """
    return (
        f"too few degrees of freedom ({dof_min:.0f} < {min_dof}) for the coherence to mean much; "
        f"fly the manoeuvre again, or longer, there"
    )


def bias_allowance_reason(coherence_min: float, noise_scales: float) -> str:
    """Why a band is not validated: the error it was given is a bias allowance, not random error.

    Parameters
    ----------
    coherence_min : float
        The band's lowest coherence.
    noise_scales : float
        The mismatch by the classical coherence bound.

    Returns
    -------
    str
    """
    return (
        f"the coherence (down to {coherence_min:.2f}) and degrees of freedom put the mismatch at "
        f"{noise_scales:.0f} noise scales: the larger error allowed there is no random error but a bias "
        f"allowance (feedback, or another surface moving with the input: see the warnings); not "
        f"validated there"
    )


def random_error_reason(noise_scales: float, coherence_min: float) -> str:
    """Why a band is data-limited: the random error explains its mismatch.

    Parameters
    ----------
    noise_scales : float
        The largest normalised mismatch in the band.
    coherence_min : float
        The band's lowest coherence.

    Returns
    -------
    str
    """
    return (f"the random error explains the mismatch (at most {noise_scales:.1f} noise scales, coherence "
            f"down to {coherence_min:.2f}); fly better sweeps there")


def band_edge_sentence(found: Sequence[tuple[Sequence[str], str, float]]) -> str:
    """The warning of a sup at an edge of the measured band, beyond the data's errors.

    Parameters
    ----------
    found : sequence of (labels, edge, frequency)
        What peaks there (``"epsilon"``, ``"sup kappa (the nu-gap)"``), which edge (``"lowest"`` or
        ``"highest"``) and its frequency [rad/s].

    Returns
    -------
    str
    """
    parts = [f"{' and '.join(labels)} {'peaks' if len(labels) == 1 else 'peak'} at the "
             f"{edge} confident frequency ({w:.3g} rad/s)"
             for labels, edge, w in found]
    return ("; ".join(parts) + ", beyond the data's errors: the mismatch may continue outside the band; the "
            "margins then do not hold")


def winding_warning(candidate: str, reason: str) -> str:
    """The warning of a top candidate whose model fails the winding-number condition with the model.

    Parameters
    ----------
    candidate : str
        The candidate's name.
    reason : str
        Why the condition fails.

    Returns
    -------
    str
    """
    return (
        f"the model and the diagnosed model ({candidate}) fail the winding-number condition "
        f"({reason}): if the diagnosis is right, the nu-gap between the model and the "
        f"aircraft is 1, not the sup over the measured band, and the margins do not hold"
    )


def limited_sentence(limited_by: str, top_sentence: str | None, *, likeliest: bool = True) -> str:
    """The report's verdict tail: model-limited with the top candidate, or data-limited (empty: neither).

    Parameters
    ----------
    limited_by : str
        ``"model"``, ``"data"`` or ``"none"``.
    top_sentence : str or None
        The top candidate in words (None: no candidate).
    likeliest : bool
        Say "the likeliest missing effect" before the candidate (a SISO channel) or not (MIMO).

    Returns
    -------
    str
    """
    if limited_by == "model" and top_sentence is not None:
        return (f" Model-limited; the likeliest missing effect: {top_sentence}." if likeliest
                else f" Model-limited; {top_sentence}.")
    if limited_by == "model":
        return " " + MODEL_LIMITED
    if limited_by == "data":
        return " " + DATA_LIMITED
    return ""


def no_fix_reason(limited_by: str, *, epsilon: float | None, candidates: bool,
                  best_epsilon: float | None) -> str:
    """Why ``--apply-diagnosis`` writes no fix for a channel: no candidate explains its mismatch.

    Parameters
    ----------
    limited_by : str
        ``"model"``, ``"data"`` or ``"none"``.
    epsilon : float or None
        The channel's epsilon (None: nothing validated).
    candidates : bool
        The diagnosis offers candidates (none of which explains the mismatch).
    best_epsilon : float or None
        The epsilon the top candidate leaves.

    Returns
    -------
    str
    """
    if not candidates:
        if limited_by == "model":
            return "model-limited, but no candidate brings a real improvement (see the diagnosis)"
        if limited_by == "data":
            return "data-limited: fly better sweeps rather than change the model"
        if epsilon is None:
            return "nothing validated (no confident frequency)"
        return f"the model fits (epsilon {epsilon:.2f}): nothing to fix"
    if limited_by != "model":
        return f"the channel is not model-limited (limited by {limited_by})"
    left = f"; the best leaves epsilon {best_epsilon:.2f}" if best_epsilon is not None else ""
    return f"no candidate explains the mismatch (none leaves the data within their errors{left})"


def mimo_band_reason(limited_by: str, kappa: float, peak_rad_s: float, noise_scales: float) -> str:
    """Why a MIMO band is model- or data-limited (its ``reason``).

    Parameters
    ----------
    limited_by : str
        ``"model"`` or ``"data"``.
    kappa : float
        The chordal distance at the band's peak.
    peak_rad_s : float
        Where [rad/s].
    noise_scales : float
        The band's largest normalised mismatch.

    Returns
    -------
    str
    """
    if limited_by == "model":
        return (f"kappa {kappa:.2f} at {peak_rad_s:.3g} rad/s is {noise_scales:.1f} noise scales "
                f"from the data (well outside the random error)")
    return (f"kappa {kappa:.2f} at {peak_rad_s:.3g} rad/s is within the random error (low coherence "
            f"or too few degrees of freedom): fly better sweeps there")


def mimo_column_sentence(input_name: str, kind: str, value: float, *, kappa_before: float,
                         kappa_after: float, nu_gap_before: float, nu_gap_after: float) -> str:
    """A MIMO column candidate (a gain or a delay on one input) in words (its ``sentence``).

    Parameters
    ----------
    input_name : str
        The input whose column of the model it changes.
    kind : str
        ``"gain"`` or ``"time_delay"``.
    value : float
        The gain, or the delay [s].
    kappa_before, kappa_after : float
        kappa where the model fails, without and with it.
    nu_gap_before, nu_gap_after : float
        The MIMO nu-gap without and with it.

    Returns
    -------
    str
    """
    words = f"gain {value:.3g}" if kind == "gain" else f"time delay of {1000 * value:.0f} ms"
    return (
        f"missing on input {input_name}: {words} (on its column of the model); "
        f"kappa where the model fails falls from {kappa_before:.2f} to {kappa_after:.2f}, "
        f"the MIMO nu-gap from {nu_gap_before:.2f} to {nu_gap_after:.2f}"
    )


def mimo_message(*, nu_gap: float | None, limited_by: str, bands: Sequence[Band], kappa_threshold: float,
                 element: dict | None = None, element_rad_s: float | None = None,
                 kappa_all: float | None = None, top_sentence: str | None = None) -> str:
    """One line for a MIMO channel: the verdict, where, which element dominates and the top candidate.

    Parameters
    ----------
    nu_gap : float or None
        The MIMO nu-gap over the confident frequencies (None: no confident frequency).
    limited_by : str
        ``"model"``, ``"data"`` or ``"none"``.
    bands : sequence of Band
        The channel's bands (the worst of its verdict leads).
    kappa_threshold : float
        The channel's threshold on kappa(w).
    element : dict or None
        The element that dominates where the model fails (``input``, ``output``, ``kappa_alone``).
    element_rad_s : float or None
        Where [rad/s].
    kappa_all : float or None
        kappa there with every element.
    top_sentence : str or None
        The top column candidate's sentence (None: none explains it).

    Returns
    -------
    str
    """
    if nu_gap is None:
        return "no confident frequency (every output's multiple coherence must pass the threshold)"
    lead = max((b for b in bands if b.limited_by == limited_by), key=lambda b: b.epsilon, default=None)
    if limited_by == "none":
        return f"MIMO nu-gap {nu_gap:.3f}: kappa(w) within {kappa_threshold} at every confident frequency"
    where = frequency_range(lead.min_rad_s, lead.max_rad_s) if lead else ""
    text = f"{limited_by}-limited at {where}: {lead.reason}" if lead else f"{limited_by}-limited"
    if element is not None:
        text += (f"; at {element_rad_s:.3g} rad/s the element {element['input']} -> "
                 f"{element['output']} "
                 f"dominates (its mismatch alone would give kappa {element['kappa_alone']:.2f}; all together "
                 f"{kappa_all:.2f})")
    if limited_by == "model":
        text += "; " + (top_sentence if top_sentence is not None else "no column effect explains it")
    return text


def candidate_line(candidate: Candidate | None) -> str:
    """A diagnosis candidate on one line (the node's ``diagnosis`` value): its sentence, or, for a candidate
    read back without one, ``missing: time delay of 45 ms (epsilon would be 0.06)``.

    Parameters
    ----------
    candidate : Candidate or None
        The top candidate (None: none; the line is empty).

    Returns
    -------
    str
    """
    if not candidate:
        return ""
    sentence = candidate.sentence
    if not sentence:
        try:
            parts = [describe_effect(e) for e in candidate.effects]
        except Exception:  # noqa: BLE001 - description is cosmetic; fall back to the effect name
            parts = []
        what = " + ".join(parts) or str(candidate.effect or "unknown effect").replace("_", " ")
        sentence = f"missing: {what}"
        if candidate.epsilon is not None:
            sentence += f" (epsilon would be {candidate.epsilon:.2f})"
    return " ".join(str(sentence).split())


def _band_text(result: ChannelResult) -> str:
    """``at 20-40 rad/s`` from the diagnosis band that holds the worst frequency, else ``at 14.9 rad/s``."""
    worst = result.worst_frequency_rad_s
    chosen = None
    for band in result.bands:
        if worst is not None and band.contains(worst):
            chosen = band
            break
        if chosen is None and band.limited_by == result.limited_by:
            chosen = band
    if chosen is not None:
        return f"at {chosen.min_rad_s:.3g}-{chosen.max_rad_s:.3g} rad/s"
    return f"at {worst:.3g} rad/s" if worst is not None else ""


def status_summary(result: ChannelResult, level: str, candidate_text: str) -> str:
    """A channel's status line: ``epsilon 0.62 (was 0.71): ERROR, model-limited at 20-40 rad/s; missing: time
    delay of 45 ms`` (the MIMO nu-gap for a MIMO channel; data-limited, or waiting, without an estimate).

    Parameters
    ----------
    result : ChannelResult
        The channel's (cheap) result.
    level : str
        Its level (``OK``, ``WARN``, ``ERROR``).
    candidate_text : str
        The top candidate on one line (:func:`candidate_line`; empty: none).

    Returns
    -------
    str
    """
    if result.epsilon is not None:
        text = f"epsilon {result.epsilon:.2f}"
        if result.epsilon_previous is not None:
            text += f" (was {result.epsilon_previous:.2f})"
        text += f": {level}"
        if result.limited_by in ("model", "data"):
            band = _band_text(result)
            text += f", {result.limited_by}-limited" + (f" {band}" if band else "")
        elif result.worst_frequency_rad_s is not None:
            text += f", worst at {result.worst_frequency_rad_s:.3g} rad/s"
        if candidate_text:
            text += f"; {candidate_text}"
        return text
    if result.mimo is not None and result.nu_gap is not None:
        text = f"MIMO nu-gap {result.nu_gap:.2f}: {level}"
        if result.limited_by in ("model", "data"):
            band = _band_text(result)
            text += f", {result.limited_by}-limited" + (f" {band}" if band else "")
        if candidate_text:
            text += f"; {candidate_text}"
        return text
    if result.sweeps > 0:
        return (result.message or "no frequency passes the coherence threshold") + \
            ": WARN, data-limited (fly better sweeps)"
    return "receiving data, waiting for a sweep (no estimate yet)"


def amplitude_sentence(low_amplitude: float, high_amplitude: float, *, detected: bool, frequencies: int,
                       probability: float, disagreeing: int = 0, worst_rad_s: float = math.nan,
                       gain_ratio: float = math.nan, phase_deg: float = math.nan) -> str:
    """Sweeps flown at two amplitudes compared, in words (JSON ``nonlinearity_evidence``).

    Parameters
    ----------
    low_amplitude, high_amplitude : float
        The two groups' input amplitudes.
    detected : bool
        They disagree beyond their errors.
    frequencies : int
        Frequencies compared.
    probability : float
        Chance of so large a disagreement for a linear response.
    disagreeing : int
        Frequencies beyond the errors.
    worst_rad_s, gain_ratio, phase_deg : float
        Where they disagree most, and the larger amplitude's response there relative to the smaller's.

    Returns
    -------
    str
    """
    amplitudes = f"sweeps at {low_amplitude:.3g} and {high_amplitude:.3g} amplitude"
    if not detected:
        return (
            f"{amplitudes} agree within their errors ({frequencies} frequencies compared, chance "
            f"{min(probability, 1.0):.2g} for a linear response)"
        )
    return (f"{amplitudes} disagree beyond their errors at {disagreeing} of {frequencies} "
            f"frequencies (at {worst_rad_s:.3g} rad/s the larger one's response is "
            f"x{gain_ratio:.2f}, {phase_deg:+.0f} deg)")


def clock_sentence(lead_s: float, culprit: str, fix: str, channels: Sequence[str] = ()) -> str:
    """A clock offset found (the rate ahead of the surface), with its fix.

    Parameters
    ----------
    lead_s : float
        How far the rate leads the surface [s].
    culprit : str
        ``"the surface topic (/servos)"``, or the topic shared by ``channels``.
    fix : str
        The config change.
    channels : sequence of str
        The channels that show it alike (empty: one channel).

    Returns
    -------
    str
    """
    if channels:
        return (f"on {', '.join(channels)} the rate leads the surface by {1000 * lead_s:.0f} ms, which no "
                f"airframe does: {culprit} is stamped late (or the IMU early, by another clock); {fix}")
    return (f"the rate leads the surface by {1000 * lead_s:.0f} ms, which no airframe "
            f"does: {culprit} is stamped late (or the IMU early, by another "
            f"clock); {fix}")


def sign_sentence(fix: str) -> str:
    """An opposite sign found on one channel, with its fix.

    Parameters
    ----------
    fix : str
        The config change.

    Returns
    -------
    str
    """
    return (f"the data are the model with the opposite sign: the surface's positive direction "
            f"is the other way round (or the model's sign is); {fix}")


def units_sentence(factor: float, what: str, fix: str, channels: Sequence[str] = (), topic: str = "") -> str:
    """Units found (the data are the model times a factor), with its fix.

    Parameters
    ----------
    factor : float
        The factor.
    what : str
        Which stream is logged in which units (:func:`units_words`).
    fix : str
        The config change.
    channels : sequence of str
        The channels that show it alike, from ``topic`` (empty: one channel).
    topic : str
        Their shared topic.

    Returns
    -------
    str
    """
    if channels:
        return f"on {', '.join(channels)} the data are the model times {factor:.6g}: {what} ({topic}); {fix}"
    sign = " and the opposite sign" if factor < 0 else ""
    return f"the data are the model times {factor:.6g}{sign}: {what}; {fix}"


def units_words(stream: str, unit: str) -> str:
    """Which stream is logged in which units where the config says SI.

    Parameters
    ----------
    stream : str
        ``"input"`` (the surface) or ``"output"`` (the rate).
    unit : str
        ``"degrees"``, or ``"units 10 times too small"``.

    Returns
    -------
    str
    """
    if stream == "input":
        return f"the surface is logged in {unit} where the config says radians"
    return (f"the rate is logged in {unit if unit != 'degrees' else 'degrees per second'} where the config "
            "says "
            f"radians per second")


def body_frame_sentence(topic: str, imu: str, model: str, fix: str) -> str:
    """Pitch and yaw reversed, not roll: the IMU's frame is not the model's, with the fix.

    Parameters
    ----------
    topic : str
        The IMU's topic.
    imu, model : str
        The IMU's frame and the model's, in words.
    fix : str
        The config change.

    Returns
    -------
    str
    """
    return (f"the rate is reversed relative to the model on pitch and yaw, not on roll: "
            f"the IMU ({topic}) is {imu}, the model {model}; {fix}")


def reversed_imu_sentence(topic: str, fix: str) -> str:
    """Every rate reversed: the IMU is mounted reversed (or every surface is), with the fix.

    Parameters
    ----------
    topic : str
        The IMU's topic.
    fix : str
        The config change.

    Returns
    -------
    str
    """
    return (f"roll, pitch and yaw rates are all reversed relative to the model: the IMU "
            f"({topic}) is mounted reversed (or every surface is); {fix}")


def dropped_lag_warning(streams: dict[str, int], max_lag_s: float) -> str:
    """Grid values given up because one stream of a channel ran too far ahead of another.

    Parameters
    ----------
    streams : dict of str to int
        Values dropped per stream (only those with some).
    max_lag_s : float
        How far one stream may run ahead of another [s].

    Returns
    -------
    str
    """
    counts = ", ".join(f"{n} of the {name.replace('_', ' ')}" for name, n in streams.items())
    return (f"samples dropped ({counts}): one stream ran more than {max_lag_s:g} s ahead of another; feed "
            f"the streams interleaved in time (whole recorded arrays: add_time_histories)")


def sparse_stream_sentence(streams: Sequence[tuple[str, int]], max_gap_s: float) -> str:
    """Streams whose samples are all further apart than a gap: nothing between them is used.

    Parameters
    ----------
    streams : sequence of (str, int)
        Each stream and how many samples it has.
    max_gap_s : float
        A larger sample spacing breaks the data [s].

    Returns
    -------
    str
    """
    what = " and ".join(f"the {name.replace('_', ' ')}'s {n}" for name, n in streams)
    return (f"every interval between {what} samples is longer than max_gap_s ({max_gap_s:g} s), a gap, so "
            f"nothing is estimated: are the times in seconds? (milliseconds or microseconds look like this)")
