"""The second simulator (``../shared/flights``): flights the project did not shape, scored against their
truth.

``flightgen.py`` and ``hard/hardgen.py`` (written apart from ``gap-validate simulate``: another pilot whose
trim corrections move every surface all the time, gusts as a surface-equivalent disturbance, jittered stamps,
dropped messages; actuator nonlinearities, gyro filters, closed loops, multisines, 3-2-1-1s, short and low-SNR
flights, cross-coupling, a faster airframe) fly 29 cases. Each is made once (cached under ``--out``), replayed
through the library's replay (``gap_validation.bag.replay``: the one data path) with the case's
``nominal.yaml`` and scored:

* **named**: a channel with a hidden effect inside the flown band must have it as its top candidate, each
  parameter within the case's tolerance (25 % where the case gives none), or be data-limited with nothing
  wrong named where the case's ``ok`` allows it;
* **clean**: every other channel (and every channel of a clean case) has no candidate and is not
  model-limited;
* **feedback**: a feedback warning on an open-loop channel is a false alarm; the closed loops without the
  excitation logged must be warned;
* **sweeps**: the sweeps counted are the sweeps flown (chirps: the case's ``sweeps``, 3 by default): the
  manoeuvres of a sweep kind the tool saw (``manoeuvres_flown``, used or not: a closed loop's sweeps that
  stand nowhere above the loop's motion are flown, and say so, but give no response), and no more used
  (``sweeps``) than seen.

The expectations are written below from ``cases.yaml`` (``expect``) and ``hard/cases.yaml`` (``truth``,
``ok``), one entry per case, and never changed to fit what the tool does.

    python benchmarks/second_simulator.py                   # all 29 cases, the table in docs/method.md
    python benchmarks/second_simulator.py --cases delay_pitch,clean --show
"""
from __future__ import annotations

import argparse
import concurrent.futures
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
FLIGHTS = ROOT.parent / "shared" / "flights"
CHANNELS = ("roll", "pitch", "yaw")
FEEDBACK_WORDS = ("feedback loop", "-1/C")
#: Kinds that are sweeps (``gap_validation.core.records.SWEEP_KINDS``, read here so the benchmark imports the
#: package only in its workers).
SWEEP_KINDS = ("chirp", "multisine", "multistep", "broadband")


@dataclass
class Expect:
    """What an honest verdict on one channel is."""

    named: list[dict] = field(default_factory=list)   # alternatives: {effect type: {parameter: value}}
    tolerance: float = 0.25
    data_ok: bool = False          # data-limited with nothing wrong named is acceptable
    forbid: tuple[str, ...] = ()   # effect types that must not be the top candidate
    fall: float = 0.0              # the top candidate must bring epsilon down by this fraction
    feedback: bool = False         # a feedback warning is required (closed loop, no excitation logged)
    feedback_ok: bool = False      # a feedback warning is allowed (closed loop)


def _flightgen_expectations(case: dict) -> dict[str, Expect]:
    out = {c: Expect() for c in CHANNELS}
    exp = case.get("expect", {})
    effect = exp.get("effect", "none")
    if effect == "none":
        return out
    hidden = case.get("hidden", {})
    if isinstance(effect, list):  # servo_all: any of these effects, epsilon falls by `fall`
        alternatives = [{e: {}} for e in effect] + [
            {a: {}, b: {}} for i, a in enumerate(effect) for b in effect[i + 1 :]
        ]
        for ch in hidden:
            out[ch] = Expect(named=alternatives, fall=float(exp.get("fall", 0.5)))
        return out
    ch = exp["channel"]
    out[ch] = Expect(
        named=[{effect: {exp["parameter"]: exp["value"]}}], tolerance=float(exp.get("tolerance", 0.25))
    )
    return out


