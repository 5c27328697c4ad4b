"""The mission end to end on the bundled flight: compare, see where it fails, learn the missing effect,
add it (--apply-diagnosis) and watch epsilon fall in the history."""
import json
from pathlib import Path

import yaml

from gap_validation.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
BAG = str(ROOT / "bags" / "ultrastick25e_flight")
CONFIG = str(ROOT / "config" / "ultrastick25e.yaml")


def test_apply_diagnosis_and_watch_epsilon_fall(tmp_path, capsys):
    history = tmp_path / "history.jsonl"
    fixed = tmp_path / "fixed.yaml"
    first = tmp_path / "first.json"
    assert main(["replay", BAG, "--config", CONFIG, "--json", str(first), "--history", str(history),
                 "--apply-diagnosis", str(fixed), "--no-progress"]) == 0
    out = capsys.readouterr().out
    before = json.loads(first.read_text())["channels"]
    for name in ("roll", "pitch", "yaw"):
        assert before[name]["limited_by"] == "model"
        top = before[name]["diagnosis"][0]
        types = sorted(e["type"] for e in top["effects"])
        assert types == ["first_order_lag", "time_delay"], top
        params = {e["type"]: e for e in top["effects"]}
        # the bundled flight hides the lab's servo model: 37.7 rad/s lag and 50 ms delay
        assert abs(params["time_delay"]["seconds"] - 0.05) < 0.01
        assert abs(params["first_order_lag"]["bandwidth_rad_s"] - 37.7) < 0.2 * 37.7
        assert f"{name}: missing: first-order lag" in out
    written = yaml.safe_load(fixed.read_text())
    assert written["history"] == str(history.resolve())
    assert len(written["channels"]["pitch"]["model"]["effects"]) == 2

    second = tmp_path / "second.json"
    assert main(["replay", BAG, "--config", str(fixed), "--json", str(second), "--no-progress"]) == 0
    out = capsys.readouterr().out
    after = json.loads(second.read_text())["channels"]
    for name in ("roll", "pitch", "yaw"):
        assert after[name]["epsilon"] < before[name]["epsilon"] / 2
        assert after[name]["epsilon"] < 0.2
        assert after[name]["epsilon_previous"] == before[name]["epsilon"]
        assert f"{name} epsilon over model versions: {before[name]['epsilon']:.2f} (airframe only) -> " in out
    assert len(history.read_text().splitlines()) == 2


def test_corrupt_history_does_not_lose_results(tmp_path, capsys):
    history = tmp_path / "history.jsonl"
    history.write_text("{not json\n")
    out_json = tmp_path / "out.json"
    assert main(["replay", BAG, "--config", CONFIG, "--json", str(out_json), "--history", str(history),
                 "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "history.jsonl:1: corrupt validation history line" in err
    assert json.loads(out_json.read_text())["channels"]["pitch"]["sweeps"] == 3
    assert history.read_text() == "{not json\n"      # left as it was for the user to inspect


def test_config_topics_missing_from_the_bag_is_an_error(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text(Path(CONFIG).read_text().replace("/imu", "/imu_missing"))
    assert main(["replay", BAG, "--config", str(bad), "--no-history", "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "topic /imu_missing (roll.output, pitch.output, yaw.output) is not in the bag" in err
    assert "no channel has both input and output samples" in err
    assert "Traceback" not in err


def test_unwritable_history_keeps_the_other_outputs_and_the_bag_errors(tmp_path, capsys):
    blocker = tmp_path / "not_a_dir"
    blocker.write_text("")
    fixed = tmp_path / "fixed.yaml"
    out_json = tmp_path / "out.json"
    status = main(
        [
            "replay",
            BAG,
            str(tmp_path / "missing.mcap"),
            "--config",
            CONFIG,
            "--json",
            str(out_json),
            "--history",
            str(blocker / "history.jsonl"),
            "--apply-diagnosis",
            str(fixed),
            "--no-progress",
        ]
    )
    assert status == 1                                   # the missing bag, not the history
    err = capsys.readouterr().err
    assert "cannot write the validation history" in err and "history is not appended" in err
    assert "missing.mcap" in err and "Traceback" not in err
    assert fixed.exists() and json.loads(out_json.read_text())["channels"]["pitch"]["sweeps"] == 3
    assert "history" not in yaml.safe_load(fixed.read_text())   # not pointed at a history it could not write
