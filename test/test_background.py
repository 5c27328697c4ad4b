"""Tests of gap_validation.core.background (the trim motion between manoeuvres) and of the judgements built on
it: the excitation floor (spectra.record_bands' ``background``), the feedback test and its bias bound
(closed_loop.feedback_evidence, feedback_bias) and the detector's quiet level (sweeps.quiet_quantile).

Each judgement is a test with a stated null distribution; these tests check the statistic against an
independent estimator (scipy's Welch estimates) and measure the false-positive rate on seeded draws under the
null."""
import json

import numpy as np
import pytest
from scipy import signal

from gap_validation.core.background import (
    MIN_TRIM_AVERAGES,
    LeadTest,
    TrimResponse,
    TrimSpectra,
    TrimSpectrum,
)
from gap_validation.core.closed_loop import (
    FEEDBACK_FALSE_ALARM,
    LEAD_SHARE,
    feedback_bias,
    feedback_evidence,
    rate_leads,
)
from gap_validation.core.spectra import STATUS_BELOW_TRIM, record_bands
from gap_validation.core.sweeps import SweepDetector, quiet_quantile

DT = 0.01
W = np.logspace(0.0, np.log10(40.0), 30)


def _trim(x, guard_s=0.0):
    spec = TrimSpectrum(W, x.shape[0], DT, guard_s=guard_s)
    spec.feed(0, x)
    spec.end_stretch()
    return spec


def test_white_noise_gives_its_variance_per_bin_in_the_records_units():
    rng = np.random.default_rng(1)
    x = 0.3 * rng.standard_normal((1, 400_000))
    spec = _trim(x)
    # the sums' means are Welch's estimate; the floor is the median over the kept segments (bias-corrected):
    # both the variance per bin, the median within its scatter (64 segments of a few bins: about 15 %)
    np.testing.assert_allclose(spec.sums[:, 0, 0].real / spec.bins, 0.09, rtol=0.08)
    np.testing.assert_allclose(spec.power([0]), 0.09, rtol=0.35)
    assert np.median(spec.power([0])) == pytest.approx(0.09, rel=0.1)
    # the record's normalised DFT (record_bands divides by sqrt(N)) of the same noise has the same level
    fx = np.fft.rfft(x[0, :6000]) / np.sqrt(6000)
    assert np.mean(np.abs(fx[10:]) ** 2) == pytest.approx(0.09, rel=0.1)


def test_the_response_between_manoeuvres_is_scipys_welch_estimate():
    """S_yu / S_uu over a band equals scipy.signal.csd / welch with the same segments (Hann, half overlap, a
    straight line removed per segment), summed over the band's bins."""
    rng = np.random.default_rng(2)
    n = 4000                                            # one 40 s stretch: 20 s segments, half overlapping
    u = signal.lfilter([1.0], [1.0, -0.9], rng.standard_normal(n))
    b, a = signal.butter(2, 0.1)
    y = signal.lfilter(b, a, u) + 0.05 * rng.standard_normal(n)
    spec = _trim(np.stack([u, y]))
    h, coherence, bins = spec.response(0, 1)
    f, pyu = signal.csd(u, y, fs=1 / DT, window="hann", nperseg=2000, noverlap=1000, detrend="linear")
    _, puu = signal.welch(u, fs=1 / DT, window="hann", nperseg=2000, noverlap=1000, detrend="linear")
    _, pyy = signal.welch(y, fs=1 / DT, window="hann", nperseg=2000, noverlap=1000, detrend="linear")
    w_bins = 2 * np.pi * f
    for i in np.flatnonzero(bins > 0):
        half = max(0.1 * W[i], 1.5 * (w_bins[1] - w_bins[0]))
        sel = np.abs(w_bins - W[i]) <= half + 1e-9
        ref = np.sum(pyu[sel]) / np.sum(puu[sel])
        assert h[i] == pytest.approx(ref, rel=1e-6)
        coh = np.abs(np.sum(pyu[sel])) ** 2 / (np.sum(puu[sel]) * np.sum(pyy[sel]))
        assert coherence[i] == pytest.approx(coh, rel=1e-6)


