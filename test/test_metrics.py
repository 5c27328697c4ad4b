"""Metrics: chordal distance, exact nu-gap with the winding-number condition, epsilon, TIC; SISO and MIMO.

Pinned numbers: the paper's example (eqs. 18-19: nu-gap 0.0852, epsilon 0.1404 at 14.9 rad/s), textbook
nu-gaps (Vinnicombe: 100/(2s+1) vs 100/(2s-1) is 0.0200, vs 100/(s+1)^2 is 0.8988), the corner cases of issue
15 against a 40-digit reference, and the rotated block-diagonal MIMO example of issue 14 (0.0852).
"""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize_scalar

from gap_validation.core.metrics import (
    _nugap_state_space,
    chordal_distance,
    epsilon,
    epsilon_frequency_data,
    epsilon_per_frequency,
    nugap,
    nugap_frequency_data,
    tic,
    tic_input_augmented,
    winding_condition,
)
from gap_validation.core.models import LinearModel, MimoModel

P1_PAPER = LinearModel.from_tf([18.75, 225.0], [1.0, 9.0, 225.0])  # eq. 18
P2_PAPER = LinearModel.from_tf([18.75, 225.0], [1.0, 7.22, 246.5])  # eq. 19
DENSE = np.concatenate([[0.0], np.geomspace(1e-5, 1e5, 400_001)])


def kappa_of(m1, m2, w):
    """Independent evaluation: eq. 13 on the models' frequency responses."""
    p1, p2 = m1.freqresp(w), m2.freqresp(w)
    return np.abs(p2 - p1) / np.sqrt((1 + np.abs(p1) ** 2) * (1 + np.abs(p2) ** 2))


def dense_sup(m1, m2, w=DENSE):
    with np.errstate(all="ignore"):
        return nugap_frequency_data(w, m1.freqresp(w), m2.freqresp(w))


# -- paper example ------------------------------------------------------------------------------------------


def test_paper_example_nugap_and_epsilon():
    gap, w_gap = nugap(P1_PAPER, P2_PAPER)
    eps, w_eps = epsilon(P1_PAPER, P2_PAPER)
    assert gap == pytest.approx(0.0852, abs=5e-4)
    assert round(gap, 2) == 0.09  # "both metrics have the same value of 0.09"
    assert eps == pytest.approx(0.1404, abs=5e-4)
    assert w_eps == pytest.approx(14.9, abs=0.2)
    assert w_gap == pytest.approx(14.9, abs=0.2)
    assert winding_condition(P1_PAPER, P2_PAPER).satisfied


@pytest.mark.parametrize("metric, per_point", [
    (nugap, lambda w: kappa_of(P1_PAPER, P2_PAPER, w)),
    (epsilon, lambda w: np.abs(P2_PAPER.freqresp(w) - P1_PAPER.freqresp(w))
     / np.abs(P2_PAPER.freqresp(w) + P1_PAPER.freqresp(w))),
])
def test_peak_is_located_to_1e_6_relative(metric, per_point):
    value, w_peak = metric(P1_PAPER, P2_PAPER)
    grid = np.linspace(13.0, 17.0, 400_001)  # 1e-5 rad/s spacing
    k = int(np.argmax(per_point(grid)))
    result = minimize_scalar(
        lambda w: -per_point(np.array([w]))[0],
        bracket=(grid[k - 1], grid[k], grid[k + 1]),
        method="brent",
        tol=1e-12,
    )
    assert abs(w_peak - result.x) <= 1e-6 * result.x
    assert value == pytest.approx(-result.fun, rel=1e-12)
    assert value >= per_point(grid).max()


# -- textbook values and the winding-number condition
# ---------------------------------------------------------


def test_textbook_nugaps():
    stable = LinearModel.from_tf([100.0], [2.0, 1.0])
    assert nugap(stable, LinearModel.from_tf([100.0], [2.0, -1.0]))[0] == pytest.approx(0.0200, abs=1e-4)
    value, w_peak = nugap(stable, LinearModel.from_tf([100.0], [1.0, 2.0, 1.0]))
    assert value == pytest.approx(0.8988, abs=1e-4)
    assert value == pytest.approx(
        dense_sup(stable, LinearModel.from_tf([100.0], [1.0, 2.0, 1.0]))[0], abs=1e-8
    )


def test_symmetric_in_its_arguments():
    a, b = LinearModel.from_tf([100.0], [2.0, 1.0]), LinearModel.from_tf([100.0], [1.0, 2.0, 1.0])
    assert nugap(a, b)[0] == pytest.approx(nugap(b, a)[0], rel=1e-12)


def test_winding_condition_failure_gives_one_although_kappa_stays_below_one():
    # 1/(s+2) vs 1/(s-2): kappa(w) = 4/(w^2 + 5) <= 0.8 but the stable/unstable counts do not match.
    # Sanity: the controller C = 0 stabilises 1/(s+2) with margin b = 1/sqrt(1 + 1/4) = 0.894 > 0.8, so if
    # the nu-gap were 0.8 it would also stabilise 1/(s-2), which it does not: the nu-gap must be 1.
    stable, unstable = LinearModel.from_tf([1.0], [1.0, 2.0]), LinearModel.from_tf([1.0], [1.0, -2.0])
    assert dense_sup(stable, unstable)[0] == pytest.approx(0.8, abs=1e-6)
    for pair in ((stable, unstable), (unstable, stable)):
        check = winding_condition(*pair)
        assert not check.satisfied and "winding" in check.reason
        assert nugap(*pair)[0] == 1.0
    # with a slower pole the counts match: 1/(s+0.5) vs 1/(s-0.5) is finite (kappa(0) = 0.8)
    value, w_peak = nugap(LinearModel.from_tf([1.0], [1.0, 0.5]), LinearModel.from_tf([1.0], [1.0, -0.5]))
    assert value == pytest.approx(0.8, abs=1e-12) and w_peak == 0.0


