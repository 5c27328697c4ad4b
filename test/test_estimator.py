"""Tests of gap_validation.core.estimator: recursive spectra, accuracy, timing, memory, checkpoints, bad data.

The known system is the paper's pitch-rate model with a 20 ms delay (``_pitch_flights``); the estimator's time
alignment (time bases, jumps back, stray stamps) is tested in ``test_alignment.py``.
"""
import copy

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import signal

from _pitch_flights import (FINE_HZ, PITCH_DEN, PITCH_NUM, SWEEPS, W_RAD_S, _chunks, _feed, _nbytes, estimate,
                            flight, fraction_within, log_sweep, measure, simulate, true_response)
from gap_validation.core.errors import ConfigError, DataError
from gap_validation.core.estimator import FrequencyResponseEstimator, SpectralEstimate


# ---------------------------------------------------------------------------------------------- equivalence
def direct_spectra(x, y, dt, w_rad_s, window_n, hop_n, start, stop, detrend):
    """Explicit sums of hann * x * exp(-j w t) over every segment in [start, stop) (reference)."""
    out = np.zeros((4, w_rad_s.size), complex)
    for f, w in enumerate(w_rad_s):
        n_win, hop = int(window_n[f]), int(hop_n[f])
        m = np.arange(n_win)
        hann = 0.5 - 0.5 * np.cos(2 * np.pi * m / n_win)
        scale = 2 * dt / np.sum(hann ** 2)
        for s in range(start, stop - n_win + 1, hop):
            xs, ys = x[s:s + n_win], y[s:s + n_win]
            if detrend:
                xs, ys = xs - xs.mean(), ys - ys.mean()
            e = np.exp(-1j * w * (s + m) * dt)
            X, Y = np.sum(hann * xs * e), np.sum(hann * ys * e)
            out[:, f] += (scale * abs(X) ** 2, scale * abs(Y) ** 2, scale * np.conj(X) * Y, 1.0)
    return out


@pytest.mark.parametrize("detrend, overlap", [(True, 0.5), (False, 0.5), (True, 0.0), (True, 0.75)])
def test_recursive_transform_equals_direct_dft(detrend, overlap):
    fs = 100.0
    rng = np.random.default_rng(2)
    k = np.arange(9000)
    t = k / fs
    x = rng.normal(size=k.size) + 0.3 + 0.01 * t
    y = np.convolve(x, [0.4, 0.3, -0.2, 0.1], "same") + 0.2 * rng.normal(size=k.size) - 1.0
    w = np.logspace(np.log10(0.7), np.log10(55.0), 17)
    est = FrequencyResponseEstimator(w, detrend=detrend, overlap=overlap, detect_sweeps=False)
    est.add_trigger([3.0, 81.23], [True, False])                # a sweep over samples 300 .. 8122
    for a in range(0, k.size, 777):
        est.add_input(t[a:a + 777], x[a:a + 777])
        est.add_output(t[a:a + 777], y[a:a + 777])
    est.flush()
    (got,) = est.sweeps
    ref = direct_spectra(x, y, 1 / fs, w, np.rint(est.window_s * fs), np.rint(est.hop_s * fs), 300, 8123,
                         detrend)
    assert np.array_equal(got.n_averages, ref[3].real.astype(int))
    assert np.all(got.n_averages >= 2)
    for ours, theirs in ((got.gxx, ref[0].real), (got.gyy, ref[1].real), (got.gxy, ref[2])):
        assert np.max(np.abs(ours * got.n_averages - theirs) / np.abs(theirs)) < 1e-9
    assert (got.start_s, got.end_s) == pytest.approx((3.0, 81.23))


