"""Tests of gap_validation.core.spectra: the local polynomial estimate of whole records, pooled over records.

References: the true response of the simulated system, scipy.signal's Welch estimates (csd / welch) of the
same samples, and the F distribution the error statistic must follow.
"""
import math

import numpy as np
import pytest
from scipy import signal, stats

from gap_validation.core.alignment import StreamResampler
from gap_validation.core.spectra import (
    STATUS_ABOVE_GRID,
    STATUS_NOT_EXCITED,
    STATUS_TOO_SHORT,
    BandSums,
    band_bins,
    expected_estimate,
    interpolation_gain,
    neighbour_noise_floor,
    record_bands,
    solve_bands,
)

DT = 0.01
W = np.geomspace(1.0, 40.0, 25)
NUM, DEN = [-133.7, -990.76], [1.0, 23.37, 235.93]          # the paper's pitch-rate model (DESIGN.md)


_B, _A, _ = signal.cont2discrete((NUM, DEN), DT, method="foh")
_B = np.squeeze(_B)


def response(w):
    """The response of the system that makes the grid samples: the model discretised for a piecewise-linear
    input (it differs from the continuous model by the hold, 0.1 % at 40 rad/s)."""
    return signal.freqz(_B, _A, worN=np.asarray(w, float) * DT)[1]


def system_output(u):
    """Pitch rate for input samples ``u`` on the grid (exact for a piecewise-linear input)."""
    return signal.lfilter(_B, _A, u)


def noisy_record(rng, n=6000, noise=0.05, settle=True):
    """White-noise input (low-passed), the system's output plus white noise; trim before and after."""
    u = signal.lfilter(*signal.butter(4, 0.3), rng.standard_normal(n))
    if settle:
        u[:200] = 0.0
        u[-400:] = 0.0
    return u, system_output(u) + noise * rng.standard_normal(n)


def estimate(records, **options):
    sums = BandSums.zeros(W.size, order=options.get("order", 2))
    for u, y in records:
        rec, status = record_bands(u[None], y[None], DT, W, options=options)
        sums.add(rec, status == 0)
    return sums, solve_bands(sums)


def test_noise_free_record_gives_the_model_through_the_estimator():
    u, y = noisy_record(np.random.default_rng(0), noise=0.0)
    sums, est = estimate([(u, y)])
    through, error = expected_estimate(sums, W, 0.1, response)
    ok = np.isfinite(est.response)
    assert ok.sum() >= 20
    assert np.all(error[ok] < 1e-6)
    assert np.allclose(est.response[ok], through[ok], rtol=1e-6, atol=0)
    # and both are within a fraction of a percent of the model at the frequency itself
    assert np.max(np.abs(est.response[ok] / response(W[ok]) - 1.0)) < 5e-3


def test_a_singular_band_leaves_only_itself_unknown():
    """The bands are solved together; one whose regressors are singular is NaN and the others are as
    before."""
    u, y = noisy_record(np.random.default_rng(0), noise=0.0)
    sums, _ = estimate([(u, y)])
    before, _ = expected_estimate(sums, W, 0.1, response)
    k = int(np.flatnonzero(np.isfinite(before))[3])
    sums.zf[k] = 0.0
    after, error = expected_estimate(sums, W, 0.1, response)
    assert np.isnan(after[k]) and error[k] == 0.0
    others = np.isfinite(before) & (np.arange(W.size) != k)
    np.testing.assert_array_equal(after[others], before[others])


def test_error_statistic_follows_the_f_distribution():
    # |H_est - H|^2 / variance ~ F(2, 2 dof): its 95 % quantile is exceeded 5 % of the time; the neighbour
    # floor on the noise (solve_bands) only ever raises the variance, so a little less (3.4 % here; 5.0 %
    # without it)
    rng = np.random.default_rng(1)
    exceed, total = 0, 0
    for _ in range(60):
        sums, est = estimate([noisy_record(rng, noise=0.3)])
        through, _ = expected_estimate(sums, W, 0.1, response)
        ok = np.isfinite(est.response) & (est.dof >= 2)
        z = np.abs(est.response[ok] - through[ok]) ** 2 / est.variance[ok]
        exceed += int(np.sum(z > stats.f.ppf(0.95, 2, 2 * est.dof[ok])))
        total += int(ok.sum())
    assert total > 800
    assert 0.025 < exceed / total < 0.06


