"""Bad input, end to end (issue 8): every failure is one clear line, local and loss-free.

Config (malformed YAML, unknown keys, wrong types, absurd effects, improper models, fields, topics, joints),
bags (missing, empty, truncated and corrupted mcap and sqlite3, unknown types), samples (a looped bag, a
saturated surface, a channel never excited) and models (unstable, epsilon >= 1, winding number). Each test
drives ``gap-validate`` (``cli.main``) or ``replay`` and checks the exit status, the one line and that the
good parts are still validated.
"""
from __future__ import annotations

import copy
import dataclasses
import json
import shutil
import sqlite3

import numpy as np
import pytest
from _flights import SHORT, config_from, single_channel, ultrastick, write_config

from gap_validation.bag.replay import replay
from gap_validation.bag.writer import write_flight
from gap_validation.cli.main import main
from gap_validation.core.simulation import simulate_flight, with_options

PITCH = with_options(SHORT, sweeps_per_channel=2, sweep_duration_s=40.0, quiet_s=5.0)
#: The three channels, one sweep each: short enough for the many variants below.
TRIO = with_options(SHORT, sweeps_per_channel=1, sweep_duration_s=40.0, quiet_s=5.0)


def one_error_line(capsys) -> str:
    """The single ``gap-validate: error:`` line on stderr (asserts there is exactly one, no traceback)."""
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.startswith("gap-validate: error:")]
    assert len(lines) == 1, err
    return lines[0]


@pytest.fixture(scope="module")
def pitch(tmp_path_factory):
    """A pitch-only config (mapping and file) and its simulated flight as an mcap and a sqlite3 bag."""
    root = tmp_path_factory.mktemp("robust")
    data = single_channel("pitch")
    config = config_from(data)
    flight = simulate_flight(config, {}, PITCH, seed=3)
    write_flight(flight, root / "bag")
    write_flight(flight, root / "db", "sqlite3")
    return {"root": root, "data": data, "config": config, "path": write_config(data, root / "pitch.yaml"),
            "flight": flight, "mcap": next((root / "bag").glob("*.mcap")),
            "db3": next((root / "db").glob("*.db3"))}


def variant(pitch, tmp_path, mutate) -> str:
    """Write a mutated copy of the pitch config; return its path."""
    data = copy.deepcopy(pitch["data"])
    mutate(data["channels"]["pitch"])
    return str(write_config(data, tmp_path / "variant.yaml"))


def replay_cli(bag, config, *extra) -> int:
    return main(["replay", str(bag), "--config", str(config), "--no-history", "--no-progress", *extra])