def test_trim_held_back_by_the_guard_is_given_to_the_record_that_reaches_back():
    spec = TrimSpectrum(W, 1, DT, guard_s=10.0)
    rng = np.random.default_rng(3)
    # 25 s: nothing released yet (20 s segment + 10 s guard)
    spec.feed(0, rng.standard_normal((1, 2500)))
    assert spec.segments == 0
    spec.cut(2000)                                     # a record starting at 20 s takes the last 5 s
    assert spec.samples == 2000


def test_a_stray_manoeuvre_in_the_trim_does_not_raise_the_floor():
    """The floor is a median over segments: one segment holding a missed sweep leaves it at the trim level."""
    rng = np.random.default_rng(4)
    spec = TrimSpectrum(W, 1, DT, guard_s=0.0)
    for k in range(9):
        x = 0.003 * rng.standard_normal((1, 2000))
        if k == 4:
            t = np.arange(2000) * DT
            x = x + 0.05 * np.sin(2 * np.pi * 2.0 * t)
        spec.feed(k * 10_000, x)
    spec.end_stretch()
    assert np.nanmedian(spec.power([0])) == pytest.approx(0.003 ** 2, rel=0.3)
    assert spec.std(0) == pytest.approx(0.003, rel=0.1)


def test_a_record_of_trim_motion_is_below_trim_and_a_sweep_above_it_counts():
    rng = np.random.default_rng(5)
    trim = signal.lfilter([1.0], [1.0, -0.95], 0.0005 * rng.standard_normal(40_000))
    background = _trim(trim[None, :]).power([0])
    t = np.arange(3000) * DT
    wander = signal.lfilter([1.0], [1.0, -0.95], 0.0005 * rng.standard_normal(t.size))
    _, status = record_bands(wander[None, :], wander[None, :], DT, W, background=background)
    assert not np.any(status == 0)
    assert np.any(status == STATUS_BELOW_TRIM)
    sweep = wander + 0.05 * signal.chirp(t, 0.3, t[-1], 5.0, method="logarithmic")
    _, status = record_bands(sweep[None, :], sweep[None, :], DT, W, background=background)
    assert np.count_nonzero(status == 0) >= 15


def _trim_response(h, n_avg=40, coherence=0.9):
    f = h.size
    return TrimResponse(np.asarray(h, complex), np.full(f, coherence), np.full(f, float(n_avg)), np.ones(f))


def test_open_loop_is_called_closed_loop_at_most_at_the_stated_rate():
    """Under "no feedback" the trim and manoeuvre responses are the same airframe plus their noise: over 4000
    seeded channels of 30 frequencies the feedback test fires at most at FEEDBACK_FALSE_ALARM (1e-3)."""
    rng = np.random.default_rng(6)
    p = (1.0 + 1j * W / 5.0) ** -2
    n_avg, coherence = 12, 0.7
    v_trim = (1 - coherence) / (coherence * n_avg)
    v_man = 0.02 ** 2
    calls = 0
    draws = 4000
    for _ in range(draws):
        noise_t = np.sqrt(v_trim / 2) * (rng.standard_normal(W.size) + 1j * rng.standard_normal(W.size))
        noise_m = np.sqrt(v_man / 2) * (rng.standard_normal(W.size) + 1j * rng.standard_normal(W.size))
        trim = _trim_response(p * (1 + noise_t), n_avg, coherence)
        calls += feedback_evidence(
            trim, p * (1 + noise_m), v_man * np.abs(p) ** 2, np.ones(W.size, bool)
        ).detected
    assert calls / draws <= FEEDBACK_FALSE_ALARM + 3 * np.sqrt(FEEDBACK_FALSE_ALARM / draws)


def test_a_loop_answering_turbulence_is_found_and_a_rate_limit_is_not_a_loop():
    p = 8.0 / (1.0 + 1j * W / 5.0)
    controller = 0.4 * np.exp(-1j * W * 0.02)
    trim = _trim_response(-1.0 / controller)                 # between manoeuvres the loop: -1/C
    found = feedback_evidence(trim, p, (0.02 * np.abs(p)) ** 2, np.ones(W.size, bool))
    assert found.detected and found.opposite[W < 5].all()
    smaller = _trim_response(p * np.where(W > 10, 0.6, 1.0))  # a rate limit: the gain changes, not the sign
    assert not feedback_evidence(smaller, p, (0.02 * np.abs(p)) ** 2, np.ones(W.size, bool)).detected


