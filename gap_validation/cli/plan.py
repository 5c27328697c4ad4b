"""gap-validate plan [RESULTS.json] --config CFG: what to fly next, as a test card (issue 25).

From a replay's results (``replay --json``, the node's ``~/save_results``) and the config they were made with:
per channel and per run of frequencies without a verdict (data-limited, not excited, too few degrees of
freedom, low coherence), the log chirp that brings the random error there to what a verdict needs, its flight
time and the error it is expected to give; what cannot be reached, with the reason. From the config alone: a
first flight, the model's response and stated noise assumptions setting the levels. The planning is
:mod:`gap_validation.core.plan`; this module reads, checks and writes: the card (YAML, docs/PLAN.md), a table
on stdout, and in the autopilots' words (``--ardupilot`` SystemID parameters, ``--px4`` fixed-wing autotune
parameters, ``--signal`` the offsets to inject).
"""
from __future__ import annotations

import math
from pathlib import Path

from gap_validation.cards import card_yaml
from gap_validation.cli.report import load_results_json
from gap_validation.core.atomic import atomic_write_text
from gap_validation.core.config import load_config
from gap_validation.core.errors import ConfigError, DataError, GapValidationError, one_line
from gap_validation.core.plan import (
    ARDUPILOT_THROW_RAD,
    PlanOptions,
    TestCard,
    ardupilot_parameters,
    card_signal,
    plan_card,
    px4_parameters,
)
from gap_validation.report.terminal import duration_text

#: PX4's QGroundControl parameter file: MAV_PARAM_TYPE of each value (9 REAL32, 6 INT32).
_PX4_TYPES = {"FW_AT_SYSID_F0": 9, "FW_AT_SYSID_F1": 9, "FW_AT_SYSID_TIME": 9, "FW_AT_SYSID_TYPE": 6,
              "FW_AT_AXES": 6, "FW_AT_APPLY": 6}


def register(sub) -> None:
    p = sub.add_parser("plan", help="the test card that turns data-limited bands into verdicts",
                       description=__doc__.split("\n\n")[0])
    p.add_argument(
        "results",
        nargs="?",
        metavar="RESULTS.json",
        help="results of replay --json or ~/save_results (without: a first flight from the config alone)",
    )
    p.add_argument("--config", metavar="CFG", help="the config the results were made with (required)")
    p.add_argument(
        "--target-error",
        type=float,
        metavar="E",
        help="random error to reach at every planned frequency (default: what a verdict at the channel's "
        "threshold needs, about 0.067)",
    )
    p.add_argument(
        "--max-amplitude-rad",
        type=float,
        metavar="A",
        help="largest sweep amplitude [rad] (with results also capped by the largest deflection flown; "
        "from a config alone 0.06 rad by default)",
    )
    p.add_argument("--log-rate-hz", type=float, metavar="R",
                   help="rate of the slowest logged stream [Hz] (planned up to a quarter of it)")
    p.add_argument("--out", metavar="CARD.yaml", help="write the card here (YAML, docs/PLAN.md)")
    p.add_argument(
        "--ardupilot", metavar="FILE.parm", help="ArduPilot SystemID parameters, one block per manoeuvre"
    )
    p.add_argument(
        "--surface-throw-deg",
        action="append",
        default=[],
        metavar="[CHANNEL=]DEG",
        help="surface deflection at full mixer output for SID_MAGNITUDE (default 45 deg, ArduPilot's "
        "notional travel; repeatable per channel)",
    )
    p.add_argument("--px4", metavar="FILE.params", help="PX4 fixed-wing autotune parameters, where they fit")
    p.add_argument(
        "--signal", metavar="FILE.csv", help="the surface offsets to inject, every manoeuvre in turn"
    )
    p.add_argument("--signal-rate-hz", type=float, metavar="R", help="sample rate of --signal [Hz]")
    p.set_defaults(func=run)


def _throws(texts: list[str], channels) -> dict[str, float]:
    """``--surface-throw-deg`` values: channel -> rad (``DEG`` alone: every channel)."""
    out: dict[str, float] = {}
    for text in texts:
        name, sep, value = text.rpartition("=")
        try:
            deg = float(value)
        except ValueError:
            deg = math.nan
        if not (math.isfinite(deg) and 0 < deg <= 90):
            raise ConfigError(f"--surface-throw-deg {text!r}: expected [CHANNEL=]DEG with 0 < DEG <= 90")
        if sep and name not in channels:
            raise ConfigError(f"--surface-throw-deg {text!r}: no channel {name!r} in the config "
                              f"(channels: {', '.join(channels)})")
        for ch in ([name] if sep else channels):
            out[ch] = math.radians(deg)
    return out


