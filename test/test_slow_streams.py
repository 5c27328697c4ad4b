"""A slow stream (PX4 logs its servos at 10 Hz) is validated up to its Nyquist frequency, honestly.

The estimator reads a stream of rate fs up to a quarter of fs, or -- a slow stream, at most a fifth of the
grid's rate, whose channel samples the other side (the gyro) at least four times faster -- up to fs/2, every
band (+-10 % of a frequency) below it: 31.4 rad/s for 10 Hz surfaces, frequencies up to 28.6 rad/s
(:func:`gap_validation.core.spectra.resolved_hz`). Below fs/2 the interpolation onto the grid is exact once
its gain is restored (the images of the sampling lie above fs/2); what the sampling folds back from above fs/2
(a manoeuvre flown past it, a sweep's tail) shows in the gyro at the mirror frequencies fs - f, and a
frequency where it does is not counted (:data:`gap_validation.core.spectra.MIRROR_MARGIN`,
:data:`~gap_validation.core.spectra.FOLD_NEAR`).

Checked here: the estimate against the true model (the paper's pitch model, ``_pitch_flights``) within its
random error up to the new top and nothing above it; a sweep flown past the Nyquist frequency counted nowhere,
one just past it below what it folds onto; the estimate against an independent one,
``scipy.signal.csd``/``welch`` on the gyro decimated properly to the surfaces' 10 Hz; a simulated PX4 ULog
(servos 10 Hz) clean on several seeds and its hidden 40 ms delay named; streams at the usual rates estimated
exactly as before.
"""
import math

import numpy as np
import pytest
from _flights import SHORT, config_from, single_channel
from _pitch_flights import (
    FINE_HZ,
    W_RAD_S,
    estimate,
    fraction_within,
    log_sweep,
    measure,
    simulate,
    true_response,
)
from scipy import signal

from gap_validation.bag.replay import replay
from gap_validation.cli.arguments import hidden_effects
from gap_validation.core.config import load_config
from gap_validation.core.estimator import FrequencyResponseEstimator
from gap_validation.core.simulation import simulate_flight, with_options
from gap_validation.core.spectra import RESOLVED_FRACTION, resolved_hz
from gap_validation.logs.checks import needed_rate_hz, rate_limit_rad_s, rate_warning
from gap_validation.logs.flight import write_flight_log

W = np.linspace(3.0, 34.0, 32)                    # rad/s: past the Nyquist frequency of 10 Hz surfaces (31.4)
NYQUIST = 10.0 * math.pi                          # of the surfaces at 10 Hz [rad/s]
TOP = NYQUIST / 1.1                               # the highest frequency whose +-10 % band lies below it
SWEEPS = ((10.0, 60.0), (80.0, 60.0))             # (start, length) [s]
T = np.arange(0.0, 150.0, 1.0 / FINE_HZ)


def _fly(f1_hz, gyro_hz, noise_out, seed, aligned=False):
    """Two log sweeps 0.1 Hz to ``f1_hz`` of the pitch model: surfaces at 10 Hz (off the grid's instants), the
    gyro at ``gyro_hz`` (``aligned``: every sample of the surfaces is one of the gyro's)."""
    u = np.full(T.size, -0.02) + sum(
        log_sweep(T - start, 0.1, f1_hz, length, 0.05) for start, length in SWEEPS
    )
    y = simulate(u)
    rng = np.random.default_rng(seed)
    ti = 0.037 + np.arange(1490) * 0.1
    to = 0.037 + np.arange(int(round(1490 * gyro_hz / 10.0))) / gyro_hz if aligned else \
        np.arange(0.0, T[-1], 1.0 / gyro_hz)
    ui = np.interp(ti, T, u) + rng.normal(0.0, 3e-4, ti.size)
    yo = np.interp(to, T, y) + rng.normal(0.0, noise_out, to.size)
    est = FrequencyResponseEstimator(W)
    est.add_time_histories(ti, ui, to, yo)
    est.flush()
    return est, (ti, ui, to, yo)


