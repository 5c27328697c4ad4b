"""The controller check: b(P, C) for the negative-feedback loop u = -C y, and b(P1, C) > nu-gap.

Pinned: b(1/s, C = 1) = 1/sqrt(2) = 0.70711 (issue 14), guaranteed against 1/(s + 0.01) and not against -1/s.
Properties: b is 1/sigma_max of the closed-loop matrix written out with numpy, the SISO polynomial path equals
the state-space path, and Vinnicombe's robust stability theorem holds on random loops.
"""
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from gap_validation.core.metrics import nugap
from gap_validation.core.models import LinearModel, MimoModel
from gap_validation.core.robust import (
    _state_space_margin,
    controller_check,
    margin_of,
    stability_margin,
    stability_sentence,
)

INTEGRATOR = LinearModel.from_tf([1.0], [1.0, 0.0])
UNIT = LinearModel.from_tf([1.0], [1.0])


def closed_loop_sigma(p, c):
    """sigma_max of [P; I] (I + C P)^-1 [C, I] from the responses (matrices p x m and m x p), written out."""
    p, c = np.atleast_2d(p), np.atleast_2d(c)
    rows, cols = p.shape
    left = np.vstack([p, np.eye(cols)])
    middle = np.linalg.inv(np.eye(cols) + c @ p)
    return np.linalg.norm(left @ middle @ np.hstack([c, np.eye(cols)]), 2)


def vinnicombe_sigma(p, c_positive):
    """The same in Vinnicombe's positive-feedback form [P; I] (I - C P)^-1 [-C, I] with C = -C_config."""
    p, c = np.atleast_2d(p), np.atleast_2d(c_positive)
    cols = p.shape[1]
    return np.linalg.norm(np.vstack([p, np.eye(cols)]) @ np.linalg.inv(np.eye(cols) - c @ p)
                          @ np.hstack([-c, np.eye(cols)]), 2)


def test_integrator_with_unit_feedback_has_b_one_over_sqrt_2():
    b, w = stability_margin(INTEGRATOR, UNIT)
    assert b == pytest.approx(1 / math.sqrt(2), rel=1e-12)
    assert round(b, 5) == 0.70711
    # the closed-loop matrix is [1/(s+1); s/(s+1)] [1, 1]: sigma_max = sqrt(2) at every frequency
    for x in (0.01, 1.0, 100.0):
        p, c = INTEGRATOR.freqresp(x), UNIT.freqresp(x)
        assert closed_loop_sigma(p, c) == pytest.approx(math.sqrt(2), rel=1e-12)
        assert vinnicombe_sigma(p, -c) == pytest.approx(math.sqrt(2), rel=1e-12)
    # the state-space path (MIMO code) agrees
    assert stability_margin(MimoModel.from_linear(INTEGRATOR), MimoModel.from_linear(UNIT))[0] == \
        pytest.approx(b, rel=1e-10)
    assert _state_space_margin(
        MimoModel.from_linear(INTEGRATOR).minimal_state_space(),
        MimoModel.from_linear(UNIT).minimal_state_space(),
    ).b == pytest.approx(b, rel=1e-10)


def test_sign_convention_is_negative_feedback():
    # u = -C y with C = -1 is u = +y: 1/s with positive feedback has its pole at s = +1
    margin = margin_of(INTEGRATOR, LinearModel.from_tf([-1.0], [1.0]))
    assert (
        margin.b == 0.0 and not margin.stable and "unstable" in margin.reason and "pole at 1" in margin.reason
    )
    assert (
        stability_margin(
            MimoModel.from_linear(INTEGRATOR),
            MimoModel(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), [[-1.0]]),
        )[0]
        == 0.0
    )


@pytest.mark.parametrize("p2, guaranteed", [(LinearModel.from_tf([1.0], [1.0, 0.01]), True),
                                           (LinearModel.from_tf([-1.0], [1.0, 0.0]), False)])
