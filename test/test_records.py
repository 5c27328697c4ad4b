"""Tests of gap_validation.core.records: where one manoeuvre ends and the next begins, and what kind each
is."""
import numpy as np
import pytest

from gap_validation.core.records import classify, period, split_record, trim_noise
from gap_validation.core.simulation import log_sweep, multisine, multistep

DT = 0.01
NOISE = 0.001
TRIM = 0.03


def card(*parts, before_s=2.0, after_s=3.0, seed=0):
    """An excitation signal: trim, the parts (arrays, or a number of seconds of trim), trim; plus noise."""
    pieces = [np.zeros(int(before_s / DT))]
    for part in parts:
        pieces.append(np.zeros(int(part / DT)) if np.isscalar(part) else np.asarray(part, float))
    pieces.append(np.zeros(int(after_s / DT)))
    u = np.concatenate(pieces) + TRIM
    return u + NOISE * np.random.default_rng(seed).standard_normal(u.size)


def chirp(length_s, w0=0.5, w1=52.0, amplitude=0.06):
    return amplitude * log_sweep(np.arange(0.0, length_s, DT), length_s, w0, w1)


def pieces_of(u):
    return split_record(u, DT, NOISE, int(2.0 / DT), int(4.0 / DT))


def kinds_of(u):
    return [classify(u, DT, p, NOISE) for p in pieces_of(u)]


def test_three_chirps_a_few_seconds_apart_are_three_sweeps():
    u = card(chirp(60.0), 3.0, chirp(60.0), 3.0, chirp(60.0))
    pieces = pieces_of(u)
    assert kinds_of(u) == ["chirp"] * 3
    # each keeps the trim before it from half of each 3 s pause on, and after it up to the next manoeuvre's
    # start (its response settles there): never a sample of another manoeuvre
    assert all(a.end <= b.active_start and a.active_end <= b.start for a, b in zip(pieces, pieces[1:]))
    assert all(p.active_start - p.start >= int(1.0 / DT) for p in pieces)
    assert all(a.end - a.active_end >= int(2.9 / DT) for a in pieces[:-1])


def test_one_second_of_trim_separates_and_less_does_not():
    assert len(pieces_of(card(chirp(40.0), 1.2, chirp(40.0, 1.0, 30.0)))) == 2
    multi = 0.05 * multistep(np.arange(0.0, 3.5, DT), 0.5, (3, 2, 1, 1), 0.04)
    assert len(pieces_of(card(multi, 1.2, multi))) == 2
    assert len(pieces_of(card(multi, 0.3, multi))) == 1


def test_a_restart_of_the_swept_frequency_separates_different_sweeps():
    u = card(chirp(50.0), chirp(70.0, 0.7, 40.0), chirp(40.0, 0.5, 30.0))
    assert kinds_of(u) == ["chirp"] * 3


def test_crossings_lost_near_the_top_of_a_sweep_do_not_start_a_new_one():
    """A low-SNR sweep: for half a second near its top the surface stays within the trim band (its crossings
    are lost); one long half-period among short ones is no restart: a new sweep stays at its low start
    frequency for several half-periods (seen on the second simulator's lowsnr flight: a 25 s chirp split at
    22.4 s)."""
    sweep = chirp(40.0)
    t = np.arange(sweep.size) * DT
    sweep[(t > 36.0) & (t < 36.5)] *= 0.02
    u = card(sweep)
    assert kinds_of(u) == ["chirp"] and len(pieces_of(u)) == 1
    # a real restart right after it still splits, and so does a doublet half a second after it (two
    # half-periods left in the group: the lasting test takes those there are)
    assert kinds_of(card(sweep, chirp(50.0, 0.7, 30.0))) == ["chirp", "chirp"]
    doublet = 0.05 * multistep(np.arange(0.0, 2.0, DT), 0.5, (1, 1), 0.04)
    assert kinds_of(card(sweep, 0.5, doublet)) == ["chirp", "doublet"]


def test_identical_sweeps_back_to_back_are_one_periodic_record():
    # three identical chirps without trim between them ARE a periodic excitation (a multisine)
    assert kinds_of(card(chirp(60.0), chirp(60.0), chirp(60.0))) == ["multisine"]


def test_the_slow_start_of_a_sweep_is_not_split():
    u = card(chirp(100.0, 0.2, 40.0))
    assert kinds_of(u) == ["chirp"] and len(pieces_of(u)) == 1


@pytest.mark.parametrize("signal, kind", [
    (lambda: 0.05 * multistep(np.arange(0.0, 3.5, DT), 0.5, (3, 2, 1, 1), 0.04), "multistep"),
    (lambda: 0.05 * multistep(np.arange(0.0, 1.0, DT), 0.5, (1, 1), 0.04), "doublet"),
    (lambda: 0.05 * multistep(np.arange(0.0, 1.0, DT), 1.0, (1,), 0.04), "pulse"),
    (lambda: 0.05 * multisine(np.arange(0.0, 60.0, DT), 20.0, 3, 0.5, 52.0), "multisine"),
    (lambda: 0.05 * multisine(np.arange(0.0, 60.0, DT), 20.0, 3, 0.5, 52.0, share=(1, 3)), "multisine"),
    (lambda: 0.03 * np.random.default_rng(1).standard_normal(2000), "broadband"),
])
def test_kinds(signal, kind):
    assert kinds_of(card(signal())) == [kind]


