"""gap-validate compare-models CFG_A CFG_B [--json OUT]: model against model, per common channel.

Exact nu-gap (winding-number condition checked), epsilon of the overbounding disk (eq. 14) and its worst
frequency, and the margins a controller needs (eqs. 15-17). MIMO channels (``inputs``/``outputs`` lists) get
the exact MIMO nu-gap and its frequency (epsilon and its margins are SISO notions: null, with a note). With a
``controller`` (u = -C y) on the channel, b(P1, C) and whether it guarantees stability: b(P1, C) > nu-gap.
"""
from __future__ import annotations

import math

import numpy as np

from gap_validation.core import metrics, robust
from gap_validation.core.config import ChannelConfig, ValidationConfig, load_config
from gap_validation.core.errors import ConfigError
from gap_validation.core.margins import margins_from_epsilon, margins_note
from gap_validation.core.models import MimoModel
from gap_validation.report.terminal import fmt, table, write_json

#: Why a MIMO channel has no epsilon and no margins.
MIMO_MARGINS_NOTE = (
    "epsilon (eq. 14) and its margins are defined for SISO channels; a MIMO channel is compared by the nu-gap"
)


def register(sub) -> None:
    p = sub.add_parser("compare-models", help="exact nu-gap, epsilon and margins between two models",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("config_a", metavar="CFG_A", help="config with the nominal models (P1) and controllers")
    p.add_argument("config_b", metavar="CFG_B", help="config with the other models (P2)")
    p.add_argument("--json", metavar="OUT", help="write the results as JSON")
    p.set_defaults(func=run)


def compare(config_a: ValidationConfig, config_b: ValidationConfig) -> dict:
    """JSON-ready comparison of every channel present in both configs.

    P1 is config A's model, P2 config B's; a MIMO channel's signals are matched by topic and field (B's model
    is reordered to A's inputs and outputs). The controller is A's (else B's).
    """
    common = [name for name in config_a.channels if name in config_b.channels]
    if not common:
        raise ConfigError(f"{config_a.source} and {config_b.source} have no channel in common")
    out = {}
    for name in common:
        try:
            out[name] = _compare_channel(name, config_a, config_b)
        except np.linalg.LinAlgError as err:  # e.g. a nearly hidden mode on the imaginary axis
            raise ConfigError(
                f"channels.{name}: the models of {config_a.source} and {config_b.source} cannot be "
                f"compared ({err})"
            ) from None
    return {"channels": out, "config_a": config_a.source, "config_b": config_b.source}


def _compare_channel(name: str, config_a: ValidationConfig, config_b: ValidationConfig) -> dict:
    """The JSON object of one channel present in both configs."""
    ch_a, ch_b = config_a.channels[name], config_b.channels[name]
    _refuse_nonlinear(name, ((config_a.source, ch_a), (config_b.source, ch_b)))
    m1, m2 = ch_a.model, _aligned(name, ch_a, ch_b, config_a.source, config_b.source)
    nugap, w_nugap = metrics.nugap(m1, m2)
    winding = metrics.winding_condition(m1, m2)
    shape = list(getattr(m1, "shape", (1, 1)))
    entry = {"nu_gap": nugap, "nu_gap_frequency_rad_s": _finite(w_nugap)}
    if shape == [1, 1]:
        eps, w_eps = metrics.epsilon(m1, m2)
        margins = margins_from_epsilon(eps)
        entry.update(
            {
                "epsilon": _finite(eps),
                "worst_frequency_rad_s": _finite(w_eps),
                **margins.to_json_dict(),
                "disk_markers": [margins.lower_disk_marker, margins.upper_disk_marker]
                if margins.lower_disk_marker is not None
                else None,
                "margins_note": margins_note(eps),
            }
        )
    else:
        entry.update({"epsilon": None, "worst_frequency_rad_s": _finite(w_nugap),
                      **margins_from_epsilon(math.nan).to_json_dict(), "disk_markers": None,
                      "margins_note": MIMO_MARGINS_NOTE})
    entry["nu_gap_note"] = None if winding.satisfied else \
        f"winding-number condition fails ({winding.reason}): nu-gap 1"
    entry["shape"] = shape
    controller = ch_a.controller if ch_a.controller is not None else ch_b.controller
    if controller is not None:
        check = robust.controller_check(m1, controller, nugap)
        entry.update({"stability_margin_b": check.stability_margin_b,
                      "stability_margin_frequency_rad_s": check.frequency_rad_s,
                      "guaranteed_stable": check.guaranteed_stable, "stability_note": check.sentence})
    return entry


def _refuse_nonlinear(name: str, channels) -> None:
    """ConfigError when a model holds an amplitude-dependent effect (``rate_limit``, ``backlash``): its
    response needs the amplitude of a flight, which two configs do not have; or a ``zero_order_hold``, which
    is not rational (the exact nu-gap's winding number needs polynomials)."""
    for source, ch in channels:
        from gap_validation.core.effects import EFFECTS, is_nonlinear

        kinds = [e["type"] for e in getattr(ch.model, "effects", ()) if is_nonlinear(e)]
        if kinds:
            raise ConfigError(
                f"{source}: channels.{name}.model.effects: {kinds[0]} depends on the input amplitude "
                f"of a flight; compare-models compares linear models only (remove it to compare "
                f"the linear parts)"
            )
        holds = [e["type"] for e in getattr(ch.model, "effects", ()) if EFFECTS[e["type"]].shape is not None]
        if holds:
            raise ConfigError(
                f"{source}: channels.{name}.model.effects: {holds[0]} is not a rational factor and the "
                f"exact nu-gap needs one; compare-models compares rational models (replace it by a "
                f"time_delay of half its period to compare the rest)"
            )


def _aligned(name: str, ch_a: ChannelConfig, ch_b: ChannelConfig, source_a: str, source_b: str):
    """B's model with its inputs and outputs in A's order (MIMO); ConfigError when they cannot be matched."""
    shape_a, shape_b = getattr(ch_a.model, "shape", (1, 1)), getattr(ch_b.model, "shape", (1, 1))
    if tuple(shape_a) != tuple(shape_b):
        raise ConfigError(f"channels.{name}: {source_a} has a {shape_a[0]}x{shape_a[1]} model, {source_b} a "
                          f"{shape_b[0]}x{shape_b[1]} one (outputs x inputs): not compared")
    if not (ch_a.is_mimo and ch_b.is_mimo):
        return ch_b.model
    order = []
    for key in ("inputs", "outputs"):
        signals_a = [(s.topic, s.field) for s in getattr(ch_a, key)]
        signals_b = [(s.topic, s.field) for s in getattr(ch_b, key)]
        if sorted(signals_a) != sorted(signals_b):
            raise ConfigError(f"channels.{name}.{key}: {source_a} has {_names(signals_a)}, {source_b} "
                              f"{_names(signals_b)}: not compared")
        order.append([signals_b.index(signal) for signal in signals_a])
    if order == [list(range(shape_a[1])), list(range(shape_a[0]))]:
        return ch_b.model
    a, b, c, d = ch_b.model.state_space()
    return MimoModel(a, b[:, order[0]], c[order[1]], d[order[1]][:, order[0]])


def _names(signals: list[tuple[str, str]]) -> str:
    return "[" + ", ".join(f"{topic} {field}" for topic, field in signals) + "]"


def _finite(value):
    return None if value is None or value != value or value in (float("inf"), float("-inf")) else float(value)


def run(args) -> int:
    result = compare(load_config(args.config_a), load_config(args.config_b))
    channels = result["channels"]
    with_controller = any("stability_margin_b" in ch for ch in channels.values())
    headers = [
        "channel",
        "nu-gap",
        "at rad/s",
        "epsilon",
        "worst rad/s",
        "GM dB",
        "PM deg",
        "disk",
        "markers",
    ]
    if with_controller:
        headers += ["b(P1,C)", "stable"]
    rows = []
    for name, ch in channels.items():
        markers = ch["disk_markers"]
        shape = ch["shape"]
        label = name if shape == [1, 1] else f"{name} ({shape[0]}x{shape[1]})"
        row = [label, fmt(ch["nu_gap"], ".4f"), fmt(ch["nu_gap_frequency_rad_s"], ".2f"),
               fmt(ch["epsilon"], ".4f"), fmt(ch["worst_frequency_rad_s"], ".2f"),
               fmt(ch["gain_margin_db"], ".2f"), fmt(ch["phase_margin_deg"], ".1f"),
               fmt(ch["disk_margin"], ".3f"),
               "-" if markers is None else f"{markers[0]:.2f}/{markers[1]:.2f}"]
        if with_controller:
            guaranteed = ch.get("guaranteed_stable")
            row += [fmt(ch.get("stability_margin_b"), ".4f"),
                    "-" if guaranteed is None else ("guaranteed" if guaranteed else "no guarantee")]
        rows.append(row)
    print(table(headers, rows))
    for name, ch in channels.items():
        for note in (ch["nu_gap_note"], ch["margins_note"], ch.get("stability_note")):
            if note:
                print(f"  {name}: {note}")
    if args.json:
        write_json(result, args.json)
    return 0
