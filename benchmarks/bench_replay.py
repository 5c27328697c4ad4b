#!/usr/bin/env python3
"""Replay speed against plain rosbags reading of the same bag, whole processes, measured in the same run.

Each variant runs as its own Python process on the same bag (start-up and imports included), timed from the
parent (wall clock, and the child's user + system CPU time from ``os.wait4``):

* *plain*: ``rosbags.rosbag2.Reader`` over the config's topics and ``Typestore.deserialize_cdr`` of every
  message (what any rosbags-based tool must at least do);
* *raw read*: the same reader, the raw bytes only (no deserialisation);
* *replay*: ``gap_validation.bag.replay.replay`` without the diagnosis (reading, decoding, batching, the
  online estimator, the results), with the fast field decoders (default: records in batches, fields read from
  many records at once) and with full deserialisation (``fast=False``).

The figure of merit is ``plain seconds / replay seconds`` of the whole processes (goal >= 3). Every variant
runs ``--repeat`` times, interleaved; the fastest run counts (the machine may be shared: the load average
before and after is printed, and the CPU-time ratio beside the wall-clock one). The replay's result is checked
to be the same in every run.

Usage::

    python benchmarks/bench_replay.py [--bag BAG] [--config CFG] [--repeat N] [--minutes M]
                                      [--imu-rate-hz 1000] [--surface-rate-hz 100] [--storage mcap|sqlite3]

Without ``--bag`` a flight of about ``--minutes`` (at least one sweep per channel) is simulated from the
config into a temporary directory first: by default a 1 kHz IMU and 100 Hz surfaces.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gap_validation.bag.writer import write_flight  # noqa: E402
from gap_validation.core.config import load_config  # noqa: E402
from gap_validation.core.simulation import FlightOptions, simulate_flight  # noqa: E402

#: The children: each prints ``{"messages": n, "work_s": seconds of the work after the imports, ...}``.
PLAIN = """
import json, sys, time
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
bag, topics, decode = {bag!r}, set({topics!r}), {decode!r}
start = time.perf_counter()
typestore = get_typestore(Stores.ROS2_JAZZY)
count = 0
with Reader(bag) as reader:
    conns = [c for c in reader.connections if c.topic in topics]
    for conn, _, raw in reader.messages(connections=conns):
        if decode:
            typestore.deserialize_cdr(raw, conn.msgtype)
        count += 1
print(json.dumps({{"messages": count, "work_s": time.perf_counter() - start}}))
"""
REPLAY = """
import json, sys, time, warnings
warnings.filterwarnings("ignore")
sys.path.insert(0, {root!r})
from gap_validation.core.config import load_config
from gap_validation.bag.replay import replay
start = time.perf_counter()
outcome = replay([{bag!r}], load_config({config!r}), fast={fast!r}, diagnose={diagnose!r})
channels = {{n: [c.epsilon, c.nu_gap, c.sweeps] for n, c in outcome.result.channels.items()}}
print(json.dumps({{"messages": outcome.messages, "work_s": time.perf_counter() - start,
                  "channels": channels}}))
