"""Random flights of the simulators written apart from ours, for ``benchmarks/false_alarms.py`` (benchmark
helper).

The second simulator (``../shared/flights/flightgen.py`` and ``hard/hardgen.py``): its own excitation (log
chirps then a doublet per axis), pilot (trim corrections moving every surface all the time), gusts (a
surface-equivalent disturbance), sensor noise and timing (stamps jittered by +-0.5 ms, 0.5 % of messages
dropped). A flight here draws its settings at random and takes the generator's own functions for the signals;
the topics are sampled as its ``write_bag`` samples them and fed to the validator in memory (no bag is
written: the library path of the one data path). The truth is the nominal airframe, so a model-limited verdict
or a named effect is a false alarm; a quarter of the flights fly pitch inside the generator's rate damper
(``hardgen.closed_loop_pitch``), without the excitation logged: there a feedback warning is required, anywhere
else it is false.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FLIGHTS = ROOT.parent / "shared" / "flights"
CHANNELS = ("roll", "pitch", "yaw")
FIELDS = {
    "roll": ("position[aileron]", "angular_velocity.x"),
    "pitch": ("position[elevator]", "angular_velocity.y"),
    "yaw": ("position[rudder]", "angular_velocity.z"),
}


def _generators():
    for path in (FLIGHTS, FLIGHTS / "hard"):
        if str(path) not in sys.path:
            sys.path.insert(0, str(path))
    import flightgen
    import hardgen
    return flightgen, hardgen


def available() -> bool:
    """Whether ``../shared/flights`` is beside the checkout."""
    return (FLIGHTS / "flightgen.py").exists()


def draw_second(rng: np.random.Generator, index: int) -> dict:
    """One random flight of the second simulator (plain values)."""
    closed = index % 4 == 3
    case = {
        "seed": int(rng.integers(0, 2 ** 31)),
        "plan": {"sweeps": int(rng.integers(1, 4)), "sweep_seconds": float(rng.uniform(12.0, 40.0)),
                 "amplitude_rad": float(math.exp(rng.uniform(math.log(0.025), math.log(0.08)))),
                 "sweep_hz": [0.2, float(rng.choice([4.0, 6.0, 8.0]))]},
        "gust_rad": float(math.exp(rng.uniform(math.log(0.002), math.log(0.008)))),
        "imu_hz": float(rng.choice([50.0, 100.0, 200.0])),
        "surfaces_hz": float(rng.choice([25.0, 50.0, 100.0])),
    }
    if closed:
        case["closed_loop"] = {"gm_db": float(rng.uniform(4.0, 10.0)), "delay_s": 0.02, "filter_rad_s": 60.0}
        case["gust_rad"] = float(math.exp(rng.uniform(math.log(0.004), math.log(0.015))))
        case["gust_corner_rad_s"] = float(rng.uniform(2.0, 5.0))
    # no sweep past its Nyquist
    case["surfaces_hz"] = max(case["surfaces_hz"], 2.5 * 2 * case["plan"]["sweep_hz"][1])
    return {"simulator": "second", "kind": "closed loop" if closed else "open loop", "case": case,
            "seed": case["seed"]}


def _sample(t: np.ndarray, x: np.ndarray, rate_hz: float, noise: float, rng: np.random.Generator):
    """Stamps every 1/rate jittered by +-0.5 ms, 0.5 % dropped, the value at the nearest simulation step plus
    noise (as ``flightgen.write_bag``)."""
    stamps = np.arange(int(t[-1] * rate_hz)) / rate_hz + rng.uniform(-5e-4, 5e-4, int(t[-1] * rate_hz))
    keep = rng.random(stamps.size) >= 0.005
    stamps = stamps[keep]
    index = np.minimum(np.round(stamps * 1000.0).astype(np.int64), t.size - 1)
    return stamps, x[index] + rng.normal(0.0, noise, stamps.size)


def fly_second(flight: dict, config) -> dict:
    """Simulate one second-simulator flight; the histories per channel for
    ``OnlineValidator.add_histories``."""
    fg, hg = _generators()
    case = flight["case"]
    rng = np.random.default_rng(case["seed"])
    u, _ = hg.excitation(case, rng)
    n = len(u["pitch"])
    t = np.arange(n) / fg.SIM_HZ
    gust = {c: hg.gust(n, rng, case["gust_rad"], case.get("gust_corner_rad_s", 2.0)) for c in CHANNELS}
    noise = {c: rng.normal(0.0, 0.005, n) for c in CHANNELS}
    rates = {}
    if "closed_loop" in case:
        u["pitch"], rates["pitch"], *_ = hg.closed_loop_pitch(
            case, u["pitch"], gust["pitch"], noise["pitch"], None, [], 1.0
        )
    for c in CHANNELS:
        if c not in rates:
            num, den, _ = hg.linear_chain(c, [])
            rates[c] = hg.filt(num, den, u[c] + gust[c])
        rates[c] = rates[c] + noise[c]
    histories = {}
    for c in CHANNELS:
        ti, ui = _sample(t, u[c], case["surfaces_hz"], 0.0005, rng)
        to, yo = _sample(t, rates[c], case["imu_hz"], 0.0, rng)
        histories[c] = {"input": (ti, ui), "output": (to, yo)}
    return histories


def second_config():
    """The second simulator's nominal config (the airframe only; its own topics and fields)."""
    from gap_validation.core.config import parse_config

    fg, _ = _generators()
    return parse_config(fg.nominal_config({}), "second simulator nominal")
