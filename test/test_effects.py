"""Effects vocabulary: names, validation (one-line ConfigError naming the key), factors and descriptions."""

import math

import numpy as np
import pytest

from gap_validation.core.effects import (
    EFFECT_TYPES,
    EFFECTS,
    EffectType,
    Parameter,
    check_plausible,
    describe_effect,
    effect_factor,
    effect_response,
    validate_effect,
)
from gap_validation.core.errors import ConfigError
from gap_validation.core.numbers import POSITIVE, Interval

W = np.geomspace(0.1, 300.0, 57)
S = 1j * W


def test_vocabulary_is_the_design_contract():
    assert EFFECT_TYPES == {
        "time_delay": ("seconds",),
        "first_order_lag": ("bandwidth_rad_s",),
        "second_order_lag": ("natural_frequency_rad_s", "damping"),
        "gain": ("factor",),
        "structural_mode": ("frequency_rad_s", "damping", "zero_frequency_rad_s", "zero_damping"),
        "rate_limit": ("rad_s",),
        "backlash": ("width_rad",),
        "zero_order_hold": ("rate_hz",),      # added after DESIGN.md's table ("more may be added")
    }


@pytest.mark.parametrize(
    "spec, expected",
    [
        ({"type": "time_delay", "seconds": 0.045}, np.exp(-S * 0.045)),
        ({"type": "first_order_lag", "bandwidth_rad_s": 37.7}, 37.7 / (S + 37.7)),
        ({"type": "second_order_lag", "natural_frequency_rad_s": 30.0, "damping": 0.4},
         900.0 / (S**2 + 2 * 0.4 * 30.0 * S + 900.0)),
        ({"type": "gain", "factor": 1.25}, 1.25 * np.ones_like(S)),
        ({"type": "structural_mode", "frequency_rad_s": 60.0, "damping": 0.02, "zero_frequency_rad_s": 55.0,
          "zero_damping": 0.03},
         (S**2 / 55.0**2 + 2 * 0.03 * S / 55.0 + 1) / (S**2 / 60.0**2 + 2 * 0.02 * S / 60.0 + 1)),
    ],
)
def test_effect_response_matches_table_formula(spec, expected):
    np.testing.assert_allclose(effect_response(spec, W), expected, rtol=1e-12, atol=1e-14)
    num, den, delay_s = effect_factor(spec)
    rational = np.polyval(num, S) / np.polyval(den, S) * np.exp(-S * delay_s)
    np.testing.assert_allclose(rational, expected, rtol=1e-12, atol=1e-14)


def test_validate_returns_normalised_floats_and_accepts_yaml_exponent_strings():
    spec = validate_effect({"type": "time_delay", "seconds": "5e-2"})
    assert spec == {"type": "time_delay", "seconds": 0.05}
    assert validate_effect({"damping": 1, "type": "second_order_lag", "natural_frequency_rad_s": 3}) == {
        "type": "second_order_lag", "natural_frequency_rad_s": 3.0, "damping": 1.0}


@pytest.mark.parametrize(
    "spec, fragment",
    [
        (
            {"type": "time_delay", "seconds": "abc"},
            "model.effects[1].seconds: expected a number >= 0, got 'abc'",
        ),
        ({"type": "time_delay", "seconds": -0.1}, "model.effects[1].seconds: expected a number >= 0"),
        ({"type": "time_delay", "seconds": True}, "model.effects[1].seconds"),
        ({"type": "time_delay", "seconds": float("nan")}, "model.effects[1].seconds"),
        ({"type": "time_delay"}, "missing parameter 'seconds'"),
        ({"type": "time_delay", "seconds": 0.1, "sec": 2}, "model.effects[1].sec: unknown parameter"),
        ({"type": "delay", "seconds": 0.1}, "model.effects[1].type: unknown effect type 'delay'"),
        ({"seconds": 0.1}, "missing key 'type'"),
        ({"type": "first_order_lag", "bandwidth_rad_s": 0.0}, "bandwidth_rad_s: expected a number > 0"),
        ({"type": "second_order_lag", "natural_frequency_rad_s": 3.0, "damping": -0.1}, "damping: expected"),
        ({"type": "gain", "factor": 0}, "factor: expected a nonzero number"),
        ({"type": "gain", "factor": float("inf")}, "factor"),
        (
            {
                "type": "structural_mode",
                "frequency_rad_s": 60.0,
                "damping": 0.02,
                "zero_frequency_rad_s": -55.0,
                "zero_damping": 0.03,
            },
            "zero_frequency_rad_s: expected a number > 0",
        ),
        ("time_delay", "expected a mapping"),
    ],
)
def test_bad_effects_raise_one_line_config_error_naming_the_key(spec, fragment):
    with pytest.raises(ConfigError) as info:
        validate_effect(spec, where="model.effects[1]")
    message = str(info.value)
    assert fragment in message
    assert "\n" not in message


@pytest.mark.parametrize(
    "spec, text",
    [
        ({"type": "time_delay", "seconds": 0.045}, "time delay of 45 ms"),
        ({"type": "time_delay", "seconds": 0.0025}, "time delay of 2.5 ms"),
        ({"type": "first_order_lag", "bandwidth_rad_s": 37.7}, "first-order lag at 37.7 rad/s (6.0 Hz)"),
        ({"type": "gain", "factor": 1.25}, "gain error x1.25"),
        ({"type": "second_order_lag", "natural_frequency_rad_s": 2 * math.pi * 8, "damping": 0.7},
         "second-order lag at 50.3 rad/s (8.0 Hz), damping 0.70"),
    ],
)
def test_describe_effect(spec, text):
    assert describe_effect(spec) == text