"""


def run_child(code: str) -> dict:
    """Run ``code`` in a fresh interpreter: its JSON line plus ``wall_s`` and ``cpu_s`` (the child's user +
    system time, from ``os.wait4``)."""
    with tempfile.TemporaryFile() as err:
        start = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=err,
                                env=os.environ.copy())
        out = proc.stdout.read()
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        proc.stdout.close()
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode:
            err.seek(0)
            raise SystemExit(f"child failed:\n{err.read().decode(errors='replace')[-2000:]}")
    data = json.loads(out.decode().strip().splitlines()[-1])
    data.update(wall_s=wall, cpu_s=usage.ru_utime + usage.ru_stime)
    return data


def simulated_bag(config, out: Path, minutes: float, imu_rate_hz: float, surface_rate_hz: float,
                  storage: str) -> Path:
    """About ``minutes`` of the test card (at least one sweep per channel), written as a rosbag2."""
    d = FlightOptions()
    card_s = len(config.channels) * (d.sweep_duration_s + 2 * d.quiet_s + 2 * d.doublet_half_period_s)
    options = FlightOptions(
        sweeps_per_channel=max(1, round(minutes * 60.0 / card_s)),
        imu_rate_hz=imu_rate_hz,
        surface_rate_hz=surface_rate_hz,
    )
    flight = simulate_flight(config, options=options, seed=1)
    print(
        f"simulated {flight.duration_s / 60:.1f} min at {imu_rate_hz:g} Hz IMU / {surface_rate_hz:g} Hz "
        "surfaces, "
        f"{flight.message_count} messages ({storage})"
    )
    return write_flight(flight, out, storage)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--bag", type=Path, help="bag to replay (default: simulate one)")
    parser.add_argument("--config", type=Path, default=ROOT / "config" / "ultrastick25e.yaml")
    parser.add_argument("--repeat", type=int, default=3, help="runs per variant; the fastest counts")
    parser.add_argument("--minutes", type=float, default=5.0, help="length of the simulated flight")
    parser.add_argument("--imu-rate-hz", type=float, default=1000.0)
    parser.add_argument("--surface-rate-hz", type=float, default=100.0)
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    args = parser.parse_args(argv)
    config = load_config(args.config)
    topics = sorted(config.topics())
    with tempfile.TemporaryDirectory() as tmp:
        bag = args.bag or simulated_bag(config, Path(tmp) / "bench", args.minutes, args.imu_rate_hz,
                                        args.surface_rate_hz, args.storage)
        children = {
            "plain": PLAIN.format(bag=str(bag), topics=topics, decode=True),
            "raw": PLAIN.format(bag=str(bag), topics=topics, decode=False),
            "fast": REPLAY.format(
                root=str(ROOT), bag=str(bag), config=str(args.config), fast=True, diagnose=False
            ),
            "full": REPLAY.format(
                root=str(ROOT), bag=str(bag), config=str(args.config), fast=False, diagnose=False
            ),
            "diagnose": REPLAY.format(
                root=str(ROOT), bag=str(bag), config=str(args.config), fast=True, diagnose=True
            ),
        }
        load_before = os.getloadavg()
        runs: dict[str, list[dict]] = {name: [] for name in children}
        for _ in range(args.repeat):
            for name, code in children.items():
                runs[name].append(run_child(code))
        load_after = os.getloadavg()
    same = len({json.dumps(r["channels"]) for name in ("fast", "full", "diagnose") for r in runs[name]}) == 1
    best = {name: min(rs, key=lambda r: r["wall_s"]) for name, rs in runs.items()}
    cpu = {name: min(r["cpu_s"] for r in rs) for name, rs in runs.items()}
    plain = best["plain"]
    print(
        f"load average before {load_before[0]:.2f}, after {load_after[0]:.2f} (1 min; {os.cpu_count()} "
        "cores); "
        f"best of {args.repeat} interleaved runs"
    )
    print(f"{'whole process':<38}{'messages':>10}{'wall s':>9}{'CPU s':>8}{'work s':>8}{'msgs/s':>12}"
          f"{'ratio':>7}{'CPU ratio':>10}")
    for label, key in (
        ("plain rosbags read + deserialise", "plain"),
        ("rosbags raw read (no deserialise)", "raw"),
        ("replay (fast: batches)", "fast"),
        ("replay (full deserialisation)", "full"),
        ("replay with the diagnosis (fast)", "diagnose"),
    ):
        r = best[key]
        print(f"{label:<38}{r['messages']:>10}{r['wall_s']:>9.2f}{cpu[key]:>8.2f}{r['work_s']:>8.2f}"
              f"{r['messages'] / r['wall_s']:>12,.0f}{plain['wall_s'] / r['wall_s']:>7.2f}"
              f"{cpu['plain'] / cpu[key]:>10.2f}")
    ratio = plain["wall_s"] / best["fast"]["wall_s"]
    print(f"whole-process ratio replay / plain rosbags read + deserialise = {ratio:.2f} (goal >= 3; CPU time "
          f"{cpu['plain'] / cpu['fast']:.2f}); replay results identical across runs and decodings: {same}")
    with_diagnosis = plain["wall_s"] / best["diagnose"]["wall_s"]
    print(
        f"whole-process ratio replay with the diagnosis / plain rosbags = {with_diagnosis:.2f} (goal >= 2; "
        "CPU time "
        f"{cpu['plain'] / cpu['diagnose']:.2f})"
    )
    return 0 if ratio >= 3.0 and with_diagnosis >= 2.0 and same else 1


if __name__ == "__main__":
    sys.exit(main())
