"""gap-validate report RESULTS.json --out DIR: the HTML report of saved results (replay --json, node).

Draws the same report as ``replay --report`` from a results file: Table 1 and the verdict, and per channel
the paper's figures (Bode with coherence, epsilon disks, where it fails, Nichols, robust Nyquist, doublets
with the Monte Carlo tube and TIC, diagnosis candidates, epsilon over model versions).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from gap_validation.core.errors import ConfigError, DataError
from gap_validation.core.results import ValidationResult
from gap_validation.history import epsilon_versions, load_history


def register(sub) -> None:
    p = sub.add_parser("report", help="HTML report with the paper's figures from a results JSON",
                       description=__doc__.split("\n\n")[0])
    p.add_argument(
        "results", metavar="RESULTS.json", help="results written by replay --json or ~/save_results"
    )
    p.add_argument("--out", required=True, metavar="DIR", help="directory for index.html and the figures")
    p.add_argument("--history", metavar="FILE",
                   help="validation history to plot epsilon over model versions from (default: the one in "
                        "the results, if any)")
    p.add_argument("--runs", type=int, default=500, metavar="N", help="Monte Carlo runs per doublet (500)")
    p.add_argument("--seed", type=int, default=0, metavar="N", help="Monte Carlo seed (0)")
    p.set_defaults(func=run)


def load_results_json(path: str) -> dict:
    """The results JSON as a mapping, or a one-line :class:`DataError` naming the file.

    Parameters
    ----------
    path : str
        The results file.
    """
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DataError(f"{path}: no such results file") from None
    except IsADirectoryError:
        raise DataError(f"{path}: is a directory, not a results file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise DataError(f"{path}: cannot read ({getattr(err, 'strerror', None) or err})") from None
    except json.JSONDecodeError as err:
        raise DataError(f"{path}:{err.lineno}: not JSON ({err.msg})") from None
    if not isinstance(data, dict) or not isinstance(data.get("channels"), dict):
        raise DataError(f"{path}: not a results file (expected an object with 'channels')")
    for name, ch in data["channels"].items():
        if not isinstance(ch, dict):
            raise DataError(f"{path}: channels.{name}: expected an object, got {type(ch).__name__}")
    return data


def load_results(path: str) -> ValidationResult:
    """Results from a JSON file; DataError (one line naming the file) when it is not readable results."""
    data = load_results_json(path)
    try:
        return ValidationResult.from_json_dict(data)
    except (TypeError, ValueError, KeyError, AttributeError, IndexError) as err:
        raise DataError(f"{path}: not a results file ({err})") from None


def run(args) -> int:
    if args.runs < 1:
        raise ConfigError(f"--runs {args.runs}: expected at least 1")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {args.out}: is a file, not a directory")
    result = load_results(args.results)
    if args.history:
        records = load_history(args.history)
        result.history = {name: epsilon_versions(records, name) for name in result.channels}
    from gap_validation.report.html import write_report

    index = write_report(result, out, runs=args.runs, seed=args.seed,
                         warn=lambda m: print(f"gap-validate: warning: {m}", file=sys.stderr))
    print(f"wrote {index}")
    return 0