def _writable(path: str | None, option: str) -> None:
    if path is None:
        return
    out = Path(path)
    if out.is_dir():
        raise ConfigError(f"{option} {path}: is a directory")
    if not out.parent.exists():
        raise ConfigError(f"{option} {path}: directory {out.parent} does not exist")


def run(args) -> int:
    results_path, config_path = args.results, args.config
    if config_path is None and results_path and Path(results_path).suffix.lower() in (".yaml", ".yml"):
        # ``plan CFG.yaml``: a first flight (DESIGN.md)
        results_path, config_path = None, results_path
    if config_path is None:
        raise ConfigError(
            "plan: give --config CFG (with RESULTS.json: the config the results were made with)"
        )
    for option, value in (("--out", args.out), ("--ardupilot", args.ardupilot), ("--px4", args.px4),
                          ("--signal", args.signal)):
        _writable(value, option)
    if args.signal and args.signal_rate_hz is None:
        raise ConfigError("--signal needs --signal-rate-hz R (the rate the offsets are sampled at)")
    if args.signal_rate_hz is not None and not (
        math.isfinite(args.signal_rate_hz) and args.signal_rate_hz > 0
    ):
        raise ConfigError(f"--signal-rate-hz {args.signal_rate_hz:g}: expected a rate > 0 Hz")
    options = PlanOptions(target_error=args.target_error, max_amplitude_rad=args.max_amplitude_rad,
                          log_rate_hz=args.log_rate_hz).check()
    config = load_config(config_path)
    throws = _throws(args.surface_throw_deg, tuple(config.channels))
    results = load_results_json(results_path) if results_path else None
    try:
        card = plan_card(config, results, options, source=results_path or config_path)
    except GapValidationError:
        raise
    except (TypeError, ValueError, KeyError, IndexError, AttributeError) as err:
        if results_path is None:
            raise
        raise DataError(f"{results_path}: not readable results ({one_line(err)})") from None
    print(render_table(card))
    if args.out:
        atomic_write_text(args.out, card_yaml(card, results_path, config_path))
        print(f"wrote {args.out}")
    if args.ardupilot:
        atomic_write_text(args.ardupilot, parm_text(card, config, throws))
        print(f"wrote {args.ardupilot}")
    if args.px4:
        atomic_write_text(args.px4, px4_text(card, config))
        print(f"wrote {args.px4}")
    if args.signal:
        atomic_write_text(args.signal, signal_csv(card, args.signal_rate_hz))
        print(f"wrote {args.signal}")
    return 0


# ------------------------------------------------------------------------------------------------ rendering
def render_table(card: TestCard) -> str:
    """The card as a table for the terminal, with the unreachable bands and the notes under it.

    Parameters
    ----------
    card : TestCard
        The card.
    """
    head = (
        "#",
        "channel",
        "closes rad/s",
        "sweep Hz",
        "amp deg",
        "sweep s",
        "x",
        "time",
        "error now",
        "predicted",
        "target",
        "why",
    )
    rows = []
    for m in card.manoeuvres:
        now = [e for e in m.error_now if e is not None]
        rows.append(
            (
                str(m.index),
                m.channel,
                f"{m.closes_rad_s[0]:.3g}-{m.closes_rad_s[1]:.3g}",
                f"{m.f_start_hz:.3g}-{m.f_stop_hz:.3g}",
                f"{math.degrees(m.amplitude_rad):.2f}",
                f"{m.duration_s:.0f}",
                str(m.repeats),
                duration_text(m.flight_time_s),
                f"{max(now):.3f}" if now else "-",
                f"{m.expected_worst_error:.3f}",
                f"{min(m.target_error):.3f}",
                ", ".join(m.reasons),
            )
        )
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(head)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths)).rstrip(), "  ".join("-" * w for w in widths)]
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
    if not rows:
        lines.append("(nothing to fly)")
    lines.append(
        f"  flight time {duration_text(card.flight_time_s)} for {len(rows)} manoeuvre(s); error: the worst "
        f"random error over the frequencies closed, now and predicted for the card replayed on its own"
    )
    for name, plan in card.channels.items():
        for u in plan.unreachable:
            lines.append(
                f"  {name}: unreachable at {u.band_rad_s[0]:.3g}-{u.band_rad_s[1]:.3g} rad/s: {u.reason}"
            )
        for note in plan.notes:
            if note.startswith(f"{name}: nothing") or "MIMO" in note or "not in the results" in note:
                lines.append(f"  {note}")
    lines.append(f"  target: {card.target_rule}")
    return "\n".join(lines)