def test_without_a_manoeuvre_response_the_model_is_the_reference_scaled_where_the_manoeuvres_measured():
    p = 8.0 / (1.0 + 1j * W / 5.0)
    # open loop, the airframe -P: the model's sign is wrong
    trim = _trim_response(-p * 1.05)
    measured = np.where(W > 20, -p, np.nan)                  # the manoeuvres measured only above 20 rad/s
    variance = np.where(W > 20, (0.02 * np.abs(p)) ** 2, np.inf)
    assert not feedback_evidence(trim, measured, variance, W > 20, model=p).detected
    loop = _trim_response(p * -2.0)
    assert feedback_evidence(loop, np.full(W.size, np.nan), np.full(W.size, np.inf), np.zeros(W.size, bool),
                             model=p).detected


def test_trim_estimates_on_few_averages_are_not_compared():
    p = 8.0 / (1.0 + 1j * W / 5.0)
    few = _trim_response(-p, n_avg=MIN_TRIM_AVERAGES - 1, coherence=0.999)
    assert not few.confident().any()


def test_a_manoeuvre_20_db_above_the_trim_motion_is_not_biased():
    p = 8.0 / (1.0 + 1j * W / 5.0)
    trim = TrimResponse(-2.0 * p, np.full(W.size, 0.9), np.full(W.size, 40.0), np.ones(W.size))
    variance = (0.05 * np.abs(p)) ** 2
    assert not feedback_bias(trim, p, variance, np.full(W.size, 100.0)).any()          # 20 dB: 1 % x |3 P|
    assert feedback_bias(trim, p, variance, np.full(W.size, 3.0)).all()                # 5 dB