@pytest.mark.parametrize("gyro_hz", [100.0, 250.0])
def test_ten_hz_surfaces_match_the_model_up_to_their_nyquist_band(gyro_hz):
    """Sweeps to 4.6 Hz (0.46 of the surfaces' rate): validated up to 26-27 rad/s, within the random error of
    the true model; nothing whose band would cross 31.4 rad/s."""
    est, _ = _fly(4.6, gyro_hz, 0.02, seed=1)
    assert est.resolved_rad_s == pytest.approx(NYQUIST)
    avg = est.averaged()
    ok = avg.excited
    h = true_response(W)
    assert W[ok].max() >= 26.0                                  # 0.41 of the rate: a quarter was 15.7 rad/s
    assert not np.any(ok[W > TOP])                              # no band reaches past 31.4 rad/s
    assert fraction_within(avg.response[ok], h[ok], avg.random_error[ok], dof=avg.n_averages[ok]) >= 0.9
    new = ok & (W > 2.0 * math.pi * RESOLVED_FRACTION * 10.0)    # what was not validated before
    assert new.sum() >= 8 and np.max(np.abs(avg.response[new] / h[new] - 1.0)) < 0.03
    assert np.all(np.asarray(avg.reasons["above_grid"])[W > TOP] > 0)


def test_a_sweep_far_past_the_nyquist_frequency_counts_nowhere():
    """Sweeps to 8 Hz logged at 10 Hz: their power at 5-8 Hz folds onto 2-5 Hz, unseen in the surfaces, seen
    in the gyro: what lies that far up may fold anywhere below, so nothing counts, as before surfaces were
    read to their Nyquist frequency."""
    est, _ = _fly(8.0, 250.0, 0.01, seed=2)
    assert est.averaged() is None or not est.averaged().excited.any()
    assert est.not_estimable["not_excited"] > 0


@pytest.mark.parametrize("f1_hz", [5.2, 5.6])
def test_a_sweep_just_past_the_nyquist_frequency_counts_below_what_it_folds_onto(f1_hz):
    """A sweep to 5.2 or 5.6 Hz: its power above 5 Hz (and its tail) folds onto 4.4-5 Hz; the gyro shows that
    nothing beyond 6 Hz (the mirror of 0.4 of the rate) folds back, so the frequencies whose band stays below
    the fold count, and are right."""
    est, _ = _fly(f1_hz, 250.0, 0.01, seed=2)
    avg = est.averaged()
    ok = avg.excited
    assert 20.0 < W[ok].max() < 2.0 * math.pi * (10.0 - f1_hz) / 1.1
    h = true_response(W)
    assert fraction_within(avg.response[ok], h[ok], avg.random_error[ok], dof=avg.n_averages[ok]) >= 0.9
    assert np.max(np.abs(avg.response[ok] / h[ok] - 1.0)) < 0.02