# ------------------------------------------------------------------------------------------------ config
def test_malformed_yaml_names_file_and_line(pitch, tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("channels:\n  pitch:\n    input: {topic: /a\n    output: x\n")
    assert replay_cli(pitch["root"] / "bag", bad) == 2
    line = one_error_line(capsys)
    assert str(bad) in line and "line 4" in line


@pytest.mark.parametrize("mutate, needles", [
    (lambda ch: ch.update(colour="red"), ["channels.pitch.colour", "unknown key"]),
    (lambda ch: ch.update(frequencies={"count": "many"}), ["channels.pitch.frequencies.count", "'many'"]),
    (lambda ch: ch.update(coherence_threshold=[0.5]), ["coherence_threshold"]),
    (lambda ch: ch["input"].update(scale="x"), ["channels.pitch.input.scale"]),
    (lambda ch: ch.update(estimator={"max_gap_s": -1}), ["max_gap_s", "-1"]),
])
def test_unknown_keys_and_wrong_types_are_named(pitch, tmp_path, capsys, mutate, needles):
    assert replay_cli(pitch["root"] / "bag", variant(pitch, tmp_path, mutate)) == 2
    line = one_error_line(capsys)
    assert all(n in line for n in needles), line


@pytest.mark.parametrize("effect, key", [
    ({"type": "time_delay", "seconds": -0.05}, "seconds"),
    ({"type": "time_delay", "seconds": 45.0}, "seconds"),                 # 45 s: ms written as s?
    ({"type": "first_order_lag", "bandwidth_rad_s": 1e300}, "bandwidth_rad_s"),
    ({"type": "second_order_lag", "natural_frequency_rad_s": 30.0, "damping": 1e4}, "damping"),
    ({"type": "gain", "factor": 0.0}, "factor"),
    ({"type": "gain", "factor": 1e9}, "factor"),
    ({"type": "time_delay", "seconds": float("nan")}, "seconds"),
])
def test_negative_or_absurd_effect_parameters_are_refused(pitch, tmp_path, capsys, effect, key):
    path = variant(pitch, tmp_path, lambda ch: ch["model"].update(effects=[effect]))
    assert replay_cli(pitch["root"] / "bag", path) == 2
    line = one_error_line(capsys)
    assert f"channels.pitch.model.effects[0].{key}" in line or "effects[0]" in line and key in line, line


@pytest.mark.parametrize("model, needle", [
    ({"numerator": [1.0, 2.0, 3.0], "denominator": [1.0, 2.0]}, "improper"),
    ({}, "expected exactly one of"),
    ({"numerator": [1.0], "denominator": [0.0, 0.0]}, "denominator"),
    ({"numerator": [], "denominator": [1.0, 1.0]}, "numerator"),
    ({"zeros": [], "poles": [[1, 2]], "gain": 1.0}, "poles"),
])
def test_improper_or_empty_models_are_refused(pitch, tmp_path, capsys, model, needle):
    path = variant(pitch, tmp_path, lambda ch: ch.update(model=model))
    assert main(["compare-models", str(pitch["path"]), path]) == 2
    line = one_error_line(capsys)
    assert path in line and "channels.pitch.model" in line and needle in line, line


def test_field_the_message_lacks_lists_the_fields_it_has(pitch, tmp_path, capsys):
    path = variant(pitch, tmp_path, lambda ch: ch["output"].update(field="angular_velocity.w"))
    assert replay_cli(pitch["root"] / "bag", path) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert "has no field 'angular_velocity.w' (angular_velocity has: x, y, z)" in err
    assert "sensor_msgs/msg/Imu" in err


def test_field_missing_at_the_top_lists_the_message_fields(pitch, tmp_path, capsys):
    path = variant(pitch, tmp_path, lambda ch: ch["output"].update(field="angular_rate.y"))
    assert replay_cli(pitch["root"] / "bag", path) == 1
    err = capsys.readouterr().err
    assert "has no field 'angular_rate' (has: header, orientation" in err and "angular_velocity" in err


def test_topic_the_bag_lacks_lists_the_topics_it_has(pitch, tmp_path, capsys):
    path = variant(pitch, tmp_path, lambda ch: ch["output"].update(topic="/imu2"))
    assert replay_cli(pitch["root"] / "bag", path) == 1
    err = capsys.readouterr().err
    assert "topic /imu2 (pitch.output) is not in the bag (it has: /control_surfaces, /imu)" in err


def test_joint_name_never_seen_is_named_with_the_names_seen(pitch, tmp_path, capsys):
    path = variant(pitch, tmp_path, lambda ch: ch["input"].update(field="position[elevatr]"))
    assert replay_cli(pitch["root"] / "bag", path) == 1
    err = capsys.readouterr().err
    assert "no joint 'elevatr' in message (names: elevator)" in err and "no usable sample" in err


# ------------------------------------------------------------------------------------------------ bags
def test_missing_and_empty_bags_are_one_line_exit_1(pitch, tmp_path, capsys):
    assert replay_cli(tmp_path / "nowhere", pitch["path"]) == 1
    assert "nowhere: no such bag" in one_error_line(capsys)
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    assert replay_cli(empty, pitch["path"]) == 1
    assert "empty.mcap: cannot read bag" in one_error_line(capsys)
    (tmp_path / "emptydir").mkdir()
    assert replay_cli(tmp_path / "emptydir", pitch["path"]) == 1
    assert "not a rosbag2 directory" in one_error_line(capsys)


@pytest.mark.parametrize("fraction", [0.6, 0.93])
def test_truncated_mcap_validates_what_was_recorded_before(pitch, tmp_path, capsys, fraction):
    data = pitch["mcap"].read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * fraction)])
    out = tmp_path / "out.json"
    assert replay_cli(cut, pitch["path"], "--json", str(out)) == 1
    line = one_error_line(capsys)
    assert f"{cut}: truncated at byte" in line and "validated the" in line, line
    validated_s = float(line.split("validated the ")[1].split(" s")[0])
    whole_s = pitch["flight"].duration_s
    assert 0.3 * fraction * whole_s < validated_s < whole_s
    pitch_json = json.loads(out.read_text())["channels"]["pitch"]
    assert pitch_json["sweeps"] >= 1 and pitch_json["epsilon"] is not None


