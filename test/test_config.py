"""Config schema: the DESIGN.md format parses; every mistake is one ConfigError line naming file, key,
value."""
import copy

import numpy as np
import pytest

from gap_validation.core.config import dump_config, load_config, parse_config
from gap_validation.core.errors import ConfigError

BASE = {
    "channels": {
        "pitch": {
            "input": {"topic": "/control_surfaces", "field": "position[elevator]"},
            "output": {"topic": "/imu", "field": "angular_velocity.y"},
            "model": {"numerator": [-133.7, -990.76], "denominator": [1.0, 23.37, 235.93],
                      "effects": [{"type": "time_delay", "seconds": 0.05}]},
        }
    }
}


def with_change(path, value):
    data = copy.deepcopy(BASE)
    node = data
    for key in path[:-1]:
        node = node[key]
    if value is KeyError:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return data


def test_design_example_parses_with_defaults():
    cfg = parse_config(BASE, "cfg.yaml")
    ch = cfg.channels["pitch"]
    assert ch.input.topic == "/control_surfaces" and ch.input.field == "position[elevator]"
    assert ch.output.scale == 1.0 and ch.coherence_threshold == 0.6
    w = ch.frequencies.values()
    # no grid configured: 0.3-100 rad/s at 20 per decade, trimmed later to the band the flight excites (issue
    # 12)
    assert not ch.frequencies.configured and np.isclose(w[0], 0.3) and np.isclose(w[-1], 100.0)
    assert w.size == 51 and np.all(np.diff(np.log(w)) > 0)
    assert ch.model.delay_s == pytest.approx(0.05)
    assert set(cfg.topics()) == {"/control_surfaces", "/imu"}
    assert cfg.topics()["/imu"][0][:2] == ("pitch", "output")


@pytest.mark.parametrize("path,value,needle", [
    (("channels", "pitch", "input", "field"), 3, "channels.pitch.input.field"),
    (("channels", "pitch", "input", "topic"), KeyError, "channels.pitch.input.topic: missing"),
    (("channels", "pitch", "output", "scale"), "deg", "channels.pitch.output.scale"),
    (("channels", "pitch", "output", "colour"), "red", "channels.pitch.output.colour: unknown key"),
    (("channels", "pitch", "coherence_threshold"), 1.5, "channels.pitch.coherence_threshold"),
    (("channels", "pitch", "frequencies"), {"min_rad_s": 10, "max_rad_s": 1}, "max_rad_s"),
    (("channels", "pitch", "frequencies"), {"count": 2.5}, "frequencies.count"),
    (("channels", "pitch", "model", "effects"), [{"type": "time_delay", "seconds": "x"}], "seconds"),
    (("channels", "pitch", "model", "effects"), [{"type": "warp_drive"}], "warp_drive"),
    (("channels", "pitch", "model"), KeyError, "channels.pitch.model: missing"),
    (("channels",), {}, "channels: empty"),
    (("extra",), 1, "extra: unknown key"),
])
def test_errors_name_the_key(path, value, needle):
    with pytest.raises(ConfigError) as err:
        parse_config(with_change(path, value), "cfg.yaml")
    text = str(err.value)
    assert "\n" not in text and text.startswith("cfg.yaml: ")
    assert needle in text


def test_load_and_dump_round_trip(tmp_path):
    path = tmp_path / "cfg.yaml"
    dump_config(BASE, path)
    cfg = load_config(path)
    assert cfg.source == str(path)
    out = tmp_path / "cfg2.yaml"
    dump_config(
        cfg.with_channel_effects("pitch", [{"type": "first_order_lag", "bandwidth_rad_s": 37.7}]), out
    )
    effects = load_config(out).channels["pitch"].model.effects
    assert [e["type"] for e in effects] == ["time_delay", "first_order_lag"]


def test_yaml_errors_are_one_line(tmp_path):
    missing = tmp_path / "nope.yaml"
    with pytest.raises(ConfigError, match="nope.yaml: config file not found"):
        load_config(missing)
    bad = tmp_path / "bad.yaml"
    bad.write_text("channels:\n  pitch: [1, 2\n")
    with pytest.raises(ConfigError, match=r"bad.yaml: YAML error at line \d+"):
        load_config(bad)


