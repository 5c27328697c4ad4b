"""The paper's figures for one channel's results (front end: matplotlib, Agg backend, PNG files).

Each ``*_figure(ch, path, ...)`` draws one figure of a :class:`~gap_validation.core.results.ChannelResult`
and saves it atomically to ``path``:

* :func:`bode_figure`: model and measured response, each sweep light, the average dark, coherence below with
  the excluded low-coherence points marked (paper Fig. 4);
* :func:`disk_figure`: perturbations P2/P1 in the complex plane with the raw and averaged epsilon disks, the
  gain-margin markers on the real axis and the phase-margin tangents (Figs. 1 right and 5);
* :func:`failure_figure`: kappa(w) and epsilon(w) (eqs. 13, 14) with the thresholds, the worst frequency
  and the model-limited / data-limited bands;
* :func:`nichols_figure`: the ellipse the epsilon disk forms around the critical point in the Nichols plane,
  inside the standard (6 dB, 45 deg) exclusion region, with the measured perturbations (Fig. 2 left);
* :func:`nyquist_figure`: robust Nyquist diagram, the tube of epsilon disks around the model containing the
  data, and the critical point (Fig. 2 right);
* :func:`time_figure`: doublets from the flight against the model inside the tube of Monte Carlo runs of
  the uncertain model, with the TIC (Fig. 6, eqs. 1 and 3);
* :func:`diagnosis_figure`: Bode of the data, the model and the model with each top candidate effect;
* :func:`history_figure`: epsilon over model versions.
"""
from __future__ import annotations

import math
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from gap_validation.core.atomic import atomic_open
from gap_validation.core.margins import STANDARD_EPSILON, STANDARD_MARGINS, WARN_EPSILON, margins_from_epsilon
from gap_validation.core.results import Candidate, ChannelResult, phase_deg
from gap_validation.core.uncertainty import monte_carlo_tube, time_domain_check

_FLAG_COLOURS = {
    "ok": "tab:green",
    "model": "tab:red",
    "data": "tab:orange",
    "excluded": "0.7",
    "not_excited": "0.88",
}
_BAND_COLOURS = {"model": "tab:red", "data": "tab:orange"}


def pyplot():
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> None:
    """Save as PNG atomically (temporary file, then rename): a crash never leaves a half-written image."""
    try:
        with atomic_open(path, "wb") as handle:
            fig.savefig(handle, dpi=90, format="png")
    finally:
        pyplot().close(fig)


def _finish(fig, ax, path: Path, title: str, fontsize: float = 6.5, **legend) -> None:
    """Grid, legend and title of a one-axes figure, then save it."""
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=fontsize, **legend)
    ax.set_title(title)
    fig.tight_layout()
    _save(fig, path)


def _db(x) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return 20.0 * np.log10(np.abs(x))


def _confident(ch: ChannelResult) -> np.ndarray:
    n = len(ch.frequency_rad_s)
    return ch.confident if ch.confident is not None and len(ch.confident) == n else np.ones(n, bool)


def _worst_index(ch: ChannelResult) -> int:
    """Index of the grid point at the worst frequency."""
    return int(np.argmin(np.abs(ch.frequency_rad_s - ch.worst_frequency_rad_s)))


def _dense(ch: ChannelResult, count: int = 400) -> np.ndarray:
    w = ch.frequency_rad_s
    return np.geomspace(float(np.min(w)), float(np.max(w)), count)


def disk_geometry(eps: float) -> tuple[float, float]:
    """Centre and radius of the epsilon disk of P2/P1 (eq. 14): (1+e^2)/(1-e^2) and 2e/(1-e^2)."""
    return (1 + eps * eps) / (1 - eps * eps), 2 * eps / (1 - eps * eps)


def disk_boundary(eps: float, count: int = 361) -> np.ndarray:
    """Points of the boundary of the epsilon disk of P2/P1 (complex), for 0 < eps < 1."""
    centre, radius = disk_geometry(eps)
    return centre + radius * np.exp(1j * np.linspace(0.0, 2 * np.pi, count))