def _hard_expectations(name: str, case: dict) -> dict[str, Expect]:
    """From ``hard/cases.yaml``: ``truth`` says what is in the flight, ``ok`` what an honest verdict may
    say."""
    out = {c: Expect() for c in CHANNELS}
    closed = "closed_loop" in case
    logged = bool(case.get("excitation_topic"))
    if closed:     # the pitch damper: warned unless the excitation is logged (and given as `excitation`)
        out["pitch"] = Expect(feedback=not logged and not case.get("trigger"), feedback_ok=not logged,
                              data_ok=True)
    table = {
        "ratelimit_pitch": {
            "pitch": Expect(
                named=[
                    {"rate_limit": {"rad_s": 0.8}},
                    {"first_order_lag": {}},
                    {"time_delay": {}},
                    {"first_order_lag": {}, "time_delay": {}},
                    {"second_order_lag": {}},
                ],
                forbid=("structural_mode",),
            )
        },
        "backlash_roll": {
            "roll": Expect(
                named=[{"backlash": {"width_rad": 0.015}}, {"gain": {}}], forbid=("structural_mode",)
            )
        },
        "gyro_lpf8": {
            c: Expect(named=[{"second_order_lag": {"natural_frequency_rad_s": 50.27}}]) for c in CHANNELS
        },
        "notch_roll": {"roll": Expect(named=[{"structural_mode": {"frequency_rad_s": 25.0}}], data_ok=True)},
        "zoh20_yaw": {
            "yaw": Expect(
                named=[
                    {"zero_order_hold": {"rate_hz": 20.0}},
                    {"time_delay": {"seconds": 0.025}},
                    {"time_delay": {"seconds": 0.025}, "first_order_lag": {}},
                ]
            )
        },
        "delay_mode_pitch": {
            "pitch": Expect(
                named=[{"time_delay": {"seconds": 0.03}, "structural_mode": {"frequency_rad_s": 45.0}}]
            )
        },
        "closed_loop_delay_pitch": {
            "pitch": Expect(named=[{"time_delay": {"seconds": 0.04}}], feedback_ok=True)
        },
        "closed_loop_exc_delay_pitch": {"pitch": Expect(named=[{"time_delay": {"seconds": 0.035}}])},
        "multisine_orth": {"pitch": Expect(named=[{"time_delay": {"seconds": 0.04}}])},
        "multisine_seq": {"pitch": Expect(named=[{"time_delay": {"seconds": 0.04}}])},
        "r3211_pitch": {"pitch": Expect(named=[{"time_delay": {"seconds": 0.04}}], data_ok=True)},
        "lowsnr_pitch": {"pitch": Expect(named=[{"time_delay": {"seconds": 0.045}}])},
        "short_pitch": {"pitch": Expect(named=[{"time_delay": {"seconds": 0.045}}])},
        "gain_delay_pitch": {
            "pitch": Expect(named=[{"gain": {"factor": 1.3}, "time_delay": {"seconds": 0.03}}])
        },
        "sign_delay_roll": {
            "roll": Expect(named=[{"gain": {"factor": -1.0}, "time_delay": {"seconds": 0.03}}])
        },
    }
    out.update(table.get(name, {}))
    return out


def expected_sweeps(case: dict) -> dict[str, tuple[int, ...]]:
    """Sweeps flown per channel (acceptable counts)."""
    plan = case.get("plan", {})
    kind = plan.get("kind", "chirp")
    n = int(plan.get("sweeps", 3))
    if kind == "multisine_orth":
        return {c: (1,) for c in CHANNELS}
    if kind == "3211":          # a train of `repeats` 3-2-1-1s with `gap_s` of trim between: one run, or each
        return {c: (n, n * int(plan.get("repeats", 6))) for c in CHANNELS}
    return {c: (n,) for c in CHANNELS}


def load_cases() -> dict[str, dict]:
    import yaml

    cases = {}
    for name, case in yaml.safe_load((FLIGHTS / "cases.yaml").read_text()).items():
        cases[name] = {**case, "_gen": FLIGHTS / "flightgen.py", "_expect": _flightgen_expectations(case)}
    for name, case in yaml.safe_load((FLIGHTS / "hard" / "cases.yaml").read_text()).items():
        cases[name] = {
            **case,
            "_gen": FLIGHTS / "hard" / "hardgen.py",
            "_expect": _hard_expectations(name, case),
        }
    return cases


def make(name: str, case: dict, out: Path) -> Path:
    """Make the case's flight once (cached: the generators are seeded)."""
    where = out / name
    if not (where / "nominal.yaml").exists() or not (where / "bag").exists():
        subprocess.run(
            [sys.executable, str(case["_gen"]), name, str(where)],
            check=True,
            env=os.environ.copy(),
            stdout=subprocess.DEVNULL,
        )
    return where


