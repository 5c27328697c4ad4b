"""What the node lends its components, as explicit public collaborators (no rclpy, no other ``ros`` module).

:class:`~gap_validation.ros.topics.Topics`, :class:`~gap_validation.ros.jobs.Jobs` and
:class:`~gap_validation.ros.excitation.Excitation` are parts
of :class:`gap_validation.ros.node.ValidatorNode`. Like diagnostic_updater's ``Updater(node, period)`` they
use the node's public rclpy API (``create_subscription``, ``create_service``, ``get_logger`` ...) and its
public state (``config``, ``validator``, ``router``, ``generation``, ``hardware_id``: reload and reset replace
them, so they are read when needed); everything else they need of the node is lent to them here, at
construction, by the node (``ValidatorNode._setup`` wires it). No component reads another module's private
names, and this module imports none of the others, so the node and its components form no import cycle.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

__all__ = ["NodeServices"]


@dataclass(frozen=True)
class NodeServices:
    """The node's services to its components (each a callable bound to the node).

    Attributes
    ----------
    param : callable (str) -> object
        The current value of a node parameter (:mod:`gap_validation.ros.parameters`).
    log_once : callable (str, str, str) -> None
        ``log_once(key, level, text)``: log ``text`` at ``level`` (``error``, ``warning``, else info) the
        first time ``key`` is seen, never again (a fault repeated every message is logged once).
    now_s : callable () -> float
        The node clock [s] (follows ``/clock`` with ``use_sim_time``).
    flush : callable () -> None
        Push the router's pending samples to the validator (a failing batch is dropped and logged once).
    poll : callable (object) -> None
        Keep a subscription or service out of the executor's wait set (the node's intake timer drains it) and
        wake the executor, so it waits on its new set.
    unpoll : callable (object) -> None
        Forget a subscription or service :attr:`poll` kept (before it is destroyed).
    """

    param: Callable[[str], Any]
    log_once: Callable[[str, str, str], None]
    now_s: Callable[[], float]
    flush: Callable[[], None]
    poll: Callable[[Any], None]
    unpoll: Callable[[Any], None]