def _square_limits(ax, points: np.ndarray, pad: float = 0.12, minimum: float = 0.05) -> None:
    """Equal-aspect limits around the finite ``points`` (complex), at least ``minimum`` wide."""
    points = points[np.isfinite(points)]
    if points.size == 0:
        return
    cx, cy = (points.real.max() + points.real.min()) / 2, (points.imag.max() + points.imag.min()) / 2
    half = max(float(np.ptp(points.real)), float(np.ptp(points.imag)), minimum) * (0.5 + pad)
    ax.set_xlim(cx - half, cx + half)
    ax.set_ylim(cy - half, cy + half)
    ax.set_aspect("equal", adjustable="box")


def _when(t_s: float) -> str:
    """A stamp in words: UTC clock time for epoch stamps, else seconds."""
    if t_s > 1e8:
        return datetime.fromtimestamp(t_s, timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
    return f"{t_s:.1f} s"


def _usable(eps) -> bool:
    return eps is not None and 0.0 < eps < 1.0


# ------------------------------------------------------------------------------------------ Fig. 4
def _span_edges(w: np.ndarray, low: float, high: float) -> tuple[float, float]:
    """A band of grid frequencies widened to the geometric midpoints with its neighbours (a band of one
    frequency stays visible), within the grid."""
    w = np.asarray(w, float)
    i, j = int(np.argmin(np.abs(w - low))), int(np.argmin(np.abs(w - high)))
    left = math.sqrt(w[i - 1] * w[i]) if i > 0 else w[i]
    right = math.sqrt(w[j] * w[j + 1]) if j + 1 < w.size else w[j]
    return float(left), float(right)


def bode_figure(ch: ChannelResult, path: Path, model=None, planned=()) -> None:
    """Model vs measurement with coherence (paper Fig. 4); excluded (not confident) points marked; the bands
    the test card's manoeuvres would close (``planned``: (low, high) grid frequencies [rad/s]) shaded.

    Parameters
    ----------
    ch : ChannelResult
        The channel.
    path : Path
        The image written.
    model : LinearModel, optional
        The model, drawn on a dense grid (default: the channel's model at the measured frequencies).
    planned : sequence of (float, float)
        Bands the test card's manoeuvres would close [rad/s].
    """
    plt = pyplot()
    w = ch.frequency_rad_s
    ok = _confident(ch)
    fig, (ax_m, ax_p, ax_c) = plt.subplots(3, 1, sharex=True, figsize=(7, 7.5),
                                           gridspec_kw={"height_ratios": [2, 2, 1]})
    for i, raw in enumerate(ch.sweep_measured):
        label = "each sweep (raw)" if i == 0 else None
        ax_m.semilogx(w, _db(raw), color="tab:blue", alpha=0.25, lw=0.8, label=label)
        ax_p.semilogx(w, phase_deg(raw, ch.model), color="tab:blue", alpha=0.25, lw=0.8)
    ph_meas = phase_deg(ch.measured, ch.model)
    ax_m.semilogx(w, _db(ch.measured), color="tab:blue", lw=2, label="flight data (average)")
    ax_p.semilogx(w, ph_meas, color="tab:blue", lw=2)
    if model is not None:
        wd = _dense(ch)
        p = model.freqresp(wd)
        ax_m.semilogx(wd, _db(p), "k--", lw=1.5, label="model")
        ax_p.semilogx(wd, phase_deg(p, p), "k--", lw=1.5)
    else:
        ax_m.semilogx(w, _db(ch.model), "k--", lw=1.5, label="model")
        ax_p.semilogx(w, phase_deg(ch.model), "k--", lw=1.5)
    ax_c.semilogx(w, ch.coherence, color="tab:blue", lw=1.5)
    low = ~ok & (np.asarray(ch.coherence, float) < ch.coherence_threshold)
    for mask, label, colour in ((low, "excluded (low coherence)", "tab:red"),
                                (~ok & ~low, "excluded (too few degrees of freedom)", "tab:purple")):
        if np.any(mask & np.isfinite(_db(ch.measured))):
            kw = dict(marker="x", color=colour, ls="none", ms=6)
            ax_m.plot(w[mask], _db(ch.measured)[mask], label=label, **kw)
            ax_p.plot(w[mask], ph_meas[mask], **kw)
            ax_c.plot(w[mask], ch.coherence[mask], **kw)
    ax_c.axhline(ch.coherence_threshold, color="0.5", ls=":")
    for k, (low, high) in enumerate(planned):
        left, right = _span_edges(w, low, high)
        for ax in (ax_m, ax_p, ax_c):
            ax.axvspan(left, right, color="tab:olive", alpha=0.15, lw=0,
                       label="planned manoeuvre (test card)" if k == 0 and ax is ax_m else None)
    ax_m.set_ylabel("magnitude [dB]")
    ax_p.set_ylabel("phase [deg]")
    ax_c.set_ylabel("coherence [-]")
    ax_c.set_ylim(0, 1.05)
    ax_c.set_xlabel("frequency [rad/s]")
    ax_m.legend(loc="best", fontsize=7)
    ax_m.set_title(f"{ch.name}: model vs flight data ({ch.sweeps} sweeps)")
    for ax in (ax_m, ax_p, ax_c):
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    _save(fig, path)


# ------------------------------------------------------------------------------------------ Figs. 1, 5
def _fill_disk(ax, eps, **kwargs) -> None:
    if _usable(eps):
        b = disk_boundary(eps)
        ax.fill(b.real, b.imag, **kwargs)


def disk_figure(ch: ChannelResult, path: Path) -> None:
    """Perturbations P2/P1 and the epsilon disks, gain-margin markers and phase-margin tangents (Figs. 1, 5).

    Parameters
    ----------
    ch : ChannelResult
        The channel.
    path : Path
        The image written.
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8.4, 5.2))
    _fill_disk(
        ax, ch.epsilon_raw, color="tab:blue", alpha=0.12, label=f"raw epsilon disk ({_fmt(ch.epsilon_raw)})"
    )
    _fill_disk(
        ax, ch.epsilon, color="tab:blue", alpha=0.35, label=f"averaged epsilon disk ({_fmt(ch.epsilon)})"
    )
    ok = _confident(ch)
    for i, raw in enumerate(ch.sweep_measured):
        ratio = raw / ch.model
        ax.plot(ratio.real[ok], ratio.imag[ok], ".", color="0.6", ms=3, label="raw data" if i == 0 else None)
    ratio = ch.measured / ch.model
    ax.plot(ratio.real[ok], ratio.imag[ok], "o", color="tab:blue", ms=4, label="averaged data")
    if ch.worst_frequency_rad_s is not None:
        k = _worst_index(ch)
        ax.plot(ratio.real[k], ratio.imag[k], "o", mfc="none", mec="tab:red", ms=11,
                label=f"worst: {ch.worst_frequency_rad_s:.3g} rad/s")
    m = margins_from_epsilon(ch.epsilon) if _usable(ch.epsilon) else None
    if m is not None:
        ax.plot([m.lower_disk_marker, m.upper_disk_marker], [0, 0], "|", color="k", ms=14, mew=2,
                label=f"gain-margin markers {m.lower_disk_marker:.2f}, {m.upper_disk_marker:.2f} "
                      f"(+-{m.gain_margin_db:.2f} dB)")
        theta = 2.0 * math.atan(ch.epsilon)        # tangent points from the origin lie on the unit circle
        for sign in (1, -1):
            ax.plot(
                [0, 1.15 * math.cos(theta)], [0, sign * 1.15 * math.sin(theta)], color="k", lw=0.8, ls="--"
            )
            ax.plot(math.cos(theta), sign * math.sin(theta), "kD", ms=5)
        ax.plot([], [], "k--", lw=0.8, label=f"phase tangents +-{math.degrees(theta):.1f} deg\n"
                                             f"(eq. 16 asks {m.phase_margin_deg:.1f} deg)")
    ax.plot([1], [0], "k+", ms=10)
    ax.axhline(0, color="0.6", lw=0.6)
    shown = [ratio[ok]] + [raw[ok] / ch.model[ok] for raw in ch.sweep_measured]
    shown += [disk_boundary(e) for e in (ch.epsilon, ch.epsilon_raw) if _usable(e)]
    _square_limits(ax, np.concatenate(shown + [np.array([1.0 + 0j])]))
    ax.set_xlabel("Re P2/P1 [-]")
    ax.set_ylabel("Im P2/P1 [-]")
    _finish(fig, ax, path, f"{ch.name}: perturbations and epsilon disks", fontsize=7, loc="upper left",
            bbox_to_anchor=(1.02, 1.0))


# ------------------------------------------------------------------------------------------ where it fails
def failure_figure(ch: ChannelResult, path: Path) -> None:
    """kappa(w), epsilon(w), thresholds, worst frequency and model-/data-limited bands."""
    plt = pyplot()
    w = ch.frequency_rad_s
    fig, ax = plt.subplots(figsize=(7, 4.0))
    labelled = set()
    for band in ch.bands:
        kind = band.limited_by
        colour = _BAND_COLOURS.get(kind)
        if colour and band.min_rad_s is not None:
            lo, hi = float(band.min_rad_s), float(band.max_rad_s)
            if hi <= lo:
                lo, hi = lo / 1.05, hi * 1.05
            ax.axvspan(lo, hi, color=colour, alpha=0.12, lw=0,
                       label=None if kind in labelled else f"{kind}-limited band")
            labelled.add(kind)
    ax.semilogx(w, ch.epsilon_per_frequency, color="0.3", lw=1, label="epsilon(w), eq. 14")
    ax.semilogx(w, ch.kappa, color="tab:purple", lw=1, ls="--", label="kappa(w), eq. 13")
    if ch.random_error is not None and len(ch.random_error) == len(w):
        ax.fill_between(w, 0, np.clip(ch.random_error / 2, 0, 1), color="tab:blue", alpha=0.15,
                        label="random error of the data / 2")
    flags = ch.frequency_flags if len(ch.frequency_flags) == len(w) else ["ok"] * len(w)
    for flag, colour in _FLAG_COLOURS.items():
        sel = np.array([f == flag for f in flags])
        if np.any(sel):
            ax.scatter(w[sel], ch.epsilon_per_frequency[sel], color=colour, s=18, zorder=3, label=flag)
    ax.axhline(STANDARD_EPSILON, color="tab:red", ls=":", lw=1,
               label=f"{STANDARD_EPSILON:g}: standard margins (6 dB, 45 deg)")
    ax.axhline(
        WARN_EPSILON, color="tab:orange", ls=":", lw=1, label=f"{WARN_EPSILON:g}: warning (4.4 dB, 29 deg)"
    )
    if ch.worst_frequency_rad_s is not None and ch.epsilon is not None:
        ax.axvline(ch.worst_frequency_rad_s, color="k", lw=0.8, ls="--")
        right = ch.worst_frequency_rad_s > math.sqrt(float(np.min(w)) * float(np.max(w)))
        ax.annotate(
            f"worst {ch.worst_frequency_rad_s:.3g} rad/s\nepsilon {ch.epsilon:.3f}",
            (ch.worst_frequency_rad_s, min(ch.epsilon, 1.0)),
            fontsize=7,
            xytext=(-5 if right else 5, -25),
            textcoords="offset points",
            ha="right" if right else "left",
        )
    top = float(np.nanmax(ch.epsilon_per_frequency)) if np.any(np.isfinite(ch.epsilon_per_frequency)) else 1.0
    ax.set_ylim(0, min(1.05, max(0.45, top * 1.15)))
    ax.set_xlabel("frequency [rad/s]")
    ax.set_ylabel("distance [-]")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6.5, ncol=2, loc="upper left")
    ax.set_title(f"{ch.name}: where the model fails (limited by: {ch.limited_by})")
    fig.tight_layout()
    _save(fig, path)


# ------------------------------------------------------------------------------------------ Fig. 2
def nichols_coordinates(ratio) -> tuple[np.ndarray, np.ndarray]:
    """Phase [deg] and gain [dB] of the loop perturbation ``-ratio`` (the critical point -1 maps to -180,
    0)."""
    ratio = np.asarray(ratio, dtype=complex)
    return -180.0 + np.degrees(np.angle(ratio)), _db(ratio)


def nichols_figure(ch: ChannelResult, path: Path) -> None:
    """The epsilon disk as an ellipse around the critical point, in the standard exclusion region (Fig. 2)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 4.6))
    gm, pm = STANDARD_MARGINS
    ax.plot([-180 - pm, -180 + pm, -180 + pm, -180 - pm, -180 - pm], [-gm, -gm, gm, gm, -gm], "k--", lw=1.2,
            label=f"standard exclusion region ({gm:.0f} dB, {pm:.0f} deg)")
    for eps, alpha, label in ((ch.epsilon_raw, 0.15, "raw"), (ch.epsilon, 0.4, "averaged")):
        if _usable(eps):
            ph, g = nichols_coordinates(disk_boundary(eps))
            ax.fill(ph, g, color="tab:blue", alpha=alpha, label=f"{label} epsilon {eps:.3f}")
    if ch.measured is not None and ch.model is not None:
        ok = _confident(ch)
        ph, g = nichols_coordinates(ch.measured / ch.model)
        ax.plot(ph[ok], g[ok], "o", color="tab:blue", ms=3, label="measured perturbations")
        if ch.worst_frequency_rad_s is not None:
            k = _worst_index(ch)
            ax.plot(ph[k], g[k], "o", mfc="none", mec="tab:red", ms=11,
                    label=f"worst: {ch.worst_frequency_rad_s:.3g} rad/s")
    ax.plot([-180], [0], "r+", ms=12, mew=2)
    if not _usable(ch.epsilon):
        ax.text(0.02, 0.04, "epsilon >= 1: no guaranteed margins", transform=ax.transAxes, color="tab:red")
    ax.set_xlim(-180 - 2 * pm, -180 + 2 * pm)
    ax.set_ylim(-2 * gm, 2 * gm)
    ax.set_xlabel("loop phase [deg]")
    ax.set_ylabel("loop gain [dB]")
    _finish(fig, ax, path, f"{ch.name}: required margins in the Nichols plane", loc="upper left")


