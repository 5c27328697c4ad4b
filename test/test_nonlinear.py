"""Amplitude-dependent effects (issue 15, part 3): ``rate_limit`` and ``backlash`` as describing functions
(pinned against a time-domain simulation of a sinusoid through the element, the describing function's own
definition), as hidden effects of the simulator, fitted by the diagnosis at the flown amplitude, and sweeps at
different amplitudes that disagree called nonlinear (never on a linear flight)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from _flights import SHORT, config_from, make_bag, single_channel

from gap_validation.bag.replay import replay
from gap_validation.cli.arguments import parse_hidden
from gap_validation.core.effects import (
    backlash_df,
    backlash_output,
    effect_response,
    rate_limit_df,
    rate_limited,
    validate_effect,
)
from gap_validation.core.errors import ConfigError
from gap_validation.core.estimator import record_amplitude
from gap_validation.core.models import LinearModel
from gap_validation.core.nonlinearity import NONLINEARITY, flown_amplitude
from gap_validation.core.simulation import FlightOptions, log_sweep


def first_harmonic(element, amplitude: float, w: float, periods: int = 30, per_period: int = 8000) -> complex:
    """First harmonic of a sinusoid through ``element(t, u)`` over its last 10 periods, over the input's."""
    t = np.arange(periods * per_period) * (2 * math.pi / w) / per_period
    y = element(t, amplitude * np.sin(w * t))[-10 * per_period:]
    t = t[-10 * per_period:]
    return complex(2 * np.mean(y * np.sin(w * t)), 2 * np.mean(y * np.cos(w * t))) / amplitude


# ------------------------------------------------------------------------------------------------ describing
# functions
@pytest.mark.parametrize("rho", [0.3, 0.5, 0.537, 0.55, 0.7, 0.9, 0.99, 1.5])
def test_rate_limit_describing_function_is_the_first_harmonic_of_a_simulated_sinusoid(rho):
    amplitude, w = 0.05, 10.0
    simulated = first_harmonic(lambda t, u: rate_limited(t, u, rho * amplitude * w), amplitude, w)
    assert abs(rate_limit_df(rho) - simulated) < 1e-4, (rate_limit_df(rho), simulated)


def test_rate_limit_describing_function_regimes():
    # a triangle wave of slope R far below the limit: 4 rho / pi, lagging by acos(pi rho / 2)
    assert rate_limit_df(0.1) == pytest.approx(0.4 / math.pi * np.exp(-1j * math.acos(math.pi * 0.05)))
    assert rate_limit_df(1.0) == 1.0 and rate_limit_df(3.0) == 1.0       # never reached: no effect
    rho = np.linspace(0.05, 1.0, 200)
    n = rate_limit_df(rho)
    assert np.all(np.diff(np.abs(n)) > 0) and np.all(np.angle(n) < 1e-12)  # more limited: smaller, later
    assert np.max(np.abs(np.diff(n))) < 0.02                            # continuous across the regimes


@pytest.mark.parametrize("ratio", [0.05, 0.3, 0.6, 1.0, 1.5, 1.9])
def test_backlash_describing_function_is_the_first_harmonic_of_a_simulated_sinusoid(ratio):
    amplitude, w = 0.05, 3.0
    simulated = first_harmonic(lambda t, u: backlash_output(u, ratio * amplitude), amplitude, w)
    assert abs(backlash_df(ratio) - simulated) < 1e-5, (backlash_df(ratio), simulated)


def test_backlash_of_the_issue_is_about_minus_07_db_and_minus_10_deg():
    n = backlash_df(0.015 / 0.05)          # 0.015 rad of free play at 0.05 rad sweeps
    assert 20 * math.log10(abs(n)) == pytest.approx(-0.72, abs=0.02)
    assert math.degrees(np.angle(n)) == pytest.approx(-10.2, abs=0.2)
    assert backlash_df(2.5) == 0.0         # the input never crosses the free play: the surface stays put


def test_effect_response_of_a_nonlinear_effect_needs_the_amplitude():
    spec = validate_effect({"type": "rate_limit", "rad_s": 0.8})
    w = np.array([1.0, 16.0, 40.0])
    np.testing.assert_allclose(effect_response(spec, w, 0.05), rate_limit_df(0.8 / (0.05 * w)))
    with pytest.raises(ConfigError, match="depends on the input amplitude"):
        effect_response(spec, w)
    with pytest.raises(ConfigError, match=r"^effect\.rad_s: "):
        validate_effect({"type": "rate_limit", "rad_s": -1.0}, where="effect")


