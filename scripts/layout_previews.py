"""Previews of the shipped plot layouts, drawn from the bundled flight (the pictures in docs/node.md).

Foxglove does not run on the machines this project is built on (PlotJuggler was built and opened once: the
screenshot beside these in docs/node.md), so these are not screenshots of the apps: each picture draws exactly
the curves its layout selects (``gap_validation.report.layouts``: ``foxglove_plots`` evaluates the Foxglove
panels' message paths, ``plotjuggler_series`` the PlotJuggler script's indices) from the
``~/<channel>/frequency_response`` messages the node publishes at the end of the bundled flight (the tables of
the replay's JSON results, ``scripts/run-example`` writes ``out/example.json``).

Usage: .venv/bin/python scripts/layout_previews.py [RESULTS.json] [--channel pitch] [--out docs]
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from gap_validation.core.config import load_config  # noqa: E402
from gap_validation.core.plottable import frequency_response_table, topic_token  # noqa: E402
from gap_validation.core.results import ValidationResult  # noqa: E402
from gap_validation.report.layouts import BODE_PLOTS, foxglove_plots, plotjuggler_series  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results", nargs="?", default=str(ROOT / "out" / "example.json"))
    parser.add_argument("--config", default=str(ROOT / "config" / "ultrastick25e.yaml"))
    parser.add_argument("--channel", default="pitch")
    parser.add_argument("--out", default=str(ROOT / "docs"))
    args = parser.parse_args()
    config = load_config(args.config)
    result = ValidationResult.from_json_dict(json.loads(Path(args.results).read_text()))
    node = "/gap_validator"
    messages = {f"{node}/{topic_token(name)}/frequency_response":
                frequency_response_table(result.channels[name], ch).ravel().tolist()
                for name, ch in config.channels.items() if name in result.channels}
    layout = json.loads((ROOT / "config" / "foxglove_layout.json").read_text())
    fox = foxglove_plots(layout, messages)
    pj = plotjuggler_series((ROOT / "config" / "plotjuggler_layout.xml").read_text(), messages)
    verdict = result.channels[args.channel]
    out = Path(args.out)
    titles = list(BODE_PLOTS)
    for kind in ("foxglove", "plotjuggler"):
        fig, axes = plt.subplots(len(titles), 1, figsize=(7.5, 7.5), sharex=True)
        for ax, title in zip(axes, titles):
            if kind == "foxglove":
                for label, x, y in fox[f"{args.channel}: {title}"]:
                    ax.plot(x, y, label=label)
            else:
                for curve in BODE_PLOTS[title][0]:
                    x, y = pj[f"{args.channel}/bode/{curve}"]
                    ax.plot(x, y, label=f"{args.channel}/bode/{curve}")
            ax.set_title(f"{args.channel}: {title}", fontsize=9)
            ax.set_ylabel(BODE_PLOTS[title][1])
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=7, loc="best")
        axes[-1].set_xlabel("log10 frequency [rad/s]")
        app = "Foxglove" if kind == "foxglove" else "PlotJuggler"
        fig.suptitle(
            f"config/{kind}_layout.{'json' if kind == 'foxglove' else 'xml'}: what the {app} layout draws "
            f"(preview, not an app screenshot)\nbundled flight, epsilon {verdict.epsilon:.2f}, "
            f"limited by {verdict.limited_by}",
            fontsize=9,
        )
        fig.tight_layout()
        path = out / f"layout_{kind}_{args.channel}.png"
        fig.savefig(path, dpi=80)
        plt.close(fig)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