def parm_text(card: TestCard, config, throws: dict[str, float]) -> str:
    """ArduPilot ``.parm`` text: one block per manoeuvre; the first active, the others commented out.

    Parameters
    ----------
    card : TestCard
        The card.
    config : ValidationConfig
        The config (each channel's axis).
    throws : dict
        Channel -> surface deflection at full mixer output [rad].
    """
    blocks = ardupilot_parameters(card, config, throws)
    lines = [
        "# gap-validate plan: ArduPilot SystemID parameters (SID_*), one block per manoeuvre of the card.",
        "# A .parm holds one value per name: the first block is active, the others are commented out. Load "
        "the",
        "# block of the manoeuvre you fly next (uncomment it, comment the active one), fly it SID_* repeats "
        "with",
        "# trim between, then the next. SID_AXIS 10/11/12 injects at the mixer (the surface, the model's "
        "input).",
        f"# SID_MAGNITUDE is 0-1 of full mixer output ({math.degrees(ARDUPILOT_THROW_RAD):g} deg of notional "
        "travel unless --surface-throw-deg); ranges from ArduPilot's",
        "# parameter docs (AP_SystemID / ModeSystemId var_info: F_START/F_STOP 0.01-100 Hz, T_FADE_IN "
        "0-20 s,",
        "# T_REC 0-255 s, T_FADE_OUT 0-5 s); every value below is inside them.",
    ]
    return _blocks_text(lines, blocks, "", lambda name, value: f"{name} {_number(value)}")


def px4_text(card: TestCard, config) -> str:
    """PX4 parameter file (QGroundControl's tab-separated format), one block per manoeuvre; the first active.

    Parameters
    ----------
    card : TestCard
        The card.
    config : ValidationConfig
        The config (each channel's axis).
    """
    blocks = px4_parameters(card, config)
    lines = [
        "# gap-validate plan: PX4 fixed-wing autotune system-identification parameters, one block per "
        "manoeuvre.",
        "# Onboard parameters format: Vehicle-Id Component-Id Name Value Type. One value per name: the first",
        "# block is active, the others commented out. Ranges from fw_autotune_attitude_control_params.c",
        "# (F0/F1 0.1-30 Hz, TIME 5-120 s); FW_AT_APPLY 0 logs only (the gains are not changed).",
        "#",
        "# Vehicle-Id\tComponent-Id\tName\tValue\tType",
    ]
    return _blocks_text(
        lines, blocks, "#", lambda name, value: f"1\t1\t{name}\t{_number(value)}\t{_PX4_TYPES[name]}"
    )


def _blocks_text(head: list[str], blocks, separator: str, line) -> str:
    """``head``, then per block ``separator``, its comment and notes as comments and its values (``line(name,
    value)``): the first block with values active, the others commented out (one value per name in the
    file)."""
    lines, active = list(head), False
    for block in blocks:
        lines += [separator, f"# {block.comment}"] + [f"# {note}" for note in block.notes]
        if block.values:
            lines += [("# " if active else "") + line(name, value) for name, value in block.values.items()]
            active = True
    return "\n".join(lines) + "\n"


def signal_csv(card: TestCard, rate_hz: float) -> str:
    """The ``--signal`` CSV: ``time_s``, ``manoeuvre`` and one ``<channel>_rad`` column of surface offsets
    each.

    Parameters
    ----------
    card : TestCard
        The card.
    rate_hz : float
        Sample rate [Hz].
    """
    t, index, offsets = card_signal(card, rate_hz)
    names = list(offsets)
    lines = [",".join(["time_s", "manoeuvre"] + [f"{n}_rad" for n in names])]
    columns = [offsets[n] for n in names]
    for k in range(t.size):
        lines.append(",".join([f"{t[k]:.6f}", str(int(index[k]))] + [f"{col[k]:.8g}" for col in columns]))
    return "\n".join(lines) + "\n"


def _number(value) -> str:
    return str(int(value)) if isinstance(value, int) else f"{float(value):.6g}"
