"""What to fly next, in the report and on the terminal (issue 25): per channel, the bands still without a
verdict and the manoeuvres of the test card (:func:`gap_validation.core.plan.plan_card`) that would close
them.

* :func:`open_bands`: the runs of grid frequencies without a verdict (data-limited, not excited, too few
  degrees of freedom, low coherence, ...), from a channel's results;
* :func:`plan_for`: the card of a replay's results, or one line saying why it is unavailable (planning never
  costs a replay its outputs);
* :func:`plan_lines`: one terminal line per channel with such bands, pointing at ``gap-validate plan``;
* :func:`summary_html`, :func:`channel_html`: the report's sections;
* :func:`planned_spans`: the bands a channel's manoeuvres close (shaded on the Bode figure).

No matplotlib here; the planning is :mod:`gap_validation.core.plan` (docs/PLAN.md).
"""
from __future__ import annotations

import html
import logging
import math
from dataclasses import dataclass

from gap_validation.core.errors import GapValidationError, one_line
from gap_validation.core.plan import REASON_WORDS, ChannelPlan, TestCard, no_verdict_reason, plan_card
from gap_validation.core.results import ChannelResult, ValidationResult
from gap_validation.report.terminal import duration_text

log = logging.getLogger(__name__)

#: Reasons no manoeuvre can remove (the planner calls those frequencies unreachable).
NOT_BY_FLYING = ("above_resolution",)
#: Bands named in a terminal line before "and N more".
LINE_BANDS = 3


@dataclass(frozen=True)
class OpenBand:
    """A run of adjacent grid frequencies without a verdict.

    Attributes
    ----------
    low_rad_s, high_rad_s : float
        Its lowest and highest grid frequency [rad/s].
    points : int
        Grid frequencies in it.
    reasons : tuple of str
        Why they have no verdict (keys of :data:`~gap_validation.core.plan.REASON_WORDS`), most frequent
        first.
    """

    low_rad_s: float
    high_rad_s: float
    points: int
    reasons: tuple[str, ...]

    @property
    def words(self) -> str:
        """The reasons in words, comma-separated."""
        return ", ".join(REASON_WORDS.get(r, str(r).replace("_", " ")) for r in self.reasons)

    @property
    def by_flying(self) -> bool:
        """Whether a manoeuvre could remove any of its reasons (not only beyond what the logs resolve)."""
        return any(r not in NOT_BY_FLYING for r in self.reasons)


def open_bands(ch: ChannelResult) -> list[OpenBand]:
    """The runs of grid frequencies of a channel's results without a verdict, and why (the planner's own rule,
    :func:`~gap_validation.core.plan.no_verdict_reason`); a run ends where the reason changes from one that
    flying can remove to one it cannot.

    Parameters
    ----------
    ch : ChannelResult
        A channel of a replay's results.
    """
    w = [] if ch.frequency_rad_s is None else [float(v) for v in ch.frequency_rad_s]
    flags = list(ch.frequency_flags) + [None] * (len(w) - len(ch.frequency_flags))
    reasons = list(ch.frequency_reasons) + [None] * (len(w) - len(ch.frequency_reasons))
    runs: list[list[tuple[float, str]]] = []
    for i, freq in enumerate(w):
        why = no_verdict_reason(flags[i], reasons[i])
        if why is None:
            runs.append([])
            continue
        if runs and runs[-1] and (runs[-1][-1][1] in NOT_BY_FLYING) == (why in NOT_BY_FLYING):
            runs[-1].append((freq, why))
        else:
            runs.append([(freq, why)])
    out = []
    for run in (r for r in runs if r):
        keys = [why for _, why in run]
        ordered = tuple(sorted(set(keys), key=lambda k: (-keys.count(k), keys.index(k))))
        out.append(OpenBand(run[0][0], run[-1][0], len(run), ordered))
    return out


def plan_for(config, result: ValidationResult, results: dict | None = None,
             source: str = "the replay's results") -> TestCard | str:
    """The test card of a replay's results, or one line saying why it could not be planned.

    Parameters
    ----------
    config : ValidationConfig
        The config the results were made with.
    result : ValidationResult
        The replay's results.
    results : dict, optional
        Their JSON mapping, when already made (``result.to_json_dict()`` otherwise).
    source : str
        The results' name in the planner's messages.
    """
    try:
        return plan_card(config, result.to_json_dict() if results is None else results, source=source)
    except Exception as err:  # noqa: BLE001 - planning never costs a replay its table, JSON or report
        log.debug("plan_card failed", exc_info=True)
        return (
            one_line(err) if isinstance(err, GapValidationError) else f"{type(err).__name__}: {one_line(err)}"
        )


def _span(low: float, high: float) -> str:
    return f"{low:.3g}" if f"{low:.3g}" == f"{high:.3g}" else f"{low:.3g}-{high:.3g}"


