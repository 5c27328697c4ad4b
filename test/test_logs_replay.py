"""Flight logs through the one data path (gap_validation.bag.replay, ``gap-validate replay|simulate
--format``): the same simulated flight as a bag, a PX4 ULog, an ArduPilot DataFlash log and CSV files gives
the same verdict; the logging checks (a stream too slow for the band, irregular stamps, a missing topic or
field) say what to fix; a damaged log is read up to the damage, reported, and its results written."""
import copy
import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest
from _flights import CONFIG_PATH, SHORT, config_from, single_channel

from gap_validation.bag.replay import BAG_GAP_S, replay
from gap_validation.bag.writer import write_flight
from gap_validation.cli.arguments import hidden_effects
from gap_validation.cli.main import main
from gap_validation.core.config import load_config
from gap_validation.core.errors import ConfigError
from gap_validation.core.simulation import simulate_flight, with_options
from gap_validation.logs.base import WriteTopic
from gap_validation.logs.checks import rate_limit_rad_s
from gap_validation.logs.csvlog import write_csv
from gap_validation.logs.flight import BOOT_S, SERVO_RANGE_RAD, write_flight_log
from gap_validation.logs.formats import open_log

#: One 30 s sweep and a doublet of pitch: surfaces and IMU at the same rates in every format.
CARD = with_options(SHORT, sweeps_per_channel=1, sweep_duration_s=30.0, quiet_s=3.0, surface_rate_hz=50.0,
                    imu_rate_hz=100.0)
HIDDEN = ["pitch:time_delay:seconds=0.04"]
#: The formats whose writers are there (ULog and DataFlash are written by their own modules).
FORMATS = ["csv"] + [f for f, m in (("ulog", "ulog"), ("dataflash", "dataflash"))
                     if importlib.util.find_spec(f"gap_validation.logs.{m}") is not None]


def _one_line(text, *needles):
    assert "\n" not in text
    for needle in needles:
        assert str(needle) in text, (needle, text)
    return text


def _as_logged(flight, config, log, log_config):
    """The flight as the log holds it (its stamps on the log's microsecond clock, its values as stored:
    float32, whole-microsecond PWM), in the config's units: written as a bag, it carries the log's very
    samples."""
    out = copy.deepcopy(flight)
    for name, ch in config.channels.items():
        for stream in ("input", "output"):
            src, logged = ch.signal(stream), log_config.channels[name].signal(stream)
            topic = logged.topic[1:]
            path = Path(log) / f"{topic}.csv" if Path(log).is_dir() else Path(log)
            with open_log(path) as f:
                series = f.read({topic: [logged.field]})[topic]
            series_out = out.topics[src.topic]
            series_out.stamp_s = series.t_s.copy()
            series_out.receive_s = series.t_s.copy()
            series_out.values[src.field] = src.raw(logged.value(series.values[:, 0]))
    return out


@pytest.fixture(scope="module")
def pitch():
    return config_from(single_channel("pitch"))


@pytest.fixture(scope="module")
def same_flight(tmp_path_factory, pitch):
    """One flight (seed 2, a hidden 40 ms delay) as a bag and in every log format, each log with its config
    and a bag of the samples it holds; and every replay."""
    root = tmp_path_factory.mktemp("same")
    flight = simulate_flight(pitch, hidden_effects(HIDDEN, pitch), CARD, seed=2)
    write_flight(flight, root / "bag")
    out = {"root": root, "flight": flight, "bag": replay([root / "bag"], pitch)}
    for fmt in FORMATS:
        log, config_path, _ = write_flight_log(flight, pitch, root / f"flight_{fmt}", fmt)
        log_config = load_config(config_path)
        write_flight(_as_logged(flight, pitch, log, log_config), root / f"bag_{fmt}")
        out[fmt] = {"log": log, "config": config_path, "outcome": replay([log], log_config),
                    "as_logged": replay([root / f"bag_{fmt}"], pitch)}
    return out


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_format_gives_the_bag_verdict_and_names_the_hidden_effect(same_flight, fmt):
    bag = same_flight["bag"].result.channels["pitch"]
    got = same_flight[fmt]["outcome"]
    log = got.result.channels["pitch"]
    assert got.errors == [] and got.warnings == []
    assert bag.limited_by == log.limited_by == "model" and log.sweeps == bag.sweeps == 1
    assert log.diagnosis[0].effect == bag.diagnosis[0].effect == "time_delay" and log.diagnosis[0].explains
    assert log.diagnosis[0].parameters["seconds"] == pytest.approx(0.04, abs=0.01)
    # the log's very samples as a bag: the same numbers through the same router and validator
    same = same_flight[fmt]["as_logged"].result.channels["pitch"]
    assert abs(log.epsilon - same.epsilon) < 1e-6 and abs(log.nu_gap - same.nu_gap) < 1e-6
    assert np.allclose(
        log.epsilon_per_frequency, same.epsilon_per_frequency, rtol=0, atol=1e-6, equal_nan=True
    )
    # against the bag of nanosecond stamps and float64 values, only the format's precision moves epsilon:
    # stamps in whole microseconds (all three), float32 (ULog, DataFlash), PWM in whole microseconds, 0.0007
    # rad (RCOU)
    assert abs(log.epsilon - bag.epsilon) < (2e-3 if fmt == "dataflash" else 1e-5)


