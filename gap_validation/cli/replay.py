"""gap-validate replay FLIGHT [FLIGHT...] --config CFG [--json OUT] [--report DIR]: validate recorded flights.

Streams rosbag2 directories, ``.mcap`` and ``.db3`` files, and flight logs -- PX4 ULog (``.ulg``), ArduPilot
DataFlash (``.bin``), CSV (``.csv``, or a directory of them) -- (only the config's topics) through the online
validator, prints the per-channel table and writes the JSON results. Several flights add up (sweeps from all
count); an unreadable or damaged one is reported and the rest is still validated (exit status 1, results
kept).
"""
from __future__ import annotations

import importlib
import importlib.util
import shlex
import sys
import time
from pathlib import Path

from gap_validation.bag.replay import is_log_source, replay
from gap_validation.core.config import dump_config, load_config
from gap_validation.core.errors import ConfigError, DataError
from gap_validation.core.wording import no_fix_reason
from gap_validation.history import (
    append_history,
    default_history_path,
    epsilon_versions,
    format_trend,
    load_history,
    model_hash,
    previous_epsilon,
)
from gap_validation.report.card import plan_for, plan_lines
from gap_validation.report.terminal import format_table, write_json


def register(sub) -> None:
    p = sub.add_parser(
        "replay",
        help="validate recorded flights (rosbag2 directories, .mcap, .db3; flight logs .ulg, .bin, .csv)",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument(
        "bags",
        nargs="+",
        metavar="FLIGHT",
        help="rosbag2 directory, .mcap or .db3 file, or a flight log: .ulg (PX4), .bin (ArduPilot), .csv "
        "(one file per topic; the CSV files of one directory are one flight)",
    )
    p.add_argument("--config", required=True, metavar="CFG", help="validation config (YAML)")
    p.add_argument("--json", metavar="OUT", help="write the results as JSON")
    p.add_argument("--report", metavar="DIR", help="write the HTML report with figures into DIR")
    p.add_argument(
        "--apply-diagnosis",
        metavar="OUT_YAML",
        help="write the config with the fix of each model-limited channel whose diagnosis has a candidate "
        "that explains the mismatch (review it, keep it); the others are left as they are",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="with --apply-diagnosis: write each channel's top candidate even when it does not explain "
        "the mismatch or the channel is not model-limited",
    )
    p.add_argument("--history", metavar="FILE",
                   help="validation history to append to (default: the config's 'history' key, else "
                        "<config stem>.history.jsonl beside the config)")
    p.add_argument("--no-history", action="store_true", help="do not read or append the validation history")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (default: on a terminal)")
    p.add_argument(
        "--annotate",
        metavar="OUT_MCAP",
        help="write one MCAP file with the flight's messages and, on the same timeline, what the node "
        "would have published: /diagnostics every second and the plottable topics "
        "(docs/NODE_TOPICS.md); one bag",
    )
    p.add_argument(
        "--full-decode",
        action="store_true",
        help="deserialise every message fully (default: read only the needed fields where possible)",
    )
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
        self.draw(done, total, lambda rate: f"msgs {rate:,.0f} msg/s")

    def draw(self, done: int, total: int, counts, ran: int | None = None) -> None:
        """Redraw (unless drawn less than 0.1 s ago): ``done/total`` then ``counts(rate)``, the rate being
        ``ran`` (default ``done``) per second since the start."""
        now = time.monotonic()
        if now - self.last < 0.1 and done < total:
            return
        self.last = now
        frac = done / total if total else 1.0
        filled = int(round(frac * self.width))
        rate = (done if ran is None else ran) / max(now - self.start, 1e-9)
        self.stream.write(f"\r{self.label} [{'#' * filled}{'.' * (self.width - filled)}] {frac:4.0%} "
                          f"{done}/{total} {counts(rate)}")
        self.stream.flush()
        self.drawn = True

    def close(self) -> None:
        if self.drawn:
            self.stream.write("\n")
            self.stream.flush()


def _report_writer():
    """``gap_validation.report.html.write_report`` or a one-line error when the report module is not
    installed."""
    if importlib.util.find_spec("gap_validation.report.html") is None:
        raise ConfigError("--report: report not available (gap_validation.report.html is not installed)")
    module = importlib.import_module("gap_validation.report.html")
    writer = getattr(module, "write_report", None)
    if writer is None:
        raise ConfigError("--report: report not available (gap_validation.report.html has no write_report)")
    return writer


def _check_outputs(args) -> None:
    """Refuse output paths that cannot be written before the replay, not after it (ConfigError, one line)."""
    if getattr(args, "annotate", None) and len(args.bags) != 1:
        raise ConfigError(
            f"--annotate {args.annotate}: takes one bag (got {len(args.bags)}): the annotation is on "
            "that bag's timeline"
        )
    if getattr(args, "annotate", None) and is_log_source(args.bags[0]):
        raise ConfigError(
            f"--annotate {args.annotate}: takes a bag, not the flight log {args.bags[0]} (the annotation "
            "copies the bag's messages); replay the log without --annotate"
        )
    for option, value in (("--json", args.json), ("--apply-diagnosis", args.apply_diagnosis),
                          ("--annotate", getattr(args, "annotate", None))):
        if not value:
            continue
        path = Path(value)
        if path.is_dir():
            raise ConfigError(f"{option} {value}: is a directory (expected a file path)")
        if not path.resolve().parent.is_dir():
            raise ConfigError(f"{option} {value}: directory {path.resolve().parent} does not exist")
    if args.report:
        existing = next((p for p in (Path(args.report), *Path(args.report).parents) if p.exists()), None)
        if existing is not None and not existing.is_dir():
            raise ConfigError(f"--report {args.report}: {existing} is a file, not a directory")


def run(args) -> int:
    config = load_config(args.config)
    write_report = _report_writer() if args.report else None
    _check_outputs(args)
    bar = ProgressBar() if not args.no_progress and sys.stderr.isatty() else None
    annotator = None
    if getattr(args, "annotate", None):
        from gap_validation.cli.annotate import Annotator

        annotator = Annotator(config)
    try:
        outcome = replay(args.bags, config, progress=bar, fast=not args.full_decode,
                         on_tick=annotator.tick if annotator is not None else None)
    finally:
        if bar is not None:
            bar.close()
    if annotator is not None:       # the flight and its verdict on one timeline; the results follow anyway
        from gap_validation.cli.annotate import write_annotated

        try:
            n = write_annotated(args.bags[0], args.annotate, annotator)
            print(
                f"annotated: {args.annotate} ({n} messages: the flight and {len(annotator.messages)} of the "
                "node's)",
                file=sys.stderr,
            )
        except DataError as err:
            outcome.errors.append(str(err))
    for warning in outcome.warnings:
        print(f"gap-validate: warning: {warning}", file=sys.stderr)
    try:
        _write_outputs(args, config, outcome.result, write_report)
    finally:  # the bags' problems are reported even when an output fails
        for error in outcome.errors:
            print(f"gap-validate: error: {error}", file=sys.stderr)
    return 1 if outcome.errors else 0


def _write_outputs(args, config, result, write_report) -> None:
    """Table, JSON, report, history and --apply-diagnosis of a replay's result.

    The test card (``gap-validate plan``, :func:`~gap_validation.report.card.plan_for`) is planned for the
    report only: it costs 0.3 s on the bundled flight (replay 6 s, report 7 s more) but 3 s on a short flight
    with three data-limited channels whose replay takes 1.4 s; without ``--report`` a line per channel with
    bands without a verdict says how to plan it. A plan that fails is a warning and a line in the report,
    never an error."""
    history = None if args.no_history else _history_path(args, config)
    records = _load_history(history) if history is not None else None
    if records is not None:
        _set_previous(result, config, records)
    plan = plan_for(config, result, source=args.json or "the replay's results") if write_report else None
    if isinstance(plan, str):
        _warn(f"plan unavailable: {plan}")
    print(format_table(result))
    command = (
        f"gap-validate plan {shlex.quote(args.json or 'RESULTS.json')} --config {shlex.quote(args.config)}"
    )
    for line in plan_lines(result, plan, command):
        print(line)
    if records is not None and any(ch.sweeps for ch in result.channels.values()):
        try:
            record = append_history(history, result, config, args.bags)
        except DataError as err:  # results come first: the other outputs are still written
            print(f"gap-validate: warning: {err}; the history is not appended", file=sys.stderr)
            history = None  # and --apply-diagnosis does not point the new config at it
        else:
            records = records + [record]
            for line in _trends(records, result):
                print(line)
    if records:
        result.history = {name: epsilon_versions(records, name) for name in result.channels}
    if args.json:
        write_json(result.to_json_dict(), args.json)
    if write_report is not None:
        write_report(result, args.report, warn=_warn, plan=plan)
    if args.apply_diagnosis:
        _apply_diagnosis(config, result, args.apply_diagnosis, history, force=getattr(args, "force", False))


def _warn(message: str) -> None:
    print(f"gap-validate: warning: {message}", file=sys.stderr)


def _history_path(args, config) -> Path:
    """--history, else the config's ``history`` key (relative to the config file), else beside the config."""
    if args.history:
        return Path(args.history)
    configured = config.raw.get("history")
    if configured:
        path = Path(configured)
        return path if path.is_absolute() else Path(args.config).resolve().parent / path
    return default_history_path(args.config)


def _load_history(path: Path) -> list[dict] | None:
    """The history records, or None (with a one-line warning) when the file is unreadable: results come
    first."""
    try:
        return load_history(path)
    except DataError as err:
        print(f"gap-validate: warning: {err}; the history is neither shown nor appended", file=sys.stderr)
        return None


def _set_previous(result, config, records: list[dict]) -> None:
    """Show the epsilon of the previous model version next to the new one."""
    for name, ch in result.channels.items():
        if ch.epsilon_previous is None and name in config.channels:
            current = model_hash(config.channels[name].model.to_spec())
            ch.epsilon_previous = previous_epsilon(records, name, exclude_model_hash=current)


def _trends(records: list[dict], result) -> list[str]:
    """Trend lines for channels validated with more than one model version."""
    lines = []
    for name in result.channels:
        hashes = {
            r["channels"].get(name, {}).get("model_hash") for r in records if name in r.get("channels", {})
        }
        if len(hashes) > 1:
            lines.append("  " + format_trend(records, name))
    return lines


def _apply_diagnosis(config, result, out_path: str, history: Path | None, force: bool = False) -> None:
    """Write the config with a fix for every channel that needs one and has one that explains the mismatch.

    A channel gets its candidate (effects appended, or the refitted model) only when it is model-limited and a
    candidate leaves the data within their errors (``explains``); with ``force``, the top candidate of any
    channel that has one. Every channel left as it is gets a line saying why.
    """
    import copy

    raw = copy.deepcopy(config.raw)
    applied, left = [], []
    done = set()
    for name, ch in result.channels.items():
        # a sign, units, the body frame or a clock (issue 23): the streams, not the model
        if ch.conventions:
            for change in (c for convention in ch.conventions for c in convention.changes):
                key = (change["channel"], change["stream"], change["key"])
                if key not in done:
                    raw["channels"][change["channel"]][change["stream"]][change["key"]] = change["value"]
                    done.add(key)
            line = f"{ch.conventions[0].fix} ({ch.conventions[0].kind.replace('_', ' ')}, not physics)"
            if not any(line in a for a in applied):        # one fix for the channels that share it
                applied.append(f"{name}: {line}")
            continue
        # MIMO models take no effects yet: say what to change
        if ch.diagnosis and config.channels[name].is_mimo:
            print(f"gap-validate: --apply-diagnosis: {name}: not applied (a MIMO model takes no effects yet; "
                  f"change its model by hand): {ch.diagnosis[0].sentence}", file=sys.stderr)
            continue
        top, why = _fix_for(ch, force)
        if top is None:
            left.append(f"{name}: left as it is: {why}")
            continue
        model = raw["channels"][name]["model"]
        if top.model:  # parameter error: the refitted model replaces the old one (effects kept in it)
            raw["channels"][name]["model"] = copy.deepcopy(top.model)
        else:
            model["effects"] = list(model.get("effects") or []) + [dict(e) for e in top.effects]
        applied.append(f"{name}: {top.sentence or top.effect}" + (f" (forced: {why})" if why else ""))
    if history is not None:
        raw["history"] = str(history.resolve())
    if not applied:
        print(
            f"gap-validate: --apply-diagnosis: no channel has a fix that explains its mismatch; {out_path} "
            "not "
            f"written",
            file=sys.stderr,
        )
        for line in left:
            print(f"  {line}", file=sys.stderr)
        return
    from gap_validation.core.config import parse_config

    parse_config(raw, out_path)  # never write a config that would not load
    dump_config(raw, out_path)
    print(f"wrote {out_path} (review it, then replay with it):")
    for line in applied + left:
        print(f"  {line}")


def _fix_for(ch, force: bool):
    """``(candidate, note)`` to write for a channel, or ``(None, why not)``.

    Without ``force``: the first candidate that explains the mismatch of a model-limited channel. With it:
    that, else the top candidate, with a note saying what it does not do.
    """
    explaining = next((c for c in ch.diagnosis if c.explains), None)
    if ch.limited_by == "model" and explaining is not None:
        return explaining, ""
    top = ch.diagnosis[0] if ch.diagnosis else None
    why = no_fix_reason(ch.limited_by, epsilon=ch.epsilon, candidates=top is not None,
                        best_epsilon=None if top is None else top.epsilon)
    if top is None:
        return None, why
    if force:
        return top, why
    return None, why + "; --force writes the top candidate anyway"