def _manoeuvre_words(plan: ChannelPlan) -> str:
    """What a channel's card flies, in a few words."""
    ms = plan.manoeuvres
    if len(ms) == 1:
        m = ms[0]
        times = "once" if m.repeats == 1 else f"{m.repeats} times"
        return (f"a {m.duration_s:.0f} s {m.kind} at {math.degrees(m.amplitude_rad):.2g} deg flown {times} "
                f"({duration_text(m.flight_time_s)} with trim)")
    kinds = sorted({m.kind for m in ms})
    return f"{len(ms)} {'/'.join(kinds)}s ({duration_text(sum(m.flight_time_s for m in ms))} with trim)"


def _plan_words(name: str, plan: TestCard | str | None, command: str, it: str) -> str:
    """What the card says of a channel's open bands (``it``: ``it`` or ``them``), one clause."""
    if plan is None:
        return f"`{command}` plans the manoeuvres that would close {it}"
    if isinstance(plan, str):
        return f"plan unavailable ({plan})"
    cp = plan.channels.get(name)
    if cp is None:
        return f"`{command}` has no card for this channel"
    if cp.manoeuvres:
        far = f" but for {len(cp.unreachable)} band(s) out of reach" if cp.unreachable else ""
        return f"`gap-validate plan` plans {_manoeuvre_words(cp)} that would close {it}{far}"
    if cp.unreachable:
        return f"`gap-validate plan` finds {it} out of reach ({cp.unreachable[0].reason.split(':')[0]})"
    note = next((n.split(": ", 1)[-1] for n in cp.notes if "MIMO" in n), "nothing planned")
    return f"`gap-validate plan`: {note}"


def plan_lines(
    result: ValidationResult, plan: TestCard | str | None = None, command: str | None = None
) -> list[str]:
    """One terminal line per channel with bands that flying could close (or a card for it), pointing at
    ``gap-validate plan``: where, why, and what the card flies when it was planned.

    Parameters
    ----------
    result : ValidationResult
        The replay's results.
    plan : TestCard or str, optional
        Their card (:func:`plan_for`), the line saying why it is unavailable, or None (not planned: the line
        says how to plan it).
    command : str, optional
        The ``gap-validate plan`` command line to point at (default: with ``RESULTS.json`` and the results'
        config).
    """
    command = command or f"gap-validate plan RESULTS.json --config {result.config_source or 'CFG'}"
    lines = []
    for name, ch in result.channels.items():
        bands = [b for b in open_bands(ch) if b.by_flying]
        cp = plan.channels.get(name) if isinstance(plan, TestCard) else None
        if not bands and not (cp and cp.manoeuvres):
            continue
        if bands:
            where = ", ".join(_span(b.low_rad_s, b.high_rad_s) for b in bands[:LINE_BANDS])
            more = f" and {len(bands) - LINE_BANDS} more" if len(bands) > LINE_BANDS else ""
            seen = []
            for b in bands:
                seen += [r for r in b.reasons if r not in seen]
            head = f"no verdict at {where}{more} rad/s ({', '.join(REASON_WORDS.get(r, r) for r in seen)})"
        else:
            head = "nothing estimated yet"
        it = "it" if len(bands) <= 1 else "them"
        lines.append(f"  {name}: {head}: {_plan_words(name, plan, command, it)}")
    return lines


def planned_spans(plan: TestCard | str | None, name: str) -> list[tuple[float, float]]:
    """The grid bands the card's manoeuvres of a channel close [rad/s] (empty without a card).

    Parameters
    ----------
    plan : TestCard or str, optional
        The card, or why it is unavailable.
    name : str
        The channel.
    """
    if not isinstance(plan, TestCard) or name not in plan.channels:
        return []
    return [(float(m.closes_rad_s[0]), float(m.closes_rad_s[1])) for m in plan.channels[name].manoeuvres]


def summary_html(result: ValidationResult, plan: TestCard | str | None) -> str:
    """The card in one paragraph for the report's summary (empty when every frequency has a verdict and
    nothing was planned).

    Parameters
    ----------
    result : ValidationResult
        The results.
    plan : TestCard or str, optional
        Their card, why it is unavailable, or None (not planned).
    """
    if isinstance(plan, str):
        return f"<h3>What to fly next</h3><p class='warn'>plan unavailable: {html.escape(plan)}</p>"
    if isinstance(plan, TestCard):
        n = len(plan.manoeuvres)
        if not n and not any(cp.unreachable for cp in plan.channels.values()):
            return "<h3>What to fly next</h3><p>nothing: every frequency has a verdict.</p>"
        far = sum(len(cp.unreachable) for cp in plan.channels.values())
        text = (f"the test card: {n} manoeuvre(s), {duration_text(plan.flight_time_s)} of flight with trim"
                + (f"; {far} band(s) out of reach" if far else "") + " (per channel below).")
        return (f"<h3>What to fly next</h3><p>{html.escape(text)}</p>"
                f"<p class='note'>target: {html.escape(plan.target_rule)}.</p>")
    if any(b.by_flying for ch in result.channels.values() for b in open_bands(ch)):
        command = f"gap-validate plan RESULTS.json --config {result.config_source or 'CFG'}"
        return (
            f"<h3>What to fly next</h3><p class='note'>the test card that would close the bands without a "
            f"verdict: <code>{html.escape(command)}</code> (docs/PLAN.md).</p>"
        )
    return ""