def test_sign_flip_vanishes_on_the_axis():
    p = LinearModel.from_tf([1.0], [1.0, 1.0])
    check = winding_condition(p, LinearModel.from_tf([-1.0], [1.0, 1.0]))
    assert not check.satisfied and check.frequency_rad_s == 0.0
    assert nugap(p, LinearModel.from_tf([-1.0], [1.0, 1.0])) == (1.0, 0.0)


@pytest.mark.parametrize("m1, m2", [
    (LinearModel.from_tf([1.0], [1.0, 0.0]), LinearModel.from_tf([1.0], [1.0, 0.1])),          # integrator
    (LinearModel.from_tf([1.0], [1.0, 1.0, 0.0]), LinearModel.from_tf([1.2], [1.0, 1.3, 0.0])),  # both
    (LinearModel.from_tf([1.0], [1.0, 0.0, 1.0]), LinearModel.from_tf([1.0], [1.0, 0.2, 1.0])),  # oscillator
    (LinearModel.from_tf([1.0], [1.0, -1.0]), LinearModel.from_tf([1.0], [1.0, -1.1])),          # unstable
])
def test_poles_on_the_axis_and_unstable_models_are_finite_and_equal_the_dense_sup(m1, m2):
    value, w_peak = nugap(m1, m2)
    grid_value, _ = dense_sup(m1, m2, np.concatenate([DENSE, [1.0]]))
    assert winding_condition(m1, m2).satisfied
    assert value < 1.0
    assert value >= grid_value - 1e-12
    assert value == pytest.approx(grid_value, abs=1e-6)


def test_undamped_oscillator_against_the_analytic_chordal_distance():
    # P1 = 1/(1 - w^2), P2 = 1/(1 - w^2 + 0.2 j w): kappa = 0.2 w / sqrt((1 + a^2)(1 + a^2 + 0.04 w^2)), a = 1
    # - w^2
    value, w_peak = nugap(
        LinearModel.from_tf([1.0], [1.0, 0.0, 1.0]), LinearModel.from_tf([1.0], [1.0, 0.2, 1.0])
    )
    w = np.linspace(0.5, 1.5, 1_000_001)
    a = 1 - w**2
    analytic = 0.2 * w / np.sqrt((1 + a**2) * (1 + a**2 + 0.04 * w**2))
    assert value == pytest.approx(analytic.max(), rel=1e-9)
    assert w_peak == pytest.approx(w[np.argmax(analytic)], abs=2e-6)


def test_common_factors_are_cancelled_before_counting():
    p = LinearModel.from_tf([1.0], [1.0, 1.0])
    with_cancelled_unstable_mode = LinearModel.from_tf(np.polymul([1.0], [1.0, -3.0]), np.polymul([1.0, 1.0],
                                                                                                 [1.0, -3.0]))
    assert nugap(p, with_cancelled_unstable_mode)[0] == pytest.approx(0.0, abs=1e-9)


# -- corner cases (issue 15): peaks at gain crossovers far from every pole and zero, beside undamped poles
# ----

W0 = 27.7200457464113
# (num1, den1, num2, den2), the sup of kappa and where (from the issue; the 40-digit reference)
CORNER_CASES = {
    "gains 1e-6/s vs 2e-6/s": (([1e-6], [1.0, 0.0], [2e-6], [1.0, 0.0]), 1 / 3, math.sqrt(2) * 1e-6),
    "gains 1e8/(s+1) vs 1.1e8/(s+1)": (([1e8], [1.0, 1.0], [1.1e8], [1.0, 1.0]), 1 / 21, 1.0488088e8),
    "-50.9/s vs -56.07/(s-0.002125)": (
        ([-50.9], [1.0, 0.0], [-56.07], [1.0, -0.002125]),
        0.0483313115,
        53.4225,
    ),
    "two peaks beside a shared undamped pole": (
        (
            np.polymul([-3.111686845952856], [1.0, 0.14255673341511005]).tolist(),
            np.polymul([1.0, 0.0, W0**2], [1.0, 0.9590014583306136]).tolist(),
            np.polymul([-2.898949107865159], [1.0, 0.14711222759321194]).tolist(),
            np.polymul([1.0, 0.0, W0**2], [1.0, 0.9844060387689597]).tolist(),
        ),
        0.0354112008,
        27.666,
    ),
}


