"""``DIR/index.html`` of a campaign: the fleet at a glance, the trends in words, and per aircraft and channel
epsilon and every diagnosed parameter over date (front end; plain HTML and PNG files, opens offline).

Sections: the findings (trends real against the flights' random error, one sentence each), the fleet table
(per aircraft and channel: flights, dates, the latest epsilon and diagnosis, the epsilon trend), the fleet's
epsilon over date per channel, then per aircraft its channels' trend figures, and last every flight. Every
name from a manifest, config or bag is HTML-escaped; a figure that cannot be drawn costs only itself (a note
and a warning). Files are written atomically.
"""
from __future__ import annotations

import hashlib
import html
import json
import logging
import re
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

from gap_validation.campaign import trend_figures
from gap_validation.campaign.findings import EPSILON, Finding, format_value
from gap_validation.campaign.results import CampaignOutcome, FlightOutcome
from gap_validation.core.atomic import atomic_write_text
from gap_validation.core.errors import DataError, one_line
from gap_validation.core.trends import FAMILY_ALPHA, MIN_FLIGHTS
from gap_validation.report.terminal import fmt

log = logging.getLogger(__name__)

__all__ = ["write_index"]

_STYLE = ("body{font-family:sans-serif;max-width:1100px;margin:auto;padding:0 1em}"
          "table{border-collapse:collapse;margin:0.5em 0;font-size:0.9em}td,th{border:1px solid #ccc;"
          "padding:3px 7px;text-align:right}th{background:#f4f4f4}td.l,th.l{text-align:left}.bad{color:#b00}"
          ".ok{color:#070}figure{margin:1em 0}figcaption{font-size:0.85em;color:#444}img{max-width:100%}"
          ".note{font-size:0.85em;color:#666}li.finding{margin:0.2em 0}td.d{white-space:nowrap}")


def _e(text) -> str:
    return html.escape(str(text))


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", text).strip("_")[:40] or "x"


#: Changes when the figures' drawing changes (every figure is then drawn again once).
FIGURE_VERSION = 3
_FIGURE_FILE = re.compile(r"^(trend|fleet)_[A-Za-z0-9_]*-[0-9a-f]{12}\.png$")


def _figure_key(findings: list[Finding], *extra: str) -> str:
    """12 hex of a hash of everything a figure shows: a figure whose data did not change is not drawn
    again."""
    data = [FIGURE_VERSION, *extra] + [dict(f.to_json_dict(), dates=[d.isoformat() for d in f.series.dates],
                                            values=f.series.values) for f in findings]
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()[:12]


class _Figures:
    """Draws figures into the campaign directory, named by their content (a re-run reuses the unchanged ones);
    a failure becomes a note and a warning."""

    def __init__(self, directory: Path):
        self.directory = directory
        self.problems: list[str] = []
        self.names: set[str] = set()
        self.drawn = 0

    def draw(self, stem: str, caption: str, findings: list[Finding], draw: Callable[[Path], None]) -> str:
        name = f"{stem}-{_figure_key(findings, stem, caption)}.png"
        path = self.directory / name
        try:
            if not path.is_file():
                draw(path)
                self.drawn += 1
        except Exception as err:  # noqa: BLE001 -- one figure never costs the page
            self.problems.append(f"{path}: figure not drawn ({one_line(err)})")
            return f"<p class='note'>{_e(caption)}: figure not drawn ({_e(one_line(err))}).</p>"
        self.names.add(name)
        return (f"<figure><img src='{_e(name)}' alt='{_e(caption)}'>"
                f"<figcaption>{_e(caption)}</figcaption></figure>")

    def prune(self) -> None:
        """Remove the figures of earlier runs that the page no longer shows."""
        for path in self.directory.glob("*.png"):
            if _FIGURE_FILE.match(path.name) and path.name not in self.names:
                path.unlink(missing_ok=True)


def _groups(findings: list[Finding]) -> dict[tuple[str, str], list[Finding]]:
    groups: dict[tuple[str, str], list[Finding]] = {}
    for f in findings:
        groups.setdefault((f.series.aircraft, f.series.channel), []).append(f)
    return groups


def _latest(outcomes: list[FlightOutcome], aircraft: str, channel: str) -> tuple[FlightOutcome, dict] | None:
    done = [o for o in outcomes if o.flight.aircraft == aircraft and channel in o.channels]
    if not done:
        return None
    last = max(done, key=lambda o: o.flight.date)
    return last, last.channels[channel]


