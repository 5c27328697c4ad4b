"""gap-validate simulate --config CFG --out BAG [--hidden CHANNEL:EFFECT:key=value[,key=value]]...

Writes a synthetic sweep flight as a rosbag2: the true aircraft of each channel is the config's model with
the hidden effects in series; sweeps per axis (roll, pitch, yaw in turn), doublets, pilot trim inputs, gusts,
sensor noise, message rates with jitter and drops. The same seed gives the same bag.
``--band-noise LOW:HIGH:RMS[:CHANNEL[,CHANNEL]]`` adds a narrow-band output disturbance (band-pass filtered
noise between LOW and HIGH rad/s, RMS rad/s) to the measured rates: the coherence drops there and the
diagnosis should call that band data-limited. ``--closed-loop-gain-margin-db``, ``--turbulence``,
``--log-excitation``, ``--coupling`` and ``--cross-response`` fly closed-loop sweeps and coupled surfaces
(docs/closed_loop.md).

``--format ulog|dataflash|csv`` writes the same flight as a PX4 ULog, an ArduPilot DataFlash log or CSV files
(each autopilot's topic names, units and logging rates: PX4's servos at 10 Hz, ArduPlane's at 25 Hz unless
``--surface-rate-hz`` says otherwise) and the config that reads it beside it (``FLIGHT.ulg.yaml``;
:mod:`gap_validation.logs.flight`).

``gap-validate simulate --jsbsim AIRCRAFT --speed-kt V --altitude-ft H --out BAG [--config CFG]`` flies the
same card in JSBSim's nonlinear model trimmed at V knots true airspeed and H ft
(:mod:`gap_validation.jsbsim.flight`): the truth is JSBSim, the hidden effects act between the logged surface
and the airframe, ``--turbulence`` is JSBSim's own (light, moderate, severe or
SEVERITY[:WIND_KT][:milspec|tustin]). Without ``--config`` the channels, topics and grid are those of
``gap-validate linearize`` at the flown condition.
"""
from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

from gap_validation.bag.reader import BAG_SUFFIXES
from gap_validation.bag.writer import STORAGES, write_flight
from gap_validation.cli.arguments import (
    hidden_effects,
    parse_band_noise,
    parse_coupling,
    parse_cross_response,
)
from gap_validation.core.config import load_config
from gap_validation.core.effects import describe_effect
from gap_validation.core.errors import ConfigError
from gap_validation.core.flight_options import EXCITATIONS, FlightOptions, with_options
from gap_validation.core.simulation import simulate_flight
from gap_validation.logs.flight import (
    FORMATS,
    SURFACE_RATE_HZ,
    log_layout,
    log_path,
    with_logged_excitation,
    write_flight_log,
)


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


def _turbulence(text: str) -> str:
    """``--turbulence``: RMS [rad/s] >= 0 (synthetic flight), or a JSBSim level checked with ``--jsbsim``."""
    try:
        value = float(text)
    except ValueError:
        return text
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return text