def mp_sup(polys, per_point, lo=1e-9, hi=1e12, per_decade=2000):
    """High-precision reference: local maxima of a float scan (2000 points per decade over 21 decades), each
    refined by a golden-section search evaluated with mpmath at 40 digits; the largest one and where."""
    mp = pytest.importorskip("mpmath")
    mp.mp.dps = 40
    n1, d1, n2, d2 = ([mp.mpf(c) for c in poly] for poly in polys)

    def horner(coefficients, s):
        out = mp.mpf(0)
        for c in coefficients:
            out = out * s + c
        return out

    def value(w):
        s = mp.mpc(0, w)
        return per_point(mp, horner(n1, s) / horner(d1, s), horner(n2, s) / horner(d2, s))

    w = np.geomspace(lo, hi, int(per_decade * math.log10(hi / lo)))
    with np.errstate(all="ignore"):
        s = 1j * w
        f1, f2 = (np.polyval(polys[i], s) / np.polyval(polys[i + 1], s) for i in (0, 2))
        scan = per_point(np, f1, f2)
    scan = np.where(np.isfinite(scan), scan, -1.0)
    peaks = np.flatnonzero((scan[1:-1] >= scan[:-2]) & (scan[1:-1] >= scan[2:])) + 1
    best_value, best_w = mp.mpf(-1), None
    golden = (mp.sqrt(5) - 1) / 2
    for k in peaks[np.argsort(scan[peaks])[::-1][:4]]:
        a, b = mp.mpf(w[k - 1]), mp.mpf(w[k + 1])
        for _ in range(160):
            c, d = b - golden * (b - a), a + golden * (b - a)
            a, b = (a, d) if value(c) > value(d) else (c, b)
        if value((a + b) / 2) > best_value:
            best_value, best_w = value((a + b) / 2), (a + b) / 2
    return float(best_value), float(best_w)


def chordal(lib, p1, p2):
    return abs(p2 - p1) / lib.sqrt((1 + abs(p1) ** 2) * (1 + abs(p2) ** 2))


def overbound(lib, p1, p2):
    return abs(p2 - p1) / abs(p2 + p1)


@pytest.mark.parametrize("name", CORNER_CASES)
def test_nugap_corner_cases_equal_a_40_digit_reference_to_1e_6(name):
    polys, published, w_published = CORNER_CASES[name]
    m1, m2 = LinearModel.from_tf(polys[0], polys[1]), LinearModel.from_tf(polys[2], polys[3])
    value, w_peak = nugap(m1, m2)
    reference, w_reference = mp_sup(polys, chordal)
    assert winding_condition(m1, m2).satisfied
    assert value == pytest.approx(reference, rel=1e-6)
    assert value == pytest.approx(published, rel=1e-6 if name != "-50.9/s vs -56.07/(s-0.002125)" else 1e-8)
    assert w_peak == pytest.approx(w_reference, rel=1e-6)
    assert w_peak == pytest.approx(w_published, rel=1e-4)
    assert nugap(m2, m1)[0] == pytest.approx(value, rel=1e-9)


@pytest.mark.parametrize("name", CORNER_CASES)
def test_epsilon_on_the_corner_cases_equals_the_reference(name):
    polys = CORNER_CASES[name][0]
    m1, m2 = LinearModel.from_tf(polys[0], polys[1]), LinearModel.from_tf(polys[2], polys[3])
    value, w_peak = epsilon(m1, m2)
    # an integrator against a finite DC gain: the limit at w = 0 is 1
    if name == "-50.9/s vs -56.07/(s-0.002125)":
        assert (value, w_peak) == (1.0, 0.0)
        return
    reference, _ = mp_sup(polys, overbound)
    assert value == pytest.approx(reference, rel=1e-6)
    assert value >= nugap(m1, m2)[0] * (1 - 1e-12)


def reference_sup(m1, m2):
    """Independent float reference: kappa from the models' frequency responses on 400 points per decade over
    1e-12..1e13 rad/s, every local maximum within 10 % of the top refined by a bounded search in ln(w)."""
    w = np.geomspace(1e-12, 1e13, 10_001)
    with np.errstate(all="ignore"):
        values = kappa_of(m1, m2, w)
    values = np.where(np.isfinite(values), values, -1.0)
    peaks = np.flatnonzero((values[1:-1] >= values[:-2]) & (values[1:-1] >= values[2:])) + 1
    best = max(values.max(), kappa_of(m1, m2, np.array([0.0]))[0] if m1.dc_gain() != math.inf and
               m2.dc_gain() != math.inf else -1.0)
    for k in peaks[values[peaks] >= 0.9 * values.max()]:
        result = minimize_scalar(lambda x: -kappa_of(m1, m2, np.array([math.exp(x)]))[0],
                                 bounds=(math.log(w[k - 1]), math.log(w[k + 1])), method="bounded",
                                 options={"xatol": 1e-12})
        best = max(best, -result.fun)
    return best


def scaled_model(gain, kind, corner, zeta):
    if kind == "integrator":
        return LinearModel.from_tf([gain], [1.0, 0.0])
    if kind == "lag":
        return LinearModel.from_tf([gain * corner], [1.0, corner])
    if kind == "lead":
        return LinearModel.from_tf([gain, gain * corner / 3], [1.0, corner])
    return LinearModel.from_tf([gain * corner**2], [1.0, 2 * zeta * corner, corner**2])


@settings(max_examples=40, deadline=None)
@given(st.floats(-9.0, 9.0), st.sampled_from(["integrator", "lag", "lead", "second order"]),
       st.floats(0.01, 100.0), st.floats(0.05, 1.0), st.floats(0.5, 2.0), st.floats(0.7, 1.4),
       st.sampled_from([1.0, -1.0]))
def test_nugap_with_gains_from_1e_9_to_1e9_equals_a_high_resolution_reference(log_gain, kind, corner, zeta,
                                                                              gain_ratio, corner_ratio, sign):
    m1 = scaled_model(sign * 10.0**log_gain, kind, corner, zeta)
    m2 = scaled_model(sign * 10.0**log_gain * gain_ratio, kind, corner * corner_ratio, zeta)
    assume(winding_condition(m1, m2).satisfied)
    value, w_peak = nugap(m1, m2)
    reference = reference_sup(m1, m2)
    # the difference of nearly equal models costs digits (a gain ratio of 1 - 1e-5 leaves 11): absolute 1e-14
    assert value >= reference * (1 - 1e-9) - 1e-14
    assert value == pytest.approx(reference, rel=1e-6, abs=1e-14)


