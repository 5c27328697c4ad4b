"""LinearModel: config forms, Ultra Stick 25e models, effects in series, exact delay, simulation."""

import math

import numpy as np
import pytest
import scipy.signal

from gap_validation.core.errors import ConfigError
from gap_validation.core.models import LinearModel, MimoModel

# Ultra Stick 25e linearisation (17 m/s), UASLab/OpenFlight, as in ../shared/reference/ultrastick25e.yaml.
SHORT_PERIOD = {"A": [[-15.81, -7.405], [15.72, -7.56]], "B": [[-133.7], [-2.703]], "C": [1.0, 0.0]}
LATERAL = {
    "A": [[-0.8726, 0.8968, -16.82, 9.791],
          [-2.757, -16.09, 3.368, 0.0],
          [1.708, 0.514, -2.775, 0.0],
          [0.0, 1.0, 0.05511, -1.507e-08]],
    "B": [[-4.198e-10, 7.984e-10, 5.302],
          [78.23, -78.23, -4.972],
          [-5.752, 5.752, -82.04],
          [0.0, 0.0, 0.0]],
    "C": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
}
W = np.geomspace(0.05, 500.0, 200)


def test_short_period_poles_and_transfer_function():
    model = LinearModel.from_spec({"state_space": SHORT_PERIOD})
    poles = np.sort_complex(model.poles())
    np.testing.assert_allclose(poles, [-11.685 - 9.9695j, -11.685 + 9.9695j], atol=1e-3)
    assert round(poles[1].real, 1) == -11.7 and round(poles[1].imag, 1) == 10.0
    np.testing.assert_allclose(model.num, [-133.7, -990.756285], rtol=1e-9)  # q/de: -133.7 s - 990.76
    np.testing.assert_allclose(model.den, [1.0, 23.37, 235.9302], rtol=1e-12)


def test_lateral_symmetric_aileron_to_roll_rate():
    model = LinearModel.from_spec({"state_space": dict(LATERAL, input=[1, -1, 0], output=1)})
    poles = model.poles()
    roll = poles[np.argmin(np.abs(poles + 16.0))]
    assert abs(roll.imag) < 1e-9
    assert abs(roll.real + 16.1) < 0.06  # -16.05 ("roll -16.1" in the published note)
    dutch = poles[np.argmax(poles.imag)]
    wn = abs(dutch)
    zeta = -dutch.real / wn
    assert round(wn, 2) == 5.60
    assert round(zeta, 2) == 0.33
    spiral = poles[np.argmin(np.abs(poles))]
    assert abs(spiral + 0.009) < 0.0005
    # the weight vector is B[:, 0] - B[:, 1]
    b = np.array(LATERAL["B"])
    explicit = {"A": LATERAL["A"], "B": (b[:, 0] - b[:, 1]).reshape(-1, 1).tolist(), "C": [0, 1, 0, 0]}
    np.testing.assert_allclose(
        LinearModel.from_spec({"state_space": explicit}).freqresp(W), model.freqresp(W), rtol=1e-10
    )
    # output as a weight vector too
    weighted = LinearModel.from_spec({"state_space": dict(LATERAL, input=[1, -1, 0], output=[0, 1, 0, 0])})
    np.testing.assert_allclose(weighted.freqresp(W), model.freqresp(W), rtol=1e-12)
    assert model.order == 4 and len(model.num) == 4  # relative degree one: leading round-off trimmed


def test_state_space_response_equals_matrix_formula():
    model = LinearModel.from_spec(
        {"state_space": dict(LATERAL, input=2, output=2, D=np.zeros((4, 3)).tolist())}
    )
    a, b, c = np.array(LATERAL["A"]), np.array(LATERAL["B"])[:, 2], np.array(LATERAL["C"])[2]
    direct = np.array([c @ np.linalg.solve(1j * w * np.eye(4) - a, b) for w in W])
    np.testing.assert_allclose(model.freqresp(W), direct, rtol=1e-9)


