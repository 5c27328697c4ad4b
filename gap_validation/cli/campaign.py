"""gap-validate campaign MANIFEST.yaml --out DIR [--scheduler ADDRESS] [--workers N]: many flights on Dask.

Validates every flight of the manifest as one Dask task (a local cluster of ``--workers`` processes by
default, an existing scheduler with ``--scheduler tcp://host:8786``), reuses the results of flights whose bags
and config are unchanged, and writes ``DIR/campaign.json``, ``DIR/campaign.csv`` and ``DIR/index.html`` (fleet
table and trends per aircraft). A flight that cannot be validated is reported in one line and the others
complete (exit status 1).
"""
from __future__ import annotations

import sys

from gap_validation.cli.replay import ProgressBar
from gap_validation.core.errors import ConfigError

__all__ = ["register", "run", "FlightProgress"]


def register(sub) -> None:
    p = sub.add_parser("campaign", help="validate many flights as Dask tasks; fleet trends per aircraft",
                       description=__doc__.split("\n\n")[0])
    p.add_argument(
        "manifest",
        metavar="MANIFEST",
        help="campaign manifest (YAML: flights with name, bag, config, aircraft, date, tags)",
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="DIR",
        help="results directory (campaign.json, campaign.csv, index.html, flights/)",
    )
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="existing Dask scheduler, e.g. tcp://host:8786 (default: a local cluster)")
    p.add_argument("--workers", type=int, metavar="N",
                   help="worker processes of the local cluster (default: the core count)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (default: on a terminal)")
    p.set_defaults(func=run)


class FlightProgress(ProgressBar):
    """A one-line progress bar of a campaign on a stream (flights done / total), redrawn at most 10 times a
    second."""

    def __init__(self, stream=None, width: int = 30):
        super().__init__(stream, width, label="campaign")
        self.counts = {"reused": 0, "failed": 0}

    def __call__(self, outcome, done: int, total: int) -> None:
        if outcome.status in self.counts:
            self.counts[outcome.status] += 1
        self.draw(
            done,
            total,
            lambda rate: (
                f"flights ({self.counts['reused']} reused, {self.counts['failed']} "
                f"failed) {rate:.2f} flights/s"
            ),
            ran=done - self.counts["reused"],
        )


def _warn(message: str) -> None:
    print(f"gap-validate: warning: {message}", file=sys.stderr)


def run(args) -> int:
    from gap_validation.campaign.manifest import load_manifest
    from gap_validation.campaign.runner import run_campaign

    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers {args.workers}: expected an integer >= 1")
    if args.workers is not None and args.scheduler:
        raise ConfigError(
            "--workers sets the size of the local cluster; with --scheduler the scheduler's workers "
            "are used (start more with 'dask worker')"
        )
    manifest = load_manifest(args.manifest)
    bar = FlightProgress() if not args.no_progress and sys.stderr.isatty() else None
    try:
        outcome = run_campaign(
            manifest, args.out, scheduler=args.scheduler, workers=args.workers, progress=bar, warn=_warn
        )
    finally:
        if bar is not None:
            bar.close()
    for warning in outcome.warnings:
        _warn(warning)
    where = (f"on {outcome.workers} worker{'s' if outcome.workers != 1 else ''} "
             f"({'scheduler ' + args.scheduler if args.scheduler else 'local cluster'})"
             if outcome.workers is not None else "(nothing to run)")
    if outcome.workers_lost:
        where += (
            f"; {outcome.workers_lost} worker{'s' if outcome.workers_lost != 1 else ''} lost during the run "
            "(the scheduler reran their flights)"
        )
    print(
        f"{len(outcome.flights)} flights of {len(manifest.aircraft)} aircraft: {outcome.count('validated')} "
        f"validated, {outcome.count('reused')} reused, {outcome.count('failed')} failed in "
        f"{outcome.elapsed_s:.1f} s {where}"
    )
    real = [f for f in outcome.findings if f.significant]
    if real:
        print("trends real against the flights' random error:")
        for finding in real:
            print(f"  {finding.sentence()}")
    else:
        print("no real trend: every quantity is flat within the flights' random error")
    print("wrote " + ", ".join(str(p) for p in outcome.files.values()))
    for error in outcome.errors:
        print(f"gap-validate: error: {error}", file=sys.stderr)
    return 1 if outcome.errors else 0
