"""Result dataclasses: what every front end (JSON, terminal table, report, diagnostics) renders.

``ValidationResult.to_json_dict()`` produces the JSON contract of DESIGN.md ("JSON results"); keys may be
added, never renamed. Non-finite numbers become ``null``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gap_validation.core.margins import Margins, margins_from_epsilon, margins_note

#: Note attached to every measured nu-gap: on frequency data the winding-number condition cannot be checked.
NUGAP_DATA_NOTE = ("nu-gap on measured frequency points assumes the winding-number condition holds "
                   "(as the paper does for rigid-body aircraft)")


def _num(value: Any) -> float | None:
    """A JSON-safe float: ``None`` for None, NaN and infinities."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _list(values: Any) -> list:
    return [_num(v) for v in np.asarray(values, dtype=float).ravel()] if values is not None else []


def phase_deg(response: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
    """Unwrapped phase [deg]; with ``reference``, on the same branch as the reference's unwrapped phase
    (phase of the reference plus the unwrapped phase of response/reference), so that curves overlay."""
    response = np.asarray(response, dtype=complex)
    if reference is None:
        return np.degrees(_unwrap_finite(np.angle(response)))
    reference = np.asarray(reference, dtype=complex)
    with np.errstate(divide="ignore", invalid="ignore"):
        relative = _unwrap_finite(np.angle(response / reference))
    return np.degrees(_unwrap_finite(np.angle(reference)) + relative)


def _unwrap_finite(angle_rad: np.ndarray) -> np.ndarray:
    """``np.unwrap`` over the finite entries only (NaN stays NaN at its own index instead of every later one)."""
    ok = np.isfinite(angle_rad)
    if ok.all() or angle_rad.ndim != 1:
        return np.unwrap(angle_rad)
    out = np.full(angle_rad.shape, np.nan)
    out[ok] = np.unwrap(angle_rad[ok])
    return out


def _mag_phase(response: np.ndarray | None, reference: np.ndarray | None = None) -> dict:
    if response is None or len(response) == 0:
        return {"magnitude_db": [], "phase_deg": []}
    response = np.asarray(response, dtype=complex)
    with np.errstate(divide="ignore"):
        mag = 20.0 * np.log10(np.abs(response))
    return {"magnitude_db": _list(mag), "phase_deg": _list(phase_deg(response, reference))}


@dataclass
class SweepResult:
    """Validation of one sweep's (raw) estimate."""

    start_s: float
    end_s: float
    epsilon: float | None
    worst_frequency_rad_s: float | None
    points_used: int

    def to_json_dict(self) -> dict:
        return {"start_s": _num(self.start_s), "end_s": _num(self.end_s), "epsilon": _num(self.epsilon),
                "worst_frequency_rad_s": _num(self.worst_frequency_rad_s), "points_used": self.points_used}


@dataclass
class ChannelResult:
    """Model against measurement for one channel (DESIGN.md JSON keys in ``to_json_dict``)."""

    name: str
    sweeps: int = 0
    nu_gap: float | None = None
    nu_gap_frequency_rad_s: float | None = None
    epsilon: float | None = None
    worst_frequency_rad_s: float | None = None
    epsilon_raw: float | None = None
    epsilon_raw_frequency_rad_s: float | None = None
    margins: Margins = field(default_factory=lambda: margins_from_epsilon(float("nan")))
    margins_raw: Margins = field(default_factory=lambda: margins_from_epsilon(float("nan")))
    coherence_threshold: float = 0.6
    frequency_rad_s: np.ndarray | None = None
    coherence: np.ndarray | None = None
    random_error: np.ndarray | None = None
    kappa: np.ndarray | None = None
    epsilon_per_frequency: np.ndarray | None = None
    measured: np.ndarray | None = None            # complex averaged estimate
    model: np.ndarray | None = None               # complex model response
    confident: np.ndarray | None = None           # bool: coherence passes the threshold
    points_excluded: int = 0
    limited_by: str = "none"
    frequency_flags: list[str] = field(default_factory=list)
    bands: list[dict] = field(default_factory=list)
    diagnosis: list[dict] = field(default_factory=list)
    sweep_results: list[SweepResult] = field(default_factory=list)
    sweep_measured: list[np.ndarray] = field(default_factory=list)   # complex raw estimate per sweep (plots)
    bad_samples: dict[str, int] = field(default_factory=dict)
    epsilon_previous: float | None = None
    model_description: str = ""
    message: str = ""

    @property
    def points_used(self) -> int:
        return int(np.count_nonzero(self.confident)) if self.confident is not None else 0

    def to_json_dict(self) -> dict:
        """The channel's JSON object (DESIGN.md keys first, extensions after)."""
        out = {
            "nu_gap": _num(self.nu_gap),
            "epsilon": _num(self.epsilon),
            "epsilon_raw": _num(self.epsilon_raw),
            "worst_frequency_rad_s": _num(self.worst_frequency_rad_s),
            **self.margins.to_json_dict(),
            "sweeps": int(self.sweeps),
            "limited_by": self.limited_by,
            "frequency_rad_s": _list(self.frequency_rad_s),
            "coherence": _list(self.coherence),
            "kappa": _list(self.kappa),
            "epsilon_per_frequency": _list(self.epsilon_per_frequency),
            "measured": _mag_phase(self.measured, self.model),
            "model": _mag_phase(self.model),
            "diagnosis": list(self.diagnosis),
            # extensions
            "nu_gap_frequency_rad_s": _num(self.nu_gap_frequency_rad_s),
            "epsilon_raw_frequency_rad_s": _num(self.epsilon_raw_frequency_rad_s),
            "margins_raw": self.margins_raw.to_json_dict(),
            "margins_note": margins_note(self.epsilon),     # why the margins are null (None when given)
            "coherence_threshold": self.coherence_threshold,
            "points_used": self.points_used,
            "points_excluded": int(self.points_excluded),
            "random_error": _list(self.random_error),
            "frequency_flags": list(self.frequency_flags),
            "bands": list(self.bands),
            "raw_sweeps": [s.to_json_dict() for s in self.sweep_results],
            "bad_samples": dict(self.bad_samples),
            "epsilon_previous": _num(self.epsilon_previous),
            "model_description": self.model_description,
            "message": self.message,
            "nu_gap_note": NUGAP_DATA_NOTE,
        }
        return out


@dataclass
class ValidationResult:
    """Results of all channels, in config order."""

    channels: dict[str, ChannelResult]
    config_source: str | None = None
    sources: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def to_json_dict(self) -> dict:
        return {
            "channels": {name: ch.to_json_dict() for name, ch in self.channels.items()},
            "config": self.config_source,
            "sources": list(self.sources),
            "notes": list(self.notes),
        }