# -- delays: numerical winding number and exact sup ----------------------------------------------------------


def pade(model, order=8):
    """Model with its delay replaced by a high-order Pade approximation (rational)."""
    k = np.arange(order + 1)
    c = np.array([math.factorial(2 * order - j) * math.factorial(order)
                  / (math.factorial(2 * order) * math.factorial(j) * math.factorial(order - j)) for j in k])
    num, den = (c * (-model.delay_s) ** k)[::-1], (c * model.delay_s ** k)[::-1]
    return LinearModel.from_tf(np.polymul(model.num, num), np.polymul(model.den, den))


@pytest.mark.parametrize("m1, m2, satisfied", [
    (LinearModel.from_tf([1.0], [1.0, 1.0], 0.1), LinearModel.from_tf([1.0], [1.0, 1.0]), True),
    (LinearModel.from_tf([1.0], [1.0, -1.0], 0.2), LinearModel.from_tf([1.0], [1.0, -1.0]), True),
    (LinearModel.from_tf([1.0], [1.0, 2.0], 0.05), LinearModel.from_tf([1.0], [1.0, -2.0]), False),
    (LinearModel.from_tf([18.75, 225.0], [1.0, 9.0, 225.0], 0.05), P2_PAPER, True),
    (LinearModel.from_tf([1.0], [1.0, 0.0]), LinearModel.from_tf([1.0], [1.0, 0.0], 0.5), True),
    (LinearModel.from_tf([0.5, 1.0], [1.0, 1.0], 0.2), LinearModel.from_tf([1.0], [1.0, 1.0]), True),
])
def test_delays_numerical_winding_agrees_with_pade_and_sup_with_dense_grid(m1, m2, satisfied):
    check = winding_condition(m1, m2)
    assert check.method == "numerical"
    assert check.satisfied == satisfied
    rational1 = pade(m1) if m1.delay_s else m1
    rational2 = pade(m2) if m2.delay_s else m2
    assert winding_condition(rational1, rational2).satisfied == satisfied
    value, w_peak = nugap(m1, m2)
    if satisfied:
        grid_value, _ = dense_sup(m1, m2)
        assert value >= grid_value - 1e-12
        assert value == pytest.approx(grid_value, abs=1e-6)
        assert value == pytest.approx(nugap(rational1, rational2)[0], abs=1e-6)
    else:
        assert value == 1.0


def test_delay_only_mismatch():
    p = LinearModel.from_tf([1.0], [1.0, 1.0])
    delayed = LinearModel.from_tf([1.0], [1.0, 1.0], 0.1)
    # P2 = -P1 at w T = pi: epsilon is infinite there
    eps, w_eps = epsilon(delayed, p)
    assert math.isinf(eps) and w_eps == pytest.approx(math.pi / 0.1, rel=1e-6)
    # kappa = |P| |1 - exp(-j w T)| / (1 + |P|^2) peaks where the analytic derivative vanishes
    value, w_peak = nugap(delayed, p)
    w = np.linspace(0.01, 40.0, 400_001)
    analytic = np.abs(1 - np.exp(-0.1j * w)) / np.sqrt(1 + w**2) / (1 + 1 / (1 + w**2))
    assert value == pytest.approx(analytic.max(), abs=1e-9)
    assert w_peak == pytest.approx(w[np.argmax(analytic)], abs=2e-4)


def test_periodic_epsilon_reports_the_lowest_frequency():
    # 2 exp(-s)/(s+1) vs 1/(s+1): epsilon(w) = |2 e^{-jw} - 1| / |2 e^{-jw} + 1|, max 3 at w = pi, 3 pi, ...
    eps, w_eps = epsilon(LinearModel.from_tf([2.0], [1.0, 1.0], 1.0), LinearModel.from_tf([1.0], [1.0, 1.0]))
    assert eps == pytest.approx(3.0, rel=1e-9)
    assert w_eps == pytest.approx(math.pi, rel=1e-6)


def test_epsilon_limits_at_zero_frequency_with_poles_or_zeros_at_the_origin():
    # P1 ~ 2 s, P2 ~ s/3 as s -> 0: epsilon -> |1/3 - 2| / |1/3 + 2| = 5/7 (0/0 at w = 0 itself)
    m1, m2 = LinearModel.from_tf([2.0, 0.0], [1.0, 1.0]), LinearModel.from_tf([1.0, 0.0], [1.0, 3.0])
    value, w_peak = epsilon(m1, m2)
    w = np.geomspace(1e-6, 1e4, 200_001)
    grid = np.abs(m2.freqresp(w) - m1.freqresp(w)) / np.abs(m2.freqresp(w) + m1.freqresp(w))
    assert value == pytest.approx(5 / 7, rel=1e-12) and w_peak == 0.0
    assert value >= grid.max() - 1e-12
    # double and single integrator: epsilon -> 1 as w -> 0
    assert epsilon(
        LinearModel.from_tf([1.0], [1.0, 0.0, 0.0]), LinearModel.from_tf([1.0], [1.0, 0.1, 0.0])
    ) == (1.0, 0.0)


# -- frequency data ------------------------------------------------------------------------------------------


