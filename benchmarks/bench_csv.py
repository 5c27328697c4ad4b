#!/usr/bin/env python3
"""CSV log reading speed: our reader against the ``csv`` module on the same file, measured in the same run.

One topic file of ``--rows`` rows (default 500 000) with a microsecond time column and three value columns is
written with :func:`gap_validation.logs.csvlog.write_csv`; then, interleaved ``--repeat`` times (the fastest
run counts; the machine may be shared):

* *ours*: ``open_log(path).read({topic: ["a", "c"]})`` (numpy's parser, the ``csv`` module only for files
  numpy refuses);
* *csv module*: ``csv.reader`` over the file, the time column and the two wanted columns gathered as strings
  and converted with ``np.array(..., dtype=float)``.

The ratio is ``ours / csv module`` (below 1: ours is faster). Each run's values are checked equal.

Usage::

    python benchmarks/bench_csv.py [--rows 500000] [--repeat 3]
"""
from __future__ import annotations

import argparse
import csv
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gap_validation.logs.base import WriteTopic
from gap_validation.logs.csvlog import write_csv  # noqa: E402
from gap_validation.logs.formats import open_log  # noqa: E402


def _ours(path: Path) -> tuple[float, np.ndarray, np.ndarray]:
    start = time.perf_counter()
    series = open_log(path).read({"big": ["a", "c"]})["big"]
    return time.perf_counter() - start, series.t_s, series.values


def _csv_module(path: Path) -> tuple[float, np.ndarray]:
    start = time.perf_counter()
    with open(path, newline="") as f:
        rows = csv.reader(f)
        next(rows)
        cols: list[list[str]] = [[], [], []]
        for row in rows:
            cols[0].append(row[0])
            cols[1].append(row[1])
            cols[2].append(row[3])
    reference = np.array(cols, dtype=float)
    return time.perf_counter() - start, reference


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rows", type=int, default=500_000)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    rng = np.random.default_rng(1)
    topic = WriteTopic("big", np.arange(args.rows, dtype=np.int64) * 4000,
                       {k: rng.standard_normal(args.rows) for k in "abc"})
    with tempfile.TemporaryDirectory() as tmp:
        path = write_csv(Path(tmp), [topic])[0]
        size_mb = path.stat().st_size / 1e6
        ours_s, theirs_s = [], []
        for _ in range(args.repeat):
            s, t_s, values = _ours(path)
            r, reference = _csv_module(path)
            if not (np.array_equal(values[:, 0], reference[1]) and np.array_equal(values[:, 1], reference[2])
                    and np.array_equal(t_s, reference[0] * 1e-6)):
                print("values differ from the csv module's", file=sys.stderr)
                return 1
            ours_s.append(s)
            theirs_s.append(r)
    ours, theirs = min(ours_s), min(theirs_s)
    print(f"{args.rows} rows, 4 columns, {size_mb:.1f} MB; 2 columns wanted; fastest of {args.repeat}")
    print(f"ours        {ours:7.3f} s")
    print(f"csv module  {theirs:7.3f} s")
    print(f"ratio ours / csv module: {ours / theirs:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
