"""Parameters of the node ``gap_validator``: names, defaults, documentation and checks (no rclpy).

``config/validator.params.yaml`` lists them with their defaults; :class:`gap_validation.ros.node.ValidatorNode`
declares :data:`PARAMETERS` and refuses values :func:`check_parameters` refuses.

config_file : str
    Validation config (YAML, DESIGN.md). Setting it at run time reloads the model (see "Live model update").
qos_depth : int, 1000
    KEEP_LAST depth of every subscription (read-only).
qos_reliability : {"reliable", "best_effort"}, "reliable"
    Reliability of the subscriptions (read-only).
diagnostic_period : float, 1.0 s
    Period of ``/diagnostics`` (read-only).
diagnosis_period : float, 10.0 s
    Shortest interval between two full diagnoses (effect fitting); <= 0 disables them.
stale_timeout : float, 3.0 s
    A channel whose input or output has had no good sample for this long is STALE.
warn_epsilon, error_epsilon : float, 0.25 and 0.38
    Levels: epsilon < warn_epsilon is OK, < error_epsilon WARN, else ERROR. 0.38 is the paper's point of
    "standard stability margins of a 6 dB gain margin and a 45 deg phase margin" (Section III, eqs. 15-16:
    2 asin(0.38) = 44.7 deg): below it a controller with standard margins is guaranteed stable on the
    aircraft. 0.25 (4.4 dB, 29 deg guaranteed) warns before that point is reached.
hardware_id : str, "" (the config file's stem)
    ``hardware_id`` of every status.
state_file : str, "" (off)
    Checkpoint of the gathered spectra (:mod:`gap_validation.core.checkpoint`), written atomically every
    ``checkpoint_period`` s and at shutdown; resumed from at start (read-only).
checkpoint_period : float, 5.0 s
    (read-only)
results_dir : str, "" (current directory)
    Where ``~/save_results`` writes.
discovery_period : float, 1.0 s
    Retry period for topics whose message type is neither in the config nor on the graph yet (read-only).
raw_decoding : bool, true
    Subscribe to the serialized messages and read only the configured fields with the decoding step replay
    uses (:mod:`gap_validation.messages.decoding`: Imu, JointState, Float64/32, Bool; checked against rclpy's
    deserialisation on the first messages of each topic); other types are deserialised (read-only).
executor : {"events", "single_threaded"}, "events"
    Executor of the console script: rclpy's EventsExecutor where available (the SingleThreadedExecutor
    when ``use_sim_time`` is set, whose /clock-driven timers the EventsExecutor of Jazzy gets wrong). The
    console script drives either with ``spin_once`` in a loop (``EventsExecutor.spin()`` of rclpy 7.1 runs no
    timers and ignores SIGINT).

CPU
---
At 1 kHz IMU and 100 Hz surfaces on three channels the node's own work (callbacks, diagnostics,
checkpoints, diagnosis) is about 2 % of one core (``benchmarks/bench_node.py``). The whole process costs more
because rclpy's executor and deserialisation dominate at these rates: a do-nothing subscriber costs about 23 %
of a core with the SingleThreadedExecutor and 9.5 % with the EventsExecutor, 4 % with raw (serialized)
subscriptions; hence the defaults ``executor:=events`` and ``raw_decoding:=true``.

QoS choice
----------
Subscriptions are RELIABLE, KEEP_LAST with a deep queue (``qos_depth`` = 1000 by default: one second of a
1 kHz IMU) and VOLATILE. The usual sensor-data profile (BEST_EFFORT, depth 5) drops samples as soon as the
node is busy for a few milliseconds (a diagnostics tick, a checkpoint, the GIL held by the diagnosis thread),
and every lost sample is a gap in the spectra. A RELIABLE subscription cannot be matched by a BEST_EFFORT
publisher (it receives nothing), so ``qos_reliability:=best_effort`` is offered for flight stacks that
publish with the sensor-data profile; the deep queue still absorbs bursts then.
"""
from __future__ import annotations

from typing import Any

from gap_validation.core.errors import ConfigError
from gap_validation.core.margins import STANDARD_EPSILON, WARN_EPSILON

__all__ = ["PARAMETERS", "check_parameters"]

#: Parameters: name -> (default, read-only, description). The params YAML mirrors these.
PARAMETERS: dict[str, tuple[Any, bool, str]] = {
    "config_file": ("", False, "validation config (YAML); setting it reloads the model"),
    "hardware_id": ("", False, "hardware_id of the statuses (default: the config file stem)"),
    "qos_depth": (1000, True, "KEEP_LAST depth of the subscriptions"),
    "qos_reliability": ("reliable", True, "reliable | best_effort (match the publishers)"),
    "diagnostic_period": (1.0, True, "period of /diagnostics [s]"),
    "diagnosis_period": (10.0, False, "shortest interval between full diagnoses [s]; <= 0 disables them"),
    "stale_timeout": (3.0, False, "STALE after this long without input or output samples [s]"),
    "warn_epsilon": (WARN_EPSILON, False, f"WARN from this epsilon ({WARN_EPSILON:g}: 4.4 dB / 29 deg, eqs. 15-16)"),
    "error_epsilon": (STANDARD_EPSILON, False,
                      f"ERROR from this epsilon ({STANDARD_EPSILON:g}: the paper's 6 dB / 45 deg point)"),
    "state_file": ("", True, "checkpoint file of the spectra ('' = off); resumed from at start"),
    "checkpoint_period": (5.0, True, "checkpoint period [s]"),
    "results_dir": ("", False, "directory of ~/save_results ('' = current directory)"),
    "discovery_period": (1.0, True, "retry period for topics whose type is not known yet [s]"),
    "raw_decoding": (True, True, "read the configured fields straight from the serialized message (Imu, "
                                 "JointState, Float64/32, Bool) instead of deserialising it in Python"),
    "executor": ("events", True, "events (rclpy's EventsExecutor, far less CPU) | single_threaded"),
}


def check_parameters(values: dict[str, Any]) -> None:
    """ConfigError (one line) for a parameter value the node cannot use.

    Parameters
    ----------
    values : dict
        Parameter name -> value (any subset of :data:`PARAMETERS`; ``warn_epsilon`` and ``error_epsilon``
        are checked against each other when both are given).
    """
    for name in ("qos_depth", "diagnostic_period", "stale_timeout", "checkpoint_period", "discovery_period"):
        if name in values and not values[name] > 0:
            raise ConfigError(f"parameter {name}: expected a number > 0, got {values[name]!r}")
    if "executor" in values and values["executor"] not in ("events", "single_threaded"):
        raise ConfigError(f"parameter executor: expected events or single_threaded, got {values['executor']!r}")
    if "qos_reliability" in values and values["qos_reliability"] not in ("reliable", "best_effort"):
        raise ConfigError(f"parameter qos_reliability: expected reliable or best_effort, got "
                          f"{values['qos_reliability']!r}")
    for name in ("warn_epsilon", "error_epsilon"):
        if name in values and not 0.0 < values[name] <= 1.0:
            raise ConfigError(f"parameter {name}: expected a number in (0, 1], got {values[name]!r}")
    if "warn_epsilon" in values and "error_epsilon" in values \
            and values["warn_epsilon"] > values["error_epsilon"]:
        raise ConfigError(f"parameter warn_epsilon ({values['warn_epsilon']}) is above error_epsilon "
                          f"({values['error_epsilon']})")
