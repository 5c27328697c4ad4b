#!/usr/bin/env python3
"""ULog reading speed: our reader against pyulog on the same flight-sized log, measured in the same run.

A log of ``--minutes`` (default 10) is written with :func:`gap_validation.logs.ulog.write_ulog` in PX4's
layouts and at PX4-like rates: the wanted topics ``vehicle_angular_velocity`` (250 Hz) and ``actuator_servos``
(50 Hz), and, as a real log has them, more bytes of topics nobody asked for (``sensor_combined``,
``sensor_accel``, two ``sensor_gyro`` instances and ``vehicle_rates_setpoint`` at 250 Hz, ``vehicle_attitude``
at 100 Hz, ``vehicle_local_position``, ``estimator_states`` and ``actuator_motors`` at 50 Hz,
``battery_status`` at 10 Hz). Then, interleaved ``--repeat`` times (the fastest run counts; the machine may be
shared):

* *pyulog all*: ``pyulog.ULog(path)``, every topic (what the issue's goal compares with);
* *pyulog filtered*: ``pyulog.ULog(path, message_name_filter_list=[the wanted topics])``;
* *ours, read*: ``ULogFile(path).read(wanted)`` (one pass: topics and samples);
* *ours, topics + read*: ``ULogFile(path).topics`` then ``.read(wanted)`` (two passes, as a caller that checks
  the topics first does);
* *ours, blocks*: ``ULogFile(path).blocks(wanted)`` and every block of it (what replay does: a pass noting
  where the wanted messages are, the topics known after it, then each 1 MiB block read again and gathered;
  replay holds a block, not the series).

Ratios are ``ours / pyulog`` (below 1: ours is faster). Every run's result is checked equal to pyulog's.

Usage::

    python benchmarks/bench_ulog.py [--minutes 10] [--repeat 3] [--keep FILE.ulg]
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import pyulog  # noqa: E402

from gap_validation.logs.base import LogBlocks, WriteTopic, join_blocks  # noqa: E402
from gap_validation.logs.ulog import ULogFile, write_ulog  # noqa: E402

WANTED = {"vehicle_angular_velocity": ["xyz[0]", "xyz[1]", "xyz[2]"],
          "actuator_servos": ["control[0]", "control[1]", "control[2]", "control[3]"]}


def _floats(rng, n: int, names: list[str]) -> dict[str, np.ndarray]:
    out = {}
    for name in names:
        base, _, size = name.partition("*")
        if size:
            out.update({f"{base}[{i}]": rng.standard_normal(n).astype(np.float32) for i in range(int(size))})
        else:
            out[name] = rng.standard_normal(n).astype(np.float32)
    return out


def flight_topics(minutes: float, seed: int = 0) -> list[WriteTopic]:
    """PX4-like topics of a flight: the wanted ones and the bulk of a real log (random float32 values).

    Parameters
    ----------
    minutes : float
        Length of the flight.
    seed : int
        Seed of the values.
    """
    rng = np.random.default_rng(seed)
    end_us = int(minutes * 60e6)

    def times(rate_hz: float, phase_us: int) -> np.ndarray:
        return np.arange(1_000_000 + phase_us, end_us, int(1e6 / rate_hz), dtype=np.int64)

    def topic(name: str, rate_hz: float, phase_us: int, fields: list[str], sample: bool = True,
              extra: dict | None = None) -> WriteTopic:
        t = times(rate_hz, phase_us)
        f = {"timestamp_sample": t - 150} if sample else {}
        f.update(_floats(rng, len(t), fields))
        for key, (dtype, value) in (extra or {}).items():
            f[key] = np.full(len(t), value, dtype)
        return WriteTopic(name, t, f)

    gyro_extra = {"device_id": (np.uint32, 2293768), "error_count": (np.uint32, 0), "samples": (np.uint8, 4)}
    return [
        topic("vehicle_angular_velocity", 250, 0, ["xyz*3", "xyz_derivative*3"]),
        topic("actuator_servos", 50, 300, ["control*8"]),
        topic(
            "sensor_combined",
            250,
            50,
            ["gyro_rad*3", "gyro_integral_dt", "accelerometer_m_s2*3", "accelerometer_integral_dt"],
            sample=False,
        ),
        topic("sensor_accel", 250, 70, ["x", "y", "z", "temperature"], extra=gyro_extra),
        topic("sensor_gyro", 250, 90, ["x", "y", "z", "temperature"], extra=gyro_extra),
        topic("sensor_gyro:1", 250, 110, ["x", "y", "z", "temperature"], extra=gyro_extra),
        topic("vehicle_rates_setpoint", 250, 130, ["roll", "pitch", "yaw", "thrust_body*3"], sample=False),
        topic("vehicle_attitude", 100, 170, ["q*4", "delta_q_reset*4"]),
        topic(
            "vehicle_local_position",
            50,
            210,
            [
                "x",
                "y",
                "z",
                "vx",
                "vy",
                "vz",
                "ax",
                "ay",
                "az",
                "heading",
                "delta_xy*2",
                "delta_vxy*2",
                "eph",
                "epv",
                "evh",
                "evv",
                "vxy_max",
                "vz_max",
                "hagl_min",
                "hagl_max",
                "ref_lat",
                "ref_lon",
                "ref_alt",
                "dist_bottom",
                "z_deriv",
                "yaw",
            ],
        ),
        topic("estimator_states", 50, 250, ["states*24", "covariances*24"]),
        topic("actuator_motors", 50, 290, ["control*12"]),
        topic("battery_status", 10, 330, ["voltage_v", "current_a", "remaining", "temperature"]),
    ]


def _check(ours: dict, path: Path) -> None:
    ref = pyulog.ULog(str(path), message_name_filter_list=list(WANTED))
    for topic, fields in WANTED.items():
        d = ref.get_dataset(topic)
        assert np.array_equal(ours[topic].t_s, d.data["timestamp_sample"] / 1e6), topic
        for j, name in enumerate(fields):
            assert np.array_equal(ours[topic].values[:, j], d.data[name].astype(np.float64)), (topic, name)


def _every_block(blocks: LogBlocks) -> LogBlocks:
    """Iterate ``blocks`` once (each block dropped as the next comes, as replay does)."""
    for _ in blocks:
        pass
    return blocks


def _timed(fn):
    start = time.perf_counter()
    out = fn()
    return time.perf_counter() - start, out


def main(argv: list[str] | None = None) -> int:
    """Write the log, time the readers, print the table.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (default ``sys.argv[1:]``).
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--keep", type=Path, help="write the log here (kept) instead of a temporary file")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        path = args.keep or Path(tmp) / "flight.ulg"
        seconds, _ = _timed(lambda: write_ulog(path, flight_topics(args.minutes), start_us=0,
                                               info={"sys_name": "PX4", "ver_hw": "SITL"}))
        size = path.stat().st_size
        with ULogFile(path) as log:
            table = log.topics
        n_msgs = sum(t.count for t in table.values())
        wanted_msgs = sum(table[t].count for t in WANTED)
        ref = pyulog.ULog(str(path), message_name_filter_list=list(WANTED))
        wanted_bytes = sum(len(d.data["timestamp"]) * (5 + sum(a.itemsize for a in d.data.values()))
                           for d in ref.data_list)
        print(
            f"log: {args.minutes:g} min, {size / 1e6:.1f} MB, {n_msgs} data messages of {len(table)} topics, "
            f"written in {seconds:.2f} s; wanted: {100 * wanted_msgs / n_msgs:.0f} % of the messages, "
            f"{100 * wanted_bytes / size:.0f} % of the bytes"
        )
        print(f"load average before: {os.getloadavg()[0]:.2f}")
        variants = {
            "pyulog all": lambda: pyulog.ULog(str(path)),
            "pyulog filtered": lambda: pyulog.ULog(str(path), message_name_filter_list=list(WANTED)),
            "ours, read": lambda: ULogFile(path).read(WANTED),
            "ours, topics + read": lambda: (lambda f: (f.topics, f.read(WANTED))[1])(ULogFile(path)),
            "ours, blocks": lambda: _every_block(ULogFile(path).blocks(WANTED)),
        }
        best = {name: float("inf") for name in variants}
        for _ in range(args.repeat):
            for name, fn in variants.items():
                seconds, out = _timed(fn)
                best[name] = min(best[name], seconds)
                if name.startswith("ours"):
                    _check(join_blocks(out) if isinstance(out, LogBlocks) else out, path)
        print(f"load average after:  {os.getloadavg()[0]:.2f}")
        peak = {}
        for name, fn in variants.items():           # a separate run each (tracemalloc slows the code down)
            tracemalloc.start()
            out = fn()
            peak[name] = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
            del out
        print(
            f"\n{'variant':22s} {'best s':>8s} {'/ pyulog all':>13s} {'/ pyulog filtered':>18s} "
            f"{'us/msg':>7s} "
            f"{'peak MB':>8s}"
        )
        for name, seconds in best.items():
            print(f"{name:22s} {seconds:8.3f} {seconds / best['pyulog all']:13.3f} "
                  f"{seconds / best['pyulog filtered']:18.3f} {1e6 * seconds / n_msgs:7.2f} "
                  f"{peak[name] / 1e6:8.1f}")
        print("(peak MB: the largest memory held during the read, tracemalloc: Python and numpy allocations)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
