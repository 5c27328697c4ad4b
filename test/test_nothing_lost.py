"""Nothing lost: one bad bag or one bad channel never costs the results of the others (CLI end to end)."""
from __future__ import annotations

import json

import pytest
from _flights import SHORT, config_from, make_bag, raw_config, single_channel, with_options, write_config

from gap_validation.bag.replay import replay
from gap_validation.cli.main import main

ONE = with_options(SHORT, sweeps_per_channel=1, sweep_duration_s=40.0, quiet_s=3.0)


@pytest.fixture(scope="module")
def good_bags(tmp_path_factory):
    root = tmp_path_factory.mktemp("good")
    config = config_from(single_channel("pitch"))
    return [make_bag(root / name, config=config, seed=seed, options=ONE) and root / name
            for seed, name in enumerate(("first", "second"))]


def test_good_corrupt_good_validates_both_good_bags_names_the_bad_one_exit_1(tmp_path, good_bags, capsys):
    corrupt = tmp_path / "corrupt.mcap"
    corrupt.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 8)   # an mcap header, then garbage
    config = write_config(single_channel("pitch"), tmp_path / "pitch.yaml")
    out = tmp_path / "out.json"
    status = main(["replay", str(good_bags[0]), str(corrupt), str(good_bags[1]), "--config", str(config),
                   "--json", str(out), "--no-history"])
    captured = capsys.readouterr()
    assert status == 1
    errors = [line for line in captured.err.splitlines() if "error" in line]
    assert len(errors) == 1 and str(corrupt) in errors[0] and "Traceback" not in captured.err
    pitch = json.loads(out.read_text())["channels"]["pitch"]
    assert pitch["sweeps"] == 2 and pitch["epsilon"] is not None    # one sweep from each good bag


def test_channel_whose_topic_is_missing_does_not_stop_the_others_exit_1(tmp_path, good_bags, capsys):
    data = raw_config()
    data["channels"] = {"pitch": data["channels"]["pitch"], "roll": data["channels"]["roll"]}
    data["channels"]["roll"]["input"]["field"] = "position[elevator]"   # the pitch-only bag has this joint
    data["channels"]["roll"]["output"] = {"topic": "/no_such_imu", "field": "angular_velocity.x"}
    config = write_config(data, tmp_path / "two.yaml")
    out = tmp_path / "out.json"
    status = main(["replay", str(good_bags[0]), "--config", str(config), "--json", str(out), "--no-history"])
    captured = capsys.readouterr()
    assert "/no_such_imu" in captured.err and "Traceback" not in captured.err
    errors = [line for line in captured.err.splitlines() if "error:" in line]
    assert len(errors) == 1 and "channel roll" in errors[0] and "not validated" in errors[0]
    channels = json.loads(out.read_text())["channels"]
    assert channels["pitch"]["sweeps"] == 1 and channels["pitch"]["epsilon"] is not None
    assert channels["roll"]["epsilon"] is None and status == 1  # requested, no data: an error (issue 15)
    alone = replay([good_bags[0]], config_from(single_channel("pitch")), diagnose=False).result.channels[
        "pitch"
    ]
    assert channels["pitch"]["epsilon"] == pytest.approx(alone.epsilon, abs=1e-12)   # unaffected by roll
