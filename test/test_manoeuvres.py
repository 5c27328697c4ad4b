"""Doublets kept from a flight for the time-domain check: found, classified, bounded, checkpointed."""
import numpy as np
import pytest

from gap_validation.core.estimator import FrequencyResponseEstimator
from gap_validation.core.manoeuvres import ManoeuvreRecorder

FS = 100.0
W = np.geomspace(1, 40, 20)


def flight(events, duration=120.0, noise=1e-4, seed=0):
    """Input with doublets / steps at the given times (kind, start_s) and a first-order response."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1 / FS)
    u = 0.01 + noise * rng.standard_normal(t.size)
    for kind, start in events:
        if kind == "doublet":
            u += 0.05 * (
                ((t >= start) & (t < start + 0.5)).astype(float) - ((t >= start + 0.5) & (t < start + 1.0))
            )
        elif kind == "pulse":
            u += 0.05 * ((t >= start) & (t < start + 0.6))
        elif kind == "step":
            u += 0.05 * (t >= start)
    y = np.zeros_like(u)
    for i in range(1, t.size):                                # 5 rad/s lag, unit gain
        y[i] = y[i - 1] + (u[i - 1] - y[i - 1]) * 5 / FS
    return t, u, y


def estimator_after(events, **kw):
    t, u, y = flight(events, **kw)
    est = FrequencyResponseEstimator(W)
    est.add_time_histories(t, u, t, y)
    est.flush()
    return est, t


def test_doublets_and_pulses_are_kept_and_trim_steps_are_not():
    est, _ = estimator_after([("doublet", 30.0), ("step", 55.0), ("pulse", 80.0)])
    found = est.manoeuvres
    assert [m.kind for m in found] == ["doublet", "pulse"]
    doublet = found[0]
    assert doublet.start_s <= 30.0 < 31.0 <= doublet.end_s         # the excitation is inside the window
    assert doublet.t_s[0] < doublet.start_s and doublet.t_s[-1] > doublet.end_s + 2.0
    assert np.allclose(np.diff(doublet.t_s), 1 / FS)
    du, dy = doublet.deviations()
    assert np.max(du) == pytest.approx(0.05, abs=2e-3) and np.min(du) == pytest.approx(-0.05, abs=2e-3)
    assert abs(np.mean(du[: doublet.trim_samples])) < 1e-12


def test_only_the_three_largest_are_kept():
    est, _ = estimator_after([("doublet", 20.0 + 15 * i) for i in range(6)], duration=130.0)
    assert len(est.manoeuvres) == 3


def test_sweeps_are_not_manoeuvres():
    t = np.arange(0.0, 100.0, 1 / FS)
    u = np.where((t > 20) & (t < 70), 0.05 * np.sin(2 * np.pi * (0.2 + 0.02 * (t - 20)) * (t - 20)), 0.0)
    est = FrequencyResponseEstimator(W)
    est.add_time_histories(t, u + 1e-4 * np.random.default_rng(1).standard_normal(t.size), t, u)
    est.flush()
    assert est.n_sweeps == 1 and est.manoeuvres == []


def test_manoeuvres_survive_a_checkpoint_midway():
    t, u, y = flight([("doublet", 30.0), ("doublet", 70.0)])
    whole = FrequencyResponseEstimator(W)
    whole.add_time_histories(t, u, t, y)
    whole.flush()
    first = FrequencyResponseEstimator(W)
    cut = np.searchsorted(t, 71.0)                       # in the middle of the second doublet
    first.add_time_histories(t[:cut], u[:cut], t[:cut], y[:cut])
    resumed = FrequencyResponseEstimator.from_state(first.state_dict())
    resumed.add_time_histories(t[cut:], u[cut:], t[cut:], y[cut:])
    resumed.flush()
    a, b = whole.manoeuvres, resumed.manoeuvres
    assert len(a) == len(b) == 2
    for x, z in zip(a, b):
        assert np.array_equal(x.u, z.u) and np.array_equal(x.y, z.y) and np.array_equal(x.t_s, z.t_s)


def test_recorder_state_is_bounded():
    rec = ManoeuvreRecorder(FS, 10.0)
    sizes = []
    rng = np.random.default_rng(2)
    for k in range(0, 200_000, 500):
        u = np.concatenate(
            [np.zeros(100), 0.05 * rng.uniform(0.5, 1.0) * np.sign(np.arange(100) - 50), np.zeros(300)]
        )
        rec.offer(k, u, u, k + 100, k + 200, "doublet")
        sizes.append(sum(np.asarray(v).nbytes for v in rec.state_dict().values()))
    assert len(set(sizes)) == 1 and len(rec.manoeuvres(0.0, 1 / FS)) == 3


def test_a_manoeuvre_without_trim_before_or_response_after_is_not_kept():
    rec = ManoeuvreRecorder(FS)
    doublet = np.concatenate([np.zeros(100), 0.05 * np.sign(np.arange(100) - 50), np.zeros(150)])
    assert not rec.offer(0, doublet[60:], doublet[60:], 40, 140, "doublet")      # 0.4 s of trim before
    assert not rec.offer(0, doublet[:250], doublet[:250], 100, 200, "doublet")   # 0.5 s after
    assert not rec.offer(0, doublet, doublet, 100, 200, "chirp")                 # not a short manoeuvre kind
    assert rec.offer(0, doublet, doublet, 100, 200, "doublet")
