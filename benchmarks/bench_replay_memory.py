#!/usr/bin/env python3
"""Replay memory against flight length: peak RSS replaying a short and a long flight, in the same run.

Peak RSS is the child's ``VmHWM`` (``ru_maxrss`` survives exec on Linux and would report the parent's peak).
Two flights of the same test card are simulated from the config (``--short`` and ``--long`` minutes, IMU 100 Hz,
surfaces 50 Hz), written as mcap bags, and each is replayed (``gap_validation.replay.replay``, no diagnosis) in a
fresh child process that reports its own peak resident set size. Streaming replay keeps memory flat: the figure of
merit is ``(peak RSS long - baseline) / (peak RSS short - baseline)`` against the bag size ratio, where the baseline
is a child that imports the same modules and replays nothing. Constant memory means a ratio near 1 however large the
bag ratio.

Usage::

    python benchmarks/bench_replay_memory.py [--short 10] [--long 60] [--config CFG]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gap_validation.bagio import write_flight  # noqa: E402
from gap_validation.config import load_config  # noqa: E402
from gap_validation.core.simulation import FlightOptions, simulate_flight  # noqa: E402

CHILD = """
import json, sys, warnings
warnings.filterwarnings("ignore")
sys.path.insert(0, {root!r})
from gap_validation.config import load_config
from gap_validation.replay import replay
config = load_config({config!r})
messages = 0
if {bag!r}:
    messages = replay([{bag!r}], config, diagnose=False).messages
hwm = next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM:"))
print(json.dumps({{"messages": messages, "max_rss_kb": hwm}}))
"""


def child_peak(config: Path, bag: Path | None) -> dict:
    """Peak RSS [kB] and messages of a fresh process replaying ``bag`` (None: imports only)."""
    code = CHILD.format(root=str(ROOT), config=str(config), bag=str(bag) if bag else "")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True,
                         env=os.environ.copy())
    return json.loads(out.stdout.strip().splitlines()[-1])


def flight_bag(config, minutes: float, out: Path) -> Path:
    """Simulate about ``minutes`` of sweeps (three channels in turn) and write an mcap bag."""
    sweeps = max(1, round(minutes * 60 / (3 * 120)))
    options = FlightOptions(sweeps_per_channel=sweeps, sweep_duration_s=100.0, quiet_s=10.0)
    write_flight(simulate_flight(config, {}, options, seed=1), out, "mcap")
    return out


def size_mb(path: Path) -> float:
    files = [path] if path.is_file() else [p for p in path.rglob("*") if p.is_file()]
    return sum(p.stat().st_size for p in files) / 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=Path, default=ROOT / "config" / "ultrastick25e.yaml")
    parser.add_argument("--short", type=float, default=10.0, help="minutes of the short flight")
    parser.add_argument("--long", type=float, default=60.0, help="minutes of the long flight")
    args = parser.parse_args()
    config = load_config(args.config)
    with tempfile.TemporaryDirectory() as tmp:
        short = flight_bag(config, args.short, Path(tmp) / "short")
        long = flight_bag(config, args.long, Path(tmp) / "long")
        sizes = size_mb(short), size_mb(long)
        base = child_peak(args.config, None)
        a, b = child_peak(args.config, short), child_peak(args.config, long)
    grow_a = (a["max_rss_kb"] - base["max_rss_kb"]) / 1024
    grow_b = (b["max_rss_kb"] - base["max_rss_kb"]) / 1024
    print(f"baseline (imports, no replay): peak RSS {base['max_rss_kb'] / 1024:.1f} MB")
    print(f"short flight: {a['messages']:>8} messages, bag {sizes[0]:6.1f} MB, peak RSS "
          f"{a['max_rss_kb'] / 1024:.1f} MB (+{grow_a:.1f} MB)")
    print(f"long flight:  {b['messages']:>8} messages, bag {sizes[1]:6.1f} MB, peak RSS "
          f"{b['max_rss_kb'] / 1024:.1f} MB (+{grow_b:.1f} MB)")
    print(f"messages ratio long/short {b['messages'] / max(a['messages'], 1):.1f}; replay memory growth ratio "
          f"{grow_b / max(grow_a, 1e-9):.2f} (constant memory: about 1)")


if __name__ == "__main__":
    main()
