"""The node's slow work off the executor, on snapshots: checkpoints, ``~/save_results`` and ``~/plan`` (no
rclpy).

Writing a checkpoint (a zip of arrays, ``fsync``-ed) takes about 20 ms, ``~/save_results`` 5-20 s (full
diagnosis, the report's figures). Run in the executor they stalled ``/diagnostics`` and, with data flowing,
made channels look STALE. The node therefore copies what a job needs in the executor (:func:`snapshot`: the
validator state, a few milliseconds) and hands the copy to :class:`Background`:

* checkpoints run in one worker thread, in submission order (a checkpoint is never overwritten by an older
  one);
* ``~/save_results`` and ``~/plan`` from the live results (the full diagnosis, then the planner: seconds) run
  in a child process (spawned for the job, gone when it is done): the report's
  matplotlib figures make the cyclic garbage collector run full collections of 0.15-0.3 s in a small process
  and seconds in a large one, and a collection holds the interpreter lock, which in a thread would stall the
  executor for as long (measured: ``/diagnostics`` 2.9 s late). In its own process nothing of it reaches the
  node.

The node harvests finished jobs from its intake timer and answers ``~/save_results`` and ``~/plan`` then (the
requests are taken by the node itself, so the executor never waits).

Files are written with the usual permissions (``0666 & ~umask``; the atomic writer's temporary files are
created ``0600``), see :func:`fix_modes`.
"""
from __future__ import annotations

import concurrent.futures
import json
import multiprocessing
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from gap_validation.cards import card_yaml
from gap_validation.core.checkpoint import save_state
from gap_validation.core.config import ValidationConfig
from gap_validation.core.errors import DataError
from gap_validation.core.plan import TestCard, plan_card
from gap_validation.core.results import ValidationResult
from gap_validation.core.validator import OnlineValidator
from gap_validation.messages.router import MessageRouter, note_saturation
from gap_validation.report.terminal import write_json
from gap_validation.ros.diagnosis_worker import copy_tree

__all__ = [
    "Background",
    "Snapshot",
    "SaveOutcome",
    "snapshot",
    "save_results",
    "full_result",
    "plan_from_results",
    "write_checkpoint",
    "fix_modes",
    "umask",
    "file_stem",
]


