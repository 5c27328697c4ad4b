"""The node's full diagnoses (effect fitting) in a background thread, on private copies of the validator.

The cheap results (``diagnose=False``) are computed every diagnostics tick. The full diagnosis fits effects,
which takes long: :class:`DiagnosisWorker` runs it in one worker thread on a copy of the validator state, at
most every ``diagnosis_period`` s and only when the results changed (at once after a model reload or a new
sweep), so message callbacks keep running. No rclpy import.
"""
from __future__ import annotations

import concurrent.futures
import math
import threading
import time
from typing import Any

import numpy as np

from gap_validation.core import diagnosis
from gap_validation.core.config import ValidationConfig
from gap_validation.core.results import ValidationResult
from gap_validation.core.validator import OnlineValidator

__all__ = ["DiagnosisWorker", "CpuShare", "DiagnosisAbandoned", "copy_tree"]


class DiagnosisAbandoned(Exception):
    """The worker was closed: the diagnosis running in it stops at its next pause."""


class CpuShare:
    """Holds the thread that calls it to ``share`` of one core: each call sleeps until the thread's CPU time
    since the first call is at most ``share`` of the wall time since then (``diagnosis.paced`` calls it
    between two candidate fits). A diagnosis costing 1.6 s of CPU takes 16 s at 0.1, and a 10 s window holds
    at most 1 s of it.

    Parameters
    ----------
    share : float
        Fraction of one core (0 or >= 1: no pacing).
    stop : threading.Event, optional
        When set, the next call raises, so a closed worker does not hold the process up.
    """

    def __init__(self, share: float, stop: threading.Event | None = None) -> None:
        self.share = float(share)
        self.stop = stop
        self._cpu0: float | None = None
        self._wall0 = 0.0
        self.slept_s = 0.0

    def __call__(self) -> None:
        if self.stop is not None and self.stop.is_set():
            raise DiagnosisAbandoned()
        if not 0.0 < self.share < 1.0:
            return
        if self._cpu0 is None:
            self._cpu0, self._wall0 = time.thread_time(), time.monotonic()
            return
        wait = (time.thread_time() - self._cpu0) / self.share - (time.monotonic() - self._wall0)
        while wait > 0.0:
            step = min(wait, 0.5)
            if self.stop is not None and self.stop.wait(step):
                raise DiagnosisAbandoned()
            if self.stop is None:
                time.sleep(step)
            self.slept_s += step
            wait -= step


def copy_tree(value: Any) -> Any:
    """Deep copy of a state tree (arrays copied), so a worker thread never sees arrays being updated.

    Parameters
    ----------
    value : object
        A state tree: dicts, lists, tuples, numpy arrays and plain values.
    """
    if isinstance(value, np.ndarray):
        return value.copy()
    if isinstance(value, dict):
        return {k: copy_tree(v) for k, v in value.items()}
    if isinstance(value, list):
        return [copy_tree(v) for v in value]
    if isinstance(value, tuple):
        return tuple(copy_tree(v) for v in value)
    return value


def _diagnose_snapshot(config: ValidationConfig, state: dict, generation: int, cache: dict,
                       pace: CpuShare | None = None) -> tuple[int, ValidationResult, dict]:
    """Worker: full results (effect fitting) on a private copy of the validator, reusing the previous run's
    analyses where what they read did not change (a channel without a new manoeuvre is not fitted again),
    paced by ``pace`` between candidate fits."""
    validator = OnlineValidator.from_state(config, state)
    validator.adopt_analysis_cache(cache)
    with diagnosis.paced(pace or (lambda: None)):
        result = validator.results(diagnose=True)
    return generation, result, validator.analysis_cache()


def _results_key(result: ValidationResult, generation: int) -> tuple:
    return (generation,) + tuple(
        (name, ch.sweeps, ch.epsilon, ch.nu_gap, ch.points_excluded) for name, ch in result.channels.items())


class DiagnosisWorker:
    """At most one full diagnosis at a time, in a worker thread.

    Attributes
    ----------
    job : concurrent.futures.Future or None
        The diagnosis running or finished and not yet harvested.
    force : bool
        Start the next diagnosis whatever the period (set after a model reload).
    """

    def __init__(self) -> None:
        self.job: concurrent.futures.Future | None = None
        self.force = True
        self._key: Any = None
        self._started = -math.inf
        self._pool: concurrent.futures.ThreadPoolExecutor | None = None
        self._cache: tuple[int, dict] = (-1, {})      # generation, the last diagnosis' analyses
        self._stop = threading.Event()

    def forget(self) -> None:
        """The spectra were reset: the next results are new whatever they say."""
        self._key = None
        self._cache = (-1, {})

    def schedule(self, result: ValidationResult, validator: OnlineValidator, config: ValidationConfig,
                 generation: int, period_s: float, cpu_share: float = 0.0) -> None:
        """Start a diagnosis of ``validator``'s state when ``result`` (the cheap results) warrants one.

        Parameters
        ----------
        result : ValidationResult
            The cheap results just computed.
        validator : OnlineValidator
            Whose state is copied for the worker.
        config : ValidationConfig
            The config the state belongs to.
        generation : int
            Model generation (changes on reload and reset); a result of an older one is not taken.
        period_s : float
            Shortest interval between two diagnoses when nothing but the numbers changed [s]; <= 0: never.
        cpu_share : float
            Fraction of one core the diagnosis may use (:class:`CpuShare`; 0: as fast as it can).
        """
        if period_s <= 0 or (self.job is not None and not self.job.done()):
            return
        if not any(ch.epsilon is not None or (ch.mimo is not None and ch.nu_gap is not None)
                   for ch in result.channels.values()):
            return
        key = _results_key(result, generation)
        if key == self._key:
            return
        sweeps_changed = self._key is None or key[0] != self._key[0] or any(
            a[1] != b[1] for a, b in zip(key[1:], self._key[1:]))
        if not (self.force or sweeps_changed or time.monotonic() - self._started >= period_s):
            return
        self.force = False
        self._key = key
        self._started = time.monotonic()
        state = copy_tree(validator.state_dict())
        if self._pool is None:
            self._pool = concurrent.futures.ThreadPoolExecutor(
                max_workers=1, thread_name_prefix="gap_diagnosis"
            )
        cache = self._cache[1] if self._cache[0] == generation else {}
        self.job = self._pool.submit(_diagnose_snapshot, config, state, generation, cache,
                                     CpuShare(cpu_share, self._stop))

    def harvest(self, generation: int) -> ValidationResult | None:
        """The finished diagnosis's results if they belong to ``generation`` (None otherwise, or still
        running).

        Parameters
        ----------
        generation : int
            The current model generation.

        Raises
        ------
        Exception
            Whatever the diagnosis raised (it is harvested all the same).
        """
        job = self.job
        if job is None or not job.done():
            return None
        self.job = None
        try:
            done_generation, result, cache = job.result()
        except DiagnosisAbandoned:
            return None
        self._cache = (done_generation, cache)
        return result if done_generation == generation else None

    def wait(self, timeout_s: float) -> bool:
        """Block until the running diagnosis (if any) is done; True when it is.

        Parameters
        ----------
        timeout_s : float
            Longest wait [s].
        """
        job = self.job
        if job is None:
            return True
        concurrent.futures.wait([job], timeout=timeout_s)
        return job.done()

    def close(self) -> None:
        """Shut the thread down; a running diagnosis works on its own copy and stops at its next pause."""
        self._stop.set()
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
            self.job = None
