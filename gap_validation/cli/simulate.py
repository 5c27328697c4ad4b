"""``gap-validate simulate --config CFG --out BAG [--hidden CHANNEL:EFFECT:key=value[,key=value]]...``

Writes a synthetic sweep flight as a rosbag2: the true aircraft of each channel is the config's model with
the hidden effects in series; sweeps per axis (roll, pitch, yaw in turn), doublets, pilot trim inputs, gusts,
sensor noise, message rates with jitter and drops. The same seed gives the same bag.
``--band-noise LOW:HIGH:RMS[:CHANNEL[,CHANNEL]]`` adds a narrow-band output disturbance (band-pass filtered noise
between LOW and HIGH rad/s, RMS rad/s) to the measured rates: the coherence drops there and the diagnosis
should call that band data-limited. ``--closed-loop-gain-margin-db``, ``--turbulence``, ``--log-excitation``,
``--coupling`` and ``--cross-response`` fly closed-loop sweeps and coupled surfaces (README, "Closed loop and
coupled surfaces").
"""
from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from gap_validation.bag.reader import BAG_SUFFIXES
from gap_validation.bag.writer import STORAGES, write_flight
from gap_validation.config import load_config
from gap_validation.core.effects import describe_effect
from gap_validation.core.errors import ConfigError
from gap_validation.core.simulation import (EXCITATIONS, FlightOptions, hidden_effects, parse_band_noise,
                                            parse_coupling, parse_cross_response, simulate_flight, with_options)


def _positive(kind):
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a {'whole ' if kind is int else ''}number > 0, "
                                             f"got {text!r}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
        return value
    return parse


def _non_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}") from None
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return value