def _trend_cell(finding: Finding | None) -> str:
    if finding is None or finding.trend is None:
        return f"<td class='note'>fewer than {MIN_FLIGHTS} flights</td>"
    rate, error, unit = finding.rate_per_week()
    text = (f"{'+' if rate >= 0 else '-'}{format_value(abs(rate))} &plusmn; {format_value(error)}"
            f"{' ' + _e(unit) if unit else ''} (p = {finding.trend.p_value:.1g})")
    return f"<td class='{'bad' if finding.significant else 'ok'}'>{text}</td>"


def _diagnosis_text(summary: dict) -> str:
    top = summary.get("diagnosis")
    if not top:
        return "none"
    return str(top.get("sentence") or top.get("effect"))


def _fleet_table(outcome: CampaignOutcome, groups) -> str:
    rows = ["<table><tr><th class='l'>aircraft</th><th class='l'>channel</th><th>flights</th><th>first</th>"
            "<th>last</th><th>epsilon (last)</th><th>epsilon per week</th><th class='l'>drifting</th>"
            "<th class='l'>diagnosis (last flight)</th></tr>"]
    for (aircraft, channel), findings in groups.items():
        eps = next((f for f in findings if f.series.quantity == EPSILON), None)
        dates = sorted({d for f in findings for d in f.series.dates})
        latest = _latest(outcome.flights, aircraft, channel)
        summary = latest[1] if latest else {}
        drifting = ", ".join(f.label[0] for f in findings if f.significant) or "-"
        rows.append(f"<tr><td class='l'>{_e(aircraft)}</td><td class='l'>{_e(channel)}</td>"
                    f"<td>{len(eps.series.values) if eps else 0}</td>"
                    f"<td class='d'>{dates[0]:%Y-%m-%d}</td><td class='d'>{dates[-1]:%Y-%m-%d}</td>"
                    f"<td>{fmt(summary.get('epsilon'))}</td>{_trend_cell(eps)}"
                    f"<td class='l {'bad' if drifting != '-' else ''}'>{_e(drifting)}</td>"
                    f"<td class='l'>{_e(_diagnosis_text(summary))}</td></tr>")
    rows.append("</table>")
    return "".join(rows)


def _flight_rows(outcome: CampaignOutcome) -> str:
    rows = [
        "<table><tr><th class='l'>flight</th><th class='l'>aircraft</th><th>date</th><th class='l'>tags</th>"
        "<th class='l'>channel</th><th>epsilon</th><th>nu-gap</th><th>limited by</th><th>sweeps</th>"
        "<th class='l'>top diagnosis</th><th class='l'>status</th></tr>"
    ]
    for o in sorted(outcome.flights, key=lambda o: (o.flight.aircraft, o.flight.date)):
        f = o.flight
        link = _e(f.name)
        if o.results_path is not None:
            link = f"<a href='{_e(o.results_path.relative_to(outcome.out_dir).as_posix())}'>{link}</a>"
        status = o.status + (": " + "; ".join(o.errors) if o.errors else "")
        head = (
            f"<td class='l'>{link}</td><td class='l'>{_e(f.aircraft)}</td><td "
            f"class='d'>{_e(f.date_text)}</td>"
            f"<td class='l'>{_e(', '.join(f.tags))}</td>"
        )
        tail = f"<td class='l {'bad' if o.errors else ''}'>{_e(status)}</td>"
        if not o.channels:
            rows.append(f"<tr>{head}<td colspan='6'></td>{tail}</tr>")
        for name, ch in o.channels.items():
            top = ch.get("diagnosis") or {}
            params = ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                               for k, v in (top.get("parameters") or {}).items() if not isinstance(v, list))
            diag = f"{top.get('effect')} ({params})" if top and params else (top.get("effect") or "-")
            rows.append(f"<tr>{head}<td class='l'>{_e(name)}</td><td>{fmt(ch.get('epsilon'))}</td>"
                        f"<td>{fmt(ch.get('nu_gap'))}</td><td>{_e(ch.get('limited_by') or '-')}</td>"
                        f"<td>{ch.get('sweeps', 0)}</td><td class='l'>{_e(diag)}</td>{tail}</tr>")
    rows.append("</table>")
    return "".join(rows)