def test_the_log_clock_and_units_are_the_autopilots(same_flight):
    flight = same_flight["flight"]
    imu = flight.topics["/imu"]
    if "ulog" in FORMATS:
        import pyulog

        ref = pyulog.ULog(str(same_flight["ulog"]["log"]))
        data = {d.name: d.data for d in ref.data_list}
        rates, servos = data["vehicle_angular_velocity"], data["actuator_servos"]
        expected_us = np.round((imu.stamp_s - flight.start_time_s + BOOT_S) * 1e6)
        assert np.array_equal(rates["timestamp_sample"], expected_us)
        assert np.allclose(rates["xyz[1]"], imu.values["angular_velocity.y"], rtol=1e-6, atol=1e-7)
        assert np.isnan(rates["xyz[0]"]).all() and np.isnan(servos["control[0]"]).all()
        surfaces = flight.topics["/control_surfaces"].values["position[elevator]"]
        assert np.allclose(servos["control[1]"], surfaces / SERVO_RANGE_RAD, rtol=1e-6, atol=1e-7)
    if "dataflash" in FORMATS:
        from pymavlink import DFReader

        reader = DFReader.DFReader_binary(str(same_flight["dataflash"]["log"]))
        pwm = []
        while (m := reader.recv_match(type="RCOU")) is not None:
            pwm.append(m.C2)
        surfaces = flight.topics["/control_surfaces"].values["position[elevator]"]
        assert np.array_equal(pwm, np.rint(1500 + 500 * surfaces / SERVO_RANGE_RAD))


def test_servos_at_10_hz_are_validated_up_to_what_their_rate_resolves_and_say_why(tmp_path):
    """PX4's default: actuator_servos every 100 ms, the gyro at 250 Hz. The servos are read up to their
    Nyquist frequency (31.4 rad/s; the gyro shows what their sampling folds back): every frequency whose band
    (+-10 %) lies below it, up to 28.6 rad/s; above that no frequency is confident, each above 31.4 rad/s says
    ``above_resolution``, no band is model-limited, and the warning says what to change. (test_slow_streams.py
    has the accuracy.)"""
    fmt = "ulog" if "ulog" in FORMATS else "csv"
    config = config_from(
        single_channel("pitch", frequencies={"min_rad_s": 1.0, "max_rad_s": 40.0, "count": 40})
    )
    # sweep to 28.8 rad/s
    card = with_options(CARD, surface_rate_hz=10.0, imu_rate_hz=250.0, band_high_factor=0.72)
    flight = simulate_flight(config, {}, card, seed=4)
    log, config_path, _ = write_flight_log(flight, config, tmp_path / "px4", fmt)
    outcome = replay([log], load_config(config_path))
    limit = rate_limit_rad_s(10.0)
    assert limit == pytest.approx(10.0 * math.pi)
    top = limit / 1.1
    slow = [w for w in outcome.warnings if "logged at 10 Hz" in w]
    assert len(slow) == 1 and not any("250 Hz" in w for w in outcome.warnings)
    _one_line(
        slow[0],
        "frequencies above 28.6 rad/s cannot be validated",
        "Nyquist frequency, 31.4 rad/s",
        "40 rad/s",
        "40 Hz or faster",
    )
    if fmt == "ulog":
        _one_line(slow[0], "actuator_servos", "SDLOG_PROFILE", "logger_topics.txt")
    ch = outcome.result.channels["pitch"]
    assert ch.limited_by != "model"
    w = np.asarray(ch.frequency_rad_s)
    confident = np.asarray(ch.confident, bool)
    assert ch.epsilon is not None and ch.worst_frequency_rad_s <= top
    assert np.all(w[confident] <= top) and w[confident].max() > 24.0        # validated up to near the limit
    above = w > limit
    assert above.any() and all(r == "above_resolution" for r, a in zip(ch.frequency_reasons, above) if a)
    # between the two: past the sweep's end (not excited) or a band crossing 31.4 rad/s
    assert all(r in ("above_resolution", "not_excited") for r, a in zip(ch.frequency_reasons, w > top) if a)
    assert all(b.max_rad_s <= top for b in ch.bands if b.limited_by == "model")


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_truncated_log_is_read_up_to_the_damage_results_written_exit_1(same_flight, tmp_path, capsys, fmt):
    log = Path(same_flight[fmt]["log"])
    if log.is_dir():
        cut = tmp_path / log.name
        cut.mkdir()
        for f in log.iterdir():
            (cut / f.name).write_bytes(f.read_bytes())
        victim = cut / "imu.csv"
    else:
        cut = victim = tmp_path / log.name
        cut.write_bytes(log.read_bytes())
    data = victim.read_bytes()
    victim.write_bytes(data[:int(len(data) * 0.8) + 5])
    out = tmp_path / "out.json"
    status = main(
        [
            "replay",
            str(cut),
            "--config",
            str(same_flight[fmt]["config"]),
            "--json",
            str(out),
            "--no-history",
            "--no-progress",
        ]
    )
    assert status == 1
    errors = [line for line in capsys.readouterr().err.splitlines() if "error:" in line]
    assert len(errors) == 1 and "Traceback" not in errors[0]
    _one_line(errors[0], victim.name, " s")
    channel = json.loads(out.read_text())["channels"]["pitch"]
    assert channel["sweeps"] == 1 and channel["epsilon"] is not None