def test_guaranteed_stable_against_the_issue_examples(p2, guaranteed):
    gap = nugap(INTEGRATOR, p2)[0]
    check = controller_check(INTEGRATOR, UNIT, gap)
    assert check.stability_margin_b == pytest.approx(0.70711, abs=5e-6)
    assert check.guaranteed_stable is guaranteed
    if guaranteed:
        assert gap < 0.02
        assert (
            check.sentence
            == "the controller is guaranteed to stabilise the aircraft: b = 0.7071 > nu-gap 0.0100"
        )
    else:
        assert gap == 1.0 and check.sentence.startswith("no guarantee")


def loop(gain, pole, zeta, wn, kp, ki, kd_pole, unstable):
    """A plant (first or second order, maybe unstable) and a PI or lead controller."""
    plant = (
        LinearModel.from_tf([gain * wn * wn], [1.0, (-1 if unstable else 1) * 2 * zeta * wn, wn * wn])
        if pole is None
        else LinearModel.from_tf([gain * abs(pole)], [1.0, (-1 if unstable else 1) * abs(pole)])
    )
    controller = LinearModel.from_tf(
        np.polymul([kp, ki], [1.0, 1.0]), np.polymul([1.0, 1e-3], [1.0, kd_pole])
    )
    return plant, controller


loops = st.builds(loop, st.floats(0.3, 5.0), st.one_of(st.none(), st.floats(0.2, 10.0)), st.floats(0.1, 1.0),
                  st.floats(0.5, 20.0), st.floats(0.05, 5.0), st.floats(0.0, 2.0), st.floats(1.0, 50.0),
                  st.booleans())


@settings(max_examples=50, deadline=None)
@given(loops)
def test_siso_polynomial_path_equals_the_state_space_path_and_the_closed_loop_matrix(pair):
    plant, controller = pair
    siso = margin_of(plant, controller)
    state_space = _state_space_margin(MimoModel.from_linear(plant).minimal_state_space(),
                                      MimoModel.from_linear(controller).minimal_state_space())
    assert siso.stable == state_space.stable
    assert siso.b == pytest.approx(state_space.b, rel=1e-7, abs=1e-12)
    if siso.stable:
        w = np.geomspace(1e-3, 1e3, 601)
        sigmas = [closed_loop_sigma(plant.freqresp(x), controller.freqresp(x)) for x in w]
        assert siso.b <= 1.0 / max(sigmas) * (1 + 1e-9)
        if math.isfinite(siso.frequency_rad_s):
            at = closed_loop_sigma(
                plant.freqresp(siso.frequency_rad_s), controller.freqresp(siso.frequency_rad_s)
            )
            assert 1.0 / at == pytest.approx(siso.b, rel=1e-8)


def closed_loop_stable(plant, controller):
    roots = np.roots(np.polyadd(np.polymul(plant.den, controller.den), np.polymul(plant.num, controller.num)))
    return bool(np.all(roots.real < 0.0))


@settings(max_examples=50, deadline=None)
@given(loops, st.floats(0.6, 1.6), st.floats(0.7, 1.4), st.floats(0.7, 1.4))
def test_vinnicombes_robust_stability_theorem(pair, gain_factor, pole_factor, damping_factor):
    plant, controller = pair
    b, _ = stability_margin(plant, controller)
    assume(b > 0.0)
    num, den = plant.num * gain_factor, plant.den.copy()
    den[1:] = den[1:] * np.array([pole_factor * damping_factor, pole_factor**2][:den.size - 1])
    other = LinearModel.from_tf(num, den)
    if nugap(plant, other)[0] < b:
        assert closed_loop_stable(other, controller)


