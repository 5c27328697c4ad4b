#!/usr/bin/env python3
"""Replay speed against plain rosbags reading of the same bag, in the same run.

*plain*: ``rosbags.rosbag2.Reader`` over the config's topics and ``Typestore.deserialize_cdr`` of every
message (what any rosbags-based tool must at least do). *replay*: ``gap_validation.bag.replay.replay`` -- reading,
field extraction, batching and the online estimator -- with the fast field decoders (default) and with full
deserialisation (``--full-decode`` path). The ratio ``replay msgs/s / plain msgs/s`` is the figure of merit
(goal >= 0.7; above 1 when decoding only the needed fields saves more than the estimator costs).

Usage::

    python benchmarks/bench_replay.py [--bag BAG] [--config CFG] [--repeat N] [--minutes M]

Without ``--bag`` a flight of about ``--minutes`` (default 15) is simulated from the config into a temporary
directory first.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rosbags.rosbag2 import Reader  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from gap_validation.bag.writer import write_flight  # noqa: E402
from gap_validation.config import load_config  # noqa: E402
from gap_validation.core.simulation import FlightOptions, simulate_flight  # noqa: E402
from gap_validation.bag.replay import replay  # noqa: E402


def plain_read(bag: Path, topics) -> tuple[int, float]:
    """(messages, seconds) to read and fully deserialise the topics with rosbags."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    start = time.perf_counter()
    count = 0
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic in topics]
        for conn, _, raw in reader.messages(connections=conns):
            typestore.deserialize_cdr(raw, conn.msgtype)
            count += 1
    return count, time.perf_counter() - start


def replay_run(bag: Path, config, fast: bool) -> tuple[int, float]:
    """(messages, seconds) of a replay without the diagnosis (results are computed)."""
    start = time.perf_counter()
    outcome = replay([bag], config, fast=fast, diagnose=False)
    return outcome.messages, time.perf_counter() - start


def best(fn, repeat: int) -> tuple[int, float]:
    runs = [fn() for _ in range(repeat)]
    return min(runs, key=lambda r: r[1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--bag", type=Path, help="bag to replay (default: simulate one)")
    parser.add_argument("--config", type=Path, default=ROOT / "config" / "ultrastick25e.yaml")
    parser.add_argument("--repeat", type=int, default=3, help="runs per variant; the fastest counts")
    parser.add_argument("--minutes", type=float, default=15.0, help="length of the simulated flight")
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    args = parser.parse_args(argv)
    config = load_config(args.config)
    topics = set(config.topics())
    with tempfile.TemporaryDirectory() as tmp:
        bag = args.bag
        if bag is None:
            d = FlightOptions()
            card_s = len(config.channels) * (d.sweep_duration_s + 2 * d.quiet_s + 2 * d.doublet_half_period_s)
            sweeps = max(1, round(args.minutes * 60.0 / card_s))
            flight = simulate_flight(config, options=FlightOptions(sweeps_per_channel=sweeps), seed=1)
            bag = write_flight(flight, Path(tmp) / "bench", args.storage)
            print(f"simulated {flight.duration_s / 60:.1f} min, {flight.message_count} messages ({args.storage})")
        plain = best(lambda: plain_read(bag, topics), args.repeat)
        fast = best(lambda: replay_run(bag, config, True), args.repeat)
        full = best(lambda: replay_run(bag, config, False), args.repeat)
    rate = {name: n / s for name, (n, s) in (("plain", plain), ("fast", fast), ("full", full))}
    print(f"{'variant':<34}{'messages':>10}{'seconds':>10}{'msgs/s':>12}{'ratio':>8}")
    for label, key, (n, s) in (("plain rosbags read + deserialise", "plain", plain),
                               ("replay (fast field decoding)", "fast", fast),
                               ("replay (full deserialisation)", "full", full)):
        print(f"{label:<34}{n:>10}{s:>10.3f}{rate[key]:>12,.0f}{rate[key] / rate['plain']:>8.2f}")
    ratio = rate["fast"] / rate["plain"]
    print(f"ratio replay/plain = {ratio:.2f} (goal >= 0.7)")
    return 0 if ratio >= 0.7 else 1


if __name__ == "__main__":
    sys.exit(main())