def test_a_trim_change_is_a_step_and_gives_no_manoeuvre_of_its_own():
    from gap_validation.core.records import Piece

    u = np.concatenate([np.full(200, TRIM), np.full(300, TRIM + 0.05)])
    assert classify(u, DT, Piece(0, u.size, 195, 210), NOISE) == "step"
    # a sweep flown before the pilot re-trims is a chirp: its own margins are its trim
    step = np.full(int(6.0 / DT), 0.05)
    assert kinds_of(card(chirp(30.0), 4.0, step, after_s=0.0)) == ["chirp"]


def test_a_trim_ramp_beside_a_doublet_leaves_it_a_doublet():
    ramp = np.linspace(0.0, 0.004, int(2.0 / DT))
    doublet = 0.05 * multistep(np.arange(0.0, 1.0, DT), 0.5, (1, 1), 0.04) + 0.004
    u = card(ramp, 0.5, doublet, after_s=3.0)
    assert kinds_of(u) == ["doublet"]


def test_a_flight_that_starts_one_second_before_a_3211_measures_its_trim_before_it():
    u = card(0.05 * multistep(np.arange(0.0, 3.5, DT), 0.5, (3, 2, 1, 1), 0.04), before_s=1.0, after_s=3.5)
    assert kinds_of(u) == ["multistep"]
    assert trim_noise(u, DT) == pytest.approx(NOISE, rel=0.3)


def test_period_of_a_multisine_is_its_fundamental():
    x = multisine(np.arange(0.0, 80.0, DT), 20.0, 4, 0.5, 30.0)
    assert period(x, DT) * DT == pytest.approx(20.0, abs=2 * DT)
    # every third harmonic only: the signal repeats three times as often
    x3 = multisine(np.arange(0.0, 80.0, DT), 20.0, 4, 0.5, 30.0, share=(0, 3))
    assert period(x3, DT) * DT == pytest.approx(20.0 / 3.0, abs=2 * DT)
    assert period(chirp(40.0), DT) == 0


def test_nothing_away_from_trim_gives_no_piece():
    assert pieces_of(card(5.0)) == []


def test_a_clipped_chirp_is_saturated_and_a_noisy_one_or_a_3211_is_not():
    from gap_validation.core.records import SATURATED_SHARE, saturated_share

    raw = chirp(20.0)
    clipped = card(np.clip(raw, -0.05, 0.05), seed=1)
    clipped_exact = np.where(np.abs(clipped - TRIM) > 0.05, TRIM + np.sign(clipped - TRIM) * 0.05, clipped)
    [piece] = pieces_of(clipped_exact)
    assert saturated_share(clipped_exact, piece) >= SATURATED_SHARE
    [piece] = pieces_of(card(raw, seed=1))
    assert saturated_share(card(raw, seed=1), piece) == 0.0  # noise never repeats its extreme value
    steps = TRIM + np.concatenate(
        [np.zeros(200), 0.05 * multistep(np.arange(0, 3.5, DT), 0.5), np.zeros(300)]
    )
    [piece] = pieces_of(steps)
    assert classify(steps, DT, piece, NOISE) == "multistep"        # plateaus by design: the estimator asks
    assert saturated_share(steps, piece) > SATURATED_SHARE         # only smooth kinds about saturation


def test_an_estimator_says_a_clipped_chirp_is_saturated_and_does_not_use_it():
    from gap_validation.core.estimator import FrequencyResponseEstimator

    w = np.geomspace(1.0, 20.0, 12)
    raw = chirp(30.0, w0=0.5, w1=30.0)
    u = np.concatenate([np.zeros(300), np.clip(raw, -0.04, 0.04), np.zeros(500)])
    t = np.arange(u.size) * DT
    y = np.convolve(u, np.exp(-t[:200] * 5.0) * DT * 5.0)[:u.size]
    est = FrequencyResponseEstimator(w)
    est.add_time_histories(t, u, t, y)
    est.flush()
    assert est.saturated == 1 and est.n_manoeuvres == 0


@pytest.mark.parametrize("period_s", [3.4, 5.0, 10.0])
def test_two_periods_of_a_short_multisine_are_one_periodic_record(period_s):
    """Its fades lie partly at trim, so the excited span is a little under two periods: still periodic, one
    record (a restart of its sweep inside each period does not split it)."""
    t = np.arange(0.0, 2 * period_s, DT)
    u = card(0.05 * multisine(t, period_s, 2, 0.5, 52.0))
    assert kinds_of(u) == ["multisine"]
    [piece] = pieces_of(u)
    assert period(u[piece.active_start:piece.active_end] - TRIM, DT) == pytest.approx(period_s / DT, abs=2)
