"""Replay (gap_validation.bag.replay and ``gap-validate replay|simulate``): simulate -> bag -> replay round
trips."""
import contextlib
import io
import json
import math

import numpy as np
import pytest
from _flights import CONFIG_PATH, SHORT, config_from, make_bag, single_channel, ultrastick, write_config
from scipy import interpolate, signal

from gap_validation.bag.reader import open_bag
from gap_validation.bag.replay import replay
from gap_validation.cli.main import main
from gap_validation.core.errors import DataError
from gap_validation.core.fields import FieldPath
from gap_validation.core.simulation import FlightOptions, with_options
from gap_validation.messages.router import stamp_seconds

#: The full test card (3 sweeps of 120 s per axis, about 20 minutes) with the IMU at 50 Hz like the paper's
#: lab.
FULL = FlightOptions(imu_rate_hz=50.0)
#: Pitch-only flights for the many variant tests: short, and pitch is well conditioned.
PITCH = with_options(SHORT, sweeps_per_channel=2, sweep_duration_s=60.0, quiet_s=8.0)


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    root = tmp_path_factory.mktemp("replay")
    clean = make_bag(root / "clean", seed=0, options=FULL)
    late = make_bag(root / "late", hidden=["pitch:time_delay:seconds=0.04"], seed=0, options=FULL)
    return {"root": root, "clean": root / "clean", "late": root / "late", "clean_flight": clean,
            "late_flight": late}


@pytest.fixture(scope="module")
def clean_outcome(bags):
    return replay([bags["clean"]], ultrastick())


@pytest.fixture(scope="module")
def pitch_config():
    return config_from(single_channel("pitch"))


@pytest.fixture(scope="module")
def pitch_bag(tmp_path_factory, pitch_config):
    path = tmp_path_factory.mktemp("pitch") / "pitch"
    flight = make_bag(path, config=pitch_config, seed=7, options=PITCH)
    return path, flight


# ------------------------------------------------------------------------------------------- round trips
def test_clean_flight_validates_every_channel(clean_outcome):
    assert clean_outcome.ok and not clean_outcome.warnings
    for name, ch in clean_outcome.result.channels.items():
        assert ch.sweeps == FULL.sweeps_per_channel, name
        assert ch.epsilon is not None and ch.epsilon < 0.15, (name, ch.epsilon)
        assert ch.points_used >= 35, name


def test_hidden_pitch_delay_flags_pitch_only(bags):
    result = replay([bags["late"]], ultrastick()).result
    eps = {name: ch.epsilon for name, ch in result.channels.items()}
    assert eps["pitch"] > 0.5
    assert eps["roll"] < 0.15 and eps["yaw"] < 0.15
    # 40 ms at the top of the grid: epsilon(w) = tan(w T / 2) = 1.02 at 40 rad/s for a pure delay (eq. 14)
    assert result.channels["pitch"].worst_frequency_rad_s == pytest.approx(40.0)
    assert eps["pitch"] == pytest.approx(math.tan(40.0 * 0.04 / 2), abs=0.1)


def test_measured_response_matches_truth_within_error_bounds(clean_outcome, bags):
    """Averaged estimate against the true model: within 3 random errors (Bendat and Piersol) plus 3 %."""
    truth = bags["clean_flight"].truth
    for name, ch in clean_outcome.result.channels.items():
        ok = ch.confident
        rel = np.abs(ch.measured[ok] / truth[name].freqresp(ch.frequency_rad_s[ok]) - 1.0)
        bound = 3.0 * ch.random_error[ok] + 0.03
        assert np.mean(rel <= bound) >= 0.9, (name, rel.max())


def _samples(bag, spec):
    path = FieldPath.parse(spec.field)
    t, v = [], []
    with open_bag(bag) as b:
        for _, msg, bag_time in b.messages([spec.topic]):
            stamp = stamp_seconds(msg)
            t.append(bag_time if stamp is None else stamp)
            v.append(path.extract(msg) * spec.scale)
    return np.asarray(t), np.asarray(v)