# ------------------------------------------------------------------------------------------------ the model
def test_linear_model_with_a_nonlinear_effect():
    plain = LinearModel([4.0], [1.0, 4.0])
    model = plain.with_effects([{"type": "backlash", "width_rad": 0.01}])
    np.testing.assert_array_equal(model.num, plain.num)          # the linear part is the linear part
    np.testing.assert_array_equal(model.den, plain.den)
    assert model.nonlinear and not plain.nonlinear and plain.at_amplitude(0.05) is plain
    w = np.geomspace(0.1, 100.0, 7)
    with pytest.raises(ConfigError, match=r"model\.effects\[0\] \(backlash\) depends on the input amplitude"):
        model.freqresp(w)
    np.testing.assert_allclose(model.at_amplitude(0.05).freqresp(w), plain.freqresp(w) * backlash_df(0.2))
    # the time response applies the element on the command, before the airframe
    t = np.arange(0.0, 20.0, 0.005)
    u = 0.05 * np.sin(2.0 * t)
    np.testing.assert_allclose(model.simulate(t, u), plain.simulate(t, backlash_output(u, 0.01)))
    assert model.to_spec()["effects"] == [{"type": "backlash", "width_rad": 0.01}]
    assert LinearModel.from_spec(model.to_spec()).nonlinear


def test_record_amplitude_of_a_chirp_on_a_trim_ramp_is_its_amplitude():
    t = np.arange(0.0, 60.0, 0.01)
    u = 0.05 * log_sweep(t, 60.0, 0.5, 50.0) + 0.03 + 0.0002 * t
    assert record_amplitude(u) == pytest.approx(0.05, rel=0.02)
    assert math.isnan(record_amplitude(np.array([1.0, 2.0])))


def test_flown_amplitude_weights_the_records_by_their_input_power():
    class Raw:
        def __init__(self, amplitude, gxx):
            self.amplitude, self.gxx = amplitude, np.asarray(gxx, float)
            self.response = np.where(self.gxx > 0, 1.0 + 0j, np.nan)

    w = np.array([1.0, 2.0, 3.0])
    amp = flown_amplitude(w, [Raw(0.02, [1.0, 1.0, 0.0]), Raw(0.06, [1.0, 3.0, 0.0])])
    np.testing.assert_allclose(amp, [0.04, 0.05, (0.02 * 2 + 0.06 * 4) / 6])
    assert flown_amplitude(w, [Raw(float("nan"), [1.0, 1.0, 1.0])]) is None


# ------------------------------------------------------------------------------------------------ simulator
def test_hidden_nonlinear_effects_parse_and_act_on_the_command():
    assert parse_hidden("pitch:rate_limit:rad_s=0.8") == ("pitch", {"type": "rate_limit", "rad_s": 0.8})
    assert parse_hidden("roll:backlash:width_rad=0.015")[1] == {"type": "backlash", "width_rad": 0.015}
    with pytest.raises(ConfigError, match="rad_s"):
        parse_hidden("pitch:rate_limit:rad_s=0")
    config = config_from(single_channel("pitch"))
    from gap_validation.core.simulation import simulate_flight

    options = FlightOptions(sweeps_per_channel=2, sweep_duration_s=10.0, quiet_s=1.0, noise=0.0,
                            sweep_amplitude_scales=(1.0, 0.5))
    flight = simulate_flight(config, {"pitch": [{"type": "rate_limit", "rad_s": 0.8}]}, options, seed=3)
    truth = flight.truth["pitch"]
    linear = config.channels["pitch"].model
    t, u = flight.t_s, flight.inputs["pitch"]
    np.testing.assert_allclose(flight.outputs["pitch"], linear.simulate(t, rate_limited(t, u, 0.8)))
    assert truth.nonlinear
    sweeps = flight.sweeps("pitch")
    peak = [np.max(np.abs(u[(t >= s.start_s) & (t <= s.end_s)])) for s in sweeps]
    assert peak[1] == pytest.approx(0.5 * peak[0], rel=1e-6)             # the second round at half amplitude
    with pytest.raises(ConfigError, match="sweep_amplitude_scales"):
        FlightOptions(sweep_amplitude_scales=(1.0, -1.0)).check()


# ------------------------------------------------------------------------------------------------ diagnosis
def _replay(tmp_path, channel, hidden, seed=1, **options):
    config = config_from(single_channel(channel))
    make_bag(tmp_path / "flight", config, hidden=hidden, seed=seed, options=SHORT, **options)
    return config, replay([tmp_path / "flight"], config).result.channels[channel]


def test_rate_limited_axis_is_fitted_as_a_rate_limit_not_a_mode(tmp_path):
    """0.8 rad/s at 0.05 rad sweeps (issue 15), also flown at 0.4 of that (issue 22: an amplitude-dependent
    effect is named only where sweeps at two amplitudes disagree): was a structural mode at the grid top; a
    rate limit."""
    config, result = _replay(tmp_path, "pitch", ["pitch:rate_limit:rad_s=0.8"], sweep_amplitude_rad=0.05,
                             sweep_amplitude_scales=(1.0, 0.4))
    assert result.limited_by == "model"
    assert result.nonlinearity == NONLINEARITY
    top = result.diagnosis[0]
    assert top["effect"] == "rate_limit", result.message
    assert top["effects"][0]["rad_s"] == pytest.approx(0.8, rel=0.1)
    assert "surface rate limit of 0.7" in result.message or "surface rate limit of 0.8" in result.message
    assert "(nonlinear, amplitude-dependent)" in result.message
    assert top["epsilon"] <= result.epsilon / 2
    assert sorted({round(a / 0.05, 1) for a in result.input_amplitudes}) == [0.4, 1.0]
    # applied like the others: the model then describes the flight (at the amplitude flown)
    fixed = config.with_channel_effects("pitch", top["effects"])
    after = replay([tmp_path / "flight"], fixed).result.channels["pitch"]
    assert after.epsilon == pytest.approx(top["epsilon"], rel=1e-6)
    assert after.limited_by != "model" and after.diagnosis == [], after.message