def _seed(text: str) -> int:
    """``--seed``: a non-negative integer (numpy's generators refuse others)."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return value


def register(sub) -> None:
    d = FlightOptions()
    p = sub.add_parser("simulate", help="write a synthetic sweep flight (truth = model + hidden effects)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--config", required=True, metavar="CFG", help="validation config (YAML): models and topics")
    p.add_argument("--out", required=True, metavar="BAG",
                   help="new rosbag2 directory (or a bare .mcap / .db3 file)")
    p.add_argument("--hidden", action="append", default=[], metavar="CHANNEL:EFFECT:key=value[,key=value]",
                   help="effect in series with the channel's model in the truth (repeatable), "
                        "e.g. pitch:time_delay:seconds=0.04; rate_limit:rad_s=R and backlash:width_rad=B act "
                        "on the surface command in the time domain (nonlinear)")
    p.add_argument("--seed", type=_seed, default=0, help="random seed (default 0)")
    p.add_argument("--storage", choices=STORAGES, default=None, help="storage plugin (default mcap)")
    p.add_argument("--excitation", choices=EXCITATIONS, default=d.excitation,
                   help="manoeuvre flown: log chirp then a doublet (default), multisine then a doublet, "
                        "multisine-orthogonal (every channel at once on interleaved harmonics), 3211, doublet")
    p.add_argument("--sweeps", type=_positive(int), default=d.sweeps_per_channel, metavar="N",
                   help=f"manoeuvres per channel (rounds of the test card; default {d.sweeps_per_channel})")
    p.add_argument("--sweep-gap-s", type=_non_negative, default=d.quiet_s, metavar="S",
                   help=f"trim between manoeuvres [s] (default {d.quiet_s:g})")
    p.add_argument("--trim-s", type=_non_negative, default=None, metavar="S",
                   help="trim before the first manoeuvre [s] (default: the gap)")
    p.add_argument("--duration-s", type=_positive(float), default=None, metavar="S",
                   help="length of the flight [s]: the test card is cut there (default: the whole card)")
    p.add_argument("--multisine-period-s", type=_positive(float), default=d.multisine_period_s, metavar="S",
                   help=f"period of a multisine [s] (lowest line 2 pi / period; default {d.multisine_period_s:g})")
    p.add_argument("--multisine-periods", type=_positive(int), default=d.multisine_periods, metavar="N",
                   help=f"periods flown per multisine (default {d.multisine_periods})")
    p.add_argument("--multistep-unit-s", type=_positive(float), default=d.multistep_unit_s, metavar="S",
                   help=f"unit of a 3-2-1-1 [s] (default {d.multistep_unit_s:g})")
    p.add_argument("--sweep-duration", type=_positive(float), default=d.sweep_duration_s, metavar="S",
                   help=f"length of one sweep [s] (default {d.sweep_duration_s:g})")
    p.add_argument("--imu-rate-hz", type=_positive(float), default=d.imu_rate_hz,
                   help=f"rate of the output (IMU) topics [Hz] (default {d.imu_rate_hz:g})")
    p.add_argument("--surface-rate-hz", type=_positive(float), default=d.surface_rate_hz,
                   help=f"rate of the input (surface) topics [Hz] (default {d.surface_rate_hz:g})")
    p.add_argument("--amplitude-deg", type=_positive(float), default=None,
                   help="sweep amplitude [deg] (default 3.4)")
    p.add_argument("--amplitude-scales", type=_amplitude_scales, default=None, metavar="S[,S...]",
                   help="round i of the test card flies its sweeps at S[i mod n] times the amplitude, e.g. 1,0.4 "
                        "(sweeps at different amplitudes reveal a nonlinear response; default: all the same)")
    p.add_argument("--noise", type=_non_negative, default=d.noise, metavar="SCALE",
                   help="multiplies sensor noise and gust levels (default 1; 0: noise-free)")
    p.add_argument("--drop-probability", type=_non_negative, default=d.drop_probability,
                   help=f"probability of a lost message (default {d.drop_probability:g})")
    p.add_argument("--band-noise", default=None, metavar="LOW:HIGH:RMS[:CHANNEL[,CHANNEL]]",
                   help="band-pass filtered noise between LOW and HIGH rad/s with RMS rad/s added to the measured "
                        "rate of every channel (or of the channels named), e.g. 8:14:0.05 (default: none)")
    p.add_argument("--closed-loop-gain-margin-db", type=_positive(float), default=None, metavar="DB",
                   help="fly every channel inside a rate damper u = r - K s/(s+0.3) y with this gain margin; the "
                        "manoeuvre r is injected inside the loop (default: open loop)")
    p.add_argument("--loop-delay-s", type=_positive(float), default=None, metavar="S",
                   help="delay of the flight computer and actuator in the loop [s] (default: one surface sample)")
    p.add_argument("--turbulence", type=_non_negative, default=0.0, metavar="RMS",
                   help="turbulence at the rates: first-order filtered noise at 8 rad/s, RMS rad/s (default 0)")
    p.add_argument("--log-excitation", default=None, metavar="TOPIC",
                   help="log the injected manoeuvre of every channel on TOPIC (its input's joint; a Float64 "
                        "TOPIC/<channel> for Float64 inputs): the config's excitation")
    p.add_argument("--coupling", action="append", default=[], metavar="FROM:TO:GAIN",
                   help="surface TO also moves by GAIN x surface FROM (an interconnect; surfaces by channel or "
                        "joint name), e.g. aileron:rudder:0.3 (repeatable)")
    p.add_argument("--cross-response", action="append", default=[], metavar="OUTPUT:SURFACE:GAIN[:WN[:DAMPING]]",
                   help="the rate of channel OUTPUT also responds to SURFACE through GAIN wn^2/(s^2+2 zeta wn s+wn^2) "
                        "(default wn 3 rad/s, damping 0.2), e.g. roll:rudder:-3:3:0.15 (repeatable)")
    p.add_argument("--no-compression", action="store_true", help="no zstd chunk compression (mcap)")
    p.add_argument("--force", action="store_true", help="replace BAG if it exists and is a bag")
    p.set_defaults(func=run)


def _amplitude_scales(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        values = ()
    if not values or not all(v > 0 and v < float("inf") for v in values):
        raise argparse.ArgumentTypeError(f"expected numbers > 0 separated by commas, got {text!r}")
    return values


def _remove_existing(out: Path) -> None:
    if not out.exists():
        return
    if out.is_dir() and (out / "metadata.yaml").exists() and all(
            p.suffix in (*BAG_SUFFIXES, ".yaml", ".zstd") for p in out.iterdir()):
        shutil.rmtree(out)
    elif out.is_file() and out.suffix in BAG_SUFFIXES:
        out.unlink()
    else:
        raise ConfigError(f"--out {out}: exists and is not a bag; not replacing it")


def _check_out(out: Path) -> None:
    """Refuse an ``--out`` that cannot be written before simulating (ConfigError, one line)."""
    existing = next((p for p in out.parents if p.exists()), None)
    if existing is not None and not existing.is_dir():
        raise ConfigError(f"--out {out}: {existing} is a file, not a directory")
    if out.suffix in BAG_SUFFIXES and not out.parent.is_dir():
        raise ConfigError(f"--out {out}: directory {out.parent} does not exist")


def options_from_args(args, channels: tuple[str, ...] | None = None, config=None) -> FlightOptions:
    """The :class:`FlightOptions` the command-line arguments ask for (``channels``: the config's, to check the
    ones ``--band-noise`` names; ``config``: to resolve the surfaces of ``--coupling`` and ``--cross-response``)."""
    import math

    loop = {"closed_loop_gain_margin_db": getattr(args, "closed_loop_gain_margin_db", None),
            "loop_delay_s": getattr(args, "loop_delay_s", None),
            "turbulence_rms_rad_s": getattr(args, "turbulence", None),
            "log_excitation_topic": getattr(args, "log_excitation", None)}
    if config is not None:
        loop["coupling"] = tuple(parse_coupling(t, config) for t in getattr(args, "coupling", None) or ()) or None
        loop["cross_responses"] = tuple(parse_cross_response(t, config)
                                        for t in getattr(args, "cross_response", None) or ()) or None
    band = {}
    if getattr(args, "band_noise", None) is not None:
        band_rad_s, rms, chosen = parse_band_noise(args.band_noise, channels)
        band = {"band_noise_rad_s": band_rad_s, "band_noise_rms_rad_s": rms, "band_noise_channels": chosen}
    return with_options(
        excitation=getattr(args, "excitation", None), quiet_s=getattr(args, "sweep_gap_s", None),
        trim_s=getattr(args, "trim_s", None), duration_s=getattr(args, "duration_s", None),
        multisine_period_s=getattr(args, "multisine_period_s", None),
        multisine_periods=getattr(args, "multisine_periods", None),
        multistep_unit_s=getattr(args, "multistep_unit_s", None),
        sweeps_per_channel=args.sweeps, sweep_duration_s=args.sweep_duration, imu_rate_hz=args.imu_rate_hz,
        surface_rate_hz=args.surface_rate_hz, noise=args.noise, drop_probability=args.drop_probability,
        sweep_amplitude_rad=math.radians(args.amplitude_deg) if args.amplitude_deg else None,
        sweep_amplitude_scales=getattr(args, "amplitude_scales", None), **band, **loop,
    ).check()


def run(args) -> int:
    config = load_config(args.config)
    hidden = hidden_effects(args.hidden, config)
    options = options_from_args(args, tuple(config.channels), config)
    out = Path(args.out)
    _check_out(out)
    if out.exists():
        if not args.force:
            raise ConfigError(f"--out {out}: exists already (use --force to replace a bag)")
        _remove_existing(out)
    flight = simulate_flight(config, hidden, options, seed=args.seed)
    write_flight(flight, out, args.storage, compress=not args.no_compression,
                 custom_data={"gap_validation.config": str(config.source)})
    print(f"wrote {out}: {flight.duration_s / 60:.1f} min, {flight.message_count} messages, seed {args.seed}")
    for topic, series in flight.topics.items():
        print(f"  {topic}: {series.msgtype}, {len(series)} messages")
    for name in config.channels:
        effects = hidden.get(name, [])
        truth = " + ".join(describe_effect(e) for e in effects) if effects else "nothing (model = truth)"
        n = len(flight.sweeps(name))
        turns = " (each input in turn)" if config.channels[name].is_mimo else ""
        print(f"  {name}: {n} {options.excitation} manoeuvre{'s' if n != 1 else ''}{turns}, hidden: {truth}")
    for name, gain in flight.loop_gains.items():
        print(f"  {name}: closed loop, rate damper K = {gain:.4g} (u = r - K s/(s+0.3) y, gain margin "
              f"{options.closed_loop_gain_margin_db:g} dB; controller for the config: "
              f"{{numerator: [{gain:.4g}, 0.0], denominator: [1.0, 0.3]}})")
    if options.log_excitation_topic:
        print(f"  injected manoeuvres logged on {options.log_excitation_topic}")
    for source, target, gain in options.coupling:
        print(f"  coupling: {target} surface moves with {gain:g} x the {source} surface")
    if options.band_noise_rad_s is not None:
        low, high = options.band_noise_rad_s
        chosen = options.band_noise_channels or tuple(config.channels)
        print(f"  band noise: {options.band_noise_rms_rad_s:g} rad/s rms at {low:g}-{high:g} rad/s on "
              f"{', '.join(chosen)}")
    return 0
