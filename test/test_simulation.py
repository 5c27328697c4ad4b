"""Synthetic flights (gap_validation.core.simulation): ROS-free, seeded, realistic enough to validate
against."""
import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from _flights import SHORT, config_from, raw_config, single_channel, ultrastick
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from gap_validation.cli.arguments import hidden_effects, parse_band_noise, parse_hidden
from gap_validation.core.errors import ConfigError
from gap_validation.core.simulation import (
    FlightOptions,
    band_noise,
    doublet,
    log_sweep,
    plan_topics,
    simulate_flight,
    truth_models,
    with_options,
)

CHANNELS = ("roll", "pitch", "yaw")


@pytest.fixture(scope="module")
def config():
    return ultrastick()


@pytest.fixture(scope="module")
def flight(config):
    return simulate_flight(config, options=SHORT, seed=3)


# ------------------------------------------------------------------------------------------- --hidden
@pytest.mark.parametrize(
    "text, channel, effect",
    [
        ("pitch:time_delay:seconds=0.04", "pitch", {"type": "time_delay", "seconds": 0.04}),
        (
            "roll:first_order_lag:bandwidth_rad_s=37.7",
            "roll",
            {"type": "first_order_lag", "bandwidth_rad_s": 37.7},
        ),
        (
            " yaw : second_order_lag : natural_frequency_rad_s=30, damping=0.5 ",
            "yaw",
            {"type": "second_order_lag", "natural_frequency_rad_s": 30.0, "damping": 0.5},
        ),
    ],
)
def test_parse_hidden(text, channel, effect):
    assert parse_hidden(text, CHANNELS) == (channel, effect)


@pytest.mark.parametrize("text, part", [
    ("pitch", "CHANNEL:EFFECT"),
    ("pitch:", "CHANNEL:EFFECT"),
    ("wing:time_delay:seconds=0.04", "'wing'"),
    ("pitch:warp:seconds=0.04", "warp"),
    ("pitch:time_delay:seconds", "'seconds'"),
    ("pitch:time_delay:seconds=abc", "'seconds=abc'"),
    ("pitch:time_delay:sec=0.04", "sec"),
    ("pitch:time_delay:seconds=-1", "seconds"),
    ("pitch:time_delay:", "seconds"),
])
def test_parse_hidden_errors_name_the_bad_part(text, part):
    with pytest.raises(ConfigError) as err:
        parse_hidden(text, CHANNELS)
    message = str(err.value)
    assert "\n" not in message and part in message


def test_hidden_effects_collect_in_order(config):
    hidden = hidden_effects(
        ["roll:first_order_lag:bandwidth_rad_s=37.7", "roll:time_delay:seconds=0.05"], config
    )
    assert [e["type"] for e in hidden["roll"]] == ["first_order_lag", "time_delay"]
    truth = truth_models(config, hidden)
    w = np.array([5.0, 20.0])
    expected = config.channels["roll"].model.freqresp(w) * 37.7 / (1j * w + 37.7) * np.exp(-0.05j * w)
    np.testing.assert_allclose(truth["roll"].freqresp(w), expected, rtol=1e-9)
    assert truth["pitch"] is config.channels["pitch"].model


# ------------------------------------------------------------------------------------------- excitation
@settings(max_examples=25, deadline=None)
@given(st.floats(0.5, 3.0), st.floats(10.0, 60.0), st.floats(20.0, 80.0))
def test_log_sweep_instantaneous_frequency(w0, ratio, duration):
    """Half-periods between zero crossings match w(t) = w0 k^(t/T) (exponential sweep)."""
    w1 = w0 * ratio
    fs = 2000.0
    t = np.arange(0.0, duration, 1.0 / fs)
    x = log_sweep(t, duration, w0, w1, taper_s=0.0)
    sign = np.signbit(x)
    i = np.flatnonzero(sign[1:] != sign[:-1])
    i = i[(i > 0) & (i < x.size - 2)]
    crossings = t[i] + (t[i + 1] - t[i]) * x[i] / (x[i] - x[i + 1])  # linear interpolation between samples
    mid = 0.5 * (crossings[1:] + crossings[:-1])
    w_measured = math.pi / np.diff(crossings)
    w_expected = w0 * ratio ** (mid / duration)
    keep = mid > 4.0 / w0  # skip the first half-cycles (zero crossing at t = 0)
    np.testing.assert_allclose(w_measured[keep], w_expected[keep], rtol=0.02)


