"""gap-validate layouts --config CFG: the Foxglove and PlotJuggler layouts that draw the node's plot topics.

Per SISO channel of the config: the Bode magnitude and phase (measured against the model), the coherence and
epsilon(w) from ``<node>/<channel>/frequency_response``, the verdict, and ``/diagnostics``
(:mod:`gap_validation.report.layouts`; the topics: docs/NODE_TOPICS.md). ``config/foxglove_layout.json`` and
``config/plotjuggler_layout.xml`` are what this writes for the bundled config.
"""
from __future__ import annotations

from pathlib import Path

from gap_validation.core.atomic import atomic_write_text
from gap_validation.core.config import load_config
from gap_validation.core.errors import ConfigError
from gap_validation.report.layouts import DEFAULT_NODE, foxglove_json, plotjuggler_layout, plotted_channels


def register(sub) -> None:
    p = sub.add_parser("layouts", help="Foxglove and PlotJuggler layouts for the node's plot topics",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--config", required=True, metavar="CFG", help="the validation config the node runs")
    p.add_argument(
        "--node",
        default=DEFAULT_NODE,
        metavar="NAME",
        help=f"the node's fully qualified name ({DEFAULT_NODE}; with a namespace /ns/gap_validator)",
    )
    p.add_argument("--foxglove", metavar="OUT.json", help="write the Foxglove layout here")
    p.add_argument("--plotjuggler", metavar="OUT.xml", help="write the PlotJuggler layout here")
    p.set_defaults(func=run)


def _write(path: str, text: str, what: str) -> None:
    out = Path(path)
    if out.is_dir():
        raise ConfigError(f"--{what} {path}: is a directory")
    if not out.parent.exists():
        raise ConfigError(f"--{what} {path}: directory {out.parent} does not exist")
    atomic_write_text(out, text)
    print(f"wrote {out}")


def run(args) -> int:
    if not args.foxglove and not args.plotjuggler:
        raise ConfigError("layouts: nothing to write (give --foxglove OUT.json and/or --plotjuggler OUT.xml)")
    config = load_config(args.config)
    channels = plotted_channels(config)
    if not channels:
        raise ConfigError(f"{args.config}: no SISO channel to draw (MIMO channels publish no table)")
    node = "/" + args.node.strip("/")
    if args.foxglove:
        _write(args.foxglove, foxglove_json(config, node), "foxglove")
    if args.plotjuggler:
        _write(args.plotjuggler, plotjuggler_layout(config, node), "plotjuggler")
    print(f"  {', '.join(f'{name} ({n} frequencies)' for name, _, n in channels)} from {node}")
    return 0