def test_tf_zpk_and_ss_forms_give_the_same_response():
    ss = LinearModel.from_spec({"state_space": SHORT_PERIOD})
    tf = LinearModel.from_spec({"numerator": [-133.7, -990.756285], "denominator": [1.0, 23.37, 235.9302]})
    zero = -990.756285 / 133.7
    pole = complex(-11.685, math.sqrt(235.9302 - 11.685**2))
    zpk_pairs = LinearModel.from_spec(
        {"zeros": [zero], "poles": [[pole.real, pole.imag], [pole.real, -pole.imag]], "gain": -133.7}
    )
    zpk_strings = LinearModel.from_spec({"zeros": [str(zero)], "poles": [str(pole), str(pole.conjugate())],
                                         "gain": -133.7})
    reference = tf.freqresp(W)
    for other in (ss, zpk_pairs, zpk_strings):
        np.testing.assert_allclose(other.freqresp(W), reference, rtol=1e-9)


@pytest.mark.parametrize(
    "spec",
    [
        {"numerator": [2.0, 3.0], "denominator": [1.0, 4.0, 5.0], "delay_s": 0.02,
         "effects": [{"type": "first_order_lag", "bandwidth_rad_s": 37.7}]},
        {"zeros": [-3.0], "poles": [[-1.0, 2.0], [-1.0, -2.0]], "gain": 4.0,
         "effects": [{"type": "time_delay", "seconds": 0.05}, {"type": "gain", "factor": 0.8}]},
        {"state_space": dict(LATERAL, input=[1, -1, 0], output=1)},
    ],
)
def test_to_spec_round_trips(spec):
    model = LinearModel.from_spec(spec)
    again = LinearModel.from_spec(model.to_spec())
    np.testing.assert_allclose(again.freqresp(W), model.freqresp(W), rtol=1e-12)
    assert again.delay_s == model.delay_s and again.effects == model.effects
    assert set(model.to_spec()) - {"delay_s", "effects"} == set(spec) - {"delay_s", "effects"}


def test_effects_multiply_the_response_and_sum_the_delays():
    base = LinearModel.from_spec(
        {"numerator": [18.75, 225.0], "denominator": [1.0, 9.0, 225.0], "delay_s": 0.01}
    )
    s = 1j * W
    cases = [
        ({"type": "time_delay", "seconds": 0.04}, np.exp(-0.04 * s)),
        ({"type": "first_order_lag", "bandwidth_rad_s": 20.0}, 20.0 / (s + 20.0)),
        ({"type": "second_order_lag", "natural_frequency_rad_s": 40.0, "damping": 0.5},
         1600.0 / (s**2 + 40.0 * s + 1600.0)),
        ({"type": "gain", "factor": -0.7}, -0.7 + 0 * s),
        ({"type": "structural_mode", "frequency_rad_s": 80.0, "damping": 0.05, "zero_frequency_rad_s": 70.0,
          "zero_damping": 0.02}, (s**2 / 4900 + 0.04 * s / 70 + 1) / (s**2 / 6400 + 0.1 * s / 80 + 1)),
    ]
    for effect, factor in cases:
        model = base.with_effects([effect])
        np.testing.assert_allclose(model.freqresp(W), base.freqresp(W) * factor, rtol=1e-10)
        assert model.airframe.effects == () and model.effects[0]["type"] == effect["type"]
    both = base.with_effects([cases[0][0], cases[1][0]])
    assert both.delay_s == pytest.approx(0.05)
    np.testing.assert_allclose(both.freqresp(W), base.freqresp(W) * cases[0][1] * cases[1][1], rtol=1e-10)
    np.testing.assert_allclose(both.airframe.freqresp(W), base.freqresp(W), rtol=1e-14)


def test_delay_in_frequency_response_is_exact():
    model = LinearModel.from_tf([1.0], [1.0], delay_s=0.05)
    np.testing.assert_allclose(model.freqresp([100.0]), [np.exp(-5j)], rtol=1e-14)