def test_the_estimate_agrees_with_scipy_on_the_gyro_decimated_to_the_surfaces_rate():
    """The reference: the gyro (250 Hz) decimated to 10 Hz by ``scipy.signal.decimate`` (two zero-phase FIR
    stages of 5, whose own response is divided out), the surfaces as logged, the H1 estimate ``csd / welch``
    (Hann windows of 25.6 s, half overlapping) with its random error from the coherence. Above a quarter of
    the rate they agree within their combined random errors."""
    est, (ti, ui, to, yo) = _fly(4.6, 250.0, 0.02, seed=3, aligned=True)
    avg = est.averaged()
    yd = signal.decimate(signal.decimate(yo, 5, ftype="fir"), 5, ftype="fir")
    assert yd.size == ui.size
    kw = dict(fs=10.0, nperseg=256, noverlap=128, detrend="linear")
    f, pxy = signal.csd(ui, yd, **kw)
    _, pxx = signal.welch(ui, **kw)
    _, coh = signal.coherence(ui, yd, **kw)
    fir = signal.firwin(101, 1.0 / 5, window="hamming")            # decimate's own filter (20 q + 1 taps)
    droop = np.abs(signal.freqz(fir, worN=f, fs=250.0)[1] * signal.freqz(fir, worN=f, fs=50.0)[1])
    h_ref = pxy / pxx / droop
    band = avg.excited & (W > 2.0 * math.pi * RESOLVED_FRACTION * 10.0)
    assert band.sum() >= 8
    w_ref = 2.0 * math.pi * f
    ref = np.interp(W[band], w_ref, h_ref.real) + 1j * np.interp(W[band], w_ref, h_ref.imag)
    gamma2 = np.interp(W[band], w_ref, coh)
    ref_error = np.sqrt((1.0 - gamma2) / (2.0 * ((ui.size - 128) // 128) * gamma2))
    diff = np.abs(avg.response[band] / ref - 1.0)
    assert np.median(diff) < 0.015
    assert np.all(diff <= 3.0 * np.hypot(avg.random_error[band], ref_error))
    # the reference itself is right (the model within a few per cent)
    assert np.median(np.abs(ref / true_response(W[band]) - 1.0)) < 0.02


@pytest.fixture(scope="module")
def px4_flights(tmp_path_factory):
    """Simulated PX4 ULogs (servos at 10 Hz, the gyro at 100 Hz, a 30 s sweep to 28.5 rad/s) and their
    replays: three clean seeds and one with a hidden 40 ms delay."""
    root = tmp_path_factory.mktemp("px4")
    config = config_from(
        single_channel("pitch", frequencies={"min_rad_s": 1.0, "max_rad_s": 31.0, "count": 60})
    )
    card = with_options(SHORT, sweeps_per_channel=1, sweep_duration_s=30.0, quiet_s=3.0, surface_rate_hz=10.0,
                        imu_rate_hz=100.0, band_high_factor=0.92)
    out = {}
    for name, seed, hidden in (("clean1", 1, []), ("clean2", 2, []), ("clean3", 3, []),
                               ("delay", 1, ["pitch:time_delay:seconds=0.04"])):
        flight = simulate_flight(config, hidden_effects(hidden, config), card, seed=seed)
        log, config_path, _ = write_flight_log(flight, config, root / name, "ulog")
        out[name] = replay([log], load_config(config_path)).result.channels["pitch"]
    return out


@pytest.mark.parametrize("name", ["clean1", "clean2", "clean3"])
def test_a_clean_px4_flight_with_10_hz_servos_stays_clean_up_to_the_new_top(px4_flights, name):
    ch = px4_flights[name]
    w = np.asarray(ch.frequency_rad_s)
    confident = np.asarray(ch.confident, bool)
    assert ch.limited_by != "model" and not ch.diagnosis
    assert w[confident].max() > 25.0 and np.all(w[confident] <= TOP)
    # past the top: the sweep's end (not excited) or the Nyquist frequency within the band (above the
    # resolution)
    assert all(
        r in ("above_resolution", "not_excited") for r, above in zip(ch.frequency_reasons, w > TOP) if above
    )
    # 31 rad/s: its band crosses 31.4
    assert ch.frequency_reasons[-1] == "above_resolution"


def test_a_hidden_delay_behind_10_hz_servos_is_named(px4_flights):
    ch = px4_flights["delay"]
    assert ch.limited_by == "model"
    assert ch.diagnosis[0].effect == "time_delay" and ch.diagnosis[0].explains
    assert ch.diagnosis[0].parameters["seconds"] == pytest.approx(0.04, abs=0.005)
    assert all(b.max_rad_s <= TOP for b in ch.bands if b.limited_by == "model")


@pytest.mark.parametrize(
    "rates",
    [
        (50.0, 200.0),
        (49.9, 200.0),
        (100.0, 100.0),
        (50.0, 50.0),
        (100.0, 1000.0),
        (200.0, 200.0),
        (10.0, 20.0),
    ],
)
def test_streams_at_the_usual_rates_resolve_a_quarter_of_the_slowest_and_fold_nothing(rates):
    """On the 100 Hz grid: 50 Hz surfaces (jittered: 49.9 Hz) and everything faster keep a quarter of their
    rate and the checks of before; so do slow surfaces whose gyro is not four times faster (nothing shows
    their folding)."""
    limit, folded = resolved_hz(rates, 1, 1, 100.0)
    assert limit == pytest.approx(RESOLVED_FRACTION * min(rates)) and folded == ()


def test_ten_hz_surfaces_with_a_fast_gyro_are_read_to_their_nyquist_frequency():
    assert resolved_hz([10.0, 250.0], 1, 1, 100.0) == (5.0, ((0, 10.0, (1,)),))
    assert resolved_hz([10.0, 40.0], 1, 1, 100.0)[0] == 5.0                   # the gyro resolves up to 10 Hz
    # 25 Hz RCOU: up to a tenth of the grid's rate (the grid folds its images back above that), no step down
    assert resolved_hz([25.0, 200.0], 1, 1, 100.0)[0] == 10.0
    limits = [resolved_hz([r, 1000.0], 1, 1, 100.0)[0] for r in np.arange(5.0, 80.0, 0.5)]
    assert np.all(np.diff(limits) >= 0.0)


@pytest.mark.parametrize("rate_hz", [10.0, 14.0, 25.0, 45.0, 100.0])
def test_the_logging_warning_states_what_the_estimator_resolves(rate_hz):
    """The logging check's numbers are the estimator's (a fast gyro, the default grid): the limit, the top of
    a sweep (the limit over 1.1), and a stream at the rate it asks for carries the band it was asked for."""
    limit = rate_limit_rad_s(rate_hz)
    assert limit == pytest.approx(2.0 * math.pi * resolved_hz([rate_hz, 1000.0], 1, 1, 100.0)[0])
    asked = 1.2 * limit / 1.1
    warning = rate_warning("ulog", "actuator_servos", rate_hz, asked, "pitch.input")
    _, top_text = warning.split("frequencies above ", 1)
    assert float(top_text.split(" rad/s")[0]) == pytest.approx(limit / 1.1, rel=1e-2)
    assert rate_warning("ulog", "actuator_servos", rate_hz, 0.99 * limit / 1.1, "pitch.input") is None
    need = needed_rate_hz(asked)
    assert rate_limit_rad_s(need) / 1.1 == pytest.approx(asked, rel=1e-9) and need > rate_hz


#: The estimates of the usual-rate flight below by the estimator before slow streams were read to their
#: Nyquist frequency (commit d37343e): index, Re H, Im H, random error.
BEFORE = {
    (50.0, 200.0, 0.001): [(3, -3.8647399655129107, -0.8424287341231889, 0.767848946568612),
                           (12, -4.5576723688902065, -0.1709991968979496, 0.026474722563615563),
                           (24, -5.524058823904766, 3.2446007349992954, 0.02012654933124324),
                           (36, 1.2381285102021111, 2.456599790510305, 0.04132530251409769)],
    (100.0, 100.0, 0.0): [(3, -5.50266195260582, -2.704170082511638, 0.34987091651823216),
                          (12, -4.759347692613758, 0.06370544137796995, 0.017716256811252634),
                          (24, -5.632161561877282, 3.1942298893513414, 0.01812054005499713),
                          (36, 1.729599478263605, 2.642568796014658, 0.040623206942663005)],
}


@pytest.mark.parametrize("key", list(BEFORE))
def test_equal_and_usual_rates_give_the_estimates_of_before(key):
    rate_in, rate_out, jitter = key
    t = np.arange(0.0, 100.0, 1.0 / FINE_HZ)
    u = -0.02 + log_sweep(t - 25.0, 0.2, 12.0, 60.0, 0.05)
    avg = estimate(
        *measure(t, u, simulate(u), rate_in, rate_out, seed=4, noise_out=0.05, jitter_s=jitter)
    ).averaged()
    assert avg.excited.sum() == W_RAD_S.size
    for i, re, im, error in BEFORE[key]:
        assert avg.response[i] == pytest.approx(complex(re, im), rel=1e-9)
        assert avg.random_error[i] == pytest.approx(error, rel=1e-9)