def config_for(name: str, case: dict, where: Path):
    """The case's nominal config as a user would run it (the logged excitation given to pitch where it
    exists)."""
    import yaml

    from gap_validation.core.config import parse_config

    data = yaml.safe_load((where / "nominal.yaml").read_text())
    if case.get("excitation_topic"):
        data["channels"]["pitch"]["excitation"] = {"topic": "/excitation", "field": "position[elevator]"}
    return parse_config(data, str(where / "nominal.yaml"))


def run_case(args: tuple[str, dict, str]) -> dict:
    """Make, replay and score one case; a dict per channel."""
    name, case, out = args
    from gap_validation.bag.replay import replay

    where = make(name, case, Path(out))
    config = config_for(name, case, where)
    start = time.perf_counter()
    outcome = replay([where / "bag"], config)
    elapsed = time.perf_counter() - start
    rows = {}
    sweeps = expected_sweeps(case)
    for ch in CHANNELS:
        res = outcome.result.channels[ch]
        top = res.diagnosis[0] if res.diagnosis else None
        rows[ch] = {
            "limited_by": res.limited_by,
            "epsilon": res.epsilon,
            "sweeps": res.sweeps,
            "flown": sum(n for kind, n in res.manoeuvres_flown.items() if kind in SWEEP_KINDS),
            "kinds": dict(res.manoeuvres_by_kind),
            "band": res.excited_band_rad_s,
            "top": None
            if top is None
            else {
                "effect": top.effect,
                "effects": top.effects,
                "epsilon": top.epsilon,
                "epsilon_before": top.epsilon_before,
                "explains": top.explains,
            },
            "named": [c.effect for c in res.diagnosis],
            "within": None if res.within_tolerance is None else res.within_tolerance.to_json_dict(),
            "feedback": any(any(word in w for word in FEEDBACK_WORDS) for w in res.warnings),
            "nonlinearity": res.nonlinearity,
            "message": res.message,
            "warnings": list(res.warnings),
            "sweeps_expected": list(sweeps[ch]),
        }
    return {"case": name, "channels": rows, "elapsed_s": elapsed}


def _matches(effects: list[dict], alternative: dict, tolerance: float) -> bool:
    """The candidate's effects are exactly the alternative's types, each given parameter within
    ``tolerance``."""
    found = {}
    for e in effects:
        found.setdefault(e["type"], e)
    if not found or set(found) != set(alternative):
        return False
    for kind, params in alternative.items():
        for key, value in params.items():
            got = found[kind].get(key)
            if got is None or abs(got - value) > tolerance * abs(value):
                return False
    return True


def score(row: dict, expect: Expect) -> tuple[str, str]:
    """``(verdict, why)``: verdict ``pass`` or ``FAIL``."""
    top = row["top"]
    if expect.feedback and not row["feedback"]:
        return "FAIL", "closed loop not warned"
    if row["feedback"] and not (expect.feedback or expect.feedback_ok):
        return "FAIL", "false feedback warning"
    flown = row.get("flown", row["sweeps"])
    if flown not in row["sweeps_expected"] or row["sweeps"] > flown:
        return "FAIL", (
            f"{flown} sweeps seen ({row['sweeps']} used), {'/'.join(map(str, row['sweeps_expected']))} flown"
        )
    within = row.get("within")
    if not expect.named:
        if top is not None:
            return "FAIL", f"clean channel, {top['effect']} named"
        if within is not None:
            return (
                "FAIL",
                f"clean channel, a constant factor {within['gain']:.3g} resolved within the tolerance",
            )
        if row["limited_by"] == "model":
            return "FAIL", "clean channel model-limited"
        return "pass", "clean" + (" (data-limited)" if row["limited_by"] == "data" else "")
    if top is None and within is not None:
        # within the tolerance the tool says only a constant factor (and the free play it equals, never named)
        readings = [[{"type": "gain", "factor": within["gain"]}]]
        readings += (
            [[{"type": "backlash", "width_rad": within["free_play_rad"]}]] if within["free_play_rad"] else []
        )
        if any(_matches(r, alt, expect.tolerance) for r in readings for alt in expect.named):
            return "pass", (
                f"within the tolerance: x{within['gain']:.3g}, {within['phase_deg']:.0f} deg"
                + (f" (free play {within['free_play_rad']:.2g} rad)" if within["free_play_rad"] else "")
            )
    if top is None:
        if expect.data_ok and row["limited_by"] == "data":
            return "pass", "data-limited (allowed)"
        return "FAIL", f"nothing named ({row['limited_by']}-limited)"
    if top["effect"] in expect.forbid or any(e["type"] in expect.forbid for e in top["effects"]):
        return "FAIL", f"{top['effect']} named"
    if not any(_matches(top["effects"], alt, expect.tolerance) for alt in expect.named):
        return "FAIL", f"named {_describe(top['effects'])}"
    if expect.fall and top["epsilon_before"] and top["epsilon"] > (1 - expect.fall) * top["epsilon_before"]:
        return "FAIL", f"epsilon {top['epsilon_before']:.2f} -> {top['epsilon']:.2f} only"
    return "pass", f"named {_describe(top['effects'])}"


