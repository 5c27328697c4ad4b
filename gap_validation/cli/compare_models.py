"""``gap-validate compare-models CFG_A CFG_B [--json OUT]``: model against model, per common channel.

Exact nu-gap (winding-number condition checked), epsilon of the overbounding disk (eq. 14) and its worst
frequency, and the margins a controller needs (eqs. 15-17).
"""
from __future__ import annotations

from gap_validation.config import load_config
from gap_validation.core import metrics
from gap_validation.core.errors import ConfigError
from gap_validation.core.margins import margins_from_epsilon, margins_note
from gap_validation.report.terminal import fmt, table, write_json


def register(sub) -> None:
    p = sub.add_parser("compare-models", help="exact nu-gap, epsilon and margins between two models",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("config_a", metavar="CFG_A", help="config with the nominal models (P1)")
    p.add_argument("config_b", metavar="CFG_B", help="config with the other models (P2)")
    p.add_argument("--json", metavar="OUT", help="write the results as JSON")
    p.set_defaults(func=run)


def compare(config_a, config_b) -> dict:
    """JSON-ready comparison of every channel present in both configs."""
    common = [name for name in config_a.channels if name in config_b.channels]
    if not common:
        raise ConfigError(f"{config_a.source} and {config_b.source} have no channel in common")
    out = {}
    for name in common:
        m1, m2 = config_a.channels[name].model, config_b.channels[name].model
        nugap, w_nugap = metrics.nugap(m1, m2)
        eps, w_eps = metrics.epsilon(m1, m2)
        margins = margins_from_epsilon(eps)
        winding = metrics.winding_condition(m1, m2)
        out[name] = {"nu_gap": nugap, "nu_gap_frequency_rad_s": _finite(w_nugap), "epsilon": _finite(eps),
                     "worst_frequency_rad_s": _finite(w_eps), **margins.to_json_dict(),
                     "disk_markers": [margins.lower_disk_marker, margins.upper_disk_marker]
                     if margins.lower_disk_marker is not None else None,
                     "margins_note": margins_note(eps),
                     "nu_gap_note": None if winding.satisfied else
                     f"winding-number condition fails ({winding.reason}): nu-gap 1"}
    return {"channels": out, "config_a": config_a.source, "config_b": config_b.source}


def _finite(value):
    return None if value is None or value != value or value in (float("inf"), float("-inf")) else float(value)


def run(args) -> int:
    result = compare(load_config(args.config_a), load_config(args.config_b))
    headers = ["channel", "nu-gap", "at rad/s", "epsilon", "worst rad/s", "GM dB", "PM deg", "disk", "markers"]
    rows = []
    for name, ch in result["channels"].items():
        markers = ch["disk_markers"]
        rows.append([name, fmt(ch["nu_gap"], ".4f"), fmt(ch["nu_gap_frequency_rad_s"], ".2f"),
                     fmt(ch["epsilon"], ".4f"), fmt(ch["worst_frequency_rad_s"], ".2f"),
                     fmt(ch["gain_margin_db"], ".2f"), fmt(ch["phase_margin_deg"], ".1f"),
                     fmt(ch["disk_margin"], ".3f"),
                     "-" if markers is None else f"{markers[0]:.2f}/{markers[1]:.2f}"])
    print(table(headers, rows))
    for name, ch in result["channels"].items():
        for note in (ch["nu_gap_note"], ch["margins_note"]):
            if note:
                print(f"  {name}: {note}")
    if args.json:
        write_json(result, args.json)
    return 0

