#!/usr/bin/env python3
"""Replay memory and throughput against flight length: a short and a long flight replayed in the same run.

Peak RSS is the child's ``VmHWM`` (``ru_maxrss`` survives exec on Linux and would report the parent's peak).
Two flights of the same test card are simulated from the config (``--short`` and ``--long`` minutes, IMU
``--imu-rate-hz``, surfaces ``--surface-rate-hz``), written in the temporary directory (``/tmp``) as mcap bags
or, with ``--format ulog|dataflash|csv``, as the flight log ``gap-validate simulate --format`` writes (each
with the config that reads it, :func:`gap_validation.logs.flight.write_flight_log`), and each is replayed
(``gap_validation.bag.replay.replay``, no diagnosis) in a fresh child process that reports its own peak
resident set size. Streaming replay keeps memory flat: the figure of
merit is ``(peak RSS long - baseline) / (peak RSS short - baseline)`` against the bag size ratio, where the
baseline is a child that imports the same modules and replays nothing. Constant memory means a ratio near 1
however large the bag ratio. Throughput (messages per second of the replay call, in the child) is compared the
same way: streaming means a ratio long/short near 1.

Usage::

    python benchmarks/bench_replay_memory.py [--format bag|ulog|dataflash|csv] [--short 10] [--long 60]
        [--imu-rate-hz 100] [--surface-rate-hz 50]
    python benchmarks/bench_replay_memory.py --format ulog --imu-rate-hz 250 --surface-rate-hz 50   # PX4 log
    python benchmarks/bench_replay_memory.py --long 120 --imu-rate-hz 1000 --surface-rate-hz 100   # 2-hour 1
    kHz
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

from gap_validation.bag.writer import write_flight  # noqa: E402
from gap_validation.core.config import load_config  # noqa: E402
from gap_validation.core.simulation import FlightOptions, simulate_flight  # noqa: E402
from gap_validation.logs.flight import FORMATS, write_flight_log  # noqa: E402

CHILD = """
import json, sys, time, warnings
warnings.filterwarnings("ignore")
sys.path.insert(0, {root!r})
from gap_validation.core.config import load_config
from gap_validation.bag.replay import replay
config = load_config({config!r})
messages, elapsed = 0, 0.0
if {bag!r}:
    start = time.perf_counter()
    messages = replay([{bag!r}], config, diagnose=False).messages
    elapsed = time.perf_counter() - start
hwm = next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM:"))
print(json.dumps({{"messages": messages, "max_rss_kb": hwm, "elapsed_s": elapsed}}))
"""


def child_peak(config: Path, bag: Path | None) -> dict:
    """Peak RSS [kB] and messages of a fresh process replaying ``bag`` (None: imports only)."""
    code = CHILD.format(root=str(ROOT), config=str(config), bag=str(bag) if bag else "")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True,
                         env=os.environ.copy())
    return json.loads(out.stdout.strip().splitlines()[-1])


def flight_bag(config, minutes: float, out: Path, imu_rate_hz: float, surface_rate_hz: float,
               fmt: str = "bag", config_path: Path | None = None) -> tuple[Path, Path | None]:
    """Simulate about ``minutes`` of sweeps (three channels in turn) and write an mcap bag (``fmt`` ``bag``)
    or a flight log of format ``fmt`` with its config; returns the bag or log and the config that reads it."""
    sweeps = max(1, round(minutes * 60 / (3 * 120)))
    options = FlightOptions(sweeps_per_channel=sweeps, sweep_duration_s=100.0, quiet_s=10.0,
                            imu_rate_hz=imu_rate_hz, surface_rate_hz=surface_rate_hz)
    flight = simulate_flight(config, {}, options, seed=1)
    if fmt == "bag":
        write_flight(flight, out, "mcap")
        return out, config_path
    log, log_config, _ = write_flight_log(flight, config, out, fmt)
    return log, log_config


def size_mb(path: Path) -> float:
    files = [path] if path.is_file() else [p for p in path.rglob("*") if p.is_file()]
    return sum(p.stat().st_size for p in files) / 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=Path, default=ROOT / "config" / "ultrastick25e.yaml")
    parser.add_argument("--format", choices=("bag",) + FORMATS, default="bag",
                        help="what the flights are written as (default bag)")
    parser.add_argument("--short", type=float, default=10.0, help="minutes of the short flight")
    parser.add_argument("--long", type=float, default=60.0, help="minutes of the long flight")
    parser.add_argument("--imu-rate-hz", type=float, default=100.0)
    parser.add_argument("--surface-rate-hz", type=float, default=50.0)
    args = parser.parse_args()
    config = load_config(args.config)
    rates = args.imu_rate_hz, args.surface_rate_hz
    with tempfile.TemporaryDirectory() as tmp:
        short, short_config = flight_bag(
            config, args.short, Path(tmp) / "short", *rates, args.format, args.config
        )
        long, long_config = flight_bag(
            config, args.long, Path(tmp) / "long", *rates, args.format, args.config
        )
        sizes = size_mb(short), size_mb(long)
        base = child_peak(args.config, None)
        a, b = child_peak(short_config, short), child_peak(long_config, long)
    grow_a = (a["max_rss_kb"] - base["max_rss_kb"]) / 1024
    grow_b = (b["max_rss_kb"] - base["max_rss_kb"]) / 1024
    print(f"baseline (imports, no replay): peak RSS {base['max_rss_kb'] / 1024:.1f} MB")
    rate_a, rate_b = (c["messages"] / max(c["elapsed_s"], 1e-9) for c in (a, b))
    print(f"format {args.format}; rates: IMU {rates[0]:g} Hz, surfaces {rates[1]:g} Hz")
    for label, minutes, c, size, grow, rate in (("short", args.short, a, sizes[0], grow_a, rate_a),
                                                  ("long", args.long, b, sizes[1], grow_b, rate_b)):
        print(
            f"{label + ' flight':<13} {minutes:g} min: {c['messages']:>8} messages, {args.format} "
            f"{size:7.1f} MB, peak RSS "
            f"{c['max_rss_kb'] / 1024:.1f} MB (+{grow:.1f} MB), {rate:,.0f} msgs/s"
        )
    print(
        f"messages ratio long/short {b['messages'] / max(a['messages'], 1):.1f}; replay memory growth ratio "
        f"{grow_b / max(grow_a, 1e-9):.2f}, peak RSS ratio {b['max_rss_kb'] / a['max_rss_kb']:.2f}, "
        "throughput "
        f"ratio {rate_b / rate_a:.2f} (constant memory, unchanged throughput: about 1)"
    )


if __name__ == "__main__":
    main()
