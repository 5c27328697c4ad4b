"""Terminal rendering of results: tables and plain sentences (no colour codes, no ROS)."""
from __future__ import annotations

import json
import os

from gap_validation.core.atomic import atomic_open
from gap_validation.core.errors import DataError
from gap_validation.core.results import ChannelResult, ValidationResult


def write_json(data: dict, path: str | os.PathLike) -> None:
    """Write ``data`` as JSON atomically (:mod:`gap_validation.core.atomic`: temporary file, then rename).

    Parameters
    ----------
    data : dict
        JSON-able data (no NaN).
    path : str or PathLike
        The file written.

    Raises
    ------
    DataError
        One line naming the file when it cannot be written (the old file, if any, is kept).
    """
    try:
        with atomic_open(path, "w") as fh:
            json.dump(data, fh, indent=1, allow_nan=False)
            fh.write("\n")
    except OSError as err:
        raise DataError(f"{path}: cannot write JSON ({err.strerror or err})") from None


def fmt(value, spec: str = ".3f", none: str = "-") -> str:
    """Format a number, or ``none`` for missing values."""
    return none if value is None else format(value, spec)


def duration_text(seconds: float) -> str:
    """A flight time for people: ``2 min 52 s``, or ``45 s`` under a minute.

    Parameters
    ----------
    seconds : float
        The time [s].
    """
    return f"{int(seconds // 60)} min {seconds % 60:02.0f} s" if seconds >= 60 else f"{seconds:.0f} s"


def table(headers: list[str], rows: list[list[str]]) -> str:
    """A plain left/right aligned text table (first column left, the others right).

    Parameters
    ----------
    headers : list of str
        Column titles.
    rows : list of list of str
        The cells.
    """
    widths = [max(len(str(r[i])) for r in [headers, *rows]) for i in range(len(headers))]
    lines = []
    for r in [headers, *rows]:
        cells = [str(c).ljust(widths[0]) if i == 0 else str(c).rjust(widths[i]) for i, c in enumerate(r)]
        lines.append("  ".join(cells).rstrip())
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _epsilon_cell(ch: ChannelResult) -> str:
    cell = fmt(ch.epsilon)
    if ch.epsilon_previous is not None and ch.epsilon is not None:
        cell = f"{fmt(ch.epsilon_previous)}->{cell}"
    return cell


def _band_cell(ch: ChannelResult) -> str:
    """``chirp 1-40``: the kind flown and the band it excited [rad/s]."""
    if ch.excited_band_rad_s is None:
        return ch.excitation or "-"
    lo, hi = ch.excited_band_rad_s
    return f"{ch.excitation or ''} {lo:.3g}-{hi:.3g}".strip()


def channel_sentences(ch: ChannelResult) -> list[str]:
    """Plain sentences about one channel: status, where it fails, the top diagnosis, the warnings."""
    out = []
    if ch.message:
        out.append(ch.message)
    out.extend(f"warning: {w}" for w in ch.warnings)
    if ch.diagnosis:
        top = ch.diagnosis[0]
        text = top.sentence or f"missing: {top.effect}"
        if text not in ch.message:
            out.append(text)
    q = ch.dynamic_pressure_ratio
    if q:
        clipped = f"; {q['clipped']} samples beyond 0.25-4 clipped" if q.get("clipped") else ""
        out.append(
            f"flown at {q['min']:.2f}-{q['max']:.2f} of the model's dynamic pressure (mean {q['mean']:.2f}, "
            f"from the airspeed): the surfaces scaled to the model's{clipped}"
        )
    bad = sum(ch.bad_samples.values())
    if bad:
        reasons = ", ".join(f"{k} x{v}" for k, v in sorted(ch.bad_samples.items()))
        out.append(f"{bad} bad samples skipped ({reasons})")
    return out


def format_table(result: ValidationResult) -> str:
    """The per-channel validation table (paper Table 1 layout, one row per channel) and sentences."""
    headers = ["channel", "nu-gap", "epsilon", "eps raw", "GM dB", "PM deg", "disk", "worst rad/s", "sweeps",
               "excited rad/s", "excluded", "limited by"]
    rows = []
    for name, ch in result.channels.items():
        n_points = len(ch.frequency_rad_s) if ch.frequency_rad_s is not None else 0
        # a MIMO channel: the frequency of its nu-gap (epsilon is a SISO notion), its shape after the name
        worst = ch.nu_gap_frequency_rad_s if ch.mimo is not None else ch.worst_frequency_rad_s
        label = f"{name} ({ch.mimo.shape[0]}x{ch.mimo.shape[1]})" if ch.mimo is not None else name
        mark = "*" if ch.margins.guaranteed and ch.margins_caveat else ""
        rows.append(
            [
                label,
                fmt(ch.nu_gap),
                _epsilon_cell(ch),
                fmt(ch.epsilon_raw),
                fmt(ch.margins.gain_margin_db, ".2f") + mark,
                fmt(ch.margins.phase_margin_deg, ".1f") + mark,
                fmt(ch.margins.disk_margin, ".3f") + mark,
                fmt(worst, ".2f"),
                str(ch.sweeps),
                _band_cell(ch),
                f"{ch.points_excluded}/{n_points}",
                ch.limited_by,
            ]
        )
    lines = [table(headers, rows)]
    if any(ch.nu_gap is not None for ch in result.channels.values()):
        lines.append(
            "  nu-gap and epsilon over the measured band (the winding-number condition assumed, as in "
            "the paper); excited rad/s: where the flight excited the input"
        )
    for name, ch in result.channels.items():
        for sentence in channel_sentences(ch):
            lines.append(f"  {name}: {sentence}")
    if any(ch.epsilon is not None and ch.epsilon >= 1 for ch in result.channels.values()):
        lines.append("  epsilon >= 1: no stability guarantee, margins not given")
    held = [name for name, ch in result.channels.items() if ch.margins_guaranteed]
    doubtful = [
        (name, ch) for name, ch in result.channels.items() if ch.margins.guaranteed and ch.margins_caveat
    ]
    if held:
        which = "" if len(held) == len(result.channels) else f" ({', '.join(held)})"
        lines.append(
            f"  margins from epsilon (eqs. 15-17){which}: a controller with these gain/phase/disk margins "
            "on the model is guaranteed stable on the aircraft, if the mismatch outside the measured band "
            "is no larger"
        )
    for name, ch in doubtful:
        lines.append(f"  * {name}: margins NOT guaranteed: {ch.margins_caveat}")
    return "\n".join(lines)
