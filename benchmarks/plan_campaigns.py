"""Predictions that hold: seeded campaigns of "fly, replay, plan, fly the plan, replay" on our simulator and
the second one (issue 25).

Each campaign draws an airframe (the Ultra Stick 25e, the same airframe twice as fast, and a sluggish one: 0.7
times as fast with 0.6 of the control power), the air (noise and gusts x0.5-2, a narrow-band disturbance on
one channel in half of them, as a vibration or a badly flown band) and a deliberately short and weak first
card (one 30-60 s log sweep per channel at 0.03-0.05 rad, ``--amplitudes``, then a 0.06 rad doublet). Then:

1. the first card is flown (:func:`gap_validation.core.simulation.simulate_flight`) and replayed (fed to the
   validator, the library path of the one data path);
2. :func:`gap_validation.core.plan.plan_card` plans from its results (``replay --json``'s JSON);
3. each planned manoeuvre is flown in the same air as its own flight of the simulator: the card's log chirp is
   the simulator's sweep (``excitation chirp``, no dwell, 1 s fades, ``sweeps_per_channel`` = the repeats, the
   band set through a one-channel config's grid and ``band_low_factor``/``band_high_factor``, zero-amplitude
   doublets so the trim between sweeps is the card's), and replayed on its own and together with the first
   flight;
4. the default (first) card is flown again and again (new seeds, same air) and replayed together with the
   first flight until every planned band's random error is as low as the planned card left it (at most
   ``--repeats``).

The second simulator (``--simulator second``; ``both`` runs ours, then it): ``../shared/flights`` (written
apart from ours: another pilot whose trim corrections move every surface, gusts as a surface-equivalent
disturbance, jittered stamps, dropped messages; benchmarks/second_simulator.py). Its generators are loaded as
modules and never changed: each flight is a case of their own ``generate`` (cached under ``--out`` by the
case's hash), replayed through the library's replay (``gap_validation.bag.replay.replay``, the one data path)
with its ``nominal.yaml``. Two airframes: flightgen's Ultra Stick 25e, and hardgen's twice-as-fast one
(``airframe_scale`` 2, set up as its ``clean_fast`` case). The air: the generator's gust level x0.5-2. The
first card: one 30-60 s sweep per channel at 0.02-0.04 rad (the generator's card: its sweeps, 3 s of trim, a
doublet at 1.6 times the amplitude, channel after channel). The planner is told the slowest logged stream's
rate (``--log-rate-hz``, as docs/flying.md asks; ``--hide-log-rate``: not): the fast airframe's grid reaches
120 rad/s, above its first card's sweeps, and without the rate its results do not say what the logs resolve
(the planner then swept to 386 rad/s, above the surfaces' Nyquist frequency). Each planned manoeuvre is flown
as the generator's card of its band, sweep length, repeats, amplitude and trim after each sweep, by hardgen
(:data:`PLANNED_GENERATOR`; all three surfaces fly it, the generator's layout; only the manoeuvre's channel
and band are scored); the generator's sweep has 0.5 s linear tapers and 2 s of trim before where the card has
1 s half-cosine fades and 5 s, so the prediction is scored twice: the card's own, and the planner's noise
estimate with the information of the sweep the generator flies (:func:`flown_prediction`). The generator also
flies a doublet after each surface's sweeps, which the card does not ask for: the planned flights are scored
with the estimator's ``min_sweep_s`` at 5 s (:data:`SCORED_MIN_SWEEP_S`), so that doublet gives no frequency
response (pooled, it raised its neighbours' noise up to 20 times near the Dutch roll). The repeated first
card and the verdicts are replays of all the flights together (as ``gap-validate replay first second
...``); the planned card's flight time is the card's own (``flight_time_s``, longer than the generator's
channel time). The true noise comes from the generator's own parameters (:func:`second_true_noise`).

Measured: (a) each planned manoeuvre's predicted random error (the worst over the frequencies it closes, as
the estimator will report it: :attr:`~gap_validation.core.plan.PlannedManoeuvre.expected_worst_error`) against
the one measured when it is replayed on its own (goal: within a factor 1.5 on 90 % of the bands); (b)
the frequencies and bands without a verdict that have one after the planned card (replayed with the first
flight); (c) the planned card's flight time against repeating the default card until the same random error
(goal: 30 % less).

    python benchmarks/plan_campaigns.py                      # 20 campaigns
    python benchmarks/plan_campaigns.py --campaigns 4 --show # quicker, with each band's numbers
    python benchmarks/plan_campaigns.py --simulator second   # 20 campaigns of ../shared/flights (45 s each)
"""
from __future__ import annotations

import argparse
import concurrent.futures
import contextlib
import copy
import hashlib
import io
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gap_validation.blas import single_threaded_blas  # noqa: E402

single_threaded_blas()

from gap_validation.core.config import parse_config  # noqa: E402
from gap_validation.core.plan import (  # noqa: E402
    PREDICTION_FACTOR,
    PlanOptions,
    _channel_base,
    _information_record,
    _response,
    estimator_record,
    expected_worst,
    manoeuvre_signal,
    plan_card,
    predicted_random_error,
)
from gap_validation.core.simulation import FlightOptions, simulate_flight  # noqa: E402
from gap_validation.core.spectra import RESOLVED_FRACTION, expected_estimate, record_bands  # noqa: E402
from gap_validation.core.validator import OnlineValidator  # noqa: E402

CONFIG = ROOT / "config" / "ultrastick25e.yaml"
AIRFRAMES = ("ultrastick", "fast", "sluggish")
#: Sweep amplitudes of the first card [rad] (the doublets fly 0.06 rad: the largest deflection seen, the cap).
AMPLITUDES = (0.03, 0.05)
#: Start times of the flights of a campaign (each flight's own clock; the validator sees a break between
#: them).
FLIGHT_SPACING_S = 100_000.0


def _within(ratio: np.ndarray) -> np.ndarray:
    """Where measured over predicted is within the goal's factor
    (:data:`~gap_validation.core.plan.PREDICTION_FACTOR`) either way."""
    ratio = np.asarray(ratio, float)
    return (ratio <= PREDICTION_FACTOR) & (ratio >= 1.0 / PREDICTION_FACTOR)


def airframe(name: str) -> dict:
    """The config mapping of an airframe: the Ultra Stick's models with time scaled by ``factor`` (``P(s /
    f)``, grid scaled alike) and the control power by ``gain``."""
    factor, gain = {"ultrastick": (1.0, 1.0), "fast": (2.0, 1.0), "sluggish": (0.7, 0.6)}[name]
    data = yaml.safe_load(CONFIG.read_text())
    for ch in data["channels"].values():
        ss = ch["model"]["state_space"]
        ss["A"] = (np.array(ss["A"]) * factor).tolist()
        ss["B"] = (np.array(ss["B"]) * factor * gain).tolist()
        grid = ch["frequencies"]
        grid["min_rad_s"], grid["max_rad_s"] = (
            grid["min_rad_s"] * factor,
            min(grid["max_rad_s"] * factor, 80.0),
        )
    return data


