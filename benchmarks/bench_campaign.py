#!/usr/bin/env python3
"""Campaign scale benchmark: 100 flights on a local Dask cluster with 1 and with 2 workers, in the same run.

A fleet is simulated first (``benchmarks/make_fleet.py``: ``--aircraft`` x ``--weeks`` short flights, UAV-3's
pitch delay drifting), then ``gap_validation.campaign.runner.run_campaign`` runs it into a fresh directory
with 1 worker and again with 2 (cluster start, every replay with its diagnosis, campaign.json/csv and
index.html included: the whole wall time a user waits). Printed: both wall times and their ratio (the
speed-up), the flights' summed task time, the time to fingerprint every flight, and a re-run that reuses every
result. The epsilons of the two runs must be identical.

Usage::

    python benchmarks/bench_campaign.py [--aircraft 10] [--weeks 10] [--channels roll,pitch,yaw] [--keep DIR]
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gap_validation.campaign.fingerprint import flight_fingerprint  # noqa: E402
from gap_validation.campaign.manifest import load_manifest  # noqa: E402
from gap_validation.campaign.runner import run_campaign  # noqa: E402
from gap_validation.campaign.task import TASK_OPTIONS  # noqa: E402


def _make_fleet():
    spec = importlib.util.spec_from_file_location("make_fleet", ROOT / "benchmarks" / "make_fleet.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def timed_campaign(manifest, out: Path, workers: int):
    """(outcome, wall seconds, load average over the last minute at the end)."""
    start = time.perf_counter()
    outcome = run_campaign(manifest, out, workers=workers)
    return outcome, time.perf_counter() - start, os.getloadavg()[0]


def task_line(outcome) -> str:
    """Summed task wall and CPU time: a task gets less than a core when the machine is shared."""
    wall = sum(o.elapsed_s or 0.0 for o in outcome.flights)
    cpu = sum(o.cpu_s or 0.0 for o in outcome.flights)
    return (
        f"tasks {wall:.1f} s wall, {cpu:.1f} s CPU ({cpu / wall:.0%} of a core each)" if wall else "no task"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--aircraft", type=int, default=10)
    p.add_argument("--weeks", type=int, default=10)
    p.add_argument("--channels", default="roll,pitch,yaw")
    p.add_argument(
        "--keep", type=Path, help="write the fleet and results here (default: a temporary directory)"
    )
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bench_campaign_") as tmp:
        base = args.keep or Path(tmp)
        began = time.perf_counter()
        manifest_path = _make_fleet().make_fleet(base / "fleet", aircraft=args.aircraft, weeks=args.weeks,
                                                 channels=args.channels.split(","), force=True)
        made = time.perf_counter() - began
        manifest = load_manifest(manifest_path)
        n = len(manifest.flights)
        size = sum(f.stat().st_size for f in (base / "fleet" / "bags").rglob("*") if f.is_file())
        print(
            f"fleet: {n} flights ({args.aircraft} aircraft x {args.weeks} weeks, channels {args.channels}), "
            f"{size / 1e6:.1f} MB of mcap, simulated in {made:.1f} s"
        )
        began = time.perf_counter()
        for f in manifest.flights:
            flight_fingerprint(f.bags, f.config, TASK_OPTIONS)
        hashed = time.perf_counter() - began
        one, t1, load1 = timed_campaign(manifest, base / "out1", 1)
        two, t2, load2 = timed_campaign(manifest, base / "out2", 2)
        again, t_again, _ = timed_campaign(manifest, base / "out2", 2)
        eps = [
            [o.channels[c]["epsilon"] for o in run.flights for c in sorted(o.channels)] for run in (one, two)
        ]
        print(
            f"1 worker:  {t1:6.1f} s wall ({t1 / n:.2f} s per flight; {task_line(one)}; load average "
            f"{load1:.1f})"
        )
        print(
            f"2 workers: {t2:6.1f} s wall ({t2 / n:.2f} s per flight; {task_line(two)}; load average "
            f"{load2:.1f})"
        )
        print(f"ratio 1 worker / 2 workers: {t1 / t2:.2f}   (2 would be perfect scaling on 2 idle cores; "
              f"{os.cpu_count()} cores here)")
        print(
            f"fingerprints of all {n} flights: {hashed:.2f} s; re-run reusing every result: {t_again:.1f} s "
            f"({again.count('reused')} reused)"
        )
        print(f"epsilons identical with 1 and 2 workers: {eps[0] == eps[1]}; failed flights: "
              f"{one.count('failed') + two.count('failed')}")
        for finding in (f for f in two.findings if f.significant):
            print(f"  {finding.sentence()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
