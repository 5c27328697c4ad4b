"""HTML validation report: Table 1, the verdict in words and the paper's figures per channel (front end).

``write_report(result, directory)`` writes ``directory/index.html`` (opens offline: plain HTML and PNG files
beside it) with, at the top, the summary in the form of the paper's Table 1 (raw and averaged epsilon, gain,
phase and disk margins per channel) and the verdict per channel in words; then per channel the figures of
:mod:`gap_validation.report.figures` (Figs. 1, 2, 4, 5 and 6 of the paper, where the model fails, the
diagnosis candidates before and after, and epsilon over model versions), and what to fly next: the bands
without a verdict and the test card's manoeuvres that would close them (:mod:`gap_validation.report.card`).
Every name that comes from a bag or a config is HTML-escaped. A figure that cannot be drawn is replaced by a
one-line note: the rest of the report is still written. Files are written atomically (temporary file, then
rename).
"""
from __future__ import annotations

import html
import logging
import os
import re
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

from gap_validation.core.atomic import atomic_write_text
from gap_validation.core.errors import DataError, one_line
from gap_validation.core.margins import STANDARD_EPSILON, WARN_EPSILON, margins_from_epsilon
from gap_validation.core.plan import TestCard
from gap_validation.core.results import NUGAP_DATA_NOTE, ChannelResult, ValidationResult
from gap_validation.core.wording import limited_sentence
from gap_validation.report import card, figures
from gap_validation.report.terminal import fmt

log = logging.getLogger(__name__)

#: Figure kinds in report order, with their captions.
FIGURES = {
    "bode": "Model and flight data: each sweep light, their average dark; coherence below, excluded points "
    "marked (paper Fig. 4).",
    "disk": "Perturbations P2/P1 per frequency with the epsilon disks of the raw and averaged data, the "
    "gain-margin markers on the real axis and the phase tangents (Figs. 1 and 5).",
    "failure": "Where the model fails: kappa(w) and epsilon(w) (eqs. 13, 14), thresholds, the worst "
    "frequency "
    "and the model-limited (red) / data-limited (orange) bands.",
    "nichols": "Nichols plane: the epsilon disk as an ellipse around the critical point, inside the standard "
    "exclusion region (Fig. 2 left).",
    "nyquist": "Robust Nyquist diagram: the tube of epsilon disks around the model contains the data; it "
    "must "
    "not cover the critical point -1 (Fig. 2 right).",
    "time": "Time domain: doublets from the flight against the model and the tube of Monte Carlo runs of the "
    "uncertain model (all-pass perturbations on the epsilon-disk boundary; Fig. 6), with the TIC "
    "(eq. 1) and input-augmented TIC (eq. 3).",
    "diagnosis": "Diagnosis: the model with each top candidate effect against the data, with the epsilon "
    "each "
    "leaves.",
    "history": "Epsilon over model versions (validation history): watch it fall.",
    "mimo_bode": "MIMO channel: Bode matrix, model against flight per element (rows: outputs, columns: "
    "inputs), "
    "with the element's partial coherence (what its input explains once the other inputs are "
    "accounted for) and the output's multiple coherence below.",
    "mimo_kappa": "MIMO channel: kappa(w), the MIMO chordal distance of model and measured matrices, its "
                  "noise "
    "scale from the random error of H, the model-limited (red) / data-limited (orange) bands and "
    "the element that fails most.",
    "mimo_sv": "MIMO channel: singular values of the model's and the measured response matrices.",
}

_STYLE = ("body{font-family:sans-serif;max-width:1050px;margin:auto;padding:0 1em}"
          "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:3px 8px;"
          "text-align:right}th{background:#f4f4f4}.verdict{margin:0.3em 0}.bad{color:#b00}.ok{color:#070}"
          ".warn{color:#a60}figure{margin:1em 0}figcaption{font-size:0.85em;color:#444}img{max-width:100%}"
          ".note{font-size:0.85em;color:#666}")