def draw(rng: np.random.Generator, index: int, amplitudes: tuple[float, float] = AMPLITUDES) -> dict:
    """One campaign: airframe, air and first card (plain values); the first card's sweeps at ``amplitudes``
    [rad]."""
    name = AIRFRAMES[index % len(AIRFRAMES)]
    data = airframe(name)
    channels = list(data["channels"])
    noise = float(math.exp(rng.uniform(math.log(0.5), math.log(2.0))))
    first = dict(sweeps_per_channel=1, sweep_duration_s=float(rng.uniform(30.0, 60.0)),
                 sweep_amplitude_rad=float(rng.uniform(*amplitudes)), doublet_amplitude_rad=0.06, quiet_s=4.0,
                 noise=noise)
    air = {"noise": noise}
    if rng.random() < 0.5:
        ch = channels[int(rng.integers(len(channels)))]
        grid = data["channels"][ch]["frequencies"]
        low = float(
            math.exp(rng.uniform(math.log(grid["min_rad_s"] * 1.5), math.log(grid["max_rad_s"] / 3.0)))
        )
        air.update(band_noise_rad_s=(low, 1.6 * low), band_noise_rms_rad_s=float(rng.uniform(0.01, 0.04)),
                   band_noise_channels=(ch,))
    return {"index": index, "airframe": name, "config": data, "first": first, "air": air,
            "seed": int(rng.integers(0, 2 ** 31))}


def _replay(config, flights: list[tuple[object, tuple[str, ...]]], diagnose: bool = True) -> dict:
    """Feed flights (each with the channels it carries) to one validator; the results JSON."""
    v = OnlineValidator(config)
    for flight, channels in flights:
        for name in channels:
            v.add_histories(name, flight.histories(config.channels[name]))
        v.finish()
    return v.results(diagnose=diagnose).to_json_dict()


def _fly_manoeuvre(campaign: dict, m, seed: int, start_s: float):
    """One planned manoeuvre as a flight of the simulator (its channel only)."""
    data = copy.deepcopy(campaign["config"])
    data["channels"] = {m.channel: data["channels"][m.channel]}
    w0, w1 = m.band_rad_s
    data["channels"][m.channel]["frequencies"] = {"min_rad_s": 2.0 * w0, "max_rad_s": w1, "count": 10}
    config = parse_config(data, "planned manoeuvre")
    air = dict(campaign["air"])
    if "band_noise_channels" in air and air["band_noise_channels"][0] != m.channel:
        air = {"noise": air["noise"]}
    opts = FlightOptions(
        excitation="chirp",
        sweeps_per_channel=m.repeats,
        sweep_duration_s=m.duration_s,
        sweep_amplitude_rad=m.amplitude_rad,
        dwell_cycles=0.0,
        band_low_factor=0.5,
        band_high_factor=1.0,
        doublet_amplitude_rad=0.0,
        doublet_half_period_s=0.005,
        quiet_s=(m.trim_between_s - 0.01) / 2.0,
        trim_s=m.trim_before_s,
        start_time_s=start_s,
        **air,
    )
    return simulate_flight(config, None, opts, seed=seed)


def _worst(results: dict, channel: str, frequencies) -> float:
    ch = results["channels"][channel]
    w = np.asarray(ch["frequency_rad_s"], float)
    if w.size == 0:
        return math.inf
    e = np.array([math.inf if x is None else x for x in ch["random_error"]])
    idx = [int(np.argmin(np.abs(w - f))) for f in frequencies]
    return float(np.max(e[idx])) if idx else math.nan


def _verdict(results: dict, channel: str, f: float) -> bool:
    ch = results["channels"][channel]
    if not ch["frequency_rad_s"]:
        return False
    i = int(np.argmin(np.abs(np.asarray(ch["frequency_rad_s"], float) - f)))
    return ch["frequency_flags"][i] == "model" or (ch["frequency_flags"][i] == "ok"
                                                   and ch["frequency_reasons"][i] is None)


def true_noise(w: np.ndarray, air: dict, channel: str, dt: float = 0.01) -> np.ndarray:
    """The simulator's output noise per DFT bin of the estimator's grid at ``w`` (what the planner estimates):
    its gusts (second-order low-pass), the gyro's white noise and the channel's band noise, from
    :class:`~gap_validation.core.simulation.FlightOptions`' defaults and the campaign's air."""
    from scipy import signal

    opts = FlightOptions()
    rms, corner = opts.gust_rms_rad_s * air["noise"], opts.gust_bandwidth_rad_s
    psd = 4.0 * math.sqrt(2.0) * rms ** 2 / corner / (1.0 + (w / corner) ** 4)
    psd = psd + 2.0 * (opts.gyro_noise_rad_s * air["noise"]) ** 2 / opts.imu_rate_hz
    if air.get("band_noise_channels") and air["band_noise_channels"][0] == channel:
        low, high = air["band_noise_rad_s"]
        sos = signal.butter(4, [low / (2 * math.pi), high / (2 * math.pi)], btype="bandpass", output="sos",
                            fs=opts.sim_rate_hz)
        f = np.linspace(1e-3, opts.sim_rate_hz / 2, 100_000)
        gain = np.abs(signal.sosfreqz(sos, worN=f, fs=opts.sim_rate_hz)[1]) ** 2
        level = air["band_noise_rms_rad_s"] ** 2 / np.trapezoid(gain, f)
        psd = psd + level * np.abs(signal.sosfreqz(sos, worN=w / (2 * math.pi), fs=opts.sim_rate_hz)[1]) ** 2
    return psd / (2.0 * dt)


def oracle_error(config, m, air: dict) -> float:
    """The band's expected worst error (:func:`~gap_validation.core.plan.expected_worst`) with the simulator's
    true noise (gusts, gyro, band noise, the surface's sensor noise seen through the response) in place of the
    one estimated from the first flight: the planner's formula alone."""
    opts = FlightOptions()
    one = type(m)(**{**m.__dict__, "repeats": 1})
    t, u = manoeuvre_signal(one, 100.0)
    w = np.asarray(m.frequencies_rad_s)
    sums, _ = record_bands(u[None] / m.amplitude_rad, u[None], 0.01, w)
    model = config.channels[m.channel].model
    seen = np.abs(
        expected_estimate(sums, w, 0.1, lambda x: np.asarray(model.freqresp(x), complex).ravel())[0]
    )
    surface = 2.0 * (opts.surface_noise_rad * air["noise"]) ** 2 + opts.surface_lsb_rad ** 2 / 12.0
    q = true_noise(w, air, m.channel) / seen ** 2 + surface
    return expected_worst(predicted_random_error(q, sums.ff * m.repeats) / m.amplitude_rad, m.predicted_dof)