@pytest.mark.parametrize("hold", ["linear", "zero"])
def test_simulate_matches_scipy_lsim_on_a_uniform_grid(hold):
    model = LinearModel.from_spec({"state_space": dict(LATERAL, input=[1, -1, 0], output=1)}).with_effects(
        [{"type": "first_order_lag", "bandwidth_rad_s": 37.7}])
    t = np.arange(3000) * 0.01
    u = np.sin(0.7 * t) * np.sin(0.05 * t) + (t > 5.0)
    ours = model.simulate(t, u, hold=hold)
    _, reference, _ = scipy.signal.lsim((model.num, model.den), u, t, interp=(hold == "linear"))
    np.testing.assert_allclose(ours, reference, atol=1e-9 * np.max(np.abs(reference)))


def test_first_order_lag_step_response_is_analytic_on_irregular_grid():
    rng = np.random.default_rng(3)
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.002, 0.03, 2000))])
    t = np.concatenate([t[:700], t[800:] + 0.5])  # a dropout
    model = LinearModel.from_spec({"numerator": [1.0], "denominator": [1.0], "effects": [
        {"type": "first_order_lag", "bandwidth_rad_s": 4.0}]})
    y = model.simulate(t, np.ones_like(t))
    np.testing.assert_allclose(y, 1.0 - np.exp(-4.0 * t), atol=1e-12)


def test_repeated_poles_on_irregular_grid_use_the_exact_step_recursion():
    # two identical lags: A is defective (not diagonalisable); step response 1 - exp(-a t)(1 + a t)
    rng = np.random.default_rng(5)
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.002, 0.02, 600))])
    lag = {"type": "first_order_lag", "bandwidth_rad_s": 3.0}
    model = LinearModel.from_spec({"numerator": [1.0], "denominator": [1.0], "effects": [lag, lag]})
    np.testing.assert_allclose(model.simulate(t, np.ones_like(t)), 1.0 - np.exp(-3.0 * t) * (1.0 + 3.0 * t),
                               atol=1e-12)


def test_jittered_grid_matches_a_fine_uniform_simulation():
    model = LinearModel.from_spec({"state_space": dict(LATERAL, input=[1, -1, 0], output=1), "effects": [
        {"type": "first_order_lag", "bandwidth_rad_s": 37.7}]})
    rng = np.random.default_rng(11)
    t = np.cumsum(rng.uniform(0.015, 0.025, 200_000))
    u = np.sin(1.3 * t) * np.cos(0.01 * t)
    y = model.simulate(t, u)
    # the same piecewise-linear input and delay on a fine uniform grid (first 5000 samples)
    t, u, y = t[:5000], u[:5000], y[:5000]
    fine = np.arange(t[0], t[-1], 0.0005)
    y_fine = model.simulate(fine, np.interp(fine, t, u))
    inside = t < fine[-1]
    np.testing.assert_allclose(y[inside], np.interp(t[inside], fine, y_fine), atol=1e-6 * np.max(np.abs(y)))


def test_uniform_runs_between_dropouts_match_the_step_by_step_recursion():
    model = LinearModel.from_tf([5.0, 100.0], [1.0, 3.0, 100.0])
    t = np.arange(5000) * 0.01
    t = np.delete(t, np.r_[1000:1100, 3000:3003])
    u = np.sin(2.0 * t) + 0.3 * np.cos(11.0 * t)
    y = model.simulate(t, u)
    fine = np.arange(0, 5000 * 20) * 0.0005
    # linear input between the remaining samples, simulated on a fine grid (exact for piecewise-linear u)
    y_fine = model.simulate(fine, np.interp(fine, t, u))
    np.testing.assert_allclose(y, np.interp(t, fine, y_fine), atol=1e-9)


def test_delay_is_applied_exactly_not_by_pade():
    t = np.arange(0.0, 10.0, 0.001)
    delay = 0.0537
    pure = LinearModel.from_tf([1.0], [1.0], delay_s=delay)
    y = pure.simulate(t, np.sin(3.0 * t))
    expected = np.where(t >= delay, np.sin(3.0 * (t - delay)), 0.0)
    # linear interpolation error of a sine sampled at 1 kHz: h^2 w^2 / 8
    assert np.max(np.abs(y - expected)[t > delay + 0.001]) < 0.001**2 * 9.0 / 8.0 + 1e-12
    # a lag with delay driven by a ramp: y = tau - (1 - exp(-a tau))/a, tau = t - T
    lagged = LinearModel.from_spec({"numerator": [1.0], "denominator": [1.0], "delay_s": 0.03, "effects": [
        {"type": "first_order_lag", "bandwidth_rad_s": 5.0}, {"type": "time_delay", "seconds": 0.0237}]})
    y = lagged.simulate(t, t)
    tau = np.clip(t - delay, 0.0, None)
    np.testing.assert_allclose(y, tau - (1.0 - np.exp(-5.0 * tau)) / 5.0, atol=2e-6)


