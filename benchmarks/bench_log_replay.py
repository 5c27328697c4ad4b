#!/usr/bin/env python3
"""Replay of a flight log against the format's own reader reading the same file (issue 24: replay at least as
fast as the reader alone).

A simulated flight of the bundled config (the default card, gyro 250 Hz, servos 50 Hz, a 40 ms delay hidden on
pitch) is written as a PX4 ULog and as an ArduPlane DataFlash log, each with the bulk of a real log beside the
streams the config reads (ULog: ten other PX4 topics at their rates, ``benchmarks/bench_ulog.py``; DataFlash:
the other message types of ``benchmarks/bench_dataflash.py``), so the wanted topics are a minority of the
bytes. Timed in the same process, best of ``--repeat``:

- ``replay``: ``gap_validation.bag.replay.replay([log], config)``: reading, routing, estimating and the full
  diagnosis, what ``gap-validate replay FLIGHT --config CFG`` does (one BLAS thread, as the command);
- the reader alone: ``pyulog.ULog(path)`` (PX4's reader, every topic: what a user's script does first) and
  with ``message_name_filter_list`` (the two topics); pymavlink's ``DFReader_binary(path)`` then
  ``recv_match`` over the wanted types until None (ArduPilot's reader).

Printed: seconds and ratios (replay / reader; below 1: replay is faster than reading the file with the
reader).

Usage::

    python benchmarks/bench_log_replay.py [--repeat 3]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from gap_validation.blas import single_threaded_blas  # noqa: E402

single_threaded_blas()      # as gap-validate does, before numpy loads

from gap_validation.bag.replay import replay  # noqa: E402
from gap_validation.cli.arguments import hidden_effects  # noqa: E402
from gap_validation.core.config import load_config  # noqa: E402
from gap_validation.core.simulation import FlightOptions, simulate_flight  # noqa: E402
from gap_validation.logs.base import WriteTopic  # noqa: E402
from gap_validation.logs.dataflash import write_dataflash  # noqa: E402
from gap_validation.logs.flight import BOOT_S, as_autopilot_logs, flight_topics, log_config, log_layout  # noqa: E402
from gap_validation.logs.ulog import write_ulog  # noqa: E402

CONFIG = ROOT / "config" / "ultrastick25e.yaml"


def _best(fn, repeat: int) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - start)
    return best, out


def _bulk(kind: str, topics: list[WriteTopic], minutes: float) -> list[WriteTopic]:
    """The other topics of a real log over the flight's span, on the flight's clock."""
    if kind == "ulog":
        from bench_ulog import flight_topics as more
        taken = {"vehicle_angular_velocity", "actuator_servos"}
    else:
        from bench_dataflash import flight as more
        taken = {t.name.split("[")[0] for t in topics}
    start = min(int(t.t_us[0]) for t in topics)
    out = []
    for t in more(minutes):
        if t.name.split("[")[0].split(":")[0] in taken:
            continue
        shifted = t.t_us - t.t_us[0] + start
        fields = {k: (v - t.t_us[0] + start if k == "timestamp_sample" else v) for k, v in t.fields.items()}
        out.append(WriteTopic(t.name, shifted, fields, dict(t.units)))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args(argv)
    import pyulog
    from pymavlink import DFReader

    config = load_config(CONFIG)
    flight = simulate_flight(config, hidden_effects(["pitch:time_delay:seconds=0.04"], config),
                             FlightOptions(imu_rate_hz=250.0, surface_rate_hz=50.0), seed=args.seed)
    minutes = flight.duration_s / 60.0
    tmp = Path(tempfile.mkdtemp(prefix="bench_log_replay_"))
    print(f"flight: {minutes:.1f} min (default card), gyro 250 Hz, servos 50 Hz, pitch delay 40 ms hidden")
    for kind in ("ulog", "dataflash"):
        layout, _ = log_layout(config, kind)
        topics = as_autopilot_logs(flight_topics(flight, config, layout), kind)
        cfg_path = tmp / f"{kind}.yaml"
        import yaml
        cfg_path.write_text(yaml.safe_dump(log_config(config, layout, str(CONFIG)), sort_keys=False))
        log_cfg = load_config(cfg_path)
        path = tmp / ("flight.ulg" if kind == "ulog" else "flight.bin")
        every = topics + _bulk(kind, topics, minutes + BOOT_S / 60.0)
        if kind == "ulog":
            write_ulog(path, every, start_us=int(BOOT_S * 1e6))
        else:
            write_dataflash(path, every)
        wanted = sorted(topic.lstrip("/") for topic in log_cfg.topics())
        share = sum(t.t_us.size for t in topics) / sum(t.t_us.size for t in every)
        t_replay, outcome = _best(lambda: replay([path], log_cfg), args.repeat)
        pitch = outcome.result.channels["pitch"]
        named = pitch.diagnosis[0]["sentence"] if pitch.diagnosis else "nothing named"
        print(
            f"\n{kind}: {path.stat().st_size / 1e6:.1f} MB, {len(every)} topics/types, the {len(wanted)} "
            "read "
            f"({', '.join(wanted)}) {100 * share:.0f} % of the messages; pitch epsilon {pitch.epsilon:.2f}: "
            f"{named[:80]}"
        )
        print(f"  replay (read, route, estimate, diagnose): {t_replay:.2f} s")
        if kind == "ulog":
            t_all, _ = _best(lambda: pyulog.ULog(str(path)), args.repeat)
            t_some, _ = _best(lambda: pyulog.ULog(str(path), message_name_filter_list=wanted), args.repeat)
            print(f"  pyulog.ULog, every topic: {t_all:.2f} s -> replay / reader {t_replay / t_all:.2f}")
            print(
                f"  pyulog.ULog, the {len(wanted)} topics: {t_some:.2f} s -> replay / reader "
                f"{t_replay / t_some:.2f}"
            )
        else:
            types = sorted({w.split("[")[0] for w in wanted})

            def dfreader():
                reader = DFReader.DFReader_binary(str(path), zero_time_base=False)
                n = 0
                while reader.recv_match(type=types) is not None:
                    n += 1
                return n

            t_df, n = _best(dfreader, args.repeat)
            print(
                f"  DFReader recv_match over {', '.join(types)} ({n} messages): {t_df:.2f} s -> replay / "
                "reader "
                f"{t_replay / t_df:.2f}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