def test_truncated_mcap_recovers_exactly_the_records_before_the_cut(pitch, tmp_path):
    """The salvaged records are the intact file's first records, byte for byte, and then a DataError."""
    from gap_validation.bag.reader import open_bag
    from gap_validation.core.errors import DataError

    data = pitch["mcap"].read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.8)])
    topics = ["/imu", "/control_surfaces"]
    got = []
    with open_bag(cut) as bag:
        assert set(bag.topics) == set(topics) and bag.damage is not None
        with pytest.raises(DataError, match="truncated at byte"):
            for topic, _, t_ns, raw in bag.records(topics):
                got.append((topic, t_ns, bytes(raw)))
    with open_bag(pitch["mcap"]) as bag:
        whole = [(topic, t_ns, bytes(raw)) for topic, _, t_ns, raw in bag.records(topics)]
    assert 0.5 * len(whole) < len(got) < len(whole)
    assert got == whole[: len(got)]


def test_corrupted_mcap_chunk_stops_there_and_keeps_the_rest(pitch, tmp_path, capsys):
    data = bytearray(pitch["mcap"].read_bytes())
    start = int(len(data) * 0.7)
    data[start:start + 2000] = bytes(2000)                          # zeroed bytes inside a chunk
    bad = tmp_path / "zeroed.mcap"
    bad.write_bytes(bytes(data))
    assert replay_cli(bad, pitch["path"]) == 1
    line = one_error_line(capsys)
    assert str(bad) in line and "validated the" in line, line


def test_corrupted_sqlite3_keeps_the_rows_before_the_damage(pitch, tmp_path, capsys):
    data = bytearray(pitch["db3"].read_bytes())
    start = len(data) // 2
    data[start:start + 8192] = b"\xab" * 8192
    bad = tmp_path / "corrupt.db3"
    bad.write_bytes(bytes(data))
    out = tmp_path / "out.json"
    assert replay_cli(bad, pitch["path"], "--json", str(out)) == 1
    line = one_error_line(capsys)
    assert str(bad) in line and "damaged at message row" in line and "validated the" in line, line
    assert json.loads(out.read_text())["channels"]["pitch"]["sweeps"] >= 1


