"""``gap-validate``: the command-line front end (DESIGN.md, CLI contract).

Each subcommand lives in ``gap_validation/cli/<name>.py`` with ``register(subparsers)`` (adds its parser
and sets ``func``) and ``run(args) -> int``. Errors are one line on stderr; ``--debug`` shows the traceback.
Exit status: 0 success, 2 bad usage or config, 1 unreadable data.
"""
from __future__ import annotations

from gap_validation.blas import single_threaded_blas

single_threaded_blas()  # before numpy loads (gap_validation/blas.py: measured 2x faster under load)

import argparse
import importlib
import logging
import os
import sys
import warnings

from gap_validation import __version__
from gap_validation.core.errors import GapValidationError

#: Subcommand modules, in the order ``--help`` lists them.
COMMANDS = ("replay", "compare_models", "simulate", "linearize", "report", "campaign", "layouts", "plan")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every available subcommand registered."""
    parser = argparse.ArgumentParser(
        prog="gap-validate",
        description="Validate linear aircraft models against flight data in the nu-gap metric.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks and debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"gap_validation.cli.{name}")
        except ModuleNotFoundError as err:
            if err.name == f"gap_validation.cli.{name}":
                continue  # subcommand not built yet
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``gap-validate``; returns the exit status."""
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    try:
        parser = build_parser()  # imports every subcommand (numpy, scipy, rosbags): the slow part of startup
    except KeyboardInterrupt:
        print("gap-validate: interrupted", file=sys.stderr)
        return 130
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.debug else logging.WARNING,
                        format="gap-validate: %(levelname)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    try:
        return int(args.func(args) or 0)
    except GapValidationError as err:
        if args.debug:
            raise
        print(f"gap-validate: error: {err}", file=sys.stderr)
        return err.exit_code
    except BrokenPipeError:  # output piped into e.g. head
        try:
            sys.stdout = open(os.devnull, "w")
        except OSError:
            pass
        return 0
    except KeyboardInterrupt:
        print("gap-validate: interrupted", file=sys.stderr)
        return 130
    except (OSError, ValueError) as err:
        if args.debug:
            raise
        print(f"gap-validate: error: {err}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
