"""``gap-validate linearize --jsbsim AIRCRAFT --speed-kt V --altitude-ft H --out CFG.yaml``

Trims a JSBSim aircraft (shipped with the jsbsim wheel) straight and level at V knots TRUE airspeed and H ft
above sea level, linearises it with JSBSim's own FGLinearization and writes a validation config: SISO channels
roll (aileron -> p), pitch (elevator -> q), yaw (rudder -> r) and the MIMO channel lateral (aileron, rudder ->
p, r); surfaces in rad (the FCS's normalised commands converted with its gains at trim), body rates in rad/s.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from gap_validation.core.errors import ConfigError


def _grid(text: str):
    """``--frequencies MIN:MAX[:COUNT]`` -> a FrequencyGrid."""
    from gap_validation.core.config import FrequencyGrid

    parts = text.split(":")
    try:
        low, high = float(parts[0]), float(parts[1])
        count = int(parts[2]) if len(parts) == 3 else 40
    except (ValueError, IndexError):
        raise argparse.ArgumentTypeError(
            f"expected MIN:MAX[:COUNT] in rad/s, e.g. 1:30:40, got {text!r}"
        ) from None
    if len(parts) > 3 or not (0 < low < high < 1e4) or not 2 <= count <= 1000:
        raise argparse.ArgumentTypeError(f"expected 0 < MIN < MAX and COUNT from 2 to 1000, got {text!r}")
    return FrequencyGrid(low, high, count)


def register(sub) -> None:
    p = sub.add_parser("linearize", help="trim and linearise a JSBSim aircraft; write a validation config",
                       description=__doc__.split("\n\n")[1].strip())
    p.add_argument("--jsbsim", metavar="AIRCRAFT",
                   help="JSBSim aircraft shipped with the jsbsim wheel, e.g. c172x, J3Cub, pa28 (required)")
    p.add_argument("--speed-kt", type=float, metavar="V", help="TRUE airspeed [kt] (required)")
    p.add_argument("--altitude-ft", type=float, metavar="H", help="altitude above sea level [ft] (required)")
    p.add_argument("--out", metavar="CFG.yaml", help="the config to write (required)")
    p.add_argument("--frequencies", type=_grid, default=None, metavar="MIN:MAX[:COUNT]",
                   help="frequency grid of every channel [rad/s] (default 1:30:40)")
    p.add_argument(
        "--airspeed-topic",
        metavar="TOPIC",
        default=None,
        help="give every channel an airspeed stream on TOPIC (std_msgs/Float64, true airspeed m/s) "
        "with the trim's: the surfaces' deviations are scaled by the dynamic pressure ratio "
        "(simulate --jsbsim then logs it)",
    )
    p.add_argument("--force", action="store_true", help="replace CFG.yaml if it exists")
    p.set_defaults(func=run)


def check_jsbsim_args(args, command: str) -> None:
    """ConfigError (one line) when ``--jsbsim``, ``--speed-kt`` or ``--altitude-ft`` is missing.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments.
    command : str
        The subcommand, for the message.
    """
    missing = [flag for flag, value in (("--jsbsim AIRCRAFT", args.jsbsim), ("--speed-kt V", args.speed_kt),
                                        ("--altitude-ft H", args.altitude_ft)) if value is None]
    if missing:
        raise ConfigError(f"{command}: missing {', '.join(missing)} (e.g. --jsbsim c172x --speed-kt 100 "
                          "--altitude-ft 3000)")


def run(args) -> int:
    check_jsbsim_args(args, "linearize")
    if not args.out:
        raise ConfigError("linearize: missing --out CFG.yaml")
    out = Path(args.out)
    if out.exists() and not args.force:
        raise ConfigError(f"--out {out}: exists already (use --force to replace it)")
    if out.exists() and not out.is_file():
        raise ConfigError(f"--out {out}: is not a file")
    if not out.parent.is_dir():
        raise ConfigError(f"--out {out}: directory {out.parent} does not exist")
    from gap_validation.jsbsim.linearize import DEFAULT_GRID, linearize, write_config

    grid = args.frequencies or DEFAULT_GRID
    lin = linearize(args.jsbsim, args.speed_kt, args.altitude_ft)
    topic = args.airspeed_topic
    if topic is not None and (not topic.strip() or " " in topic):
        raise ConfigError(f"--airspeed-topic {topic!r}: expected a ROS topic name such as /airspeed")
    write_config(lin, out, grid, None if topic is None else "/" + topic.lstrip("/"))
    poles = ", ".join(
        f"{z.real:.3g}{z.imag:+.3g}j" if abs(z.imag) > 1e-9 else f"{z.real:.3g}" for z in lin.poles()
    )
    print(f"wrote {out}: JSBSim {lin.point.version} {lin.point.describe()}")
    print(
        "  channels roll (aileron -> p), pitch (elevator -> q), yaw (rudder -> r), lateral (aileron, rudder "
        "-> "
        f"p, r); grid {grid.min_rad_s:g}-{grid.max_rad_s:g} rad/s x {grid.count}"
    )
    print(f"  {len(lin.states)} states ({', '.join(lin.states)}); poles [rad/s]: {poles}")
    for warning in lin.warnings:
        print(f"  warning: {warning}")
    return 0