def _findings_html(findings: list[Finding]) -> str:
    real = [f for f in findings if f.significant]
    tested = sum(1 for f in findings if f.trend is not None)
    method = (f"A trend is real when its slope stands out of the flights' random error about the line: least "
              f"squares over date, Student's t on the residual scatter, Holm over all {tested} trends tested "
              f"(family-wise {FAMILY_ALPHA:.0%} false alarms), at least {MIN_FLIGHTS} flights.")
    if not real:
        body = "<p class='ok'>No real trend: every quantity is flat within the flights' random error.</p>"
    else:
        body = "<ul>" + "".join(f"<li class='finding bad'>{_e(f.sentence())}</li>" for f in real) + "</ul>"
    return f"<h2 id='findings'>Findings</h2>{body}<p class='note'>{_e(method)}</p>"


def _aircraft_sections(outcome: CampaignOutcome, groups, figures: _Figures, origin: datetime) -> list[str]:
    parts = []
    aircraft = list(dict.fromkeys(a for a, _ in groups))
    for i, name in enumerate(aircraft):
        parts.append(f"<h2 id='aircraft{i}'>{_e(name)}</h2>")
        for j, ((a, channel), findings) in enumerate(groups.items()):
            if a != name:
                continue
            parts.append(f"<h3>{_e(name)} {_e(channel)}</h3><ul>")
            parts += [f"<li class='finding {'bad' if f.significant else ''}'>{_e(f.sentence())}</li>"
                      for f in findings]
            parts.append("</ul>")
            caption = (
                f"{name} {channel}: epsilon and each diagnosed parameter over date; red line: a real trend, "
                f"grey dashes: within the flights' random error"
            )
            stem = f"trend_{i}_{j}_{_slug(name)}_{_slug(channel)}"
            parts.append(figures.draw(stem, caption, findings,
                                      lambda p, fs=findings: trend_figures.trend_figure(fs, origin, p)))
    return parts


def write_index(outcome: CampaignOutcome, warn: Callable[[str], None] | None = None) -> Path:
    """Write ``index.html`` and its figures into the campaign directory; return the HTML path.

    Raises
    ------
    DataError
        One line naming the file when the page cannot be written.
    """
    directory = outcome.out_dir
    figures = _Figures(directory)
    findings = list(outcome.findings)
    groups = _groups(findings)
    when = datetime.now(timezone.utc).isoformat(timespec="seconds")
    counts = ", ".join(f"{outcome.count(s)} {s}" for s in ("validated", "reused", "failed"))
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>gap_validation campaign</title>",
        f"<style>{_STYLE}</style></head><body><h1>Campaign: model validation across the fleet</h1>",
        f"<p class='note'>manifest: {_e(outcome.manifest.source)}; {len(outcome.flights)} flights ({counts}) "
        f"of {len(outcome.manifest.aircraft)} aircraft; written {when}; results: "
        f"<a href='campaign.json'>campaign.json</a>, <a href='campaign.csv'>campaign.csv</a></p>",
    ]
    if outcome.errors:
        parts.append("<h2 id='errors'>Errors</h2><ul>" +
                     "".join(f"<li class='bad'>{_e(e)}</li>" for e in outcome.errors) + "</ul>")
    parts.append(_findings_html(findings))
    parts += ["<h2 id='fleet'>Fleet</h2>", _fleet_table(outcome, groups) if groups else
              "<p>No flight validated.</p>"]
    origin = min((d for f in findings for d in f.series.dates), default=datetime(1970, 1, 1))
    channels = list(dict.fromkeys(c for _, c in groups))
    for k, channel in enumerate(channels):
        eps = [f for f in findings if f.series.channel == channel and f.series.quantity == EPSILON]
        if eps:
            parts.append(
                figures.draw(
                    f"fleet_{k}_{_slug(channel)}",
                    f"{channel}: epsilon over date, every aircraft",
                    eps,
                    lambda p, fs=eps, c=channel: trend_figures.fleet_figure(fs, c, p),
                )
            )
    parts += _aircraft_sections(outcome, groups, figures, origin)
    parts += ["<h2 id='flights'>Flights</h2>", _flight_rows(outcome), "</body></html>"]
    index = directory / "index.html"
    try:
        atomic_write_text(index, "\n".join(parts))
    except OSError as err:
        raise DataError(f"{index}: cannot write the campaign index ({err.strerror or err})") from None
    figures.prune()
    for problem in figures.problems:
        (warn or log.warning)(problem)
    return index

