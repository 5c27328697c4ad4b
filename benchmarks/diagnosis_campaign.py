#!/usr/bin/env python3
"""Diagnosis on flights the tests never saw: random hidden effects, parameters, rates, noise and seeds.

Each case simulates a flight (``gap-validate simulate``) from ``config/ultrastick25e.yaml`` with one random
effect (or a lag + delay pair) hidden in one random channel, at random IMU/surface rates and noise levels,
replays it (``gap-validate replay``) and checks that the top candidate of that channel names the hidden effect
with its parameters within 20 % (dampings within 50 %: window smearing biases them), that adding it halves
epsilon, and that the clean channels get no candidate (no false alarm). Prints one line per case and the
totals.

Usage::

    python benchmarks/diagnosis_campaign.py [--seed 1] [--cases 8]
"""
from __future__ import annotations

import argparse
import json
import os
import random
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "ultrastick25e.yaml"
CLI = [sys.executable, "-c", "import sys; from gap_validation.cli.main import main; sys.exit(main())"]


def random_case(rng: random.Random) -> tuple[str, list[dict]]:
    """(channel, hidden effects) drawn from physically sensible ranges."""
    channel = rng.choice(["roll", "pitch", "yaw"])
    kind = rng.choice(
        ["time_delay", "first_order_lag", "second_order_lag", "gain", "structural_mode", "pair"]
    )
    if kind == "time_delay":
        effects = [{"type": kind, "seconds": rng.uniform(0.015, 0.08)}]
    elif kind == "first_order_lag":
        effects = [{"type": kind, "bandwidth_rad_s": rng.uniform(10, 40)}]
    elif kind == "second_order_lag":
        effects = [
            {"type": kind, "natural_frequency_rad_s": rng.uniform(12, 40), "damping": rng.uniform(0.4, 0.9)}
        ]
    elif kind == "gain":
        effects = [{"type": kind, "factor": rng.choice([rng.uniform(0.6, 0.8), rng.uniform(1.25, 1.6)])}]
    elif kind == "structural_mode":
        wp = rng.uniform(8, 30)
        effects = [
            {
                "type": kind,
                "frequency_rad_s": wp,
                "damping": rng.uniform(0.05, 0.15),
                "zero_frequency_rad_s": wp * rng.uniform(0.8, 0.9),
                "zero_damping": rng.uniform(0.05, 0.15),
            }
        ]
    else:
        effects = [{"type": "first_order_lag", "bandwidth_rad_s": rng.uniform(15, 40)},
                   {"type": "time_delay", "seconds": rng.uniform(0.02, 0.06)}]
    return channel, effects


def hidden_arg(channel: str, effect: dict) -> str:
    params = ",".join(f"{k}={v:.4g}" for k, v in effect.items() if k != "type")
    return f"{channel}:{effect['type']}:{params}"


def parameters_match(hidden: list[dict], found: list[dict]) -> bool:
    if sorted(e["type"] for e in hidden) != sorted(e["type"] for e in found):
        return False
    by_type = {e["type"]: e for e in found}
    for e in hidden:
        for key, value in e.items():
            if key == "type":
                continue
            tolerance = 0.5 if "damping" in key else 0.2
            if abs(by_type[e["type"]][key] - value) > tolerance * abs(value):
                return False
    return True


def run_case(index: int, rng: random.Random, tmp: Path) -> tuple[bool, bool]:
    channel, effects = random_case(rng)
    imu, surf = rng.choice([50, 100, 200]), rng.choice([25, 50, 100])
    noise, seed = rng.choice([0.5, 1.0, 2.0]), rng.randrange(1000)
    bag, out = tmp / f"flight{index}", tmp / f"flight{index}.json"
    args = [
        "simulate",
        "--config",
        str(CONFIG),
        "--out",
        str(bag),
        "--seed",
        str(seed),
        "--imu-rate-hz",
        str(imu),
        "--surface-rate-hz",
        str(surf),
        "--noise",
        str(noise),
        "--force",
    ]
    for effect in effects:
        args += ["--hidden", hidden_arg(channel, effect)]
    env = os.environ.copy()
    subprocess.run(CLI + args, check=True, capture_output=True, env=env, cwd=ROOT)
    subprocess.run(CLI + ["replay", str(bag), "--config", str(CONFIG), "--json", str(out), "--no-history",
                          "--no-progress"], capture_output=True, env=env, cwd=ROOT)
    result = json.loads(out.read_text())["channels"]
    top = (result[channel]["diagnosis"] or [None])[0]
    found = (
        bool(top)
        and parameters_match(effects, top["effects"])
        and top["epsilon"] <= result[channel]["epsilon"] / 2
    )
    false_alarm = any(result[c]["diagnosis"] for c in result if c != channel)
    told = (
        "-"
        if not top
        else f"{top['effect']} {top['parameters']} eps {result[channel]['epsilon']:.2f}->{top['epsilon']:.2f}"
    )
    print(
        f"{index:3d} {'ok ' if found else 'MISS'} {'FALSE ALARM' if false_alarm else ''} hidden "
        f"{[hidden_arg(channel, e) for e in effects]} imu {imu} Hz surf {surf} Hz noise x{noise} seed "
        f"{seed}: {told}"
    )
    sys.stdout.flush()
    return found, false_alarm


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--cases", type=int, default=8)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        outcomes = [run_case(i, rng, Path(tmp)) for i in range(args.cases)]
    found = sum(f for f, _ in outcomes)
    alarms = sum(a for _, a in outcomes)
    print(
        "hidden effect named (params within 20 %, dampings 50 %) and epsilon at least halved: "
        f"{found}/{args.cases}; "
        f"cases with a false alarm on a clean channel: {alarms}/{args.cases} ({2 * args.cases} clean "
        "channels)"
    )


if __name__ == "__main__":
    main()
