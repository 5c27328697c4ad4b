"""Result dataclasses: what every front end (JSON, terminal table, report, diagnostics) renders.

``ValidationResult.to_json_dict()`` produces the JSON contract of DESIGN.md ("JSON results"); keys may be
added, never renamed. Non-finite numbers become ``null``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gap_validation.core.manoeuvres import Manoeuvre
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


def _complex(mag_phase: dict | None) -> np.ndarray | None:
    """Inverse of :func:`_mag_phase` (null entries become NaN)."""
    if not mag_phase or not mag_phase.get("magnitude_db"):
        return None
    mag = _array(mag_phase["magnitude_db"])
    phase = _array(mag_phase["phase_deg"])
    return 10.0 ** (mag / 20.0) * np.exp(1j * np.radians(phase))


def _array(values) -> np.ndarray | None:
    """A float array from a JSON list (null -> NaN); None for a missing or empty list."""
    if not values:
        return None
    return np.array([np.nan if v is None else v for v in values], dtype=float)


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

    @classmethod
    def from_json_dict(cls, data: dict) -> "SweepResult":
        return cls(_float(data.get("start_s")), _float(data.get("end_s")), data.get("epsilon"),
                   data.get("worst_frequency_rad_s"), int(data.get("points_used") or 0))


def _float(value) -> float:
    return float("nan") if value is None else float(value)


def _manoeuvre_json(m: Manoeuvre, check: dict | None, samples: bool = True) -> dict:
    """A kept manoeuvre: its TIC against the model and its samples (so a report can be drawn from the JSON)."""
    dt = float(m.t_s[1] - m.t_s[0]) if m.t_s.size > 1 else 0.0
    out = {"kind": m.kind, "start_s": _num(m.start_s), "end_s": _num(m.end_s)}
    out.update({key: _num(value) for key, value in (check or {}).items()})
    if not samples:
        return out
    out.update({"t0_s": _num(m.t_s[0]) if m.t_s.size else None, "dt_s": dt, "trim_samples": int(m.trim_samples),
                "input": _list(m.u), "output": _list(m.y)})
    return out


def _manoeuvre_from_json(data: dict) -> Manoeuvre:
    u, y = _array(data.get("input")), _array(data.get("output"))
    n = 0 if u is None else u.size
    t = float(data.get("t0_s") or 0.0) + np.arange(n) * float(data.get("dt_s") or 0.0)
    return Manoeuvre(str(data.get("kind", "doublet")), t, u if u is not None else np.zeros(0),
                     y if y is not None else np.zeros(0), _float(data.get("start_s")), _float(data.get("end_s")),
                     int(data.get("trim_samples") or 0))


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
    model_spec: dict = field(default_factory=dict)                   # the config's model mapping
    manoeuvres: list[Manoeuvre] = field(default_factory=list)        # doublets kept for the time domain
    time_domain: list[dict] = field(default_factory=list)            # per manoeuvre: tic, tic_input_augmented

    @property
    def points_used(self) -> int:
        return int(np.count_nonzero(self.confident)) if self.confident is not None else 0

    def to_json_dict(self, samples: bool = True) -> dict:
        """The channel's JSON object (DESIGN.md keys first, extensions after).

        ``samples=False`` leaves out the bulky parts only figures need (each raw sweep's response, the doublets'
        samples): the node's 1 Hz diagnostics read a few numbers.
        """
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
            "model_spec": self.model_spec,
            "confident": [] if self.confident is None else [bool(c) for c in self.confident],
            "time_domain": [_manoeuvre_json(m, c, samples) for m, c in zip(self.manoeuvres, self._checks())],
        }
        for entry, response in zip(out["raw_sweeps"], self.sweep_measured if samples else ()):
            entry["measured"] = _mag_phase(response, self.model)
        return out

    def _checks(self) -> list[dict | None]:
        return list(self.time_domain) + [None] * (len(self.manoeuvres) - len(self.time_domain))

    @classmethod
    def from_json_dict(cls, name: str, data: dict) -> "ChannelResult":
        """Rebuild a channel's result from its JSON object (e.g. to draw a report from saved results)."""
        ch = cls(name=name, sweeps=int(data.get("sweeps") or 0), nu_gap=data.get("nu_gap"),
                 nu_gap_frequency_rad_s=data.get("nu_gap_frequency_rad_s"), epsilon=data.get("epsilon"),
                 worst_frequency_rad_s=data.get("worst_frequency_rad_s"), epsilon_raw=data.get("epsilon_raw"),
                 epsilon_raw_frequency_rad_s=data.get("epsilon_raw_frequency_rad_s"),
                 coherence_threshold=float(data.get("coherence_threshold", 0.6)),
                 points_excluded=int(data.get("points_excluded") or 0), limited_by=data.get("limited_by", "none"),
                 frequency_flags=list(data.get("frequency_flags") or []), bands=list(data.get("bands") or []),
                 diagnosis=list(data.get("diagnosis") or []), bad_samples=dict(data.get("bad_samples") or {}),
                 epsilon_previous=data.get("epsilon_previous"),
                 model_description=data.get("model_description", ""), message=data.get("message", ""),
                 model_spec=dict(data.get("model_spec") or {}))
        ch.margins = margins_from_epsilon(ch.epsilon if ch.epsilon is not None else float("nan"))
        if ch.epsilon_raw is not None:
            ch.margins_raw = margins_from_epsilon(ch.epsilon_raw)
        for key in ("frequency_rad_s", "coherence", "random_error", "kappa", "epsilon_per_frequency"):
            setattr(ch, key, _array(data.get(key)))
        ch.measured, ch.model = _complex(data.get("measured")), _complex(data.get("model"))
        confident = data.get("confident")
        ch.confident = np.array(confident, dtype=bool) if confident else None
        raw = list(data.get("raw_sweeps") or [])
        ch.sweep_results = [SweepResult.from_json_dict(r) for r in raw]
        ch.sweep_measured = [m for m in (_complex(r.get("measured")) for r in raw) if m is not None]
        entries = list(data.get("time_domain") or [])
        ch.manoeuvres = [_manoeuvre_from_json(e) for e in entries]
        ch.time_domain = [{k: e.get(k) for k in ("tic", "tic_input_augmented")} for e in entries]
        return ch


@dataclass
class ValidationResult:
    """Results of all channels, in config order."""

    channels: dict[str, ChannelResult]
    config_source: str | None = None
    sources: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    history: dict[str, list[dict]] = field(default_factory=dict)   # per channel: epsilon per model version

    def to_json_dict(self) -> dict:
        return {
            "channels": {name: ch.to_json_dict() for name, ch in self.channels.items()},
            "config": self.config_source,
            "sources": list(self.sources),
            "notes": list(self.notes),
            "history": {name: list(v) for name, v in self.history.items()},
        }

    @classmethod
    def from_json_dict(cls, data: dict) -> "ValidationResult":
        """Rebuild results from :meth:`to_json_dict` output (``gap-validate report RESULTS.json``)."""
        channels = data.get("channels")
        if not isinstance(channels, dict):
            raise ValueError("no 'channels' object")
        return cls(channels={name: ChannelResult.from_json_dict(name, ch) for name, ch in channels.items()},
                   config_source=data.get("config"), sources=list(data.get("sources") or []),
                   notes=list(data.get("notes") or []), history=dict(data.get("history") or {}))
