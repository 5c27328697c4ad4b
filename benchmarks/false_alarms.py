"""False alarms on flights whose truth IS the model, on three simulators written apart: how often is a correct
model called model-limited, given a named effect, or warned of a feedback loop it does not have?

* **ours** (``gap-validate simulate``, issue 12): every excitation kind it flies (log chirps, multisines,
  orthogonal multisines on all axes at once, 3-2-1-1 multisteps, doublets) and NASA-style short runs (1 s of
  trim, a 3-2-1-1, 8 s at 50 Hz), manoeuvre lengths 6-300 s, 1-4 manoeuvres per channel, gaps of 1-10 s, noise
  and gusts x0.25-2, IMU 50-200 Hz, surfaces 25-100 Hz, the Ultra Stick 25e and the same airframe twice as
  fast. Half of the flights (drawn from a stream of their own, so the other draws are as before) fly their
  rounds at two amplitudes: there every ``nonlinearity`` verdict is a false alarm too. One flight in eight is
  flown inside rate dampers on every axis (6 dB gain margin, turbulence), without the excitation logged: there
  the feedback warning is required.
* **second** (``../shared/flights``, written apart: a pilot whose trim corrections move every surface all the
  time, surface-equivalent gusts, jittered and dropped stamps; ``benchmarks/_other_simulators.py``): random
  sweeps, gusts and rates; one flight in four flies pitch inside the generator's rate damper, without the
  excitation logged.
* **jsbsim** (the nonlinear 6-DOF of FlightGear and ArduPilot SITL; ``gap_validation.jsbsim``): the c172x,
  c182 and pa28 at their trim conditions, calm and in JSBSim's light turbulence, against JSBSim's own
  linearisation at the flown condition (5-10 % off the nonlinear model at some frequencies: a real model's
  error).

The truth is the config's own model (no hidden effect): every "model-limited" verdict, every named effect and
every constant factor said within the tolerance (``within_tolerance``) is a false alarm; a feedback warning is
false on every channel flown open loop (JSBSim's pilot flies the wings and the pitch attitude back between the
manoeuvres, a true loop: a warning there is counted apart, neither false nor required). Goals (issue 22):
model-limited and a named effect at most 1 % of the channels, a feedback warning at most 1 % of the open-loop
channels, and at least 95 % of the closed-loop channels (no excitation logged) warned, on every simulator.

Flights are simulated and fed to the validator in memory (the library path of the one data path; no bag is
written). Seeded: the same ``--seed`` gives the same flights.

    python benchmarks/false_alarms.py                                   # 240 + 60 + 30 flights:
    docs/method.md python benchmarks/false_alarms.py --flights 40 --second 20 --jsbsim 9     # quicker
    python benchmarks/false_alarms.py --simulators ours                 # one simulator
    python benchmarks/false_alarms.py --simulators jsbsim --airspeed    # JSBSim with the airspeed logged
"""
from __future__ import annotations

import argparse
import concurrent.futures
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from gap_validation.core.config import (
    load_config,  # noqa: E402
    parse_config,  # noqa: E402
)
from gap_validation.core.simulation import FlightOptions, simulate_flight  # noqa: E402
from gap_validation.core.validator import OnlineValidator  # noqa: E402

KINDS = ("chirp", "multisine", "multisine-orthogonal", "3211", "doublet", "nasa-run")


def faster(config_path: Path, factor: float = 2.0):
    """The config's airframe with every time constant ``factor`` times shorter: ``P(s / factor)``."""
    import yaml

    data = yaml.safe_load(config_path.read_text())
    for ch in data["channels"].values():
        ss = ch["model"]["state_space"]
        ss["A"] = (np.array(ss["A"]) * factor).tolist()
        ss["B"] = (np.array(ss["B"]) * factor).tolist()
        grid = ch.setdefault("frequencies", {"min_rad_s": 1.0, "max_rad_s": 40.0, "count": 40})
        grid["min_rad_s"], grid["max_rad_s"] = (
            grid["min_rad_s"] * factor,
            min(grid["max_rad_s"] * factor, 90.0),
        )
    return parse_config(data, f"{config_path.name} x{factor:g} faster")