def _cells(values) -> str:
    return "".join(f"<td>{html.escape(str(v))}</td>" for v in values)


def _bands_table(bands: list[OpenBand]) -> str:
    rows = "".join(
        "<tr>"
        + _cells(
            (
                _span(b.low_rad_s, b.high_rad_s),
                _span(b.low_rad_s / (2 * math.pi), b.high_rad_s / (2 * math.pi)),
                b.points,
                b.words,
            )
        )
        + "</tr>"
        for b in bands
    )
    return (
        "<table class='open-bands'><tr><th>no verdict, rad/s</th><th>Hz</th><th>points</th><th>why</th></tr>"
        f"{rows}</table>"
    )


def _manoeuvres_table(cp: ChannelPlan) -> str:
    head = (
        "#",
        "kind",
        "closes rad/s",
        "sweep rad/s",
        "sweep Hz",
        "amplitude deg (rad)",
        "sweep s",
        "repeats",
        "flight time",
        "random error now",
        "predicted",
        "target",
        "why",
    )
    rows = []
    for m in cp.manoeuvres:
        now = [e for e in m.error_now if e is not None]
        rows.append(
            "<tr>"
            + _cells(
                (
                    m.index,
                    m.kind,
                    _span(*m.closes_rad_s),
                    f"{m.band_rad_s[0]:.3g}-{m.band_rad_s[1]:.3g}",
                    f"{m.f_start_hz:.3g}-{m.f_stop_hz:.3g}",
                    f"{math.degrees(m.amplitude_rad):.2f} ({m.amplitude_rad:.3g})",
                    f"{m.duration_s:.0f}",
                    m.repeats,
                    duration_text(m.flight_time_s),
                    f"{max(now):.3f}" if now else "-",
                    f"{m.expected_worst_error:.3f}",
                    f"{min(m.target_error):.3f}" if m.target_error else "-",
                    ", ".join(m.reasons),
                )
            )
            + "</tr>"
        )
    return ("<table class='card'><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"
            + "".join(rows) + "</table>")


def channel_html(name: str, ch: ChannelResult, plan: TestCard | str | None) -> str:
    """A channel's "what to fly next": its bands without a verdict, the card's manoeuvres that would close
    them (kind, band in rad/s and Hz, amplitude, length, repeats, flight time, random error now, predicted and
    needed), the bands out of reach with the reason; or why the card is unavailable, or how to plan it.

    Parameters
    ----------
    name : str
        The channel.
    ch : ChannelResult
        Its results.
    plan : TestCard or str, optional
        The card, why it is unavailable, or None (not planned).
    """
    bands = open_bands(ch)
    cp = plan.channels.get(name) if isinstance(plan, TestCard) else None
    if not bands and not (cp and (cp.manoeuvres or cp.unreachable)):
        if ch.frequency_rad_s is None or not len(ch.frequency_rad_s):
            return ""
        return "<p class='note'>what to fly next: nothing, every frequency has a verdict.</p>"
    parts = ["<h3>What to fly next</h3>"]
    if bands:
        parts.append(_bands_table(bands))
    if isinstance(plan, str):
        parts.append(f"<p class='warn'>plan unavailable: {html.escape(plan)}</p>")
    elif cp is not None:
        if cp.manoeuvres:
            what = (f"the card that would close {'it' if len(bands) == 1 else 'them'}" if bands
                    else "nothing estimated yet: the card of a first flight")
            parts.append(
                f"<p>{what} "
                f"({html.escape(duration_text(sum(m.flight_time_s for m in cp.manoeuvres)))} of flight; "
                "random error: the worst over the frequencies closed, now, predicted for the card flown "
                "on its own, and what a verdict needs):</p>"
            )
            parts.append(_manoeuvres_table(cp))
        parts += [f"<p class='warn'>out of reach at {html.escape(_span(*u.band_rad_s))} rad/s: "
                  f"{html.escape(u.reason)}</p>" for u in cp.unreachable]
        if cp.amplitude_cap_rad is not None and cp.manoeuvres:
            parts.append(
                f"<p class='note'>amplitude cap {cp.amplitude_cap_rad:.3g} rad "
                f"({math.degrees(cp.amplitude_cap_rad):.2f} deg): {html.escape(cp.amplitude_cap_reason)}; "
                "the card as YAML and in ArduPilot's and PX4's parameters: <code>gap-validate plan</code> "
                "(docs/PLAN.md).</p>"
            )
        parts += [f"<p class='note'>{html.escape(n)}</p>" for n in cp.notes if "MIMO" in n]
    else:
        parts.append(
            "<p class='note'>not planned here: <code>gap-validate plan RESULTS.json --config CFG</code> "
            "plans the card that would close them (docs/PLAN.md).</p>"
        )
    return "\n".join(parts)
