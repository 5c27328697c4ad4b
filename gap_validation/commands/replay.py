"""``gap-validate replay BAG [BAG...] --config CFG [--json OUT] [--report DIR]``: validate recorded flights.

Streams rosbag2 directories, ``.mcap`` and ``.db3`` files (only the config's topics) through the online
validator, prints the per-channel table and writes the JSON results. Several bags add up (sweeps from all
count); an unreadable bag is reported and the others are still validated (exit status 1, results kept).
"""
from __future__ import annotations

import importlib
import importlib.util
import sys
import time

from gap_validation.config import load_config
from gap_validation.core.errors import ConfigError
from gap_validation.render import format_table, write_json
from gap_validation.replay import replay


def register(sub) -> None:
    p = sub.add_parser("replay", help="validate recorded flights (rosbag2 directories, .mcap, .db3)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("bags", nargs="+", metavar="BAG", help="rosbag2 directory, .mcap or .db3 file")
    p.add_argument("--config", required=True, metavar="CFG", help="validation config (YAML)")
    p.add_argument("--json", metavar="OUT", help="write the results as JSON")
    p.add_argument("--report", metavar="DIR", help="write the HTML report with figures into DIR")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (default: on a terminal)")
    p.add_argument("--full-decode", action="store_true",
                   help="deserialise every message fully (default: read only the needed fields where possible)")
    p.set_defaults(func=run)


class ProgressBar:
    """A one-line progress bar on a stream (messages done / total), redrawn at most ten times a second."""

    def __init__(self, stream=None, width: int = 30, label: str = "replay"):
        self.stream = stream or sys.stderr
        self.width = width
        self.label = label
        self.start = time.monotonic()
        self.last = 0.0
        self.drawn = False

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        if now - self.last < 0.1 and done < total:
            return
        self.last = now
        frac = done / total if total else 1.0
        filled = int(round(frac * self.width))
        rate = done / max(now - self.start, 1e-9)
        self.stream.write(f"\r{self.label} [{'#' * filled}{'.' * (self.width - filled)}] {frac:4.0%} "
                          f"{done}/{total} msgs {rate:,.0f} msg/s")
        self.stream.flush()
        self.drawn = True

    def close(self) -> None:
        if self.drawn:
            self.stream.write("\n")
            self.stream.flush()


def _report_writer():
    """``gap_validation.report.write_report`` or a one-line error when the report module is not installed."""
    if importlib.util.find_spec("gap_validation.report") is None:
        raise ConfigError("--report: report not available (gap_validation.report is not installed)")
    module = importlib.import_module("gap_validation.report")
    writer = getattr(module, "write_report", None)
    if writer is None:
        raise ConfigError("--report: report not available (gap_validation.report has no write_report)")
    return writer


def run(args) -> int:
    config = load_config(args.config)
    write_report = _report_writer() if args.report else None
    bar = ProgressBar() if not args.no_progress and sys.stderr.isatty() else None
    try:
        outcome = replay(args.bags, config, progress=bar, fast=not args.full_decode)
    finally:
        if bar is not None:
            bar.close()
    for warning in outcome.warnings:
        print(f"gap-validate: warning: {warning}", file=sys.stderr)
    print(format_table(outcome.result))
    if args.json:
        write_json(outcome.result.to_json_dict(), args.json)
    if write_report is not None:
        write_report(outcome.result, args.report)
    for error in outcome.errors:
        print(f"gap-validate: error: {error}", file=sys.stderr)
    return 1 if outcome.errors else 0