def test_replay_agrees_with_a_scipy_batch_estimate_on_the_same_samples(bags, clean_outcome):
    """Independent batch estimate: the bag's samples, cubic-spline aligned on a 100 Hz grid, cut to the sweeps
    the replay detected, each sweep's whole-record cross and auto spectra from ``scipy.signal.csd``/``welch``
    (one rectangular segment, the record's own resolution), summed over the bins within 10 % of each analysis
    frequency and over sweeps (H1 = Gxy/Gxx, the smoothed ETFE). The replay's local polynomial estimate
    removes the transients this reference keeps, so the two agree within the replay's random error plus a few
    percent."""
    config = ultrastick()
    channel = config.channels["pitch"]
    result = clean_outcome.result.channels["pitch"]
    tx, x = _samples(bags["clean"], channel.input)
    ty, y = _samples(bags["clean"], channel.output)
    fs = 100.0
    w = result.frequency_rad_s
    spans = [(s.start_s, s.end_s) for s in result.sweep_results]
    assert len(spans) == 3
    fx, fy = interpolate.CubicSpline(tx, x), interpolate.CubicSpline(ty, y)
    pxy, pxx = np.zeros(w.size, complex), np.zeros(w.size)
    for start, end in spans:
        grid = np.arange(math.ceil(start * fs), math.floor(end * fs)) / fs
        xs, ys = fx(grid), fy(grid)
        f, gxy = signal.csd(xs, ys, fs=fs, window="boxcar", nperseg=grid.size, detrend="constant")
        _, gxx = signal.welch(xs, fs=fs, window="boxcar", nperseg=grid.size, detrend="constant")
        for i, wi in enumerate(w):
            band = np.abs(2 * math.pi * f - wi) <= 0.1 * wi
            pxy[i] += gxy[band].sum()
            pxx[i] += gxx[band].sum()
    h = pxy / pxx
    ok = result.confident
    assert np.count_nonzero(ok) >= 0.8 * w.size
    rel = np.abs(result.measured[ok] / h[ok] - 1.0)
    assert np.all(rel <= 3.0 * result.random_error[ok] + 0.05), rel.max()
    assert np.median(rel) < 0.03


# ------------------------------------------------------------------------------------------- storages,
# variants
def test_mcap_sqlite3_bare_files_and_full_decode_agree(tmp_path, pitch_config, pitch_bag):
    path, flight = pitch_bag
    from gap_validation.bag.writer import write_flight

    reference = replay([path], pitch_config).result.to_json_dict()
    assert reference["channels"]["pitch"]["epsilon"] < 0.15
    others = [write_flight(flight, tmp_path / "sql", "sqlite3"), write_flight(flight, tmp_path / "f.db3"),
              write_flight(flight, tmp_path / "f.mcap")]
    for bag in others:
        assert replay([bag], pitch_config).result.to_json_dict()["channels"] == reference["channels"], bag
    full = replay([path], pitch_config, fast=False)
    assert full.result.to_json_dict()["channels"] == reference["channels"]
    fast = replay([path], pitch_config)
    assert fast.bags[0].fast_topics == ["/control_surfaces", "/imu"] and full.bags[0].fast_topics == []


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_batched_replay_gives_the_record_by_record_result(tmp_path, monkeypatch, storage):
    """Replay reads records in batches and decodes them at once (TopicDecoder.decode_batch): the JSON is the
    one of the record-by-record replay (every record through TopicDecoder.decode and MessageRouter.on_values,
    as before batching) and of full deserialisation, to the bit, on a 1 kHz flight of three channels."""
    from gap_validation.messages.decoding import TopicDecoder
    from gap_validation.messages.router import MessageRouter

    bag = tmp_path / "flight"
    make_bag(
        bag,
        seed=3,
        storage=storage,
        options=with_options(
            SHORT, sweeps_per_channel=1, sweep_duration_s=30.0, imu_rate_hz=1000.0, surface_rate_hz=100.0
        ),
    )
    config = ultrastick()
    batched_messages = []
    run = MessageRouter.on_values_batch
    monkeypatch.setattr(MessageRouter, "on_values_batch",
                        lambda self, topics, which, *rest: batched_messages.append(len(which)) or
                        run(self, topics, which, *rest))
    batched = replay([bag], config)
    assert sum(batched_messages) > 0.9 * batched.messages          # nearly all records were read in batches
    monkeypatch.setattr(MessageRouter, "on_values_batch", run)
    full = replay([bag], config, fast=False)
    skip = TopicDecoder.decode_batch
    monkeypatch.setattr(TopicDecoder, "decode_batch", lambda self, records: tuple(
        (out if i < 2 else np.zeros_like(out)) for i, out in enumerate(skip(self, records))))
    one_by_one = replay([bag], config)
    reference = json.dumps(one_by_one.result.to_json_dict(), sort_keys=True)
    assert one_by_one.messages == batched.messages == full.messages > 100_000
    assert json.dumps(batched.result.to_json_dict(), sort_keys=True) == reference
    assert json.dumps(full.result.to_json_dict(), sort_keys=True) == reference
    assert all(ch.sweeps == 1 for ch in batched.result.channels.values())