def nyquist_figure(ch: ChannelResult, path: Path, model=None) -> None:
    """Robust Nyquist diagram: the tube of epsilon disks around the model, the data and -1 (Fig. 2 right)."""
    plt = pyplot()
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Circle

    fig, ax = plt.subplots(figsize=(6, 5.4))
    wd = _dense(ch, 300) if model is not None else ch.frequency_rad_s
    p1 = model.freqresp(wd) if model is not None else ch.model
    if _usable(ch.epsilon):
        centre, radius = disk_geometry(ch.epsilon)
        discs = [Circle((c.real, c.imag), r) for c, r in zip(p1 * centre, np.abs(p1) * radius)]
        ax.add_collection(PatchCollection(discs, facecolor="#c6dbef", edgecolor="none", zorder=1))
        ax.plot([], [], color="#c6dbef", lw=8, label=f"uncertainty tube (epsilon {ch.epsilon:.3f})")
    else:
        ax.text(0.02, 0.04, "epsilon >= 1: no uncertainty tube (no guarantee)", transform=ax.transAxes,
                color="tab:red")
    ax.plot(p1.real, p1.imag, "k--", lw=1.5, label="model", zorder=3)
    ok = _confident(ch)
    ax.plot(
        ch.measured.real[ok],
        ch.measured.imag[ok],
        "o",
        color="tab:blue",
        ms=3,
        label="flight data (average)",
        zorder=4,
    )
    if ch.worst_frequency_rad_s is not None:
        k = _worst_index(ch)
        for point in (ch.measured[k], ch.model[k]):
            ax.plot(point.real, point.imag, "o", mfc="none", mec="tab:red", ms=11, zorder=5)
        ax.plot([], [], "o", mfc="none", mec="tab:red", label=f"worst: {ch.worst_frequency_rad_s:.3g} rad/s")
    ax.plot([-1], [0], "r+", ms=14, mew=2, label="critical point -1", zorder=6)
    _square_limits(ax, np.concatenate((p1, ch.measured[ok], [-1.0 + 0j])), minimum=1.0)
    ax.set_xlabel("Re P [(rad/s)/rad]")
    ax.set_ylabel("Im P [(rad/s)/rad]")
    _finish(fig, ax, path, f"{ch.name}: robust Nyquist diagram", loc="best")