def test_frequency_data_sup_and_nan_points_are_ignored():
    w = np.array([1.0, 2.0, 3.0, 4.0])
    p1 = np.array([1.0, 1.0j, 2.0, np.nan])
    p2 = np.array([1.0, -1.0j, 2.5, 1.0])
    kappa = chordal_distance(p1, p2)
    assert kappa[0] == 0.0 and kappa[1] == pytest.approx(1.0)
    assert nugap_frequency_data(w, p1, p2) == (pytest.approx(1.0), 2.0)
    eps = epsilon_per_frequency(p1, p2)
    assert eps[0] == 0.0 and math.isinf(eps[1]) and eps[2] == pytest.approx(0.5 / 4.5)
    assert epsilon_frequency_data(w, p1, p2) == (math.inf, 2.0)
    assert math.isnan(nugap_frequency_data(w[:1], [np.nan], [1.0])[0])


def test_epsilon_conventions_for_zero_and_infinite_responses():
    assert epsilon_per_frequency(0.0, 0.0) == 0.0
    assert epsilon_per_frequency(0.0, 1.0) == 1.0
    assert chordal_distance(np.inf, 0.0) == 1.0
    assert chordal_distance(np.inf, 1.0) == pytest.approx(1 / math.sqrt(2))
    assert chordal_distance(np.inf, np.inf) == 0.0


# -- properties ----------------------------------------------------------------------------------------------

finite = st.floats(-1e3, 1e3, allow_nan=False)
complexes = st.builds(complex, finite, finite)


@settings(max_examples=200, deadline=None)
@given(complexes, complexes)
def test_chordal_distance_properties(a, b):
    kappa = float(chordal_distance(a, b))
    assert 0.0 <= kappa <= 1.0
    assert kappa == pytest.approx(float(chordal_distance(b, a)), abs=1e-15)
    assert chordal_distance(a, a) == 0.0
    assert kappa <= float(epsilon_per_frequency(a, b)) * (1 + 1e-12) + 1e-15


def second_order(gain, wn, zeta, zero):
    return LinearModel.from_tf(np.array([1.0 / zero, 1.0]) * gain * wn * wn if zero else [gain * wn * wn],
                               [1.0, 2 * zeta * wn, wn * wn])


models = st.builds(second_order, st.floats(0.2, 5.0), st.floats(0.5, 50.0), st.floats(0.1, 1.5),
                   st.one_of(st.just(0.0), st.floats(1.0, 30.0)))


@settings(max_examples=25, deadline=None)
@given(models, models)
def test_exact_nugap_of_stable_models_equals_dense_sup(m1, m2):
    check = winding_condition(m1, m2)
    assume(check.satisfied)
    value, w_peak = nugap(m1, m2)
    grid_value, _ = dense_sup(m1, m2)
    assert value >= grid_value - 1e-12
    assert value <= grid_value + 1e-6
    if math.isfinite(w_peak):
        assert float(kappa_of(m1, m2, np.array([w_peak]))[0]) == pytest.approx(value, abs=1e-12)


def first_or_second_order(gain, pole, wn, zeta, sign, second):
    if second:
        return LinearModel.from_tf([gain * wn * wn], [1.0, sign * 2 * zeta * wn, wn * wn])
    return LinearModel.from_tf([gain * abs(pole)], [1.0, sign * abs(pole)])


any_models = st.builds(
    first_or_second_order,
    st.floats(-5.0, 5.0).filter(lambda g: abs(g) > 0.1),
    st.floats(0.1, 20.0),
    st.floats(0.5, 20.0),
    st.floats(0.1, 1.2),
    st.sampled_from([1.0, -1.0]),
    st.booleans(),
)


def vinnicombe_condition(m1, m2):
    """Independent check: wno(1 + P2~ P1) + eta(P1) - eta(P2) - eta0(P2) = 0 (no axis poles here), the winding
    number counted clockwise along w from -inf to inf (Nyquist-contour orientation), by phase unwrapping."""
    w = np.concatenate([[0.0], np.geomspace(1e-5, 1e6, 300_001)])
    f = 1 + np.conj(m2.freqresp(w)) * m1.freqresp(w)
    if np.min(np.abs(f)) < 1e-9:
        return False
    turns_ccw = 2 * (np.unwrap(np.angle(f))[-1] - np.angle(f[0])) / (2 * math.pi)
    wno = -round(turns_ccw)
    eta1, eta2 = int(np.sum(m1.poles().real > 0)), int(np.sum(m2.poles().real > 0))
    return wno + eta1 - eta2 == 0


@settings(max_examples=40, deadline=None)
@given(any_models, any_models)
def test_winding_condition_matches_vinnicombes_formula(m1, m2):
    assert winding_condition(m1, m2).satisfied == vinnicombe_condition(m1, m2)


# -- MIMO: chordal distance of matrices, exact nu-gap from normalised coprime factors -----------------------


def rotation(angle):
    return np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])


def block_diagonal(*models):
    """The MIMO model diag(models) from the SISO models' realizations."""
    systems = [m.state_space() for m in models]
    n = sum(a.shape[0] for a, _, _, _ in systems)
    a, b, c, d = (
        np.zeros((n, n)),
        np.zeros((n, len(models))),
        np.zeros((len(models), n)),
        np.zeros((len(models),) * 2),
    )
    k = 0
    for i, (ai, bi, ci, di) in enumerate(systems):
        size = ai.shape[0]
        a[k:k + size, k:k + size], b[k:k + size, i], c[i, k:k + size], d[i, i] = ai, bi[:, 0], ci[0], di[0, 0]
        k += size
    return MimoModel(a, b, c, d)