def run_campaign(campaign: dict, repeats: int) -> dict:
    """Fly, replay, plan, fly the plan, replay; repeat the first card for the comparison."""
    t_start = time.perf_counter()
    config = parse_config(copy.deepcopy(campaign["config"]), f"{campaign['airframe']}.yaml")
    channels = tuple(config.channels)
    seeds = np.random.SeedSequence(campaign["seed"]).generate_state(64)
    first_opts = FlightOptions(
        **campaign["first"], **{k: v for k, v in campaign["air"].items() if k != "noise"}
    )
    first = simulate_flight(config, None, first_opts, seed=int(seeds[0]))
    r1 = _replay(config, [(first, channels)])
    card = plan_card(config, r1, PlanOptions())
    out = _campaign_start(campaign, card, r1, channels, first.duration_s)
    flights, flown_s = [], 0.0
    for k, m in enumerate(card.manoeuvres):
        flight = _fly_manoeuvre(
            campaign, m, int(seeds[1 + k % 30]), first_opts.start_time_s + (k + 1) * FLIGHT_SPACING_S
        )
        flights.append((flight, (m.channel,)))
        flown_s += flight.duration_s
        alone = _replay(config, [(flight, (m.channel,))], diagnose=False)
        out["bands"].append(
            {
                "channel": m.channel,
                "closes": m.closes_rad_s,
                "predicted": m.expected_worst_error,
                "flown_s": flight.duration_s,
                "measured": _worst(alone, m.channel, m.frequencies_rad_s),
                "target": min(m.target_error),
                "points": len(m.frequencies_rad_s),
                "oracle": oracle_error(config, m, campaign["air"]),
                "amplitude": m.amplitude_rad,
                "set_by": m.amplitude_set_by,
                "per_point": [
                    (p, _worst(alone, m.channel, [f])) for f, p in zip(m.frequencies_rad_s, m.predicted_error)
                ],
            }
        )
    out["flown_plan_s"] = flown_s
    if flights:
        r12 = _replay(config, [(first, channels)] + flights)
        _score_verdicts(out, card, r1, r12, channels)
        for band, n in zip(
            out["bands"],
            _repeat_default(campaign, config, first, first_opts, card, out["bands"], seeds, repeats),
        ):
            band["repeats"] = n
    out["seconds"] = time.perf_counter() - t_start
    return out


def _campaign_start(campaign: dict, card, r1: dict, channels: tuple[str, ...], first_s: float) -> dict:
    """A campaign's record after the first flight and the plan."""
    out = {"campaign": campaign["index"], "airframe": campaign["airframe"], "first_s": first_s,
           "plan_s": card.flight_time_s, "bands": [], "unreachable": sum(len(p.unreachable)
                                                                          for p in card.channels.values()),
           "planned_points": 0, "points_closed": 0, "bands_closed": 0, "targets_before": 0}
    for name in channels:
        ch = r1["channels"][name]
        out["targets_before"] += sum(1 for flag, why in zip(ch["frequency_flags"], ch["frequency_reasons"])
                                     if flag != "model" and (flag == "data" or why is not None))
    return out


def _score_verdicts(out: dict, card, r1: dict, r12: dict, channels: tuple[str, ...]) -> None:
    """The planned bands and the first flight's data-limited frequencies with a verdict after the planned card
    (``r12``: replayed with the first flight)."""
    for band, m in zip(out["bands"], card.manoeuvres):
        closed = [_verdict(r12, m.channel, f) for f in m.frequencies_rad_s]
        band["closed"] = all(closed)
        band["pooled"] = _worst(r12, m.channel, m.frequencies_rad_s)
        out["planned_points"] += len(closed)
        out["points_closed"] += sum(closed)
        out["bands_closed"] += int(all(closed))
    out["data_before"] = out["data_closed"] = 0
    for name in channels:
        ch = r1["channels"][name]
        for f, flag in zip(ch["frequency_rad_s"], ch["frequency_flags"]):
            if flag == "data":
                out["data_before"] += 1
                out["data_closed"] += int(_verdict(r12, name, f))


def _repeat_default(campaign, config, first, first_opts, card, bands, seeds, repeats: int) -> list[float]:
    """Per planned band: how many more first cards (same air, new seeds), replayed with the first flight,
    bring its worst random error down to what the planned card left there (:func:`_repeats_needed`)."""
    channels = tuple(config.channels)
    v = OnlineValidator(config)
    for name in channels:
        v.add_histories(name, first.histories(config.channels[name]))
    v.finish()

    def repeated(k: int) -> dict:
        opts = FlightOptions(
            **{**first_opts.__dict__, "start_time_s": first_opts.start_time_s - k * FLIGHT_SPACING_S}
        )
        flight = simulate_flight(config, None, opts, seed=int(seeds[40 + k % 24]) + k)
        for name in channels:
            v.add_histories(name, flight.histories(config.channels[name]))
        v.finish()
        return v.results(diagnose=False).to_json_dict()

    return _repeats_needed(card, bands, repeated, repeats)


def _repeats_needed(card, bands, repeated, repeats: int) -> list[float]:
    """Per planned band, the repeats of the first card that bring its worst random error down to what the
    planned card left there (``band["pooled"]``); ``repeated(k)`` is the results after ``k`` repeats (called
    with k = 1, 2,
    ... in turn). Beyond ``repeats`` flown, extrapolated from the error after the last one as ``1 / sqrt(n)``
    (returned negative); ``inf`` when the repeated card never estimated the band (its input there stays below
    what the estimator counts); NaN when the planned card did not estimate it either (nothing to compare)."""
    needed = [math.inf if math.isfinite(band["pooled"]) else math.nan for band in bands]
    results = None
    for k in range(1, repeats + 1):
        results = repeated(k)
        for j, (m, band) in enumerate(zip(card.manoeuvres, bands)):
            if math.isinf(needed[j]) and _worst(results, m.channel, m.frequencies_rad_s) <= band["pooled"]:
                needed[j] = float(k)
        if not any(math.isinf(x) for x in needed):
            break
    for j, (m, band) in enumerate(zip(card.manoeuvres, bands)):
        # beyond the repeats flown: error falls as 1 / sqrt(n)
        if math.isinf(needed[j]) and results is not None:
            left = _worst(results, m.channel, m.frequencies_rad_s)
            if math.isfinite(left) and band["pooled"] > 0:
                needed[j] = -math.ceil(repeats * (left / band["pooled"]) ** 2)   # negative: extrapolated
    return needed