def test_a_missing_topic_and_a_missing_field_are_one_line_each_and_the_rest_validated(same_flight, tmp_path):
    fmt = FORMATS[-1]
    data = __import__("yaml").safe_load(Path(same_flight[fmt]["config"]).read_text())
    good = data["channels"]["pitch"]
    topic = good["output"]["topic"]
    data["channels"]["late"] = copy.deepcopy(good)
    data["channels"]["late"]["output"] = {"topic": topic, "field": "NoSuchField"}
    data["channels"]["gone"] = copy.deepcopy(good)
    data["channels"]["gone"]["output"] = {"topic": "NOPE", "field": "q"}
    outcome = replay([same_flight[fmt]["log"]], config_from(data))
    missing = [w for w in outcome.warnings if "NOPE" in w]
    assert len(missing) == 1
    _one_line(missing[0], "topic NOPE (gone.output) is not in the log", "it has: ", topic)
    field = [e for e in outcome.errors if "NoSuchField" in e]
    assert len(field) == 1
    have = (
        open_log(Path(same_flight[fmt]["log"]) / f"{topic}.csv" if fmt == "csv" else same_flight[fmt]["log"])
        .topics[topic]
        .fields
    )
    _one_line(field[0], Path(same_flight[fmt]["log"]).name, f"topic {topic} has no field NoSuchField",
              ", ".join(have), "late.output skipped")
    assert not any("late" in e and e is not field[0] for e in outcome.errors)       # one line for that stream
    assert any("gone" in e and "no samples" in e for e in outcome.errors)
    pitch = outcome.result.channels["pitch"]
    assert pitch.sweeps == 1 and pitch.limited_by == "model"
    assert outcome.result.channels["late"].epsilon is None and outcome.result.channels["gone"].epsilon is None