def test_initial_state_free_response():
    model = LinearModel.from_tf([1.0], [1.0, 1.0])  # tf2ss: A = -1, B = 1, C = 1
    t = np.linspace(0.0, 5.0, 501)
    np.testing.assert_allclose(model.simulate(t, np.zeros_like(t), x0=[2.0]), 2.0 * np.exp(-t), rtol=1e-12)


def test_static_gain_and_pure_delay_models():
    t = np.arange(10) * 0.1
    assert np.allclose(LinearModel.from_tf([3.0], [2.0]).simulate(t, t), 1.5 * t)
    y = LinearModel.from_tf([3.0], [2.0], delay_s=0.2).simulate(t, t)
    np.testing.assert_allclose(y, 1.5 * np.clip(t - 0.2, 0, None), atol=1e-12)


def test_a_million_samples_stay_finite_and_match_lsim():
    # speed against scipy.signal.lsim: benchmarks/bench_core.py
    model = LinearModel.from_spec({"state_space": dict(LATERAL, input=[1, -1, 0], output=1), "effects": [
        {"type": "first_order_lag", "bandwidth_rad_s": 37.7}, {"type": "time_delay", "seconds": 0.05}]})
    t = np.arange(1_000_000) * 0.004
    u = np.sin(0.5 * t) * np.sin(0.01 * t)
    y = model.simulate(t, u)
    assert np.all(np.isfinite(y))
    # spot check the end against a short simulation of the last stretch from the exact state is costly;
    # instead compare the first 20000 samples with lsim
    _, reference, _ = scipy.signal.lsim((model.num, model.den), np.interp(t[:20000] - 0.05, t, u, left=0.0),
                                        t[:20000])
    np.testing.assert_allclose(y[:20000], reference, atol=1e-8 * np.max(np.abs(reference)))


@pytest.mark.parametrize(
    "spec, fragment",
    [
        ({"numerator": [1.0, 2.0, 3.0], "denominator": [1.0, 2.0]}, "improper model"),
        ({"numerator": [], "denominator": [1.0]}, "model.numerator: expected a non-empty list"),
        ({"numerator": [1.0], "denominator": [0.0, 0.0]}, "model.denominator"),
        ({"numerator": [1.0], "denominator": [1.0, float("inf")]}, "model.denominator[1]"),
        ({"numerator": [1.0], "denominator": "1 2"}, "model.denominator: expected a list of numbers"),
        ({"numerator": [1.0]}, "missing key 'denominator'"),
        ({"numerator": [1.0], "denominator": [1.0, 1.0], "colour": 3}, "model.colour: unknown key"),
        ({"numerator": [1.0], "denominator": [1.0, 1.0], "poles": [-1]}, "exactly one of"),
        (
            {"numerator": [1.0], "denominator": [1.0, 1.0], "delay_s": -1},
            "model.delay_s: expected a number >= 0",
        ),
        (
            {"numerator": [1.0], "denominator": [1.0, 1.0], "effects": {"type": "gain"}},
            "model.effects: expected a list",
        ),
        (
            {
                "numerator": [1.0],
                "denominator": [1.0, 1.0],
                "effects": [{"type": "time_delay", "seconds": "abc"}],
            },
            "model.effects[0].seconds: expected a number >= 0, got 'abc'",
        ),
        ({"poles": ["-1+2j"]}, "model.poles: complex root -1+2j has no conjugate"),
        ({"poles": [[-1, 2, 3]]}, "model.poles[0]"),
        ({"poles": ["x"]}, "model.poles[0]"),
        ({"zeros": [-1, -2], "poles": [-3]}, "improper model"),
        (
            {"state_space": {"A": [[1, 2], [3, 4]], "B": [[1], [2]], "C": [1, 0], "E": 1}},
            "model.state_space.E",
        ),
        ({"state_space": {"A": [[1, 2], [3, 4]], "B": [[1], [2], [3]], "C": [1, 0]}}, "model.state_space.B"),
        ({"state_space": {"A": [[1, 2, 3], [3, 4, 5]], "B": [[1], [2]], "C": [1, 0]}}, "model.state_space.A"),
        ({"state_space": dict(LATERAL)}, "model.state_space.input: missing"),
        (
            {"state_space": dict(LATERAL, input=[1, -1], output=1)},
            "model.state_space.input: expected 3 weights",
        ),
        (
            {"state_space": dict(LATERAL, input=0, output=7)},
            "model.state_space.output: expected an index 0..3",
        ),
        ({"state_space": {"A": [[1]], "B": [[1]], "C": [[1]], "D": [["a"]]}}, "model.state_space.D"),
        ([1, 2], "model: expected a mapping"),
    ],
)
def test_config_errors_name_the_key(spec, fragment):
    with pytest.raises(ConfigError) as info:
        LinearModel.from_spec(spec, where="model")
    assert fragment in str(info.value)
    assert "\n" not in str(info.value)