def _describe(effects: list[dict]) -> str:
    return " + ".join(e["type"] + "(" + ", ".join(f"{v:.3g}" for k, v in e.items() if k != "type") + ")"
                      for e in effects) or "parameter_error"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--out", default=str(ROOT / "out" / "second_simulator"), help="flights are made here once"
    )
    parser.add_argument("--cases", default="", help="comma-separated case names (default: all)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--json", help="write every row here")
    parser.add_argument("--show", action="store_true", help="print each failing channel's message")
    args = parser.parse_args(argv)
    cases = load_cases()
    names = [n for n in args.cases.split(",") if n] or list(cases)
    unknown = [n for n in names if n not in cases]
    if unknown:
        parser.error(f"unknown case {unknown[0]!r} (known: {', '.join(cases)})")
    start = time.perf_counter()
    with concurrent.futures.ProcessPoolExecutor(max_workers=args.workers) as pool:
        results = list(pool.map(run_case, [(n, cases[n], args.out) for n in names], chunksize=1))
    total = {"pass": 0, "FAIL": 0}
    kinds = {"named": [0, 0], "clean": [0, 0], "feedback": [0, 0], "sweeps": [0, 0]}
    print(f"{len(names)} cases of ../shared/flights, {time.perf_counter() - start:.0f} s\n")
    print(
        f"{'case':28s} {'channel':7s} {'verdict':7s} {'eps':>7s} {'used/seen':>9s} {'excited rad/s':>14s}  "
        "why"
    )
    for res in results:
        name = res["case"]
        for ch in CHANNELS:
            row, expect = res["channels"][ch], cases[name]["_expect"][ch]
            verdict, why = score(row, expect)
            total[verdict] += 1
            group = "named" if expect.named else "clean"
            kinds[group][0] += 1
            kinds[group][1] += verdict == "pass"
            if not (expect.feedback or expect.feedback_ok):
                kinds["feedback"][0] += 1
                kinds["feedback"][1] += not row["feedback"]
            kinds["sweeps"][0] += 1
            flown = row.get("flown", row["sweeps"])
            kinds["sweeps"][1] += flown in row["sweeps_expected"] and row["sweeps"] <= flown
            band = "-" if row["band"] is None else f"{row['band'][0]:.3g}-{row['band'][1]:.3g}"
            eps = "-" if row["epsilon"] is None else f"{row['epsilon']:.3g}"
            print(
                f"{name:28s} {ch:7s} {verdict:7s} {eps:>7s} "
                f"{str(row['sweeps']) + '/' + str(row.get('flown', '?')):>9s} {band:>14s}  {why}"
            )
            if args.show and verdict != "pass":
                print(f"{'':44s}{row['message'][:400]}")
                for w in row["warnings"]:
                    print(f"{'':44s}warning: {w[:200]}")
    n = total["pass"] + total["FAIL"]
    print(
        f"\n{total['pass']} of {n} channels pass; hidden effects named "
        f"{kinds['named'][1]}/{kinds['named'][0]}, "
        f"clean channels clean {kinds['clean'][1]}/{kinds['clean'][0]}, open-loop channels without a "
        "feedback "
        f"warning {kinds['feedback'][1]}/{kinds['feedback'][0]}, sweeps as flown {kinds['sweeps'][1]}/"
        f"{kinds['sweeps'][0]}"
    )
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=str))
    return 0 if total["FAIL"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