def test_bundled_configs_parse():
    cfg = load_config("config/ultrastick25e.yaml")
    assert list(cfg.channels) == ["roll", "pitch", "yaw"]
    for name in ("paper_example_p1", "paper_example_p2"):
        assert "pitch" in load_config(f"config/{name}.yaml").channels


# -- MIMO channels and controllers (issue 14)
# ------------------------------------------------------------------

LATERAL = {
    "inputs": [
        {"topic": "/control_surfaces", "field": "position[aileron]"},
        {"topic": "/control_surfaces", "field": "position[rudder]"},
    ],
    "outputs": [
        {"topic": "/imu", "field": "angular_velocity.x"},
        {"topic": "/imu", "field": "angular_velocity.z"},
    ],
    "model": {
        "state_space": {
            "A": [[-0.87, 0.90, -16.8], [-2.76, -16.1, 3.37], [1.71, 0.51, -2.78]],
            "B": [[0.0, 5.3], [156.5, -5.0], [-11.5, -82.0]],
            "C": [[0, 1, 0], [0, 0, 1]],
        }
    },
    "controller": {
        "transfer_matrix": [
            [{"numerator": [0.05], "denominator": [1.0]}, 0.0],
            [0.0, {"numerator": [0.1, 0.0], "denominator": [1.0, 1.0]}],
        ]
    },
}


def mimo_config(**changes):
    data = copy.deepcopy(BASE)
    data["channels"]["pitch"]["controller"] = {"numerator": [0.2], "denominator": [1.0]}
    data["channels"]["lateral"] = copy.deepcopy(LATERAL)
    data["channels"]["lateral"].update(changes)
    return data


def test_mimo_channel_and_controllers_parse():
    cfg = parse_config(mimo_config(), "cfg.yaml")
    lateral, pitch = cfg.channels["lateral"], cfg.channels["pitch"]
    assert lateral.is_mimo and not pitch.is_mimo
    assert lateral.input is None and [s.field for s in lateral.inputs] == [
        "position[aileron]",
        "position[rudder]",
    ]
    assert lateral.model.shape == (2, 2) and lateral.controller.shape == (2, 2)
    assert pitch.controller.freqresp([1.0])[0] == pytest.approx(0.2)
    assert lateral.controller_spec == LATERAL["controller"] and lateral.model_spec == LATERAL["model"]


def test_flight_data_path_accepts_mimo_channels(tmp_path):
    from gap_validation.core.validator import OnlineValidator

    cfg = parse_config(mimo_config(), "cfg.yaml")
    streams = [(c, s) for entries in cfg.topics().values() for c, s, _ in entries if c == "lateral"]
    assert sorted(streams) == [("lateral", "inputs[0]"), ("lateral", "inputs[1]"), ("lateral", "outputs[0]"),
                               ("lateral", "outputs[1]")]
    assert cfg.channels["lateral"].signal("inputs[1]").field == "position[rudder]"
    assert OnlineValidator(cfg).results().channels["lateral"].message.startswith("no sweep found")
    # effects on a MIMO model are still one line
    with pytest.raises(ConfigError) as err:
        cfg.with_channel_effects("lateral", [{"type": "gain", "factor": 2.0}])
    assert "\n" not in str(err.value) and "effects on a MIMO model" in str(err.value)
    # a MIMO config can be swapped in live (its channel starts empty)
    validator = OnlineValidator(parse_config(BASE, "cfg.yaml"))
    assert "lateral" in validator.set_config(cfg)
    path = tmp_path / "mimo.yaml"
    dump_config(cfg, path)
    again = load_config(path)
    assert again.channels["lateral"].model.shape == (2, 2)