def test_log_sweep_zero_outside_and_tapered():
    t = np.linspace(-1.0, 11.0, 5001)
    x = log_sweep(t, 10.0, 1.0, 40.0, taper_s=1.0)
    assert np.all(x[(t < 0) | (t > 10)] == 0.0)
    assert np.max(np.abs(x)) <= 1.0 + 1e-12
    assert abs(x[np.searchsorted(t, 0.05)]) < 0.01


def test_doublet_shape():
    t = np.array([-0.1, 0.0, 0.4, 0.5, 0.9, 1.0, 1.5])
    assert doublet(t, 0.5).tolist() == [0.0, 1.0, 1.0, -1.0, -1.0, 0.0, 0.0]


# ------------------------------------------------------------------------------------------- test card
def test_test_card_sweeps_each_axis_in_turn(flight, config):
    sweeps = [s for s in flight.segments if s.kind == "sweep"]
    assert [s.channel for s in sweeps] == list(CHANNELS) * SHORT.sweeps_per_channel
    doublets = [s for s in flight.segments if s.kind == "doublet"]
    assert [s.channel for s in doublets] == list(CHANNELS) * SHORT.sweeps_per_channel
    starts = [s.start_s for s in flight.segments]
    assert starts == sorted(starts)
    for seg in sweeps:
        grid = config.channels[seg.channel].frequencies
        assert seg.band_rad_s[0] < grid.min_rad_s and seg.band_rad_s[1] > grid.max_rad_s
        assert seg.end_s - seg.start_s == SHORT.sweep_duration_s
        # the channel's surface moves most during its own sweep
        inside = (flight.t_s >= seg.start_s) & (flight.t_s <= seg.end_s)
        assert np.std(flight.inputs[seg.channel][inside]) > 0.6 * SHORT.sweep_amplitude_rad / math.sqrt(2)


def test_outputs_are_truth_response(flight):
    """The noise-free output is the truth model driven by the surface deflection."""
    for name in CHANNELS:
        expected = flight.truth[name].simulate(flight.t_s, flight.inputs[name])
        np.testing.assert_allclose(flight.outputs[name], expected, rtol=0, atol=1e-9)


def test_hidden_delay_shifts_the_response(config):
    """Same seed: the same inputs; a hidden 40 ms pitch delay delays the pitch response by exactly 40 ms."""
    clean = simulate_flight(config, options=SHORT, seed=5)
    late = simulate_flight(config, hidden_effects(["pitch:time_delay:seconds=0.04"], config), SHORT, seed=5)
    np.testing.assert_array_equal(clean.inputs["pitch"], late.inputs["pitch"])
    shifted = np.interp(clean.t_s - 0.04, clean.t_s, clean.outputs["pitch"], left=0.0)
    np.testing.assert_allclose(late.outputs["pitch"], shifted, atol=2e-3 * np.max(np.abs(shifted)))
    np.testing.assert_array_equal(clean.outputs["roll"], late.outputs["roll"])


# ------------------------------------------------------------------------------------------- sampling
def test_topics_types_rates_jitter_drops_latency(flight):
    imu, surfaces = flight.topics["/imu"], flight.topics["/control_surfaces"]
    assert imu.msgtype == "sensor_msgs/msg/Imu" and surfaces.msgtype == "sensor_msgs/msg/JointState"
    assert surfaces.joint_names == ("aileron", "elevator", "rudder")
    assert set(imu.values) == {"angular_velocity.x", "angular_velocity.y", "angular_velocity.z"}
    for series, rate in ((imu, SHORT.imu_rate_hz), (surfaces, SHORT.surface_rate_hz)):
        rel = series.stamp_s - flight.start_time_s
        expected = flight.duration_s * rate
        assert expected * (1 - 5 * SHORT.drop_probability) - 2 < len(series) < expected + 1
        assert len(series) < expected - 1  # some messages dropped
        assert np.all(np.diff(rel) > 0)
        phase = (rel * rate) % 1.0
        jitter = ((phase - np.median(phase) + 0.5) % 1.0 - 0.5) / rate
        assert 0.5 * SHORT.jitter_s < np.std(jitter) < 1.5 * SHORT.jitter_s
        latency = series.receive_s - series.stamp_s
        assert np.all(latency >= SHORT.latency_s - 1e-6) and np.all(np.diff(series.receive_s) >= 0)
        assert np.median(latency) < SHORT.latency_s + 3 * SHORT.latency_jitter_s


