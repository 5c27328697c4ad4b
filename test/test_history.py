"""Validation history: append per replay, load, previous epsilon, trend over model versions, corrupt files."""
import json
from datetime import datetime, timezone

import pytest

from gap_validation.core.config import parse_config
from gap_validation.core.errors import DataError
from gap_validation.core.results import ChannelResult, ValidationResult
from gap_validation.history import (
    append_history,
    default_history_path,
    format_trend,
    load_history,
    model_hash,
    previous_epsilon,
)

DELAY = {"type": "time_delay", "seconds": 0.045}


def config(effects=(), numerator=(-133.7, -990.76)):
    model = {"numerator": list(numerator), "denominator": [1.0, 23.37, 235.93]}
    if effects:
        model["effects"] = [dict(e) for e in effects]
    return parse_config({"channels": {"pitch": {
        "input": {"topic": "/control_surfaces", "field": "position[elevator]"},
        "output": {"topic": "/imu", "field": "angular_velocity.y"},
        "model": model}}}, "cfg.yaml")


def result(epsilon, diagnosis=(), nu_gap=0.05):
    channel = ChannelResult(name="pitch", sweeps=3, nu_gap=nu_gap, epsilon=epsilon, epsilon_raw=epsilon * 1.2,
                            worst_frequency_rad_s=31.4, limited_by="model" if epsilon > 0.15 else "none",
                            diagnosis=list(diagnosis))
    return ValidationResult(channels={"pitch": channel}, config_source="cfg.yaml")


TOP = {"effect": "time_delay", "parameters": {"seconds": 0.045}, "effects": [DELAY], "epsilon": 0.07,
       "nu_gap": 0.04}
T0 = datetime(2024, 5, 1, 12, 0, tzinfo=timezone.utc)


def test_default_path_is_beside_the_config(tmp_path):
    assert default_history_path(tmp_path / "ultrastick25e.yaml") == tmp_path / "ultrastick25e.history.jsonl"
    assert default_history_path("cfg.yml").name == "cfg.history.jsonl"


def test_append_and_load(tmp_path):
    path = tmp_path / "cfg.history.jsonl"
    assert load_history(path) == []
    record = append_history(path, result(0.62, [TOP]), config(), ["flight1.mcap", "flight2"], timestamp=T0)
    append_history(path, result(0.07), config([DELAY]), ["flight1.mcap"])
    history = load_history(path)
    assert len(history) == 2 and history[0] == record
    first = history[0]
    assert first["timestamp"] == "2024-05-01T12:00:00+00:00"
    assert first["sources"] == ["flight1.mcap", "flight2"] and first["config"] == "cfg.yaml"
    pitch = first["channels"]["pitch"]
    assert pitch["epsilon"] == 0.62 and pitch["nu_gap"] == 0.05 and pitch["sweeps"] == 3
    assert pitch["epsilon_raw"] == pytest.approx(0.744) and pitch["worst_frequency_rad_s"] == 31.4
    assert pitch["limited_by"] == "model" and pitch["diagnosis"]["effect"] == "time_delay"
    assert pitch["model"] == config().channels["pitch"].model.to_spec()
    assert pitch["model_description"] == "airframe only"
    second = history[1]["channels"]["pitch"]
    assert second["diagnosis"] is None
    assert second["model"]["effects"] == [DELAY] and second["model_description"] == "+ time delay of 45 ms"
    assert second["model_hash"] != pitch["model_hash"] and second["airframe_hash"] == pitch["airframe_hash"]
    assert path.read_text().count("\n") == 2      # one JSON line per replay, appended


def test_non_finite_numbers_are_null(tmp_path):
    path = tmp_path / "h.jsonl"
    append_history(path, result(float("nan")), config(), [])
    line = path.read_text()
    assert "NaN" not in line and json.loads(line)["channels"]["pitch"]["epsilon"] is None


def test_model_hash_is_stable_and_short():
    spec = config([DELAY]).channels["pitch"].model.to_spec()
    assert model_hash(spec) == model_hash(json.loads(json.dumps(spec)))
    assert len(model_hash(spec)) == 10 and model_hash(spec) != model_hash({**spec, "effects": []})


def test_previous_epsilon(tmp_path):
    path = tmp_path / "h.jsonl"
    assert previous_epsilon([], "pitch") is None
    append_history(path, result(0.62), config(), ["a"])
    append_history(path, result(0.60), config(), ["b"])
    append_history(path, result(0.07), config([DELAY]), ["b"])
    history = load_history(path)
    assert previous_epsilon(history, "pitch") == 0.07
    current = history[-1]["channels"]["pitch"]["model_hash"]
    assert previous_epsilon(history, "pitch", exclude_model_hash=current) == 0.60
    assert previous_epsilon(history, "roll") is None


def test_trend_over_model_versions(tmp_path):
    path = tmp_path / "h.jsonl"
    assert format_trend([], "pitch") == "pitch: no validation history yet"
    append_history(path, result(0.65), config(), ["a"])
    append_history(path, result(0.62), config(), ["a", "b"])          # same model: one version, latest value
    append_history(path, result(0.07), config([DELAY]), ["a", "b"])
    assert format_trend(load_history(path), "pitch") == \
        "pitch epsilon over model versions: 0.62 (airframe only) -> 0.07 (+ time delay of 45 ms)"


def test_trend_names_a_changed_airframe(tmp_path):
    path = tmp_path / "h.jsonl"
    append_history(path, result(0.30), config(), ["a"])
    append_history(path, result(0.05), config(numerator=(-150.0, -990.76)), ["a"])
    trend = format_trend(load_history(path), "pitch")
    assert trend.startswith("pitch epsilon over model versions: 0.30 (airframe only, airframe ")
    assert trend.count("airframe only") == 2 and " -> 0.05 (" in trend


def test_corrupt_line_is_an_error_naming_file_and_line(tmp_path):
    path = tmp_path / "h.jsonl"
    append_history(path, result(0.62), config(), ["a"])
    with path.open("a") as handle:
        handle.write('{"timestamp": "x", "channels": {"pitch": \n')
    append_history(path, result(0.07), config([DELAY]), ["a"])
    with pytest.raises(DataError) as err:
        load_history(path)
    message = str(err.value)
    assert message.startswith(f"{path}:2: corrupt validation history line") and "\n" not in message


def test_record_without_channels_is_an_error(tmp_path):
    path = tmp_path / "h.jsonl"
    path.write_text('\n["not", "a", "record"]\n')
    with pytest.raises(DataError, match=r"h.jsonl:2: corrupt validation history line"):
        load_history(path)


def test_unwritable_history_is_a_data_error(tmp_path):
    with pytest.raises(DataError, match="cannot write the validation history"):
        append_history(tmp_path / "missing-dir" / "h.jsonl", result(0.1), config(), [])