def verdict(ch: ChannelResult) -> tuple[str, str]:
    """The channel's verdict in words and its CSS class (ok / warn / bad)."""
    eps = ch.epsilon
    if ch.mimo is not None and ch.nu_gap is not None:
        return _mimo_verdict(ch)
    if eps is None:
        return f"not validated yet: {ch.message or 'no sweep'}.", "warn"
    m = margins_from_epsilon(eps)
    if not m.guaranteed:
        text, cls = (
            (
                f"not validated: epsilon {eps:.3g} >= 1, the data lie outside every disk that guarantees "
                f"margins; no controller designed on this model is guaranteed stable on the aircraft."
            ),
            "bad",
        )
    elif ch.margins_caveat:
        text, cls = (
            (
                f"not validated beyond the measured band (epsilon {eps:.3f} over it): {ch.margins_caveat}; a "
                f"controller with {m.gain_margin_db:.2f} dB gain margin and {m.phase_margin_deg:.1f} deg "
                "phase "
                f"margin on the model is NOT guaranteed stable on the aircraft."
            ),
            "bad",
        )
    else:
        need = (
            f"a controller with at least {m.gain_margin_db:.2f} dB gain margin and {m.phase_margin_deg:.1f} "
            "deg "
            f"phase margin on the model is guaranteed stable on the aircraft"
        )
        if eps < WARN_EPSILON:
            text, cls = f"validated (epsilon {eps:.3f}): {need}; well within standard margins.", "ok"
        elif eps < STANDARD_EPSILON:
            text, cls = (
                f"validated (epsilon {eps:.3f}): {need}; within standard margins (6 dB, 45 deg).",
                "ok",
            )
        else:
            text, cls = (
                (
                    f"validated with large margins only (epsilon {eps:.3f}): {need}, more than the standard "
                    f"6 dB / 45 deg."
                ),
                "warn",
            )
    top = ch.diagnosis[0] if ch.diagnosis else None
    text += limited_sentence(ch.limited_by, None if top is None else top.sentence or top.effect)
    return text, cls


def _mimo_verdict(ch: ChannelResult) -> tuple[str, str]:
    """A MIMO channel's verdict from its MIMO nu-gap (epsilon and its margins are SISO notions)."""
    nu = ch.nu_gap
    shape = "x".join(str(n) for n in ch.mimo.shape)
    cls = "ok" if nu < WARN_EPSILON else "warn" if nu < STANDARD_EPSILON else "bad"
    text = (
        f"{shape} MIMO nu-gap {nu:.3f} over the confident frequencies: a controller whose stability margin "
        f"b(P, C) exceeds it on the model is guaranteed to stabilise the aircraft (Vinnicombe)."
    )
    text += limited_sentence(ch.limited_by, ch.diagnosis[0].sentence if ch.diagnosis else None,
                             likeliest=False)
    if ch.limited_by == "model":
        cls = "warn" if cls == "ok" else cls
    return text, cls


def _cell(value) -> str:
    return f"<td>{html.escape(value)}</td>"


def table1_html(result: ValidationResult) -> str:
    """The summary in the paper's Table 1 form: raw and averaged columns per channel."""
    channels = list(result.channels.values())
    head1 = "<tr><th rowspan='2'></th>" + "".join(
        f"<th colspan='2'>{html.escape(ch.name)}</th>" for ch in channels) + "</tr>"
    head2 = "<tr>" + "<th>Raw</th><th>Average</th>" * len(channels) + "</tr>"
    rows = [("Gap metric epsilon", lambda c, m, e: fmt(e, ".2f")),
            ("Gain margin, dB", lambda c, m, e: fmt(m.gain_margin_db, ".2f")),
            ("Phase margin, deg", lambda c, m, e: fmt(m.phase_margin_deg, ".2f")),
            ("Disk margin", lambda c, m, e: fmt(m.disk_margin, ".2f"))]
    out = ["<table class='table1'>", head1, head2]
    for label, cell in rows:
        cells = []
        for ch in channels:
            for eps, margins in ((ch.epsilon_raw, ch.margins_raw), (ch.epsilon, ch.margins)):
                cells.append(_cell(cell(ch, margins, eps)))
        out.append(f"<tr><th>{html.escape(label)}</th>{''.join(cells)}</tr>")
    out.append("</table>")
    out.append(
        "<p class='note'>nu-gap and epsilon over the measured band (the winding-number condition assumed, as "
        "in the paper); the margins hold if the mismatch outside the band is no larger.</p>"
    )
    doubtful = [ch for ch in channels if ch.margins.guaranteed and ch.margins_caveat]
    out += [
        f"<p class='warn'>{html.escape(ch.name)}: margins NOT guaranteed: "
        f"{html.escape(ch.margins_caveat)}</p>"
        for ch in doubtful
    ]
    return "\n".join(out)