def umask() -> int:
    """The process umask, read without changing it (``/proc/self/status``; else set and restored at once)."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    old = os.umask(0o022)   # not thread-safe: only where /proc is missing
    os.umask(old)
    return old


def fix_modes(paths: list[Path], mask: int) -> None:
    """Give files (and the files of directories, one level) the usual mode ``0666 & ~mask``.

    Parameters
    ----------
    paths : list of Path
        Files or directories written.
    mask : int
        The umask (:func:`umask`).
    """
    mode = 0o666 & ~mask
    for path in paths:
        targets = [p for p in path.iterdir() if p.is_file()] if path.is_dir() else [path]
        for target in targets:
            try:
                os.chmod(target, mode)
            except OSError:
                pass


def file_stem(hardware_id: str) -> str:
    """A file-name stem from a hardware_id (``/uav1/gv2`` -> ``uav1_gv2``)."""
    stem = "".join(c if c.isalnum() or c in "-_." else "_" for c in hardware_id).strip("_.")
    return stem or "gap_validation"


@dataclass
class Snapshot:
    """What a background job needs, copied in the executor: config, validator state, router figures."""

    config: ValidationConfig
    state: dict
    generation: int
    saturation: dict = field(default_factory=dict)   # channel -> MessageRouter.saturation(channel)
    meta: dict = field(default_factory=dict)


class _Saturation:
    """A stand-in for the router in :func:`note_saturation`, answering from the snapshot."""

    def __init__(self, table: dict):
        self.table = table

    def saturation(self, channel: str) -> list:
        return self.table.get(channel, [])


def snapshot(config: ValidationConfig, validator: OnlineValidator, router: MessageRouter | None,
             generation: int, meta: dict | None = None) -> Snapshot:
    """Copy the validator's state (and the router's saturation figures) for a job in another thread.

    Parameters
    ----------
    config : ValidationConfig
        The config the state belongs to.
    validator : OnlineValidator
        Its :meth:`~OnlineValidator.state_dict` is deep-copied.
    router : MessageRouter or None
        Saturation figures per channel (for ``~/save_results``).
    generation : int
        The node's model generation (a result of an older one is not taken back).
    meta : dict, optional
        Checkpoint metadata.
    """
    saturation = {name: router.saturation(name) for name in config.channels} if router is not None else {}
    return Snapshot(config, copy_tree(validator.state_dict()), generation, saturation, dict(meta or {}))


def write_checkpoint(snap: Snapshot, path: str, mask: int) -> str:
    """Job: the snapshot's state written atomically to ``path``
    (:func:`gap_validation.core.checkpoint.save_state`), with the usual mode.

    Parameters
    ----------
    snap : Snapshot
        From :func:`snapshot`.
    path : str
        The ``state_file``.
    mask : int
        umask for the file's mode (:func:`fix_modes`).
    """
    save_state(snap.state, path, meta={**snap.meta, "saved_unix_s": time.time()})
    fix_modes([Path(path)], mask)
    return path


@dataclass
class SaveOutcome:
    """What ``~/save_results`` wrote: the JSON path, each channel's top diagnosis candidate (None: no effect
    helps; channels without an estimate are absent) for the snapshot's model generation, and one-line warnings
    (a figure or report that could not be written)."""

    path: Path
    generation: int = 0
    top: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)


def save_results(snap: Snapshot, out_dir: Path, stem: str, mask: int) -> SaveOutcome:
    """Job (in a child process): full results (diagnosis included) of the snapshot, written as JSON and, when
    matplotlib is there, as the HTML report beside it.

    Parameters
    ----------
    snap : Snapshot
        From :func:`snapshot`.
    out_dir : Path
        ``results_dir`` (created when missing).
    stem : str
        File name stem (hardware_id); a time stamp and, when needed, a counter are added.
    mask : int
        umask for the files' modes (:func:`fix_modes`).

    Raises
    ------
    DataError
        The directory or the JSON cannot be written (one line).
    """
    result = full_result(snap)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise DataError(f"{out_dir}: cannot create results directory ({err.strerror or err})") from None
    base = f"{stem}_{time.strftime('%Y%m%d-%H%M%S')}"
    path, n = out_dir / f"{base}.json", 1
    while path.exists():
        n += 1
        path = out_dir / f"{base}_{n}.json"
    write_json(result.to_json_dict(), path)
    outcome = SaveOutcome(
        path,
        snap.generation,
        {
            name: (ch.diagnosis[0] if ch.diagnosis else None)
            for name, ch in result.channels.items()
            if ch.epsilon is not None
        },
    )
    written = [path]
    report = _write_report(result, path.with_suffix(""), outcome.warnings)
    if report is not None:
        written.append(report)
    fix_modes(written, mask)
    return outcome


def full_result(snap: Snapshot) -> ValidationResult:
    """The full results of a snapshot (diagnosis included, saturation noted): what ``~/save_results`` writes.

    Parameters
    ----------
    snap : Snapshot
        From :func:`snapshot`.
    """
    result = OnlineValidator.from_state(snap.config, snap.state).results(diagnose=True)
    note_saturation(snap.config, _Saturation(snap.saturation), result)
    return result


def plan_from_results(snap: Snapshot, results_name: str, config_name: str) -> tuple[str, TestCard]:
    """Job (in a child process): the test card of the snapshot's results, as ``~/plan`` answers it.

    The results are exactly the JSON ``~/save_results`` would write (:func:`full_result`, through ``json``),
    planned by :func:`gap_validation.core.plan.plan_card` as ``gap-validate plan RESULTS.json`` plans that
    file, and written as ``plan --out`` writes the card (:func:`gap_validation.cards.card_yaml`).

    Parameters
    ----------
    snap : Snapshot
        From :func:`snapshot`.
    results_name : str
        What the card says it was planned from (``results``).
    config_name : str
        The config file (``config``).

    Returns
    -------
    (str, TestCard)
        The card's YAML and the card.
    """
    data = json.loads(json.dumps(full_result(snap).to_json_dict(), allow_nan=False))
    card = plan_card(snap.config, data, source=results_name)
    return card_yaml(card, results_name, config_name), card


def _write_report(result: ValidationResult, target: Path, warnings: list) -> Path | None:
    try:
        from gap_validation.report.html import write_report
    except ImportError:  # no matplotlib: the JSON is written, the report is a bonus
        return None
    try:
        write_report(result, target, warn=warnings.append)
    except Exception as err:  # noqa: BLE001 - the JSON is written; the report is a bonus
        warnings.append(f"report not written: {err}")
        return None
    return target


class Background:
    """The node's jobs off the executor: a worker thread (jobs in submission order), or a child process for
    jobs submitted with ``process=True`` (spawned on demand, shut down when it has nothing left to do);
    finished jobs are harvested.

    Attributes
    ----------
    jobs : list of (str, concurrent.futures.Future, Any)
        ``(kind, future, tag)`` submitted and not yet harvested (``tag``: what the node needs to finish it,
        e.g. the service request's header).
    """

    def __init__(self) -> None:
        self.jobs: list[tuple[str, concurrent.futures.Future, Any]] = []
        self._pool: concurrent.futures.ThreadPoolExecutor | None = None
        self._processes: concurrent.futures.ProcessPoolExecutor | None = None

    def submit(self, kind: str, tag: Any, fn: Callable, *args: Any, process: bool = False
               ) -> concurrent.futures.Future:
        """Run ``fn(*args)`` after the jobs already submitted (to the thread, or to the child process).

        Parameters
        ----------
        kind : str
            What it is (``checkpoint``, ``save_results``).
        tag : object
            Kept with the job for :meth:`harvest`.
        fn : callable
            The job (module-level and its arguments picklable when ``process``).
        *args
            Its arguments.
        process : bool
            Run it in a child process (``spawn``: a fresh interpreter, nothing inherited but the environment).
        """
        if process:
            if self._processes is None:
                self._processes = concurrent.futures.ProcessPoolExecutor(
                    max_workers=1, mp_context=multiprocessing.get_context("spawn"))
            future = self._processes.submit(fn, *args)
        else:
            if self._pool is None:
                self._pool = concurrent.futures.ThreadPoolExecutor(max_workers=1,
                                                                   thread_name_prefix="gap_background")
            future = self._pool.submit(fn, *args)
        self.jobs.append((kind, future, tag))
        return future

    def busy(self, kind: str) -> bool:
        """Whether a job of ``kind`` is queued or running.

        Parameters
        ----------
        kind : str
            The kind of job.
        """
        return any(k == kind and not f.done() for k, f, _ in self.jobs)

    def harvest(self) -> list[tuple[str, concurrent.futures.Future, Any]]:
        """The finished jobs (removed from :attr:`jobs`), in submission order."""
        done = [job for job in self.jobs if job[1].done()]
        if done:
            self.jobs = [job for job in self.jobs if not job[1].done()]
        if self._processes is not None and not self.jobs:   # the child process has nothing left to do
            self._processes.shutdown(wait=False)
            self._processes = None
        return done

    def wait(self, timeout_s: float) -> bool:
        """Block until every job submitted is done; True when they are.

        Parameters
        ----------
        timeout_s : float
            Longest wait [s].
        """
        pending = [f for _, f, _ in self.jobs]
        if pending:
            concurrent.futures.wait(pending, timeout=timeout_s)
        return all(f.done() for f in pending)

    def close(self, timeout_s: float = 60.0) -> None:
        """Finish the jobs submitted (up to ``timeout_s``) and stop the thread.

        Parameters
        ----------
        timeout_s : float
            Longest wait for running jobs [s].
        """
        self.wait(timeout_s)
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
        if self._processes is not None:
            self._processes.shutdown(wait=False, cancel_futures=True)
            self._processes = None