def test_custom_topics_joint_names_and_rates(tmp_path):
    data = single_channel("pitch")
    data["channels"]["pitch"]["input"] = {"topic": "/fmu/servo_feedback", "field": "position[elev_servo]"}
    data["channels"]["pitch"]["output"] = {"topic": "/vn300/imu", "field": "angular_velocity.y"}
    config = config_from(data)
    make_bag(
        tmp_path / "custom", config=config, seed=3, options=PITCH, imu_rate_hz=200.0, surface_rate_hz=25.0
    )
    with open_bag(tmp_path / "custom") as bag:
        topics = bag.topics
    assert set(topics) == {"/fmu/servo_feedback", "/vn300/imu"}
    assert 7.0 < topics["/vn300/imu"].count / topics["/fmu/servo_feedback"].count < 9.0
    outcome = replay([tmp_path / "custom"], config)
    assert outcome.ok and outcome.result.channels["pitch"].epsilon < 0.15


def test_float64_topics_with_scale(tmp_path):
    data = single_channel("pitch")
    data["channels"]["pitch"]["input"] = {"topic": "/surfaces/elevator_deg", "field": "data",
                                          "scale": math.pi / 180.0}
    config = config_from(data)
    make_bag(tmp_path / "f64", config=config, seed=4, options=PITCH)
    with open_bag(tmp_path / "f64") as bag:
        assert bag.topics["/surfaces/elevator_deg"].msgtype == "std_msgs/msg/Float64"
        _, msg, _ = next(bag.messages(["/surfaces/elevator_deg"]))
        assert abs(msg.data) > 0.3  # degrees in the message (trim offset and noise), not radians
    outcome = replay([tmp_path / "f64"], config)
    assert outcome.ok and outcome.result.channels["pitch"].epsilon < 0.15
    wrong = config_from(single_channel("pitch", input={"topic": "/surfaces/elevator_deg", "field": "data"}))
    assert replay([tmp_path / "f64"], wrong).result.channels["pitch"].epsilon > 0.9  # missing deg->rad scale


