"""Tests of gap_validation.core.sweeps: excitation energy, hysteresis, minimum length, trigger."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gap_validation.core.errors import ConfigError, DataError
from gap_validation.core.sweeps import SweepDetector, TriggerTracker, detect_sweeps, detrended_std

FS_HZ = 100.0


def log_sweep(t_s, f0_hz, f1_hz, length_s, amplitude, taper_s=1.0):
    """Logarithmic sine sweep on [0, length_s] with cosine tapers, zero outside."""
    t = np.asarray(t_s, dtype=float)
    rate = np.log(f1_hz / f0_hz) / length_s
    phase = 2.0 * np.pi * f0_hz * np.expm1(rate * t) / rate
    taper = np.clip(np.minimum(t, length_s - t) / taper_s, 0.0, 1.0)
    taper = 0.5 - 0.5 * np.cos(np.pi * taper)
    return np.where((t >= 0) & (t <= length_s), amplitude * np.sin(phase) * taper, 0.0)


def doublet(t_s, start_s, half_s, amplitude):
    t = np.asarray(t_s, dtype=float)
    return (amplitude * ((t >= start_s) & (t < start_s + half_s))
            - amplitude * ((t >= start_s + half_s) & (t < start_s + 2 * half_s)))


def pilot_flight(seed=0, noise=3e-4):
    """Input with 3 sweeps and, between them, doublets, a trim step and a slow trim ramp.

    Returns t [s], u [rad] and the true sweep intervals [s].
    """
    t = np.arange(0.0, 330.0, 1.0 / FS_HZ)
    sweeps = [(20.0, 70.0), (128.0, 60.0), (240.0, 80.0)]
    u = np.full(t.size, -0.02)
    for start, length in sweeps:
        u += log_sweep(t - start, 0.1, 10.0, length, 0.05)
    u += doublet(t, 98.0, 1.0, 0.05)                              # 2 s doublet
    u += 0.01 * (t >= 110.0)                                      # trim step
    u += doublet(t, 200.0, 1.5, 0.04)                             # 3 s doublet
    u += np.clip((t - 212.0) / 12.0, 0.0, 1.0) * -0.015           # slow trim ramp over 12 s
    u += np.random.default_rng(seed).normal(0.0, noise, t.size)
    return t, u, sweeps


def test_detrended_std_matches_polyfit():
    rng = np.random.default_rng(1)
    x = np.cumsum(rng.normal(size=600)) + 100.0
    window = 57
    e = detrended_std(x, window)
    assert e.size == x.size - window + 1
    for i in (0, 13, 300, e.size - 1):
        seg = x[i:i + window]
        m = np.arange(window)
        resid = seg - np.polyval(np.polyfit(m, seg, 1), m)
        assert e[i] == pytest.approx(np.sqrt(np.mean(resid ** 2)), rel=1e-7)


@settings(max_examples=30, deadline=None)
@given(st.floats(-1e3, 1e3), st.floats(-10.0, 10.0), st.integers(3, 80))
def test_detrended_std_ignores_lines(offset, slope, window):
    """Property: a trim offset plus any ramp has no excitation energy."""
    t = np.arange(400) / FS_HZ
    e = detrended_std(offset + slope * t, window)
    assert np.all(e <= 1e-9 * (1.0 + abs(offset) + abs(slope)))


def test_finds_the_three_sweeps_not_doublets_steps_or_ramps():
    t, u, truth = pilot_flight()
    found = detect_sweeps(t, u, min_sweep_s=10.0)
    assert len(found) == 3
    for (start, end), (t0, length) in zip(found, truth):
        assert start == pytest.approx(t0, abs=1.5)
        assert end == pytest.approx(t0 + length, abs=2.5)


def test_pilot_inputs_alone_are_no_sweeps():
    t = np.arange(0.0, 120.0, 1.0 / FS_HZ)
    u = (doublet(t, 20.0, 0.5, 0.05) + doublet(t, 40.0, 1.5, 0.08) + 0.02 * (t > 60.0)
         + np.clip((t - 80.0) / 15.0, 0.0, 1.0) * 0.03)
    u += np.random.default_rng(3).normal(0.0, 3e-4, t.size)
    assert detect_sweeps(t, u, min_sweep_s=10.0) == []
    # the same stretches are excited (so the minimum length is what rejects them)
    assert len(detect_sweeps(t, u, min_sweep_s=0.0)) >= 3


def test_noise_free_input_uses_absolute_floor():
    t, u, _ = pilot_flight(noise=0.0)
    assert len(detect_sweeps(t, u)) == 3


def test_short_dip_does_not_split_but_long_pause_does():
    t = np.arange(0.0, 140.0, 1.0 / FS_HZ)
    u = np.random.default_rng(4).normal(0.0, 3e-4, t.size)
    burst = 0.05 * np.sin(2 * np.pi * 2.0 * t)
    u += np.where(((t > 20) & (t < 50)) | ((t > 50.8) & (t < 80)), burst, 0.0)   # 0.8 s dip: one sweep
    u += np.where(((t > 95) & (t < 110)) | ((t > 117) & (t < 132)), burst, 0.0)  # 7 s pause: two
    found = detect_sweeps(t, u)
    assert len(found) == 3
    assert found[0][0] == pytest.approx(20.0, abs=1.5) and found[0][1] == pytest.approx(80.0, abs=2.5)


@settings(max_examples=15, deadline=None)
@given(st.lists(st.integers(1, 4000), min_size=1, max_size=12))
def test_chunking_does_not_change_edges(sizes):
    """Property: feeding the samples in any chunks gives the same sweep edges."""
    _, u, _ = pilot_flight(seed=5)
    ref = SweepDetector(FS_HZ)
    ref.start_run(0)
    expected = ref.process(0, u) + ref.end_run(u.size)
    det = SweepDetector(FS_HZ)
    det.start_run(0)
    edges, pos = [], 0
    for size in sizes * (u.size // sum(sizes) + 1):
        if pos >= u.size:
            break
        edges += det.process(pos, u[pos:pos + size])
        pos += size
    edges += det.end_run(u.size)
    assert edges == expected


def test_state_round_trip_mid_sweep():
    _, u, _ = pilot_flight(seed=6)
    ref = SweepDetector(FS_HZ)
    ref.start_run(0)
    expected = ref.process(0, u) + ref.end_run(u.size)
    det = SweepDetector(FS_HZ)
    det.start_run(0)
    first = det.process(0, u[:5000])                     # t = 50 s: inside the first sweep
    assert det.active
    saved = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in det.state_dict().items()}
    again = SweepDetector(FS_HZ)
    again.load_state(saved)
    assert first + again.process(5000, u[5000:]) + again.end_run(u.size) == expected


def test_lookahead_covers_start_and_end_dating():
    det = SweepDetector(FS_HZ, energy_window_s=2.0, hold_s=2.0)
    assert det.lookahead_samples >= det.hold_n and det.lookahead_samples >= det.window_n // 2


def test_bad_options_name_the_key():
    with pytest.raises(ConfigError, match="off_ratio"):
        SweepDetector(FS_HZ, on_ratio=2.0, off_ratio=3.0)
    with pytest.raises(ConfigError, match="hold_s"):
        SweepDetector(FS_HZ, hold_s=-1.0)


def test_trigger_edges():
    trig = TriggerTracker()
    assert trig.edges(np.array([0, 5, 9]), np.array([False, False, True])) == [(9, True)]
    assert trig.edges(np.array([12, 20, 21]), np.array([True, False, False])) == [(20, False)]
    assert trig.edges(np.array([30]), np.array([True])) == [(30, True)]
    assert trig.seen and trig.state


@pytest.mark.parametrize("t_s, u", [(np.zeros(5), np.zeros(5)), (np.arange(5.0)[::-1], np.zeros(5)),
                                    (np.arange(5.0), np.zeros(3)), ([0.0, np.nan, 2.0], np.zeros(3))])
def test_detect_sweeps_bad_times_are_a_data_error(t_s, u):
    """Regression: constant times raised ZeroDivisionError, decreasing ones blamed an estimator option, and
    mismatched lengths were used silently."""
    with pytest.raises(DataError, match="detect_sweeps"):
        detect_sweeps(t_s, u)
