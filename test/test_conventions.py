"""Issue 23: the mistakes every user makes -- a sign, units, the body frame, a clock -- named as such (never
as physics), with the fix in the config; on flights of our simulator (which flies each mistake: ``--flip``,
``--degrees``, ``--imu-frame flu``, ``--stamp-offset``), of the second simulator (its nominal config
rewritten) and a NASA-style short run; a clean flight names none."""
import copy
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from gap_validation.cli.main import main
from gap_validation.core.config import load_config, parse_config
from gap_validation.core.conventions import DEGREES, Convention, candidates, fit_clock
from gap_validation.core.errors import ConfigError
from gap_validation.core.simulation import FlightOptions, simulate_flight
from gap_validation.core.validator import OnlineValidator

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "ultrastick25e.yaml"
CARD = dict(sweeps_per_channel=2, sweep_duration_s=40.0)


def _validate(config, flight):
    validator = OnlineValidator(config)
    for name, ch in config.channels.items():
        validator.add_histories(name, flight.histories(ch))
    validator.finish()
    return validator.results()


@pytest.fixture(scope="module")
def config():
    return load_config(CONFIG)


@pytest.mark.parametrize("mistake, kinds, stream", [
    (dict(flips=(("pitch", "input"),)), {"pitch": "sign"}, "input"),
    (dict(surfaces_in_degrees=True), {"roll": "units", "pitch": "units", "yaw": "units"}, "input"),
    (dict(imu_frame="flu"), {"pitch": "body_frame", "yaw": "body_frame"}, "output"),
    (dict(stamp_offsets=(("/control_surfaces", 0.04),)), {"roll": "clock_offset", "pitch": "clock_offset",
                                                          "yaw": "clock_offset"}, "input"),
])
def test_each_mistake_is_named_with_its_kind_and_stream_and_the_fix_brings_epsilon_back(
    config, mistake, kinds, stream
):
    clean = _validate(config, simulate_flight(config, {}, FlightOptions(**CARD), seed=5))
    flown = simulate_flight(config, {}, FlightOptions(**CARD, **mistake), seed=5)
    result = _validate(config, flown)
    for name, ch in result.channels.items():
        if name not in kinds:
            assert not ch.conventions and not ch.diagnosis, (name, ch.message)
            continue
        assert [c.kind for c in ch.conventions] == [kinds[name]], (name, ch.message)
        assert ch.conventions[0].stream == stream
        assert not ch.diagnosis, ch.message                   # no physical effect named
        assert "not physics" in ch.message and ch.margins.gain_margin_db is None
    # the fix, written into the config, gives the clean flight's numbers
    raw = copy.deepcopy(config.raw)
    for ch in result.channels.values():
        for convention in ch.conventions:
            for change in convention.changes:
                raw["channels"][change["channel"]][change["stream"]][change["key"]] = change["value"]
    fixed = _validate(parse_config(raw, "fixed"), flown)
    for name, ch in fixed.channels.items():
        assert not ch.conventions and ch.limited_by != "model", (name, ch.message)
        assert ch.epsilon == pytest.approx(clean.channels[name].epsilon, rel=0.05, abs=0.01)


def test_a_clean_flight_names_no_convention(config):
    result = _validate(config, simulate_flight(config, {}, FlightOptions(**CARD), seed=6))
    assert all(not ch.conventions for ch in result.channels.values())
    assert all(
        json.loads(json.dumps(ch.to_json_dict()))["conventions"] == [] for ch in result.channels.values()
    )


def test_a_nasa_style_short_run_with_its_elevator_reversed_is_a_sign(config):
    """1 s of trim, one 3-2-1-1, 8 s at 50 Hz, the elevator logged with the opposite sign."""
    pitch = type(config)(channels={"pitch": config.channels["pitch"]}, source=config.source, raw=config.raw)
    options = FlightOptions(
        excitation="3211",
        imu_rate_hz=50.0,
        surface_rate_hz=50.0,
        trim_s=1.0,
        sweeps_per_channel=1,
        multistep_unit_s=0.5,
        duration_s=8.0,
        flips=(("pitch", "input"),),
    )
    ch = _validate(pitch, simulate_flight(pitch, {}, options, seed=2)).channels["pitch"]
    assert [c.kind for c in ch.conventions] == ["sign"], ch.message
    assert ch.conventions[0].changes == [
        {"channel": "pitch", "stream": "input", "key": "scale", "value": -1.0}
    ]


def test_convention_factors_and_the_clock_fit():
    factors = {round(c.factor, 9) for c in candidates()}
    assert -1.0 in factors and round(1 / DEGREES, 9) in factors and round(-DEGREES, 9) in factors
    assert {round(10.0 ** k, 9) for k in (-3, -2, -1, 1, 2, 3)} <= factors
    w = np.geomspace(1.0, 40.0, 30)
    assert fit_clock(w, np.exp(1j * w * 0.037), np.ones(w.size)) == pytest.approx(0.037, abs=5e-4)
    back = Convention.from_json_dict(
        Convention(
            "units",
            factor=0.0174533,
            stream="input",
            fix="f",
            sentence="s",
            changes=[{"channel": "a", "stream": "input", "key": "scale", "value": 0.0174533}],
        ).to_json_dict()
    )
    assert back.factor == pytest.approx(0.0174533) and back.changes[0]["key"] == "scale"


