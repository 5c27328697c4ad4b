"""MIMO validation from flight data (issue 14) over simulated lateral flights: the model that flew, and the
same model with 0.6 x aileron effectiveness (its B column scaled).

Each flight: aileron sweeps then rudder sweeps in turn (``gap-validate simulate``'s test card), the truth the
full lateral-directional state space of ``config/ultrastick25e_lateral.yaml``, gusts and sensor noise.
Prints per seed the MIMO nu-gap and verdict of both models, the dominant element and the diagnosed aileron
gain, then the counts: the model that flew must never be model-limited (a nu-gap above 0.15 only where the
data are data-limited: short flights leave the lowest frequencies to the gusts), the weakened one always.

    python benchmarks/mimo_flights.py [--seeds 10] [--sweeps 2] [--sweep-duration 40] [--sweep-gap-s 3]
"""
from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gap_validation.core.config import (
    load_config,  # noqa: E402
    parse_config,  # noqa: E402
)
from gap_validation.core.simulation import simulate_flight, with_options  # noqa: E402
from gap_validation.core.validator import OnlineValidator  # noqa: E402

CONFIG = ROOT / "config" / "ultrastick25e_lateral.yaml"


def weakened(config, factor: float):
    """The config with the aileron (first) column of B scaled by ``factor``."""
    raw = copy.deepcopy(config.raw)
    ss = raw["channels"]["lateral"]["model"]["state_space"]
    ss["B"] = [[factor * row[0], row[1]] for row in ss["B"]]
    return parse_config(raw, f"{config.source} (aileron x{factor})")


def validate(flight, config):
    channel = config.channels["lateral"]
    validator = OnlineValidator(config)
    validator.add_histories("lateral", flight.histories(channel))
    validator.finish()
    return validator.results().channels["lateral"]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--sweeps", type=int, default=2)
    parser.add_argument("--sweep-duration", type=float, default=40.0)
    parser.add_argument("--sweep-gap-s", type=float, default=3.0)
    args = parser.parse_args()
    truth = load_config(CONFIG)
    weak = weakened(truth, 0.6)
    options = with_options(
        sweeps_per_channel=args.sweeps, sweep_duration_s=args.sweep_duration, quiet_s=args.sweep_gap_s
    )
    counts = {
        "truth model-limited": 0,
        "weak model-limited": 0,
        "aileron named": 0,
        "aileron -> p dominates": 0,
    }
    nus, gains, above = [], [], []
    started = time.perf_counter()
    for seed in range(args.seeds):
        flight = simulate_flight(truth, options=options, seed=seed)
        a, b = validate(flight, truth), validate(flight, weak)
        top = b.diagnosis[0] if b.diagnosis else None
        worst = b.mimo.worst_elements[0] if b.mimo and b.mimo.worst_elements else {}
        counts["truth model-limited"] += a.limited_by == "model"
        counts["weak model-limited"] += b.limited_by == "model"
        named = top is not None and top.effect == "gain" and top.parameters.get("input_index") == 0
        counts["aileron named"] += named
        counts["aileron -> p dominates"] += (worst.get("input_index"), worst.get("output_index")) == (0, 0)
        nus.append(a.nu_gap)
        if a.nu_gap >= 0.15:
            above.append(a.limited_by)
        if named:
            gains.append(top.parameters["factor"])
        print(f"seed {seed}: truth nu-gap {a.nu_gap:.3f} ({a.limited_by}); x0.6 nu-gap {b.nu_gap:.3f} "
              f"({b.limited_by}), worst element {worst.get('input', '-')} -> {worst.get('output', '-')}, "
              f"diagnosis {top.effect + ' ' + str(top.parameters) if top else 'none'}", flush=True)
    n = args.seeds
    print(f"{n} flights of {flight.duration_s:.0f} s in {time.perf_counter() - started:.0f} s")
    print(f"truth: nu-gap median {np.median(nus):.3f}, max {np.max(nus):.3f}; model-limited "
          f"{counts['truth model-limited']}/{n}; nu-gap >= 0.15 on {len(above)}/{n}"
          + (f" (limited by: {', '.join(above)})" if above else ""))
    print(
        f"aileron x0.6: model-limited {counts['weak model-limited']}/{n}; element aileron -> roll rate "
        "dominates "
        f"{counts['aileron -> p dominates']}/{n}; aileron gain named "
        f"{counts['aileron named']}/{n}"
        + (f", factor median {np.median(gains):.3f} (truth 1/0.6 = 1.667)" if gains else "")
    )
    # the model that flew: never model-limited; a nu-gap above 0.15 only where the data say they cannot tell
    ok = (
        counts["truth model-limited"] == 0
        and counts["weak model-limited"] == n
        and all(v == "data" for v in above)
    )
    print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