def test_sensor_quantisation_and_noise(config):
    quiet = simulate_flight(config, options=with_options(SHORT, noise=0.0), seed=1)
    noisy = simulate_flight(config, options=SHORT, seed=1)
    y_quiet = quiet.topics["/imu"].values["angular_velocity.y"]
    lsb = SHORT.gyro_lsb_rad_s
    np.testing.assert_allclose(y_quiet / lsb, np.round(y_quiet / lsb), atol=1e-9)
    clean = np.interp(noisy.topics["/imu"].stamp_s - noisy.start_time_s, noisy.t_s, noisy.outputs["pitch"])
    residual = noisy.topics["/imu"].values["angular_velocity.y"] - clean
    # gyro noise plus gusts
    expected = math.hypot(SHORT.gyro_noise_rad_s, SHORT.gust_rms_rad_s)
    assert 0.6 * expected < np.std(residual) < 1.5 * expected


def test_gusts_are_low_frequency(config):
    """The disturbance is coloured: its power sits below the gust bandwidth, so coherence falls there."""
    fl = simulate_flight(
        config, options=with_options(SHORT, gyro_noise_rad_s=0.0, gyro_lsb_rad_s=0.0), seed=2
    )
    imu = fl.topics["/imu"]
    disturbance = imu.values["angular_velocity.x"] - np.interp(imu.stamp_s - fl.start_time_s, fl.t_s,
                                                               fl.outputs["roll"])
    f, pxx = signal.welch(disturbance, fs=SHORT.imu_rate_hz, nperseg=4096)
    w = 2 * math.pi * f
    low = np.mean(pxx[(w > 0.3) & (w < 1.0)])
    high = np.mean(pxx[(w > 20.0) & (w < 40.0)])
    assert low > 100 * high


def test_same_seed_same_flight_other_seed_differs(config):
    a = simulate_flight(config, options=SHORT, seed=11)
    b = simulate_flight(config, options=SHORT, seed=11)
    c = simulate_flight(config, options=SHORT, seed=12)
    for topic in a.topics:
        np.testing.assert_array_equal(a.topics[topic].stamp_s, b.topics[topic].stamp_s)
        for key in a.topics[topic].values:
            np.testing.assert_array_equal(a.topics[topic].values[key], b.topics[topic].values[key])
    assert not np.array_equal(a.topics["/imu"].values["angular_velocity.y"][:100],
                              c.topics["/imu"].values["angular_velocity.y"][:100])


# ------------------------------------------------------------------------------------------- band noise
BAND = with_options(SHORT, sweeps_per_channel=1, band_noise_rad_s=(5.0, 10.0), band_noise_rms_rad_s=0.05,
                    band_noise_channels=("pitch",))


def _rates(fl):
    return {key: fl.topics["/imu"].values[key] for key in sorted(fl.topics["/imu"].values)}


def test_band_noise_is_off_by_default():
    assert FlightOptions().band_noise_rad_s is None and FlightOptions().band_noise_rms_rad_s == 0.0
    cfg = ultrastick()
    plain = simulate_flight(cfg, options=with_options(SHORT, sweeps_per_channel=1), seed=4)
    # a band with zero rms, or an rms without a band, changes nothing
    for changes in ({"band_noise_rad_s": (5.0, 10.0)}, {"band_noise_rms_rad_s": 0.05}):
        other = simulate_flight(cfg, options=with_options(SHORT, sweeps_per_channel=1, **changes), seed=4)
        for topic in plain.topics:
            np.testing.assert_array_equal(plain.topics[topic].stamp_s, other.topics[topic].stamp_s)
            for key, value in plain.topics[topic].values.items():
                np.testing.assert_array_equal(value, other.topics[topic].values[key])


def test_band_noise_is_band_limited_on_the_chosen_channel_only(config):
    """Same seed with and without band noise: only the pitch rate differs, by noise of the asked RMS whose
    power lies in the band."""
    plain = simulate_flight(config, options=replace(BAND, band_noise_rad_s=None), seed=6)
    noisy = simulate_flight(config, options=BAND, seed=6)
    np.testing.assert_array_equal(plain.topics["/control_surfaces"].values["position[elevator]"],
                                  noisy.topics["/control_surfaces"].values["position[elevator]"])
    np.testing.assert_array_equal(plain.topics["/imu"].stamp_s, noisy.topics["/imu"].stamp_s)
    for key in ("angular_velocity.x", "angular_velocity.z"):
        np.testing.assert_array_equal(plain.topics["/imu"].values[key], noisy.topics["/imu"].values[key])
    added = (
        noisy.topics["/imu"].values["angular_velocity.y"] - plain.topics["/imu"].values["angular_velocity.y"]
    )
    assert 0.9 * 0.05 < np.std(added) < 1.1 * 0.05
    f, pxx = signal.welch(added, fs=SHORT.imu_rate_hz, nperseg=2048)
    w = 2 * math.pi * f
    inside = np.mean(pxx[(w > 6.0) & (w < 9.0)])
    assert inside > 300 * np.mean(pxx[(w > 0.5) & (w < 2.0)])
    assert inside > 300 * np.mean(pxx[(w > 25.0) & (w < 60.0)])


