"""HTML report: every figure of the paper for every channel of the bundled flight, from a replay and from its
JSON; names escaped; one failing figure never costs the report; the page renders in headless Chromium."""
import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from matplotlib import image

from gap_validation.cli.main import main
from gap_validation.core.results import ValidationResult
from gap_validation.report import figures
from gap_validation.report import html as report
from gap_validation.report.html import write_report

ROOT = Path(__file__).resolve().parents[1]
BAG = str(ROOT / "bags" / "ultrastick25e_flight")
CONFIG = str(ROOT / "config" / "ultrastick25e.yaml")
KINDS = ("bode", "disk", "failure", "nichols", "nyquist", "time", "diagnosis", "history")
CHANNELS = ("roll", "pitch", "yaw")


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    """The bundled flight replayed once with --json, --report and a history."""
    out = tmp_path_factory.mktemp("report")
    code = main(["replay", BAG, "--config", CONFIG, "--json", str(out / "results.json"), "--report",
                 str(out / "report"), "--history", str(out / "history.jsonl"), "--no-progress"])
    assert code == 0
    return out


def assert_real_plot(path: Path) -> None:
    assert path.stat().st_size > 10_000, path
    pixels = image.imread(path)                     # decodes as a PNG image
    assert pixels.shape[0] > 250 and pixels.shape[1] > 350, (path, pixels.shape)
    assert float(np.std(pixels[..., :3])) > 0.02, path   # not a blank canvas


def test_bundled_flight_report_holds_every_figure_for_every_channel(replayed):
    directory = replayed / "report"
    text = (directory / "index.html").read_text()
    for name in CHANNELS:
        assert f">{name}</h2>" in text
        for kind in KINDS:
            png = directory / f"{name}_{kind}.png"
            assert_real_plot(png)
            assert f"src='{png.name}'" in text
    # Table 1 form at the top: raw and averaged epsilon and margins per channel, then the verdict
    top = text.split("<h2 id=")[0]
    for row in (
        "Gap metric epsilon",
        "Gain margin, dB",
        "Phase margin, deg",
        "Disk margin",
        "Raw",
        "Average",
    ):
        assert row in top
    assert top.count("class='verdict") == 3 and "not validated: epsilon" in top
    assert "first-order lag" in top                    # the missing effect named in the verdict
    assert "TIC of the doublets" in top


def test_time_domain_keys_in_the_json(replayed):
    channels = json.loads((replayed / "results.json").read_text())["channels"]
    for name in CHANNELS:
        checks = channels[name]["time_domain"]
        assert checks and all(c["kind"] == "doublet" for c in checks)
        for c in checks:
            assert 0.0 <= c["tic_input_augmented"] <= c["tic"] <= 1.0
            assert len(c["input"]) == len(c["output"]) > 500


def test_report_command_redraws_the_same_report_from_the_json(replayed, capsys):
    out = replayed / "from_json"
    assert main(["report", str(replayed / "results.json"), "--out", str(out), "--runs", "50"]) == 0
    assert "index.html" in capsys.readouterr().out
    first, second = (replayed / "report" / "index.html").read_text(), (out / "index.html").read_text()
    table = lambda html: html.split("<h3>Verdict")[0].split("<h2>Summary")[1]   # noqa: E731
    assert table(first) == table(second)
    assert sorted(p.name for p in out.glob("*.png")) == sorted(
        p.name for p in (replayed / "report").glob("*.png")
    )


def test_json_round_trip_keeps_what_the_figures_need(replayed):
    data = json.loads((replayed / "results.json").read_text())
    result = ValidationResult.from_json_dict(data)
    pitch, saved = result.channels["pitch"], data["channels"]["pitch"]
    assert pitch.epsilon == saved["epsilon"] and len(pitch.sweep_measured) == saved["sweeps"]
    assert np.allclose(20 * np.log10(np.abs(pitch.measured)), saved["measured"]["magnitude_db"])
    again = result.to_json_dict()["channels"]["pitch"]
    assert again["epsilon_per_frequency"] == saved["epsilon_per_frequency"]
    assert again["time_domain"] == saved["time_domain"]
    assert np.allclose(again["measured"]["phase_deg"], saved["measured"]["phase_deg"])


def test_names_from_configs_and_bags_are_escaped(replayed, tmp_path):
    data = json.loads((replayed / "results.json").read_text())
    evil = "<script>alert(1)</script>&"
    data["channels"] = {evil: data["channels"]["pitch"]}
    data["sources"] = ["<img src=x onerror=alert(2)>"]
    index = write_report(ValidationResult.from_json_dict(data), tmp_path / "r", runs=20)
    text = index.read_text()
    assert "<script>" not in text and "<img src=x" not in text
    assert "&lt;script&gt;alert(1)&lt;/script&gt;&amp;" in text
    names = [p.name for p in (tmp_path / "r").glob("*.png")]
    assert names and all(n.startswith("channel0_script_alert_1_script") for n in names)