def test_stream_keys_offset_time_offset_and_frame_are_applied_and_checked(config):
    raw = copy.deepcopy(config.raw)
    raw["channels"]["pitch"]["input"].update(offset=-1500.0, scale=0.0007, time_offset_s=-0.02)
    raw["channels"]["pitch"]["output"]["frame"] = "flu"
    spec = parse_config(raw, "x").channels["pitch"]
    assert spec.input.value(np.array([2000.0])) == pytest.approx([0.35])
    assert spec.output.gain == -1.0 and spec.input.time_offset_s == -0.02
    for key, value, needle in (
        ("frame", "ned", "frame"),
        ("offset", "x", "offset"),
        ("time_offset_s", float("nan"), "time_offset_s"),
    ):
        bad = copy.deepcopy(config.raw)
        bad["channels"]["roll"]["output" if key == "frame" else "input"][key] = value
        with pytest.raises(ConfigError, match=needle):
            parse_config(bad, "bad.yaml")
    bad = copy.deepcopy(config.raw)
    bad["channels"]["roll"]["input"]["frame"] = "flu"           # position[aileron] has no x/y/z
    with pytest.raises(ConfigError, match="frame"):
        parse_config(bad, "bad.yaml")


def test_simulate_flies_the_mistakes_and_refuses_bad_ones_in_one_line(tmp_path, capsys):
    out = tmp_path / "flight"
    assert (
        main(
            [
                "simulate",
                "--config",
                str(CONFIG),
                "--out",
                str(out),
                "--sweeps",
                "1",
                "--sweep-duration",
                "30",
                "--imu-frame",
                "flu",
                "--seed",
                "1",
            ]
        )
        == 0
    )
    assert main(["replay", str(out), "--config", str(CONFIG), "--no-history", "--no-progress",
                 "--json", str(tmp_path / "r.json")]) == 0
    data = json.loads((tmp_path / "r.json").read_text())
    assert [c["kind"] for c in data["channels"]["pitch"]["conventions"]] == ["body_frame"]
    capsys.readouterr()
    for args, needle in ((["--flip", "elevator:input"], "--flip elevator:input"),
                         (["--stamp-offset", "/nope:0.1"], "--stamp-offset /nope:0.1"),
                         (["--stamp-offset", "/imu"], "--stamp-offset /imu")):
        code = main(["simulate", "--config", str(CONFIG), "--out", str(tmp_path / "x"), *args])
        err = capsys.readouterr().err.strip()
        assert code == 2 and needle in err and "Traceback" not in err and len(err.splitlines()) == 1, err


SHARED = ROOT.parent / "shared" / "flights"


@pytest.mark.skipif(
    not (SHARED / "flightgen.py").exists(), reason="../shared/flights is not beside the checkout"
)
def test_the_second_simulators_clean_flight_against_configs_with_each_mistake(tmp_path):
    """The second simulator's clean case, its nominal config rewritten with each mistake (the config now wrong
    where the flight is right): named with the right kind and stream, nothing physical named."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import second_simulator as bench

    from gap_validation.bag.replay import replay

    cases = bench.load_cases()
    where = bench.make("clean", cases["clean"], tmp_path)
    import yaml

    nominal = yaml.safe_load((where / "nominal.yaml").read_text())

    def run(change, fixes=()):
        raw = copy.deepcopy(nominal)
        change(raw["channels"])
        for fix in fixes:
            raw["channels"][fix["channel"]][fix["stream"]][fix["key"]] = fix["value"]
        return replay([where / "bag"], parse_config(raw, "rewritten.yaml")).result.channels

    clean = run(lambda chs: None)

    def sign(chs):
        chs["roll"]["model"]["numerator"] = [-v for v in chs["roll"]["model"]["numerator"]]

    def degrees(chs):
        for ch in chs.values():
            ch["input"]["scale"] = DEGREES

    def flu(chs):
        for ch in chs.values():
            ch["output"]["frame"] = "flu"

    def clock(chs):
        for ch in chs.values():
            ch["input"]["time_offset_s"] = 0.04

    for change, expected, stream in ((sign, {"roll": "sign"}, "input"),
                                     (degrees, {"roll": "units", "pitch": "units", "yaw": "units"}, "input"),
                                     (flu, {"pitch": "body_frame", "yaw": "body_frame"}, "output"),
                                     (clock, {"roll": "clock_offset", "pitch": "clock_offset",
                                              "yaw": "clock_offset"}, "input")):
        channels = run(change)
        for name, ch in channels.items():
            assert [c.kind for c in ch.conventions] == ([expected[name]] if name in expected else []), \
                (change.__name__, name, ch.message)
            assert not ch.diagnosis, (change.__name__, name, ch.message)
            if name in expected:
                assert ch.conventions[0].stream == stream, (change.__name__, ch.conventions[0])
        # the written fix gives the clean config's numbers back
        fixed = run(change, [fix for ch in channels.values() for c in ch.conventions for fix in c.changes])
        for name, ch in fixed.items():
            assert not ch.conventions and ch.limited_by != "model", (change.__name__, name, ch.message)
            assert ch.epsilon == pytest.approx(clean[name].epsilon, rel=0.05, abs=0.01), (
                change.__name__,
                name,
            )