def _airframe_trim(rng, n, loop_gain=0.0, pilot=0.003, gust=0.02, noise=0.002):
    """Trim at 100 Hz: a roll-rate airframe 50 / (s + 10) (discretised), a pilot's slow corrections (white
    noise through 1 s knots, as the second simulator's), gusts at the surface, sensor noise on both logged
    signals; with ``loop_gain`` a damper u = -K y_measured one step late adds to the pilot's input."""
    knots = rng.standard_normal(n // 100 + 2)
    command = pilot * np.interp(np.arange(n) / 100, np.arange(knots.size), knots)
    b, a = signal.butter(1, 2.0 / (np.pi * 100))
    d = signal.lfilter(b, a, rng.standard_normal(n))
    d *= gust / d.std()
    pole = np.exp(-10 * DT)
    y = np.zeros(n)
    u = np.zeros(n)
    y_meas = np.zeros(n)
    for k in range(1, n):
        u[k] = command[k] - loop_gain * y_meas[k - 1]
        y[k] = pole * y[k - 1] + 5.0 * (1 - pole) * (u[k - 1] + d[k - 1])
        y_meas[k] = y[k] + noise * rng.standard_normal()
    return np.stack([u + 0.1 * noise * rng.standard_normal(n), y_meas])


def test_the_lead_test_is_the_nested_least_squares_f_test_and_regresses_each_sample_once():
    """One segment: the share and F equal two least-squares fits of the surface on the lags (numpy's lstsq on
    the detrended data, built here independently). A long stretch fed through the half-overlapping spectra:
    every sample after the first lags regressed once."""
    rng = np.random.default_rng(11)
    x = _airframe_trim(rng, 3500, loop_gain=0.05)      # 35 s: more than LEAD_MIN_S
    lead = LeadTest(DT, 0, 1)
    t = np.arange(x.shape[1]) - (x.shape[1] - 1) / 2
    detrended = x - x.mean(axis=1, keepdims=True)
    detrended -= np.outer(detrended @ t / (t @ t), t)
    lead.add(detrended)
    p, step = lead.lags, lead.step
    # 0.25 s at 100 Hz in at most 16 lags: 1, 3, 5, ... 23 steps
    assert (p, step) == (12, 2)
    rows = np.arange(1 + (p - 1) * step, x.shape[1])
    own = np.stack([detrended[0, rows - 1 - j * step] for j in range(p)], axis=1)
    rate = np.stack([detrended[1, rows - 1 - j * step] for j in range(p)], axis=1)
    target = detrended[0, rows]
    rss_own = np.sum((target - own @ np.linalg.lstsq(own, target, rcond=None)[0]) ** 2)
    both = np.hstack((own, rate))
    rss_both = np.sum((target - both @ np.linalg.lstsq(both, target, rcond=None)[0]) ** 2)
    got = lead.result()
    assert got.rows == rows.size and got.lags == p and got.lags_s == pytest.approx(0.23)
    assert got.share == pytest.approx((rss_own - rss_both) / rss_own, rel=1e-6)
    assert got.f == pytest.approx((rss_own - rss_both) / p / (rss_both / (rows.size - 2 * p)), rel=1e-6)
    spec = TrimSpectrum(W, 2, DT, guard_s=0.0, lead=(0, 1))
    spec.feed(0, _airframe_trim(rng, 9000))
    spec.end_stretch()
    assert spec.lead.rows == 9000 - 1 - (p - 1) * step


def test_a_pilots_corrections_do_not_lead_and_a_damper_does():
    """Open loop the rate's past adds nothing once the surface's own past is known: over 100 seeded minutes of
    a pilot's corrections with gusts, the share stays below LEAD_SHARE and rate_leads never fires; a damper
    answering the same gusts leads, whatever the pilot does beside it."""
    rng = np.random.default_rng(12)
    shares = []
    for _ in range(100):
        spec = TrimSpectrum(W, 2, DT, guard_s=0.0, lead=(0, 1))
        spec.feed(0, _airframe_trim(rng, 6000))
        spec.end_stretch()
        result = spec.lead.result()
        shares.append(result.share)
        assert not rate_leads(result)
    assert max(shares) < LEAD_SHARE / 5
    for gain in (0.05, 0.2):
        spec = TrimSpectrum(W, 2, DT, guard_s=0.0, lead=(0, 1))
        spec.feed(0, _airframe_trim(rng, 6000, loop_gain=gain))
        spec.end_stretch()
        assert rate_leads(spec.lead.result()), gain


def test_quiet_quantile_is_the_tenth_percentile_of_the_blocks_seen():
    blocks = np.array([[5.0, 1.0, 2.0, 3.0, 4.0, 6.0, 7.0, 8.0, 9.0, 10.0, np.inf, np.inf]])
    assert quiet_quantile(blocks)[0] == 1.0
    more = np.array([np.concatenate((np.arange(1.0, 21.0), [np.inf]))])
    assert quiet_quantile(more)[0] == 2.0
    assert quiet_quantile(np.full((1, 4), np.inf))[0] == np.inf


def test_random_trim_motion_makes_no_manoeuvre():
    """A pilot's corrections (a new random trim every 0.2 s, linearly joined) for 20 minutes: no excitation is
    detected, where the minimum of the one-second energies as the quiet level found dozens."""
    rng = np.random.default_rng(7)
    knots = 0.003 * rng.standard_normal(6001)
    t = np.arange(0.0, 1200.0, DT)
    u = np.interp(t, np.arange(knots.size) * 0.2, knots) + 0.0005 * rng.standard_normal(t.size)
    det = SweepDetector(1 / DT)
    det.start_run(0)
    edges = det.process(0, u) + det.end_run(u.size)
    assert not [e for e in edges if e[1]]
    chirp = u + np.where(
        (t > 600) & (t < 625), 0.012 * np.sin(2 * np.pi * (0.5 + 0.1 * (t - 600)) * (t - 600)), 0
    )
    det = SweepDetector(1 / DT)
    det.start_run(0)
    edges = det.process(0, chirp) + det.end_run(u.size)
    starts = [k * DT for k, on in edges if on]
    assert len(starts) == 1 and 595 < starts[0] < 610


def test_an_error_wider_than_the_coherence_allows_is_not_called_random():
    """Issue 22: a channel whose response is the model's with the opposite sign, at coherence 0.98 on 60
    degrees of freedom, cannot be "explained by the random error"; where a bias allowance widened its errors
    (a feedback or coupling warning), the band says so instead."""
    from types import SimpleNamespace

    from gap_validation.core.closed_loop import BIAS_ALLOWANCE
    from gap_validation.core.diagnosis import analyse_channel, bendat_piersol_random_error
    from gap_validation.core.models import LinearModel

    model = LinearModel([5.0], [1.0, 5.0])
    p = model.freqresp(W)
    measured = -p * (1.0 + 0.02j)                           # the opposite sign, within 1 deg
    coherence, dof = np.full(W.size, 0.98), np.full(W.size, 60.0)
    honest = bendat_piersol_random_error(coherence, dof)

    def estimate(error):
        return SimpleNamespace(
            w_rad_s=W,
            response=measured,
            coherence=coherence,
            n_averages=dof,
            random_error=error,
            coefficients=3,
            variance=2 * (error * np.abs(measured)) ** 2,
        )

    assert analyse_channel(model, estimate(honest), [], 0.6, fit=False).limited_by == "model"
    allowed = analyse_channel(model, estimate(np.full(W.size, BIAS_ALLOWANCE)), [], 0.6, fit=False)
    assert allowed.limited_by == "data"
    assert all(
        "bias allowance" in b.reason and "random error explains" not in b.reason for b in allowed.bands
    )


def _loop_flight(gain: float, seconds: float = 1200.0, seed: int = 5):
    """Trim only: a first-order airframe ``y = P u + n`` (``P(z) = 0.5 z^-1 / (1 - 0.95 z^-1)``), gusts ``n``
    (white noise through a low-pass, known spectrum), a pilot's open-loop corrections, and with ``gain`` > 0
    a loop that moves the surface against the measured output (``u = pilot - gain y``): the surface then
    follows the gusts."""
    rng = np.random.default_rng(seed)
    n_samples = int(seconds / DT)
    bn, an = signal.butter(1, 0.02)
    gust = 0.05 * signal.lfilter(bn, an, rng.standard_normal(n_samples))
    pilot = 0.01 * signal.lfilter(*signal.butter(1, 0.05), rng.standard_normal(n_samples))
    u, y = np.zeros(n_samples), np.zeros(n_samples)
    state = 0.0
    for k in range(n_samples):
        y[k] = state + gust[k]
        u[k] = pilot[k] - gain * y[k]
        state = 0.95 * state + 0.5 * u[k]
    model = signal.freqz([0.0, 0.5], [1.0, -0.95], worN=W * DT)[1]
    noise = 0.05 ** 2 * np.abs(signal.freqz(bn, an, worN=W * DT)[1]) ** 2     # per bin, the records' units
    return np.stack([u, y]), model, noise


@pytest.mark.parametrize("gain", [0.0, 0.5])
def test_the_trim_output_error_is_the_noise_whatever_moves_the_surface(gain):
    """E |Y - P U|^2 between manoeuvres is the output's noise (its known spectrum, per bin in the records'
    units) whether a pilot moves the surface open loop or a loop moves it against the gusts; the regression
    residual S_yy (1 - coherence) is the noise only in open loop: in the loop it removes the gusts the surface
    followed."""
    x, model, noise = _loop_flight(gain)
    trim = _trim(x).spectra(0, 1)
    assert np.all(trim.averages >= MIN_TRIM_AVERAGES)
    ratio = trim.output_error(model) / noise
    assert np.median(ratio) == pytest.approx(1.0, abs=0.1)
    assert np.all((ratio > 0.7) & (ratio < 1.4))
    regression = trim.output_power - np.abs(trim.cross) ** 2 / trim.input_power
    low = W < 5.0
    if gain == 0.0:
        assert np.median(regression[low] / noise[low]) == pytest.approx(1.0, abs=0.15)
    else:
        assert np.median(regression[low] / noise[low]) < 0.5


def test_trim_spectra_read_back_from_json_and_take_frequencies():
    x, model, _ = _loop_flight(0.0, seconds=120.0)
    trim = _trim(x).spectra(0, 1)
    back = TrimSpectra.from_json_dict(json.loads(json.dumps(trim.to_json_dict())))
    for name in ("input_power", "output_power", "cross", "averages"):
        np.testing.assert_array_equal(getattr(back, name), getattr(trim, name))
    np.testing.assert_array_equal(back.output_error(model), trim.output_error(model))
    part = trim.take(np.arange(3, 7))
    np.testing.assert_array_equal(part.output_error(model[3:7]), trim.output_error(model)[3:7])
