#!/usr/bin/env python3
"""DataFlash reading speed: :class:`~gap_validation.logs.dataflash.DataFlashFile` against pymavlink's
``DFReader`` on the same file, in the same run.

A copter system-identification flight of ``--minutes`` (10 by default) is written with
:func:`~gap_validation.logs.dataflash.write_dataflash`, at ArduPilot's rates with fast logging: ``RATE`` and
``SIDD`` at 400 Hz and ``RCOU`` at 50 Hz (the wanted ones), and as many other messages as a real log has
(``IMU[0]``, ``IMU[1]``, ``PIDR``, ``PIDP``, ``PIDY``, ``ATT`` at 400 Hz; ``CTUN``, ``BARO``, ``GPS``,
``BAT``, ``MAG``, ``VIBE`` at 10 Hz), so that the wanted messages are about a quarter of the file. Then timed:

* *DFReader recv_match*: ``DFReader_binary(path)`` (its index) and ``recv_match(type=[RATE, SIDD, RCOU])``
  until None, the usual way; also with the wanted fields taken from each message (``getattr``);
* *DFReader whole file*: ``recv_msg()`` until None (every message decoded);
* *ours*: ``DataFlashFile(path)``, ``.topics`` and ``.read(wanted)`` (the wanted fields as float64 arrays),
  the best of ``--repeat`` runs, and its peak of allocations (tracemalloc, numpy included).

The ratios are ours / DFReader (below 1: ours is faster). The numbers read are checked to be the same.

Usage::

    python benchmarks/bench_dataflash.py [--minutes 10] [--repeat 3] [--no-whole-file] [--keep FILE.bin]
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

from pymavlink import DFReader  # noqa: E402

from gap_validation.logs.base import WriteTopic  # noqa: E402
from gap_validation.logs.dataflash import DataFlashFile, write_dataflash  # noqa: E402

WANTED = {"RATE": ["ROut", "POut", "YOut", "R", "P", "Y"], "SIDD": ["Targ", "Gx", "Gy", "Gz"],
          "RCOU": ["C1", "C2", "C3", "C4"]}
RATE = "RDes,R,ROut,PDes,P,POut,YDes,Y,YOut,ADes,A,AOut,AOutSlew".split(",")
SIDD = "Time,Targ,F,Gx,Gy,Gz,Ax,Ay,Az".split(",")
PID = "Tar,Act,Err,P,I,D,FF,DFF,Dmod,SRate,Flags".split(",")
OTHERS_400 = {"ATT": "DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw".split(","),
              "PIDR": PID, "PIDP": PID, "PIDY": PID}
OTHERS_10 = {"CTUN": "ThI,ABst,ThO,ThH,DAlt,Alt,BAlt,DSAlt,SAlt,TAlt,DCRt,CRt".split(","),
             "BARO": "Alt,Press,Temp,CRt,SMS,Offset,GndTemp".split(","),
             "GPS": "Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw".split(","),
             "BAT": "Volt,VoltR,Curr,CurrTot,EnrgTot,Temp,Res".split(","),
             "MAG": "MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ".split(","),
             "VIBE": "VibeX,VibeY,VibeZ,Clip".split(",")}
IMU = "GyrX,GyrY,GyrZ,AccX,AccY,AccZ,T".split(",")


def flight(minutes: float, seed: int = 0) -> list[WriteTopic]:
    """The topics of the benchmark flight (float32 columns, as ArduPilot logs them; PWM for RCOU)."""
    rng = np.random.default_rng(seed)
    t400 = np.arange(int(minutes * 60 * 400), dtype=np.int64) * 2500
    t50, t10 = t400[::8] + 300, t400[::40] + 700

    def cols(names, t):
        return {c: rng.normal(size=len(t)).astype(np.float32) for c in names}

    topics = [WriteTopic("RATE", t400, cols(RATE, t400)), WriteTopic("SIDD", t400 + 100, cols(SIDD, t400)),
              WriteTopic("RCOU", t50, {f"C{k}": 1500 + rng.integers(-400, 400, len(t50)).astype(np.uint16)
                                       for k in range(1, 15)})]
    topics += [WriteTopic(f"IMU[{k}]", t400 + 50 + k, cols(IMU, t400)) for k in (0, 1)]
    topics += [WriteTopic(name, t400 + 150, cols(c, t400)) for name, c in OTHERS_400.items()]
    topics += [WriteTopic(name, t10, cols(c, t10)) for name, c in OTHERS_10.items()]
    return topics


def dfreader_match(path: Path, fields: bool) -> tuple[float, float, dict[str, int], dict]:
    """DFReader's index, then recv_match over the wanted types: (index s, total s, counts, first values)."""
    start = time.perf_counter()
    reader = DFReader.DFReader_binary(str(path))
    indexed = time.perf_counter()
    counts = {t: 0 for t in WANTED}
    values = {t: [] for t in WANTED}
    while True:
        m = reader.recv_match(type=list(WANTED))
        if m is None:
            break
        name = m.get_type()
        counts[name] += 1
        if fields:
            values[name].append([getattr(m, f) for f in WANTED[name]])
    done = time.perf_counter()
    return indexed - start, done - start, counts, values


