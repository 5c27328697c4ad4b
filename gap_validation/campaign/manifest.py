"""Campaign manifests: which flights to validate, with which config, of which aircraft, on which date.

A manifest is a YAML file (``gap-validate campaign MANIFEST.yaml``)::

    flights:
      - name: UAV-3 week 5                  # unique within the manifest
        bag: flights/uav3_w5                # one path, or a list of paths (their sweeps add up, as in replay)
        config: config/uav.yaml             # the validation config (DESIGN.md)
        aircraft: UAV-3                     # trends are drawn per aircraft and channel
        date: 2025-04-07                    # YYYY-MM-DD (or an ISO date and time)
        tags: [weekly, card-A]              # optional: strings, kept in the results

Relative paths are relative to the manifest's directory. Unknown keys and wrong types are errors that name
the file, the key and the value (:class:`~gap_validation.core.errors.ConfigError`, one line, CLI exit 2), like
the validation config's.
"""
from __future__ import annotations

import datetime as dt
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gap_validation.core.config import read_yaml
from gap_validation.core.errors import ConfigError

__all__ = ["Flight", "Manifest", "load_manifest", "parse_manifest", "FLIGHT_KEYS", "REQUIRED_KEYS"]

#: Keys of one flight entry; all but ``tags`` are required.
FLIGHT_KEYS = ("name", "bag", "config", "aircraft", "date", "tags")
REQUIRED_KEYS = ("name", "bag", "config", "aircraft", "date")


@dataclass(frozen=True)
class Flight:
    """One flight of a campaign (paths resolved against the manifest's directory)."""

    name: str
    bags: tuple[Path, ...]
    config: Path
    aircraft: str
    date: dt.datetime
    tags: tuple[str, ...] = ()

    @property
    def date_text(self) -> str:
        """The date as the manifest gave it: ``YYYY-MM-DD``, or an ISO date and time when it had a time."""
        if (self.date.hour, self.date.minute, self.date.second, self.date.microsecond) == (0, 0, 0, 0):
            return self.date.date().isoformat()
        return self.date.isoformat()

    def metadata(self) -> dict:
        """``name``, ``aircraft``, ``date``, ``tags``, ``bags``, ``config`` as JSON values."""
        return {"name": self.name, "aircraft": self.aircraft, "date": self.date_text, "tags": list(self.tags),
                "bags": [str(b) for b in self.bags], "config": str(self.config)}


@dataclass(frozen=True)
class Manifest:
    """The flights of a campaign, in manifest order."""

    flights: tuple[Flight, ...]
    source: str = "<manifest>"
    configs: tuple[Path, ...] = field(default=())   # distinct config files, in first-use order

    @property
    def aircraft(self) -> list[str]:
        """Aircraft names in first-appearance order."""
        return list(dict.fromkeys(f.aircraft for f in self.flights))


def _fail(source: str, where: str, message: str) -> ConfigError:
    return ConfigError(f"{source}: {where}: {message}")


def _text(value: Any, source: str, where: str) -> str:
    if isinstance(value, bool) or not isinstance(value, (str, int, float)) or not str(value).strip():
        raise _fail(source, where, f"expected a non-empty string, got {_show(value)}")
    return str(value).strip()