def test_equals_scipy_welch_csd_on_fft_bins():
    """Independent check: with one window length and frequencies on its FFT bins, scipy.signal.csd agrees."""
    fs, n_win = 100.0, 400
    w = 2 * np.pi * np.arange(5, 31) * fs / n_win
    rng = np.random.default_rng(3)
    t = np.arange(12345) / fs
    x = rng.normal(size=t.size) + 0.3
    y = np.convolve(x, [0.5, 0.3, -0.2], "same") + 0.1 * rng.normal(size=t.size) + 5.0
    est = FrequencyResponseEstimator(w, detect_sweeps=False, min_window_s=4.0, max_window_s=4.0)
    est.add_trigger([0.0], [True])
    est.add_time_histories(t, x, t, y, chunk_s=7.3)
    est.flush()
    got = est.averaged()
    kw = dict(fs=fs, window="hann", nperseg=n_win, noverlap=n_win // 2, detrend="constant")
    bins = np.arange(5, 31)
    assert np.all(got.n_averages == (t.size - n_win) // (n_win // 2) + 1)
    np.testing.assert_allclose(got.gxy, signal.csd(x, y, **kw)[1][bins], rtol=1e-10)
    np.testing.assert_allclose(got.gxx, signal.welch(x, **kw)[1][bins], rtol=1e-10)
    np.testing.assert_allclose(got.gyy, signal.welch(y, **kw)[1][bins], rtol=1e-10)
    _, coh = signal.coherence(x, y, **kw)
    np.testing.assert_allclose(got.coherence, coh[bins], rtol=1e-9)


@settings(max_examples=10, deadline=None)
@given(st.lists(st.floats(0.001, 8.0), min_size=1, max_size=6), st.lists(st.floats(0.001, 8.0), min_size=1,
                                                                         max_size=6))
def test_batching_does_not_change_the_estimate(in_steps_s, out_steps_s):
    """Property: however the two streams are cut into calls, the estimate is the same (1e-9)."""
    ti, ui, to, yo = _short_flight()

    def run(steps_in, steps_out):
        cuts = []
        for s, (times, steps) in enumerate(((ti, steps_in), (to, steps_out))):
            edges = np.cumsum(np.resize(steps, int(times[-1] / min(steps)) + 2))
            idx = np.unique(np.searchsorted(times, edges[edges < times[-1] + 1]))
            cuts += [(times[min(i, times.size - 1)], s, i) for i in idx]
        est = FrequencyResponseEstimator(W_RAD_S)
        pos = [0, 0]
        for _, s, i in sorted(cuts):                      # calls in time order: streams interleaved
            times, vals = ((ti, ui), (to, yo))[s]
            (est.add_input if s == 0 else est.add_output)(times[pos[s]:i], vals[pos[s]:i])
            pos[s] = i
        est.add_input(ti[pos[0]:], ui[pos[0]:])
        est.add_output(to[pos[1]:], yo[pos[1]:])
        est.flush()
        return est

    ref = run([5.0], [5.0])
    got = run(in_steps_s, out_steps_s)
    assert got.n_sweeps == ref.n_sweeps == 1
    for name in ("gxx", "gyy", "gxy"):
        np.testing.assert_allclose(getattr(got.averaged(), name), getattr(ref.averaged(), name), rtol=1e-9)


def _short_flight():
    """One 60 s sweep; surfaces at 50 Hz, IMU at 200 Hz (jittered)."""
    t = np.arange(0.0, 100.0, 1.0 / FINE_HZ)
    u = -0.02 + log_sweep(t - 25.0, 0.2, 12.0, 60.0, 0.05)
    return measure(t, u, simulate(u), 50.0, 200.0, seed=4, noise_out=0.05, jitter_s=0.001)


def test_ros_epoch_timestamps_keep_precision():
    """Stamps near 1.7e9 s (float64 resolution 0.24 us) give the same estimate as stamps near 0."""
    ti, ui, to, yo = _short_flight()
    near_zero = estimate(ti, ui, to, yo).averaged()
    epoch = 1.7e9
    far = estimate(ti + epoch, ui, to + epoch, yo).averaged()
    assert far.start_s - epoch == pytest.approx(near_zero.start_s, abs=0.01)
    np.testing.assert_allclose(far.response, near_zero.response, rtol=1e-4)


# ---------------------------------------------------------------------------------------------- accuracy
def test_known_system_within_error_bounds(nominal):
    *_, est = nominal
    assert est.n_sweeps == 3
    h_true = true_response(W_RAD_S)
    avg = est.averaged()
    assert avg.n_sweeps == 3
    assert fraction_within(avg.response, h_true, avg.random_error) >= 0.9
    for raw in est.sweeps:
        assert fraction_within(raw.response, h_true, raw.random_error) >= 0.85
        # coherence means something for a single sweep: several averages, not trivially 1
        assert np.all(raw.n_averages >= 4)
        assert np.min(raw.coherence) < 0.9
    # averaging three sweeps lowers the random error about sqrt(3) times (Fig. 4: the dark curve is smooth)
    ratio = avg.random_error / np.mean([s.random_error for s in est.sweeps], axis=0)
    assert np.median(ratio) < 0.7 and np.all(ratio < 1.0)
    # the stated error is not vacuous: it is a few per cent where coherence is high
    assert np.median(avg.random_error) < 0.05


def test_sweeps_counted_and_dated_between_doublets_and_trim(nominal):
    *_, est = nominal
    spans = [(s.start_s, s.end_s) for s in est.sweeps]
    for (start, end), (t0, length) in zip(spans, SWEEPS):
        assert start == pytest.approx(t0, abs=1.5)
        assert end == pytest.approx(t0 + length, abs=2.5)
    avg = est.averaged()
    assert (avg.start_s, avg.end_s) == (spans[0][0], spans[-1][1])


def test_coherence_falls_where_a_gust_dominates():
    t, u, y = flight(gust_std=0.1)
    est = estimate(*measure(t, u, y, 100.0, 1000.0, seed=7))
    avg = est.averaged()
    band = (W_RAD_S > 20.0) & (W_RAD_S < 30.0)
    calm = (W_RAD_S > 3.0) & (W_RAD_S < 10.0)
    assert np.max(avg.coherence[band]) < 0.5 < 0.9 < np.min(avg.coherence[calm])
    assert np.all(avg.random_error[band] > 2 * np.max(avg.random_error[calm]))
    # the widened bounds still hold there
    h_true = true_response(W_RAD_S)
    assert fraction_within(avg.response[band], h_true[band], avg.random_error[band]) >= 0.75


def test_more_noise_lowers_coherence_and_widens_bounds(nominal):
    t, u, y, _, quiet = nominal
    noisy = estimate(*measure(t, u, y, 100.0, 1000.0, seed=1, noise_out=0.4))
    assert np.all(noisy.averaged().coherence <= quiet.averaged().coherence + 1e-3)
    assert np.median(noisy.averaged().random_error) > 2 * np.median(quiet.averaged().random_error)
    assert fraction_within(noisy.averaged().response, true_response(W_RAD_S),
                           noisy.averaged().random_error) >= 0.9


def test_trigger_overrides_detection(nominal):
    t, u, y, streams, _ = nominal
    est = FrequencyResponseEstimator(W_RAD_S)
    est.add_trigger([0.0, 15.0, 95.0, 235.0, 325.0], [False, True, False, True, False])
    est.add_time_histories(*streams)
    est.flush()
    assert est.n_sweeps == 2                        # the sweep at 128 s is not triggered: not a sweep
    assert [(s.start_s, s.end_s) for s in est.sweeps] == [pytest.approx((15.0, 95.0)),
                                                          pytest.approx((235.0, 325.0))]
    # a trigger around a doublet makes it a sweep (the user said so), without detection's minimum length
    est = FrequencyResponseEstimator(W_RAD_S)
    est.add_trigger([96.0, 103.0], [True, False])
    est.add_time_histories(*streams)
    est.flush()
    assert est.n_sweeps == 1 and est.sweeps[0].end_s - est.sweeps[0].start_s == pytest.approx(7.0)


def test_trigger_only_mode_without_trigger_finds_nothing(nominal):
    *_, streams, _ = nominal
    est = estimate(*streams, detect_sweeps=False)
    assert est.n_sweeps == 0 and est.averaged() is None and est.sweeps == []


def test_cubic_interpolation_of_a_50hz_surface_keeps_magnitude_within_1_percent():
    """Identity system: surface at 50 Hz, the same signal at 1 kHz: |H| = 1 up to 5 Hz within 1 %."""
    t = np.arange(0.0, 100.0, 1.0 / FINE_HZ)
    x = log_sweep(t - 5.0, 0.3, 8.0, 90.0, 0.05)
    w = np.logspace(np.log10(3.0), np.log10(2 * np.pi * 5.0), 12)
    err = {}
    for cubic in (True, False):
        est = FrequencyResponseEstimator(w, cubic_interpolation=cubic)
        est.add_trigger([0.0], [True])
        est.add_time_histories(t[::20], x[::20], t, x)
        est.flush()
        err[cubic] = np.max(np.abs(np.abs(est.averaged().response) - 1.0))
    assert err[True] < 0.01
    assert err[False] > 0.01


# ---------------------------------------------------------------------------------------------- timing
def test_irregular_rates_jitter_and_drops_give_the_same_response(nominal):
    t, u, y, _, fast = nominal
    slow = estimate(*measure(t, u, y, 50.0, 50.0, seed=9, jitter_s=0.003, drop=0.01))
    assert slow.n_sweeps == fast.n_sweeps == 3
    a, b = fast.averaged(), slow.averaged()
    sigma = np.hypot(a.random_error, b.random_error)
    assert fraction_within(b.response, a.response, sigma) >= 0.9
    assert fraction_within(b.response, true_response(W_RAD_S), b.random_error) >= 0.9
    counts = slow.bad_sample_counts
    assert counts["input"]["nonfinite"] == counts["input"]["non_monotonic"] == 0


def test_gap_breaks_the_sweep(nominal):
    *_, (ti, ui, to, yo), _ = nominal
    keep = (to < 155.0) | (to > 157.0)                   # IMU silent for 2 s inside the second sweep
    est = estimate(ti, ui, to[keep], yo[keep])
    spans = [(s.start_s, s.end_s) for s in est.sweeps]
    assert est.n_sweeps == 4
    assert spans[1][1] == pytest.approx(155.0, abs=0.02)     # ends at the last sample before the gap
    assert 157.0 <= spans[2][0] <= 160.0


def test_one_stream_far_ahead_is_bounded_and_counted(nominal):
    *_, (ti, ui, to, yo), _ = nominal
    est = FrequencyResponseEstimator(W_RAD_S)
    size = sum(np.asarray(v).nbytes for v in est.state_dict().values())
    est.add_input(ti, ui)                                 # the whole flight of one stream first
    est.add_output(to, yo)
    est.flush()
    assert est.bad_sample_counts["input"]["dropped_lag"] > 0
    assert sum(np.asarray(v).nbytes for v in est.state_dict().values()) == size


# ---------------------------------------------------------------------------------------------- memory
def _long_flight(minutes):
    """Grid-rate streams: a 60 s sweep every 90 s."""
    fs = 100.0
    t = np.arange(0.0, 60.0 * minutes, 1.0 / fs)
    u = -0.02 + log_sweep(np.mod(t, 90.0) - 20.0, 0.2, 12.0, 60.0, 0.05)
    u += np.random.default_rng(11).normal(0.0, 3e-4, t.size)
    bd, ad, _ = signal.cont2discrete((PITCH_NUM, PITCH_DEN), 1.0 / fs, method="foh")
    y = signal.lfilter(np.ravel(bd), ad, u) + np.random.default_rng(12).normal(0.0, 0.05, t.size)
    return t, u, y


def test_state_size_is_independent_of_flight_length():
    t, u, y = _long_flight(100)
    est = FrequencyResponseEstimator(W_RAD_S, max_raw_sweeps=50)
    sizes = {0: _nbytes(est.state_dict())}
    step = 60000                                          # 10 min per batch
    for a in range(0, t.size, step):
        est.add_time_histories(t[a:a + step], u[a:a + step], t[a:a + step], y[a:a + step], chunk_s=60.0)
        sizes[(a + step) // 6000] = _nbytes(est.state_dict())
    est.flush()
    assert sizes[10] == sizes[100] == sizes[0]
    assert est.n_sweeps == 67                             # 66 whole sweeps + the one cut at 100 min by flush
    assert len(est.sweeps) == 50 and est.averaged().n_sweeps == 67
    assert est.sweeps[-1].end_s == pytest.approx(6000.0)  # the kept raw estimates are the most recent
    assert est.sweeps[0].start_s == pytest.approx(17 * 90.0 + 20.0, abs=1.0)
    assert np.all(est.averaged().n_averages >= 66 * 2)


# ---------------------------------------------------------------------------------------------- checkpoint
@pytest.mark.parametrize("split", [7, 21, 40])            # 49 s (mid sweep), 147 s, 280 s
def test_restored_estimator_continues_identically(nominal, split):
    *_, streams, _ = nominal
    chunks = _chunks(streams)
    whole = FrequencyResponseEstimator(W_RAD_S)
    _feed(whole, chunks)
    whole.flush()
    first = FrequencyResponseEstimator(W_RAD_S)
    _feed(first, chunks[:split])
    state = first.state_dict()
    for key, value in state.items():
        assert isinstance(value, (np.ndarray, int, float)), key
    resumed = FrequencyResponseEstimator.from_state(copy.deepcopy(state))
    _feed(resumed, chunks[split:])
    resumed.flush()
    assert resumed.n_sweeps == whole.n_sweeps == 3
    for a, b in zip(resumed.sweeps + [resumed.averaged()], whole.sweeps + [whole.averaged()]):
        for name in ("gxx", "gyy", "gxy", "n_averages", "response", "coherence", "random_error"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert (a.start_s, a.end_s) == (b.start_s, b.end_s)


def test_state_with_missing_key_is_a_data_error():
    state = FrequencyResponseEstimator(W_RAD_S).state_dict()
    del state["xf.ring"]
    with pytest.raises(DataError, match="xf.ring"):
        FrequencyResponseEstimator.from_state(state)


# ---------------------------------------------------------------------------------------------- bad input
def test_nan_inf_and_non_monotonic_samples_are_dropped_and_counted(nominal):
    *_, (ti, ui, to, yo), clean = nominal
    ui_bad, to_bad, yo_bad = ui.copy(), to.copy(), yo.copy()
    ui_bad[[100, 5000, 20000]] = [np.nan, np.inf, -np.inf]
    to_bad[[7, 70000]] = np.nan
    yo_bad[123456] = np.nan
    # out-of-order and repeated timestamps inserted into the output stream
    at = [1000, 50000, 200000]
    to_bad = np.insert(to_bad, at, [to[999] - 0.5, to[49999], to[199999] - 1e-4])
    yo_bad = np.insert(yo_bad, at, [99.0, 99.0, 99.0])
    est = estimate(ti, ui_bad, to_bad, yo_bad)
    counts = est.bad_sample_counts
    assert counts["input"]["nonfinite"] == 3 and counts["input"]["non_monotonic"] == 0
    assert counts["output"]["nonfinite"] == 3 and counts["output"]["non_monotonic"] == 3
    assert est.n_sweeps == 3
    a, b = est.averaged(), clean.averaged()
    assert np.max(np.abs(a.response - b.response) / np.abs(b.response)) < 0.01


def test_odd_calls_never_crash():
    est = FrequencyResponseEstimator(W_RAD_S)
    est.add_input([], [])
    est.add_output(np.array([np.nan]), np.array([1.0]))
    est.add_input(5.0, 0.1)                                   # scalars
    est.add_input([4.0, 3.0], [0.1, 0.2])                     # backwards
    est.add_trigger([np.inf, 1.0], [True, True])
    est.flush()
    est.flush()
    assert est.averaged() is None
    assert est.bad_sample_counts["input"]["non_monotonic"] == 2
    assert est.bad_sample_counts["trigger"]["nonfinite"] == 1
    with pytest.raises(DataError, match="output"):
        est.add_output([1.0, 2.0], [1.0])



def test_whole_arrays_with_a_stray_timestamp_are_fed_in_few_chunks(monkeypatch):
    """Regression: add_time_histories made one chunk per chunk_s over the whole time span, so one zero stamp
    among epoch times (span 1.7e9 s) meant 1.7e8 chunks: gigabytes and minutes. Chunks now follow the samples."""
    t = 1.0e6 + np.arange(0.0, 1.0, 0.01)
    t_in = t.copy()
    t_in[0] = 0.0                                             # unset header stamp
    est = FrequencyResponseEstimator(W_RAD_S)
    calls = []
    original = est.add_input
    monkeypatch.setattr(est, "add_input", lambda ts, u: (calls.append(len(ts)), original(ts, u)))
    est.add_time_histories(t_in, np.zeros(t.size), t, np.zeros(t.size))
    assert sum(calls) == t.size and len(calls) <= 4
    for chunk_s in (0.0, -1.0, float("nan")):
        with pytest.raises(ConfigError, match="chunk_s"):
            est.add_time_histories(t, np.zeros(t.size), t, np.zeros(t.size), chunk_s=chunk_s)


# ---------------------------------------------------------------------------------------------- options
def test_unknown_option_is_a_config_error_naming_it():
    with pytest.raises(ConfigError, match="window_cylces"):
        FrequencyResponseEstimator(W_RAD_S, window_cylces=5)


@pytest.mark.parametrize("key, value", [("sample_rate_hz", 15.0), ("overlap", 0.6), ("max_raw_sweeps", 0),
                                        ("min_window_s", -1.0), ("detrend", "yes"), ("on_ratio", 1.0)])
def test_bad_option_values_name_the_key(key, value):
    with pytest.raises(ConfigError, match=key if key != "on_ratio" else "off_ratio"):
        FrequencyResponseEstimator(W_RAD_S, **{key: value})


def test_options_listed_for_the_config():
    assert "sample_rate_hz" in FrequencyResponseEstimator.OPTIONS
    assert "max_raw_sweeps" in FrequencyResponseEstimator.OPTIONS


# ---------------------------------------------------------------------------------------------- formulas
def test_random_error_is_bendat_piersol():
    n = np.array([10, 10, 1, 0])
    est = SpectralEstimate.from_sums([1.0, 2.0, 3.0, 4.0], sum_xx=n * 1.0, sum_yy=n * 1.25,
                                     sum_xy=n * (0.6 + 0.8j), n=n)
    # coherence |Gxy|^2 / (Gxx Gyy) = 1 / 1.25 = 0.8; error sqrt(1 - 0.8) / (sqrt(0.8) sqrt(2 * 10))
    assert est.coherence[0] == pytest.approx(0.8)
    assert est.random_error[0] == pytest.approx(0.1118034, rel=1e-6)
    assert est.response[0] == pytest.approx(0.6 + 0.8j)
    assert est.coherence[2] == 0.0 and est.random_error[2] == np.inf      # one average: not meaningful
    assert np.isnan(est.response[3]) and est.random_error[3] == np.inf


def test_windows_have_the_documented_length():
    est = FrequencyResponseEstimator(W_RAD_S)
    cycles = est.window_s * W_RAD_S / (2 * np.pi)
    assert np.all(est.window_s >= 2.0 - 1e-9) and np.all(est.window_s <= 20.0 + 1e-9)
    assert np.all((cycles >= 7.0) | (est.window_s >= 19.9) | (est.window_s <= 2.1))
    np.testing.assert_allclose(est.hop_s, est.window_s / 2)