def test_an_airspeed_topic_is_read_and_its_ratio_reported(tmp_path):
    """The ``airspeed`` stream through the one data path (bag -> router -> estimator): the simulator's
    airframe flies at the model's condition, so the dynamic pressure ratio is 1 and the estimate that of the
    plain channel; a trim airspeed 20 % above the flown one reads the flight as 0.69 of it and scales the
    surface by that: the response comes out 1.44 times too small and the verdict says so."""
    airspeed = {"topic": "/air_data/airspeed", "field": "data", "trim_m_s": 19.0}
    data = single_channel("pitch", airspeed=airspeed)
    config = config_from(data)
    make_bag(tmp_path / "air", config=config, seed=4, options=PITCH)
    with open_bag(tmp_path / "air") as bag:
        assert bag.topics["/air_data/airspeed"].msgtype == "std_msgs/msg/Float64"
    held = replay([tmp_path / "air"], config).result.channels["pitch"]
    ratio = held.to_json_dict()["dynamic_pressure_ratio"]
    assert ratio["clipped"] == 0 and all(
        ratio[k] == pytest.approx(1.0, abs=1e-12) for k in ("mean", "min", "max")
    )
    plain = replay([tmp_path / "air"], config_from(single_channel("pitch"))).result.channels["pitch"]
    assert plain.to_json_dict()["dynamic_pressure_ratio"] is None
    assert held.epsilon == pytest.approx(plain.epsilon, rel=1e-6, abs=1e-9) and held.epsilon < 0.15
    fast = config_from(single_channel("pitch", airspeed={**airspeed, "trim_m_s": 22.8}))
    off = replay([tmp_path / "air"], fast).result.channels["pitch"]
    assert off.dynamic_pressure_ratio["mean"] == pytest.approx((19.0 / 22.8) ** 2)
    assert off.limited_by == "model" and off.epsilon > 0.15
    lines = "\n".join(main_lines(tmp_path, data))
    assert "flown at 1.00-1.00 of the model's dynamic pressure (mean 1.00, from the airspeed)" in lines


def main_lines(tmp_path, data: dict) -> list[str]:
    path = write_config(data, tmp_path / "air.yaml")
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert (
            main(["replay", str(tmp_path / "air"), "--config", str(path), "--no-history", "--no-progress"])
            == 0
        )
    return out.getvalue().splitlines()


def test_trigger_topic_defines_the_sweeps(tmp_path):
    config = config_from(single_channel("pitch", trigger={"topic": "/test_point/active", "field": "data"}))
    flight = make_bag(tmp_path / "trig", config=config, seed=5, options=PITCH)
    result = replay([tmp_path / "trig"], config).result.channels["pitch"]
    assert result.sweeps == PITCH.sweeps_per_channel
    for measured, true in zip(result.sweep_results, flight.sweeps("pitch")):
        assert measured.start_s - flight.start_time_s == pytest.approx(true.start_s, abs=0.1)
        assert measured.end_s - flight.start_time_s == pytest.approx(true.end_s, abs=0.1)


def test_several_bags_add_their_sweeps(tmp_path, pitch_config):
    one = with_options(PITCH, sweeps_per_channel=1)
    paths = [tmp_path / "a", tmp_path / "b.mcap", tmp_path / "c.db3"]
    for seed, path in enumerate(paths):
        make_bag(path, config=pitch_config, seed=10 + seed, options=one)  # all three start at the same epoch
    single = replay(paths[:1], pitch_config).result.channels["pitch"]
    outcome = replay(paths, pitch_config)
    combined = outcome.result.channels["pitch"]
    assert outcome.ok and single.sweeps == 1 and combined.sweeps == 3
    assert sorted(b.time_offset_s > 0 for b in outcome.bags) == [False, True, True]  # clocks overlap: shifted
    both = combined.confident & single.confident      # compare on the same frequencies
    assert both.any()
    assert combined.random_error[both].mean() < single.random_error[both].mean()
    assert combined.epsilon < 0.15 and outcome.result.sources == [str(p) for p in paths]


# ------------------------------------------------------------------------------------------- bad inputs
def test_one_unreadable_bag_among_several_keeps_the_rest(tmp_path, pitch_bag, pitch_config):
    path, _ = pitch_bag
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"\x89MCAP0\r\n" + bytes(100))
    outcome = replay([path, tmp_path / "missing", junk], pitch_config)
    assert outcome.result.channels["pitch"].sweeps == PITCH.sweeps_per_channel
    assert len(outcome.errors) == 2
    assert str(tmp_path / "missing") in outcome.errors[0] and str(junk) in outcome.errors[1]
    assert all("\n" not in e for e in outcome.errors)


def _copy_with_damaged_records(src, dst, damage):
    """Copy bag ``src`` to ``dst`` with the records whose 1-based numbers are in ``damage`` cut to 20
    bytes."""
    from rosbags.rosbag2 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(src) as reader, Writer(dst, version=Writer.VERSION_LATEST) as writer:
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=store) for c in reader.connections}
        for number, (conn, stamp, raw) in enumerate(reader.messages(), start=1):
            writer.write(conns[conn.id], stamp, bytes(raw)[:20] if number in damage else raw)


