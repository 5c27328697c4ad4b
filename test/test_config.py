"""Config schema: the DESIGN.md format parses; every mistake is one ConfigError line naming file, key, value."""
import copy

import numpy as np
import pytest

from gap_validation.config import dump_config, load_config
from gap_validation.core.config import parse_config
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
    assert w.size == 40 and np.isclose(w[0], 1.0) and np.isclose(w[-1], 60.0)
    assert np.all(np.diff(np.log(w)) > 0)
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
    dump_config(cfg.with_channel_effects("pitch", [{"type": "first_order_lag", "bandwidth_rad_s": 37.7}]), out)
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
