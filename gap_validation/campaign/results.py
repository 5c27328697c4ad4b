"""A campaign's results: what happened to each flight, and the files ``campaign.json`` and ``campaign.csv``.

Each validated flight's full replay JSON (``replay --json``, plus a ``campaign`` object with the flight's
manifest entry, fingerprint, errors and warnings) is written as ``DIR/flights/<flight>.json`` as soon as its
task finishes (atomically): a campaign that is interrupted keeps every finished flight, and a re-run reuses
them (:mod:`gap_validation.campaign.fingerprint`). ``gap-validate report DIR/flights/<flight>.json --out R``
draws the flight's full report.

``campaign.json`` (DESIGN.md, CLI contract)::

    {"flights": [{"name": ..., "aircraft": ..., "date": "2025-04-07", "tags": [...],
                  "channels": {"pitch": <the replay JSON's channel object>, ...},
                  "status": "validated" | "reused" | "failed", "errors": [...], "warnings": [...],
                  "bags": [...], "config": ..., "fingerprint": ..., "results": "flights/<flight>.json"}],
     "errors": ["<flight>: <one line>", ...], "trends": [...], "manifest": ..., "written": ...}

It is written flight by flight from the per-flight files (memory does not grow with the campaign).
``campaign.csv`` has one row per flight and channel (a failed flight: one row with its error).
"""
from __future__ import annotations

import csv
import hashlib
import json
import math
import re
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable

from gap_validation.campaign.manifest import Flight, Manifest
from gap_validation.core.atomic import atomic_open
from gap_validation.core.errors import ConfigError, DataError

__all__ = [
    "FlightOutcome",
    "CampaignOutcome",
    "channel_summary",
    "flight_file",
    "load_flight_file",
    "write_campaign_json",
    "write_campaign_csv",
    "ensure_directory",
    "CSV_COLUMNS",
    "FLIGHTS_DIR",
    "VALIDATED",
    "REUSED",
    "FAILED",
]

FLIGHTS_DIR = "flights"
VALIDATED, REUSED, FAILED = "validated", "reused", "failed"

#: Columns of ``campaign.csv``.
CSV_COLUMNS = ("flight", "aircraft", "date", "tags", "channel", "status", "epsilon", "epsilon_raw", "nu_gap",
               "limited_by", "sweeps", "diagnosis", "diagnosis_parameters", "diagnosis_epsilon", "excitation",
               "error")


@dataclass
class FlightOutcome:
    """What happened to one flight of the campaign.

    ``channels`` holds per channel the few numbers the index and the CSV need (:func:`channel_summary`);
    the full replay JSON is in ``results_path``.
    """

    flight: Flight
    status: str = FAILED
    fingerprint: str | None = None
    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    results_path: Path | None = None
    channels: dict[str, dict] = field(default_factory=dict)
    elapsed_s: float | None = None
    cpu_s: float | None = None
    worker: str | None = None
    unsaved: dict | None = None          # the replay JSON when its results file could not be written


@dataclass
class CampaignOutcome:
    """A campaign's flights (manifest order), its one-line errors and warnings and what it wrote."""

    manifest: Manifest
    out_dir: Path
    flights: list[FlightOutcome]
    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    elapsed_s: float = 0.0
    workers: int | None = None
    # workers gone during the run (their tasks were rerun)
    workers_lost: int = 0
    scheduler: str | None = None
    findings: list = field(default_factory=list)          # campaign.findings.Finding, one per trend tested
    files: dict[str, Path] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.errors

    def count(self, status: str) -> int:
        return sum(1 for f in self.flights if f.status == status)