def test_agrees_with_scipy_welch_on_a_long_record():
    rng = np.random.default_rng(2)
    u, y = noisy_record(rng, n=60000, noise=0.3, settle=False)
    _, est = estimate([(u, y)])
    f, pxy = signal.csd(u, y, fs=1 / DT, nperseg=4096)
    _, pxx = signal.welch(u, fs=1 / DT, nperseg=4096)
    welch = np.interp(W, 2 * np.pi * f, (pxy / pxx).real) + 1j * np.interp(W, 2 * np.pi * f, (pxy / pxx).imag)
    sigma = np.sqrt(est.variance / 2.0)
    ok = np.isfinite(est.response) & (W > 2.0)
    # the estimate is within 4 sigma of the truth, and scipy's within a percent or so of ours
    assert np.mean(np.abs(est.response[ok] - response(W[ok])) < 4 * np.sqrt(2) * sigma[ok]) >= 0.95
    assert np.median(np.abs(welch[ok] / est.response[ok] - 1.0)) < 0.02


def test_a_record_cut_mid_response_is_handled_by_the_transient_term():
    # the record starts while the system still rings from a large earlier input (nonzero initial state):
    # without a transient term the free response lands in the estimate (33 % median error here), a constant
    # one removes most of it (4 %), a linear one more (1 %); the error bounds stay honest in every case
    rng = np.random.default_rng(3)
    errors = {-1: [], 0: [], 1: []}
    for _ in range(12):
        u = signal.lfilter(*signal.butter(4, 0.3), rng.standard_normal(3000))
        u[:2000] *= 20.0
        y = system_output(u) + 0.01 * rng.standard_normal(u.size)
        cut = slice(2000, 2600)                                    # 6 s of it, right after the large input
        for order in errors:
            sums, est = estimate([(u[cut], y[cut])], transient_order=order)
            ok = np.isfinite(est.response)
            errors[order].append(np.median(np.abs(est.response[ok] / response(W[ok]) - 1.0)))
            through, _ = expected_estimate(sums, W, 0.1, response)
            honest = np.abs(est.response[ok] - through[ok]) <= 5 * np.sqrt(est.variance[ok])
            assert honest.mean() > 0.9
    median = {order: float(np.median(e)) for order, e in errors.items()}
    assert median[-1] > 4 * median[0] > 4 * median[1]


def test_pooling_adds_degrees_of_freedom_and_lowers_the_variance():
    rng = np.random.default_rng(4)
    a, b = noisy_record(rng, noise=0.3), noisy_record(rng, noise=0.3)
    _, one = estimate([a])
    sums, two = estimate([a, b])
    ok = np.isfinite(one.response) & (sums.records == 2)
    nh = 3                                                         # order 2: three coefficients
    assert np.all(two.dof[ok] == sums.dof[ok] - nh)
    assert np.all(two.dof[ok] > one.dof[ok])
    assert np.median(two.variance[ok] / one.variance[ok]) < 0.7


def test_instruments_equal_to_the_inputs_give_least_squares():
    rng = np.random.default_rng(5)
    u, y = noisy_record(rng, noise=0.2)
    ls, _ = record_bands(u[None], y[None], DT, W)
    iv, _ = record_bands(u[None], y[None], DT, W, instruments=u[None])
    a, b = solve_bands(ls), solve_bands(iv)
    ok = np.isfinite(a.response)
    assert np.allclose(a.response[ok], b.response[ok], rtol=1e-9)
    assert np.allclose(a.variance[ok], b.variance[ok], rtol=1e-9)


def test_band_widens_to_min_bins_and_a_record_too_short_resolves_nothing_low():
    w_bins = 2 * np.pi * np.fft.rfftfreq(1000, DT)                  # 10 s: bins 0.63 rad/s apart
    assert band_bins(w_bins, 30.0, 0.1, 7, 0.6).size == 10          # +-3 rad/s: the band's own bins
    assert band_bins(w_bins, 6.0, 0.1, 7, 0.6).size == 7            # widened to 7 bins (+-1.9 rad/s)
    assert band_bins(w_bins, 2.0, 0.1, 7, 0.6).size == 0            # 7 bins would reach past +-60 %


