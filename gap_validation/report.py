"""HTML report of a validation: the paper's figures per channel and Table 1 (front end; uses matplotlib).

Per channel, three figures:

* Bode overlay (paper Fig. 4): model, each sweep's raw estimate lightly, the average darkly, coherence below
  with the threshold;
* where it fails: kappa(w) and epsilon(w) (eqs. 13, 14) with the random-error band of the data, points
  coloured by their flag (ok, model-limited, data-limited, excluded by coherence);
* perturbation plane (paper Fig. 5): P2/P1 per frequency with the epsilon disks of the raw and averaged data.

``write_report(result, directory)`` writes ``index.html`` and the PNG files and returns the HTML path.
"""
from __future__ import annotations

import html
import os
from pathlib import Path

import numpy as np

from gap_validation.core.errors import DataError
from gap_validation.core.results import ChannelResult, ValidationResult, phase_deg
from gap_validation.render import fmt

_FLAG_COLOURS = {"ok": "tab:green", "model": "tab:red", "data": "tab:orange", "excluded": "0.7"}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _db(x: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return 20.0 * np.log10(np.abs(x))


def bode_figure(ch: ChannelResult, path: Path) -> None:
    """Model vs measurement with coherence (paper Fig. 4)."""
    plt = _pyplot()
    w = ch.frequency_rad_s
    fig, (ax_m, ax_p, ax_c) = plt.subplots(3, 1, sharex=True, figsize=(7, 7.5),
                                           gridspec_kw={"height_ratios": [2, 2, 1]})
    for raw in ch.sweep_measured:
        ax_m.semilogx(w, _db(raw), color="tab:blue", alpha=0.25, lw=0.8)
        ax_p.semilogx(w, phase_deg(raw, ch.model), color="tab:blue", alpha=0.25, lw=0.8)
    ax_m.semilogx(w, _db(ch.measured), color="tab:blue", lw=2, label="flight data (average)")
    ax_p.semilogx(w, phase_deg(ch.measured, ch.model), color="tab:blue", lw=2)
    ax_m.semilogx(w, _db(ch.model), "k--", lw=1.5, label="model")
    ax_p.semilogx(w, phase_deg(ch.model), "k--", lw=1.5)
    ax_c.semilogx(w, ch.coherence, color="tab:blue", lw=1.5)
    ax_c.axhline(ch.coherence_threshold, color="0.5", ls=":", label="threshold")
    ax_m.set_ylabel("magnitude [dB]")
    ax_p.set_ylabel("phase [deg]")
    ax_c.set_ylabel("coherence")
    ax_c.set_ylim(0, 1.05)
    ax_c.set_xlabel("frequency [rad/s]")
    ax_m.legend(loc="best", fontsize=8)
    ax_m.set_title(f"{ch.name}: model vs flight data ({ch.sweeps} sweeps)")
    for ax in (ax_m, ax_p, ax_c):
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def failure_figure(ch: ChannelResult, path: Path) -> None:
    """kappa(w) and epsilon(w) with flags and the data's random-error level (where it fails)."""
    plt = _pyplot()
    w = ch.frequency_rad_s
    fig, ax = plt.subplots(figsize=(7, 3.8))
    ax.semilogx(w, ch.epsilon_per_frequency, color="0.3", lw=1, label="epsilon(w), eq. 14")
    ax.semilogx(w, ch.kappa, color="tab:purple", lw=1, ls="--", label="kappa(w), eq. 13")
    if ch.random_error is not None and len(ch.random_error):
        ax.fill_between(w, 0, np.clip(ch.random_error / 2, 0, 1), color="tab:blue", alpha=0.15,
                        label="random error of the data / 2")
    flags = ch.frequency_flags or ["ok"] * len(w)
    for flag, colour in _FLAG_COLOURS.items():
        sel = np.array([f == flag for f in flags])
        if np.any(sel):
            ax.scatter(w[sel], ch.epsilon_per_frequency[sel], color=colour, s=18, zorder=3, label=flag)
    if ch.epsilon is not None:
        ax.axhline(ch.epsilon, color="tab:red", ls=":", lw=1, label=f"epsilon = {ch.epsilon:.3f}")
    ax.set_xlabel("frequency [rad/s]")
    ax.set_ylabel("distance")
    ax.set_ylim(0, min(1.05, max(0.2, float(np.nanmax(ch.epsilon_per_frequency)) * 1.15)))
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    ax.set_title(f"{ch.name}: where the model fails (limited by: {ch.limited_by})")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _disk(ax, eps: float, **kwargs) -> None:
    """The epsilon disk (eq. 14): centre (1+e^2)/(1-e^2), radius 2e/(1-e^2) on the P2/P1 plane."""
    if eps is None or not 0 < eps < 1:
        return
    centre, radius = (1 + eps**2) / (1 - eps**2), 2 * eps / (1 - eps**2)
    theta = np.linspace(0, 2 * np.pi, 200)
    ax.fill(centre + radius * np.cos(theta), radius * np.sin(theta), **kwargs)


def disk_figure(ch: ChannelResult, path: Path) -> None:
    """Perturbations P2/P1 and the epsilon disks (paper Fig. 5)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(4.8, 4.8))
    _disk(ax, ch.epsilon_raw, color="tab:blue", alpha=0.12, label="raw epsilon disk")
    _disk(ax, ch.epsilon, color="tab:blue", alpha=0.35, label="averaged epsilon disk")
    ok = ch.confident if ch.confident is not None else np.ones(len(ch.frequency_rad_s), bool)
    for raw in ch.sweep_measured:
        ratio = raw / ch.model
        ax.plot(ratio.real[ok], ratio.imag[ok], ".", color="0.6", ms=3)
    ratio = ch.measured / ch.model
    ax.plot(ratio.real[ok], ratio.imag[ok], "o", color="tab:blue", ms=4, label="averaged data")
    ax.plot([1], [0], "k+", ms=10)
    ax.set_aspect("equal")
    ax.set_xlabel("Re P2/P1")
    ax.set_ylabel("Im P2/P1")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title(f"{ch.name}: perturbations and epsilon disks")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _table_html(result: ValidationResult) -> str:
    head = ["", *result.channels]
    rows = [
        ("epsilon (average)", [fmt(c.epsilon) for c in result.channels.values()]),
        ("epsilon (raw)", [fmt(c.epsilon_raw) for c in result.channels.values()]),
        ("nu-gap", [fmt(c.nu_gap) for c in result.channels.values()]),
        ("gain margin, dB", [fmt(c.margins.gain_margin_db, ".2f") for c in result.channels.values()]),
        ("phase margin, deg", [fmt(c.margins.phase_margin_deg, ".2f") for c in result.channels.values()]),
        ("disk margin", [fmt(c.margins.disk_margin, ".2f") for c in result.channels.values()]),
        ("worst frequency, rad/s", [fmt(c.worst_frequency_rad_s, ".2f") for c in result.channels.values()]),
        ("sweeps", [str(c.sweeps) for c in result.channels.values()]),
        ("limited by", [c.limited_by for c in result.channels.values()]),
    ]
    out = ["<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"]
    for label, cells in rows:
        out.append(f"<tr><th>{html.escape(label)}</th>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells)
                   + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def write_report(result: ValidationResult, directory: str | os.PathLike) -> Path:
    """Write ``index.html`` and the figures of every channel into ``directory``; return the HTML path."""
    directory = Path(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise DataError(f"{directory}: cannot create report directory ({err.strerror or err})") from None
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>gap_validation report</title>",
             "<style>body{font-family:sans-serif;max-width:1000px;margin:auto}table{border-collapse:collapse}"
             "td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}</style></head><body>",
             "<h1>Model validation in the gap metric</h1>",
             f"<p>config: {html.escape(str(result.config_source))}; data: "
             f"{html.escape(', '.join(result.sources) or '-')}</p>", _table_html(result)]
    for name, ch in result.channels.items():
        parts.append(f"<h2>{html.escape(name)}</h2>")
        parts.append(f"<p>model: {html.escape(ch.model_description)}</p>")
        for sentence in ([ch.message] if ch.message else []) + [d.get("sentence", "") for d in ch.diagnosis[:3]]:
            if sentence:
                parts.append(f"<p>{html.escape(sentence)}</p>")
        if ch.frequency_rad_s is None or len(ch.frequency_rad_s) == 0:
            parts.append("<p>no sweep yet: nothing to plot</p>")
            continue
        for kind, draw in (("bode", bode_figure), ("failure", failure_figure), ("disk", disk_figure)):
            png = directory / f"{name}_{kind}.png"
            draw(ch, png)
            parts.append(f"<img src='{png.name}' alt='{html.escape(name)} {kind}'>")
    parts.append("</body></html>")
    index = directory / "index.html"
    index.write_text("\n".join(parts), encoding="utf-8")
    return index