def test_where_prefix_is_used():
    with pytest.raises(ConfigError, match=r"^channels\.pitch\.model\.effects\[1\]\.seconds"):
        LinearModel.from_spec(
            {
                "numerator": [1.0],
                "denominator": [1.0, 1.0],
                "effects": [{"type": "gain", "factor": 2}, {"type": "time_delay", "seconds": None}],
            },
            where="channels.pitch.model",
        )


def test_model_is_immutable():
    model = LinearModel.from_tf([1.0], [1.0, 1.0])
    with pytest.raises(ValueError):
        model.num[0] = 2.0
    with pytest.raises(AttributeError):
        model.delay_s = 1.0


# -- MIMO models
# -----------------------------------------------------------------------------------------------

LATERAL_MIMO = {"A": LATERAL["A"], "B": LATERAL["B"], "C": [LATERAL["C"][1], LATERAL["C"][2]]}


def test_mimo_state_space_response_is_the_matrix_formula_and_round_trips():
    model = MimoModel.from_spec({"state_space": LATERAL_MIMO}, inputs=3, outputs=2)
    assert model.shape == (2, 3) and model.order == 4
    a, b, c = (np.array(LATERAL_MIMO[k], dtype=float) for k in "ABC")
    w = np.array([0.3, 4.0, 40.0])
    expected = np.stack([c @ np.linalg.solve(1j * x * np.eye(4) - a, b) for x in w])
    np.testing.assert_allclose(model.freqresp(w), expected, rtol=1e-10)
    again = MimoModel.from_spec(model.to_spec(), inputs=3, outputs=2)
    np.testing.assert_allclose(again.freqresp(w), expected, rtol=1e-12)
    # every element matches the SISO model that selects it
    siso = LinearModel.from_spec({"state_space": dict(LATERAL, input=1, output=2)})
    np.testing.assert_allclose(model.freqresp(w)[:, 1, 1], siso.freqresp(w), rtol=1e-9)


