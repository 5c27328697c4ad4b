"""Tests of gap_validation.core.alignment: the estimator's time bases (jumps back, stray stamps, gaps) and the
time-order check the router shares with it (``ordered_run``, ``increasing``, ``jump_back_s``)."""
import copy

import numpy as np
import pytest
from _pitch_flights import W_RAD_S, _feed, _nbytes, estimate
from hypothesis import given, settings
from hypothesis import strategies as st

from gap_validation.core.alignment import JUMP_BACK_S, increasing, jump_back_s, ordered_run
from gap_validation.core.estimator import FrequencyResponseEstimator


# ---------------------------------------------------------------------------------------------- the shared
# check
def test_jump_threshold_is_the_larger_of_one_second_and_max_gap():
    assert jump_back_s(0.5) == JUMP_BACK_S == 1.0
    assert jump_back_s(2.5) == 2.5


def test_ordered_run_stops_at_the_first_jump_and_marks_reorders():
    t = np.array([1.0, 2.0, 1.5, 2.0, 3.0, 0.5, 0.6])
    j, ok, prev = ordered_run(t, -np.inf, back_s=1.0)
    assert j == 5                                         # 0.5 is 2.5 s before the latest (3.0): a jump back
    assert ok.tolist() == [True, True, False, False, True]
    assert prev[5] == 3.0
    j, ok, _ = ordered_run(t[:5], 0.0, back_s=1.0, forward_s=0.8)
    # 1.0 s after 0.0 is beyond forward_s: a jump forward
    assert j == 0 and ok.size == 0


def test_increasing_keeps_the_first_sample_after_each_jump_and_counts_jumps():
    t = np.array([10.0, 11.0, 10.5, 12.0, 2.0, 3.0, 2.5, 4.0])
    keep, jumps = increasing(t, 9.0, back_s=1.0)
    assert jumps == 1
    assert keep.tolist() == [True, True, False, True, True, True, False, True]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.0, 100.0), min_size=1, max_size=40), st.floats(0.5, 5.0))
def test_kept_samples_increase_within_each_segment(times, back_s):
    t = np.array(times)
    keep, jumps = increasing(t, -np.inf, back_s)
    kept = t[keep]
    steps = np.diff(kept)
    # every step back among the kept ones is a new segment
    assert np.count_nonzero(steps <= 0.0) <= jumps
    assert np.all(steps[steps <= 0.0] < -back_s)


# ---------------------------------------------------------------------------------------------- time jumping
# back
def test_time_jumping_back_starts_a_new_segment_and_both_laps_count(lap):
    once = FrequencyResponseEstimator(W_RAD_S)
    _feed(once, lap)
    once.flush()
    looped = FrequencyResponseEstimator(W_RAD_S)
    _feed(looped, lap + lap)                              # a looped bag: the same stamps again
    looped.flush()
    assert once.n_sweeps == 1 and looped.n_sweeps == 2
    counts = looped.bad_sample_counts
    for stream in ("input", "output"):
        assert counts[stream]["time_jumps_back"] == 1
        assert counts[stream]["non_monotonic"] == counts[stream]["dropped_lag"] == 0
    first, second = looped.sweeps
    ref = once.sweeps[0]
    for est in (first, second):                           # the new base keeps the grid phase: same numbers
        assert np.allclose(est.response, ref.response, rtol=1e-9)
        assert np.array_equal(est.n_averages, ref.n_averages)
    assert second.start_s > first.end_s                   # the second lap on a continued time axis


def test_stray_stamp_back_is_dropped_not_a_new_segment(lap):
    est = FrequencyResponseEstimator(W_RAD_S)
    stray = []
    for i, (ti, ui, to, yo) in enumerate(lap):
        if i == 20:                                       # one IMU sample stamped 30 s in the past
            to = np.insert(to, 5, to[4] - 30.0)
            yo = np.insert(yo, 5, 99.0)
            stray.append(True)
        est.add_input(ti, ui)
        est.add_output(to, yo)
    est.flush()
    counts = est.bad_sample_counts["output"]
    assert stray and counts["time_jumps_back"] == 0 and counts["non_monotonic"] == 1
    assert est.n_sweeps == 1


def test_small_step_back_and_duplicates_are_dropped_and_counted(lap):
    est = FrequencyResponseEstimator(W_RAD_S)
    ti, ui, to, yo = lap[10]
    est.add_input(ti, ui)
    est.add_output(to, yo)
    est.add_output(to[-50:] - 0.2, yo[-50:])              # 0.2 s back: a reorder, not a new time base
    est.add_output(to[-1:], yo[-1:])                      # a duplicate stamp
    assert est.bad_sample_counts["output"]["non_monotonic"] == 51
    assert est.bad_sample_counts["output"]["time_jumps_back"] == 0


@pytest.mark.parametrize("split", [50, 56, 57, 60])      # before, at and after the jump (lap: 55 chunks)
def test_checkpoint_across_a_time_jump_continues_identically(lap, split):
    chunks = lap + lap
    whole = FrequencyResponseEstimator(W_RAD_S)
    _feed(whole, chunks)
    whole.flush()
    first = FrequencyResponseEstimator(W_RAD_S)
    _feed(first, chunks[:split])
    empty = FrequencyResponseEstimator(W_RAD_S)
    record = 2 * int(empty.options["max_record_s"] * empty.options["sample_rate_hz"]) * 8
    # bounded: the record in progress
    assert _nbytes(first.state_dict()) <= _nbytes(empty.state_dict()) + record
    resumed = FrequencyResponseEstimator.from_state(copy.deepcopy(first.state_dict()))
    _feed(resumed, chunks[split:])
    resumed.flush()
    assert resumed.n_sweeps == whole.n_sweeps == 2
    for a, b in zip(resumed.sweeps, whole.sweeps):
        assert np.array_equal(a.gxy, b.gxy) and (a.start_s, a.end_s) == (b.start_s, b.end_s)


def test_stray_stamp_forward_is_dropped_and_the_flight_goes_on(lap):
    """One IMU stamp 500 s in the future: dropped (not confirmed), the samples after it still count."""
    est = FrequencyResponseEstimator(W_RAD_S)
    for i, (ti, ui, to, yo) in enumerate(lap):
        if i == 20:
            to = to.copy()
            to[5] += 500.0
        est.add_input(ti, ui)
        est.add_output(to, yo)
    est.flush()
    counts = est.bad_sample_counts["output"]
    assert counts["non_monotonic"] == 1 and counts["dropped_lag"] == 0 and counts["time_jumps_back"] == 0
    assert est.n_sweeps == 1


def test_real_gap_is_confirmed_and_kept(nominal):
    """A 2 s silence is a gap (confirmed by the samples after it): nothing after it is lost."""
    *_, (ti, ui, to, yo), _ = nominal
    keep = (to < 155.0) | (to > 157.0)
    est = estimate(ti, ui, to[keep], yo[keep])
    counts = est.bad_sample_counts["output"]
    assert counts["accepted"] == np.count_nonzero(keep) and counts["non_monotonic"] == 0