def draw_flight(rng: np.random.Generator, index: int) -> dict:
    """One random flight: options and airframe (plain values, so a worker process can rebuild it)."""
    kind = KINDS[index % len(KINDS)]
    noise = float(math.exp(rng.uniform(math.log(0.25), math.log(2.0))))
    base = dict(noise=noise, imu_rate_hz=float(rng.choice([50.0, 100.0, 200.0])),
                surface_rate_hz=float(rng.choice([25.0, 50.0, 100.0])), quiet_s=float(rng.uniform(1.0, 10.0)),
                trim_s=float(rng.uniform(1.0, 5.0)), sweeps_per_channel=int(rng.integers(1, 5)))
    length = float(math.exp(rng.uniform(math.log(6.0), math.log(300.0))))
    if kind == "chirp":
        opts = dict(base, excitation="chirp", sweep_duration_s=length)
    elif kind in ("multisine", "multisine-orthogonal"):
        periods = int(rng.integers(2, 5))
        opts = dict(
            base, excitation=kind, multisine_periods=periods, multisine_period_s=max(length / periods, 3.0)
        )
    elif kind == "3211":
        opts = dict(base, excitation="3211", multistep_unit_s=float(rng.uniform(0.3, 1.0)))
    elif kind == "doublet":
        opts = dict(base, excitation="doublet", doublet_half_period_s=float(rng.uniform(0.3, 1.5)))
    else:   # a NASA-style short run: 1 s of trim, one 3-2-1-1, 8 s in all, 50 Hz
        opts = dict(noise=noise, excitation="3211", imu_rate_hz=50.0, surface_rate_hz=50.0, trim_s=1.0,
                    sweeps_per_channel=1, multistep_unit_s=0.5, duration_s=float(rng.uniform(6.0, 10.0)))
    flight = {"kind": kind, "options": opts, "airframe": "x2" if rng.random() < 0.3 else "x1",
              "seed": int(rng.integers(0, 2 ** 31))}
    amplitudes = np.random.default_rng([flight["seed"], 15])        # own stream: the draws above unchanged
    if amplitudes.random() < 0.5 and kind != "nasa-run":
        opts["sweep_amplitude_scales"] = (1.0, float(amplitudes.uniform(0.3, 0.7)))
    return flight


def _config(airframe: str):
    path = ROOT / "config" / "ultrastick25e.yaml"
    return faster(path) if airframe == "x2" else load_config(path)


def draw_closed(rng: np.random.Generator) -> dict:
    """One closed-loop flight of ours: chirps inside a rate damper on every axis, turbulence, no excitation
    logged."""
    opts = dict(
        excitation="chirp",
        closed_loop_gain_margin_db=float(rng.uniform(4.0, 10.0)),
        turbulence_rms_rad_s=float(rng.uniform(0.02, 0.08)),
        sweeps_per_channel=int(rng.integers(1, 4)),
        sweep_duration_s=float(rng.uniform(40.0, 120.0)),
        quiet_s=float(rng.uniform(5.0, 15.0)),
        noise=float(math.exp(rng.uniform(math.log(0.25), math.log(2.0)))),
    )
    return {"simulator": "ours", "kind": "closed loop", "options": opts, "airframe": "x1",
            "seed": int(rng.integers(0, 2 ** 31))}


JSBSIM_CONDITIONS = (("c172x", 100.0, 3000.0), ("c182", 110.0, 3000.0), ("pa28", 90.0, 3000.0))


