"""The Foxglove and PlotJuggler layouts (gap_validation.report.layouts, ``gap-validate layouts``): the shipped
files are what the command writes for the bundled config, and what each layout draws from the node's
``~/<channel>/frequency_response`` messages is the channel's JSON curves, channel by channel."""
from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from gap_validation.cli.main import main
from gap_validation.core.config import load_config
from gap_validation.core.plottable import frequency_response_table, topic_token
from gap_validation.core.results import ChannelResult
from gap_validation.report.layouts import (
    BODE_PLOTS,
    foxglove_json,
    foxglove_layout,
    foxglove_plots,
    plotjuggler_layout,
    plotjuggler_series,
)

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "ultrastick25e.yaml"


def _messages(config, node="/gap_validator"):
    """Per channel a different result (gain 0.9, 0.8, 0.7 of the model; estimates on part of the grid only),
    as the node publishes it; and the curves the JSON holds."""
    messages, expected = {}, {}
    for k, (name, channel) in enumerate(config.channels.items()):
        grid = channel.frequencies.values()
        w = grid[3 + k:30 + k]
        p = channel.model.freqresp(w)
        gain = 0.9 - 0.1 * k
        result = ChannelResult(
            name=name,
            frequency_rad_s=w,
            measured=gain * p * np.exp(-0.01j * w),
            model=p,
            coherence=np.linspace(0.6 + 0.1 * k, 0.99, w.size),
            kappa=np.full(w.size, 0.05),
            epsilon_per_frequency=np.linspace(0.05, 0.3 + k, w.size),
            random_error=np.full(w.size, 0.02),
            frequency_flags=["ok"] * w.size,
        )
        table = frequency_response_table(result, channel)
        messages[f"{node}/{topic_token(name)}/frequency_response"] = table.ravel().tolist()
        data = result.to_json_dict(samples=False)
        expected[name] = {"x": np.log10(w),
                          "measured_magnitude_db": data["measured"]["magnitude_db"],
                          "model_magnitude_db": data["model"]["magnitude_db"],
                          "measured_phase_deg": data["measured"]["phase_deg"],
                          "model_phase_deg": data["model"]["phase_deg"],
                          "coherence": data["coherence"], "epsilon": data["epsilon_per_frequency"]}
    return messages, expected


def test_the_shipped_layouts_are_what_the_command_writes_for_the_bundled_config(tmp_path, capsys):
    assert main(["layouts", "--config", str(CONFIG), "--foxglove", str(tmp_path / "f.json"),
                 "--plotjuggler", str(tmp_path / "p.xml")]) == 0
    assert (tmp_path / "f.json").read_text() == (ROOT / "config" / "foxglove_layout.json").read_text()
    assert (tmp_path / "p.xml").read_text() == (ROOT / "config" / "plotjuggler_layout.xml").read_text()
    assert "roll (40 frequencies), pitch (40 frequencies), yaw (40 frequencies)" in capsys.readouterr().out


def test_foxglove_draws_each_channels_json_curves_against_log10_frequency():
    config = load_config(CONFIG)
    messages, expected = _messages(config)
    layout = json.loads(foxglove_json(config))
    plots = foxglove_plots(layout, messages)
    assert len(plots) == len(config.channels) * len(BODE_PLOTS)
    for name, curves in expected.items():
        for title, (rows, _) in BODE_PLOTS.items():
            lines = plots[f"{name}: {title}"]
            assert len(lines) == len(rows)
            for (label, x, y), row in zip(lines, rows):
                np.testing.assert_allclose(x, curves["x"], rtol=1e-12)
                np.testing.assert_allclose(y, curves[row], rtol=1e-12, err_msg=f"{name} {row}")
    panels = layout["configById"]
    assert panels[layout["layout"]]["tabs"][-1]["title"] == "diagnostics"
    verdicts = sorted(p["topicPath"] for k, p in panels.items() if k.startswith("RawMessages!"))
    assert verdicts == sorted(f"/gap_validator/{n}/verdict.data" for n in config.channels)


def test_plotjuggler_script_builds_each_channels_json_curves_and_the_plots_draw_them():
    config = load_config(CONFIG)
    messages, expected = _messages(config, node="/uav/gap_validator")
    text = plotjuggler_layout(config, node="uav/gap_validator/")
    series = plotjuggler_series(text, messages)
    assert len(series) == len(config.channels) * 6
    for name, curves in expected.items():
        for row in ("measured_magnitude_db", "model_magnitude_db", "measured_phase_deg", "model_phase_deg",
                    "coherence", "epsilon"):
            x, y = series[f"{name}/bode/{row}"]
            np.testing.assert_allclose(x, curves["x"], rtol=1e-12)
            np.testing.assert_allclose(y, curves[row], rtol=1e-12, err_msg=f"{name} {row}")
    root = ET.fromstring(text)
    drawn = {c.get("name") for c in root.iter("curve")}
    assert drawn == set(series)                          # every plot draws a series the script makes, and all
    streamer = root.find("./Plugins/plugin[@ID='ROS2 Topic Subscriber']")
    assert int(streamer.find("max_array_size").get("value")) >= 11 * 40
    assert "/uav/gap_validator/pitch/frequency_response" in streamer.find("selected_topics").get("value")


def test_a_wrong_index_is_seen():
    """The checks above read the layouts' own indices: a layout whose rows were shifted draws other curves."""
    config = load_config(CONFIG)
    messages, expected = _messages(config)
    layout = foxglove_layout(config)
    pid = next(
        k for k, p in layout["configById"].items() if p.get("foxglovePanelTitle") == "pitch: magnitude"
    )
    layout["configById"][pid]["paths"][0]["value"] = "/gap_validator/pitch/frequency_response.data[160:199]"
    (_, _, y), _ = foxglove_plots(layout, messages)["pitch: magnitude"]
    assert not np.allclose(y, expected["pitch"]["measured_magnitude_db"])


def test_layouts_command_errors_are_one_line(tmp_path, capsys):
    assert main(["layouts", "--config", str(CONFIG)]) == 2
    assert "nothing to write" in capsys.readouterr().err
    assert main(["layouts", "--config", str(CONFIG), "--foxglove", str(tmp_path / "no" / "f.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "does not exist" in err
    assert (
        main(["layouts", "--config", str(tmp_path / "missing.yaml"), "--foxglove", str(tmp_path / "f.json")])
        != 0
    )
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