def _show(value: Any, limit: int = 80) -> str:
    """``repr(value)``, shortened: error messages stay one readable line."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _path(value: Any, base: Path, source: str, where: str) -> Path:
    if not isinstance(value, str) or not value.strip():
        raise _fail(source, where, f"expected a path, got {_show(value)}")
    path = Path(os.path.expanduser(value.strip()))
    return path if path.is_absolute() else base / path


def _bags(value: Any, base: Path, source: str, where: str) -> tuple[Path, ...]:
    if isinstance(value, list):
        if not value:
            raise _fail(source, where, "expected a path or a non-empty list of paths, got []")
        return tuple(_path(v, base, source, f"{where}[{i}]") for i, v in enumerate(value))
    return (_path(value, base, source, where),)


def _date(value: Any, source: str, where: str) -> dt.datetime:
    if isinstance(value, dt.datetime):
        return (
            value.replace(tzinfo=None)
            if value.tzinfo is None
            else value.astimezone(dt.timezone.utc).replace(tzinfo=None)
        )
    if isinstance(value, dt.date):
        return dt.datetime(value.year, value.month, value.day)
    if isinstance(value, str):
        try:
            return _date(dt.datetime.fromisoformat(value.strip()), source, where)
        except ValueError:
            pass
    raise _fail(source, where, f"{_show(value)} is not a date (expected YYYY-MM-DD)")


def _tags(value: Any, source: str, where: str) -> tuple[str, ...]:
    if value is None:
        return ()
    if isinstance(value, str):
        return (_text(value, source, where),)
    if not isinstance(value, list):
        raise _fail(source, where, f"expected a list of strings, got {_show(value)}")
    return tuple(_text(v, source, f"{where}[{i}]") for i, v in enumerate(value))


def _flight(entry: Any, index: int, base: Path, source: str) -> Flight:
    where = f"flights[{index}]"
    if not isinstance(entry, dict):
        raise _fail(
            source, where, f"expected a mapping with keys {', '.join(REQUIRED_KEYS)}, got {_show(entry)}"
        )
    unknown = sorted(str(k) for k in entry if k not in FLIGHT_KEYS)
    if unknown:
        raise _fail(source, f"{where}.{unknown[0]}", f"unknown key (allowed: {', '.join(FLIGHT_KEYS)})")
    missing = [k for k in REQUIRED_KEYS if k not in entry]
    if missing:
        raise _fail(source, f"{where}.{missing[0]}", "missing (each flight needs "
                                                      f"{', '.join(REQUIRED_KEYS)})")
    return Flight(name=_text(entry["name"], source, f"{where}.name"),
                  bags=_bags(entry["bag"], base, source, f"{where}.bag"),
                  config=_path(entry["config"], base, source, f"{where}.config"),
                  aircraft=_text(entry["aircraft"], source, f"{where}.aircraft"),
                  date=_date(entry["date"], source, f"{where}.date"),
                  tags=_tags(entry.get("tags"), source, f"{where}.tags"))


def parse_manifest(data: Any, source: str = "<manifest>", base: str | os.PathLike | None = None) -> Manifest:
    """A :class:`Manifest` from its YAML mapping.

    Parameters
    ----------
    data : Any
        The loaded YAML document (a mapping with a ``flights`` list).
    source : str
        Name of the file, for the error messages.
    base : path, optional
        Directory that relative paths are relative to (default: the current directory).

    Raises
    ------
    ConfigError
        One line naming the file, the key (``flights[3].date``) and the value.
    """
    base = Path(base) if base is not None else Path.cwd()
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping with a 'flights' list, got {_show(data)}")
    unknown = sorted(str(k) for k in data if k != "flights")
    if unknown:
        raise _fail(source, unknown[0], "unknown key (allowed: flights)")
    entries = data.get("flights")
    if not isinstance(entries, list) or not entries:
        raise _fail(source, "flights", f"expected a non-empty list of flights, got {_show(entries)}")
    flights = [_flight(entry, i, base, source) for i, entry in enumerate(entries)]
    seen: dict[str, int] = {}
    for i, f in enumerate(flights):
        if f.name in seen:
            raise _fail(
                source,
                f"flights[{i}].name",
                f"{f.name!r} is already the name of flights[{seen[f.name]}] (names must be unique)",
            )
        seen[f.name] = i
    configs = tuple(dict.fromkeys(f.config for f in flights))
    return Manifest(flights=tuple(flights), source=source, configs=configs)


def load_manifest(path: str | os.PathLike) -> Manifest:
    """Read a campaign manifest (YAML); relative paths in it are relative to its directory.

    Parameters
    ----------
    path : str or PathLike
        The manifest file.

    Raises
    ------
    ConfigError
        One line naming the file and the problem (missing file, YAML syntax with line number, bad key or
        value).
    """
    path = Path(path)
    data = read_yaml(path, "manifest")
    return parse_manifest(data, str(path), base=path.resolve().parent)
