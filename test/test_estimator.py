"""Tests of gap_validation.core.estimator: manoeuvres to frequency responses, accuracy, timing, memory,
checkpoints, bad data.

The known system is the paper's pitch-rate model with a 20 ms delay (``_pitch_flights``); the local polynomial
estimate itself is tested in ``test_spectra.py``, the splitting into manoeuvres in ``test_records.py``, the
time alignment (time bases, jumps back, stray stamps) in ``test_alignment.py``.
"""
import copy
from pathlib import Path

import numpy as np
import pytest
import yaml
from _pitch_flights import (
    FINE_HZ,
    PITCH_DEN,
    PITCH_NUM,
    SWEEPS,
    W_RAD_S,
    _chunks,
    _feed,
    _nbytes,
    estimate,
    flight,
    fraction_within,
    log_sweep,
    measure,
    simulate,
    true_response,
)
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from gap_validation.core.config import parse_config
from gap_validation.core.errors import ConfigError, DataError
from gap_validation.core.estimator import RETIRED_OPTIONS, FrequencyResponseEstimator, SpectralEstimate
from gap_validation.core.simulation import FlightOptions, multisine, multistep, simulate_flight
from gap_validation.core.spectra import interpolation_gain
from gap_validation.core.validator import OnlineValidator

ROOT = Path(__file__).resolve().parents[1]


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
    # the trim between the manoeuvres too (its floors, the feedback tests): the samples after a record's end
    # that came in blocks before the one that closed it are trim whatever the blocks were (node and replay
    # batch differently)
    assert got._trim.samples == ref._trim.samples and got._trim.lead.rows == ref._trim.lead.rows
    np.testing.assert_allclose(got._trim.sums, ref._trim.sums, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(got._trim.lead.gram, ref._trim.lead.gram, rtol=1e-9, atol=1e-15)


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
    assert avg.n_sweeps == est.n_manoeuvres == 5             # three sweeps and two doublets pooled
    assert fraction_within(avg.response, h_true, avg.random_error, dof=avg.n_averages) >= 0.9
    for raw in est.sweeps:
        assert fraction_within(raw.response, h_true, raw.random_error, dof=raw.n_averages) >= 0.85
        # coherence and error mean something for a single sweep: degrees of freedom, coherence not trivially 1
        assert np.all(raw.n_averages >= 3)
        assert np.min(raw.coherence) < 0.95
    # pooling three sweeps lowers the random error about sqrt(3) times (Fig. 4: the dark curve is smooth)
    ratio = avg.random_error / np.mean([s.random_error for s in est.sweeps], axis=0)
    assert np.median(ratio) < 0.7 and np.all(ratio < 1.05)
    # the stated error is not vacuous: it is a few per cent where coherence is high
    assert np.median(avg.random_error) < 0.05


def test_sweeps_counted_and_dated_between_doublets_and_trim(nominal):
    *_, est = nominal
    spans = [(s.start_s, s.end_s) for s in est.sweeps]
    assert [s.kind for s in est.sweeps] == ["chirp"] * 3
    for (start, end), (t0, length) in zip(spans, SWEEPS):      # dated by the sweep itself (tapered ends)
        assert t0 - 0.5 <= start <= t0 + 1.0
        assert t0 + length - 1.0 <= end <= t0 + length + 0.5
    # the doublets count for the pooled estimate (not sweeps); the trim step and the trim ramp count for
    # nothing
    assert est.counted_kinds == {"chirp": 3, "doublet": 2}
    assert est.n_sweeps == 3 and est.n_manoeuvres == 5 and est.excitation == "chirp"
    avg = est.averaged()
    assert avg.start_s == spans[0][0] and avg.end_s >= spans[-1][1]


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
    assert fraction_within(avg.response[band], h_true[band], avg.random_error[band],
                           dof=avg.n_averages[band]) >= 0.75


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
    # each manoeuvre is dated by the triggered span (its record keeps 2 s of trim before, 4 s after)
    assert [(s.start_s, s.end_s) for s in est.sweeps] == [pytest.approx((15.0, 95.0)),
                                                          pytest.approx((235.0, 325.0))]
    # a trigger around a doublet makes it a manoeuvre (the user said so): its response counts
    est = FrequencyResponseEstimator(W_RAD_S)
    est.add_trigger([96.0, 103.0], [True, False])
    est.add_time_histories(*streams)
    est.flush()
    assert est.n_manoeuvres == 1 and est.averaged() is not None


def test_trigger_only_mode_without_trigger_finds_nothing(nominal):
    *_, streams, _ = nominal
    est = estimate(*streams, detect_sweeps=False)
    assert est.n_sweeps == 0 and est.averaged() is None and est.sweeps == []


def test_a_50hz_surface_keeps_its_magnitude_within_1_percent():
    """Identity system: surface at 50 Hz, the same signal at 1 kHz: |H| = 1 up to 8 Hz within 1 %. The
    interpolation onto the grid loses magnitude (linear: 8 % at 8 Hz, cubic 1.2 %); the estimator restores it
    from each stream's rate (spectra.interpolation_gain, the mean over the grid's phases: exact enough for
    cubic interpolation, 2 % off for linear on a grid that meets every other sample)."""
    t = np.arange(0.0, 100.0, 1.0 / FINE_HZ)
    x = log_sweep(t - 5.0, 0.3, 10.0, 90.0, 0.05)
    w = np.logspace(np.log10(3.0), np.log10(2 * np.pi * 8.0), 12)
    for cubic in (True, False):
        est = FrequencyResponseEstimator(w, cubic_interpolation=cubic)
        est.add_trigger([0.0], [True])
        est.add_time_histories(t[::20], x[::20], t, x)
        est.flush()
        assert np.max(np.abs(np.abs(est.averaged().response) - 1.0)) < (0.01 if cubic else 0.03)
        assert 1.0 - interpolation_gain(w[-1:], 50.0, cubic)[0] > (0.01 if cubic else 0.07)


# ---------------------------------------------------------------------------------------------- timing
def test_irregular_rates_jitter_and_drops_give_the_same_response(nominal):
    t, u, y, _, fast = nominal
    slow = estimate(*measure(t, u, y, 50.0, 50.0, seed=9, jitter_s=0.003, drop=0.01))
    assert slow.n_sweeps == fast.n_sweeps == 3
    a, b = fast.averaged(), slow.averaged()
    sigma = np.hypot(a.random_error, b.random_error)
    assert fraction_within(b.response, a.response, sigma) >= 0.9
    assert fraction_within(b.response, true_response(W_RAD_S), b.random_error, dof=b.n_averages) >= 0.9
    counts = slow.bad_sample_counts
    assert counts["input"]["nonfinite"] == counts["input"]["non_monotonic"] == 0


def test_gap_breaks_the_sweep(nominal):
    *_, (ti, ui, to, yo), _ = nominal
    keep = (to < 155.0) | (to > 157.0)                   # IMU silent for 2 s inside the second sweep
    est = estimate(ti, ui, to[keep], yo[keep])
    spans = [(s.start_s, s.end_s) for s in est.sweeps]
    assert est.n_sweeps == 4
    assert spans[1][1] == pytest.approx(155.0, abs=0.02)     # ends at the last sample before the gap
    assert 157.0 <= spans[2][0] <= 158.0                    # the rest starts with the first sample after it


def test_one_stream_far_ahead_is_bounded_and_counted(nominal):
    *_, (ti, ui, to, yo), _ = nominal
    est = FrequencyResponseEstimator(W_RAD_S)
    size = _nbytes(est.state_dict())
    est.add_input(ti, ui)                                 # the whole flight of one stream first
    est.add_output(to, yo)
    est.flush()
    assert est.bad_sample_counts["input"]["dropped_lag"] > 0
    assert _nbytes(est.state_dict()) == size              # fixed-size state; the record buffer is empty


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
    empty = _nbytes(est.state_dict())
    # the only part that varies is the record in progress: at most max_record_s of every stream
    bound = empty + 2 * int(est.options["max_record_s"] * est.options["sample_rate_hz"]) * 8
    sizes = {}
    step = 60000                                          # 10 min per batch
    for a in range(0, t.size, step):
        est.add_time_histories(t[a:a + step], u[a:a + step], t[a:a + step], y[a:a + step], chunk_s=60.0)
        sizes[(a + step) // 6000] = _nbytes(est.state_dict())
    est.flush()
    assert max(sizes.values()) <= bound and _nbytes(est.state_dict()) == empty
    assert est.n_sweeps == 67                             # 66 whole sweeps + the one cut at 100 min by flush
    assert len(est.sweeps) == 50 and est.averaged().n_sweeps == 67
    assert est.sweeps[-1].end_s == pytest.approx(6000.0)  # the kept raw estimates are the most recent
    assert est.sweeps[0].start_s == pytest.approx(17 * 90.0 + 20.0, abs=1.5)
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
        assert isinstance(value, (np.ndarray, int, float, np.integer, np.floating)), key
    resumed = FrequencyResponseEstimator.from_state(copy.deepcopy(state))
    _feed(resumed, chunks[split:])
    resumed.flush()
    assert resumed.n_sweeps == whole.n_sweeps == 3
    for a, b in zip(resumed.sweeps + [resumed.averaged()], whole.sweeps + [whole.averaged()]):
        for name in ("gxx", "gyy", "gxy", "n_averages", "response", "coherence", "random_error"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert (a.start_s, a.end_s) == (b.start_s, b.end_s)
        assert np.array_equal(a.amplitude, b.amplitude, equal_nan=True)       # each record's input amplitude
    assert all(s.amplitude > 0 for s in resumed.sweeps)


def test_state_with_missing_key_is_a_data_error():
    state = FrequencyResponseEstimator(W_RAD_S).state_dict()
    del state["rec.buf"]
    with pytest.raises(DataError, match="missing key 'buf'"):
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
    assert np.all(np.abs(a.response - b.response) / np.abs(b.response) < np.maximum(0.01, 2 * b.random_error))


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
    among epoch times (span 1.7e9 s) meant 1.7e8 chunks: gigabytes and minutes. Chunks now follow the
    samples."""
    t = 1.0e6 + np.arange(0.0, 1.0, 0.01)
    t_in = t.copy()
    t_in[0] = 0.0                                             # unset header stamp
    est = FrequencyResponseEstimator(W_RAD_S)
    calls = []
    original = est.add_samples
    monkeypatch.setattr(est, "add_samples", lambda name, ts, u: (name == "input" and calls.append(len(ts)),
                                                                 original(name, ts, u)))
    est.add_time_histories(t_in, np.zeros(t.size), t, np.zeros(t.size))
    assert sum(calls) == t.size and len(calls) <= 4
    for chunk_s in (0.0, -1.0, float("nan")):
        with pytest.raises(ConfigError, match="chunk_s"):
            est.add_time_histories(t, np.zeros(t.size), t, np.zeros(t.size), chunk_s=chunk_s)


# ---------------------------------------------------------------------------------------------- options
def test_unknown_option_is_a_config_error_naming_it():
    with pytest.raises(ConfigError, match="window_cylces"):
        FrequencyResponseEstimator(W_RAD_S, window_cylces=5)


@pytest.mark.parametrize(
    "key, value",
    [
        ("sample_rate_hz", 15.0),
        ("max_raw_sweeps", 0),
        ("band_fraction", -1.0),
        ("min_bins", 3),
        ("order", 7),
        ("cubic_interpolation", "yes"),
        ("max_record_s", 5.0),
        ("on_ratio", 1.0),
    ],
)
def test_bad_option_values_name_the_key(key, value):
    with pytest.raises(ConfigError, match=key if key != "on_ratio" else "off_ratio"):
        FrequencyResponseEstimator(W_RAD_S, **{key: value})


@pytest.mark.parametrize("key", RETIRED_OPTIONS)
def test_options_of_the_windowed_estimator_are_refused_with_the_reason(key):
    with pytest.raises(ConfigError, match=f"{key}.*no longer used.*whole manoeuvres"):
        FrequencyResponseEstimator(W_RAD_S, **{key: 1.0})


def test_options_listed_for_the_config():
    assert "sample_rate_hz" in FrequencyResponseEstimator.OPTIONS
    assert "max_raw_sweeps" in FrequencyResponseEstimator.OPTIONS


# ---------------------------------------------------------------------------------------------- formulas
def test_random_error_is_half_the_complex_variance_per_component():
    # each component of the complex error has variance var / 2: the relative error of |H| is sqrt(var / 2) /
    # |H|
    rows = np.array([[0.6, 0.6], [0.8, 0.8], [0.02, np.inf], [12, 0], [0.9, 0.0], [1.0, 1.0], [1.0, 1.0]])
    est = SpectralEstimate.from_rows([1.0, 2.0], rows, 0.0, 10.0, "chirp", 0.1, 3)
    assert est.response[0] == pytest.approx(0.6 + 0.8j)
    assert est.random_error[0] == pytest.approx(0.1)
    assert est.random_error[1] == np.inf
    assert np.array_equal(SpectralEstimate.from_rows([1.0, 2.0], est.rows(), 0, 10, "chirp", 0.1, 3).rows(),
                          est.rows())


def test_an_older_checkpoint_of_windowed_spectra_is_refused_with_the_reason():
    state = FrequencyResponseEstimator(W_RAD_S).state_dict()
    state["version"] = 2
    with pytest.raises(DataError, match="version 2 holds windowed spectra.*cannot be resumed"):
        FrequencyResponseEstimator.from_state(state)


# ---------------------------------------------------------------------------------------------- manoeuvres
def _grid_flight(u, noise_out=0.02, seed=5):
    """Grid-rate (100 Hz) input ``u`` and the pitch rate it makes, both with noise."""
    t = np.arange(u.size) / 100.0
    fine = np.arange(0.0, t[-1], 1.0 / FINE_HZ)
    y = np.interp(t, fine, simulate(np.interp(fine, t, u)))
    rng = np.random.default_rng(seed)
    return t, u + 3e-4 * rng.standard_normal(u.size), t, y + noise_out * rng.standard_normal(u.size)


def test_three_chirps_three_seconds_apart_are_three_sweeps():
    t = np.arange(0.0, 215.0, 0.01)
    u = sum(log_sweep(t - start, 0.1, 9.0, 60.0, 0.05) for start in (5.0, 68.0, 131.0 + 0.0))
    est = estimate(*_grid_flight(u))
    assert est.n_sweeps == 3 and [s.kind for s in est.sweeps] == ["chirp"] * 3
    starts = [s.start_s for s in est.sweeps]
    assert starts[1] > est.sweeps[0].end_s - 1e-9 and starts[2] > est.sweeps[1].end_s - 1e-9


def test_above_the_end_of_a_sweep_nothing_is_estimated():
    # a chirp to 50 rad/s, the grid to 60 rad/s: the points above the excitation are not estimated (no
    # smeared estimate of the last excited frequency, with a high coherence, as short windows gave)
    t = np.arange(0.0, 100.0, 0.01)
    u = log_sweep(t - 5.0, 1.0 / (2 * np.pi), 50.0 / (2 * np.pi), 90.0, 0.05)
    est = estimate(*_grid_flight(u))
    avg = est.averaged()
    assert not np.any(avg.excited[W_RAD_S > 52.0])
    assert np.all(avg.excited[(W_RAD_S > 2.0) & (W_RAD_S < 45.0)])
    assert avg.reasons["not_excited"][W_RAD_S > 55.0].sum() >= 1


@pytest.mark.parametrize(
    "name, u",
    [
        ("multisine", lambda t: 0.04 * multisine(t - 5.0, 20.0, 4, 1.0, 55.0)),
        (
            "multistep",
            lambda t: sum(0.05 * multistep(t - s, 0.4, (3, 2, 1, 1), 0.04) for s in (5.0, 20.0, 35.0, 50.0)),
        ),
        (
            "doublet",
            lambda t: sum(0.05 * multistep(t - s, 0.3, (1, 1), 0.04) for s in np.arange(5.0, 65.0, 6.0)),
        ),
    ],
)
def test_any_manoeuvre_gives_a_response_within_its_error_bounds(name, u):
    t = np.arange(0.0, 100.0, 0.01)
    est = estimate(*_grid_flight(u(t)))
    avg = est.averaged()
    assert est.excitation == name
    ok = avg.excited & np.isfinite(avg.random_error)
    assert ok.sum() >= 8
    # the error bounds hold for what the estimator measures (the system seen through its local polynomial),
    # and that is within a few per cent of the system itself
    through, _ = avg.expected(true_response)
    assert fraction_within(avg.response[ok], through[ok], avg.random_error[ok], dof=avg.n_averages[ok]) >= 0.9
    assert np.median(np.abs(through[ok] / true_response(W_RAD_S[ok]) - 1.0)) < 0.02


def _slow_sweeps(f1_hz):
    """Three log sweeps 0.1 Hz to ``f1_hz`` (the pitch flight's timing), noise-free at 1 kHz."""
    t = np.arange(0.0, 330.0, 1.0 / FINE_HZ)
    u = np.full(t.size, -0.02) + sum(
        log_sweep(t - start, 0.1, f1_hz, length, 0.05) for start, length in SWEEPS
    )
    return t, u, simulate(u)


def test_a_slow_stream_limits_the_band():
    """Surfaces at 10 Hz, the rate at 200 Hz: the surfaces are read up to their Nyquist frequency (31.4 rad/s;
    the rate shows what their sampling folds back), every band below it (test_slow_streams.py has the
    accuracy)."""
    t, u, y = _slow_sweeps(4.6)                                       # up to 0.46 of the surfaces' rate
    ti, ui, to, yo = measure(t, u, y, 10.0, 200.0, seed=2, noise_out=0.02)   # surfaces at 10 Hz
    est = estimate(ti, ui, to, yo)
    assert est.resolved_rad_s == pytest.approx(2 * np.pi * 5.0, rel=0.01)
    avg = est.averaged()
    assert not np.any(avg.excited[W_RAD_S > 10 * np.pi / 1.1])        # a band of +-10 % below 31.4 rad/s
    assert np.all(avg.excited[(W_RAD_S > 2.0) & (W_RAD_S < 25.0)])
    # the same flight with the rate at 20 Hz: nothing shows what the surfaces fold back: a quarter of their
    # rate
    slow = estimate(*measure(t, u, y, 10.0, 20.0, seed=2))
    assert slow.resolved_rad_s == pytest.approx(2 * np.pi * 2.5, rel=0.01)


def test_a_sweep_past_the_slow_streams_nyquist_frequency_is_not_used_where_it_folds_back():
    """Sweeps to 12 Hz logged at 10 Hz: their power above 5 Hz folds onto 0-5 Hz unseen (aliasing); the rate,
    logged at 200 Hz, shows it past the Nyquist frequency (the sweep goes on there), and the frequencies it
    would corrupt are not estimated."""
    t, u, y = _slow_sweeps(12.0)
    est = estimate(*measure(t, u, y, 10.0, 200.0, seed=2))
    avg = est.averaged()
    assert avg is None or not np.any(avg.excited[W_RAD_S > 2.0])
    assert est.not_estimable["not_excited"] > 0
    clean = estimate(*measure(*_slow_sweeps(3.0), 10.0, 200.0, seed=2)).averaged()
    assert clean is not None and np.all(clean.excited[(W_RAD_S > 2.0) & (W_RAD_S < 14.0)])


def test_a_full_record_buffer_keeps_the_manoeuvre_in_progress():
    # two sweeps 3 s apart, the buffer holds 100 s: the first is estimated when the buffer fills, the second
    # is kept whole (not cut where the buffer happened to fill)
    t = np.arange(0.0, 150.0, 0.01)
    u = log_sweep(t - 5.0, 0.2, 9.0, 60.0, 0.05) + log_sweep(t - 68.0, 0.2, 9.0, 60.0, 0.05)
    est = estimate(*_grid_flight(u), max_record_s=100.0)
    assert [s.kind for s in est.sweeps] == ["chirp", "chirp"]
    assert est.sweeps[1].end_s - est.sweeps[1].start_s >= 58.0     # the 60 s sweep, tapered ends aside



def test_a_record_cut_in_a_slow_sweeps_middle_is_not_split_at_its_peaks():
    """Three 107 s sweeps of the rudder from 0.71 rad/s (a planned card's) with 6 s of trim between merge into
    one record (the detector is still on when the next begins), which the buffer (300 s) cuts in the third
    sweep's middle. That end is no trim: taken as the level "after", it lay near a peak of the sweep, where a
    slow sweep dwells for more than the 1 s that separates manoeuvres every period, and the three sweeps came
    apart into steps, pulses and one-period multisteps (no response at all)."""
    data = yaml.safe_load((ROOT / "config" / "ultrastick25e.yaml").read_text())
    data["channels"] = {"yaw": data["channels"]["yaw"]}
    data["channels"]["yaw"]["frequencies"] = {"min_rad_s": 1.43, "max_rad_s": 3.57, "count": 10}
    config = parse_config(data, "yaw.yaml")
    opts = FlightOptions(excitation="chirp", sweeps_per_channel=3, sweep_duration_s=107.0,
                         sweep_amplitude_rad=0.06, dwell_cycles=0.0, band_low_factor=0.5,
                         band_high_factor=1.0, doublet_amplitude_rad=0.0, doublet_half_period_s=0.005,
                         quiet_s=2.995, trim_s=5.0)
    flight = simulate_flight(config, None, opts, seed=3)
    assert flight.duration_s > 300.0
    v = OnlineValidator(config)
    v.add_histories("yaw", flight.histories(config.channels["yaw"]))
    v.finish()
    assert v.results(diagnose=False).to_json_dict()["channels"]["yaw"]["manoeuvres_by_kind"] == {"chirp": 3}


# ------------------------------------------------------------------------------------- the flight condition
def _off_condition_flight(speed_ratio, seed=11, trim=-0.02):
    """Three sweeps flown with the airspeed ``speed_ratio(t)`` times the model's: the control power, and so
    the response to the surface's deviation from its trim (``trim`` rad), scales with the dynamic pressure
    ``speed_ratio^2``. The airspeed is logged at 20 Hz with 0.1 m/s of noise about a 30 m/s trim."""
    t = np.arange(0.0, 300.0, 1.0 / FINE_HZ)
    u = np.full(t.size, trim)
    for start, length in ((20.0, 70.0), (110.0, 70.0), (200.0, 70.0)):
        u += log_sweep(t - start, 0.1, 12.0, length, 0.05)
    q = speed_ratio(t) ** 2
    ti, ui, to, yo = measure(t, u, simulate(trim + (u - trim) * q), 50.0, 200.0, seed=seed, noise_out=0.05)
    rng = np.random.default_rng(seed + 1)
    ta = np.arange(0.0, 300.0, 0.05)
    return {
        "input": (ti, ui),
        "output": (to, yo),
        "airspeed": (ta, 30.0 * speed_ratio(ta) + rng.normal(0, 0.1, ta.size)),
    }


@pytest.mark.parametrize("constant, speed_ratio, trim", [
    (True, lambda t: np.full(np.shape(t), 1.2), -0.02),
    (False, lambda t: 1.0 + 0.15 * np.sin(2 * np.pi * t / 47.0), -0.02),
    (False, lambda t: 1.0 + 0.15 * np.sin(2 * np.pi * t / 5.0), -0.1)],
    ids=["20 % fast throughout", "+-15 % slowly", "+-15 % at 1.3 rad/s, 0.1 rad of trim"])
def test_an_airspeed_stream_brings_the_response_to_the_model_condition(constant, speed_ratio, trim):
    """Principle: control power scales with the dynamic pressure, so the surface scaled by (V / V_trim)^2 is
    the input the model at V_trim sees. Flown 20 % fast the plain estimate is 1.44 times the model's response
    (far outside its error); with the airspeed logged the flights agree with the model within their errors.
    Only the deviation from trim is scaled (at trim the surface's moment balances the rest, all scaling
    together): scaling the whole deflection would add 0.1 rad of trim times the gusts' 15 % at 1.3 rad/s as a
    false input."""
    streams = _off_condition_flight(speed_ratio, trim=trim)
    plain = FrequencyResponseEstimator(W_RAD_S)
    plain.add_histories({k: v for k, v in streams.items() if k != "airspeed"})
    plain.flush()
    held = FrequencyResponseEstimator(W_RAD_S, ("input", "output", "airspeed"), trim_airspeed=30.0)
    held.add_histories(streams)
    held.flush()
    h_true = true_response(W_RAD_S)
    avg = held.averaged()
    assert held.n_sweeps == plain.n_sweeps == 3
    assert fraction_within(avg.response, h_true, avg.random_error, dof=avg.n_averages) >= 0.9
    ratio = held.dynamic_pressure_ratio
    assert ratio["clipped"] == 0
    if constant:
        assert ratio["min"] > 1.38 and ratio["max"] < 1.50 and ratio["mean"] == pytest.approx(1.44, abs=0.005)
        gain = np.abs(plain.averaged().response / h_true)
        assert np.median(gain) == pytest.approx(1.44, rel=0.02)
        assert fraction_within(plain.averaged().response, h_true, plain.averaged().random_error,
                               dof=plain.averaged().n_averages) < 0.1
    else:
        assert ratio["min"] < 0.75 and ratio["max"] > 1.3 and ratio["mean"] == pytest.approx(1.01, abs=0.03)


def test_the_airspeed_stream_resumes_from_a_checkpoint():
    streams = _off_condition_flight(lambda t: 1.0 + 0.15 * np.sin(2 * np.pi * t / 47.0))
    whole = FrequencyResponseEstimator(W_RAD_S, ("input", "output", "airspeed"), trim_airspeed=30.0)
    whole.add_histories(streams)
    whole.flush()
    cut = {k: (t[t < 150.0], v[t < 150.0]) for k, (t, v) in streams.items()}
    rest = {k: (t[t >= 150.0], v[t >= 150.0]) for k, (t, v) in streams.items()}
    first = FrequencyResponseEstimator(W_RAD_S, ("input", "output", "airspeed"), trim_airspeed=30.0)
    first.add_histories(cut)
    resumed = FrequencyResponseEstimator.from_state(copy.deepcopy(first.state_dict()))
    assert resumed.trim_airspeed == 30.0
    resumed.add_histories(rest)
    resumed.flush()
    assert resumed.dynamic_pressure_ratio == whole.dynamic_pressure_ratio
    np.testing.assert_allclose(resumed.averaged().gxy, whole.averaged().gxy, rtol=1e-9)


def test_a_bad_trim_airspeed_is_a_config_error():
    with pytest.raises(ConfigError, match="trim_airspeed"):
        FrequencyResponseEstimator(W_RAD_S, ("input", "output", "airspeed"), trim_airspeed=-3.0)
    with pytest.raises(ConfigError, match="the airspeed"):
        FrequencyResponseEstimator(W_RAD_S, ("input", "output"), trim_airspeed=30.0)


def test_manoeuvres_flown_count_a_triggered_sweep_that_gives_nothing_and_not_detected_wander():
    """``flown_kinds``: a manoeuvre the trigger marks is flown whatever it gives (here saturated: pinned at
    its limits, no response); without a trigger only what gave a response counts (a detected stretch that
    gives nothing cannot be told from trim wander)."""
    t, u, y = flight()
    trim = -0.02
    clipped = np.clip(u, trim - 0.02, trim + 0.02)                       # the 0.05 rad sweeps pinned at 0.02
    y = simulate(clipped) + 0.01
    streams = measure(t, clipped, y, 100.0, 1000.0, seed=3, noise_in=0.0)     # pinned: exactly at its limits
    est = FrequencyResponseEstimator(W_RAD_S)
    est.add_trigger([0.0, 15.0, 95.0, 235.0, 325.0], [False, True, False, True, False])
    est.add_time_histories(*streams)
    est.flush()
    assert est.counted_kinds.get("chirp", 0) == 0 and est.saturated == 2
    assert est.flown_kinds == {"chirp": 2}
    state = est.state_dict()                                             # kept across a restart
    assert FrequencyResponseEstimator.from_state(state).flown_kinds == {"chirp": 2}
    # the same flight unclipped and detected: flown is what gave a response
    est = estimate(*measure(t, u, *flight()[2:], 100.0, 1000.0, seed=3))
    assert est.flown_kinds == {k: n for k, n in est.counted_kinds.items()}