def test_irregular_stamps_and_cells_that_are_not_numbers_are_counted(same_flight, tmp_path):
    src = Path(same_flight["csv"]["log"])
    flight = tmp_path / "odd"
    flight.mkdir()
    (flight / "control_surfaces.csv").write_bytes((src / "control_surfaces.csv").read_bytes())
    lines = (src / "imu.csv").read_text().splitlines(keepends=True)
    header, rows = lines[:2], lines[2:]
    rows = rows[:500] + rows[500:530] + rows[500:] # 30 rows again: the same stamps repeated
    rows = rows[:2000] + rows[2200:]               # 2 s lost
    cells = rows[3000].split(",")
    rows[3000] = f"{cells[0]},bad\n"
    (flight / "imu.csv").write_text("".join(header + rows))
    outcome = replay([flight], load_config(same_flight["csv"]["config"]))
    stamps = [w for w in outcome.warnings if "irregular stamps" in w]
    assert len(stamps) == 1
    # the 30 rows again: the last equals the latest stamp, 29 lie before it; the router drops all 30
    _one_line(stamps[0], "imu.csv: topic imu", "1 repeated stamps", "29 stamps going back",
              "1 gaps longer than 5 sample intervals", "the longest 2.0")
    nan = [w for w in outcome.warnings if "not numbers" in w]
    assert len(nan) == 1
    _one_line(nan[0], "1 of", "values of q are not numbers", "pitch.output")
    bad = outcome.result.channels["pitch"].bad_samples
    assert bad.get("output: not finite") == 1 and bad.get("output: time not increasing", 0) >= 30


def test_a_bag_and_a_csv_log_add_up_in_one_run(same_flight, pitch, tmp_path):
    """A CSV export with the bag's topic and field names reads with the bag's config; the two flights' clocks
    overlap, so the later one is shifted to start BAG_GAP_S after the first, as for two bags."""
    second = simulate_flight(pitch, hidden_effects(HIDDEN, pitch), CARD, seed=3)
    topics = []
    for name, series in second.topics.items():
        t_us = np.round(series.stamp_s * 1e6).astype(np.int64)
        topics.append(WriteTopic(name.strip("/"), t_us, dict(series.values)))
    csv_dir = tmp_path / "export"
    write_csv(csv_dir, topics)
    outcome = replay([csv_dir, same_flight["root"] / "bag"], pitch)
    assert outcome.errors == [] and outcome.result.channels["pitch"].sweeps == 2
    reports = {Path(r.path).name: r for r in outcome.bags}
    offsets = sorted(r.time_offset_s for r in reports.values())
    assert offsets[0] == 0.0 and offsets[1] > BAG_GAP_S           # the one that starts later is shifted
    assert outcome.result.channels["pitch"].diagnosis[0].effect == "time_delay"
    assert sorted(Path(s).name for s in outcome.result.sources) == ["bag", "export"]


def test_cli_simulate_writes_the_log_and_its_config_and_replay_reads_it(tmp_path, capsys):
    fmt = "ulog" if "ulog" in FORMATS else "csv"
    out = tmp_path / "flight"
    args = ["simulate", "--config", str(CONFIG_PATH), "--out", str(out), "--format", fmt, "--sweeps", "1",
            "--sweep-duration", "12", "--sweep-gap-s", "1", "--seed", "5"]
    assert main(args) == 0
    text = capsys.readouterr().out
    log = out.with_name(out.name + ".ulg") if fmt == "ulog" else out
    config = Path(str(log) + ".yaml")
    assert log.exists() and config.exists()
    assert f"next: gap-validate replay {log} --config {config}" in text
    if fmt == "ulog":
        assert "surfaces at 10 Hz" in text                      # PX4's default logging interval
        assert "# actuator_servos control[k]" in config.read_text()
    assert main(args) == 2 and "exists already" in capsys.readouterr().err
    status = main(
        [
            "replay",
            str(log),
            "--config",
            str(config),
            "--json",
            str(tmp_path / "r.json"),
            "--no-history",
            "--no-progress",
        ]
    )
    assert status == 0
    assert set(json.loads((tmp_path / "r.json").read_text())["channels"]) == {"roll", "pitch", "yaw"}
    assert main(["replay", str(log), "--config", str(config), "--annotate", str(tmp_path / "a.mcap")]) == 2
    _one_line(capsys.readouterr().err.strip().splitlines()[-1], "--annotate", "flight log")


def test_cli_simulate_format_errors_are_one_line(tmp_path, capsys):
    base = ["simulate", "--config", str(CONFIG_PATH), "--sweeps", "1", "--sweep-duration", "5"]
    assert main(base + ["--out", str(tmp_path / "x"), "--format", "csv", "--storage", "mcap"]) == 2
    _one_line(capsys.readouterr().err.strip(), "--storage", "bags only")
    if "dataflash" in FORMATS:
        assert main(base + ["--out", str(tmp_path / "y"), "--format", "dataflash", "--log-excitation", "/ex",
                            "--closed-loop-gain-margin-db", "6"]) == 2
        _one_line(capsys.readouterr().err.strip(), "SystemID", "one axis per run")