@pytest.mark.parametrize("fast", [True, False])
def test_damaged_record_is_skipped_and_the_rest_of_the_bag_kept(tmp_path, pitch_bag, pitch_config, fast):
    path, _ = pitch_bag
    damaged = tmp_path / "damaged"
    _copy_with_damaged_records(path, damaged, {3, 2000, 2001})   # the first while verifying the fast path
    outcome = replay([damaged], pitch_config, fast=fast, diagnose=False)
    clean = replay([path], pitch_config, fast=fast, diagnose=False)
    pitch = outcome.result.channels["pitch"]
    assert pitch.sweeps == clean.result.channels["pitch"].sweeps == PITCH.sweeps_per_channel
    assert abs(pitch.epsilon - clean.result.channels["pitch"].epsilon) < 0.01
    assert sum(v for k, v in pitch.bad_samples.items() if "undecodable" in k) == 3
    assert len(outcome.errors) == 2 and all("\n" not in e and "damaged record" in e for e in outcome.errors)
    assert any("/imu" in e for e in outcome.errors) and any("/control_surfaces" in e for e in outcome.errors)


def test_only_bad_bags_raise_data_error(tmp_path, pitch_config):
    with pytest.raises(DataError) as err:
        replay([tmp_path / "missing"], pitch_config)
    assert str(tmp_path / "missing") in str(err.value) and "\n" not in str(err.value)


def test_missing_topic_warns_and_no_topic_is_an_error(pitch_bag):
    path, _ = pitch_bag
    data = single_channel("pitch")
    data["channels"]["roll"] = dict(ultrastick().raw["channels"]["roll"])
    data["channels"]["roll"]["output"] = {"topic": "/imu_roll", "field": "angular_velocity.x"}
    outcome = replay([path], config_from(data))
    assert any("/imu_roll" in w and "not in the bag" in w for w in outcome.warnings)
    assert outcome.result.channels["pitch"].sweeps == PITCH.sweeps_per_channel
    nothing = config_from(single_channel("pitch", input={"topic": "/a", "field": "data"},
                                         output={"topic": "/b", "field": "data"}))
    with pytest.raises(DataError) as err:
        replay([path], nothing)
    assert "/a" in str(err.value) and "/imu" in str(err.value)


@pytest.mark.parametrize("change, needles", [
    ({"output": {"topic": "/imu", "field": "angular_velocity.w"}}, ["/imu", "angular_velocity.w"]),
    ({"input": {"topic": "/control_surfaces", "field": "position[flap]"}}, ["flap", "/control_surfaces"]),
    ({"input": {"topic": "/control_surfaces", "field": "position[elevator]", "type": "sensor_msgs/msg/Imu"}},
     ["/control_surfaces", "sensor_msgs/msg/JointState", "sensor_msgs/msg/Imu"]),
    ({"input": {"topic": "/imu", "field": "position[elevator]"}}, ["/imu", "position"]),
])
def test_bad_fields_give_one_line_errors(pitch_bag, change, needles):
    path, _ = pitch_bag
    outcome = replay([path], config_from(single_channel("pitch", **change)))
    assert outcome.errors
    text = outcome.errors[0]
    assert "\n" not in text and all(n in text for n in needles), text


# ------------------------------------------------------------------------------------------- CLI
def test_cli_replay_table_and_json(tmp_path, pitch_bag, capsys):
    path, _ = pitch_bag
    config = write_config(single_channel("pitch"), tmp_path / "pitch.yaml")
    out = tmp_path / "out.json"
    assert main(["replay", str(path), "--config", str(config), "--json", str(out)]) == 0
    captured = capsys.readouterr()
    assert captured.out.splitlines()[0].split()[:3] == ["channel", "nu-gap", "epsilon"]
    data = json.loads(out.read_text())
    pitch = data["channels"]["pitch"]
    for key in (
        "nu_gap",
        "epsilon",
        "epsilon_raw",
        "worst_frequency_rad_s",
        "sweeps",
        "coherence",
        "measured",
    ):
        assert key in pitch
    assert pitch["sweeps"] == PITCH.sweeps_per_channel and data["sources"] == [str(path)]


