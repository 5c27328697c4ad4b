"""Predictions that hold: seeded campaigns of "fly, replay, plan, fly the plan, replay" on our simulator (issue 25).

Each campaign draws an airframe (the Ultra Stick 25e, the same airframe twice as fast, and a sluggish one: 0.7 times as
fast with 0.6 of the control power), the air (noise and gusts x0.5-2, a narrow-band disturbance on one channel in
half of them, as a vibration or a badly flown band) and a deliberately short and weak first card (one 30-60 s log
sweep per channel at 0.02-0.04 rad, then the usual 0.05 rad doublet). Then:

1. the first card is flown (:func:`gap_validation.core.simulation.simulate_flight`) and replayed (fed to the
   validator, the library path of the one data path);
2. :func:`gap_validation.core.plan.plan_card` plans from its results (``replay --json``'s JSON);
3. each planned manoeuvre is flown in the same air as its own flight of the simulator: the card's log chirp is the
   simulator's sweep (``excitation chirp``, no dwell, 1 s fades, ``sweeps_per_channel`` = the repeats, the band set
   through a one-channel config's grid and ``band_low_factor``/``band_high_factor``, zero-amplitude doublets so the
   trim between sweeps is the card's), and replayed on its own and together with the first flight;
4. the default (first) card is flown again and again (new seeds, same air) and replayed together with the first
   flight until every planned band's random error is as low as the planned card left it (at most ``--repeats``).

Measured: (a) each planned manoeuvre's predicted random error (the worst over the frequencies it closes) against the
one measured when it is replayed on its own (goal: within a factor 1.5 on 90 % of the bands); (b) the frequencies
and bands without a verdict that have one after the planned card (replayed with the first flight); (c) the planned
card's flight time against repeating the default card until the same random error (goal: 30 % less).

    python benchmarks/plan_campaigns.py                      # 20 campaigns
    python benchmarks/plan_campaigns.py --campaigns 4 --show # quicker, with each band's numbers
"""
from __future__ import annotations

import argparse
import copy
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
from gap_validation.core.plan import PlanOptions, manoeuvre_signal, plan_card, predicted_random_error  # noqa: E402
from gap_validation.core.spectra import expected_estimate, record_bands  # noqa: E402
from gap_validation.core.simulation import FlightOptions, simulate_flight  # noqa: E402
from gap_validation.core.validator import OnlineValidator  # noqa: E402

CONFIG = ROOT / "config" / "ultrastick25e.yaml"
AIRFRAMES = ("ultrastick", "fast", "sluggish")
#: Sweep amplitudes of the first card [rad] (the doublets fly 0.06 rad: the largest deflection seen, the cap).
AMPLITUDES = (0.03, 0.05)
#: Start times of the flights of a campaign (each flight's own clock; the validator sees a break between them).
FLIGHT_SPACING_S = 100_000.0


def airframe(name: str) -> dict:
    """The config mapping of an airframe: the Ultra Stick's models with time scaled by ``factor`` (``P(s / f)``,
    grid scaled alike) and the control power by ``gain``."""
    factor, gain = {"ultrastick": (1.0, 1.0), "fast": (2.0, 1.0), "sluggish": (0.7, 0.6)}[name]
    data = yaml.safe_load(CONFIG.read_text())
    for ch in data["channels"].values():
        ss = ch["model"]["state_space"]
        ss["A"] = (np.array(ss["A"]) * factor).tolist()
        ss["B"] = (np.array(ss["B"]) * factor * gain).tolist()
        grid = ch["frequencies"]
        grid["min_rad_s"], grid["max_rad_s"] = grid["min_rad_s"] * factor, min(grid["max_rad_s"] * factor, 80.0)
    return data