def details_html(result: ValidationResult) -> str:
    """Further figures per channel: nu-gap, worst frequency, sweeps, limits, TIC, previous epsilon."""
    channels = list(result.channels.values())

    def tic(ch):
        values = [d.get("tic") for d in ch.time_domain if d.get("tic") is not None]
        return ", ".join(f"{v:.3f}" for v in values) or "-"

    rows = [("nu-gap (average)", lambda c: fmt(c.nu_gap)),
            ("worst frequency, rad/s", lambda c: fmt(c.nu_gap_frequency_rad_s if c.mimo is not None
                                                     else c.worst_frequency_rad_s, ".3g")),
            ("sweeps", lambda c: str(c.sweeps)),
            ("points used / excluded", lambda c: f"{c.points_used} / {c.points_excluded}"),
            ("limited by", lambda c: c.limited_by),
            ("TIC of the doublets (eq. 1)", tic),
            ("previous epsilon", lambda c: fmt(c.epsilon_previous))]
    out = ["<table><tr><th></th>" + "".join(f"<th>{html.escape(c.name)}</th>" for c in channels) + "</tr>"]
    for label, cell in rows:
        out.append(f"<tr><th>{html.escape(label)}</th>" + "".join(_cell(cell(c)) for c in channels) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def _slug(name: str, index: int) -> str:
    """A safe file stem for a channel name (names come from configs: never trust them in a path)."""
    if re.fullmatch(r"[A-Za-z0-9_-]{1,64}", name):
        return name
    return f"channel{index}_" + (re.sub(r"[^A-Za-z0-9_-]+", "_", name)[:40].strip("_") or "x")


class _Channel:
    """Draws one channel's figures, collecting the HTML and the problems."""

    def __init__(
        self,
        ch: ChannelResult,
        stem: str,
        directory: Path,
        versions: list[dict],
        runs: int,
        seed: int,
        planned: list[tuple[float, float]] | None = None,
    ):
        self.ch, self.stem, self.directory, self.versions = ch, stem, directory, versions
        self.runs, self.seed, self.planned = runs, seed, list(planned or [])
        self.parts: list[str] = []
        self.problems: list[str] = []
        self.model = self._model()

    def _model(self):
        # MIMO figures read the matrices of the result
        if not self.ch.model_spec or self.ch.mimo is not None:
            return None
        from gap_validation.core.models import LinearModel

        try:
            from gap_validation.report.figures import at_flown_amplitude

            return at_flown_amplitude(LinearModel.from_spec(self.ch.model_spec), self.ch)
        except Exception as err:  # noqa: BLE001 - a bad model only costs the figures that need it
            self.problems.append(f"{self.ch.name}: model not usable for figures ({one_line(err)})")
            return None

    def figure(self, kind: str, draw: Callable[[Path], None], caption: str = "") -> None:
        path = self.directory / f"{self.stem}_{kind}.png"
        try:
            draw(path)
        except Exception as err:  # noqa: BLE001 - one figure never costs the rest of the report
            problem = f"{self.ch.name}: {kind} figure not drawn ({one_line(err)})"
            log.debug("figure failed", exc_info=True)
            self.problems.append(problem)
            self.parts.append(f"<p class='bad'>{html.escape(problem)}</p>")
            return
        alt = html.escape(f"{self.ch.name} {kind}", quote=True)
        self.parts.append(f"<figure id='{html.escape(self.stem, quote=True)}-{kind}'>"
                          f"<img src='{html.escape(path.name, quote=True)}' alt='{alt}'>"
                          f"<figcaption>{html.escape(FIGURES[kind] + caption)}</figcaption></figure>")

    def draw_all(self) -> None:
        ch, model = self.ch, self.model
        if ch.mimo is not None:
            self.draw_mimo()
            return
        has_frequency = (
            ch.frequency_rad_s is not None and len(ch.frequency_rad_s) > 0 and ch.measured is not None
        )
        if has_frequency:
            shaded = " Shaded: the bands the test card's manoeuvres would close." if self.planned else ""
            self.figure("bode", lambda p: figures.bode_figure(ch, p, model, self.planned), shaded)
            self.figure("disk", lambda p: figures.disk_figure(ch, p))
            self.figure("failure", lambda p: figures.failure_figure(ch, p))
            self.figure("nichols", lambda p: figures.nichols_figure(ch, p))
            self.figure("nyquist", lambda p: figures.nyquist_figure(ch, p, model))
        else:
            self.parts.append("<p>no sweep yet: no frequency-domain figure.</p>")
        if ch.manoeuvres and model is not None:
            self.figure("time", lambda p: figures.time_figure(ch, p, model, self.runs, self.seed))
        else:
            reason = "no model to simulate" if ch.manoeuvres else "no doublet found in the flight (fly one, "\
                     "separated by at least 8 s from the sweeps)"
            self.parts.append(f"<p class='note'>time domain: {html.escape(reason)}.</p>")
        if has_frequency and ch.diagnosis and model is not None:
            self.figure("diagnosis", lambda p: figures.diagnosis_figure(ch, p, model))
        if self.versions:
            self.figure("history", lambda p: figures.history_figure(ch.name, self.versions, p))


    def draw_mimo(self) -> None:
        """A MIMO channel: Bode matrix, kappa(w), singular values (and the history, if any)."""
        ch = self.ch
        if ch.frequency_rad_s is not None and len(ch.frequency_rad_s) and ch.mimo.measured is not None:
            self.figure("mimo_bode", lambda p: figures.mimo_bode_figure(ch, p))
            self.figure("mimo_kappa", lambda p: figures.mimo_kappa_figure(ch, p))
            self.figure("mimo_sv", lambda p: figures.mimo_singular_values_figure(ch, p))
        else:
            self.parts.append("<p>no sweep yet: no frequency-domain figure.</p>")
        if self.versions:
            self.figure("history", lambda p: figures.history_figure(ch.name, self.versions, p))


def write_report(result: ValidationResult, directory: str | os.PathLike, *, runs: int = 500, seed: int = 0,
                 warn: Callable[[str], None] | None = None, plan: TestCard | str | None = None) -> Path:
    """Write ``index.html`` and the figures of every channel into ``directory``; return the HTML path.

    Parameters
    ----------
    result : ValidationResult
        From a replay, the node, the library or :meth:`ValidationResult.from_json_dict`.
    directory : path
        Created when missing.
    runs : int
        Monte Carlo runs per doublet (paper: 500).
    seed : int
        Seed of the Monte Carlo sampling (the report is reproducible).
    warn : callable, optional
        Called with a one-line message for each figure that could not be drawn.
    plan : TestCard or str, optional
        The test card of these results (:func:`gap_validation.report.card.plan_for`): per channel its
        manoeuvres beside the bands without a verdict, shaded on the Bode figure; a str: one line saying why
        it is unavailable; None: not planned (the report says how to plan it).
    """
    directory = Path(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise DataError(f"{directory}: cannot create report directory ({err.strerror or err})") from None
    when = datetime.now(timezone.utc).isoformat(timespec="seconds")
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>gap_validation report</title>",
             f"<style>{_STYLE}</style></head><body>", "<h1>Model validation in the gap metric</h1>",
             f"<p class='note'>config: {html.escape(str(result.config_source or '-'))}; data: "
             f"{html.escape(', '.join(result.sources) or '-')}; written {when}</p>",
             "<h2>Summary (paper Table 1)</h2>", table1_html(result), "<h3>Verdict</h3><ul>"]
    verdicts = {name: verdict(ch) for name, ch in result.channels.items()}
    for name, ch in result.channels.items():
        text, cls = verdicts[name]
        parts.append(f"<li class='verdict {cls}'><b>{html.escape(ch.name)}</b>: {html.escape(text)}</li>")
    parts += ["</ul>", details_html(result), card.summary_html(result, plan)]
    problems = []
    for index, (name, ch) in enumerate(result.channels.items()):
        drawer = _Channel(ch, _slug(name, index), directory, list(result.history.get(name) or []), runs, seed,
                          card.planned_spans(plan, name))
        drawer.draw_all()
        text, cls = verdicts[name]
        parts.append(f"<h2 id='{html.escape(drawer.stem, quote=True)}'>{html.escape(name)}</h2>")
        parts.append(f"<p class='verdict {cls}'>{html.escape(text)}</p>")
        parts.append(f"<p>model: {html.escape(ch.model_description or '-')}</p>")
        if ch.message:
            parts.append(f"<p>{html.escape(ch.message)}</p>")
        for warning in ch.warnings:
            parts.append(f"<p class=\"warn\">Warning: {html.escape(warning)}</p>")
        if ch.diagnosis:
            parts.append("<ol>" + "".join(f"<li>{html.escape(str(d.sentence or d.effect))}</li>"
                                          for d in ch.diagnosis[:3]) + "</ol>")
        parts.append(card.channel_html(name, ch, plan))
        parts += drawer.parts
        problems += drawer.problems
    parts.append(f"<p class='note'>{html.escape(NUGAP_DATA_NOTE)}.</p></body></html>")
    index = directory / "index.html"
    try:
        atomic_write_text(index, "\n".join(parts))
    except OSError as err:
        raise DataError(f"{index}: cannot write the report ({err.strerror or err})") from None
    for problem in problems:
        (warn or log.warning)(problem)
    return index
