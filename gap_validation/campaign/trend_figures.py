"""Figures of a campaign's trends (front end: matplotlib, Agg backend, PNG written atomically).

* :func:`trend_figure`: one aircraft's channel over date, a panel per quantity (epsilon on a log axis, then
  each diagnosed parameter), each flight a point, the least-squares line red when the trend is real, grey and
  dashed when it is within the flights' random error;
* :func:`fleet_figure`: epsilon over date of every aircraft for one channel (log axis).
"""
from __future__ import annotations

from datetime import datetime, timedelta
from pathlib import Path
from typing import Sequence

import numpy as np

from gap_validation.campaign.findings import Finding, format_value
from gap_validation.core.atomic import atomic_open
from gap_validation.report.figures import pyplot

__all__ = ["trend_figure", "fleet_figure"]


def _save(fig, path: Path) -> None:
    plt = pyplot()
    try:
        with atomic_open(path, "wb") as handle:
            fig.savefig(handle, dpi=90, format="png")
    finally:
        plt.close(fig)


def _margins(fig, top_in: float) -> None:
    """Fixed margins in inches (room for the title, the y label and the slanted dates): a tenth of the time of
    ``tight_layout``, which draws the figure twice."""
    width, height = fig.get_size_inches()
    fig.subplots_adjust(
        left=0.85 / width,
        right=1 - 0.15 / width,
        top=1 - top_in / height,
        bottom=0.85 / height,
        hspace=0.5 / max(1.0, (height - 1.2) / len(fig.axes)),
    )


def _log_axis(ax) -> None:
    """A log y axis labelled 0.4, 0.6, 1, 2 (not 4x10^-1); minor ticks labelled when it spans under a
    decade."""
    from matplotlib import ticker

    ax.set_yscale("log")
    plain = ticker.FuncFormatter(lambda value, _: f"{value:g}")
    low, high = ax.get_ylim()
    ax.yaxis.set_major_formatter(plain)
    ax.yaxis.set_minor_formatter(plain if high < 10 * low else ticker.NullFormatter())


def _ylabel(finding: Finding) -> str:
    words, unit, _ = finding.label
    return f"{words} [{unit}]" if unit else words


def _line(ax, finding: Finding, origin: datetime) -> None:
    trend = finding.trend
    if trend is None:
        return
    days = np.linspace(trend.first_day, trend.last_day, 50)
    dates = [origin + timedelta(days=float(d)) for d in days]
    values = [finding.fitted(float(d)) for d in days]
    rate, _, unit = finding.rate_per_week()
    label = f"{'+' if rate >= 0 else '-'}{format_value(abs(rate))}{' ' + unit if unit else ''}/week " \
            f"(p = {trend.p_value:.1g})"
    if finding.significant:
        ax.plot(dates, values, "-", color="tab:red", lw=2, label=f"trend {label}")
    else:
        ax.plot(dates, values, "--", color="0.6", lw=1, label=f"no real trend ({label})")


def trend_figure(findings: Sequence[Finding], origin: datetime, path: Path) -> None:
    """One panel per finding (same aircraft and channel), shared date axis; saved to ``path``."""
    plt = pyplot()
    n = len(findings)
    fig, axes = plt.subplots(n, 1, figsize=(7.5, 1.2 + 2.1 * n), sharex=True, squeeze=False)
    first = findings[0].series
    fig.suptitle(f"{first.aircraft} {first.channel}: over the campaign")
    for ax, finding in zip(axes[:, 0], findings):
        _, _, scale = finding.label
        s = finding.series
        ax.plot(
            s.dates,
            [v * scale for v in s.values],
            "o",
            color="tab:red" if finding.significant else "tab:blue",
            ms=5,
            label="flights",
        )
        _line(ax, finding, origin)
        if finding.log:
            _log_axis(ax)
        ax.set_ylabel(_ylabel(finding))
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=8)
    axes[-1, 0].set_xlabel("date")
    fig.autofmt_xdate()
    _margins(fig, top_in=0.5)
    _save(fig, path)


def fleet_figure(findings: Sequence[Finding], channel: str, path: Path) -> None:
    """Epsilon over date of every aircraft (``findings``: epsilon findings of ``channel``); saved to
    ``path``."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 3.6))
    for finding in findings:
        s = finding.series
        style = dict(lw=2.2, color="tab:red") if finding.significant else dict(lw=1, alpha=0.8)
        ax.plot(s.dates, s.values, "o-", ms=4, label=s.aircraft + (" (trend)" if finding.significant else ""),
                **style)
    _log_axis(ax)
    ax.set_title(f"{channel}: epsilon over date, every aircraft")
    ax.set_ylabel("epsilon")
    ax.set_xlabel("date")
    ax.grid(True, alpha=0.3)
    if len(findings) <= 12:
        ax.legend(loc="best", fontsize=8, ncol=2)
    fig.autofmt_xdate()
    _margins(fig, top_in=0.35)
    _save(fig, path)