def register(sub) -> None:
    d = FlightOptions()
    p = sub.add_parser("simulate", help="write a synthetic sweep flight (truth = model + hidden effects)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--config",
        metavar="CFG",
        help="validation config (YAML): models and topics (required, except with --jsbsim, where the "
        "default is the linearisation at the flown condition)",
    )
    p.add_argument(
        "--jsbsim",
        metavar="AIRCRAFT",
        help="fly the card in JSBSim's nonlinear model of AIRCRAFT (c172x, J3Cub, pa28 ...) instead of the "
        "config's linear models; needs --speed-kt and --altitude-ft",
    )
    p.add_argument(
        "--speed-kt", type=float, metavar="V", help="with --jsbsim: TRUE airspeed of the trim [kt]"
    )
    p.add_argument("--altitude-ft", type=float, metavar="H",
                   help="with --jsbsim: altitude of the trim above sea level [ft]")
    p.add_argument("--save-config", metavar="CFG.yaml",
                   help="with --jsbsim and no --config: also write the linearised config the flight used")
    p.add_argument(
        "--out",
        metavar="BAG",
        help="new rosbag2 directory (or a bare .mcap / .db3 file; required); with "
        "--format ulog or dataflash the .ulg or .bin file, csv a directory",
    )
    p.add_argument(
        "--format",
        choices=("bag",) + FORMATS,
        default="bag",
        help="bag (default), or a flight log: ulog (PX4: vehicle_angular_velocity, actuator_servos), "
        "dataflash (ArduPilot: IMU, RCOU; with --log-excitation the SystemID layout RATE, SIDD), csv "
        "(one file per topic); the config that reads it is written beside it (OUT.yaml)",
    )
    p.add_argument("--hidden", action="append", default=[], metavar="CHANNEL:EFFECT:key=value[,key=value]",
                   help="effect in series with the channel's model in the truth (repeatable), "
                        "e.g. pitch:time_delay:seconds=0.04; rate_limit:rad_s=R and backlash:width_rad=B act "
                        "on the surface command in the time domain (nonlinear)")
    p.add_argument("--seed", type=_seed, default=0, help="random seed (default 0)")
    p.add_argument("--storage", choices=STORAGES, default=None, help="storage plugin (default mcap)")
    p.add_argument(
        "--excitation",
        choices=EXCITATIONS,
        default=d.excitation,
        help="manoeuvre flown: log chirp then a doublet (default), multisine then a doublet, "
        "multisine-orthogonal (every channel at once on interleaved harmonics), 3211, doublet",
    )
    p.add_argument("--sweeps", type=_positive(int), default=d.sweeps_per_channel, metavar="N",
                   help=f"manoeuvres per channel (rounds of the test card; default {d.sweeps_per_channel})")
    p.add_argument("--sweep-gap-s", type=_non_negative, default=d.quiet_s, metavar="S",
                   help=f"trim between manoeuvres [s] (default {d.quiet_s:g})")
    p.add_argument("--trim-s", type=_non_negative, default=None, metavar="S",
                   help="trim before the first manoeuvre [s] (default: the gap)")
    p.add_argument("--duration-s", type=_positive(float), default=None, metavar="S",
                   help="length of the flight [s]: the test card is cut there (default: the whole card)")
    p.add_argument(
        "--multisine-period-s",
        type=_positive(float),
        default=d.multisine_period_s,
        metavar="S",
        help=f"period of a multisine [s] (lowest line 2 pi / period; default {d.multisine_period_s:g})",
    )
    p.add_argument("--multisine-periods", type=_positive(int), default=d.multisine_periods, metavar="N",
                   help=f"periods flown per multisine (default {d.multisine_periods})")
    p.add_argument("--multistep-unit-s", type=_positive(float), default=d.multistep_unit_s, metavar="S",
                   help=f"unit of a 3-2-1-1 [s] (default {d.multistep_unit_s:g})")
    p.add_argument("--sweep-duration", type=_positive(float), default=d.sweep_duration_s, metavar="S",
                   help=f"length of one sweep [s] (default {d.sweep_duration_s:g})")
    p.add_argument("--imu-rate-hz", type=_positive(float), default=d.imu_rate_hz,
                   help=f"rate of the output (IMU) topics [Hz] (default {d.imu_rate_hz:g})")
    p.add_argument(
        "--surface-rate-hz",
        type=_positive(float),
        default=None,
        help=f"rate of the input (surface) topics [Hz] (default {d.surface_rate_hz:g}; --format ulog "
        f"{SURFACE_RATE_HZ['ulog']:g}: PX4 logs actuator_servos every 100 ms; dataflash "
        f"{SURFACE_RATE_HZ['dataflash']:g}: ArduPlane writes RCOU at 25 Hz)",
    )
    p.add_argument("--amplitude-deg", type=_positive(float), default=None,
                   help="sweep amplitude [deg] (default 3.4; with --jsbsim 2, and 2 deg doublets)")
    p.add_argument(
        "--amplitude-scales",
        type=_amplitude_scales,
        default=None,
        metavar="S[,S...]",
        help="round i of the test card flies its sweeps at S[i mod n] times the amplitude, e.g. 1,0.4 "
        "(sweeps at different amplitudes reveal a nonlinear response; default: all the same)",
    )
    p.add_argument("--noise", type=_non_negative, default=d.noise, metavar="SCALE",
                   help="multiplies sensor noise and gust levels (default 1; 0: noise-free)")
    p.add_argument("--drop-probability", type=_non_negative, default=d.drop_probability,
                   help=f"probability of a lost message (default {d.drop_probability:g})")
    p.add_argument(
        "--band-noise",
        default=None,
        metavar="LOW:HIGH:RMS[:CHANNEL[,CHANNEL]]",
        help="band-pass filtered noise between LOW and HIGH rad/s with RMS rad/s added to the measured "
        "rate of every channel (or of the channels named), e.g. 8:14:0.05 (default: none)",
    )
    p.add_argument(
        "--closed-loop-gain-margin-db",
        type=_positive(float),
        default=None,
        metavar="DB",
        help="fly every channel inside a rate damper u = r - K s/(s+0.3) y with this gain margin; the "
        "manoeuvre r is injected inside the loop (default: open loop)",
    )
    p.add_argument(
        "--loop-delay-s",
        type=_positive(float),
        default=None,
        metavar="S",
        help="delay of the flight computer and actuator in the loop [s] (default: one surface sample)",
    )
    p.add_argument(
        "--turbulence",
        type=_turbulence,
        default=None,
        metavar="RMS|LEVEL",
        help="turbulence at the rates: first-order filtered noise at 8 rad/s, RMS rad/s (default 0); with "
        "--jsbsim JSBSim's Dryden turbulence: light, moderate, severe or SEVERITY[:WIND_KT] "
        "(severity 1-7, wind at 20 ft in kt), then optionally :milspec (default) or :tustin",
    )
    p.add_argument("--log-excitation", default=None, metavar="TOPIC",
                   help="log the injected manoeuvre of every channel on TOPIC (its input's joint; a Float64 "
                        "TOPIC/<channel> for Float64 inputs): the config's excitation")
    p.add_argument(
        "--coupling",
        action="append",
        default=[],
        metavar="FROM:TO:GAIN",
        help="surface TO also moves by GAIN x surface FROM (an interconnect; surfaces by channel or "
        "joint name), e.g. aileron:rudder:0.3 (repeatable)",
    )
    p.add_argument(
        "--cross-response",
        action="append",
        default=[],
        metavar="OUTPUT:SURFACE:GAIN[:WN[:DAMPING]]",
        help="the rate of channel OUTPUT also responds to SURFACE through GAIN wn^2/(s^2+2 zeta wn s+wn^2) "
        "(default wn 3 rad/s, damping 0.2), e.g. roll:rudder:-3:3:0.15 (repeatable)",
    )
    p.add_argument("--flip", action="append", default=[], metavar="CHANNEL:input|output",
                   help="log that stream with the opposite sign (a reversed surface or rate; repeatable)")
    p.add_argument("--degrees", action="store_true",
                   help="log every surface in degrees where the config says radians")
    p.add_argument("--imu-frame", choices=("frd", "flu"), default="frd",
                   help="flu: log the rates in ROS's body frame (REP 103: y left, z up; the model's is FRD)")
    p.add_argument("--stamp-offset", action="append", default=[], metavar="TOPIC:SECONDS",
                   help="stamp that topic's messages SECONDS late (another clock; repeatable)")
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
    ones ``--band-noise`` names; ``config``: to resolve the surfaces of ``--coupling`` and
    ``--cross-response``)."""
    import math

    turbulence = getattr(args, "turbulence", None)
    if turbulence is not None:
        try:
            turbulence = float(turbulence)
        except ValueError:
            raise ConfigError(
                f"--turbulence {turbulence}: a JSBSim turbulence level needs --jsbsim (without it: "
                "the RMS at the rates in rad/s)"
            ) from None
    loop = {"closed_loop_gain_margin_db": getattr(args, "closed_loop_gain_margin_db", None),
            "loop_delay_s": getattr(args, "loop_delay_s", None),
            "turbulence_rms_rad_s": turbulence,
            "log_excitation_topic": getattr(args, "log_excitation", None)}
    if config is not None:
        loop["coupling"] = (
            tuple(parse_coupling(t, config) for t in getattr(args, "coupling", None) or ()) or None
        )
        loop["cross_responses"] = tuple(parse_cross_response(t, config)
                                        for t in getattr(args, "cross_response", None) or ()) or None
    mistakes = _mistakes(args, config)
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
        sweep_amplitude_scales=getattr(args, "amplitude_scales", None), **band, **loop, **mistakes,
    ).check()


def _mistakes(args, config) -> dict:
    """The mistakes ``--flip``, ``--degrees``, ``--imu-frame`` and ``--stamp-offset`` fly (issue 23), as
    :class:`FlightOptions` fields; a bad one is a one-line ConfigError naming it."""
    flips = []
    for text in getattr(args, "flip", None) or ():
        channel, _, stream = str(text).partition(":")
        if stream not in ("input", "output") or (config is not None and channel not in config.channels):
            known = ", ".join(config.channels) if config is not None else "the config's"
            raise ConfigError(f"--flip {text}: expected CHANNEL:input or CHANNEL:output (channels: {known})")
        flips.append((channel, stream))
    offsets = []
    for text in getattr(args, "stamp_offset", None) or ():
        topic, _, seconds = str(text).rpartition(":")
        try:
            value = float(seconds)
        except ValueError:
            value = float("nan")
        if not topic or value != value or abs(value) == float("inf"):
            raise ConfigError(f"--stamp-offset {text}: expected TOPIC:SECONDS, e.g. /control_surfaces:0.04")
        topics = set(config.topics()) if config is not None else None
        topic = topic if topic.startswith("/") else "/" + topic
        if topics is not None and topic not in topics:
            raise ConfigError(f"--stamp-offset {text}: the config reads no topic {topic} "
                              f"(it reads {', '.join(sorted(topics))})")
        offsets.append((topic, value))
    out = {}
    if flips:
        out["flips"] = tuple(flips)
    if getattr(args, "degrees", False):
        out["surfaces_in_degrees"] = True
    if getattr(args, "imu_frame", "frd") != "frd":
        out["imu_frame"] = args.imu_frame
    if offsets:
        out["stamp_offsets"] = tuple(offsets)
    return out


def run(args) -> int:
    if getattr(args, "jsbsim", None) is not None:
        return run_jsbsim(args)
    extra = [
        flag
        for flag, name in (
            ("--speed-kt", "speed_kt"),
            ("--altitude-ft", "altitude_ft"),
            ("--save-config", "save_config"),
        )
        if getattr(args, name, None) is not None
    ]
    if extra:
        raise ConfigError(f"simulate: {extra[0]} needs --jsbsim AIRCRAFT")
    if not args.config:
        raise ConfigError("simulate: missing --config CFG (or fly JSBSim: --jsbsim AIRCRAFT --speed-kt V "
                          "--altitude-ft H)")
    if not args.out:
        raise ConfigError("simulate: missing --out BAG")
    config = load_config(args.config)
    hidden = hidden_effects(args.hidden, config)
    _format_defaults(args)
    options = options_from_args(args, tuple(config.channels), config)
    fmt = getattr(args, "format", "bag") or "bag"
    if fmt != "bag":                # a stream the log has no place for: said before flying, not after
        log_layout(with_logged_excitation(config, options.log_excitation_topic), fmt)
    out = _prepare_out(args)
    flight = simulate_flight(config, hidden, options, seed=args.seed)
    if not _write_log(args, flight, config, out, str(config.source)):
        write_flight(flight, out, args.storage, compress=not args.no_compression,
                     custom_data={"gap_validation.config": str(config.source)})
        print(
            f"wrote {out}: {flight.duration_s / 60:.1f} min, {flight.message_count} messages, seed "
            f"{args.seed}"
        )
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


def _prepare_out(args) -> Path:
    if not args.out:
        raise ConfigError("simulate: missing --out BAG")
    fmt = getattr(args, "format", "bag") or "bag"
    if fmt != "bag":
        return _prepare_log_out(args, fmt)
    out = Path(args.out)
    _check_out(out)
    if out.exists():
        if not args.force:
            raise ConfigError(f"--out {out}: exists already (use --force to replace a bag)")
        _remove_existing(out)
    return out


def _format_defaults(args) -> None:
    """``--format``'s defaults: the autopilot's surface logging rate unless ``--surface-rate-hz`` is given;
    bag options refused with a log format."""
    fmt = getattr(args, "format", "bag") or "bag"
    if fmt == "bag":
        return
    if args.storage is not None or args.no_compression:
        raise ConfigError(
            f"simulate --format {fmt}: {'--storage' if args.storage else '--no-compression'} applies to "
            f"bags only"
        )
    if args.surface_rate_hz is None:
        args.surface_rate_hz = SURFACE_RATE_HZ.get(fmt)


def _prepare_log_out(args, fmt: str) -> Path:
    """The log ``--out`` names (``.ulg``/``.bin`` added when missing; a CSV flight is a directory), checked;
    an existing one replaced only with ``--force`` (a CSV directory only when it holds nothing but CSV
    files)."""
    out = log_path(args.out, fmt)
    existing = next((p for p in out.parents if p.exists()), None)
    if existing is not None and not existing.is_dir():
        raise ConfigError(f"--out {out}: {existing} is a file, not a directory")
    if not out.parent.is_dir():
        raise ConfigError(f"--out {out}: directory {out.parent} does not exist")
    config_path = Path(str(out) + ".yaml")
    for path in (out, config_path):
        if not path.exists():
            continue
        if not args.force:
            raise ConfigError(f"--out {out}: {path} exists already (use --force to replace it)")
        if path.is_dir():
            if fmt != "csv" or any(p.suffix.lower() != ".csv" or p.is_dir() for p in path.iterdir()):
                raise ConfigError(
                    f"--out {out}: {path} is a directory that is not a CSV flight; not replacing it"
                )
            shutil.rmtree(path)
        elif path == out and fmt == "csv":
            raise ConfigError(f"--out {out}: is a file; a CSV flight is a directory")
        else:
            path.unlink()
    return out


def _write_log(args, flight, config, out: Path, source: str) -> bool:
    """With ``--format ulog|dataflash|csv``: write the flight as that log and its config, print what was
    written and the replay command; False for a bag."""
    fmt = getattr(args, "format", "bag") or "bag"
    if fmt == "bag":
        return False
    log, config_path, layout = write_flight_log(flight, config, out, fmt, source)
    print(
        f"wrote {log} ({layout}): {flight.duration_s / 60:.1f} min, surfaces at "
        f"{flight.options.surface_rate_hz:g} Hz, rates at {flight.options.imu_rate_hz:g} Hz, seed {args.seed}"
    )
    print(
        f"wrote {config_path} (the config that reads it: the same models, the streams under {layout}'s names)"
    )
    print(f"  next: gap-validate replay {log} --config {config_path}")
    return True


def run_jsbsim(args) -> int:
    """``simulate --jsbsim``: the card flown in JSBSim
    (:func:`gap_validation.jsbsim.flight.simulate_jsbsim_flight`)."""
    import dataclasses
    import json
    import math

    from gap_validation.cli.linearize import check_jsbsim_args

    check_jsbsim_args(args, "simulate --jsbsim")
    if not args.out:
        raise ConfigError("simulate: missing --out BAG")
    _format_defaults(args)
    for flag, name in (("--closed-loop-gain-margin-db", "closed_loop_gain_margin_db"),
                       ("--loop-delay-s", "loop_delay_s"), ("--log-excitation", "log_excitation"),
                       ("--coupling", "coupling"), ("--cross-response", "cross_response")):
        if getattr(args, name, None):
            raise ConfigError(f"simulate --jsbsim: {flag} is not available (JSBSim flies the card open loop; "
                              "cross responses and couplings are its own)")
    if args.config and args.save_config:
        raise ConfigError(
            "simulate --jsbsim: --save-config writes the linearised config, not wanted with --config"
        )
    started = time.process_time()
    from gap_validation.jsbsim.flight import SWEEP_AMPLITUDE_RAD, parse_turbulence, simulate_jsbsim_flight
    from gap_validation.jsbsim.linearize import DEFAULT_GRID, write_config

    turbulence = parse_turbulence(args.turbulence)
    config = load_config(args.config) if args.config else None
    plain = argparse.Namespace(**{**vars(args), "turbulence": None})
    options = options_from_args(plain, tuple(config.channels) if config else None, config)
    options = dataclasses.replace(options, doublet_amplitude_rad=SWEEP_AMPLITUDE_RAD,
                                  sweep_amplitude_rad=math.radians(args.amplitude_deg) if args.amplitude_deg
                                  else SWEEP_AMPLITUDE_RAD)
    out = _prepare_out(args)
    if args.save_config and Path(args.save_config).exists() and not args.force:
        raise ConfigError(f"--save-config {args.save_config}: exists already (use --force to replace it)")
    hidden = None
    if config is not None:
        hidden = hidden_effects(args.hidden, config)
    # the channels of the config to come, checked before the trim
    elif args.hidden:
        from gap_validation.cli.arguments import parse_hidden
        from gap_validation.jsbsim.linearize import CHANNELS, MIMO_CHANNEL

        hidden = {}
        for text in args.hidden:
            channel, effect = parse_hidden(text, tuple(CHANNELS) + (MIMO_CHANNEL[0],))
            hidden.setdefault(channel, []).append(effect)
    jf = simulate_jsbsim_flight(args.jsbsim, args.speed_kt, args.altitude_ft, config, hidden, options,
                                seed=args.seed, turbulence=turbulence)
    flight, config = jf.flight, jf.config
    source = str(config.source) if args.config else (args.save_config or "linearised at the flown condition")
    custom = {
        "gap_validation.config": source,
        "gap_validation.jsbsim": json.dumps(
            {
                "aircraft": jf.point.aircraft,
                "speed_kt_true": jf.point.speed_kt,
                "altitude_ft": jf.point.altitude_ft,
                "version": jf.point.version,
                "turbulence": dataclasses.asdict(jf.turbulence) if jf.turbulence else None,
                "surface_effects": jf.surface_effects,
            },
            sort_keys=True,
        ),
    }
    if not _write_log(args, flight, config, out, source):
        write_flight(flight, out, args.storage, compress=not args.no_compression, custom_data=custom)
    if args.save_config and jf.linearization is not None:
        write_config(jf.linearization, args.save_config, DEFAULT_GRID)
    cpu_s = time.process_time() - started
    p = jf.point
    if (getattr(args, "format", "bag") or "bag") == "bag":
        print(f"wrote {out}: {flight.duration_s / 60:.1f} min in JSBSim {p.version}, {flight.message_count} "
              f"messages, seed {args.seed}")
    print(f"  trim: {p.describe()}")
    print(f"  flown: {jf.steps} steps of {p.dt_s * 1e3:.3g} ms in {jf.jsbsim_cpu_s:.1f} s CPU "
          f"({jf.steps / max(jf.jsbsim_s, 1e-9):.0f} steps/s); the whole command {cpu_s:.1f} s CPU")
    print("  " + (jf.turbulence.describe() + f" (atmosphere/randomseed {jf.turbulence_seed})" if jf.turbulence
                  else "no turbulence"))
    if not args.config:
        print("  config: " + (f"{args.save_config}" if args.save_config else
                              f"the linearisation (gap-validate linearize --jsbsim {p.aircraft} --speed-kt "
                              f"{p.speed_kt:g} --altitude-ft {p.altitude_ft:g} --out CFG.yaml writes it)"))
    if (getattr(args, "format", "bag") or "bag") == "bag":
        for topic, series in flight.topics.items():
            print(f"  {topic}: {series.msgtype}, {len(series)} messages")
    for warning in jf.warnings:
        print(f"  warning: {warning}")
    for name, ch in config.channels.items():
        ins = jf.surfaces[name][0]
        effects = [e for s in ins for e in jf.surface_effects.get(s, [])]
        truth = " + ".join(describe_effect(e) for e in effects) if effects else "nothing (JSBSim = truth)"
        n = len(flight.sweeps(name))
        print(f"  {name} ({', '.join(ins)}): {n} {options.excitation} manoeuvre{'s' if n != 1 else ''}, "
              f"hidden: {truth}")
    return 0