def rotated(model, u, v):
    """U P V for constant matrices U, V."""
    a, b, c, d = model.state_space()
    return MimoModel(a, b @ v, u @ c, u @ d @ v)


VINNICOMBE_STABLE = LinearModel.from_tf([100.0], [2.0, 1.0])
VINNICOMBE_UNSTABLE = LinearModel.from_tf([100.0], [2.0, -1.0])


def test_rotated_block_diagonal_mimo_nugap_is_the_largest_block_0_0852():
    u, v = rotation(0.7), rotation(-1.9)
    p1 = rotated(block_diagonal(P1_PAPER, VINNICOMBE_STABLE), u, v)
    p2 = rotated(block_diagonal(P2_PAPER, VINNICOMBE_UNSTABLE), u, v)
    value, w_peak = nugap(p1, p2)
    assert value == pytest.approx(0.0852, abs=1e-4)
    paper, w_paper = nugap(P1_PAPER, P2_PAPER)
    assert value == pytest.approx(max(paper, nugap(VINNICOMBE_STABLE, VINNICOMBE_UNSTABLE)[0]), rel=1e-7)
    assert w_peak == pytest.approx(w_paper, rel=1e-6)
    check = winding_condition(p1, p2)
    assert check.satisfied and check.method == "state space"
    # a block whose winding condition fails (1/(s+2) vs 1/(s-2), sup kappa 0.8) makes the whole nu-gap 1
    q1 = rotated(block_diagonal(P1_PAPER, LinearModel.from_tf([1.0], [1.0, 2.0])), u, v)
    q2 = rotated(block_diagonal(P2_PAPER, LinearModel.from_tf([1.0], [1.0, -2.0])), u, v)
    check = winding_condition(q1, q2)
    assert not check.satisfied and "winding number" in check.reason
    assert nugap(q1, q2)[0] == 1.0


siso_blocks = st.builds(first_or_second_order, st.floats(-5.0, 5.0).filter(lambda g: abs(g) > 0.1),
                        st.floats(0.1, 20.0), st.floats(0.5, 20.0), st.floats(0.1, 1.2),
                        st.sampled_from([1.0, -1.0]), st.booleans())


@settings(max_examples=30, deadline=None)
@given(
    siso_blocks,
    siso_blocks,
    siso_blocks,
    siso_blocks,
    st.floats(-math.pi, math.pi),
    st.floats(-math.pi, math.pi),
)
def test_block_diagonal_nugap_is_the_largest_block_whatever_the_rotations(a1, a2, b1, b2, angle_u, angle_v):
    u, v = rotation(angle_u), rotation(angle_v)
    value, _ = nugap(rotated(block_diagonal(a1, b1), u, v), rotated(block_diagonal(a2, b2), u, v))
    held = [winding_condition(a1, a2).satisfied, winding_condition(b1, b2).satisfied]
    assume(any(held))  # both failing: their winding numbers may cancel in the determinant (next test)
    gaps = [nugap(a1, a2)[0], nugap(b1, b2)[0]]
    assert value == pytest.approx(max(gaps), rel=1e-7, abs=1e-9)


def test_opposite_winding_failures_of_two_blocks_cancel_in_the_determinant():
    # Vinnicombe's condition is on det(I + P2~ P1): block a winds once one way, block b once the other way, so
    # the 2x2 pair meets the condition although neither block does; its nu-gap is then the sup of kappa.
    a1, a2 = LinearModel.from_tf([0.5], [1.0, -1.0]), LinearModel.from_tf([1.0], [1.0, 1.0])
    b1, b2 = LinearModel.from_tf([4.0], [1.0, 2.0]), LinearModel.from_tf([-1.0], [1.0, 1.0])
    assert not winding_condition(a1, a2).satisfied and not winding_condition(b1, b2).satisfied
    p1, p2 = block_diagonal(a1, b1), block_diagonal(a2, b2)
    assert winding_condition(p1, p2).satisfied and winding_by_phase(p1, p2)
    sup_kappa = max(dense_sup(a1, a2)[0], dense_sup(b1, b2)[0])
    assert nugap(p1, p2)[0] == pytest.approx(sup_kappa, abs=1e-6) and sup_kappa < 1.0


@settings(max_examples=40, deadline=None)
@given(any_models, any_models)
def test_one_by_one_state_space_path_equals_the_siso_function(m1, m2):
    systems = [MimoModel.from_linear(m).minimal_state_space() for m in (m1, m2)]
    value, w_peak, check = _nugap_state_space(*systems)
    assert check.satisfied == winding_condition(m1, m2).satisfied
    siso_value, _ = nugap(m1, m2)
    assert value == pytest.approx(siso_value, rel=1e-7, abs=1e-10)
    if check.satisfied and math.isfinite(w_peak):
        assert float(kappa_of(m1, m2, np.array([w_peak]))[0]) == pytest.approx(value, rel=1e-7)
    # the public function takes a 1 x 1 MimoModel as SISO
    assert nugap(MimoModel.from_linear(m1), m2)[0] == pytest.approx(siso_value, rel=1e-10, abs=1e-14)