def test_delay_in_the_loop_agrees_with_a_pade_approximation_and_a_long_delay_destabilises():
    plant = LinearModel.from_tf([2.0], [1.0, 1.0], 0.1)
    controller = LinearModel.from_tf([1.0, 0.5], [1.0, 0.0])
    b, w = stability_margin(plant, controller)
    order = 8
    k = np.arange(order + 1)
    c = np.array([math.factorial(2 * order - j) * math.factorial(order)
                  / (math.factorial(2 * order) * math.factorial(j) * math.factorial(order - j)) for j in k])
    pade = LinearModel.from_tf(
        np.polymul([2.0], (c * (-0.1) ** k)[::-1]), np.polymul([1.0, 1.0], (c * 0.1**k)[::-1])
    )
    assert 0.0 < b == pytest.approx(stability_margin(pade, controller)[0], rel=1e-6)
    for x in (0.3, 3.0, 30.0):
        assert 1.0 / closed_loop_sigma(plant.freqresp(x), controller.freqresp(x)) >= b * (1 - 1e-9)
    unstable = margin_of(LinearModel.from_tf([2.0], [1.0, 1.0], 2.0), controller)
    assert unstable.b == 0.0 and "right half plane" in unstable.reason


def diagonal(*models):
    systems = [MimoModel.from_linear(m).state_space() for m in models]
    n = sum(s[0].shape[0] for s in systems)
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


def test_mimo_b_of_block_diagonal_loops_is_the_smallest_block_and_rotation_invariant():
    p1, c1 = LinearModel.from_tf([18.75, 225.0], [1.0, 9.0, 225.0]), LinearModel.from_tf([0.5], [1.0])
    p2, c2 = LinearModel.from_tf([100.0], [2.0, 1.0]), LinearModel.from_tf([0.02, 0.01], [1.0, 0.0])
    plant, controller = diagonal(p1, p2), diagonal(c1, c2)
    b, w = stability_margin(plant, controller)
    blocks = [stability_margin(p1, c1), stability_margin(p2, c2)]
    assert b == pytest.approx(min(blocks)[0], rel=1e-8)
    u = np.array([[math.cos(0.4), -math.sin(0.4)], [math.sin(0.4), math.cos(0.4)]])
    v = np.array([[0.0, 1.0], [1.0, 0.0]])
    a, bb, cc, d = plant.state_space()
    ac, bc, ccc, dc = controller.state_space()
    rotated_plant = MimoModel(a, bb @ v, u @ cc, u @ d @ v)
    rotated_controller = MimoModel(ac, bc @ u.T, v.T @ ccc, v.T @ dc @ u.T)
    assert stability_margin(rotated_plant, rotated_controller)[0] == pytest.approx(b, rel=1e-8)
    with pytest.raises(ValueError, match="controller"):
        stability_margin(
            plant, MimoModel(np.zeros((0, 0)), np.zeros((0, 3)), np.zeros((2, 0)), np.zeros((2, 3)))
        )


def test_sentences_say_why_and_show_enough_digits():
    from gap_validation.core.robust import StabilityMargin

    assert stability_sentence(StabilityMargin(0.71, 1.0), 0.09) == \
        "the controller is guaranteed to stabilise the aircraft: b = 0.71 > nu-gap 0.09"
    assert "b = 0.0852 > nu-gap 0.0851" in stability_sentence(StabilityMargin(0.0852, 1.0), 0.0851)
    assert "no guarantee" in stability_sentence(StabilityMargin(0.05, 1.0), 0.09)
    assert "winding-number condition assumed" in stability_sentence(
        StabilityMargin(0.5, 1.0), 0.1, measured=True
    )
    assert "does not stabilise the model" in stability_sentence(
        StabilityMargin(0.0, math.nan, False, "x"), 0.1
    )
    assert "no nu-gap yet" in stability_sentence(StabilityMargin(0.5, 1.0), None)
    check = controller_check(INTEGRATOR, UNIT, None)
    assert check.guaranteed_stable is None and check.nu_gap is None


def test_small_numbers_keep_two_significant_digits():
    from gap_validation.core.robust import StabilityMargin

    assert "b = 0.00063 <= nu-gap 0.25000" in stability_sentence(StabilityMargin(0.00063, 1.0), 0.25)
    assert "b = 0.0085" in stability_sentence(StabilityMargin(0.0085, 1.0), None)