def test_transfer_matrix_form_and_static_gains():
    spec = {"transfer_matrix": [[{"numerator": [18.75, 225.0], "denominator": [1.0, 9.0, 225.0]}, 0.5],
                                [0, {"zeros": [], "poles": [-0.5], "gain": 50.0,
                                     "effects": [{"type": "first_order_lag", "bandwidth_rad_s": 30.0}]}]]}
    model = MimoModel.from_spec(spec, inputs=2, outputs=2)
    w = np.array([0.0, 2.0, 20.0])
    p = model.freqresp(w)
    s = 1j * w
    np.testing.assert_allclose(p[:, 0, 0], (18.75 * s + 225.0) / (s * s + 9.0 * s + 225.0), rtol=1e-10)
    np.testing.assert_allclose(p[:, 0, 1], 0.5)
    np.testing.assert_allclose(p[:, 1, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(p[:, 1, 1], 50.0 / (s + 0.5) * 30.0 / (s + 30.0), rtol=1e-10)
    gain = MimoModel.from_spec({"state_space": {"D": [[1.0, 2.0], [3.0, 4.0]]}}, inputs=2, outputs=2)
    assert gain.order == 0 and gain.poles().size == 0
    np.testing.assert_allclose(gain.freqresp([1.0])[0], [[1.0, 2.0], [3.0, 4.0]])


def test_minimal_realization_and_poles_of_a_mimo_model():
    # a heading state (integrator) that the rate outputs do not see is not a pole of the transfer matrix
    a = np.array([[-2.0, 0.0], [1.0, 0.0]])
    model = MimoModel(a, [[1.0, 0.5], [0.0, 0.0]], [[1.0, 0.0], [2.0, 0.0]])
    assert model.order == 2 and model.minimal_state_space()[0].shape == (1, 1)
    np.testing.assert_allclose(model.poles(), [-2.0])
    one = MimoModel(a, [[1.0], [0.0]], [[1.0, 0.0]])
    siso = one.siso()
    np.testing.assert_allclose(siso.freqresp([0.0, 3.0]), one.freqresp([0.0, 3.0])[:, 0, 0], rtol=1e-12)
    with pytest.raises(ValueError, match="not SISO"):
        model.siso()
    assert MimoModel.from_linear(LinearModel.from_tf([1.0], [1.0, 1.0])).shape == (1, 1)
    with pytest.raises(ValueError, match="delay"):
        MimoModel.from_linear(LinearModel.from_tf([1.0], [1.0, 1.0], 0.1))
    with pytest.raises(ConfigError, match="effects on a MIMO model"):
        model.with_effects([{"type": "time_delay", "seconds": 0.1}])
    assert model.with_effects([]) is model


@pytest.mark.parametrize(
    "spec, fragment",
    [
        (
            {"state_space": dict(LATERAL_MIMO, B=[[1, 2], [3, 4], [5, 6], [7, 8]])},
            "model.state_space.B: expected 3 columns (one per entry of inputs), got shape 4x2",
        ),
        (
            {"state_space": dict(LATERAL_MIMO, C=[LATERAL["C"][1]])},
            "model.state_space.C: expected 2 rows (one per entry of outputs), got shape 1x4",
        ),
        ({"state_space": dict(LATERAL_MIMO, D=[[0, 0], [0, 0]])}, "model.state_space.D: expected 3 columns"),
        ({"state_space": dict(LATERAL_MIMO, input=0)}, "model.state_space.input: not used by a MIMO model"),
        ({"state_space": {"A": LATERAL["A"], "B": LATERAL["B"]}}, "model.state_space: missing key 'C'"),
        (
            {"state_space": dict(LATERAL_MIMO), "delay_s": 0.05},
            "model.delay_s: not available for a MIMO model yet",
        ),
        (
            {"state_space": dict(LATERAL_MIMO), "effects": []},
            "model.effects: not available for a MIMO model yet",
        ),
        ({"numerator": [1.0], "denominator": [1.0, 1.0]}, "model.numerator: unknown key for a MIMO model"),
        (
            {"transfer_matrix": [[1, 2, 3]]},
            "model.transfer_matrix: expected 2 rows (one per entry of outputs), got 1",
        ),
        ({"transfer_matrix": [[1, 2], [3, 4]]}, "model.transfer_matrix[0]: expected 3 elements"),
        (
            {"transfer_matrix": [[1, 2, 3], [4, 5]]},
            "model.transfer_matrix[1]: expected 3 elements like row 0",
        ),
        ({"transfer_matrix": [[1, 2, "x"], [4, 5, 6]]}, "model.transfer_matrix[0][2]"),
        (
            {
                "transfer_matrix": [
                    [1, 2, {"numerator": [1], "denominator": [1, 1], "delay_s": 0.1}],
                    [4, 5, 6],
                ]
            },
            "model.transfer_matrix[0][2]: delays are not available in a MIMO model yet",
        ),
        ({"transfer_matrix": [[1, 2, 3], [4, 5, 6]], "state_space": LATERAL_MIMO}, "exactly one of"),
        ({"state_space": dict(LATERAL_MIMO, A=[[1e300]])}, "model.state_space.A"),
    ],
)
def test_mimo_config_errors_name_key_and_value(spec, fragment):
    with pytest.raises(ConfigError) as info:
        MimoModel.from_spec(spec, "model", inputs=3, outputs=2, inputs_are="entry of inputs",
                            outputs_are="entry of outputs")
    assert fragment in str(info.value)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("seed", range(8))
def test_transfer_function_of_a_state_space_is_scipys(seed):
    """models._ss2tf (no scipy.signal import on the replay's path) gives scipy.signal.ss2tf's numbers to the
    bit."""
    from gap_validation.core.models import _ss2tf

    rng = np.random.default_rng(seed)
    n = 1 + seed % 5
    a, b, c, d = (
        rng.normal(size=(n, n)),
        rng.normal(size=(n, 1)),
        rng.normal(size=(1, n)),
        rng.normal(size=(1, 1)),
    )
    if seed % 2:
        d[:] = 0.0
    num, den = _ss2tf(a, b, c, d)
    ref_num, ref_den = scipy.signal.ss2tf(a, b, c, d)
    np.testing.assert_array_equal(den, ref_den)
    np.testing.assert_array_equal(num, ref_num)
    # and the response is the matrix formula's
    s = 2.3j
    expected = (c @ np.linalg.solve(s * np.eye(n) - a, b) + d)[0, 0]
    assert abs(np.polyval(num[0], s) / np.polyval(den, s) - expected) < 1e-9 * max(1.0, abs(expected))


@pytest.mark.parametrize("seed", range(6))
def test_realization_of_a_transfer_function_is_scipys(seed):
    """models._tf2ss (no scipy.signal import on the replay's path) gives scipy.signal.tf2ss's matrices to the
    bit, leading zeros and near-zero numerator coefficients included."""
    import warnings

    from gap_validation.core.models import _tf2ss

    rng = np.random.default_rng(seed)
    for _ in range(200):
        k = int(rng.integers(2, 10))
        den = rng.normal(size=k) * 10 ** rng.uniform(-3, 3, size=k)
        num = rng.normal(size=int(rng.integers(1, k + 1))) * 10 ** rng.uniform(-3, 3)
        if rng.random() < 0.3:
            num[0] = 0.0 if rng.random() < 0.5 else 1e-15
        if rng.random() < 0.2:
            den = np.concatenate(([0.0], den))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ref = scipy.signal.tf2ss(num, den)
        got = _tf2ss(num, den)
        for r, g in zip(ref[:3] + (np.atleast_2d(ref[3]),), got):
            np.testing.assert_array_equal(g, r)


def test_a_replay_with_the_time_domain_check_does_not_import_scipy_signal():
    """A state-space model built from a transfer function (the time-domain check of every doublet) needs no
    scipy.signal either."""
    import os
    import subprocess
    import sys

    code = ("import sys, numpy as np; from gap_validation.core.models import LinearModel; "
            "m = LinearModel.from_tf([5.0, 100.0], [1.0, 3.0, 100.0], delay_s=0.02); "
            "t = np.arange(1000) * 0.01; m.simulate(t, np.sin(t)); print('scipy.signal' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=os.environ.copy(),
                         check=True)
    assert out.stdout.strip().splitlines()[-1] == "False"


def test_loading_a_state_space_config_does_not_import_scipy_signal():
    """scipy.signal costs a replay's start-up about 0.7 s (benchmarks/bench_replay.py): the config path avoids
    it."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    code = (
        "import sys; from gap_validation.core.config import load_config; "
        f"load_config({str(root / 'config' / 'ultrastick25e.yaml')!r}); print('scipy.signal' in sys.modules)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        cwd=root,
        env=os.environ.copy(),
        check=True,
    )
    assert out.stdout.strip().splitlines()[-1] == "False"
