"""Validation history: every replay appends its per-channel results, so the error can be followed across model
versions ("add the effect and watch epsilon fall", DESIGN.md step 4).

The history is a JSON Lines file beside the config (``<config stem>.history.jsonl``): one record per replay,
appended; each append rewrites the file atomically (temporary file, then rename), so a crash or ``kill -9``
never leaves a half record::

    {"timestamp": "2024-05-01T12:00:00+00:00", "config": "cfg.yaml", "sources": ["flight1.mcap"],
     "channels": {"pitch": {"nu_gap": 0.08, "epsilon": 0.62, "epsilon_raw": 0.7, "worst_frequency_rad_s":
     31.4,
                            "sweeps": 3, "limited_by": "model", "diagnosis": {...top candidate...},
                            "model": {...model spec incl. effects...}, "model_hash": "3f2a9c01d4",
                            "airframe_hash": "77b0e1c2aa", "model_description": "airframe only"}}}

:func:`format_trend` turns it into one line per channel, e.g.
``pitch epsilon over model versions: 0.62 (airframe only) -> 0.07 (+ time delay of 45 ms)``.
No ROS imports; JSON only.
"""
from __future__ import annotations

import hashlib
import json
import logging
import math
import os
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Sequence

from gap_validation.core.atomic import atomic_write_bytes
from gap_validation.core.errors import DataError

log = logging.getLogger(__name__)

__all__ = ["default_history_path", "append_history", "load_history", "previous_epsilon", "format_trend",
           "model_hash", "describe_model"]

#: Per-channel result keys copied into the history (JSON names of DESIGN.md).
_RESULT_KEYS = ("nu_gap", "epsilon", "epsilon_raw", "worst_frequency_rad_s", "sweeps", "limited_by")


def default_history_path(config_path: str | os.PathLike) -> Path:
    """The history file beside a config: ``<dir>/<config stem>.history.jsonl``."""
    path = Path(config_path)
    return path.with_name(f"{path.stem}.history.jsonl")