def random_mimo(rng, states, outputs=2, inputs=2):
    """Random real model: modes from 0.2 to 30 rad/s, mostly stable, sometimes one unstable real pole."""
    a = np.zeros((states, states))
    k = 0
    while k < states:
        if states - k >= 2 and rng.random() < 0.5:
            wn, zeta = 10 ** rng.uniform(-0.7, 1.5), rng.uniform(0.1, 0.9)
            a[k : k + 2, k : k + 2] = [
                [-zeta * wn, wn * math.sqrt(1 - zeta**2)],
                [-wn * math.sqrt(1 - zeta**2), -zeta * wn],
            ]
            k += 2
        else:
            a[k, k] = -10 ** rng.uniform(-0.7, 1.3) * (1.0 if rng.random() < 0.85 else -0.3)
            k += 1
    d = rng.normal(size=(outputs, inputs)) * 0.2 if rng.random() < 0.3 else np.zeros((outputs, inputs))
    return MimoModel(a, rng.normal(size=(states, inputs)), rng.normal(size=(outputs, states)), d)


def perturbed_mimo(rng, model, size):
    return MimoModel(*(m * (1 + size * rng.normal(size=m.shape)) for m in model.state_space()))


def dense_mimo_sup(m1, m2):
    """Reference: kappa from matrix square roots on a dense grid, the best point refined in ln(w), and the
    limit at infinity (the D matrices)."""
    w = np.concatenate([[0.0], np.geomspace(1e-4, 1e4, 8001)])

    def kappa(x):
        return chordal_distance(m1.freqresp(x), m2.freqresp(x))

    values = kappa(w)
    k = int(np.argmax(values))
    best = values[k]
    if 0 < k < w.size - 1:
        result = minimize_scalar(
            lambda x: -kappa(np.array([math.exp(x)]))[0],
            method="bounded",
            bounds=(math.log(max(w[k - 1], 1e-5)), math.log(w[k + 1])),
            options={"xatol": 1e-12},
        )
        best = max(best, -result.fun)
    # and the limit at infinity, beyond the grid: P(jw) -> D
    d1, d2 = m1.state_space()[3], m2.state_space()[3]
    best = max(best, float(chordal_distance(d1[None], d2[None])[0]))
    return best, kappa