def dfreader_whole(path: Path) -> tuple[float, int]:
    """DFReader decoding every message (recv_msg until None)."""
    start = time.perf_counter()
    reader = DFReader.DFReader_binary(str(path))
    n = 0
    while reader.recv_msg() is not None:
        n += 1
    return time.perf_counter() - start, n


def ours(path: Path) -> tuple[float, float, dict]:
    """DataFlashFile: open, topics, read the wanted fields. (seconds, topics part, series)."""
    start = time.perf_counter()
    with DataFlashFile(path) as log:
        topics = log.topics
        listed = time.perf_counter()
        series = log.read(WANTED)
    done = time.perf_counter()
    assert all(topics[t].count == len(series[t].t_s) for t in WANTED)
    return done - start, listed - start, series


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--no-whole-file", action="store_true", help="skip DFReader's whole-file pass")
    parser.add_argument("--keep", type=Path, help="write the log here (and keep it)")
    args = parser.parse_args(argv)

    with tempfile.TemporaryDirectory() as tmp:
        path = args.keep or Path(tmp) / "FLIGHT.bin"
        start = time.perf_counter()
        topics = flight(args.minutes)
        write_dataflash(path, topics, start_us=12_000_000)
        n_msgs = sum(len(t.t_us) for t in topics)
        n_wanted = sum(len(t.t_us) for t in topics if t.name in WANTED)
        del topics
        print(f"log: {args.minutes:g} min, {path.stat().st_size / 1e6:.1f} MB, {n_msgs} messages, "
              f"{n_wanted} wanted ({100 * n_wanted / n_msgs:.0f} %), {len(WANTED)} types; "
              f"written in {time.perf_counter() - start:.1f} s; load {os.getloadavg()[0]:.2f}")

        runs = [ours(path) for _ in range(max(1, args.repeat))]
        best = min(r[0] for r in runs)
        tracemalloc.start()
        _, _, series = ours(path)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        kept = sum(s.values.nbytes + s.t_s.nbytes for s in series.values())
        print(
            f"ours: {best:.3f} s (runs {', '.join(f'{r[0]:.3f}' for r in runs)}; topics walk "
            f"{min(r[1] for r in runs):.3f} s); peak allocations {peak / 1e6:.1f} MB, kept {kept / 1e6:.1f} "
            "MB"
        )

        index_s, match_s, counts, _ = dfreader_match(path, fields=False)
        print(f"DFReader recv_match: {match_s:.2f} s (index {index_s:.2f} s); ours / DFReader = "
              f"{best / match_s:.4f} ({match_s / best:.0f}x faster)")
        assert counts == {t: len(series[t].t_s) for t in WANTED}, (
            counts,
            {t: len(s.t_s) for t, s in series.items()},
        )
        _, fields_s, _, values = dfreader_match(path, fields=True)
        for topic, rows in values.items():
            assert np.array_equal(np.array(rows, float), series[topic].values), topic
        print(f"DFReader recv_match + fields: {fields_s:.2f} s; ours / DFReader = {best / fields_s:.4f} "
              f"({fields_s / best:.0f}x faster); the same numbers")
        if not args.no_whole_file:
            whole_s, n = dfreader_whole(path)
            assert n >= n_msgs
            print(f"DFReader whole file (recv_msg, {n} messages): {whole_s:.2f} s; ours / DFReader = "
                  f"{best / whole_s:.4f} ({whole_s / best:.0f}x faster)")
        print(f"load after {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