@pytest.mark.parametrize(
    "changes, needle",
    [
        (
            {"input": {"topic": "/a", "field": "x"}},
            "channels.lateral.input: give input/output (SISO) or inputs/outputs",
        ),
        ({"outputs": KeyError}, "channels.lateral.outputs: missing"),
        ({"inputs": []}, "channels.lateral.inputs: expected a non-empty list of signals"),
        ({"inputs": {"topic": "/a", "field": "x"}}, "channels.lateral.inputs: expected a non-empty list"),
        (
            {"inputs": [{"topic": "/a", "field": "x"}, {"topic": "/a", "field": "x"}]},
            "channels.lateral.inputs[1]: the same signal as channels.lateral.inputs[0] (/a x)",
        ),
        (
            {"outputs": [{"topic": "/imu", "field": 3}, {"topic": "/imu", "field": "y"}]},
            "channels.lateral.outputs[0].field",
        ),
        (
            {"model": {"state_space": dict(LATERAL["model"]["state_space"], B=[[0.0], [156.5], [-11.5]])}},
            "cfg.yaml: channels.lateral.model.state_space.B: expected 2 columns (one per entry of "
            "channels.lateral.inputs),"
            " got shape 3x1",
        ),
        (
            {"model": {"state_space": dict(LATERAL["model"]["state_space"], C=[[0, 1, 0]])}},
            "channels.lateral.model.state_space.C: expected 2 rows (one per entry of "
            "channels.lateral.outputs), got shape 1x3",
        ),
        (
            {"model": {"numerator": [1.0], "denominator": [1.0, 1.0]}},
            "channels.lateral.model.numerator: unknown key for a MIMO model",
        ),
        (
            {"controller": {"state_space": {"D": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]}}},
            "channels.lateral.controller.state_space.D: expected 2 columns (one per entry of "
            "channels.lateral.outputs "
            "(the controller reads them)), got shape 2x3",
        ),
        ({"controller": {"numerator": [1.0], "denominator": [1.0]}}, "channels.lateral.controller.numerator"),
    ],
)
def test_mimo_errors_name_file_key_and_value(changes, needle):
    data = mimo_config()
    for key, value in changes.items():
        if value is KeyError:
            del data["channels"]["lateral"][key]
        else:
            data["channels"]["lateral"][key] = value
    with pytest.raises(ConfigError) as err:
        parse_config(data, "cfg.yaml")
    text = str(err.value)
    assert "\n" not in text and text.startswith("cfg.yaml: ")
    assert needle in text


def test_siso_controller_errors_name_the_key():
    data = copy.deepcopy(BASE)
    data["channels"]["pitch"]["controller"] = {"numerator": [1.0, 2.0, 3.0], "denominator": [1.0]}
    with pytest.raises(ConfigError, match=r"^cfg\.yaml: channels\.pitch\.controller: improper model"):
        parse_config(data, "cfg.yaml")


def test_an_airspeed_stream_with_the_trim_it_scales_to():
    airspeed = {"topic": "/airspeed", "field": "data", "scale": 0.514444, "trim_m_s": 51.4}
    ch = parse_config(with_change(("channels", "pitch", "airspeed"), airspeed), "cfg.yaml").channels["pitch"]
    assert ch.airspeed.topic == "/airspeed" and ch.airspeed.scale == pytest.approx(0.514444)
    assert ch.trim_airspeed_m_s == 51.4
    assert [s for s, _ in ch.extra_streams()] == ["airspeed"] and ch.signal("airspeed") is ch.airspeed


@pytest.mark.parametrize(
    "value,needle",
    [
        ({"topic": "/airspeed", "field": "data"}, "channels.pitch.airspeed.trim_m_s: missing"),
        ({"topic": "/airspeed", "field": "data", "trim_m_s": 0}, "channels.pitch.airspeed.trim_m_s"),
        ({"topic": "/airspeed", "field": "data", "trim_m_s": "fast"}, "channels.pitch.airspeed.trim_m_s"),
        (
            {"topic": "/airspeed", "field": "data", "trim_m_s": 50, "frame": "flu"},
            "channels.pitch.airspeed.frame",
        ),
        (
            {"topic": "/airspeed", "field": "data", "trim_m_s": 50, "units": "kt"},
            "channels.pitch.airspeed.units: unknown",
        ),
        ({"field": "data", "trim_m_s": 50}, "channels.pitch.airspeed.topic: missing"),
        (51.4, "channels.pitch.airspeed: expected a mapping"),
    ],
)
def test_airspeed_errors_name_the_key(value, needle):
    with pytest.raises(ConfigError) as err:
        parse_config(with_change(("channels", "pitch", "airspeed"), value), "cfg.yaml")
    assert "\n" not in str(err.value) and needle in str(err.value)