def test_multisine_bands_hold_its_lines_not_the_empty_bins_between_them():
    n = 4000
    k = np.arange(n // 2 + 1)
    power = np.where(k % 8 == 0, 1.0, 1e-8)                         # a line every 8th bin
    w_bins = 2 * np.pi * np.fft.rfftfreq(n, DT)
    sel = band_bins(w_bins, 60.0, 0.1, 7, 0.6, power)
    assert sel.size >= 7 and np.all(sel % 8 == 0)


def test_why_a_record_does_not_count():
    rng = np.random.default_rng(6)
    t = np.arange(0.0, 60.0, DT)
    f = 2.0 * np.exp(np.log(20.0 / 2.0) * t / 60.0) / (2 * np.pi)  # a chirp from 2 to 20 rad/s
    u = np.sin(2 * np.pi * np.cumsum(f) * DT) + 1e-3 * rng.standard_normal(t.size)
    y = system_output(u) + 1e-3 * rng.standard_normal(t.size)
    _, status = record_bands(u[None], y[None], DT, np.array([0.1, 10.0, 35.0, 200.0]), noise_floor=1e-6,
                             max_rad_s=150.0)
    assert list(status) == [STATUS_TOO_SHORT, 0, STATUS_NOT_EXCITED, STATUS_ABOVE_GRID]


@pytest.mark.parametrize("fraction", [0.05, 0.15, 0.25])
def test_interpolation_gain_is_what_the_resampler_loses(fraction):
    rate = 50.0
    t = np.arange(0.0, 20.0, 1.0 / rate)
    w = 2 * np.pi * fraction * rate
    resampler = StreamResampler(0.01 * 0.9993, 0.5, True)          # a grid drifting through every phase
    k, v = resampler.add(t, np.sin(w * t))
    tg = k * 0.01 * 0.9993
    fit = np.linalg.lstsq(np.column_stack([np.sin(w * tg), np.cos(w * tg)]), v, rcond=None)[0]
    assert math.hypot(*fit) == pytest.approx(float(interpolation_gain(np.array([w]), rate)[0]), abs=2e-3)


def test_neighbour_noise_floor_pools_a_frequency_with_its_neighbours():
    floor = neighbour_noise_floor(np.array([1.0, 0.1, 1.0]), np.array([3, 3, 3]))
    assert floor == pytest.approx([0.55, 0.7, 0.55])
    # weighted by degrees of freedom; frequencies without an estimate neither count nor get one
    floor = neighbour_noise_floor(np.array([1.0, 2.0, np.inf, 0.5, np.nan]), np.array([1, 3, 0, 4, 0]))
    assert floor[:2] == pytest.approx([7.0 / 4.0, 7.0 / 4.0]) and floor[3] == pytest.approx(0.5)
    assert np.isnan(floor[2]) and np.isnan(floor[4])


def test_the_floor_makes_chance_low_noise_estimates_rare():
    """On 3 degrees of freedom a noise estimate falls below a quarter of the truth one time in 25 (chi^2(6) /
    6); never below its neighbours' pooled estimate, one time in thousands. Where the estimate is right it
    changes it little (median ratio of the floored to the own estimate at most 1.2)."""
    rng = np.random.default_rng(7)
    d = 3
    own = rng.chisquare(2 * d, size=(20000, 40)) / (2 * d)       # true noise 1 at every frequency
    floored = np.maximum(own, np.array([neighbour_noise_floor(row, np.full(40, d)) for row in own]))
    assert np.mean(own < 0.25) == pytest.approx(stats.chi2.cdf(1.5, 2 * d), rel=0.05)     # 0.041
    assert np.mean(floored < 0.25) < 1e-3
    assert np.median(floored / own) < 1.2


def test_solve_bands_raises_a_noise_below_its_neighbours_floor_and_its_variance_with_it(monkeypatch):
    from gap_validation.core import spectra

    sums, est = estimate([noisy_record(np.random.default_rng(3), noise=0.3)])
    monkeypatch.setattr(spectra, "neighbour_noise_floor", lambda noise, dof: np.full(noise.shape, np.nan))
    own = solve_bands(sums)                                    # the estimates without the floor
    floor = neighbour_noise_floor(own.noise, own.dof)
    known = np.isfinite(floor)
    assert known.sum() >= 15 and np.any(floor[known] > own.noise[known])     # some are raised
    assert np.allclose(est.noise[known], np.maximum(own.noise[known], floor[known]), rtol=1e-12)
    assert np.allclose(
        est.variance[known] / own.variance[known], est.noise[known] / own.noise[known], rtol=1e-12
    )
    assert np.array_equal(est.response[known], own.response[known])     # the response itself is untouched
