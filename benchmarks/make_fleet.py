#!/usr/bin/env python3
"""Simulate a fleet: N aircraft x M weekly flights, one airframe with a hidden effect drifting week by week.

Every aircraft is the config's airframe (``config/ultrastick25e.yaml`` by default) with a servo delay the
model lacks (``--delay-ms``, 20 ms, on every channel: the diagnosis finds it on every flight); on one aircraft
and channel (``--drifting UAV-3 --channel pitch``) the delay grows by ``--growth-ms-per-week`` (6 ms) each
week, e.g. a worn linkage. Flights are short sweep cards (``--sweeps`` x ``--sweep-duration`` s per channel),
each with its own seed (noise, gusts, jitter): the flight-to-flight random error is real. Writes::

    OUT/config.yaml                  the validation config (the channels asked for)
    OUT/bags/<aircraft>_w<week>/     one rosbag2 (mcap) per flight
    OUT/manifest.yaml                flights: name, bag, config, aircraft, date, tags (for gap-validate
    campaign)

Usage::

    python benchmarks/make_fleet.py OUT [--aircraft 4] [--weeks 6] [--drifting UAV-3] [--channel pitch]
        [--channels roll,pitch,yaw] [--delay-ms 20] [--growth-ms-per-week 6] [--sweeps 2] [--sweep-duration
        30] [--seed 0] [--start 2025-03-03] [--force]

Used by ``test/test_campaign.py``, docs/campaigns.md and ``benchmarks/bench_campaign.py``.
"""
from __future__ import annotations

import argparse
import datetime as dt
import shutil
import sys
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gap_validation.bag.writer import write_flight  # noqa: E402
from gap_validation.core.config import parse_config  # noqa: E402
from gap_validation.core.simulation import FlightOptions, simulate_flight  # noqa: E402

CONFIG = ROOT / "config" / "ultrastick25e.yaml"
#: Short flights: two 30 s sweeps per channel, 10 s of quiet between manoeuvres (sweeps closer than about 8 s
#: merge into one).
FLEET_OPTIONS = FlightOptions(sweeps_per_channel=2, sweep_duration_s=30.0, quiet_s=10.0)


def aircraft_names(count: int) -> list[str]:
    return [f"UAV-{i + 1}" for i in range(count)]


def fleet_delay_s(week: int, drifting: bool, delay_s: float, growth_s_per_week: float) -> float:
    """The hidden delay of a flight [s]: the fleet's servo delay, plus the drift on the drifting airframe."""
    return delay_s + (growth_s_per_week * week if drifting else 0.0)


def make_fleet(
    out: str | Path,
    *,
    aircraft: int = 4,
    weeks: int = 6,
    drifting: str = "UAV-3",
    channel: str = "pitch",
    channels: list[str] | None = None,
    delay_s: float = 0.020,
    growth_s_per_week: float = 0.006,
    options: FlightOptions = FLEET_OPTIONS,
    seed: int = 0,
    start: dt.date = dt.date(2025, 3, 3),
    config: str | Path = CONFIG,
    force: bool = False,
) -> Path:
    """Write the fleet's bags, config and manifest into ``out``; return the manifest path.

    Aircraft ``k`` flies on day ``k - 1`` of each week (a weekly card, each airframe on its own day).
    """
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        if not force:
            raise SystemExit(f"make_fleet: {out} is not empty (use --force to replace it)")
        shutil.rmtree(out)
    (out / "bags").mkdir(parents=True, exist_ok=True)
    raw = yaml.safe_load(Path(config).read_text())
    if channels:
        raw["channels"] = {name: raw["channels"][name] for name in channels}
    (out / "config.yaml").write_text(yaml.safe_dump(raw, sort_keys=False))
    cfg = parse_config(raw, str(out / "config.yaml"))
    if channel not in cfg.channels:
        raise SystemExit(f"make_fleet: --channel {channel}: not among the channels {', '.join(cfg.channels)}")
    flights = []
    for k, name in enumerate(aircraft_names(aircraft)):
        for week in range(weeks):
            hidden = {ch: [{"type": "time_delay", "seconds": delay_s}] for ch in cfg.channels}
            hidden[channel] = [{"type": "time_delay",
                                "seconds": fleet_delay_s(week, name == drifting, delay_s, growth_s_per_week)}]
            date = start + dt.timedelta(days=7 * week + k % 7)
            bag = Path("bags") / f"{name.lower()}_w{week:02d}"
            flight = simulate_flight(cfg, hidden, options, seed=seed * 100_000 + k * 1000 + week)
            write_flight(flight, out / bag)
            flights.append(
                {
                    "name": f"{name} {date.isoformat()}",
                    "bag": bag.as_posix(),
                    "config": "config.yaml",
                    "aircraft": name,
                    "date": date,
                    "tags": ["weekly", f"week-{week}"],
                }
            )
    manifest = out / "manifest.yaml"
    manifest.write_text(yaml.safe_dump({"flights": flights}, sort_keys=False))
    return manifest


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", type=Path)
    p.add_argument("--aircraft", type=int, default=4)
    p.add_argument("--weeks", type=int, default=6)
    p.add_argument("--drifting", default="UAV-3", help="aircraft whose delay drifts (none: 'none')")
    p.add_argument("--channel", default="pitch", help="channel of the drifting delay")
    p.add_argument("--channels", help="channels of the config, comma-separated (default: all)")
    p.add_argument("--delay-ms", type=float, default=20.0, help="servo delay of every aircraft [ms]")
    p.add_argument(
        "--growth-ms-per-week", type=float, default=6.0, help="drift of the drifting airframe [ms/week]"
    )
    p.add_argument("--sweeps", type=int, default=FLEET_OPTIONS.sweeps_per_channel)
    p.add_argument("--sweep-duration", type=float, default=FLEET_OPTIONS.sweep_duration_s)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--start", type=dt.date.fromisoformat, default=dt.date(2025, 3, 3))
    p.add_argument("--force", action="store_true", help="replace OUT if it is not empty")
    args = p.parse_args(argv)
    options = FlightOptions(sweeps_per_channel=args.sweeps, sweep_duration_s=args.sweep_duration,
                            quiet_s=FLEET_OPTIONS.quiet_s)
    began = time.perf_counter()
    manifest = make_fleet(args.out, aircraft=args.aircraft, weeks=args.weeks, drifting=args.drifting,
                          channel=args.channel, channels=args.channels.split(",") if args.channels else None,
                          delay_s=args.delay_ms / 1e3, growth_s_per_week=args.growth_ms_per_week / 1e3,
                          options=options, seed=args.seed, start=args.start, force=args.force)
    print(f"wrote {args.aircraft * args.weeks} flights and {manifest} in {time.perf_counter() - began:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
