"""The node's diagnosis worker (gap_validation.ros.diagnosis_worker) keeps the last run's analyses: a channel
whose estimates did not change is not fitted again (issue 26: work only when new data changes a result), and
what it gives equals a diagnosis from scratch."""
from __future__ import annotations

import json

import pytest
from _flights import TINY, ultrastick

from gap_validation.bag.replay import replay
from gap_validation.bag.writer import write_flight
from gap_validation.cli.arguments import hidden_effects
from gap_validation.core import diagnosis
from gap_validation.core.simulation import simulate_flight
from gap_validation.ros.diagnosis_worker import DiagnosisWorker, _diagnose_snapshot


@pytest.fixture(scope="module")
def states(tmp_path_factory):
    """Validator states of two flights (a lag and a delay hidden on every axis, seeds 1 and 2)."""
    config = ultrastick()
    hidden = hidden_effects(
        [
            f"{c}:{e}"
            for c in config.channels
            for e in ("first_order_lag:bandwidth_rad_s=20", "time_delay:seconds=0.04")
        ],
        config,
    )
    out = []
    for seed in (1, 2):
        path = tmp_path_factory.mktemp("flights") / f"f{seed}"
        write_flight(simulate_flight(config, hidden, options=TINY, seed=seed), path)
        out.append(replay([path], config, diagnose=False).validator.state_dict())
    return config, out


def _json(result):
    return json.dumps(result.to_json_dict(), sort_keys=True, default=str)


def test_only_the_channel_with_new_estimates_is_fitted_again_and_the_result_is_as_from_scratch(
    states, monkeypatch
):
    config, (first, second) = states
    calls = []
    real = diagnosis.analyse_channel
    monkeypatch.setattr(diagnosis, "analyse_channel", lambda *a, **k: calls.append(1) or real(*a, **k))
    _, result, cache = _diagnose_snapshot(config, first, 0, {})
    fitted = len(calls)
    assert fitted == len(config.channels) and all(ch.diagnosis for ch in result.channels.values())
    # the same state again: nothing is fitted, the same result
    calls.clear()
    _, again, cache = _diagnose_snapshot(config, first, 0, cache)
    assert not calls and _json(again) == _json(result)
    # pitch from the other flight: pitch alone is fitted, and the result is the one from scratch
    mixed = dict(first, channels=dict(first["channels"], pitch=second["channels"]["pitch"]))
    calls.clear()
    _, cached, _ = _diagnose_snapshot(config, mixed, 0, cache)
    assert len(calls) == 1
    _, scratch, _ = _diagnose_snapshot(config, mixed, 0, {})
    assert _json(cached) == _json(scratch)
    assert _json(cached.channels["pitch"]) != _json(result.channels["pitch"])


def test_the_worker_hands_the_analyses_on_within_a_generation_only(states, monkeypatch):
    """Through the node's scheduling: the second diagnosis of a generation reuses the first one's analyses; a
    new generation (a model reload) or a reset (``forget``) starts from scratch."""
    import dataclasses

    from gap_validation.core.validator import OnlineValidator

    config, (first, _) = states

    class Source:
        def state_dict(self):
            return first

    cheap = OnlineValidator.from_state(config, first).results(diagnose=False)
    moved = dataclasses.replace(
        cheap,
        channels=dict(
            cheap.channels,
            roll=dataclasses.replace(cheap.channels["roll"], epsilon=cheap.channels["roll"].epsilon + 1),
        ),
    )
    calls = []
    real = diagnosis.analyse_channel
    monkeypatch.setattr(diagnosis, "analyse_channel", lambda *a, **k: calls.append(1) or real(*a, **k))
    worker = DiagnosisWorker()
    n = len(config.channels)
    try:
        for results, generation, forget, fitted in (
            (cheap, 0, False, n),
            (moved, 0, False, 0),
            (cheap, 1, False, n),
            (moved, 1, True, n),
        ):
            calls.clear()
            if forget:
                worker.forget()
            worker.force = True                     # whatever the period: the key changed, the test says when
            worker.schedule(results, Source(), config, generation, 3600.0)
            assert worker.wait(120.0) and worker.harvest(generation) is not None
            assert len(calls) == fitted, (generation, forget, len(calls))
    finally:
        worker.close()


def test_a_paced_diagnosis_keeps_to_its_share_of_a_core_and_gives_the_same_result(states):
    """``diagnosis_cpu_share``: the worker sleeps between candidate fits so that its thread's CPU stays within
    the share of the wall time; the result is the same as unpaced. A closed worker's diagnosis stops at its
    next pause."""
    import threading
    import time

    from gap_validation.ros.diagnosis_worker import CpuShare, DiagnosisAbandoned

    config, (first, _) = states
    _, fast, _ = _diagnose_snapshot(config, first, 0, {})
    pace = CpuShare(0.25)
    start, cpu0 = time.perf_counter(), time.thread_time()
    _, slow, _ = _diagnose_snapshot(config, first, 0, {}, pace)
    wall, cpu = time.perf_counter() - start, time.thread_time() - cpu0
    assert _json(slow) == _json(fast)
    # kept to its share (thread CPU: a loaded machine's waits count as rest, not work), up to the work after
    # the last pause (the results' assembly): at 0.25 the wall time is 4 x the CPU, at least 3 x here;
    # unpaced, 1 x
    assert wall >= 3.0 * cpu and pace.slept_s > 0.0
    stop = threading.Event()
    stop.set()
    with pytest.raises(DiagnosisAbandoned):
        _diagnose_snapshot(config, first, 0, {}, CpuShare(0.25, stop))
