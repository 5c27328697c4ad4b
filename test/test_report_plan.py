"""What to fly next in the replay's report and terminal (issue 25, item 4): per channel the bands without a
verdict and the test card's manoeuvre that would close them, the planned bands shaded on the Bode figure, one
terminal line pointing at ``gap-validate plan``; a plan that fails never costs the replay its report."""
from __future__ import annotations

import contextlib
import io
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from gap_validation.cli.main import main
from gap_validation.core.results import ChannelResult, ValidationResult
from gap_validation.report import card as report_card
from gap_validation.report import figures

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "ultrastick25e.yaml"


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A short, weak flight of pitch alone (one 40 s sweep at 1.7 deg, gusts): data-limited at its low end;
    replayed once with --json and --report, and planned by ``gap-validate plan`` from its JSON."""
    out = tmp_path_factory.mktemp("report_plan")
    data = yaml.safe_load(CONFIG.read_text())
    data["channels"] = {"pitch": data["channels"]["pitch"]}
    config = out / "pitch.yaml"
    config.write_text(yaml.safe_dump(data, sort_keys=False))
    bag = out / "flight"
    assert (
        main(
            [
                "simulate",
                "--config",
                str(config),
                "--out",
                str(bag),
                "--sweeps",
                "1",
                "--sweep-duration",
                "40",
                "--amplitude-deg",
                "1.72",
                "--sweep-gap-s",
                "4",
                "--seed",
                "7",
            ]
        )
        == 0
    )
    return {"out": out, "config": config, "bag": bag}


@pytest.fixture(scope="module")
def replayed(flight):
    out = flight["out"]
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        assert (
            main(
                [
                    "replay",
                    str(flight["bag"]),
                    "--config",
                    str(flight["config"]),
                    "--json",
                    str(out / "r1.json"),
                    "--report",
                    str(out / "report"),
                    "--no-history",
                    "--no-progress",
                ]
            )
            == 0
        )
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["plan", str(out / "r1.json"), "--config", str(flight["config"]), "--out",
                     str(out / "card.yaml")]) == 0
    return {**flight, "stdout": buffer.getvalue(),
            "results": json.loads((out / "r1.json").read_text()),
            "card": yaml.safe_load((out / "card.yaml").read_text()),
            "html": (out / "report" / "index.html").read_text()}


def _pitch_section(text: str) -> str:
    return text.split("<h2 id='pitch'>")[1]


def test_the_report_shows_the_data_limited_band_and_the_manoeuvre_that_closes_it(replayed):
    ch = replayed["results"]["channels"]["pitch"]
    w = ch["frequency_rad_s"]
    data_limited = [f for f, flag in zip(w, ch["frequency_flags"]) if flag == "data"]
    assert data_limited, "the weak flight should leave a data-limited band"
    section = _pitch_section(replayed["html"])
    assert "<h3>What to fly next</h3>" in section
    # the bands table: every data-limited frequency inside a listed band, and the band's reasons in words
    table = section.split("<table class='open-bands'>")[1].split("</table>")[0]
    bands = [(float(m.group(1)), float(m.group(2) or m.group(1)))
             for m in re.finditer(r"<tr><td>([\d.]+)(?:-([\d.]+))?</td>", table)]
    assert bands
    assert all(any(lo * 0.999 <= f <= hi * 1.001 for lo, hi in bands) for f in data_limited)
    assert "data-limited" in table
    # the card's manoeuvre, as `gap-validate plan` plans it from the same results
    manoeuvres = replayed["card"]["channels"]["pitch"]["manoeuvres"]
    assert manoeuvres
    rows = section.split("<table class='card'>")[1].split("</table>")[0]
    for m in manoeuvres:
        lo, hi = m["band_rad_s"]
        expected = [
            f"{m['closes_rad_s'][0]:.3g}-{m['closes_rad_s'][1]:.3g}",
            f"{lo:.3g}-{hi:.3g}",
            f"{lo / (2 * math.pi):.3g}-{hi / (2 * math.pi):.3g}",
            f"{math.degrees(m['amplitude_rad']):.2f} ({m['amplitude_rad']:.3g})",
            f"{m['duration_s']:.0f}",
            str(m["repeats"]),
            f"{m['expected_worst_error']:.3f}",
        ]
        for cell in expected:
            assert f"<td>{cell}</td>" in rows, (cell, rows)
        minutes, seconds = divmod(m["flight_time_s"], 60)
        assert f"{int(minutes)} min {seconds:02.0f} s" in rows
        # it closes the data-limited frequencies
        assert all(m["closes_rad_s"][0] <= f <= m["closes_rad_s"][1] for f in data_limited)
    assert "Shaded: the bands the test card" in section       # the Bode figure shows the planned bands
    assert "plan unavailable" not in replayed["html"]


def test_one_terminal_line_points_at_the_plan(replayed):
    lines = [line for line in replayed["stdout"].splitlines() if "gap-validate plan" in line]
    assert len(lines) == 1
    m = replayed["card"]["channels"]["pitch"]["manoeuvres"][0]
    assert lines[0].startswith("  pitch: no verdict at ") and "data-limited" in lines[0]
    assert f"a {m['duration_s']:.0f} s chirp" in lines[0] and "that would close" in lines[0]


def test_without_a_report_the_replay_does_not_plan_and_says_how(replayed, monkeypatch, capsys, tmp_path):
    def refuse(*args, **kwargs):
        raise AssertionError("planned without --report")

    monkeypatch.setattr(report_card, "plan_card", refuse)
    assert main(["replay", str(replayed["bag"]), "--config", str(replayed["config"]), "--json",
                 str(tmp_path / "r.json"), "--no-history", "--no-progress"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if "gap-validate plan" in line]
    assert len(lines) == 1
    assert f"`gap-validate plan {tmp_path / 'r.json'} --config {replayed['config']}` plans" in lines[0]


def test_a_plan_that_fails_costs_the_replay_nothing(replayed, monkeypatch, capsys, tmp_path):
    def boom(*args, **kwargs):
        raise RuntimeError("planner exploded\non two lines")

    monkeypatch.setattr(report_card, "plan_card", boom)
    code = main(
        [
            "replay",
            str(replayed["bag"]),
            "--config",
            str(replayed["config"]),
            "--json",
            str(tmp_path / "r.json"),
            "--report",
            str(tmp_path / "report"),
            "--no-history",
            "--no-progress",
        ]
    )
    assert code == 0
    captured = capsys.readouterr()
    assert (tmp_path / "r.json").exists()
    text = (tmp_path / "report" / "index.html").read_text()
    # summary, pitch
    assert text.count("plan unavailable: RuntimeError: planner exploded on two lines</p>") == 2
    assert "<table class='open-bands'>" in text            # the bands are still shown, from the results
    assert (tmp_path / "report" / "pitch_bode.png").exists()
    assert "Shaded" not in text
    assert (
        "gap-validate: warning: plan unavailable: RuntimeError: planner exploded on two lines" in captured.err
    )
    lines = [line for line in captured.out.splitlines() if "pitch: no verdict" in line]
    assert len(lines) == 1 and "plan unavailable (RuntimeError: planner exploded on two lines)" in lines[0]


# ------------------------------------------------------------------------------------------------ by hand
def _channel(flags, reasons, w=(1.0, 2.0, 4.0, 8.0, 16.0, 32.0)) -> ChannelResult:
    return ChannelResult("pitch", frequency_rad_s=np.array(w), frequency_flags=list(flags),
                         frequency_reasons=list(reasons))


def test_open_bands_follow_the_planners_rule():
    """model-limited: a verdict whatever the estimate; data-limited: open whatever the estimate; else open
    where the estimate is not confident; a run splits where flying can no longer help (above what the logs
    resolve)."""
    ch = _channel(["data", "ok", "model", "ok", "not_excited", "not_excited"],
                  [None, "too_few_dof", "low_coherence", None, "not_excited", "above_resolution"])
    bands = report_card.open_bands(ch)
    assert [(b.low_rad_s, b.high_rad_s, b.points, b.reasons) for b in bands] == [
        (1.0, 2.0, 2, ("data", "too_few_dof")), (16.0, 16.0, 1, ("not_excited",)),
        (32.0, 32.0, 1, ("above_resolution",))]
    assert [b.by_flying for b in bands] == [True, True, False]
    assert bands[0].words == "data-limited, too few degrees of freedom"


def test_no_line_where_every_frequency_has_a_verdict_or_only_the_logs_limit():
    result = ValidationResult(channels={
        "pitch": _channel(["ok"] * 6, [None] * 6),
        "roll": _channel(["ok"] * 5 + ["not_excited"], [None] * 5 + ["above_resolution"])})
    assert report_card.plan_lines(result) == []
    result.channels["yaw"] = _channel(["ok", "data"] + ["ok"] * 4, [None] * 6)
    assert report_card.plan_lines(result, None, "gap-validate plan r.json --config c.yaml") == [
        "  yaw: no verdict at 2 rad/s (data-limited): `gap-validate plan r.json --config c.yaml` plans the "
        "manoeuvres that would close it"]


def test_the_bode_figure_shades_the_planned_bands(tmp_path):
    from matplotlib import image

    w = np.geomspace(1.0, 40.0, 12)
    h = 5.0 / (1j * w + 2.0)
    ch = ChannelResult(
        "pitch",
        sweeps=1,
        frequency_rad_s=w,
        measured=h,
        model=h,
        coherence=np.full(w.size, 0.9),
        confident=np.ones(w.size, bool),
        sweep_measured=[h],
    )
    plain, shaded = tmp_path / "plain.png", tmp_path / "shaded.png"
    figures.bode_figure(ch, plain)
    figures.bode_figure(ch, shaded, planned=[(w[0], w[2])])
    a, b = image.imread(plain)[..., :3], image.imread(shaded)[..., :3]
    assert a.shape == b.shape
    differ = np.any(np.abs(a - b) > 0.02, axis=2)[int(0.8 * a.shape[0]):]     # the coherence axes: no legend
    columns = np.flatnonzero(differ.any(axis=0))
    assert columns.size                                        # something is drawn ...
    assert columns.max() < 0.4 * a.shape[1]                    # ... over the low-frequency end only
