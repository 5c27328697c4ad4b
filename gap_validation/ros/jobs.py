"""The node's files: resume from a checkpoint, checkpoints and ``~/save_results``, written off the executor
(rclpy).

:class:`Jobs` is the part of :class:`gap_validation.ros.node.ValidatorNode` that reads and writes its files,
as a component holding a reference to the node (its public rclpy API and its ``config``, ``validator``,
``router``, ``generation`` and ``hardware_id``) and the services the node lends it (the parameters
``state_file`` / ``results_dir``, log-once, flush: :class:`~gap_validation.ros.collaborators.NodeServices`).
It owns the ``~/save_results`` service. The slow writes run on snapshots
in :class:`gap_validation.ros.background.Background` (no rclpy there;
why: :mod:`gap_validation.ros.background`); this module takes the ``~/save_results`` requests and answers them
when their files are written, so the executor never waits.

Importing it imports rclpy (when available), never rosbags.
"""
from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any, Callable

from gap_validation.core.checkpoint import load_state, save_state
from gap_validation.core.errors import DataError, one_line
from gap_validation.core.validator import OnlineValidator
from gap_validation.ros import background
from gap_validation.ros.background import Background
from gap_validation.ros.collaborators import NodeServices

try:  # rclpy is only needed to run the node
    from std_srvs.srv import Trigger
except ImportError:  # pragma: no cover - exercised only without ROS 2
    pass

__all__ = ["Jobs"]


class Jobs:
    """A node's checkpoints and saved results, written by a :class:`Background` on snapshots.

    Parameters
    ----------
    node : rclpy.node.Node
        The node: its name, logger and ``create_service``, and its ``config``, ``validator``, ``router``,
        ``generation`` and ``hardware_id`` (read when needed: they change on reload and reset).
    services : NodeServices
        The node's parameters (``state_file``, ``results_dir``), log-once and flush.
    runner : Background
        The jobs off the executor (:attr:`background`; shared with
        :class:`~gap_validation.ros.excitation.Excitation`, whose ``~/plan`` jobs are finished here too).
    take_diagnoses : callable (dict of str to Candidate) -> None
        Hands the channels' top candidates of a save, diagnosed on a snapshot of the current generation, to
        the channels' statuses.
    finish_plan : callable (object, object) -> None
        Finishes a ``~/plan`` job: ``finish_plan(outcome, tag)``
        (:meth:`Excitation.finish <gap_validation.ros.excitation.Excitation.finish>`).

    Attributes
    ----------
    background : Background
        The jobs off the executor.
    umask : int
        The process's umask (files are written ``0666 & ~umask``).
    service : rclpy.service.Service or None
        ``~/save_results`` (std_srvs/Trigger), once :meth:`open_service` made it.
    """

    def __init__(self, node: Any, services: NodeServices, runner: Background,
                 take_diagnoses: Callable[[dict[str, Any]], None], finish_plan: Callable[[Any, Any], None]):
        self.node = node
        self.services = services
        self.umask = background.umask()
        self.background = runner
        self.take_diagnoses = take_diagnoses
        self.finish_plan = finish_plan
        self.service = None

    # ---------------------------------------------------------------- checkpoint and resume
    def initial_validator(self) -> OnlineValidator:
        """The validator to start with: resumed from ``state_file`` when it holds a usable checkpoint (an
        unusable one is set aside as ``<state_file>.corrupt``), else a fresh one."""
        node = self.node
        path = self.services.param("state_file")
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

        The checkpoint timer writes in the background instead (:meth:`checkpoint_in_background`); this waits
        for those.
        """
        path = self.services.param("state_file")
        if not path:
            return None
        self.services.flush()
        self.background.wait(60.0)
        try:
            save_state(self.node.validator.state_dict(), path,
                       meta={**self._checkpoint_meta(), "saved_unix_s": time.time()})
        except (DataError, TypeError) as err:
            self.services.log_once(f"checkpoint:{err}", "error", f"checkpoint failed: {one_line(err)}")
            return None
        background.fix_modes([Path(path)], self.umask)
        return path

    def checkpoint_in_background(self, force: bool = False) -> None:
        """Snapshot now, write in the background thread (after the writes before it); skipped while the
        previous checkpoint is still being written, unless ``force`` (a reset must reach the file).

        Parameters
        ----------
        force : bool
            Write even while the previous checkpoint is being written.
        """
        node = self.node
        path = self.services.param("state_file")
        if not path or (self.background.busy("checkpoint") and not force):
            return
        self.services.flush()
        snap = background.snapshot(
            node.config, node.validator, None, node.generation, self._checkpoint_meta()
        )
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
        """Snapshot now; the full diagnosis, JSON and report are written by the background process (the answer
        to ``~/save_results`` is sent when they are, :meth:`harvest`).

        Parameters
        ----------
        tag : object, optional
            The request header to answer, or None (nobody to answer).
        """
        node = self.node
        self.services.flush()
        snap = background.snapshot(node.config, node.validator, node.router, node.generation)
        out_dir = Path(self.services.param("results_dir") or ".").resolve()
        self.background.submit("save_results", tag, background.save_results, snap, out_dir,
                               background.file_stem(node.hardware_id), self.umask, process=True)

    def save_results(self) -> Path:
        """Write the JSON (and report, when available) of what was gathered so far, and wait for it; the JSON
        path."""
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
            self.services.log_once(f"{kind}:{one_line(err)}", "error", f"{kind} failed: {one_line(err)}")
            outcome = err
        if kind == "plan":
            self.finish_plan(outcome, tag)
            return outcome
        if kind == "save_results":
            if not isinstance(outcome, BaseException):
                for line in outcome.warnings:
                    node.get_logger().warning(one_line(line))
                if outcome.generation == node.generation:   # no reload or reset since the snapshot
                    self.take_diagnoses(outcome.top)
                outcome = outcome.path
            if tag is not None:
                response = Trigger.Response()
                if isinstance(outcome, BaseException):
                    response.success, response.message = False, f"save_results failed: {one_line(outcome)}"
                else:
                    response.success, response.message = True, str(outcome)
                try:
                    self.service.send_response(response, tag)
                except Exception as err:  # noqa: BLE001 - the client left
                    self.services.log_once(f"respond:{type(err).__name__}", "warning",
                                           f"~/save_results: could not answer ({one_line(err)})")
        return outcome

    def harvest(self) -> None:
        """Finish the jobs that are done: log failures, take saves' diagnoses, answer their requests."""
        for kind, future, tag in self.background.harvest():
            self._finish(kind, future, tag)

    def open_service(self) -> None:
        """Offer ``~/save_results`` (std_srvs/Trigger), kept out of the executor's wait set: its requests are
        taken by :meth:`serve_requests` (the node's intake timer) and answered when their files are
        written."""
        self.service = self.node.create_service(Trigger, "~/save_results", self._srv_save_results)
        self.services.poll(self.service)

    def _srv_save_results(self, request, response):
        """Callback of ``~/save_results`` should an executor serve it (the intake timer normally takes the
        requests): waits for the files."""
        try:
            response.message = str(self.save_results())
            response.success = True
        except Exception as err:  # noqa: BLE001
            response.success, response.message = False, f"save_results failed: {one_line(err)}"
            self.node.get_logger().error(response.message)
        return response

    def serve_requests(self) -> None:
        """Take ``~/save_results`` requests (the service is drained here, not by the executor)."""
        srv = self.service
        while True:
            with srv.handle:
                request, header = srv.handle.service_take_request(srv.srv_type.Request)
            if header is None:
                return
            self.save_results_in_background(tag=header)