def test_a_failing_figure_costs_only_itself(replayed, tmp_path, monkeypatch):
    data = json.loads((replayed / "results.json").read_text())

    def broken(*args, **kwargs):
        raise RuntimeError("no ink")

    monkeypatch.setattr(figures, "nyquist_figure", broken)
    warnings = []
    index = write_report(ValidationResult.from_json_dict(data), tmp_path / "r", runs=20, warn=warnings.append)
    text = index.read_text()
    assert len(warnings) == 3 and all("nyquist figure not drawn (no ink)" in w for w in warnings)
    assert "roll_bode.png" in text and "roll_nyquist.png" not in text
    assert not list((tmp_path / "r").glob(".*tmp"))            # no temporary file left behind


def test_channel_without_sweeps_or_doublets_still_reports(tmp_path):
    data = {"channels": {"roll": {"sweeps": 0, "message": "no sweep yet"}}, "sources": []}
    text = write_report(ValidationResult.from_json_dict(data), tmp_path / "r").read_text()
    assert "not validated yet: no sweep yet" in text and "no doublet found" in text


@pytest.mark.parametrize("args, code, needle", [
    (["report", "missing.json", "--out", "r"], 1, "no such results file"),
    (["report", "bad.json", "--out", "r"], 1, "bad.json:1: not JSON"),
    (["report", "list.json", "--out", "r"], 1, "not a results file"),
])
def test_report_command_errors_are_one_line(tmp_path, monkeypatch, capsys, args, code, needle):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "bad.json").write_text("{nope")
    (tmp_path / "list.json").write_text("[1, 2]")
    assert main(args) == code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0]


def test_verdict_in_words():
    from gap_validation.core.margins import margins_from_epsilon
    from gap_validation.core.results import ChannelResult

    good = ChannelResult("pitch", epsilon=0.10, margins=margins_from_epsilon(0.10))
    text, cls = report.verdict(good)
    assert cls == "ok" and "1.74 dB gain margin" in text and "11.5 deg" in text
    assert report.verdict(ChannelResult("yaw", epsilon=0.5))[1] == "warn"
    assert report.verdict(ChannelResult("roll", epsilon=1.3))[1] == "bad"


def _chromium() -> str:
    found = shutil.which("chromium")
    if found is None:
        script = ROOT / "scripts" / "install-chromium"
        try:
            subprocess.run([str(script)], check=True, timeout=600, env=os.environ, capture_output=True)
        except (subprocess.SubprocessError, OSError) as err:
            pytest.skip(f"headless Chromium not available and could not be installed ({err})")
        found = shutil.which("chromium")
    if found is None:
        pytest.skip("headless Chromium not available after scripts/install-chromium")
    return found


#: Appended to a copy of the report (never to the report itself): logs how many images loaded.
_IMAGE_PROBE = ("<script>window.addEventListener('load', () => {const all = [...document.images];"
                "const broken = all.filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.src);"
                "console.log('IMAGES ' + all.length + ' BROKEN ' + JSON.stringify(broken));});</script>")


def run_chromium(chromium: str, page: Path, shot: Path, profile: Path) -> tuple[list[str], list[str]]:
    """Load ``page`` headless, screenshot it; return (console lines, error lines)."""
    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             f"--user-data-dir={profile}", "--enable-logging=stderr", "--v=0", "--virtual-time-budget=10000",
             "--window-size=1100,2400", f"--screenshot={shot}"]
    done = subprocess.run([chromium, *flags, page.resolve().as_uri()], capture_output=True, text=True,
                          timeout=120, env=os.environ)
    assert done.returncode == 0, done.stderr[-2000:]
    console = [line for line in done.stderr.splitlines() if ":CONSOLE" in line]
    errors = [line for line in console if "Uncaught" in line or "Failed to load resource" in line]
    return console, errors


def assert_page_renders(directory: Path, images: int, tmp_path: Path) -> None:
    """``directory/index.html`` loads in headless Chromium without errors, with all ``images`` loaded, and its
    screenshot is a real plot (the page is probed through a copy with :data:`_IMAGE_PROBE` appended)."""
    chromium = _chromium()
    probe = directory / "_probe.html"
    probe.write_text((directory / "index.html").read_text() + _IMAGE_PROBE)
    try:
        console, errors = run_chromium(chromium, probe, tmp_path / "shot.png", tmp_path / "profile")
    finally:
        probe.unlink()
    assert errors == []
    loaded = [line for line in console if "IMAGES " in line]
    assert loaded and f"IMAGES {images} BROKEN []" in loaded[0], console
    assert_real_plot(tmp_path / "shot.png")


def test_report_renders_in_headless_chromium(replayed, tmp_path):
    assert_page_renders(replayed / "report", len(CHANNELS) * len(KINDS), tmp_path)


def test_chromium_probe_sees_a_missing_image(replayed, tmp_path):
    """The browser check can fail: a report with an image removed is caught."""
    chromium = _chromium()
    broken = tmp_path / "broken"
    shutil.copytree(replayed / "report", broken)
    (broken / "roll_bode.png").unlink()
    (broken / "_probe.html").write_text((broken / "index.html").read_text() + _IMAGE_PROBE)
    console, _ = run_chromium(chromium, broken / "_probe.html", tmp_path / "shot.png", tmp_path / "profile")
    assert any("roll_bode.png" in line and "BROKEN" in line for line in console), console