def _finite(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return float(value)


def channel_summary(channel: dict) -> dict:
    """The numbers of one channel's replay JSON that trends and tables use.

    Returns
    -------
    dict
        ``epsilon``, ``epsilon_raw``, ``nu_gap``, ``limited_by``, ``sweeps``, ``excitation`` (the replay
        JSON's ``excitation`` key if present, else None) and ``diagnosis``: the top candidate's ``effect``,
        ``parameters``, ``effects``, ``epsilon`` and ``sentence``, or None when the diagnosis is empty.
    """
    top = (channel.get("diagnosis") or [None])[0]
    diagnosis = None
    if isinstance(top, dict):
        diagnosis = {"effect": top.get("effect"), "parameters": dict(top.get("parameters") or {}),
                     "effects": [dict(e) for e in top.get("effects") or [] if isinstance(e, dict)],
                     "epsilon": _finite(top.get("epsilon")), "sentence": top.get("sentence")}
    return {"epsilon": _finite(channel.get("epsilon")), "epsilon_raw": _finite(channel.get("epsilon_raw")),
            "nu_gap": _finite(channel.get("nu_gap")), "limited_by": channel.get("limited_by"),
            "sweeps": int(channel.get("sweeps") or 0), "excitation": channel.get("excitation"),
            "diagnosis": diagnosis}


def flight_file(out_dir: Path, flight: Flight) -> Path:
    """``DIR/flights/<slug>-<8 hex of the name>.json``: a file name for any flight name, stable across
    runs."""
    slug = re.sub(r"[^A-Za-z0-9._-]+", "_", flight.name).strip("._")[:60] or "flight"
    tag = hashlib.sha256(flight.name.encode("utf-8", "surrogateescape")).hexdigest()[:8]
    return out_dir / FLIGHTS_DIR / f"{slug}-{tag}.json"


def load_flight_file(path: Path) -> dict | None:
    """A per-flight results file, or None when it is missing, unreadable or not one (then it is redone)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or not isinstance(data.get("channels"), dict) \
            or not isinstance(data.get("campaign"), dict):
        return None
    return data


def _entry(outcome: FlightOutcome, out_dir: Path, channels: dict) -> dict:
    return {
        **outcome.flight.metadata(),
        "channels": channels,
        "status": outcome.status,
        "errors": list(outcome.errors),
        "warnings": list(outcome.warnings),
        "fingerprint": outcome.fingerprint,
        "results": outcome.results_path.relative_to(out_dir).as_posix() if outcome.results_path else None,
        "elapsed_s": outcome.elapsed_s,
        "cpu_s": outcome.cpu_s,
        "worker": outcome.worker,
    }


def _write_entries(handle, outcomes: Iterable[FlightOutcome], out_dir: Path) -> None:
    for i, outcome in enumerate(outcomes):
        data = load_flight_file(outcome.results_path) if outcome.results_path else outcome.unsaved
        channels = data["channels"] if data else {}
        handle.write(",\n" if i else "\n")
        json.dump(_entry(outcome, out_dir, channels), handle, allow_nan=False)


def write_campaign_json(outcome: CampaignOutcome, path: Path | None = None) -> Path:
    """Write ``campaign.json`` (module docstring), streaming the flights from their per-flight files.

    Raises
    ------
    DataError
        One line naming the file when it cannot be written (the old file, if any, is kept).
    """
    path = path or outcome.out_dir / "campaign.json"
    head = {
        "manifest": outcome.manifest.source,
        "written": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "errors": list(outcome.errors),
        "warnings": list(outcome.warnings),
        "trends": [f.to_json_dict() for f in outcome.findings],
    }
    try:
        with atomic_open(path, "w") as handle:
            handle.write(json.dumps(head, allow_nan=False)[:-1] + ', "flights": [')
            _write_entries(handle, outcome.flights, outcome.out_dir)
            handle.write("\n]}\n")
    except OSError as err:
        raise DataError(f"{path}: cannot write campaign results ({err.strerror or err})") from None
    return path


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (dict, list)):
        return json.dumps(value, separators=(",", ":"))
    return str(value)


def _parameters_cell(parameters: dict) -> str:
    return ";".join(f"{k}={_cell(v)}" for k, v in parameters.items())


def _csv_rows(outcome: FlightOutcome) -> list[list[str]]:
    f = outcome.flight
    head = [f.name, f.aircraft, f.date_text, ";".join(f.tags)]
    error = " | ".join(outcome.errors)
    if not outcome.channels:
        return [head + ["", outcome.status] + [""] * (len(CSV_COLUMNS) - 7) + [error]]
    rows = []
    for name, ch in outcome.channels.items():
        top = ch.get("diagnosis") or {}
        rows.append(
            head
            + [
                name,
                outcome.status,
                _cell(ch["epsilon"]),
                _cell(ch["epsilon_raw"]),
                _cell(ch["nu_gap"]),
                _cell(ch["limited_by"]),
                str(ch["sweeps"]),
                _cell(top.get("effect")),
                _parameters_cell(top.get("parameters") or {}),
                _cell(top.get("epsilon")),
                _cell(ch.get("excitation")),
                error,
            ]
        )
    return rows


def write_campaign_csv(outcome: CampaignOutcome, path: Path | None = None) -> Path:
    """Write ``campaign.csv``: :data:`CSV_COLUMNS`, one row per flight and channel; numbers in full precision,
    tags joined by ``;``, the top diagnosis' parameters as ``name=value;name=value``.

    Raises
    ------
    DataError
        One line naming the file when it cannot be written (the old file, if any, is kept).
    """
    path = path or outcome.out_dir / "campaign.csv"
    try:
        with atomic_open(path, "w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(CSV_COLUMNS)
            for flight in outcome.flights:
                writer.writerows(_csv_rows(flight))
    except OSError as err:
        raise DataError(f"{path}: cannot write campaign CSV ({err.strerror or err})") from None
    return path


def ensure_directory(path: Path, what: str = "--out") -> Path:
    """Create ``path`` (and ``path/flights``); ConfigError (one line) when it is a file or cannot be made."""
    existing = next((p for p in (path, *path.parents) if p.exists()), None)
    if existing is not None and not existing.is_dir():
        raise ConfigError(f"{what} {path}: {existing} is a file, not a directory")
    try:
        (path / FLIGHTS_DIR).mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ConfigError(f"{what} {path}: cannot create directory ({err.strerror or err})") from None
    return path