def _time_comparison(run: dict, extrapolated: bool) -> tuple[float, float, int]:
    """A campaign's planned flight time for the bands the repeated first card reached (within the repeats
    flown, or also by extrapolation), that repetition's time (the most repeats any of them needed, times the
    first card), and how many bands it did not reach."""
    def reached(b: dict) -> bool:
        n = b.get("repeats", math.inf)
        return math.isfinite(n) and (n > 0 or extrapolated)

    bands = [b for b in run["bands"] if reached(b)]
    plan = sum(b["flown_s"] for b in bands)
    repeat = max((abs(b["repeats"]) for b in bands), default=0.0) * run["first_s"]
    return plan, repeat, len(run["bands"]) - len(bands)


def summarise(runs: list[dict], show: bool, repeats: int, airframes: tuple[str, ...] = AIRFRAMES,
              labels: dict | None = None) -> str:
    """The benchmark's table and sentences (rows per airframe of ``airframes``, named by ``labels``)."""
    labels = labels or {}
    lines = [
        "| airframe | campaigns | planned bands | predicted error within x1.5 | measured / predicted "
        "(median, "
        "10-90 %) | bands closed | frequencies closed | unreachable bands | planned card | planned against "
        "repeated "
        "first card (bands reached within the repeats) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name in tuple(airframes) + ("all",):
        rs = [r for r in runs if name in ("all", r["airframe"])]
        if not rs:
            continue
        bs = [b for r in rs for b in r["bands"] if b["predicted"] > 0]
        rr = np.array([b["measured"] / b["predicted"] for b in bs])
        fin = rr[np.isfinite(rr)]
        ok = int(np.count_nonzero(_within(rr)))
        closed = sum(r["bands_closed"] for r in rs)
        pts, pts_closed = sum(r["planned_points"] for r in rs), sum(r["points_closed"] for r in rs)
        plan_all = sum(r["flown_plan_s"] for r in rs)
        measured = [_time_comparison(r, False) for r in rs]
        plan_m, rep_m = sum(c[0] for c in measured), sum(c[1] for c in measured)
        spread = (
            f"{np.median(fin):.2f} ({np.percentile(fin, 10):.2f}-{np.percentile(fin, 90):.2f})"
            if fin.size
            else "-"
        )
        lines.append(
            f"| {labels.get(name, name)} | {len(rs)} | {len(bs)} | {ok} ({100 * ok / max(len(bs), 1):.0f} %) "
            f"| {spread} | "
            f"{closed} of {len(bs)} | {pts_closed} of {pts} | {sum(r['unreachable'] for r in rs)} | "
            f"{plan_all / 60:.1f} min | {sum(len(r['bands']) - c[2] for r, c in zip(rs, measured))} bands: "
            f"{plan_m / 60:.1f} min against {rep_m / 60:.1f} min"
            f"{f' ({100 * (1 - plan_m / rep_m):.0f} % less)' if rep_m > 0 else ''} |"
        )
    lines.append("")
    for extrapolated in (False, True):
        cmp_ = [_time_comparison(r, extrapolated) for r in runs if r["bands"]]
        per = [1 - c[0] / c[1] for c in cmp_ if c[1] > 0]
        if not per:
            continue
        what = (f"with the bands beyond {repeats} repeats extrapolated as 1/sqrt(n)" if extrapolated else
                f"the bands the first card reached within {repeats} repeats")
        lines.append(
            f"flight time for the same random error ({what}): the planned card "
            f"{100 * (1 - sum(c[0] for c in cmp_) / sum(c[1] for c in cmp_)):.0f} % less in all, per "
            "campaign "
            f"median {100 * float(np.median(per)):.0f} % less, {sum(1 for x in per if x >= 0.3)} of "
            f"{len(per)} "
            f"campaigns at least 30 % less; bands left out: {sum(c[2] for c in cmp_)}"
        )
    before = sum(r["targets_before"] for r in runs)
    data = sum(r.get("data_before", 0) for r in runs)
    lines.append(
        f"after the first card, {before} frequencies had no verdict ({data} of them data-limited); after the "
        f"planned card (replayed with the first), {sum(r.get('data_closed', 0) for r in runs)} of the {data} "
        f"data-limited ones have a verdict, {sum(r['points_closed'] for r in runs)} of the "
        f"{sum(r['planned_points'] for r in runs)} planned ones; the rest is unreachable, with the reason"
    )
    oracle = np.array([b["measured"] / b["oracle"] for r in runs for b in r["bands"] if b["oracle"] > 0])
    if oracle.size:
        ok = int(np.count_nonzero(_within(oracle)))
        fin = oracle[np.isfinite(oracle)]
        gone = (
            f" ({oracle.size - fin.size} not estimated by the flight alone)" if fin.size < oracle.size else ""
        )
        lines.append(
            "the same prediction with the simulator's true noise spectrum in place of the one estimated "
            "from the "
            f"first flight: {ok} of {oracle.size} bands within x1.5 ({100 * ok / oracle.size:.0f} %), "
            f"measured/predicted median {np.median(fin):.2f}, 10-90 % {np.percentile(fin, 10):.2f}-"
            f"{np.percentile(fin, 90):.2f}{gone}"
        )
    pts = np.array(
        [m / p for r in runs for b in r["bands"] for p, m in b["per_point"] if math.isfinite(m) and p > 0]
    )
    if pts.size:
        lines.append(
            f"per frequency: measured/predicted median {np.median(pts):.2f}, 10-90 % "
            f"{np.percentile(pts, 10):.2f}-"
            f"{np.percentile(pts, 90):.2f}, within x1.5: {100 * np.mean(_within(pts)):.0f} %"
        )
    lines.append(f"time per campaign: {np.mean([r['seconds'] for r in runs]):.1f} s")
    if show:
        for r in runs:
            lines.append(
                f"campaign {r['campaign']} ({r['airframe']}): first card {r['first_s']:.0f} s, planned card "
                f"{r['flown_plan_s']:.0f} s, {r['unreachable']} unreachable"
            )
            for b in r["bands"]:
                lines.append(
                    f"  {b['channel']:5s} {b['closes'][0]:6.3g}-{b['closes'][1]:<6.3g} predicted "
                    f"{b['predicted']:.3f} measured {b['measured']:.3f} with the first "
                    f"{b.get('pooled', math.nan):.3f} "
                    f"target {b['target']:.3f} A {b['amplitude']:.3f} ({b['set_by']}) {b['flown_s']:.0f} s "
                    f"{'closed' if b.get('closed') else 'OPEN'}; first card "
                    f"x{abs(b.get('repeats', math.nan)):g}"
                    f"{' (extrapolated)' if b.get('repeats', 0) < 0 else ''}"
                )
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------ the second
# simulator
#: The second simulator's airframes (``../shared/flights``, written apart from ours:
#: benchmarks/second_simulator.py): flightgen's Ultra Stick 25e at its own rates (IMU 100 Hz, surfaces 50 Hz,
#: first sweeps 0.2-8 Hz), on the project config's grid; hardgen's twice-as-fast airframe (``airframe_scale``
#: 2) set up as its own ``clean_fast`` case (IMU 200 Hz, surfaces 100 Hz, sweeps 0.3-16 Hz, grid 2-120 rad/s).
SECOND_AIRFRAMES = {
    "ultrastick": {"label": "Ultra Stick 25e (flightgen)", "generator": "flightgen.py", "case": {},
                   "grid": {"min_rad_s": 1.0, "max_rad_s": 40.0, "count": 40}, "sweep_hz": [0.2, 8.0],
                   "imu_hz": 100.0, "surfaces_hz": 50.0},
    "fast": {"label": "twice as fast (hardgen)", "generator": "hard/hardgen.py",
             "case": {"airframe_scale": 2.0, "imu_hz": 200.0, "surfaces_hz": 100.0},
             "grid": {"min_rad_s": 2.0, "max_rad_s": 120.0, "count": 40}, "sweep_hz": [0.3, 16.0],
             "imu_hz": 200.0, "surfaces_hz": 100.0},
}
#: The generator that flies the planned manoeuvres: hardgen (flightgen's airframe, gusts, sensors and pilot;
#: at ``airframe_scale`` 1 with no effects it is flightgen) takes the trim after each sweep as ``pause_s``, so
#: the card's 6 s are flown; flightgen's 3 s cut a 10 s sweep's records too short at its lowest target.
PLANNED_GENERATOR = "hard/hardgen.py"
#: The first card's sweep amplitudes [rad] (its doublets fly 1.6 times that: the largest deflection, the cap).
SECOND_AMPLITUDES = (0.02, 0.04)
#: The generators' own constants (flightgen.py, hardgen.py), for the noise they fly: gust level
#: (``gust_rad``'s default, rad rms surface-equivalent) through a first-order low-pass of 2 rad/s, gyro noise
#: [rad/s per sample], surface sensor noise [rad per sample]; the least trim before a sweep (the 2 s at the
#: start) and the trim after each sweep [s] (hardgen's ``pause_s``, flightgen's always).
SECOND_GUST_RAD, SECOND_GUST_CORNER_RAD_S, SECOND_GYRO_NOISE, SECOND_SURFACE_NOISE = 0.004, 2.0, 0.005, 0.0005
SECOND_TRIM_BEFORE_S, SECOND_TRIM_BETWEEN_S = 2.0, 3.0


class _Still:
    """A generator's random source drawing zeros: its excitation without the pilot's trim motion (the layout
    and the sweeps exactly as it flies them)."""

    def standard_normal(self, n: int) -> np.ndarray:
        return np.zeros(n)


def _generator(name: str):
    """``flightgen.py`` or ``hard/hardgen.py`` as a module (``benchmarks/_other_simulators.py`` imports them;
    never changed: its ``generate`` is called with ``HERE`` pointing at a directory holding the flight's own
    ``cases.yaml``)."""
    import _other_simulators

    return dict(zip(("flightgen.py", "hard/hardgen.py"), _other_simulators._generators()))[name]


def make_second_flight(out: Path, generator: str, case: dict) -> Path:
    """Make one flight of the second simulator once (cached under ``out`` by the case's hash): ``bag`` and
    ``nominal.yaml`` in the returned directory."""
    key = json.dumps({"generator": generator, "case": case}, sort_keys=True)
    where = out / hashlib.sha1(key.encode()).hexdigest()[:16]
    if (where / "made.json").exists():
        return where
    where.mkdir(parents=True, exist_ok=True)
    (where / "cases.yaml").write_text(yaml.safe_dump({"flight": case}, sort_keys=True))
    module = _generator(generator)
    here, module.HERE = module.HERE, where
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            module.generate("flight", where)
    finally:
        module.HERE = here
    (where / "made.json").write_text(key)
    return where


def _second_case(campaign: dict, plan: dict, seed: int) -> dict:
    """A case of the generator: the airframe's setup, the campaign's air, the flight's own seed and card."""
    return {
        **SECOND_AIRFRAMES[campaign["airframe"]]["case"],
        "seed": int(seed),
        "gust_rad": campaign["gust_rad"],
        "plan": plan,
    }


def _second_plan(m) -> dict:
    """A planned manoeuvre as the generator's card: its band, one sweep's length, the repeats, the amplitude
    and the trim after each sweep."""
    return {
        "sweeps": int(m.repeats),
        "sweep_seconds": float(m.duration_s),
        "amplitude_rad": float(m.amplitude_rad),
        "sweep_hz": [float(m.f_start_hz), float(m.f_stop_hz)],
        "pause_s": float(m.trim_between_s),
    }


def _flown(generator: str, plan: dict) -> tuple[dict, float]:
    """The generator's surfaces for ``plan`` without the pilot's trim motion, and its sample rate [Hz]."""
    module = _generator(generator)
    u = module.excitation({"plan": plan}, _Still())
    return (u[0] if isinstance(u, tuple) else u), float(
        getattr(module, "SIM_HZ", getattr(module, "FS", 1000.0))
    )


def second_flight_s(generator: str, plan: dict, channel: str | None = None) -> float:
    """A flight's length [s] (``channel``: only that surface's part: its sweeps, the trim after each, its
    doublet)."""
    u, rate = _flown(generator, plan)
    if channel is None:
        return len(u["pitch"]) / rate
    return plan["sweeps"] * (int(plan["sweep_seconds"] * rate) / rate + _pause(generator, plan)) + 6.0


def _pause(generator: str, plan: dict) -> float:
    """The trim the generator flies after each sweep [s]: hardgen's ``pause_s``, flightgen's 3 s."""
    return (
        float(plan.get("pause_s", SECOND_TRIM_BETWEEN_S)) if "hardgen" in generator else SECOND_TRIM_BETWEEN_S
    )


#: A planned manoeuvre's flight is scored with the estimator's ``min_sweep_s`` at this [s]. The generator
#: flies a doublet (1 s) after each surface's sweeps, which the card does not ask for (its sweeps last at
#: least :data:`~gap_validation.core.plan.MIN_SWEEP_S`, 10 s). Pooled with the sweeps where its short record
#: counts, the doublet lifted the neighbouring frequencies' noise through the estimator's neighbour floor
#: (:func:`~gap_validation.core.spectra.neighbour_noise_floor`; 4-20 times near the Ultra Stick's Dutch roll,
#: 5 rad/s): the measured error was the doublet's, not the card's. With the option (a config option a user
#: has) the doublet gives no frequency response, only its time history.
SCORED_MIN_SWEEP_S = 5.0


def second_config(where: Path, grid: dict, min_sweep_s: float | None = None):
    """The flight's ``nominal.yaml`` (the airframe-only config a user starts from) with the airframe's
    grid (and the estimator's ``min_sweep_s``, when given)."""
    data = yaml.safe_load((where / "nominal.yaml").read_text())
    for ch in data["channels"].values():
        ch["frequencies"] = dict(grid)
        if min_sweep_s is not None:
            ch["estimator"] = {**(ch.get("estimator") or {}), "min_sweep_s": float(min_sweep_s)}
    return parse_config(data, str(where / "nominal.yaml"))


def _replay_bags(config, dirs: list[Path], diagnose: bool = True) -> dict:
    """The flights replayed together through the library's replay (the one data path); the results JSON."""
    from gap_validation.bag.replay import replay

    return replay([d / "bag" for d in dirs], config, diagnose=diagnose).result.to_json_dict()


def flown_sums(config, generator: str, m):
    """One sweep of the manoeuvre at amplitude 1 as the generator flies it (its log chirp, 0.5 s linear
    tapers, its 2 s of trim before and the trim after), on the record the estimator cuts around it
    (:func:`~gap_validation.core.plan.estimator_record`, as the planner computes its own), through
    :func:`~gap_validation.core.spectra.record_bands`: ``(sums, status)``."""
    c = _channel_base(m.channel, config.channels[m.channel])
    plan = {**_second_plan(m), "sweeps": 1, "amplitude_rad": 1.0}
    u, rate = _flown(generator, plan)
    x = u[m.channel]
    start = int(np.flatnonzero(x)[0]) - 1             # the sweep starts at zero (sin, tapered)
    length = int(m.duration_s * rate)
    step = int(round(rate * c.dt))
    around = x[max(start - int(round(SECOND_TRIM_BEFORE_S * rate)), 0):
               start + length + int(round(_pause(generator, plan) * rate)): step]
    record = estimator_record(around, c.dt, c.pre_s, c.post_s)
    return record_bands(record[None], record[None], c.dt, np.asarray(m.frequencies_rad_s), options=c.spectra)


def card_sums(config, m):
    """One sweep of the card's manoeuvre at amplitude 1 on the record the estimator cuts around it (as the
    planner computes its information: ``_information_record``): ``(sums, status)``."""
    c = _channel_base(m.channel, config.channels[m.channel])
    opts = PlanOptions(fade_s=m.fade_in_s, trim_before_s=m.trim_before_s, trim_between_s=m.trim_between_s)
    u = _information_record(c, opts, m.duration_s, m.f_start_hz, m.f_stop_hz)
    return record_bands(u[None], u[None], c.dt, np.asarray(m.frequencies_rad_s), options=c.spectra)


def flown_prediction(config, generator: str, m) -> np.ndarray:
    """The planner's prediction for what the generator flies: its noise estimate (recovered from the card's
    predicted error and the card's own sweep, ``q = 2 n A^2 e^2 / [(Phi^H Phi)^-1]_00``) with the information
    of the generator's sweep instead of the card's; inf where the flown sweep does not count
    (:func:`record_bands`)."""
    card, card_status = card_sums(config, m)
    flown, status = flown_sums(config, generator, m)
    ratio = predicted_random_error(1.0, flown.ff) / predicted_random_error(1.0, card.ff)
    pred = np.asarray(m.predicted_error) * ratio
    return np.where((status == 0) & (card_status == 0) & np.isfinite(pred), pred, np.inf)


def second_true_noise(
    w: np.ndarray, gust_rad: float, spec: dict, dt: float
) -> tuple[np.ndarray, float, float]:
    """The generator's noise per DFT bin of the estimator's grid at ``w``, from its own parameters: the gust
    (surface-equivalent: first-order low-pass at 2 rad/s of white noise at 1 kHz, scaled to ``gust_rad`` rms),
    the gyro's white noise at the IMU's rate, and the surface sensor's at the surfaces' rate."""
    from scipy import signal

    module = _generator(spec["generator"])
    rate = float(getattr(module, "SIM_HZ", getattr(module, "FS", 1000.0)))
    b, a = signal.butter(1, SECOND_GUST_CORNER_RAD_S / (math.pi * rate))
    f = np.linspace(0.0, rate / 2.0, 400_001)
    gain = np.abs(signal.freqz(b, a, worN=f, fs=rate)[1]) ** 2
    level = gust_rad ** 2 / np.trapezoid(gain, f)
    gust = level * np.abs(signal.freqz(b, a, worN=w / (2 * math.pi), fs=rate)[1]) ** 2 / (2.0 * dt)
    gyro = 2.0 * SECOND_GYRO_NOISE ** 2 / spec["imu_hz"] / (2.0 * dt)
    surface = 2.0 * SECOND_SURFACE_NOISE ** 2 / spec["surfaces_hz"] / (2.0 * dt)
    return gust, gyro, surface


def second_oracle(config, campaign: dict, m) -> np.ndarray:
    """Per frequency, the planner's formula on the flown sweep with the generator's true noise in place of the
    one estimated from the first flight: ``q = (gust |P|^2 + gyro) / |P_seen|^2 + surface``."""
    spec = SECOND_AIRFRAMES[campaign["airframe"]]
    c = _channel_base(m.channel, config.channels[m.channel])
    sums, status = flown_sums(config, PLANNED_GENERATOR, m)
    w = np.asarray(m.frequencies_rad_s)
    response = _response(c.model)
    seen = np.abs(expected_estimate(sums, w, float(c.spectra["band_fraction"]), response)[0])
    gust, gyro, surface = second_true_noise(w, campaign["gust_rad"], spec, c.dt)
    q = (gust * np.abs(response(w)) ** 2 + gyro) / seen ** 2 + surface
    e = predicted_random_error(q, sums.ff * m.repeats) / m.amplitude_rad
    return np.where(status == 0, e, np.inf)


def _scatter_ceiling(bands: list[dict], draws: int = 2000, seed: int = 0) -> float:
    """The share of bands within x1.5 a perfect prediction would reach, the measured error scattering as its
    noise estimate does on the predicted degrees of freedom (``e sqrt(chi2(2 d) / 2 d)`` per frequency,
    independently: ``d`` counts complex DFT bins, two real ones each; the band's worst against its expected
    value, :func:`~gap_validation.core.plan.expected_worst`)."""
    rng = np.random.default_rng(seed)
    hits = []
    for b in bands:
        exact = np.array([o for _, _, o in b["flown_per_point"]])
        dof = np.maximum(np.array(b["dof"]), 1.0)
        if not np.all(np.isfinite(exact)):
            continue
        worst = np.max(
            exact * np.sqrt(rng.chisquare(2.0 * dof, size=(draws, dof.size)) / (2.0 * dof)), axis=1
        ) / expected_worst(exact, dof)
        hits.append(np.mean(_within(worst)))
    return float(np.mean(hits)) if hits else math.nan


def draw_second(
    rng: np.random.Generator, index: int, amplitudes: tuple[float, float] = SECOND_AMPLITUDES
) -> dict:
    """One campaign of the second simulator: airframe, air (the gust x0.5-2) and a short weak first card (one
    30-60 s sweep per channel at ``amplitudes``, its doublets at 1.6 times that)."""
    name = tuple(SECOND_AIRFRAMES)[index % len(SECOND_AIRFRAMES)]
    gust = SECOND_GUST_RAD * float(math.exp(rng.uniform(math.log(0.5), math.log(2.0))))
    first = {"sweeps": 1, "sweep_seconds": round(float(rng.uniform(30.0, 60.0)), 2),
             "amplitude_rad": round(float(rng.uniform(*amplitudes)), 4),
             "sweep_hz": list(SECOND_AIRFRAMES[name]["sweep_hz"])}
    return {
        "index": index,
        "airframe": name,
        "gust_rad": gust,
        "first": first,
        "seed": int(rng.integers(0, 2**31)),
    }


def run_second_campaign(job: tuple[dict, int, str, bool]) -> dict:
    """Fly, replay, plan, fly the plan, replay; repeat the first card: on the second simulator (a worker's
    job)."""
    campaign, repeats, out, tell_log_rate = job
    out = Path(out)
    t_start = time.perf_counter()
    spec = SECOND_AIRFRAMES[campaign["airframe"]]
    generator = spec["generator"]
    slowest_hz = min(spec["imu_hz"], spec["surfaces_hz"])
    seeds = np.random.SeedSequence(campaign["seed"]).generate_state(64)
    first = make_second_flight(out, generator, _second_case(campaign, campaign["first"], seeds[0]))
    config = second_config(first, SECOND_AIRFRAMES[campaign["airframe"]]["grid"])
    scored_config = second_config(first, spec["grid"], SCORED_MIN_SWEEP_S)
    channels = tuple(config.channels)
    r1 = _replay_bags(config, [first])
    card = plan_card(config, r1, PlanOptions(log_rate_hz=slowest_hz if tell_log_rate else None))
    run = _campaign_start(campaign, card, r1, channels, second_flight_s(generator, campaign["first"]))
    dirs = []
    for k, m in enumerate(card.manoeuvres):
        plan = _second_plan(m)
        where = make_second_flight(out, PLANNED_GENERATOR, _second_case(campaign, plan, seeds[1 + k % 30]))
        dirs.append(where)
        alone = _replay_bags(scored_config, [where], diagnose=False)
        flown = flown_prediction(config, PLANNED_GENERATOR, m)
        oracle = second_oracle(config, campaign, m)
        run["bands"].append(
            {
                "channel": m.channel,
                "closes": m.closes_rad_s,
                "predicted": m.expected_worst_error,
                "flown_s": m.flight_time_s,
                "generator_s": second_flight_s(PLANNED_GENERATOR, plan, m.channel),
                "measured": _worst(alone, m.channel, m.frequencies_rad_s),
                "target": min(m.target_error),
                "points": len(m.frequencies_rad_s),
                "oracle": expected_worst(oracle, m.predicted_dof),
                "flown_predicted": expected_worst(flown, m.predicted_dof),
                "amplitude": m.amplitude_rad,
                "set_by": m.amplitude_set_by,
                "repeats_flown": m.repeats,
                "above_logs": m.band_rad_s[1] > 2 * math.pi * RESOLVED_FRACTION * slowest_hz * (1 + 1e-4),
                "per_point": [
                    (p, _worst(alone, m.channel, [f])) for f, p in zip(m.frequencies_rad_s, m.predicted_error)
                ],
                "flown_per_point": [
                    (float(p), _worst(alone, m.channel, [f]), float(o))
                    for f, p, o in zip(m.frequencies_rad_s, flown, oracle)
                ],
                "dof": [float(d) for d in m.predicted_dof],
            }
        )
    run["flown_plan_s"] = sum(b["flown_s"] for b in run["bands"])
    if dirs:
        r12 = _replay_bags(config, [first] + dirs)
        _score_verdicts(run, card, r1, r12, channels)

        def repeated(k: int) -> dict:
            flights = [make_second_flight(out, generator, _second_case(campaign, campaign["first"],
                                                                        int(seeds[40 + j % 24]) + j))
                       for j in range(1, k + 1)]
            return _replay_bags(config, [first] + flights, diagnose=False)

        for band, n in zip(run["bands"], _repeats_needed(card, run["bands"], repeated, repeats)):
            band["repeats"] = n
    run["seconds"] = time.perf_counter() - t_start
    return run


def second_notes(runs: list[dict], show: bool) -> str:
    """What the second simulator adds to the table: the prediction for the sweep the generator flies, the
    planner's noise against the generator's, and the flight time as the generator flies the card."""
    lines = []
    bs = [b for r in runs for b in r["bands"] if b["predicted"] > 0]
    rr = np.array([b["measured"] / b["flown_predicted"] for b in bs])
    fin = rr[np.isfinite(rr)]
    if fin.size:
        ok = int(np.count_nonzero(_within(rr)))
        lines.append(
            f"predicted for the sweep the generator flies (its 0.5 s linear tapers and 2 s first trim; the "
            f"planner's noise estimate): {ok} of {rr.size} bands within x1.5 ({100 * ok / rr.size:.0f} %), "
            f"measured/predicted median {np.median(fin):.2f}, 10-90 % {np.percentile(fin, 10):.2f}-"
            f"{np.percentile(fin, 90):.2f}"
        )
    noise = np.array(
        [b["predicted"] / b["oracle"] for b in bs if b["oracle"] > 0 and math.isfinite(b["oracle"])]
    )
    if noise.size:
        lines.append(f"the planner's predicted error over the one with the generator's true noise (its noise "
                     f"estimate's error, as a random error): median {np.median(noise):.2f}, 10-90 % "
                     f"{np.percentile(noise, 10):.2f}-{np.percentile(noise, 90):.2f}; within x1.5 on "
                     f"{int(np.count_nonzero(_within(noise)))} of {noise.size} bands")
    truth = np.array(
        [b["measured"] / b["oracle"] for b in bs if math.isfinite(b["measured"]) and b["oracle"] > 0]
    )
    if truth.size:
        ok = int(np.count_nonzero(_within(truth)))
        lines.append(
            f"with the true noise, on the {truth.size} bands the flight alone estimated: {ok} within x1.5 "
            f"({100 * ok / truth.size:.0f} %), measured/predicted median {np.median(truth):.2f}, 10-90 % "
            f"{np.percentile(truth, 10):.2f}-{np.percentile(truth, 90):.2f}"
        )
        ideal = _scatter_ceiling([b for b in bs if math.isfinite(b["measured"]) and b["oracle"] > 0])
        lines.append(
            "  of which the measured error's own scatter allows (its noise estimate on the predicted "
            "degrees "
            f"of freedom, chi-square, each frequency alone, the band's worst against its expected value): "
            f"{100 * ideal:.0f} % within x1.5"
        )
    misses = [b for b in bs if not _within(b["measured"] / b["predicted"])]
    if misses:
        low = sum(1 for b in misses if b["measured"] < b["predicted"])
        gone = sum(1 for b in misses if math.isinf(b["measured"]))
        lines.append(
            f"misses: {len(misses)} bands, {low} measured better than predicted, {len(misses) - low - gone} "
            f"worse, {gone} with a frequency the flight alone did not estimate"
        )
    above = [b for b in bs if b["above_logs"]]
    if above:
        lines.append(
            f"{len(above)} bands swept above {RESOLVED_FRACTION:g} of the slowest stream's rate (what the "
            f"logs resolve), {sum(1 for b in above if b.get('closed'))} of them closed"
        )
    fate = {
        "reached within the repeats": 0,
        "extrapolated": 0,
        "never estimated": 0,
        "not estimated by the plan": 0,
    }
    for b in bs:
        n = b.get("repeats", math.nan)
        key = ("not estimated by the plan" if math.isnan(n) else "never estimated" if math.isinf(n) else
               "extrapolated" if n < 0 else "reached within the repeats")
        fate[key] += 1
    lines.append(
        "the repeated first card, per planned band: " + ", ".join(f"{k} {v}" for k, v in fate.items())
    )
    card_s, flown_s = sum(b["flown_s"] for b in bs), sum(b["generator_s"] for b in bs)
    lines.append(
        f"flight time: the planned manoeuvres as the card flies them {card_s / 60:.1f} min (counted in the "
        f"table), as the generator flies them (a doublet per channel) {flown_s / 60:.1f} min of "
        f"their channel's time"
    )
    if show:
        for r in runs:
            for b in r["bands"]:
                lines.append(
                    f"campaign {r['campaign']} ({r['airframe']}) {b['channel']:5s} {b['closes'][0]:6.3g}-"
                    f"{b['closes'][1]:<6.3g} x{b['repeats_flown']} predicted {b['predicted']:.3f} for the "
                    f"flown sweep {b['flown_predicted']:.3f} true noise {b['oracle']:.3f} measured "
                    f"{b['measured']:.3f}"
                )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--campaigns", type=int, default=20, help="campaigns (20)")
    parser.add_argument("--seed", type=int, default=25, help="seed of the draws (25)")
    parser.add_argument("--repeats", type=int, default=12, help="most repeats of the first card (12)")
    parser.add_argument("--show", action="store_true", help="each campaign's bands")
    parser.add_argument("--amplitudes", type=float, nargs=2, default=AMPLITUDES, metavar=("LOW", "HIGH"),
                        help=f"the first card's sweep amplitudes [rad] ({AMPLITUDES[0]:g} {AMPLITUDES[1]:g})")
    parser.add_argument(
        "--simulator",
        choices=("ours", "second", "both"),
        default="ours",
        help="ours (gap_validation.core.simulation, the default), second (../shared/flights) or "
        "both (ours, then the second)",
    )
    parser.add_argument(
        "--second-amplitudes",
        type=float,
        nargs=2,
        default=SECOND_AMPLITUDES,
        metavar=("LOW", "HIGH"),
        help="the second simulator's first card's sweep amplitudes [rad] "
        f"({SECOND_AMPLITUDES[0]:g} {SECOND_AMPLITUDES[1]:g})",
    )
    parser.add_argument("--out", default=str(ROOT / "out" / "plan_campaigns"),
                        help="the second simulator's flights are made here once")
    parser.add_argument(
        "--workers", type=int, default=1, help="worker processes of the second simulator (1-2; 1)"
    )
    parser.add_argument("--json", help="second simulator: write every campaign's record here")
    parser.add_argument(
        "--hide-log-rate",
        action="store_true",
        help="second simulator: plan without --log-rate-hz (the slowest logged stream's rate, given "
        "by default as docs/flying.md asks: the first card's results do not say it where it "
        "swept below it)",
    )
    args = parser.parse_args(argv)
    if not 1 <= args.workers <= 2:
        parser.error(f"--workers {args.workers}: expected 1 or 2")
    if args.simulator in ("ours", "both"):
        rng = np.random.default_rng(args.seed)
        campaigns = [draw(rng, i, tuple(args.amplitudes)) for i in range(args.campaigns)]
        runs = []
        for campaign in campaigns:
            runs.append(run_campaign(campaign, args.repeats))
            print(
                f"campaign {campaign['index']} ({campaign['airframe']}): {len(runs[-1]['bands'])} bands "
                "planned, "
                f"{runs[-1]['seconds']:.1f} s",
                file=sys.stderr,
                flush=True,
            )
        print(summarise(runs, args.show, args.repeats))
    if args.simulator in ("second", "both"):
        print(second_main(args))
    return 0


def second_main(args: argparse.Namespace) -> str:
    """The campaigns on the second simulator (``args.workers`` processes), their table and sentences."""
    rng = np.random.default_rng([args.seed, 2])
    campaigns = [draw_second(rng, i, tuple(args.second_amplitudes)) for i in range(args.campaigns)]
    jobs = [(c, args.repeats, str(Path(args.out).resolve()), not args.hide_log_rate) for c in campaigns]
    runs = []
    start = time.perf_counter()
    with concurrent.futures.ProcessPoolExecutor(max_workers=args.workers) as pool:
        for run in pool.map(run_second_campaign, jobs):
            runs.append(run)
            print(
                f"second simulator, campaign {run['campaign']} ({run['airframe']}): {len(run['bands'])} "
                "bands "
                f"planned, {run['seconds']:.1f} s",
                file=sys.stderr,
                flush=True,
            )
    head = (f"\nthe second simulator (../shared/flights): {len(runs)} campaigns, seed {args.seed}, "
            f"{time.perf_counter() - start:.0f} s on {args.workers} workers\n")
    if args.json:
        Path(args.json).write_text(json.dumps(runs, indent=1, default=str))
    labels = {name: spec["label"] for name, spec in SECOND_AIRFRAMES.items()}
    return "\n".join([head, summarise(runs, args.show, args.repeats, tuple(SECOND_AIRFRAMES), labels),
                      second_notes(runs, args.show)])


if __name__ == "__main__":
    sys.exit(main())