def draw_jsbsim(rng: np.random.Generator, index: int) -> dict:
    """One JSBSim flight: an aircraft at its trim condition, calm or in light turbulence, a short card."""
    aircraft, speed, altitude = JSBSIM_CONDITIONS[index % len(JSBSIM_CONDITIONS)]
    turbulent = (index // len(JSBSIM_CONDITIONS)) % 2 == 1
    opts = dict(sweeps_per_channel=int(rng.integers(1, 3)), sweep_duration_s=float(rng.uniform(40.0, 90.0)),
                quiet_s=float(rng.uniform(3.0, 10.0)))
    return {
        "simulator": "jsbsim",
        "kind": f"{aircraft}{' turbulent' if turbulent else ''}",
        "aircraft": aircraft,
        "speed_kt": speed,
        "altitude_ft": altitude,
        "turbulent": turbulent,
        "options": opts,
        "seed": int(rng.integers(0, 2**31)),
    }


_JSBSIM_CONFIGS: dict = {}


#: The channels JSBSim's pilot flies back to trim between the manoeuvres
#: (``gap_validation.jsbsim.flight.Pilot``: wings level on the ailerons, the pitch attitude on the elevator;
#: the rudder is left alone): a true loop there, so a feedback warning on them is neither false nor required
#: (counted apart).
JSBSIM_HELD = ("roll", "pitch")


def _jsbsim_config(aircraft: str, speed_kt: float, altitude_ft: float, airspeed: bool = False):
    """JSBSim's linearisation at the flown condition, its SISO channels (cached per worker); with ``airspeed``
    each channel's airspeed stream (the inputs' deviations scaled by the dynamic pressure ratio)."""
    key = (aircraft, speed_kt, altitude_ft, airspeed)
    if key not in _JSBSIM_CONFIGS:
        from gap_validation.jsbsim.linearize import AIRSPEED_TOPIC, config_mapping, linearize

        data = config_mapping(linearize(aircraft, speed_kt, altitude_ft),
                              airspeed_topic=AIRSPEED_TOPIC if airspeed else None)
        data["channels"] = {k: v for k, v in data["channels"].items() if k in ("roll", "pitch", "yaw")}
        _JSBSIM_CONFIGS[key] = parse_config(data, f"JSBSim {aircraft} linearised at {speed_kt:g} kt")
    return _JSBSIM_CONFIGS[key]


def _validate(config, histories: dict) -> OnlineValidator:
    validator = OnlineValidator(config)
    for name, streams in histories.items():
        validator.add_histories(name, streams)
    validator.finish()
    return validator


def _topic_histories(config, topics) -> dict:
    out = {}
    for name, ch in config.channels.items():
        streams = {"input": ch.input, "output": ch.output, **dict(ch.extra_streams())}   # the airspeed too
        out[name] = {stream: (topics[spec.topic].stamp_s, spec.value(topics[spec.topic].values[spec.field]))
                     for stream, spec in streams.items()}
    return out


def fly(flight: dict) -> list[dict]:
    """Simulate and validate one flight; one row per channel."""
    simulator = flight.get("simulator", "ours")
    closed, held = set(), set()
    if simulator == "second":
        import _other_simulators as other

        config = other.second_config()
        histories = other.fly_second(flight, config)
        closed = {"pitch"} if "closed_loop" in flight["case"] else set()
    elif simulator == "jsbsim":
        from gap_validation.jsbsim.flight import jsbsim_options, parse_turbulence, simulate_jsbsim_flight

        config = _jsbsim_config(flight["aircraft"], flight["speed_kt"], flight["altitude_ft"],
                                flight.get("airspeed", False))
        flown = simulate_jsbsim_flight(flight["aircraft"], flight["speed_kt"], flight["altitude_ft"], config,
                                       options=jsbsim_options(**flight["options"]), seed=flight["seed"],
                                       turbulence=parse_turbulence("light" if flight["turbulent"] else None))
        histories = _topic_histories(config, flown.flight.topics)
        held = set(JSBSIM_HELD)
    else:
        config = _config(flight["airframe"])
        if flight["kind"] == "nasa-run":            # one channel per run, as the real records
            name = list(config.channels)[flight["seed"] % len(config.channels)]
            config = type(config)(
                channels={name: config.channels[name]}, source=config.source, raw=config.raw
            )
        sim = simulate_flight(config, {}, FlightOptions(**flight["options"]), seed=flight["seed"])
        histories = _topic_histories(config, sim.topics)
        if flight["kind"] == "closed loop":
            closed = set(config.channels)
    validator = _validate(config, histories)
    rows = []
    for name, ch in validator.results().channels.items():
        rows.append(
            {
                "simulator": simulator,
                "kind": flight["kind"],
                "channel": name,
                "airframe": flight.get("airframe", flight.get("aircraft", "")),
                "closed": name in closed,
                "held": name in held,
                "limited_by": ch.limited_by,
                "diagnosed": bool(ch.diagnosis),
                "epsilon": ch.epsilon,
                "points": ch.points_used,
                "message": ch.message,
                "seed": flight["seed"],
                "nonlinear": ch.nonlinearity is not None,
                "compared": ch.nonlinearity_evidence is not None,
                "warnings": list(ch.warnings),
                "feedback": any("feedback loop" in w for w in ch.warnings),
                "convention": bool(ch.conventions),
                "within": ch.within_tolerance is not None,
                "lead_share": (ch.rate_leads_surface or {}).get("share", float("nan")),
                "lead_p": (ch.rate_leads_surface or {}).get("p_value", float("nan")),
                "coupling": any("other_inputs" in w for w in ch.warnings),
            }
        )
    return rows


def _table(rows: list[dict], kinds: list[str]) -> None:
    header = (f"{'flights':22s} {'channels':>8s} {'model-limited':>14s} {'named effect':>13s} "
              f"{'data-limited':>13s} {'feedback warned':>16s} {'median eps':>11s} {'median points':>14s}")
    print(header)
    print("-" * len(header))
    for kind in kinds + ["all"]:
        group = [r for r in rows if kind == "all" or r["kind"] == kind]
        if not group:
            continue
        n = len(group)
        model = sum(r["limited_by"] == "model" for r in group)
        named = sum(r["diagnosed"] for r in group)
        data = sum(r["limited_by"] == "data" for r in group)
        warned = sum(r["feedback"] for r in group)
        eps = [r["epsilon"] for r in group if r["epsilon"] is not None]
        print(
            f"{kind:22s} {n:8d} {model:7d} ({100 * model / n:4.1f}%) {named:5d} ({100 * named / n:4.1f}%) "
            f"{data:6d} ({100 * data / n:4.0f}%) {warned:8d} ({100 * warned / n:4.1f}%) "
            f"{np.median(eps) if eps else float('nan'):11.3f} {np.median([r['points'] for r in group]):14.0f}"
        )


def _verdict(rows: list[dict]) -> tuple[bool, str]:
    open_loop = [r for r in rows if not r["closed"]]
    closed = [r for r in rows if r["closed"]]
    n = max(len(open_loop), 1)
    model = sum(r["limited_by"] == "model" for r in open_loop) / n
    named = sum(r["diagnosed"] for r in open_loop) / n
    # no loop at all: a feedback warning is false there
    free = [r for r in open_loop if not r.get("held")]
    feedback = sum(r["feedback"] for r in free) / max(len(free), 1)
    held = [r for r in open_loop if r.get("held")]
    conventions = sum(r["convention"] for r in rows) / max(len(rows), 1)
    within = sum(r["within"] for r in open_loop) / n
    warned = sum(r["feedback"] for r in closed) / len(closed) if closed else float("nan")
    wrong = sum(r["diagnosed"] for r in closed)
    compared = sum(r["compared"] for r in rows)
    nonlinear = sum(r["nonlinear"] for r in rows)
    ok = model <= 0.01 and named <= 0.01 and feedback <= 0.01 and (not closed or warned >= 0.95) and \
        nonlinear <= 0.01 * max(compared, 1) and conventions <= 0.01 and within <= 0.01
    text = (
        f"open loop ({len(open_loop)} channels): model-limited {100 * model:.2f} %, a named effect "
        f"{100 * named:.2f} %, a feedback warning {100 * feedback:.2f} % of the {len(free)} without a loop "
        f"(goals <= 1 %)"
        + (
            f" (the pilot's attitude hold between the manoeuvres, a true loop, warned on "
            f"{sum(r['feedback'] for r in held)} of {len(held)})"
            if held
            else ""
        )
        + f"; a convention error "
        f"(sign, units, frame, clock) named on {100 * conventions:.2f} % of all channels (goal <= 1 %); "
        "called "
        f"nonlinear {nonlinear} of {compared} channels with sweeps at two amplitudes; a constant factor "
        "resolved "
        f"within the tolerance on {100 * within:.2f} % (goal <= 1 %)"
    )
    if closed:
        text += (
            f"; closed loop without the excitation ({len(closed)} channels): warned {100 * warned:.1f} % "
            f"(goal >= 95 %), an effect named on {wrong}"
        )
    return ok, text + (": PASS" if ok else ": FAIL") + _lead_shares(open_loop, closed)


def _lead_shares(open_loop: list[dict], closed: list[dict]) -> str:
    """The lead test's share (background.LeadTest) on open- and closed-loop channels: its false-positive
    margin."""
    def spread(rows, significant=False):
        shares = np.array([r["lead_share"] for r in rows if not significant or r["lead_p"] < 1e-3], float)
        shares = shares[np.isfinite(shares)]
        return shares if shares.size else np.array([np.nan])

    text = ""
    if open_loop:
        q = np.percentile(spread(open_loop), [50, 99, 100])
        text += (
            f"\n  lead share, open loop: median {100 * q[0]:.1f} %, 99th percentile {100 * q[1]:.1f} %, "
            "largest "
            f"{100 * q[2]:.1f} % (largest with F beyond chance {100 * np.max(spread(open_loop, True)):.1f} %)"
        )
    if closed:
        text += f"; closed loop: smallest {100 * np.min(spread(closed)):.1f} %"
    return text


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--flights", type=int, default=240, help="open-loop flights of ours")
    parser.add_argument("--closed", type=int, default=24, help="closed-loop flights of ours")
    parser.add_argument("--second", type=int, default=60, help="flights of the second simulator")
    parser.add_argument("--jsbsim", type=int, default=30, help="JSBSim flights")
    parser.add_argument("--simulators", default="ours,second,jsbsim")
    parser.add_argument(
        "--airspeed",
        action="store_true",
        help="JSBSim configs with the airspeed stream (the surfaces scaled by the dynamic pressure)",
    )
    parser.add_argument("--seed", type=int, default=12)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--show", action="store_true", help="print every false alarm")
    args = parser.parse_args(argv)
    chosen = [s.strip() for s in args.simulators.split(",") if s.strip()]
    flights: list[dict] = []
    if "ours" in chosen:
        rng = np.random.default_rng(args.seed)
        flights += [draw_flight(rng, i) for i in range(args.flights)]
        closed_rng = np.random.default_rng([args.seed, 13])
        flights += [draw_closed(closed_rng) for _ in range(args.closed)]
    if "second" in chosen:
        import _other_simulators as other

        if not other.available():
            print("the second simulator is not beside the checkout (../shared/flights): skipped")
        else:
            rng = np.random.default_rng([args.seed, 2])
            flights += [other.draw_second(rng, i) for i in range(args.second)]
    if "jsbsim" in chosen:
        rng = np.random.default_rng([args.seed, 3])
        flights += [{**draw_jsbsim(rng, i), "airspeed": args.airspeed} for i in range(args.jsbsim)]
    start = time.perf_counter()
    rows: list[dict] = []
    with concurrent.futures.ProcessPoolExecutor(max_workers=args.workers) as pool:
        for result in pool.map(fly, flights, chunksize=1):
            rows.extend(result)
    elapsed = time.perf_counter() - start
    print(f"{len(flights)} flights, {len(rows)} channels whose truth is the model, {elapsed:.0f} s "
          f"({args.workers} workers, seed {args.seed})")
    all_ok = True
    for simulator in ("ours", "second", "jsbsim"):
        group = [r for r in rows if r["simulator"] == simulator]
        if not group:
            continue
        print(f"\n{simulator}:")
        _table(group, list(dict.fromkeys(r["kind"] for r in group)))
        ok, text = _verdict(group)
        all_ok &= ok
        print(text)
    ok, text = _verdict(rows)
    print(f"\nall simulators: {text}")
    all_ok &= ok
    if args.show:
        for r in rows:
            wrong = (
                (r["feedback"] != r["closed"] and not r["held"])
                or r["convention"]
                or (
                    not r["closed"]
                    and (r["limited_by"] == "model" or r["diagnosed"] or r["nonlinear"] or r["within"])
                )
            )
            if wrong or r["coupling"]:
                print(f"  {r['simulator']} {r['kind']} {r['channel']} {r['airframe']} seed {r['seed']}: "
                      f"{r['message'][:300]} {r['warnings']}")
    return 0 if all_ok else 1


if __name__ == "__main__":
    sys.exit(main())