def _plain(value: Any) -> Any:
    """JSON-safe copy: numpy scalars and arrays to Python, non-finite floats to None, tuples to lists."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):
        return _plain(value.tolist())
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    try:
        number = float(value)
    except (TypeError, ValueError):
        return str(value)
    return number if math.isfinite(number) else None


def model_hash(spec: dict) -> str:
    """Short, stable fingerprint of a model spec (10 hex digits of SHA-256 of its canonical JSON)."""
    text = json.dumps(_plain(spec), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:10]


def _airframe_spec(spec: dict) -> dict:
    return {k: v for k, v in spec.items() if k != "effects"}


def describe_model(spec: dict) -> str:
    """``"airframe only"`` or ``"+ time delay of 45 ms + first-order lag at ..."`` (the effects of the
    spec)."""
    effects = spec.get("effects") or []
    if not effects:
        return "airframe only"
    try:
        from gap_validation.core.effects import describe_effect

        return "+ " + " + ".join(describe_effect(e) for e in effects)
    except Exception:  # an unreadable effect must not lose the history entry
        return "+ " + " + ".join(str(e.get("type", "?")) for e in effects)


def _channel_record(channel_result, channel_config) -> dict:
    out = {key: _plain(getattr(channel_result, key, None)) for key in _RESULT_KEYS}
    diagnosis = list(getattr(channel_result, "diagnosis", None) or [])
    out["diagnosis"] = _plain(diagnosis[0].to_json_dict()) if diagnosis else None
    if channel_config is not None:
        spec = _plain(channel_config.model.to_spec())
        out["model"] = spec
        out["model_hash"] = model_hash(spec)
        out["airframe_hash"] = model_hash(_airframe_spec(spec))
        out["model_description"] = describe_model(spec)
    else:
        out["model"], out["model_hash"], out["airframe_hash"] = None, None, None
        out["model_description"] = getattr(channel_result, "model_description", "") or ""
    return out


def append_history(path: str | os.PathLike, result, config, sources: Sequence[str],
                   timestamp: datetime | None = None) -> dict:
    """Append one replay's results to the history file (created when missing).

    Parameters
    ----------
    path : path
        History file (JSON Lines), e.g. :func:`default_history_path` of the config.
    result : ValidationResult
        The replay's results.
    config : ValidationConfig
        The config it used (models incl. effects are recorded with a hash per channel).
    sources : list of str
        The bags replayed.
    timestamp : datetime, optional
        Time of the record (default now, UTC).

    Returns
    -------
    dict
        The record written.

    Raises
    ------
    DataError
        When the file cannot be written (one line naming it).
    """
    when = (timestamp or datetime.now(timezone.utc)).isoformat(timespec="seconds")
    channels = {name: _channel_record(ch, config.channels.get(name)) for name, ch in result.channels.items()}
    record = {
        "timestamp": when,
        "config": getattr(config, "source", None),
        "sources": [str(s) for s in sources],
        "channels": channels,
    }
    line = json.dumps(record, sort_keys=False, allow_nan=False)
    path = Path(path)
    try:
        kept = _complete_lines(path.read_bytes()) if path.exists() else b""
        atomic_write_bytes(path, kept + line.encode("utf-8") + b"\n")
    except OSError as err:
        raise DataError(f"{path}: cannot write the validation history ({err.strerror or err})") from None
    return record


def _complete_lines(data: bytes) -> bytes:
    """``data`` up to its last complete line, newline-terminated: a torn last line (no newline, not JSON) is
    dropped, a complete record without its newline (edited by hand) is kept."""
    if not data or data.endswith(b"\n"):
        return data
    head, _, last = data.rpartition(b"\n")
    try:
        json.loads(last)
    except (json.JSONDecodeError, UnicodeDecodeError):
        log.warning(
            "validation history: dropping a torn last line (%d bytes, an interrupted write)", len(last)
        )
        return head + b"\n" if head else b""
    return data + b"\n"


def load_history(path: str | os.PathLike) -> list[dict]:
    """Read a history file; a missing file is an empty history.

    The history is rewritten atomically (:mod:`gap_validation.core.atomic`), so no write of this tool leaves a
    half line; a torn *last* line without its newline (a file written by an older version or another tool,
    killed mid-append) is skipped with a logged warning naming the file and line, since every record before
    it is complete.

    Raises
    ------
    DataError
        One line naming the file and line of the first corrupt record (the history is not silently
        truncated), or the file when it cannot be read.
    """
    path = Path(path)
    if not path.exists():
        return []
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise DataError(
            f"{path}: cannot read the validation history ({getattr(err, 'strerror', None) or err})"
        ) from None
    lines = text.splitlines()
    records = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as err:
            if number == len(lines) and not text.endswith("\n"):
                log.warning("%s:%d: torn last line of the validation history skipped (an interrupted write)",
                            path, number)
                break
            raise DataError(
                f"{path}:{number}: corrupt validation history line ({err.msg}, column {err.colno})"
            ) from None
        if not isinstance(record, dict) or not isinstance(record.get("channels"), dict):
            raise DataError(f"{path}:{number}: corrupt validation history line (expected an object with "
                            f"'channels')")
        records.append(record)
    return records


def _entries(history: Sequence[dict], channel: str):
    for record in history:
        entry = record.get("channels", {}).get(channel)
        if isinstance(entry, dict) and isinstance(entry.get("epsilon"), (int, float)):
            yield record, entry


def previous_epsilon(
    history: Sequence[dict], channel: str, exclude_model_hash: str | None = None
) -> float | None:
    """The most recent recorded epsilon of ``channel`` (None when there is none).

    Parameters
    ----------
    history : list of dict
        Records from :func:`load_history`.
    channel : str
        Channel name.
    exclude_model_hash : str, optional
        Skip records made with this model (e.g. the current one, to get the previous model version's epsilon).
    """
    for _, entry in reversed(list(_entries(history, channel))):
        if exclude_model_hash is None or entry.get("model_hash") != exclude_model_hash:
            return float(entry["epsilon"])
    return None


def epsilon_versions(history: Sequence[dict], channel: str) -> list[dict]:
    """Epsilon of ``channel`` per model version, in the order they were flown (for the report's plot).

    Consecutive replays with the same model form one version; its latest record counts. Each entry has
    ``model_description``, ``model_hash``, ``airframe_hash``, ``epsilon``, ``epsilon_raw`` and ``timestamp``.
    """
    versions: list[dict] = []
    for record, entry in _entries(history, channel):
        item = {"model_description": entry.get("model_description") or "model",
                "model_hash": entry.get("model_hash"), "airframe_hash": entry.get("airframe_hash"),
                "epsilon": float(entry["epsilon"]), "epsilon_raw": entry.get("epsilon_raw"),
                "timestamp": record.get("timestamp")}
        if versions and versions[-1]["model_hash"] == item["model_hash"]:
            versions[-1] = item
        else:
            versions.append(item)
    return versions


def format_trend(history: Sequence[dict], channel: str) -> str:
    """One line: epsilon of ``channel`` per model version, in the order they were flown.

    Consecutive replays with the same model form one version (its latest epsilon is shown). When the airframe
    itself changed (e.g. a refitted ``parameter_error``), versions name their airframe by hash.

    Examples
    --------
    ``pitch epsilon over model versions: 0.62 (airframe only) -> 0.07 (+ time delay of 45 ms)``
    """
    versions = epsilon_versions(history, channel)
    if not versions:
        return f"{channel}: no validation history yet"
    airframes = {v["airframe_hash"] for v in versions}
    parts = []
    for v in versions:
        description = v["model_description"]
        if len(airframes) > 1 and v["airframe_hash"]:
            description = f"{description}, airframe {v['airframe_hash'][:6]}"
        parts.append(f"{v['epsilon']:.2f} ({description})")
    return f"{channel} epsilon over model versions: " + " -> ".join(parts)
