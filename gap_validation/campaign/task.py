"""One flight of a campaign: the function a Dask worker runs (plain Python, no Dask import).

It is exactly ``gap-validate replay BAG... --config CFG --json``:
:func:`gap_validation.core.config.load_config` and
:func:`gap_validation.bag.replay.replay` (the diagnosis included), and the result is the replay JSON
(:meth:`ValidationResult.to_json_dict`), so a campaign's epsilons are a single replay's.
"""
from __future__ import annotations

import os
import socket
import time
from typing import Sequence

from gap_validation.bag.replay import replay
from gap_validation.core.config import load_config
from gap_validation.core.errors import GapValidationError, one_line

__all__ = ["validate_flight", "TASK_OPTIONS"]

#: What the task does, part of every flight's fingerprint (a change redoes the flights).
TASK_OPTIONS = {"task": "replay", "fast_decode": True, "diagnose": True}


def validate_flight(bags: Sequence[str], config: str) -> dict:
    """Replay one flight's bags against its config.

    Parameters
    ----------
    bags : sequence of str
        rosbag2 directories, ``.mcap`` or ``.db3`` files (sweeps from all count), as paths the worker can
        read.
    config : str
        Validation config file.

    Returns
    -------
    dict
        ``results``: the replay JSON, or None when nothing could be validated; ``errors`` and ``warnings``:
        one line each (replay's); ``messages``, ``elapsed_s`` (wall), ``cpu_s`` (CPU time of the task's
        thread: below ``elapsed_s`` when the machine is shared) and ``worker`` (``host:pid``).
        Bad data never raises: it is reported in ``errors``.
    """
    start, cpu = time.perf_counter(), time.thread_time()
    worker = f"{socket.gethostname()}:{os.getpid()}"
    try:
        outcome = replay(list(bags), load_config(config), fast=TASK_OPTIONS["fast_decode"],
                         diagnose=TASK_OPTIONS["diagnose"])
    except GapValidationError as err:
        return {"results": None, "errors": [one_line(err)], "warnings": [], "messages": 0,
                "elapsed_s": time.perf_counter() - start, "cpu_s": time.thread_time() - cpu, "worker": worker}
    return {"results": outcome.result.to_json_dict(), "errors": list(outcome.errors),
            "warnings": list(outcome.warnings), "messages": outcome.messages,
            "elapsed_s": time.perf_counter() - start, "cpu_s": time.thread_time() - cpu, "worker": worker}