def test_sweeps_at_two_amplitudes_call_a_rate_limit_nonlinear(tmp_path):
    _, result = _replay(tmp_path, "pitch", ["pitch:rate_limit:rad_s=0.8"], sweep_amplitude_rad=0.05,
                        sweep_amplitude_scales=(1.0, 0.4))
    assert result.nonlinearity == NONLINEARITY
    assert NONLINEARITY in result.message and "disagree beyond their errors" in result.nonlinearity_evidence
    data = result.to_json_dict()
    assert data["nonlinearity"] == NONLINEARITY and len(data["input_amplitudes"]) == 2


def test_one_amplitude_names_no_nonlinear_effect_and_no_mode(tmp_path):
    """Issue 22: at a single amplitude a rate limit fits like any lag; nothing amplitude-dependent is named
    from one amplitude's mismatch, and no structural mode either."""
    _, result = _replay(tmp_path, "pitch", ["pitch:rate_limit:rad_s=0.8"], sweep_amplitude_rad=0.05)
    assert result.limited_by == "model"
    named = {e["type"] for c in result.diagnosis for e in c["effects"]}
    assert not named & {"rate_limit", "backlash", "structural_mode"}, result.message


def test_backlash_is_not_named_a_structural_mode(tmp_path):
    _, result = _replay(tmp_path, "roll", ["roll:backlash:width_rad=0.015"], sweep_amplitude_rad=0.03,
                        sweep_amplitude_scales=(1.0, 2.0))
    assert result.limited_by == "model", result.message
    top = result.diagnosis[0]
    assert top["effect"] == "backlash", result.message
    # within the 25 % a named effect must meet (issue 22); measured 0.0166 since records keep the pause after
    # their manoeuvre (0.015 with the pause split at its midpoint)
    assert top["effects"][0]["width_rad"] == pytest.approx(0.015, rel=0.25)
    assert "structural mode" not in result.message


def test_a_linear_flight_at_two_amplitudes_is_not_called_nonlinear(tmp_path):
    _, result = _replay(
        tmp_path, "pitch", [], seed=2, sweep_amplitude_rad=0.05, sweep_amplitude_scales=(1.0, 0.4)
    )
    assert result.nonlinearity is None, result.message
    assert "agree within their errors" in result.nonlinearity_evidence
    assert result.limited_by != "model" and result.diagnosis == [], result.message


def test_a_checkpoint_without_amplitudes_loads_with_them_unknown():
    from gap_validation.core.estimator import FrequencyResponseEstimator

    t = np.arange(0.0, 80.0, 0.01)
    u = 0.04 * log_sweep(t - 10.0, 60.0, 1.0, 20.0)
    est = FrequencyResponseEstimator(np.geomspace(2.0, 15.0, 8))
    est.add_time_histories(t, u, t, np.convolve(u, np.ones(5) / 5.0, mode="same"))
    est.flush()
    assert [s.amplitude for s in est.sweeps] == [pytest.approx(0.04, rel=0.03)]
    state = est.state_dict()
    del state["raw_amplitude"]                 # written before amplitudes were recorded
    old = FrequencyResponseEstimator.from_state(state)
    assert len(old.sweeps) == 1 and math.isnan(old.sweeps[0].amplitude)
    np.testing.assert_array_equal(old.sweeps[0].response, est.sweeps[0].response)


@pytest.mark.parametrize("effect, words", [
    ({"type": "rate_limit", "rad_s": 0.8}, "rate_limit depends on the input amplitude"),
    ({"type": "zero_order_hold", "rate_hz": 50.0}, "zero_order_hold is not a rational factor")])
def test_compare_models_refuses_an_amplitude_dependent_model_or_a_hold(tmp_path, capsys, effect, words):
    import yaml
    from _flights import ROOT

    from gap_validation.cli.main import main

    p1 = ROOT / "config" / "paper_example_p1.yaml"
    data = yaml.safe_load(p1.read_text())
    data["channels"]["pitch"]["model"]["effects"] = [effect]
    other = tmp_path / "other.yaml"
    other.write_text(yaml.safe_dump(data))
    assert main(["compare-models", str(other), str(p1)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"channels.pitch.model.effects: {words}" in err