def winding_by_phase(m1, m2):
    """Independent check of Vinnicombe's condition for models without poles on the axis:
    wno det(I + P2~ P1) + eta(P1) - eta(P2) = 0, the winding counted clockwise by unwrapping the phase."""
    w = np.concatenate([[0.0], np.geomspace(1e-5, 1e5, 200_001)])
    p1, p2 = m1.freqresp(w), m2.freqresp(w)
    f = np.linalg.det(np.eye(p1.shape[2]) + np.conj(np.swapaxes(p2, 1, 2)) @ p1)
    if np.min(np.abs(f)) < 1e-9:
        return False
    turns_ccw = 2 * (np.unwrap(np.angle(f))[-1] - np.angle(f[0])) / (2 * math.pi)
    eta1, eta2 = (int(np.sum(m.poles().real > 0)) for m in (m1, m2))
    return -round(turns_ccw) + eta1 - eta2 == 0


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 4), st.floats(0.01, 0.5))
def test_mimo_nugap_equals_a_dense_grid_reference_and_its_winding_check(seed, states, size):
    rng = np.random.default_rng(seed)
    m1 = random_mimo(rng, states)
    m2 = perturbed_mimo(rng, m1, size) if rng.random() < 0.7 else random_mimo(rng, states)
    value, w_peak = nugap(m1, m2)
    check = winding_condition(m1, m2)
    assert check.satisfied == winding_by_phase(m1, m2)
    if not check.satisfied:
        assert value == 1.0
        return
    reference, kappa = dense_mimo_sup(m1, m2)
    assert value >= reference - 1e-9
    assert value == pytest.approx(reference, rel=1e-6, abs=1e-9)
    if math.isfinite(w_peak):
        assert float(kappa(np.array([w_peak]))[0]) == pytest.approx(value, rel=1e-7)


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(-6.0, 12.0))
def test_matrix_chordal_distance_properties(seed, log_scale):
    rng = np.random.default_rng(seed)
    p1, p2 = (
        (rng.normal(size=(3, 2, 2)) + 1j * rng.normal(size=(3, 2, 2))) * 10.0**log_scale for _ in range(2)
    )
    kappa = chordal_distance(p1, p2)
    assert kappa.shape == (3,) and np.all((kappa >= 0.0) & (kappa <= 1.0))
    np.testing.assert_allclose(kappa, chordal_distance(p2, p1), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(chordal_distance(p1, p1), 0.0, atol=1e-12)
    u, v = rotation(0.3) * 1j, rotation(2.0)   # unitary changes of coordinates
    np.testing.assert_allclose(chordal_distance(u @ p1 @ v, u @ p2 @ v), kappa, rtol=1e-7, atol=1e-12)
    # 1 x 1 matrices: the SISO formula
    np.testing.assert_allclose(
        chordal_distance(p1[:, :1, :1], p2[:, :1, :1]),
        chordal_distance(p1[:, 0, 0], p2[:, 0, 0]),
        rtol=1e-9,
        atol=1e-15,
    )


def test_round_off_in_the_coefficients_changes_nothing():
    # 1/(s+1)^2 through a state-space round trip: its coefficients differ by round-off, so n2 d1 - n1 d2 has a
    # leading coefficient of 1e-16 unless cancellations are recognised (a spurious root near 1e15 once moved
    # the whole analysis grid there)
    m1, m2 = LinearModel.from_tf([1.0], [1.0, 2.0, 1.0]), LinearModel.from_tf([1.0], [1.0, 1.0, 1.0])
    round_trip = MimoModel.from_linear(m1).siso()
    assert nugap(round_trip, m2)[0] == pytest.approx(nugap(m1, m2)[0], rel=1e-9)
    assert nugap(round_trip, m2)[0] == pytest.approx(0.3204237536639, rel=1e-9)
    assert epsilon(round_trip, m2)[0] == pytest.approx(epsilon(m1, m2)[0], rel=1e-9)


def test_mimo_frequency_data_and_errors():
    p1, p2 = block_diagonal(P1_PAPER, VINNICOMBE_STABLE), block_diagonal(P2_PAPER, VINNICOMBE_UNSTABLE)
    w = np.geomspace(1.0, 100.0, 2001)
    value, w_peak = nugap_frequency_data(w, p1.freqresp(w), p2.freqresp(w))
    assert value == pytest.approx(nugap(p1, p2)[0], rel=1e-5) and w_peak == pytest.approx(14.93, rel=1e-3)
    with pytest.raises(ValueError, match="different shapes"):
        nugap(p1, P1_PAPER)
    with pytest.raises(ValueError, match="SISO"):
        epsilon(p1, p2)
    assert epsilon(MimoModel.from_linear(P1_PAPER), P2_PAPER) == pytest.approx(epsilon(P1_PAPER, P2_PAPER))


# -- Theil inequality coefficient ----------------------------------------------------------------------------


def test_tic_eq1():
    y = np.sin(np.linspace(0, 10, 500))
    assert tic(y, y) == 0.0
    assert tic(y, -y) == pytest.approx(1.0)
    assert tic(y, np.zeros_like(y)) == pytest.approx(1.0)
    assert tic(y, 2 * y) == pytest.approx(1 / 3)
    assert tic(np.zeros(3), np.zeros(3)) == 0.0
    with pytest.raises(ValueError):
        tic([1.0, 2.0], [1.0])


def test_tic_input_augmented_eq3():
    y1, y2, u = np.array([1.0, 0.0]), np.array([0.0, 1.0]), np.array([1.0, 1.0])
    # ||y1 - y2|| = sqrt(2); ||[u; y1]|| = ||[u; y2]|| = sqrt(3)
    assert tic_input_augmented(y1, y2, u) == pytest.approx(math.sqrt(2) / (2 * math.sqrt(3)))
    assert tic_input_augmented(y1, y2, np.zeros(2)) == pytest.approx(tic(y1, y2))
    assert tic_input_augmented(y1, y2, u) < tic(y1, y2)


# --------------------------------------------------------------------------------------------- model or data
def test_nugap_and_epsilon_take_a_model_or_measured_data():
    """One function for both (as python-control's stability_margins): a model against data is compared at the
    data's frequencies, exactly what the frequency-data functions give; every accepted form gives the same."""
    from types import SimpleNamespace

    from gap_validation.core.frd import FrequencyData
    from gap_validation.core.metrics import epsilon_frequency_data, nugap_frequency_data

    p1 = LinearModel.from_tf([40.0], [1.0, 12.0, 40.0])
    p2 = LinearModel.from_tf([48.0], [1.0, 12.0, 40.0], delay_s=0.02)
    w = np.logspace(-1, 2, 300)
    h = p2.freqresp(w)
    expected_gap = nugap_frequency_data(w, p1.freqresp(w), h)
    expected_eps = epsilon_frequency_data(w, p1.freqresp(w), h)
    forms = [(w, h), FrequencyData(w, h), SimpleNamespace(w_rad_s=w, response=h),
             SimpleNamespace(frequency_rad_s=w, measured=h),
             SimpleNamespace(omega=w, fresp=h[None, None, :])]          # python-control's FRD layout
    for data in forms:
        assert nugap(p1, data) == expected_gap
        assert epsilon(p1, data) == expected_eps
        assert nugap(data, p1) == nugap_frequency_data(w, h, p1.freqresp(w))
    # over dense points the data's nu-gap approaches the exact one from below
    exact = nugap(p1, p2)[0]
    assert expected_gap[0] <= exact + 1e-12 and expected_gap[0] > exact - 1e-3
    # data against data on the same frequencies; different frequencies are an error, not a silent
    # interpolation
    assert nugap((w, p1.freqresp(w)), (w, h)) == expected_gap
    with pytest.raises(ValueError, match="frequencies differ"):
        nugap((w, h), (w[:-1], h[:-1]))
    with pytest.raises(ValueError, match="300 frequencies but 299"):
        nugap(p1, (w, h[:-1]))
    # a negative or non-finite frequency is refused, not evaluated (the model at -w is the conjugate: the
    # sup would be taken over frequencies the data never had)
    for bad, text in ((-w, "frequency -0.1 rad/s .index 0."), (np.where(w > 1, np.nan, w), "frequency nan")):
        with pytest.raises(ValueError, match=text):
            nugap(p1, (bad, h))
        with pytest.raises(ValueError, match="finite and non-negative"):
            epsilon((bad, h), p1)


def test_nugap_of_mimo_data_and_epsilon_refuses_it():
    from gap_validation.core.models import MimoModel

    a = np.array([[-1.0, 0.5], [0.0, -3.0]])
    b, c, d = np.eye(2), np.array([[1.0, 0.0], [0.3, 1.0]]), np.zeros((2, 2))
    m1, m2 = MimoModel(a, b, c, d), MimoModel(a, b * [0.7, 1.0], c, d)
    w = np.logspace(-2, 2, 400)
    data = (w, m2.freqresp(w))
    value = nugap(m1, data)[0]
    assert value == pytest.approx(nugap(m1, m2)[0], rel=2e-3)
    with pytest.raises(ValueError, match="SISO"):
        epsilon(m1, data)