def test_band_noise_is_seeded(config):
    a = simulate_flight(config, options=BAND, seed=6).topics["/imu"].values["angular_velocity.y"]
    b = simulate_flight(config, options=BAND, seed=6).topics["/imu"].values["angular_velocity.y"]
    np.testing.assert_array_equal(a, b)
    rng = [np.random.default_rng(1), np.random.default_rng(1), np.random.default_rng(2)]
    x, y, z = (band_noise(4000, 100.0, (5.0, 10.0), 0.1, r) for r in rng)
    np.testing.assert_array_equal(x, y)
    assert not np.allclose(x, z)
    assert np.std(x) == pytest.approx(0.1)
    assert not np.any(band_noise(100, 100.0, (5.0, 10.0), 0.0, np.random.default_rng(1)))


def test_band_noise_on_every_channel_by_default(config):
    plain = simulate_flight(config, options=replace(BAND, band_noise_rad_s=None), seed=6)
    noisy = simulate_flight(config, options=replace(BAND, band_noise_channels=None), seed=6)
    for key, value in _rates(plain).items():
        assert 0.9 * 0.05 < np.std(noisy.topics["/imu"].values[key] - value) < 1.1 * 0.05, key


@pytest.mark.parametrize("text, expected", [
    ("8:14:0.05", ((8.0, 14.0), 0.05, None)),
    (" 1.2 : 4 : 0.08 : pitch ", ((1.2, 4.0), 0.08, ("pitch",))),
    ("8:14:0.05:roll,yaw", ((8.0, 14.0), 0.05, ("roll", "yaw"))),
])
def test_parse_band_noise(text, expected):
    assert parse_band_noise(text, CHANNELS) == expected


@pytest.mark.parametrize("text, part", [
    ("8:14", "LOW:HIGH:RMS"),
    ("8-14-0.05", "LOW:HIGH:RMS"),
    ("8:14:0.05:pitch:x", "LOW:HIGH:RMS"),
    ("a:14:0.05", "'a'"),
    ("8:14:nan", "'nan'"),
    ("14:8:0.05", "14:8"),
    ("0:8:0.05", "0:8"),
    ("8:14:-1", "'-1'"),
    ("8:14:0.05:wing", "'wing'"),
    ("8:14:0.05:", "no channel"),
])
def test_parse_band_noise_errors_name_the_bad_part(text, part):
    with pytest.raises(ConfigError) as err:
        parse_band_noise(text, CHANNELS)
    message = str(err.value)
    assert "\n" not in message and part in message and "--band-noise" in message


@pytest.mark.parametrize("changes, needle", [
    ({"band_noise_rad_s": (10.0, 5.0)}, "band_noise_rad_s"),
    ({"band_noise_rad_s": (5.0, 2000.0)}, "Nyquist"),
    ({"band_noise_rad_s": (5.0,)}, "band_noise_rad_s"),
    ({"band_noise_rad_s": (5.0, 10.0), "band_noise_rms_rad_s": -0.1}, "band_noise_rms_rad_s"),
    ({"band_noise_rad_s": (5.0, 10.0), "band_noise_channels": "pitch"}, "band_noise_channels"),
])
def test_band_noise_options_checked(changes, needle):
    with pytest.raises(ConfigError, match=needle):
        with_options(SHORT, **changes).check()


def test_band_noise_unknown_channel(config):
    with pytest.raises(ConfigError, match="'wing'"):
        simulate_flight(config, options=with_options(BAND, band_noise_channels=("wing",)), seed=0)