def draw(rng: np.random.Generator, index: int, amplitudes: tuple[float, float] = AMPLITUDES) -> dict:
    """One campaign: airframe, air and first card (plain values); the first card's sweeps at ``amplitudes`` [rad]."""
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
        low = float(math.exp(rng.uniform(math.log(grid["min_rad_s"] * 1.5), math.log(grid["max_rad_s"] / 3.0))))
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
    opts = FlightOptions(excitation="chirp", sweeps_per_channel=m.repeats, sweep_duration_s=m.duration_s,
                         sweep_amplitude_rad=m.amplitude_rad, dwell_cycles=0.0, band_low_factor=0.5,
                         band_high_factor=1.0, doublet_amplitude_rad=0.0, doublet_half_period_s=0.005,
                         quiet_s=(m.trim_between_s - 0.01) / 2.0, trim_s=m.trim_before_s, start_time_s=start_s, **air)
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
    """The simulator's output noise per DFT bin of the estimator's grid at ``w`` (what the planner estimates): its
    gusts (second-order low-pass), the gyro's white noise and the channel's band noise, from
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
    """The band's worst predicted error with the simulator's true noise (gusts, gyro, band noise, the surface's
    sensor noise seen through the response) in place of the one estimated from the first flight: the planner's
    formula alone."""
    opts = FlightOptions()
    one = type(m)(**{**m.__dict__, "repeats": 1})
    t, u = manoeuvre_signal(one, 100.0)
    w = np.asarray(m.frequencies_rad_s)
    sums, _ = record_bands(u[None] / m.amplitude_rad, u[None], 0.01, w)
    model = config.channels[m.channel].model
    seen = np.abs(expected_estimate(sums, w, 0.1, lambda x: np.asarray(model.freqresp(x), complex).ravel())[0])
    surface = 2.0 * (opts.surface_noise_rad * air["noise"]) ** 2 + opts.surface_lsb_rad ** 2 / 12.0
    q = true_noise(w, air, m.channel) / seen ** 2 + surface
    return float(np.max(predicted_random_error(q, sums.ff * m.repeats) / m.amplitude_rad))


def run_campaign(campaign: dict, repeats: int) -> dict:
    """Fly, replay, plan, fly the plan, replay; repeat the first card for the comparison."""
    t_start = time.perf_counter()
    config = parse_config(copy.deepcopy(campaign["config"]), f"{campaign['airframe']}.yaml")
    channels = tuple(config.channels)
    seeds = np.random.SeedSequence(campaign["seed"]).generate_state(64)
    first_opts = FlightOptions(**campaign["first"], **{k: v for k, v in campaign["air"].items() if k != "noise"})
    first = simulate_flight(config, None, first_opts, seed=int(seeds[0]))
    r1 = _replay(config, [(first, channels)])
    card = plan_card(config, r1, PlanOptions())
    out = {"campaign": campaign["index"], "airframe": campaign["airframe"], "first_s": first.duration_s,
           "plan_s": card.flight_time_s, "bands": [], "unreachable": sum(len(p.unreachable)
                                                                          for p in card.channels.values()),
           "planned_points": 0, "points_closed": 0, "bands_closed": 0, "targets_before": 0}
    for name in channels:
        ch = r1["channels"][name]
        out["targets_before"] += sum(1 for flag, why in zip(ch["frequency_flags"], ch["frequency_reasons"])
                                     if flag != "model" and (flag == "data" or why is not None))
    flights, flown_s = [], 0.0
    for k, m in enumerate(card.manoeuvres):
        flight = _fly_manoeuvre(campaign, m, int(seeds[1 + k % 30]), first_opts.start_time_s + (k + 1) * FLIGHT_SPACING_S)
        flights.append((flight, (m.channel,)))
        flown_s += flight.duration_s
        alone = _replay(config, [(flight, (m.channel,))], diagnose=False)
        out["bands"].append({"channel": m.channel, "closes": m.closes_rad_s, "predicted": m.worst_predicted_error,
                             "flown_s": flight.duration_s,
                             "measured": _worst(alone, m.channel, m.frequencies_rad_s),
                             "target": min(m.target_error), "points": len(m.frequencies_rad_s),
                             "oracle": oracle_error(config, m, campaign["air"]),
                             "amplitude": m.amplitude_rad, "set_by": m.amplitude_set_by,
                             "per_point": [(p, _worst(alone, m.channel, [f])) for f, p in
                                           zip(m.frequencies_rad_s, m.predicted_error)]})
    out["flown_plan_s"] = flown_s
    if flights:
        r12 = _replay(config, [(first, channels)] + flights)
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
        for band, n in zip(out["bands"], _repeat_default(campaign, config, first, first_opts, card, out["bands"],
                                                          seeds, repeats)):
            band["repeats"] = n
    out["seconds"] = time.perf_counter() - t_start
    return out


def _repeat_default(campaign, config, first, first_opts, card, bands, seeds, repeats: int) -> list[float]:
    """Per planned band: how many more first cards (same air, new seeds), replayed with the first flight, bring its
    worst random error down to what the planned card left there. Beyond ``repeats`` flown, extrapolated from the
    error after the last one as ``1 / sqrt(n)`` (returned negative); ``inf`` when the repeated card never estimated
    the band (its input there stays below what the estimator counts)."""
    channels = tuple(config.channels)
    v = OnlineValidator(config)
    for name in channels:
        v.add_histories(name, first.histories(config.channels[name]))
    v.finish()
    needed = [math.inf] * len(bands)
    results = None
    for k in range(1, repeats + 1):
        opts = FlightOptions(**{**first_opts.__dict__, "start_time_s": first_opts.start_time_s - k * FLIGHT_SPACING_S})
        flight = simulate_flight(config, None, opts, seed=int(seeds[40 + k % 24]) + k)
        for name in channels:
            v.add_histories(name, flight.histories(config.channels[name]))
        v.finish()
        results = v.results(diagnose=False).to_json_dict()
        for j, (m, band) in enumerate(zip(card.manoeuvres, bands)):
            if math.isinf(needed[j]) and _worst(results, m.channel, m.frequencies_rad_s) <= band["pooled"]:
                needed[j] = float(k)
        if all(math.isfinite(x) for x in needed):
            break
    for j, (m, band) in enumerate(zip(card.manoeuvres, bands)):
        if math.isinf(needed[j]) and results is not None:    # beyond the repeats flown: error falls as 1 / sqrt(n)
            left = _worst(results, m.channel, m.frequencies_rad_s)
            if math.isfinite(left) and band["pooled"] > 0:
                needed[j] = -math.ceil(repeats * (left / band["pooled"]) ** 2)   # negative: extrapolated
    return needed


def _time_comparison(run: dict, extrapolated: bool) -> tuple[float, float, int]:
    """A campaign's planned flight time for the bands the repeated first card reached (within the repeats flown, or
    also by extrapolation), that repetition's time (the most repeats any of them needed, times the first card), and
    how many bands it did not reach."""
    def reached(b: dict) -> bool:
        n = b.get("repeats", math.inf)
        return math.isfinite(n) and (n > 0 or extrapolated)

    bands = [b for b in run["bands"] if reached(b)]
    plan = sum(b["flown_s"] for b in bands)
    repeat = max((abs(b["repeats"]) for b in bands), default=0.0) * run["first_s"]
    return plan, repeat, len(run["bands"]) - len(bands)


def summarise(runs: list[dict], show: bool, repeats: int) -> str:
    """The benchmark's table and sentences."""
    lines = ["| airframe | campaigns | planned bands | predicted error within x1.5 | measured / predicted (median, "
             "10-90 %) | bands closed | frequencies closed | unreachable bands | planned card | planned against repeated "
             f"first card (bands reached within the repeats) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for name in AIRFRAMES + ("all",):
        rs = [r for r in runs if name in ("all", r["airframe"])]
        if not rs:
            continue
        bs = [b for r in rs for b in r["bands"] if b["predicted"] > 0]
        rr = np.array([b["measured"] / b["predicted"] for b in bs])
        fin = rr[np.isfinite(rr)]
        ok = int(np.count_nonzero((rr <= 1.5) & (rr >= 1 / 1.5)))
        closed = sum(r["bands_closed"] for r in rs)
        pts, pts_closed = sum(r["planned_points"] for r in rs), sum(r["points_closed"] for r in rs)
        plan_all = sum(r["flown_plan_s"] for r in rs)
        measured = [_time_comparison(r, False) for r in rs]
        plan_m, rep_m = sum(c[0] for c in measured), sum(c[1] for c in measured)
        spread = f"{np.median(fin):.2f} ({np.percentile(fin, 10):.2f}-{np.percentile(fin, 90):.2f})" if fin.size else "-"
        lines.append(f"| {name} | {len(rs)} | {len(bs)} | {ok} ({100 * ok / max(len(bs), 1):.0f} %) | {spread} | "
                     f"{closed} of {len(bs)} | {pts_closed} of {pts} | {sum(r['unreachable'] for r in rs)} | "
                     f"{plan_all / 60:.1f} min | {sum(len(r['bands']) - c[2] for r, c in zip(rs, measured))} bands: "
                     f"{plan_m / 60:.1f} min against {rep_m / 60:.1f} min"
                     f"{f' ({100 * (1 - plan_m / rep_m):.0f} % less)' if rep_m > 0 else ''} |")
    lines.append("")
    for extrapolated in (False, True):
        cmp_ = [_time_comparison(r, extrapolated) for r in runs if r["bands"]]
        per = [1 - c[0] / c[1] for c in cmp_ if c[1] > 0]
        if not per:
            continue
        what = (f"with the bands beyond {repeats} repeats extrapolated as 1/sqrt(n)" if extrapolated else
                f"the bands the first card reached within {repeats} repeats")
        lines.append(f"flight time for the same random error ({what}): the planned card "
                     f"{100 * (1 - sum(c[0] for c in cmp_) / sum(c[1] for c in cmp_)):.0f} % less in all, per campaign "
                     f"median {100 * float(np.median(per)):.0f} % less, {sum(1 for x in per if x >= 0.3)} of {len(per)} "
                     f"campaigns at least 30 % less; bands left out: {sum(c[2] for c in cmp_)}")
    before = sum(r["targets_before"] for r in runs)
    data = sum(r.get("data_before", 0) for r in runs)
    lines.append(f"after the first card, {before} frequencies had no verdict ({data} of them data-limited); after the "
                 f"planned card (replayed with the first), {sum(r.get('data_closed', 0) for r in runs)} of the {data} "
                 f"data-limited ones have a verdict, {sum(r['points_closed'] for r in runs)} of the "
                 f"{sum(r['planned_points'] for r in runs)} planned ones; the rest is unreachable, with the reason")
    oracle = np.array([b["measured"] / b["oracle"] for r in runs for b in r["bands"] if b["oracle"] > 0])
    if oracle.size:
        ok = int(np.count_nonzero((oracle <= 1.5) & (oracle >= 1 / 1.5)))
        lines.append(f"the same prediction with the simulator's true noise spectrum in place of the one estimated from the "
                     f"first flight: {ok} of {oracle.size} bands within x1.5 ({100 * ok / oracle.size:.0f} %), "
                     f"measured/predicted median {np.median(oracle):.2f}, 10-90 % {np.percentile(oracle, 10):.2f}-"
                     f"{np.percentile(oracle, 90):.2f}")
    pts = np.array([m / p for r in runs for b in r["bands"] for p, m in b["per_point"] if math.isfinite(m) and p > 0])
    if pts.size:
        lines.append(f"per frequency: measured/predicted median {np.median(pts):.2f}, 10-90 % {np.percentile(pts, 10):.2f}-"
                     f"{np.percentile(pts, 90):.2f}, within x1.5: {100 * np.mean((pts <= 1.5) & (pts >= 1 / 1.5)):.0f} %")
    lines.append(f"time per campaign: {np.mean([r['seconds'] for r in runs]):.1f} s")
    if show:
        for r in runs:
            lines.append(f"campaign {r['campaign']} ({r['airframe']}): first card {r['first_s']:.0f} s, planned card "
                         f"{r['flown_plan_s']:.0f} s, {r['unreachable']} unreachable")
            for b in r["bands"]:
                lines.append(f"  {b['channel']:5s} {b['closes'][0]:6.3g}-{b['closes'][1]:<6.3g} predicted "
                             f"{b['predicted']:.3f} measured {b['measured']:.3f} with the first {b.get('pooled', math.nan):.3f} "
                             f"target {b['target']:.3f} A {b['amplitude']:.3f} ({b['set_by']}) {b['flown_s']:.0f} s "
                             f"{'closed' if b.get('closed') else 'OPEN'}; first card x{abs(b.get('repeats', math.nan)):g}"
                             f"{' (extrapolated)' if b.get('repeats', 0) < 0 else ''}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--campaigns", type=int, default=20, help="campaigns (20)")
    parser.add_argument("--seed", type=int, default=25, help="seed of the draws (25)")
    parser.add_argument("--repeats", type=int, default=12, help="most repeats of the first card (12)")
    parser.add_argument("--show", action="store_true", help="each campaign's bands")
    parser.add_argument("--amplitudes", type=float, nargs=2, default=AMPLITUDES, metavar=("LOW", "HIGH"),
                        help=f"the first card's sweep amplitudes [rad] ({AMPLITUDES[0]:g} {AMPLITUDES[1]:g})")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    campaigns = [draw(rng, i, tuple(args.amplitudes)) for i in range(args.campaigns)]
    runs = []
    for campaign in campaigns:
        runs.append(run_campaign(campaign, args.repeats))
        print(f"campaign {campaign['index']} ({campaign['airframe']}): {len(runs[-1]['bands'])} bands planned, "
              f"{runs[-1]['seconds']:.1f} s", file=sys.stderr, flush=True)
    print(summarise(runs, args.show, args.repeats))
    return 0


if __name__ == "__main__":
    sys.exit(main())