@pytest.mark.skipif("dataflash" not in FORMATS, reason="the DataFlash writer is not there")
def test_a_copter_systemid_log_with_sidd_as_the_excitation_gives_the_plant_like_the_bag(tmp_path, pitch):
    """The rate loop closed, the SystemID signal injected at the mixer and logged as SIDD.Targ: the excitation
    is the instrument, so the plant comes out without feedback bias, exactly as from the bag with the same
    excitation topic."""
    card = with_options(CARD, closed_loop_gain_margin_db=6.0, log_excitation_topic="/sysid/excitation")
    flight = simulate_flight(pitch, hidden_effects(HIDDEN, pitch), card, seed=6)
    log, config_path, layout = write_flight_log(flight, pitch, tmp_path / "copter", "dataflash")
    assert layout == "ArduCopter SystemID"
    log_config = load_config(config_path)
    ch = log_config.channels["pitch"]
    assert (ch.input.topic, ch.input.field, ch.excitation.topic, ch.excitation.field) == (
        "/RATE",
        "POut",
        "/SIDD",
        "Targ",
    )
    write_flight(flight, tmp_path / "bag")
    bag_config = copy.deepcopy(pitch.raw)
    bag_config["channels"]["pitch"]["excitation"] = {
        "topic": "/sysid/excitation",
        "field": "position[elevator]",
    }
    from_bag = replay([tmp_path / "bag"], config_from(bag_config)).result.channels["pitch"]
    from_log = replay([log], log_config).result.channels["pitch"]
    assert from_log.limited_by == from_bag.limited_by == "model"
    assert from_log.diagnosis[0].effect == from_bag.diagnosis[0].effect == "time_delay"
    assert from_log.diagnosis[0].parameters["seconds"] == pytest.approx(0.04, abs=0.01)
    # PWM-free, float32 and microsecond stamps only
    assert abs(from_log.epsilon - from_bag.epsilon) < 2e-3


def test_conflicting_csv_time_columns_are_a_config_error(same_flight, tmp_path):
    data = __import__("yaml").safe_load(Path(same_flight["csv"]["config"]).read_text())
    data["channels"]["pitch"]["output"]["time_column"] = "TimeUS"
    data["channels"]["twin"] = copy.deepcopy(data["channels"]["pitch"])
    data["channels"]["twin"]["output"]["time_column"] = "time"
    with pytest.raises(ConfigError) as err:
        replay([same_flight["csv"]["log"]], config_from(data))
    _one_line(str(err.value), "/imu", "different time_column", "TimeUS, time")


@pytest.mark.parametrize("name, fmt, pitch_only", [("px4_fixedwing", "ulog", False),
                                                  ("ardupilot_plane", "dataflash", False),
                                                  ("ardupilot_copter_sysid", "dataflash", True)])
def test_the_example_configs_are_what_simulate_writes_for_the_bundled_model(name, fmt, pitch_only):
    from gap_validation.logs.flight import log_config, log_layout, with_logged_excitation

    config = load_config(CONFIG_PATH)
    if pitch_only:
        config = with_logged_excitation(config_from(single_channel("pitch")), "/sysid/excitation")
    layout, _ = log_layout(config, fmt)
    example = load_config(Path(CONFIG_PATH).parent / f"{name}.yaml")
    assert log_config(config, layout)["channels"] == example.raw["channels"]
    text = (Path(CONFIG_PATH).parent / f"{name}.yaml").read_text()
    assert "rad/s" in text and "FRD" in text                          # units and frames stated


def test_a_ulog_instance_0_may_be_named_with_its_index(same_flight):
    """pyulog names instance 0 of a multi-instance topic plainly (``vehicle_angular_velocity``) and the others
    ``name:K``: a config that writes ``name:0`` reads the same samples."""
    data = __import__("yaml").safe_load(Path(same_flight["ulog"]["config"]).read_text())
    plain = replay([same_flight["ulog"]["log"]], config_from(data))
    for stream in ("input", "output"):
        data["channels"]["pitch"][stream]["topic"] = (
            data["channels"]["pitch"][stream]["topic"].lstrip("/") + ":0"
        )
    indexed = replay([same_flight["ulog"]["log"]], config_from(data))
    assert not [w for w in indexed.warnings if "not in the log" in w], indexed.warnings
    assert indexed.result.channels["pitch"].epsilon == plain.result.channels["pitch"].epsilon
