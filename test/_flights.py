"""Shared helpers for tests that need simulated flights and bags (short flights, modest rates)."""
from __future__ import annotations

import copy
from pathlib import Path

import yaml

from gap_validation.bag.writer import write_flight
from gap_validation.cli.arguments import hidden_effects
from gap_validation.core.config import load_config, parse_config
from gap_validation.core.simulation import FlightOptions, simulate_flight, with_options

ROOT = Path(__file__).resolve().parents[1]
CONFIG_PATH = ROOT / "config" / "ultrastick25e.yaml"

#: A short test card: two 40 s sweeps per channel (about 5 minutes of flight), IMU 100 Hz, surfaces 50 Hz.
SHORT = FlightOptions(sweeps_per_channel=2, sweep_duration_s=40.0, quiet_s=3.0)
#: A tiny one: one 10 s sweep per channel (bag I/O tests).
TINY = with_options(SHORT, sweeps_per_channel=1, sweep_duration_s=10.0, quiet_s=1.0)


def ultrastick():
    """The bundled Ultra Stick 25e config (roll, pitch, yaw)."""
    return load_config(CONFIG_PATH)


def raw_config() -> dict:
    """The Ultra Stick 25e config as a mapping (to derive variants from)."""
    return yaml.safe_load(CONFIG_PATH.read_text())


def config_from(data: dict, name: str = "variant.yaml"):
    """A ValidationConfig from a mapping."""
    return parse_config(copy.deepcopy(data), name)


def write_config(data: dict, path: Path) -> Path:
    """Write a config mapping as YAML and return the path."""
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def single_channel(channel: str = "pitch", **changes) -> dict:
    """A config mapping with only ``channel`` of the Ultra Stick config; ``changes`` update it."""
    data = raw_config()
    data["channels"] = {channel: data["channels"][channel]}
    data["channels"][channel].update(changes)
    return data


def make_bag(path: Path, config=None, hidden=(), seed: int = 0, storage: str | None = None,
             options: FlightOptions | None = None, **option_changes):
    """Simulate a flight for ``config`` (default Ultra Stick) and write it to ``path``; returns the flight."""
    config = config or ultrastick()
    flight = simulate_flight(config, hidden_effects(list(hidden), config),
                             with_options(options or SHORT, **option_changes), seed=seed)
    write_flight(flight, path, storage)
    return flight
