"""The node's files: resume from a checkpoint, checkpoints and ``~/save_results``, written off the executor (rclpy).

:class:`Jobs` is the part of :class:`gap_validation.ros.node.ValidatorNode` that reads and writes its files, as a
component holding a reference to the node (for its parameters ``state_file`` / ``results_dir``, its config,
validator, router, channel tasks, logging and the ``~/save_results`` service). The slow writes run on snapshots in
:class:`gap_validation.ros.background.Background` (no rclpy there; why: :mod:`gap_validation.ros.background`);
this module takes the ``~/save_results`` requests and answers them when their files are written, so the executor
never waits.

Importing it imports rclpy (when available), never rosbags.
"""
from __future__ import annotations

import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gap_validation.core.checkpoint import load_state, save_state
from gap_validation.core.errors import DataError, one_line
from gap_validation.core.validator import OnlineValidator
from gap_validation.ros import background
from gap_validation.ros.background import Background

try:  # rclpy is only needed to run the node
    from std_srvs.srv import Trigger
except ImportError:  # pragma: no cover - exercised only without ROS 2
    pass

if TYPE_CHECKING:  # pragma: no cover
    from gap_validation.ros.node import ValidatorNode

__all__ = ["Jobs"]


class Jobs:
    """A node's checkpoints and saved results, written by a :class:`Background` on snapshots.

    Parameters
    ----------
    node : ValidatorNode
        The node (its parameters, config, validator, router, tasks, generation, logging and ``_save_srv`` are
        used through it; they change on reload and reset).

    Attributes
    ----------
    background : Background
        The jobs off the executor.
    umask : int
        The process's umask (files are written ``0666 & ~umask``).
    """

    def __init__(self, node: "ValidatorNode"):
        self.node = node
        self.umask = background.umask()
        self.background = Background()

    # ---------------------------------------------------------------- checkpoint and resume
    def initial_validator(self) -> OnlineValidator:
        """The validator to start with: resumed from ``state_file`` when it holds a usable checkpoint (an unusable
        one is set aside as ``<state_file>.corrupt``), else a fresh one."""
        node = self.node
        path = node._param("state_file")
        if not path or not os.path.exists(path):
            return OnlineValidator(node.config, diagnose=False)
        try:
            validator = OnlineValidator.from_state(node.config, load_state(path), diagnose=False)
        except Exception as err:  # noqa: BLE001 - any unusable checkpoint: set it aside, start fresh
            aside = f"{path}.corrupt"
            try:
                os.replace(path, aside)
            except OSError:
                aside = "(could not move it aside)"
            node.get_logger().error(f"checkpoint {path} unusable ({one_line(err)}); kept as {aside}, "
                                    "starting fresh")
            return OnlineValidator(node.config, diagnose=False)
        node.get_logger().info(f"resumed from checkpoint {path}")
        return validator

    def _checkpoint_meta(self) -> dict:
        return {"node": self.node.get_fully_qualified_name(), "config_file": self.node.config.source}

    def checkpoint(self) -> str | None:
        """Write the validator state to ``state_file`` now, in this thread (atomically); the path or None.

        The checkpoint timer writes in the background instead (:meth:`checkpoint_in_background`); this waits for
        those.
        """
        node = self.node
        path = node._param("state_file")
        if not path:
            return None
        node._flush()
        self.background.wait(60.0)
        try:
            save_state(node.validator.state_dict(), path, meta={**self._checkpoint_meta(), "saved_unix_s": time.time()})
        except (DataError, TypeError) as err:
            node._log_once(f"checkpoint:{err}", "error", f"checkpoint failed: {one_line(err)}")
            return None
        background.fix_modes([Path(path)], self.umask)
        return path

    def checkpoint_in_background(self, force: bool = False) -> None:
        """Snapshot now, write in the background thread (after the writes before it); skipped while the previous
        checkpoint is still being written, unless ``force`` (a reset must reach the file).

        Parameters
        ----------
        force : bool
            Write even while the previous checkpoint is being written.
        """
        node = self.node
        path = node._param("state_file")
        if not path or (self.background.busy("checkpoint") and not force):
            return
        node._flush()
        snap = background.snapshot(node.config, node.validator, None, node._generation, self._checkpoint_meta())
        self.background.submit("checkpoint", path, background.write_checkpoint, snap, path, self.umask)

    def wait(self, timeout_s: float = 60.0) -> bool:
        """Block until the background jobs (checkpoints, saves) are written and answered; whether they are.

        Parameters
        ----------
        timeout_s : float
            Longest wait [s].
        """
        done = self.background.wait(timeout_s)
        self.harvest()
        return done

    # ---------------------------------------------------------------- ~/save_results
    def save_results_in_background(self, tag: Any = None) -> None:
        """Snapshot now; the full diagnosis, JSON and report are written by the background process (the answer to
        ``~/save_results`` is sent when they are, :meth:`harvest`).

        Parameters
        ----------
        tag : object, optional
            The request header to answer, or None (nobody to answer).
        """
        node = self.node
        node._flush()
        snap = background.snapshot(node.config, node.validator, node.router, node._generation)
        out_dir = Path(node._param("results_dir") or ".").resolve()
        self.background.submit("save_results", tag, background.save_results, snap, out_dir,
                               background.file_stem(node.hardware_id), self.umask, process=True)

    def save_results(self) -> Path:
        """Write the JSON (and report, when available) of what was gathered so far, and wait for it; the JSON path."""
        self.save_results_in_background(tag=None)
        self.background.wait(600.0)
        path = None
        for kind, future, tag in self.background.harvest():
            outcome = self._finish(kind, future, tag)
            if kind == "save_results" and tag is None:
                path = outcome
        if isinstance(path, BaseException):
            raise path
        return path

    def _finish(self, kind: str, future: Any, tag: Any) -> Any:
        """A finished background job: log a failure, take a save's diagnosis, answer its request."""
        node = self.node
        try:
            outcome = future.result()
        except Exception as err:  # noqa: BLE001 - reported, never raised into the executor
            node._log_once(f"{kind}:{one_line(err)}", "error", f"{kind} failed: {one_line(err)}")
            outcome = err
        if kind == "plan":
            node.excitation.finish(outcome, tag)
            return outcome
        if kind == "save_results":
            if not isinstance(outcome, BaseException):
                for line in outcome.warnings:
                    node.get_logger().warning(one_line(line))
                if outcome.generation == node._generation:   # no reload or reset since the snapshot
                    for name, top in outcome.top.items():
                        if name in node._tasks:
                            node._tasks[name].take_diagnosis(top)
                outcome = outcome.path
            if tag is not None:
                response = Trigger.Response()
                if isinstance(outcome, BaseException):
                    response.success, response.message = False, f"save_results failed: {one_line(outcome)}"
                else:
                    response.success, response.message = True, str(outcome)
                try:
                    node._save_srv.send_response(response, tag)
                except Exception as err:  # noqa: BLE001 - the client left
                    node._log_once(f"respond:{type(err).__name__}", "warning",
                                   f"~/save_results: could not answer ({one_line(err)})")
        return outcome

    def harvest(self) -> None:
        """Finish the jobs that are done: log failures, take saves' diagnoses, answer their requests."""
        for kind, future, tag in self.background.harvest():
            self._finish(kind, future, tag)

    def serve_requests(self) -> None:
        """Take ``~/save_results`` requests (the service is drained here, not by the executor)."""
        srv = self.node._save_srv
        while True:
            with srv.handle:
                request, header = srv.handle.service_take_request(srv.srv_type.Request)
            if header is None:
                return
            self.save_results_in_background(tag=header)