# ------------------------------------------------------------------------------------------ Fig. 6
def time_figure(ch: ChannelResult, path: Path, model, runs: int = 500, seed: int = 0) -> None:
    """Doublets of the flight against the model and the Monte Carlo tube of the uncertain model (Fig. 6);
    each title gives the TIC (eqs. 1, 3) and the share of the flight samples inside the tube."""
    plt = pyplot()
    shown = ch.manoeuvres[:3]
    fig, axes = plt.subplots(len(shown), 1, figsize=(7, 3.0 * len(shown)), squeeze=False)
    band = ((float(np.min(ch.frequency_rad_s)), float(np.max(ch.frequency_rad_s)))
            if ch.frequency_rad_s is not None and len(ch.frequency_rad_s) else (0.5, 100.0))
    for ax, m in zip(axes[:, 0], shown):
        check = time_domain_check(model, m)
        t = check.t_s - check.t_s[0]
        inside = None
        if _usable(ch.epsilon):
            tube = monte_carlo_tube(
                model, ch.epsilon, check.t_s, check.u, count=runs, band_rad_s=band, rng=seed
            )
            ax.fill_between(
                t,
                np.degrees(tube.lower),
                np.degrees(tube.upper),
                color="tab:blue",
                alpha=0.2,
                lw=0,
                label=f"{runs} Monte Carlo runs (epsilon {ch.epsilon:.3f})",
            )
            inside = tube.fraction_inside(check.y_flight)
        ax.plot(t, 5 * np.degrees(check.u), color="tab:green", lw=1, label="surface x5 [deg]")
        ax.plot(t, np.degrees(check.y_flight), color="tab:blue", lw=2, label="flight")
        ax.plot(t, np.degrees(check.y_model), "k--", lw=1.5, label="model")
        tube_text = f", {100 * inside:.0f} % inside the tube" if inside is not None else \
            ", no tube (epsilon >= 1)"
        ax.set_title(f"{ch.name} {m.kind} at {_when(m.start_s)}: TIC {check.tic:.3f}, input-augmented "
                     f"{check.tic_input_augmented:.3f}{tube_text}", fontsize=8)
        ax.set_ylabel("rate [deg/s]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=6.5, loc="upper right")
    axes[-1, 0].set_xlabel("time from the manoeuvre window start [s]")
    fig.tight_layout()
    _save(fig, path)


# ------------------------------------------------------------------------------------------ diagnosis,
# history
def candidate_model(model, candidate: Candidate):
    """The model with a diagnosis candidate applied (its effects appended, or its refitted model)."""
    from gap_validation.core.models import LinearModel

    if candidate.model:
        return LinearModel.from_spec(candidate.model)
    return model.with_effects(candidate.effects)


def at_flown_amplitude(model, ch: ChannelResult):
    """A model with an amplitude-dependent effect (``rate_limit``, ``backlash``) at the mean input amplitude
    of the channel's sweeps (JSON ``input_amplitudes``; unknown: the effect drawn as absent); others as they
    are."""
    if not getattr(model, "nonlinear", False):
        return model
    amplitudes = [a for a in ch.input_amplitudes if np.isfinite(a) and a > 0]
    return model.at_amplitude(float(np.mean(amplitudes)) if amplitudes else float("nan"))


def diagnosis_figure(ch: ChannelResult, path: Path, model) -> None:
    """Bode of the averaged data, the model, and the model with each of the top three candidates."""
    plt = pyplot()
    w = ch.frequency_rad_s
    wd = _dense(ch)
    ok = _confident(ch)
    fig, (ax_m, ax_p) = plt.subplots(2, 1, sharex=True, figsize=(7, 6))
    p0 = model.freqresp(wd)
    ax_m.semilogx(w[ok], _db(ch.measured)[ok], "o", color="tab:blue", ms=3, label="flight data (average)")
    ax_p.semilogx(w[ok], phase_deg(ch.measured, ch.model)[ok], "o", color="tab:blue", ms=3)
    ax_m.semilogx(wd, _db(p0), "k--", lw=1.5, label=f"model: epsilon {_fmt(ch.epsilon)}")
    ax_p.semilogx(wd, phase_deg(p0), "k--", lw=1.5)
    for candidate, colour in zip(ch.diagnosis[:3], ("tab:red", "tab:green", "tab:purple")):
        p = at_flown_amplitude(candidate_model(model, candidate), ch).freqresp(wd)
        label = f"+ {candidate.effect or '?'}: epsilon {_fmt(candidate.epsilon)}"
        ax_m.semilogx(wd, _db(p), color=colour, lw=1.3, label=label)
        ax_p.semilogx(wd, phase_deg(p, p0), color=colour, lw=1.3)
    ax_m.set_ylabel("magnitude [dB]")
    ax_p.set_ylabel("phase [deg]")
    ax_p.set_xlabel("frequency [rad/s]")
    ax_m.legend(fontsize=7)
    ax_m.set_title(f"{ch.name}: candidate effects, before and after")
    for ax in (ax_m, ax_p):
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    _save(fig, path)


def history_figure(name: str, versions: list[dict], path: Path) -> None:
    """Epsilon (averaged, and raw where known) per model version, oldest first: watch it fall."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 3.6))
    x = np.arange(len(versions))
    eps = [v.get("epsilon") for v in versions]
    ax.plot(
        x, [np.nan if e is None else e for e in eps], "o-", color="tab:blue", lw=2, label="epsilon (average)"
    )
    raw = [v.get("epsilon_raw") for v in versions]
    if any(r is not None for r in raw):
        ax.plot(x, [np.nan if r is None else r for r in raw], "s:", color="tab:blue", alpha=0.5,
                label="epsilon (raw)")
    ax.axhline(
        STANDARD_EPSILON, color="tab:red", ls=":", lw=1, label=f"{STANDARD_EPSILON:g}: standard margins"
    )
    ax.set_yscale("log")
    ax.set_xticks(x)
    ax.set_xticklabels([_short(v.get("model_description") or f"v{i + 1}") for i, v in enumerate(versions)],
                       rotation=15, ha="right", fontsize=7)
    ax.set_ylabel("epsilon [-]")
    ax.set_xlabel("model version")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title(f"{name}: epsilon over model versions")
    fig.tight_layout()
    _save(fig, path)


def _short(text: str, width: int = 40) -> str:
    return text if len(text) <= width else text[: width - 3] + "..."


def _fmt(value) -> str:
    return "-" if value is None or not np.isfinite(value) else f"{value:.3g}"


# ------------------------------------------------------------------------------------------ MIMO channels
def _element_names(detail) -> tuple[list[str], list[str]]:
    """Short names of a MIMO channel's inputs and outputs (the field, without the topic)."""
    short = lambda text: text.split(" ", 1)[-1]  # noqa: E731
    return [short(n) for n in detail.inputs], [short(n) for n in detail.outputs]


def mimo_bode_figure(ch: ChannelResult, path: Path) -> None:
    """A MIMO channel's Bode matrix: per element (row: output, column: input) the model and the measured
    magnitude (confident points filled) and phase, and the element's partial coherence below."""
    plt = pyplot()
    detail = ch.mimo
    p, m = detail.shape
    w = ch.frequency_rad_s
    conf = _confident(ch)
    inputs, outputs = _element_names(detail)
    fig, axes = plt.subplots(3 * p, m, figsize=(4.2 * m, 2.1 * 3 * p), sharex=True, squeeze=False,
                             gridspec_kw={"height_ratios": [2, 1.4, 0.9] * p})
    for i in range(p):
        for j in range(m):
            mag, pha, coh = axes[3 * i, j], axes[3 * i + 1, j], axes[3 * i + 2, j]
            model, meas = detail.model[:, i, j], detail.measured[:, i, j]
            mag.semilogx(w, _db(model), color="k", lw=1.2, label="model")
            mag.semilogx(w, _db(meas), color="tab:blue", lw=0.8, alpha=0.6)
            mag.scatter(w[conf], _db(meas)[conf], color="tab:blue", s=8, label="flight (confident)")
            mag.scatter(w[~conf], _db(meas)[~conf], color="tab:blue", s=10, marker="x", alpha=0.6,
                        label="excluded")
            pha.semilogx(w, phase_deg(model), color="k", lw=1.2)
            pha.semilogx(w, phase_deg(meas, model), color="tab:blue", lw=0.8, marker=".", ms=3)
            coh.semilogx(w, detail.partial_coherence[:, i, j], color="tab:green", lw=1,
                         label="partial coherence")
            coh.semilogx(w, detail.multiple_coherence[:, i], color="0.5", lw=0.8, ls="--",
                         label="multiple coherence of the output")
            coh.axhline(ch.coherence_threshold, color="tab:red", ls=":", lw=0.8)
            coh.set_ylim(0, 1.05)
            mag.set_title(f"{_short(inputs[j], 24)} -> {_short(outputs[i], 24)}", fontsize=8)
            mag.set_ylabel("dB", fontsize=7)
            pha.set_ylabel("deg", fontsize=7)
            coh.set_ylabel("coh.", fontsize=7)
            for ax in (mag, pha, coh):
                ax.grid(True, which="both", alpha=0.3)
                ax.tick_params(labelsize=6.5)
            if i == 0 and j == 0:
                mag.legend(fontsize=6)
                coh.legend(fontsize=5.5, loc="lower left")
    for j in range(m):
        axes[-1, j].set_xlabel("frequency [rad/s]", fontsize=7)
    fig.suptitle(f"{ch.name}: Bode matrix, model against flight (rows: outputs, columns: inputs)", fontsize=9)
    fig.tight_layout()
    _save(fig, path)


def mimo_kappa_figure(ch: ChannelResult, path: Path) -> None:
    """A MIMO channel's kappa(w) (Vinnicombe's MIMO chordal distance) with its noise scale, the threshold, the
    model- and data-limited bands, the nu-gap and the element that dominates where it fails."""
    plt = pyplot()
    w, kappa, detail = ch.frequency_rad_s, np.asarray(ch.kappa, float), ch.mimo
    fig, ax = plt.subplots(figsize=(7, 4.0))
    labelled = set()
    for band in ch.bands:
        colour = _BAND_COLOURS.get(band.limited_by)
        if colour:
            lo, hi = float(band.min_rad_s), float(band.max_rad_s)
            if hi <= lo:
                lo, hi = lo / 1.05, hi * 1.05
            ax.axvspan(lo, hi, color=colour, alpha=0.12, lw=0,
                       label=None if band.limited_by in labelled else f"{band.limited_by}-limited band")
            labelled.add(band.limited_by)
    ax.semilogx(w, kappa, color="tab:purple", lw=1.2, label="kappa(w), MIMO chordal distance")
    if detail.kappa_noise is not None and len(detail.kappa_noise) == len(w):
        ax.fill_between(w, 0, np.clip(detail.kappa_noise, 0, 1), color="tab:blue", alpha=0.15,
                        label="noise scale of kappa (random error of H)")
    flags = ch.frequency_flags if len(ch.frequency_flags) == len(w) else ["ok"] * len(w)
    for flag, colour in _FLAG_COLOURS.items():
        sel = np.array([f == flag for f in flags])
        if np.any(sel):
            ax.scatter(w[sel], kappa[sel], color=colour, s=18, zorder=3, label=flag)
    from gap_validation.core.mimo import KAPPA_THRESHOLD

    ax.axhline(
        KAPPA_THRESHOLD, color="tab:orange", ls=":", lw=1, label=f"{KAPPA_THRESHOLD:g}: band threshold"
    )
    if ch.nu_gap is not None:
        ax.axvline(ch.nu_gap_frequency_rad_s, color="k", lw=0.8, ls="--")
        text = f"nu-gap {ch.nu_gap:.3f} at {ch.nu_gap_frequency_rad_s:.3g} rad/s"
        if detail.worst_elements and ch.limited_by == "model":
            top = detail.worst_elements[0]
            inputs, outputs = _element_names(detail)
            text += (f"\nfails most: {inputs[top['input_index']]} -> {outputs[top['output_index']]} "
                     f"at {detail.worst_elements_frequency_rad_s:.3g} rad/s")
        ax.set_title(f"{ch.name}: where the model fails (limited by: {ch.limited_by})\n{text}", fontsize=8.5)
    top = float(np.nanmax(kappa)) if np.any(np.isfinite(kappa)) else 1.0
    ax.set_ylim(0, min(1.05, max(0.3, top * 1.15)))
    ax.set_xlabel("frequency [rad/s]")
    ax.set_ylabel("kappa [-]")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6.5, ncol=2, loc="upper left")
    fig.tight_layout()
    _save(fig, path)


def mimo_singular_values_figure(ch: ChannelResult, path: Path) -> None:
    """Singular values of the model's and the measured response matrices over frequency (dB)."""
    plt = pyplot()
    w, detail = ch.frequency_rad_s, ch.mimo
    conf = _confident(ch)
    fig, ax = plt.subplots(figsize=(7, 4.0))
    model, meas = detail.singular_values("model"), detail.singular_values("measured")
    for k in range(model.shape[1]):
        ax.semilogx(w, _db(model[:, k]), color="k", lw=1.2, ls="-" if k == 0 else "--",
                    label=f"model sigma_{k + 1}")
        ax.semilogx(w, _db(meas[:, k]), color="tab:blue", lw=0.8, alpha=0.6, ls="-" if k == 0 else "--")
        ax.scatter(w[conf], _db(meas[:, k])[conf], color="tab:blue", s=8, marker="o" if k == 0 else "s",
                   label=f"flight sigma_{k + 1} (confident)")
    ax.set_xlabel("frequency [rad/s]")
    ax.set_ylabel("singular value [dB]")
    _finish(fig, ax, path, f"{ch.name}: singular values of model and flight data")