def test_cli_replay_bad_bag_exit_1_results_kept(tmp_path, pitch_bag, capsys):
    path, _ = pitch_bag
    config = write_config(single_channel("pitch"), tmp_path / "pitch.yaml")
    out = tmp_path / "out.json"
    status = main(["replay", str(path), str(tmp_path / "nope"), "--config", str(config), "--json", str(out)])
    assert status == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(tmp_path / "nope") in err[0] and "Traceback" not in err[0]
    assert json.loads(out.read_text())["channels"]["pitch"]["sweeps"] == PITCH.sweeps_per_channel
    assert main(["replay", str(tmp_path / "nope"), "--config", str(config)]) == 1
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


@pytest.mark.parametrize("option, target, needle", [
    ("--json", "missing/out.json", "does not exist"),
    ("--json", ".", "is a directory"),
    ("--apply-diagnosis", "missing/fixed.yaml", "does not exist"),
    ("--report", "file.txt/report", "is a file"),
])
def test_cli_unwritable_output_is_refused_before_the_replay(tmp_path, pitch_bag, capsys, monkeypatch, option,
                                                            target, needle):
    import gap_validation.cli.replay as command

    path, _ = pitch_bag
    config = write_config(single_channel("pitch"), tmp_path / "pitch.yaml")
    (tmp_path / "file.txt").write_text("")
    monkeypatch.setattr(
        command, "replay", lambda *a, **k: pytest.fail("replayed before checking the outputs")
    )
    assert main(["replay", str(path), "--config", str(config), "--no-history", option,
                 str(tmp_path / target)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and option in err and needle in err, err


def test_cli_bad_config_exit_2(tmp_path, pitch_bag, capsys):
    path, _ = pitch_bag
    bad = tmp_path / "bad.yaml"
    bad.write_text("channels: {pitch: {input: {topic: /a, field: 'a..b'}}}")
    assert main(["replay", str(path), "--config", str(bad)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_cli_report_hook(tmp_path, pitch_bag, capsys, monkeypatch):
    import importlib.util

    from gap_validation.cli import replay as command

    path, _ = pitch_bag
    config = write_config(single_channel("pitch"), tmp_path / "pitch.yaml")
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "gap_validation.report.html" else real(name, *a))
    assert main(["replay", str(path), "--config", str(config), "--report", str(tmp_path / "r")]) == 2
    assert "report not available" in capsys.readouterr().err
    monkeypatch.undo()
    calls = []
    monkeypatch.setattr(command, "_report_writer", lambda: lambda result, d, **kw: calls.append((result, d)))
    assert main(["replay", str(path), "--config", str(config), "--report", str(tmp_path / "r")]) == 0
    assert calls and calls[0][1] == str(tmp_path / "r") and "pitch" in calls[0][0].channels


def test_progress_bar_draws_on_a_stream():
    from gap_validation.cli.replay import ProgressBar

    stream = io.StringIO()
    bar = ProgressBar(stream)
    bar(50, 100)
    bar(100, 100)
    bar.close()
    text = stream.getvalue()
    assert text.startswith("\rreplay [") and "100%" in text and "100/100 msgs" in text and text.endswith("\n")


def test_cli_simulate_and_errors(tmp_path, capsys):
    out = tmp_path / "sim"
    argv = ["simulate", "--config", str(CONFIG_PATH), "--out", str(out), "--sweeps", "1", "--sweep-duration",
            "20", "--hidden", "pitch:time_delay:seconds=0.04", "--seed", "3"]
    assert main(argv) == 0
    assert "pitch: 1 chirp manoeuvre, hidden: time delay of 40 ms" in capsys.readouterr().out
    first = next(out.glob("*.mcap")).read_bytes()
    assert main(argv) == 2 and "exists already" in capsys.readouterr().err
    assert main(argv + ["--force"]) == 0
    assert next(out.glob("*.mcap")).read_bytes() == first  # same seed, same bag
    capsys.readouterr()
    for bad, part in (("pitch:time_delay:seconds=abc", "seconds=abc"), ("wing:gain:factor=2", "wing"),
                      ("pitch-time_delay", "CHANNEL:EFFECT")):
        assert main(["simulate", "--config", str(CONFIG_PATH), "--out", str(tmp_path / "x"),
                     "--hidden", bad]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and part in err
    (tmp_path / "file.txt").write_text("")
    for bad, part in (("missing/y.mcap", "does not exist"), ("file.txt/y", "is a file")):
        assert main(["simulate", "--config", str(CONFIG_PATH), "--out", str(tmp_path / bad), "--sweeps", "1",
                     "--sweep-duration", "10"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "--out" in err and part in err, err
    assert main(["simulate", "--config", str(CONFIG_PATH), "--out", str(tmp_path / "y.db3"), "--sweeps", "1",
                 "--sweep-duration", "10", "--storage", "sqlite3"]) == 0
    assert (tmp_path / "y.db3").is_file()


def test_cli_simulates_a_nasa_style_3211_run_and_replay_says_what_was_flown(tmp_path, capsys):
    """`simulate --excitation 3211 --trim-s 1 --duration-s 8` at 50 Hz: one short multistep; replay of the
    model that generated it finds a multistep, its band, and no model-limited point."""
    out = tmp_path / "nasa"
    assert main(["simulate", "--config", str(CONFIG_PATH), "--out", str(out), "--excitation", "3211",
                 "--sweeps", "1", "--trim-s", "1", "--duration-s", "8", "--multistep-unit-s", "0.5",
                 "--imu-rate-hz", "50", "--surface-rate-hz", "50", "--seed", "4"]) == 0
    text = capsys.readouterr().out
    assert "roll: 1 3211 manoeuvre, hidden: nothing" in text and "8.0 s" in text or "0.1 min" in text
    result = replay([out], ultrastick()).result.channels["roll"]
    assert result.excitation == "multistep" and result.manoeuvres_by_kind == {"multistep": 1}
    assert result.limited_by != "model" and not result.diagnosis
    low, high = result.excited_band_rad_s
    # an 8 s record resolves down to about 4.5 rad/s (7 bins of 2 pi / 8 s within 60 % of the frequency); the
    # steps excite the whole grid above
    assert 3.0 < low < 6.0 and high > 20.0, (low, high)
    with pytest.raises(SystemExit) as exit_:
        main(["simulate", "--config", str(CONFIG_PATH), "--out", str(tmp_path / "x"), "--excitation", "sine"])
    assert exit_.value.code == 2 and "invalid choice" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------
# --apply-diagnosis
def _apply(tmp_path, capsys, channels: dict, force: bool = False):
    """Run the CLI's --apply-diagnosis step on hand-made results for the Ultra Stick config; returns the
    written config (or None), stdout and stderr."""
    import yaml

    from gap_validation.cli.replay import _apply_diagnosis
    from gap_validation.core.results import ChannelResult, ValidationResult

    config = ultrastick()
    result = ValidationResult(
        channels={name: ChannelResult(name=name, **fields) for name, fields in channels.items()}
    )
    out = tmp_path / "fixed.yaml"
    _apply_diagnosis(config, result, str(out), None, force=force)
    captured = capsys.readouterr()
    return (yaml.safe_load(out.read_text()) if out.exists() else None), captured.out, captured.err


_DELAY = {
    "effect": "time_delay",
    "effects": [{"type": "time_delay", "seconds": 0.05}],
    "epsilon": 0.05,
    "sentence": "missing: time delay of 50 ms; adding it brings epsilon from 0.62 to 0.05, which explains "
                "the "
    "mismatch (the rest is within the data's errors)",
    "explains": True,
}
_MODE = {
    "effect": "structural_mode",
    "effects": [
        {
            "type": "structural_mode",
            "frequency_rad_s": 2.9,
            "damping": 0.48,
            "zero_frequency_rad_s": 3.5,
            "zero_damping": 0.5,
        }
    ],
    "epsilon": 0.09,
    "sentence": "missing: structural mode ...; but does not explain the mismatch",
    "explains": False,
}


def test_apply_diagnosis_writes_only_fixes_that_explain_a_model_limited_channel(tmp_path, capsys):
    """issue 15: a channel that fits (the backlash case: a candidate but the verdict 'model fits'), a
    data-limited one and one whose best candidate does not explain the mismatch are left as they are, each
    with a line saying why; the model-limited channel with an explaining candidate gets it."""
    written, out, err = _apply(tmp_path, capsys, {
        "roll": {"limited_by": "none", "epsilon": 0.125, "diagnosis": [_MODE]},
        "pitch": {"limited_by": "model", "epsilon": 0.62, "diagnosis": [_DELAY]},
        "yaw": {"limited_by": "model", "epsilon": 0.3, "diagnosis": [_MODE]},
    })
    channels = written["channels"]
    assert channels["pitch"]["model"]["effects"] == [{"type": "time_delay", "seconds": 0.05}]
    original = raw_config_channels()
    assert channels["roll"]["model"] == original["roll"]["model"]
    assert channels["yaw"]["model"] == original["yaw"]["model"]
    assert "  pitch: missing: time delay of 50 ms" in out
    assert "  roll: left as it is: the channel is not model-limited (limited by none); --force writes" in out
    assert (
        "  yaw: left as it is: no candidate explains the mismatch (none leaves the data within their errors; "
        "the best leaves epsilon 0.09); --force writes the top candidate anyway"
    ) in out


def test_apply_diagnosis_without_an_explaining_fix_writes_nothing_and_says_why(tmp_path, capsys):
    written, out, err = _apply(tmp_path, capsys, {
        "roll": {"limited_by": "none", "epsilon": 0.04},
        "pitch": {"limited_by": "data", "epsilon": 0.3},
        "yaw": {"limited_by": "model", "epsilon": 0.3, "diagnosis": [_MODE]},
    })
    assert written is None and out == ""
    assert "no channel has a fix that explains its mismatch; " in err and "fixed.yaml not written" in err
    assert "  roll: left as it is: the model fits (epsilon 0.04): nothing to fix" in err
    assert "  pitch: left as it is: data-limited: fly better sweeps rather than change the model" in err
    assert "  yaw: left as it is: no candidate explains the mismatch" in err


def test_apply_diagnosis_force_writes_the_top_candidate_and_says_what_it_does_not_do(tmp_path, capsys):
    written, out, err = _apply(tmp_path, capsys, {
        "roll": {"limited_by": "none", "epsilon": 0.125, "diagnosis": [_MODE]},
        "pitch": {"limited_by": "model", "epsilon": 0.62, "diagnosis": [_MODE, _DELAY]},
        "yaw": {"limited_by": "none", "epsilon": 0.04},
    }, force=True)
    channels = written["channels"]
    assert channels["roll"]["model"]["effects"][-1]["type"] == "structural_mode"
    # the explaining one, even forced
    assert channels["pitch"]["model"]["effects"][-1]["type"] == "time_delay"
    assert "(forced: the channel is not model-limited (limited by none))" in out
    assert "  yaw: left as it is: the model fits" in out


def raw_config_channels() -> dict:
    import yaml

    return yaml.safe_load(CONFIG_PATH.read_text())["channels"]


def test_clean_flight_gets_no_fix_written_even_forced(bags, tmp_path, capsys):
    """End to end: the truth is the model, so no channel is model-limited and nothing is written; --force has
    no candidate to write either."""
    fixed = tmp_path / "fixed.yaml"
    for extra in ([], ["--force"]):
        assert (
            main(
                [
                    "replay",
                    str(bags["clean"]),
                    "--config",
                    str(CONFIG_PATH),
                    "--apply-diagnosis",
                    str(fixed),
                    "--no-history",
                    "--no-progress",
                    *extra,
                ]
            )
            == 0
        )
        err = capsys.readouterr().err
        assert not fixed.exists() and "not written" in err
        for name in ("roll", "pitch", "yaw"):
            assert f"  {name}: left as it is: the model fits (epsilon " in err
