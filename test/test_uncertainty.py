"""Monte Carlo of the uncertain model (paper Fig. 6): all-pass perturbations on the epsilon-disk boundary."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gap_validation.core import metrics
from gap_validation.core.errors import DataError
from gap_validation.core.manoeuvres import Manoeuvre
from gap_validation.core.models import LinearModel
from gap_validation.core.uncertainty import (
    filter_uniform,
    monte_carlo_tube,
    sample_perturbations,
    time_domain_check,
)

P1 = LinearModel.from_spec({"numerator": [18.75, 225.0], "denominator": [1.0, 9.0, 225.0]})   # eq. 18


def doublet_input(dt=0.01, duration=8.0):
    t = np.arange(0.0, duration, dt)
    u = np.where((t >= 1.0) & (t < 1.5), 1.0, 0.0) - np.where((t >= 1.5) & (t < 2.0), 1.0, 0.0)
    return t, 0.05 * u


@settings(max_examples=25, deadline=None)
@given(eps=st.floats(0.0, 0.95), seed=st.integers(0, 10_000))
def test_perturbations_lie_on_the_disk_boundary_at_every_frequency(eps, seed):
    w = np.geomspace(1e-3, 1e4, 4000)
    p1 = P1.freqresp(w)
    for p in sample_perturbations(eps, 12, (1.0, 40.0), seed):
        p2 = p1 * p.freqresp(w)
        eps_w = metrics.epsilon_per_frequency(p1, p2)
        assert np.all(eps_w <= eps + 1e-9)                  # inside the epsilon disk (eq. 14) ...
        assert np.all(eps_w >= eps - 1e-9)                  # ... on its boundary, as the paper samples
        assert np.all(np.roots(p.den).real < 0) if len(p.den) > 1 else True   # a stable perturbed model
        assert np.allclose(np.abs(np.polyval(p.allpass_num, 1j * w) / np.polyval(p.allpass_den, 1j * w)), 1.0)


def test_first_two_samples_are_the_gain_margin_markers():
    first, second = sample_perturbations(0.1404, 2, (1.0, 40.0))
    assert first.freqresp([0.0, 10.0]) == pytest.approx([1.1404 / 0.8596] * 2)   # upper marker, 1.33
    assert second.freqresp([0.0, 10.0]) == pytest.approx([0.8596 / 1.1404] * 2)  # lower marker, 0.75


def test_nominal_response_lies_inside_the_tube():
    t, u = doublet_input()
    tube = monte_carlo_tube(P1, 0.14, t, u, count=500, band_rad_s=(1.0, 40.0), rng=1)
    assert tube.runs.shape == (500, t.size)
    assert np.all(tube.nominal >= tube.lower - 1e-12) and np.all(tube.nominal <= tube.upper + 1e-12)
    assert tube.fraction_inside(tube.nominal) == 1.0
    # the tube is a real spread: the disk's gain markers alone move the doublet peak by -/+ 14 %
    peak = np.argmax(np.abs(tube.nominal))
    assert tube.upper[peak] - tube.lower[peak] > 0.2 * abs(tube.nominal[peak])
    # a response well outside (three times the model) leaves the tube
    assert tube.fraction_inside(3 * tube.nominal) < 0.9


def test_true_perturbed_plant_inside_the_tube_of_its_epsilon():
    """P2 of eq. 19 is covered by the disk of epsilon 0.1404: its doublet response stays near the tube."""
    p2 = LinearModel.from_spec({"numerator": [18.75, 225.0], "denominator": [1.0, 7.22, 246.5]})
    t, u = doublet_input()
    eps, _ = metrics.epsilon(P1, p2)
    tube = monte_carlo_tube(P1, eps, t, u, count=500, band_rad_s=(1.0, 100.0), rng=2)
    y2 = p2.simulate(t, u)
    margin = 0.05 * np.max(np.abs(tube.nominal))
    assert tube.fraction_inside(y2, tolerance=margin) > 0.95


def test_filter_uniform_matches_the_exact_simulation():
    t, u = doublet_input()
    lag = LinearModel.from_spec({"numerator": [10.0], "denominator": [1.0, 10.0]})
    assert filter_uniform([10.0], [1.0, 10.0], 0.01, u) == pytest.approx(lag.simulate(t, u), abs=1e-9)


def test_bad_epsilon_and_input_are_one_line_errors():
    t, u = doublet_input()
    with pytest.raises(DataError, match="epsilon < 1"):
        monte_carlo_tube(P1, 1.2, t, u)
    with pytest.raises(DataError, match="uniformly sampled"):
        monte_carlo_tube(P1, 0.1, np.r_[t[:10], t[11:]], np.r_[u[:10], u[11:]])


def test_time_domain_check_tic_of_model_against_itself_and_a_wrong_model():
    t, u = doublet_input()
    trim_u, trim_y = 0.02, 0.3
    y = P1.simulate(t, u)
    same = time_domain_check(
        P1, Manoeuvre("doublet", 1.7e9 + t, u + trim_u, y + trim_y, 1.7e9 + 1, 1.7e9 + 4, 90)
    )
    assert same.tic == pytest.approx(0.0, abs=1e-9)
    opposite = time_domain_check(P1, Manoeuvre("doublet", t, u, -y, 1.0, 4.0, 90))
    assert opposite.tic == pytest.approx(1.0)
    assert opposite.tic_input_augmented < opposite.tic