def test_describe_structural_mode_names_both_frequencies():
    text = describe_effect({"type": "structural_mode", "frequency_rad_s": 60.0, "damping": 0.02,
                            "zero_frequency_rad_s": 55.0, "zero_damping": 0.03})
    assert text.startswith("structural mode at 60.0 rad/s (9.5 Hz)")
    assert "55.0 rad/s" in text


# ------------------------------------------------------------------------------------------------ the
# registry
def test_one_registry_entry_per_effect_serves_every_reader():
    from gap_validation.core import diagnosis

    assert EFFECT_TYPES == {name: entry.names for name, entry in EFFECTS.items()}
    assert all(
        diagnosis.FAMILIES[name] is entry.fit for name, entry in EFFECTS.items() if entry.factor is not None
    )
    assert all(
        diagnosis.NONLINEAR_FAMILIES[name] is entry for name, entry in EFFECTS.items() if entry.factor is None
    )
    for name, entry in EFFECTS.items():
        spec = {"type": name, **{p.name: 0.5 for p in entry.parameters}}
        amplitude = None if entry.factor is not None else 0.7        # a describing function needs it
        np.testing.assert_array_equal(entry.response(spec, W, amplitude), effect_response(spec, W, amplitude))
        assert entry.complexity == len(entry.parameters)


@pytest.mark.parametrize("spec, key, value", [
    ({"type": "time_delay", "seconds": 45.0}, "seconds", 45.0),
    ({"type": "gain", "factor": -1e9}, "factor", -1e9),
    ({"type": "second_order_lag", "natural_frequency_rad_s": 30.0, "damping": 1e4}, "damping", 1e4),
])
def test_plausible_ranges_name_the_key(spec, key, value):
    with pytest.raises(
        ConfigError, match=rf"^model.effects\[0\]\.{key}: {value!r} is outside the plausible range"
    ):
        check_plausible(validate_effect(spec), "model.effects[0]")
    check_plausible(validate_effect({"type": "gain", "factor": -2.0}), "model.effects[0]")  # |k| counts


def test_an_amplitude_dependent_effect_is_one_more_entry():
    """A describing function (e.g. a rate limit, N(A, w)) needs no factor: the response takes the
    amplitude."""
    rate_limit = EffectType(
        "rate_limit", (Parameter("rad_s", POSITIVE, Interval(1e-3, 1e3)),), factor=None,
        describe=lambda p: f"rate limit of {p['rad_s']:.3g} rad/s",
        describing_function=lambda p, w, a: np.minimum(1.0, p["rad_s"] / (np.asarray(a) * w)) + 0j)
    params = {"rad_s": 2.0}
    response = rate_limit.response(params, W, amplitude=0.1)
    assert response.shape == W.shape and np.all(np.abs(response) <= 1.0)
    assert response[0] == 1.0 and abs(response[-1]) < 0.1        # slow inputs pass, fast ones are limited
    with pytest.raises(ConfigError, match="depends on the input amplitude"):
        rate_limit.response(params, W)


def test_a_zero_order_hold_is_its_textbook_response_and_its_simulation_samples_and_holds():
    """(1 - exp(-s T)) / (s T) at s = j w (Franklin, Powell & Workman, Digital Control, the ZOH's response);
    the simulated model holds its input for T and the fundamental of its sine response is the frequency
    response."""
    from gap_validation.core.models import LinearModel

    w = np.array([0.5, 5.0, 44.3, 100.0, 2 * np.pi * 20.0])
    spec = {"type": "zero_order_hold", "rate_hz": 20.0}
    expected = (1.0 - np.exp(-1j * w * 0.05)) / (1j * w * 0.05)
    assert np.allclose(effect_response(spec, w), expected, rtol=1e-12, atol=1e-15)
    assert abs(effect_response(spec, np.array([2 * np.pi * 20.0]))[0]) < 1e-12      # a null at the hold rate
    assert effect_factor(spec)[2] == pytest.approx(0.025)                              # its delay, T/2
    plant = LinearModel([1.0], [1.0, 5.0])
    model = plant.with_effects([spec])
    assert np.allclose(model.freqresp(w[:3]), plant.freqresp(w[:3]) * expected[:3])
    t = np.arange(0.0, 40.0, 1e-3)
    u = np.sin(7.0 * t)
    y_held = LinearModel([1.0], [1.0]).with_effects([spec]).simulate(t, u)
    ticks = np.floor(t * 20.0 + 1e-9) / 20.0
    assert np.allclose(y_held, np.sin(7.0 * ticks), atol=1e-9)                        # sampled and held
    for wt in (5.0, 30.0):
        y = model.simulate(t, np.sin(wt * t))
        keep = t > 10.0
        basis = np.c_[np.sin(wt * t[keep]), np.cos(wt * t[keep])]
        re, im = np.linalg.lstsq(basis, y[keep], rcond=None)[0]
        h = model.freqresp(np.array([wt]))[0]
        # the images of the hold are not the response
        assert abs(complex(re, im) - h) < 0.03 * abs(h)


@pytest.mark.parametrize("value", [0.0, -20.0, "fast"])
def test_a_bad_hold_rate_is_one_line(value):
    with pytest.raises(ConfigError) as err:
        validate_effect({"type": "zero_order_hold", "rate_hz": value}, "model.effects[0]")
    assert "model.effects[0].rate_hz" in str(err.value) and "\n" not in str(err.value)
