"""Issue 13's done-when, measured over seeds: closed-loop flights in turbulence with and without
``excitation``, coupled surfaces with and without ``other_inputs`` (docs/closed_loop.md, the "Measured"
table).

    python benchmarks/closed_loop.py [--seeds 1 2 3 4 5]

Per seed: a clean airframe and one with a hidden 35 ms delay, flown inside a rate damper with a 6 dB gain
margin and 0.05 rad/s of turbulence (three 90 s roll sweeps, 12 s of trim between manoeuvres), validated with
and without ``excitation``; and a roll-yaw flight whose rudder moves with 0.3 x the aileron (the roll rate
answering the rudder through a lightly damped 3 rad/s term), the rudder also swept on its own, validated with
and without ``other_inputs``.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "test"))

from test_closed_loop import CLOSED_LOOP, COUPLED, roll_config, validate  # noqa: E402

from gap_validation.core.simulation import simulate_flight, with_options  # noqa: E402


def _row(ch) -> str:
    top = ch.diagnosis[0] if ch.diagnosis else None
    named = f"{top.effect} {top.parameters}" if top else "-"
    eps = f"{ch.epsilon:.3f}" if ch.epsilon is not None else "-"
    return f"eps {eps:>6}  limited {ch.limited_by:<5} named {named:<34} warnings {len(ch.warnings)}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    args = parser.parse_args()
    start = time.time()
    for seed in args.seeds:
        for label, hidden in (("clean", {}), ("35 ms", {"roll": [{"type": "time_delay", "seconds": 0.035}]})):
            flight = simulate_flight(roll_config(), hidden, with_options(**CLOSED_LOOP), seed=seed)
            for excitation in (True, False):
                ch = validate(roll_config(excitation=excitation), flight).channels["roll"]
                print(f"seed {seed} closed loop {label:<5} {'with' if excitation else 'without'} excitation: "
                      f"{_row(ch)}", flush=True)
        flight = simulate_flight(
            roll_config(channels=("roll", "yaw")), {}, with_options(**COUPLED), seed=seed
        )
        for other in (True, False):
            result = validate(roll_config(channels=("roll", "yaw"), other_inputs=other), flight)
            ch = result.channels["roll"]
            rudder = any("position[rudder]" in w for w in ch.warnings)
            print(
                f"seed {seed} coupled roll {'with' if other else 'without'} other_inputs: {_row(ch)} "
                f"(names the rudder: {rudder}; yaw warnings {len(result.channels['yaw'].warnings)})",
                flush=True,
            )
    print(f"{time.time() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