def test_cli_band_noise(tmp_path, capsys):
    from _flights import CONFIG_PATH

    from gap_validation.cli.main import main

    base = [
        "simulate",
        "--config",
        str(CONFIG_PATH),
        "--sweeps",
        "1",
        "--sweep-duration",
        "10",
        "--seed",
        "2",
    ]
    assert main(base + ["--out", str(tmp_path / "a"), "--band-noise", "5:10:0.05:pitch"]) == 0
    assert "band noise: 0.05 rad/s rms at 5-10 rad/s on pitch" in capsys.readouterr().out
    for bad, part in (("5:10", "LOW:HIGH:RMS"), ("5:x:0.05", "'x'"), ("5:10:0.05:wing", "'wing'")):
        assert main(base + ["--out", str(tmp_path / "b"), "--band-noise", bad]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and part in err and "--band-noise" in err
    assert not (tmp_path / "b").exists()


def test_bundled_example_bag_is_reproduced(tmp_path):
    """Options added to the simulator leave default flights alone: scripts/make_example_bag rebuilds the
    bundled bag byte for byte."""
    from _flights import ROOT

    out = tmp_path / "ultrastick25e_flight"
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "make_example_bag"), "--out", str(out)],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    bundled = ROOT / "bags" / "ultrastick25e_flight"
    for name in ("ultrastick25e_flight.mcap", "metadata.yaml"):
        assert (out / name).read_bytes() == (bundled / name).read_bytes(), name


# ------------------------------------------------------------------------------------------- config variants
def test_custom_topics_float64_scale_and_rates():
    data = single_channel("pitch")
    data["channels"]["pitch"]["input"] = {"topic": "/elevator_deg", "field": "data", "scale": math.pi / 180}
    data["channels"]["pitch"]["output"] = {"topic": "/vn100/imu", "field": "angular_velocity.y"}
    cfg = config_from(data)
    fl = simulate_flight(cfg, options=with_options(SHORT, sweeps_per_channel=1, imu_rate_hz=200.0,
                                                   surface_rate_hz=25.0), seed=0)
    assert fl.topics["/elevator_deg"].msgtype == "std_msgs/msg/Float64"
    assert fl.topics["/vn100/imu"].msgtype == "sensor_msgs/msg/Imu"
    n_imu, n_surface = len(fl.topics["/vn100/imu"]), len(fl.topics["/elevator_deg"])
    assert 7.0 < n_imu / n_surface < 9.0
    degrees = fl.topics["/elevator_deg"].values["data"]
    assert 2.0 < np.max(np.abs(degrees)) < 10.0  # the sweep amplitude (3.4 deg) plus trim, in degrees


def test_joint_names_and_indices_from_config():
    data = raw_config()
    data["channels"]["roll"]["input"]["field"] = "position[ail_left]"
    data["channels"]["yaw"]["input"]["field"] = "position[4]"
    plans = plan_topics(config_from(data))
    names = plans["/control_surfaces"].joint_names
    assert names[0] == "ail_left" and "elevator" in names and len(names) == 5


@pytest.mark.parametrize("change, needle", [
    ({"output": {"topic": "/imu", "field": "twist.angular.y"}}, "/imu"),
    ({"output": {"topic": "/imu", "field": "angular_velocity.y", "type": "geometry_msgs/msg/Twist"}},
     "geometry_msgs/msg/Twist"),
    ({"input": {"topic": "/imu", "field": "position[elevator]"}}, "/imu"),
])
def test_unsupported_topics_are_config_errors(change, needle):
    cfg = config_from(single_channel("pitch", **change))
    with pytest.raises(ConfigError) as err:
        simulate_flight(cfg, options=SHORT)
    assert needle in str(err.value) and "\n" not in str(err.value)


def test_options_checked():
    with pytest.raises(ConfigError, match="imu_rate_hz"):
        FlightOptions(imu_rate_hz=0.0).check()
    with pytest.raises(ConfigError, match="sweeps_per_channel"):
        FlightOptions(sweeps_per_channel=0).check()


# ------------------------------------------------------------------------------------------- core rules
def test_simulation_is_ros_free():
    code = ("import sys, gap_validation.core.simulation; "
            "bad = [m for m in ('rclpy', 'rosbags', 'matplotlib', 'yaml') if m in sys.modules]; "
            "print(bad); sys.exit(1 if bad else 0)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=str(
        __import__("pathlib").Path(__file__).resolve().parents[1]))
    assert done.returncode == 0, done.stdout + done.stderr


def test_fifteen_minute_flight_is_made(config):
    # seconds of flight per second of work: benchmarks/bench_core.py
    fl = simulate_flight(config, options=FlightOptions(sweeps_per_channel=4, sweep_duration_s=60.0), seed=0)
    assert fl.duration_s > 14 * 60