def test_truncated_sqlite3_is_a_clear_error(pitch, tmp_path, capsys):
    data = pitch["db3"].read_bytes()
    bad = tmp_path / "cut.db3"
    bad.write_bytes(data[: len(data) // 2])
    assert replay_cli(bad, pitch["path"]) == 1
    line = one_error_line(capsys)
    assert f"{bad}: cannot read bag" in line and "nothing recoverable" in line


def test_unknown_message_type_is_named(pitch, tmp_path, capsys):
    bad = tmp_path / "weird.db3"
    shutil.copy(pitch["db3"], bad)
    with sqlite3.connect(bad) as con:
        con.execute("UPDATE topics SET type = 'acme_msgs/msg/Gyro' WHERE name = '/imu'")
    assert replay_cli(bad, pitch["path"]) == 1
    err = capsys.readouterr().err
    assert (
        "Traceback" not in err and "unknown message type acme_msgs/msg/Gyro" in err and "topic skipped" in err
    )
    assert "damaged record" not in err


def test_one_damaged_bag_never_costs_the_others(pitch, tmp_path):
    data = pitch["mcap"].read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    both = replay([pitch["root"] / "bag", cut, tmp_path / "missing"], pitch["config"], diagnose=False)
    alone = replay([pitch["root"] / "bag"], pitch["config"], diagnose=False)
    assert len(both.errors) == 2
    assert both.result.channels["pitch"].sweeps > alone.result.channels["pitch"].sweeps


# ------------------------------------------------------------------------------------------------ samples
def _looped(flight):
    """The flight recorded twice in one bag: bag time goes on, header stamps start over (a looped replay)."""
    topics = {}
    for name, series in flight.topics.items():
        shift = flight.duration_s + 5.0
        topics[name] = dataclasses.replace(
            series, stamp_s=np.concatenate((series.stamp_s, series.stamp_s)),
            receive_s=np.concatenate((series.receive_s, series.receive_s + shift)),
            values={k: np.concatenate((v, v)) for k, v in series.values.items()})
    return dataclasses.replace(flight, topics=topics)


def test_looped_bag_validates_both_laps(pitch, tmp_path):
    write_flight(_looped(pitch["flight"]), tmp_path / "looped")
    once = replay([pitch["root"] / "bag"], pitch["config"], diagnose=False).result.channels["pitch"]
    twice = replay([tmp_path / "looped"], pitch["config"], diagnose=False).result.channels["pitch"]
    assert once.sweeps == PITCH.sweeps_per_channel
    assert twice.sweeps == 2 * once.sweeps
    assert twice.bad_samples.get("input: time jumped back (new segment)") == 1
    assert twice.bad_samples.get("output: time jumped back (new segment)") == 1
    assert not any("not increasing" in k for k in twice.bad_samples)
    # the same data twice: the same spectra twice (the pooled response equals one lap's)
    assert np.allclose(twice.measured, once.measured, rtol=1e-9, equal_nan=True)


def _flight_with(config, mutate, seed=5, options=TRIO):
    flight = simulate_flight(config, {}, options, seed=seed)
    series = flight.topics["/control_surfaces"]
    values = {k: v.copy() for k, v in series.values.items()}
    mutate(values)
    topics = dict(flight.topics)
    topics["/control_surfaces"] = dataclasses.replace(series, values=values)
    return dataclasses.replace(flight, topics=topics)


def test_channel_never_excited_says_no_sweep_found_and_the_others_validate(tmp_path, capsys):
    config = ultrastick()

    def no_roll(values):
        values["position[aileron]"][:] = values["position[aileron]"][0]

    write_flight(_flight_with(config, no_roll), tmp_path / "bag")
    path = tmp_path / "us.yaml"
    shutil.copy(ultrastick().source, path)
    out = tmp_path / "out.json"
    code = replay_cli(tmp_path / "bag", path, "--json", str(out))
    assert code == 0, capsys.readouterr().err
    text = capsys.readouterr().out
    assert "roll: no sweep found" in text
    channels = json.loads(out.read_text())["channels"]
    assert channels["roll"]["message"].startswith("no sweep found: ") and channels["roll"]["epsilon"] is None
    for name in ("pitch", "yaw"):
        assert channels[name]["sweeps"] == 1 and channels[name]["epsilon"] is not None, name


def test_saturated_surface_is_reported_in_the_channel(pitch, tmp_path):
    trim = float(np.median(pitch["flight"].topics["/control_surfaces"].values["position[elevator]"]))

    def clip(values):
        v = values["position[elevator]"]
        reach = np.max(np.abs(v - trim))
        values["position[elevator]"] = np.clip(v, trim - 0.5 * reach, trim + 0.5 * reach)

    flight = _flight_with(pitch["config"], clip, seed=3, options=PITCH)
    write_flight(flight, tmp_path / "clipped")
    outcome = replay([tmp_path / "clipped"], pitch["config"], diagnose=False)
    ch = outcome.result.channels["pitch"]
    assert any("pinned at its maximum" in w for w in outcome.warnings)
    assert "saturated surface" in ch.message
    assert ch.bad_samples.get("input: saturated at maximum", 0) > 25
    assert ch.bad_samples.get("input: saturated at minimum", 0) > 25


def test_unsaturated_flight_raises_no_saturation_warning(pitch):
    outcome = replay([pitch["root"] / "bag"], pitch["config"], diagnose=False)
    assert not any("pinned" in w for w in outcome.warnings)
    assert not any("saturated" in k for k in outcome.result.channels["pitch"].bad_samples)


# ------------------------------------------------------------------------------------------------ models
def test_unstable_and_marginally_stable_models_validate(pitch, tmp_path):
    for den in ([1.0, -23.37, 235.93], [1.0, 0.0, 235.93], [1.0, 23.37, 0.0]):
        data = copy.deepcopy(pitch["data"])
        data["channels"]["pitch"]["model"] = {"numerator": [-133.7, -990.76], "denominator": den}
        ch = replay([pitch["root"] / "bag"], config_from(data), diagnose=False).result.channels["pitch"]
        assert ch.epsilon is not None and np.isfinite(ch.epsilon), den
        assert 0.0 <= ch.nu_gap <= 1.0 and np.all(np.isfinite(ch.kappa)), den


def test_epsilon_at_least_one_gives_null_margins_with_the_reason(pitch, tmp_path):
    data = copy.deepcopy(pitch["data"])
    data["channels"]["pitch"]["model"]["effects"] = [{"type": "time_delay", "seconds": 0.2}]
    out = tmp_path / "out.json"
    assert (
        replay_cli(pitch["root"] / "bag", write_config(data, tmp_path / "late.yaml"), "--json", str(out)) == 0
    )
    ch = json.loads(out.read_text())["channels"]["pitch"]
    assert ch["epsilon"] >= 1
    assert ch["gain_margin_db"] is None and ch["phase_margin_deg"] is None and ch["disk_margin"] is None
    assert ch["margins_note"].startswith("epsilon ") and ">= 1" in ch["margins_note"]
    fine = tmp_path / "fine.json"
    assert replay_cli(pitch["root"] / "bag", pitch["path"], "--json", str(fine)) == 0
    assert json.loads(fine.read_text())["channels"]["pitch"]["margins_note"] is None


def test_winding_number_failure_gives_nu_gap_one_with_the_reason(tmp_path, capsys):
    def model_file(name, den):
        data = {"channels": {"pitch": {"input": {"topic": "/a", "field": "data"},
                                       "output": {"topic": "/b", "field": "data"},
                                       "model": {"numerator": [1.0], "denominator": den}}}}
        return str(write_config(data, tmp_path / name))

    out = tmp_path / "out.json"
    assert main(["compare-models", model_file("a.yaml", [1.0, 2.0]), model_file("b.yaml", [1.0, -2.0]),
                 "--json", str(out)]) == 0
    text = capsys.readouterr().out
    ch = json.loads(out.read_text())["channels"]["pitch"]
    assert ch["nu_gap"] == 1.0 and "winding-number condition fails" in ch["nu_gap_note"]
    assert "pitch: winding-number condition fails" in text
    assert ch["gain_margin_db"] is None and ch["margins_note"]


def test_one_bad_channel_never_costs_the_others(tmp_path, capsys):
    """roll's output names a field the IMU lacks: roll is reported and skipped, pitch and yaw (same topic)
    are validated."""
    config = ultrastick()
    write_flight(simulate_flight(config, {}, TRIO, seed=5), tmp_path / "bag")
    data = copy.deepcopy(config.raw)
    data["channels"]["roll"]["output"]["field"] = "angular_velocity.p"
    out = tmp_path / "out.json"
    assert replay_cli(tmp_path / "bag", write_config(data, tmp_path / "cfg.yaml"), "--json", str(out)) == 1
    err = capsys.readouterr().err
    assert "has no field 'angular_velocity.p' (angular_velocity has: x, y, z); roll.output skipped" in err
    channels = json.loads(out.read_text())["channels"]
    assert channels["roll"]["sweeps"] == 0
    for name in ("pitch", "yaw"):
        assert channels[name]["sweeps"] == 1 and channels[name]["epsilon"] is not None, name


def test_truncated_mcap_inside_a_rosbag2_directory_names_the_file(pitch, tmp_path):
    bag = tmp_path / "bag"
    shutil.copytree(pitch["root"] / "bag", bag)
    mcap = next(bag.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[: int(mcap.stat().st_size * 0.7)])
    outcome = replay([bag], pitch["config"], diagnose=False)
    assert len(outcome.errors) == 1 and outcome.errors[0].startswith(f"{mcap}: truncated at byte")
    assert outcome.result.channels["pitch"].sweeps >= 1
