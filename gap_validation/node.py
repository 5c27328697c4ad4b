"""ROS 2 node ``gap_validator``: live model validation beside the flight stack.

A thin shell (docs/ARCHITECTURE.md, "one data path"): every subscribed message goes to
:class:`gap_validation.ingest.MessageRouter`, exactly as :mod:`gap_validation.replay` feeds a bag (serialized
messages through the same fast field decoders and ``MessageRouter.on_values``; others deserialised and
``MessageRouter.on_message``), and the router feeds :class:`gap_validation.core.validator.OnlineValidator`. The node owns no estimation or metrics code; it
wires topics, timers, parameters and services to the validator and renders its results as
``diagnostic_msgs/msg/DiagnosticArray`` on ``/diagnostics``.

Run::

    ros2 run gap_validation validator_node --ros-args -p config_file:=/path/cfg.yaml
    ros2 launch gap_validation validator.launch.py config_file:=/path/cfg.yaml
    validator_node --ros-args -p config_file:=/path/cfg.yaml        # pip install, no colcon

Parameters (``config/validator.params.yaml`` lists them with their defaults)
---------------------------------------------------------------------------
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
    Subscribe to the serialized messages and read only the configured fields with the decoders
    :mod:`gap_validation.replay` uses (Imu, JointState, Float64/32, Bool; checked against rclpy's
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

Time
----
The router stamps samples with ``header.stamp`` when the message has one, else with the node clock at
reception. With ``ros2 bag play --clock`` and ``use_sim_time:=true`` the node therefore sees the same samples
and stamps as ``gap-validate replay`` on the bag and gives the same numbers (topics without a header, e.g.
``std_msgs/Float64``, are stamped with the receive time, which differs slightly from the bag time).
Staleness and the timers use the node clock: with ``use_sim_time`` they follow ``/clock``, so nothing is
published before the bag plays or while it is paused.

Diagnostics
-----------
Published every ``diagnostic_period`` by a timer; when the timer is 1.5 periods late (a flood: rclpy's
EventsExecutor queues it behind every pending message) the next message callback publishes instead, so
``/diagnostics`` stays on time under load (``benchmarks/bench_node_flood.py``). One status per channel, named
``gap_validator: <channel>``. Level:

* STALE before any data (message "waiting for data on ..."), when a topic's type is still being discovered,
  when the input or output had no good sample for ``stale_timeout`` s (the last numbers stay in the values),
  and while data flow but no sweep has completed ("receiving data, waiting for a sweep"): there is no
  estimate to judge then, and OK would claim a validation that has not happened.
* WARN when sweeps were flown but no frequency reached the coherence threshold (data-limited: fly better
  sweeps), or when ``warn_epsilon <= epsilon < error_epsilon``.
* ERROR when ``epsilon >= error_epsilon``; OK below ``warn_epsilon``.

Values are strings under the JSON key names (``nu_gap``, ``epsilon``, ``epsilon_raw``, ``epsilon_previous``,
``gain_margin_db``, ``phase_margin_deg``, ``disk_margin``, ``worst_frequency_rad_s``, ``sweeps``, ``limited_by``,
``points_excluded``, ``bad_samples`` (total; ``bad_samples_by_reason`` has the JSON dict), ``diagnosis`` (top
candidate sentence; ``pending`` before the first fit, ``none`` when no effect helps, ``off`` when disabled),
``diagnosis_effects`` (the JSON list to append to the model's effects), ``samples_input``/``samples_output``,
``samples_dropped`` ...). ``samples_dropped`` counts the messages missing from the channel's topics, inferred from
gaps in their ``header.stamp`` (:class:`StampGaps`; DDS does not tell the node when a queue overflows; topics
without a header are not counted). Numbers are Python ``repr``
(round-trip exact); missing numbers are ``null`` (margins for epsilon >= 1: no guarantee).

The cheap results (``diagnose=False``) are computed every tick. The full diagnosis fits effects, which takes
long: it runs in a worker thread on a copy of the validator state, at most every ``diagnosis_period`` s and
only when the results changed (at once after a model reload or a new sweep), so message callbacks keep
running; the last top candidate is kept for the message.

Live model update
-----------------
Setting ``config_file`` or calling ``~/reload`` (std_srvs/Trigger) re-reads the config and calls
``OnlineValidator.set_config``: the spectra already gathered are kept, and the next diagnostics show the new
epsilon with the previous one (``epsilon_previous``, "epsilon 0.12 (was 0.62)"). A bad file is refused (the
old model stays; the service answers success=False, the parameter set fails, with the one-line error).
``~/reset`` forgets the spectra; ``~/save_results`` writes the JSON (and the HTML report when
:mod:`gap_validation.report` is available) of what was gathered so far to ``results_dir`` and answers with
the path. Bad messages (NaN, missing joint, short arrays) are counted by the router and shown in
``bad_samples``; nothing in a message can stop the node.
"""
from __future__ import annotations

import argparse
import concurrent.futures
import importlib
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from gap_validation.config import load_config
from gap_validation.core.checkpoint import load_state, save_state
from gap_validation.core.config import ValidationConfig
from gap_validation.core.errors import ConfigError, DataError, GapValidationError, one_line
from gap_validation.core.margins import STANDARD_EPSILON, WARN_EPSILON
from gap_validation.core.results import Candidate, ChannelResult, ValidationResult
from gap_validation.core.validator import OnlineValidator
from gap_validation.ingest import (VERIFY_MESSAGES, FieldError, FieldPath, MessageRouter, fast_values_agree,
                                   note_saturation, stamp_seconds)
from gap_validation.render import write_json

try:  # rclpy is only needed to run the node; the pure helpers below work without it
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
    from rclpy.exceptions import ParameterException
    from rclpy.executors import ExternalShutdownException
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import deserialize_message
    from std_srvs.srv import Trigger
    _ROS_IMPORT_ERROR: ImportError | None = None
except ImportError as _err:  # pragma: no cover - exercised only without ROS 2
    rclpy = None
    Node = object
    _ROS_IMPORT_ERROR = _err

__all__ = ["NODE_NAME", "PARAMETERS", "ChannelStatus", "channel_status", "candidate_sentence", "StampGaps",
           "ValidatorNode", "main"]

#: Node name (DESIGN.md).
NODE_NAME = "gap_validator"

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

#: Status values taken from ``ChannelResult.to_json_dict()`` under the same key names.
_JSON_VALUES = ("nu_gap", "epsilon", "epsilon_raw", "epsilon_previous", "gain_margin_db", "phase_margin_deg",
                "disk_margin", "worst_frequency_rad_s", "sweeps", "limited_by", "points_excluded")
_STREAM_TOPICS = ("input", "output")


# ============================================================================ pure helpers (no rclpy)
def _value_text(value: Any) -> str:
    """A status value string: ``repr`` of numbers (round-trip exact), ``null`` for None, JSON otherwise."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return value
    return json.dumps(value, sort_keys=True)


def candidate_sentence(candidate: Candidate | None) -> str:
    """One line about a diagnosis candidate: ``missing: time delay of 45 ms (epsilon would be 0.06)``."""
    if not candidate:
        return ""
    sentence = candidate.sentence
    if not sentence:
        parts = []
        try:
            from gap_validation.core.effects import describe_effect

            parts = [describe_effect(e) for e in candidate.effects]
        except Exception:  # noqa: BLE001 - description is cosmetic; fall back to the effect name
            parts = []
        what = " + ".join(parts) or str(candidate.effect or "unknown effect").replace("_", " ")
        sentence = f"missing: {what}"
        if candidate.epsilon is not None:
            sentence += f" (epsilon would be {candidate.epsilon:.2f})"
    return " ".join(str(sentence).split())


def _band_text(result: ChannelResult) -> str:
    """``at 20-40 rad/s`` from the diagnosis band that holds the worst frequency, else ``at 14.9 rad/s``."""
    worst = result.worst_frequency_rad_s
    chosen = None
    for band in result.bands:
        if worst is not None and band.contains(worst):
            chosen = band
            break
        if chosen is None and band.limited_by == result.limited_by:
            chosen = band
    if chosen is not None:
        return f"at {chosen.min_rad_s:.3g}-{chosen.max_rad_s:.3g} rad/s"
    return f"at {worst:.3g} rad/s" if worst is not None else ""


def _level_for(epsilon: float, warn_epsilon: float, error_epsilon: float) -> str:
    if epsilon >= error_epsilon:
        return "ERROR"
    return "WARN" if epsilon >= warn_epsilon else "OK"


def _summary(result: ChannelResult, level: str, candidate_text: str) -> str:
    """``epsilon 0.62 (was 0.71): ERROR, model-limited at 20-40 rad/s; missing: time delay of 45 ms``."""
    text = f"epsilon {result.epsilon:.2f}"
    if result.epsilon_previous is not None:
        text += f" (was {result.epsilon_previous:.2f})"
    text += f": {level}"
    if result.limited_by in ("model", "data"):
        band = _band_text(result)
        text += f", {result.limited_by}-limited" + (f" {band}" if band else "")
    elif result.worst_frequency_rad_s is not None:
        text += f", worst at {result.worst_frequency_rad_s:.3g} rad/s"
    if candidate_text:
        text += f"; {candidate_text}"
    return text


@dataclass
class ChannelStatus:
    """What one ``DiagnosticStatus`` says, without ROS types: level name, message and string values."""

    channel: str
    level: str
    message: str
    values: list[tuple[str, str]] = field(default_factory=list)


def channel_status(result: ChannelResult, *, warn_epsilon: float = WARN_EPSILON,
                   error_epsilon: float = STANDARD_EPSILON,
                   stale_reason: str | None = None, waiting_reason: str | None = None,
                   candidate: Candidate | dict | None = None, diagnosis_state: str = "pending",
                   extra_values: dict | None = None) -> ChannelStatus:
    """The status of one channel from its (cheap) result.

    Parameters
    ----------
    result : ChannelResult
        ``OnlineValidator.results(diagnose=False)`` of the channel.
    warn_epsilon, error_epsilon : float
        Level thresholds on the averaged epsilon (eq. 14).
    stale_reason : str, optional
        Why the inputs count as stopped ("no data for 4.2 s on /imu (output)"): level STALE, numbers kept.
    waiting_reason : str, optional
        Why there is no data yet ("waiting for data on /imu (output)"): level STALE.
    candidate : Candidate or dict, optional
        Top diagnosis candidate of the last full diagnosis (or its JSON object, a ``diagnosis`` entry).
    diagnosis_state : {"pending", "done", "off"}
        Whether a full diagnosis has been run for the current model.
    extra_values : dict, optional
        More values appended (e.g. sample ages).

    Returns
    -------
    ChannelStatus
    """
    if isinstance(candidate, dict):
        candidate = Candidate.from_json_dict(candidate)
    data = result.to_json_dict(samples=False)
    values = [(key, _value_text(data.get(key))) for key in _JSON_VALUES]
    bad = dict(result.bad_samples)
    values.append(("bad_samples", str(int(sum(bad.values())))))
    values.append(("bad_samples_by_reason", json.dumps(bad, sort_keys=True)))
    cand_text = candidate_sentence(candidate)
    if diagnosis_state == "off":
        diagnosis_value = "off"
    elif candidate:
        diagnosis_value = cand_text
    else:
        diagnosis_value = "none" if diagnosis_state == "done" else "pending"
    values.append(("diagnosis", diagnosis_value))
    values.append(("diagnosis_effects", json.dumps(candidate.effects if candidate else [])))
    values.append(("diagnosis_epsilon", _value_text(candidate.epsilon if candidate else None)))
    values.append(("nu_gap_frequency_rad_s", _value_text(data.get("nu_gap_frequency_rad_s"))))
    values.append(("coherence_threshold", _value_text(result.coherence_threshold)))
    values.append(("model_description", result.model_description))
    for key, value in (extra_values or {}).items():
        values.append((key, _value_text(value)))

    if result.epsilon is not None:
        level = _level_for(result.epsilon, warn_epsilon, error_epsilon)
        summary = _summary(result, level, cand_text)
    elif result.sweeps > 0:
        level = "WARN"
        summary = (result.message or "no frequency passes the coherence threshold") + \
            ": WARN, data-limited (fly better sweeps)"
    else:
        level, summary = "STALE", "receiving data, waiting for a sweep (no estimate yet)"
    if waiting_reason:
        resumed = f" (resumed: {summary})" if result.epsilon is not None else ""
        return ChannelStatus(result.name, "STALE", waiting_reason + resumed, values)
    if stale_reason:
        last = f"; last: {summary}" if result.epsilon is not None or result.sweeps > 0 else ""
        return ChannelStatus(result.name, "STALE", stale_reason + last, values)
    return ChannelStatus(result.name, level, summary, values)


def _copy_tree(value: Any) -> Any:
    """Deep copy of a state tree (arrays copied), so a worker thread never sees arrays being updated."""
    if isinstance(value, np.ndarray):
        return value.copy()
    if isinstance(value, dict):
        return {k: _copy_tree(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_copy_tree(v) for v in value]
    if isinstance(value, tuple):
        return tuple(_copy_tree(v) for v in value)
    return value


class StampGaps:
    """Messages missing from one topic, inferred from its ``header.stamp`` continuity.

    The node cannot see losses inside DDS (a KEEP_LAST queue that overflows drops the oldest samples silently,
    a BEST_EFFORT link loses some), so it counts them from the stamps: the nominal period is learnt from the
    first :attr:`LEARN` intervals (their median) and then refined as the mean of every interval below 1.5
    periods (stamps of 1.7e9 s carry float rounding of 0.24 us, which the mean averages out), and an interval of
    ``dt`` with ``1.5 period < dt <= max_gap_s`` counts ``round(dt / period) - 1`` missing messages. Longer
    silences are pauses (STALE), not drops; after one the period is learnt again. A rate change in flight would
    count as drops; stamps going backwards are ignored.
    """

    LEARN = 16
    __slots__ = ("max_gap_s", "period_s", "first_s", "last_s", "dropped", "_intervals", "_sum_s", "_count")

    def __init__(self, max_gap_s: float):
        self.max_gap_s = float(max_gap_s)
        self.first_s: float | None = None   # first stamp seen [s]
        self.last_s: float | None = None
        self.dropped = 0
        self._learn()

    def _learn(self) -> None:
        self.period_s, self._intervals, self._sum_s, self._count = 0.0, [], 0.0, 0

    def add(self, t_s: float) -> None:
        """One message stamped ``t_s`` [s]."""
        last, self.last_s = self.last_s, t_s
        if last is None:
            self.first_s = t_s
            return
        dt = t_s - last
        if dt <= 0.0:
            self.last_s = last if dt < 0.0 else t_s
        elif dt > self.max_gap_s:
            self._learn()
        elif self.period_s <= 0.0:
            self._intervals.append(dt)
            if len(self._intervals) >= self.LEARN:
                self.period_s = float(np.median(self._intervals))
                normal = [d for d in self._intervals if d <= 1.5 * self.period_s]
                self._sum_s, self._count = float(sum(normal)), len(normal)
        elif dt > 1.5 * self.period_s:
            self.dropped += int(round(dt / self.period_s)) - 1
        else:
            self._sum_s += dt
            self._count += 1
            self.period_s = self._sum_s / self._count


def message_class(type_name: str) -> type:
    """The rclpy message class of ``pkg/msg/Name`` (``pkg/Name`` accepted).

    Raises
    ------
    ConfigError
        When the package or the message is not installed.
    """
    parts = type_name.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise ConfigError(f"message type {type_name!r}: expected pkg/msg/Name")
    try:
        module = importlib.import_module(f"{parts[0]}.{parts[1]}")
        return getattr(module, parts[2])
    except (ImportError, AttributeError) as err:
        raise ConfigError(f"message type {type_name!r} is not installed ({one_line(err)})") from None


def _check_fields(topic: str, cls: type, entries) -> None:
    """ConfigError when ``cls`` lacks a configured field (checked on a default message)."""
    sample = cls()
    for channel, stream, spec in entries:
        try:
            FieldPath.parse(spec.field).extract(sample)
        except FieldError as err:
            if err.structural:
                raise ConfigError(f"channels.{channel}.{stream}: topic {topic} ({cls.__name__}): {err}") from None


def topic_types(config: ValidationConfig) -> dict[str, str | None]:
    """Topic -> message type from the config (None: discover it from the graph).

    Raises
    ------
    ConfigError
        When two signals on one topic name different types.
    """
    out: dict[str, str | None] = {}
    for topic, entries in config.topics().items():
        types = {spec.type for _, _, spec in entries if spec.type}
        if len(types) > 1:
            raise ConfigError(f"{config.source}: topic {topic}: conflicting types {', '.join(sorted(types))}")
        out[topic] = types.pop() if types else None
    return out


# ============================================================================ the node
class ValidatorNode(Node):
    """The ``gap_validator`` node (see the module docstring for parameters, QoS, levels and services).

    Parameters
    ----------
    **kwargs
        Passed to :class:`rclpy.node.Node` (``context``, ``parameter_overrides``, ``cli_args`` ...).

    Raises
    ------
    ConfigError
        Bad startup config or parameter (one line; ``main`` exits with status 2).
    """

    #: Diagnostics periods after the last publication when a message callback publishes in the timer's stead.
    DIAGNOSTICS_LATE = 1.5

    def __init__(self, **kwargs):
        if rclpy is None:  # pragma: no cover
            raise ConfigError(f"rclpy is not available ({_ROS_IMPORT_ERROR})")
        super().__init__(NODE_NAME, **kwargs)
        try:
            self._setup()
        except BaseException:
            self._close_worker()
            self.destroy_node()
            raise

    # ---------------------------------------------------------------- setup
    def _setup(self) -> None:
        self._logged: set[str] = set()
        self._declare_parameters()
        self._check_parameters({name: self.get_parameter(name).value for name in PARAMETERS})
        config_file = self.get_parameter("config_file").value
        if not config_file:
            raise ConfigError("parameter config_file is not set (ros2 run gap_validation validator_node "
                              "--ros-args -p config_file:=/path/cfg.yaml)")
        self.config = load_config(config_file)
        self._types = self._resolve_types(self.config)
        self.validator = self._initial_validator()
        self.router = MessageRouter(self.config, self.validator)
        self.last_result: ValidationResult | None = None
        self._subs: dict[str, Any] = {}
        self._raw: dict[str, _RawTopic] = {}
        self._sub_types: dict[str, str] = {}
        self._pending: dict[str, None] = {}
        self._last_arrival: dict[str, float] = {}
        self._gaps: dict[str, StampGaps] = {}
        self._last_seen: dict[tuple[str, str], float] = {}
        self._seen_count: dict[tuple[str, str], int] = {}
        self._top: dict[str, Candidate | None] = {}
        self._generation = 0
        self._diagnosed_key: Any = None
        self._force_diagnosis = True
        self._diagnosis_started = -math.inf
        self._job: concurrent.futures.Future | None = None
        self._worker: concurrent.futures.ThreadPoolExecutor | None = None
        self._discovery_timer = None
        self._qos = self._make_qos()
        self._subscribe_all()
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_service(Trigger, "~/reload", self._srv_reload)
        self.create_service(Trigger, "~/reset", self._srv_reset)
        self.create_service(Trigger, "~/save_results", self._srv_save_results)
        self._diag_due_s = self._now_s() + self.DIAGNOSTICS_LATE * self._param("diagnostic_period")
        self._diag_timer = self.create_timer(self._param("diagnostic_period"), self._diagnostics_tick)
        self._ckpt_timer = None
        if self._param("state_file"):
            self._ckpt_timer = self.create_timer(self._param("checkpoint_period"), self.checkpoint)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.get_logger().info(
            f"validating {', '.join(self.config.channels)} from {config_file} on "
            f"{', '.join(self.router.topics)} (QoS {self._param('qos_reliability')}, depth "
            f"{self._param('qos_depth')})")

    def _declare_parameters(self) -> None:
        for name, (default, read_only, description) in PARAMETERS.items():
            try:
                self.declare_parameter(name, default, ParameterDescriptor(description=description,
                                                                           read_only=read_only))
            except ParameterException as err:
                kind = type(default).__name__.replace("str", "string").replace("float", "double (e.g. 1.0)")
                raise ConfigError(f"parameter {name}: expected a {kind} ({one_line(err)})") from None

    def _param(self, name: str) -> Any:
        return self.get_parameter(name).value

    @staticmethod
    def _check_parameters(values: dict) -> None:
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

    def _make_qos(self) -> "QoSProfile":
        reliability = ReliabilityPolicy.RELIABLE if self._param("qos_reliability") == "reliable" \
            else ReliabilityPolicy.BEST_EFFORT
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(self._param("qos_depth")),
                          reliability=reliability, durability=DurabilityPolicy.VOLATILE)

    def _log_once(self, key: str, level: str, text: str) -> None:
        if key in self._logged:
            return
        self._logged.add(key)
        logger = self.get_logger()  # rclpy wants one severity per call site: one call per level
        if level == "error":
            logger.error(text)
        elif level == "warning":
            logger.warning(text)
        else:
            logger.info(text)

    @property
    def hardware_id(self) -> str:
        """The ``hardware_id`` parameter, or the config file's stem."""
        return self._param("hardware_id") or Path(self.config.source or "gap_validation").stem

    # ---------------------------------------------------------------- checkpoint and resume
    def _initial_validator(self) -> OnlineValidator:
        path = self._param("state_file")
        if not path or not os.path.exists(path):
            return OnlineValidator(self.config, diagnose=False)
        try:
            validator = OnlineValidator.from_state(self.config, load_state(path), diagnose=False)
        except Exception as err:  # noqa: BLE001 - any unusable checkpoint: set it aside, start fresh
            aside = f"{path}.corrupt"
            try:
                os.replace(path, aside)
            except OSError:
                aside = "(could not move it aside)"
            self.get_logger().error(f"checkpoint {path} unusable ({one_line(err)}); kept as {aside}, "
                                    "starting fresh")
            return OnlineValidator(self.config, diagnose=False)
        self.get_logger().info(f"resumed from checkpoint {path}")
        return validator

    def checkpoint(self) -> str | None:
        """Write the validator state to ``state_file`` now (atomically); returns the path or None."""
        path = self._param("state_file")
        if not path:
            return None
        self._flush()
        try:
            save_state(self.validator.state_dict(), path,
                       meta={"node": self.get_fully_qualified_name(), "config_file": self.config.source,
                             "saved_unix_s": time.time()})
        except (DataError, TypeError) as err:
            self._log_once(f"checkpoint:{err}", "error", f"checkpoint failed: {one_line(err)}")
            return None
        return path

    # ---------------------------------------------------------------- subscriptions
    def _resolve_types(self, config: ValidationConfig) -> dict[str, str | None]:
        """Topic -> type from the config, with classes importable and fields present (ConfigError if not)."""
        types = topic_types(config)
        topics = config.topics()
        for topic, type_name in types.items():
            if type_name is not None:
                _check_fields(topic, message_class(type_name), topics[topic])
        return types

    def _subscribe_all(self) -> None:
        for topic in list(self._subs):
            if topic not in self._types or (self._types[topic] and self._types[topic] != self._sub_types[topic]):
                self.destroy_subscription(self._subs.pop(topic))
                self._sub_types.pop(topic)
                self._raw.pop(topic, None)
        for topic, raw in self._raw.items():  # the fields may have changed (reload): new decoders
            raw.decoder = self._fast_decoder(topic, self._sub_types[topic])
            raw.verify_left = VERIFY_MESSAGES
        self._pending = {}
        for topic, type_name in self._types.items():
            if topic in self._subs:
                continue
            if type_name is None:
                self._pending[topic] = None
                self._log_once(f"discover:{topic}", "info",
                               f"topic {topic}: type not in the config, waiting for it to appear on the graph")
            else:
                self._subscribe(topic, type_name)
        if not self._pending:
            return
        self._discover()
        if self._pending and self._discovery_timer is None:
            self._discovery_timer = self.create_timer(self._param("discovery_period"), self._discover)

    def _subscribe(self, topic: str, type_name: str) -> None:
        cls = message_class(type_name)
        decoder = self._fast_decoder(topic, type_name) if self._param("raw_decoding") else None
        if decoder is None:
            self._subs[topic] = self.create_subscription(cls, topic, partial(self.on_message, topic), self._qos)
        else:
            self._raw[topic] = _RawTopic(cls, decoder)
            self._subs[topic] = self.create_subscription(cls, topic, partial(self.on_raw, topic), self._qos,
                                                         raw=True)
        self._sub_types[topic] = type_name

    def _fast_decoder(self, topic: str, type_name: str):
        """The field decoder of :mod:`gap_validation.bagio` for this topic's routes, or None."""
        try:
            from gap_validation.bagio import fast_decoder
        except ImportError:  # pragma: no cover - rosbags missing: deserialise in Python
            self._log_once("nobagio", "info", "gap_validation.bagio unavailable: messages are deserialised")
            return None
        return fast_decoder(type_name, [route.path for route in self.router.routes.get(topic, ())])

    def _discover(self) -> None:
        """Subscribe to pending topics whose type has appeared on the graph (timer callback)."""
        if not self._pending:
            return
        graph = dict(self.get_topic_names_and_types())
        for topic in list(self._pending):
            types = graph.get(topic)
            if not types:
                continue
            type_name = types[0]
            if len(types) > 1:
                self._log_once(f"types:{topic}", "warning",
                               f"topic {topic}: several types on the graph ({', '.join(types)}), using {type_name}")
            try:
                cls = message_class(type_name)
                _check_fields(topic, cls, self.config.topics()[topic])
            except ConfigError as err:
                self._log_once(f"badtype:{topic}", "error", f"topic {topic}: {err} (its samples count as bad)")
                if "not installed" in str(err):
                    continue
            self._pending.pop(topic)
            self._subscribe(topic, type_name)
            self.get_logger().info(f"topic {topic}: discovered type {type_name}, subscribed")
        if not self._pending and self._discovery_timer is not None:
            self.destroy_timer(self._discovery_timer)
            self._discovery_timer = None

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def on_raw(self, topic: str, data: bytes) -> None:
        """Callback of raw subscriptions: read the configured fields from the CDR bytes (never raises).

        The fast decoder reads only the configured fields (the one :mod:`gap_validation.replay` uses); its
        first :data:`VERIFY_MESSAGES` messages per topic are checked against rclpy's deserialisation, and any
        message it cannot read (missing joint, short array, other encoding) is deserialised and routed
        normally, so bad samples are counted the same way.
        """
        now_s = self._now_s()
        self._last_arrival[topic] = now_s
        self._diagnostics_overdue(now_s)
        raw = self._raw.get(topic)
        if raw is None:
            return
        stamp, values = None, None
        if raw.decoder is not None:
            try:
                stamp, values = raw.decoder(data)
            except Exception:  # noqa: BLE001 - FastDecodeError, struct.error: decode this one fully
                stamp, values = None, None
            if values is not None and raw.verify_left <= 0:
                if stamp is not None:
                    self._stamp_gaps(topic, stamp)
                try:
                    self.router.on_values(topic, now_s if stamp is None else stamp, values)
                except Exception as err:  # noqa: BLE001 - a message must never stop the node
                    self._log_once(f"raw:{topic}:{type(err).__name__}", "error",
                                   f"topic {topic}: message skipped ({one_line(err)})")
                return
        try:
            msg = deserialize_message(data, raw.cls)
        except Exception as err:  # noqa: BLE001 - a damaged message: counted as replay counts it
            self.router.count_bad_message(topic, "undecodable")
            self._log_once(f"raw:{topic}:{type(err).__name__}", "error",
                           f"topic {topic}: message skipped ({one_line(err)})")
            return
        if values is not None:
            raw.verify_left -= 1
            if not fast_values_agree(self.router.routes.get(topic, ()), msg, stamp, values):
                raw.decoder = None
                self._log_once(f"fast:{topic}", "info", f"topic {topic}: fast decoding disagrees with rclpy; "
                                                        "deserialising instead")
        self._route(topic, msg, now_s)

    def on_message(self, topic: str, msg: Any) -> None:
        """Subscription callback: hand the message to the router (never raises)."""
        now_s = self._now_s()
        self._last_arrival[topic] = now_s
        self._diagnostics_overdue(now_s)
        self._route(topic, msg, now_s)

    def _stamp_gaps(self, topic: str, stamp_s: float) -> None:
        gaps = self._gaps.get(topic)
        if gaps is None:
            gaps = self._gaps[topic] = StampGaps(self._param("stale_timeout"))
        gaps.add(stamp_s)

    def samples_dropped(self, topic: str) -> int:
        """Messages of ``topic`` missing from its header stamps so far (:class:`StampGaps`)."""
        gaps = self._gaps.get(topic)
        return gaps.dropped if gaps is not None else 0

    def _route(self, topic: str, msg: Any, now_s: float) -> None:
        stamp = stamp_seconds(msg)
        if stamp is not None:
            self._stamp_gaps(topic, stamp)
        try:
            self.router.on_message(topic, msg, now_s)
        except FieldError as err:  # the message type lacks a configured field: every message will fail
            for route in self.router.routes.get(topic, ()):
                self.validator.count_bad(route.channel, route.stream, err.reason)
            self._log_once(f"field:{topic}", "error", f"{one_line(err)} (check the config; counted as bad)")
        except Exception as err:  # noqa: BLE001 - a message must never stop the node
            self._log_once(f"msg:{topic}:{type(err).__name__}", "error",
                           f"topic {topic}: message skipped ({one_line(err)})")

    # ---------------------------------------------------------------- diagnostics
    def _update_seen(self, now_s: float) -> None:
        for name, channel in self.config.channels.items():
            for stream in _STREAM_TOPICS:
                key = (name, stream)
                count = self.router.samples(name, stream)
                if count > self._seen_count.get(key, 0):
                    topic = channel.signal(stream).topic
                    self._last_seen[key] = self._last_arrival.get(topic, now_s)
                self._seen_count[key] = count

    def _reasons(self, name: str, now_s: float) -> tuple[str | None, str | None, dict]:
        """(waiting reason, stale reason, age values) of one channel."""
        channel = self.config.channels[name]
        waiting, stale, ages = [], [], {}
        for stream in _STREAM_TOPICS:
            topic = channel.signal(stream).topic
            seen = self._last_seen.get((name, stream))
            if seen is None:
                pending = "; type not known yet" if topic in self._pending else ""
                waiting.append(f"{topic} ({stream}{pending})")
            else:
                age = max(0.0, now_s - seen)
                ages[f"{stream}_age_s"] = round(age, 3)
                if age > self._param("stale_timeout"):
                    stale.append((age, f"{topic} ({stream})"))
        waiting_reason = f"waiting for data on {' and '.join(waiting)}" if waiting else None
        stale_reason = None
        if stale:
            age = max(a for a, _ in stale)
            stale_reason = f"no data for {age:.1f} s on {' and '.join(t for _, t in stale)}"
        return waiting_reason, stale_reason, ages

    def statuses(self, result: ValidationResult, now_s: float | None = None) -> list[ChannelStatus]:
        """Per-channel :class:`ChannelStatus` for ``result`` at node time ``now_s``."""
        now_s = self._now_s() if now_s is None else now_s
        off = self._param("diagnosis_period") <= 0
        out = []
        for name, ch in result.channels.items():
            waiting, stale, ages = self._reasons(name, now_s)
            state = "off" if off else ("done" if name in self._top else "pending")
            topics = {self.config.channels[name].signal(stream).topic for stream in _STREAM_TOPICS}
            extra = {**ages, "samples_input": self.router.samples(name, "input"),
                     "samples_output": self.router.samples(name, "output"),
                     "samples_dropped": sum(self.samples_dropped(topic) for topic in sorted(topics))}
            out.append(channel_status(ch, warn_epsilon=self._param("warn_epsilon"),
                                      error_epsilon=self._param("error_epsilon"), stale_reason=stale,
                                      waiting_reason=waiting, candidate=self._top.get(name),
                                      diagnosis_state=state, extra_values=extra))
        return out

    def diagnostic_array(self, statuses: list[ChannelStatus]) -> "DiagnosticArray":
        """The ``DiagnosticArray`` message of ``statuses`` (levels are the DiagnosticStatus byte constants)."""
        levels = {"OK": DiagnosticStatus.OK, "WARN": DiagnosticStatus.WARN, "ERROR": DiagnosticStatus.ERROR,
                  "STALE": DiagnosticStatus.STALE}
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        hardware_id = self.hardware_id
        for status in statuses:
            array.status.append(DiagnosticStatus(
                level=levels[status.level], name=f"{NODE_NAME}: {status.channel}", message=status.message,
                hardware_id=hardware_id, values=[KeyValue(key=k, value=v) for k, v in status.values]))
        return array

    def _diagnostics_tick(self) -> None:
        """Timer callback: publish, unless a message callback just did (the timer was late, see below)."""
        period = self._param("diagnostic_period")
        if self._now_s() >= self._diag_due_s - (self.DIAGNOSTICS_LATE - 0.5) * period:
            self.publish_diagnostics()

    def _diagnostics_overdue(self, now_s: float) -> None:
        """From the message callbacks: publish when the timer is late (under a flood rclpy's EventsExecutor
        queues the timer behind every pending message, and /diagnostics would stall while the flood lasts)."""
        if now_s > self._diag_due_s:
            self.publish_diagnostics()

    def publish_diagnostics(self) -> "DiagnosticArray":
        """Flush, compute the cheap results, schedule a diagnosis, publish /diagnostics (timer callback, or a
        message callback when the timer is :attr:`DIAGNOSTICS_LATE` periods late)."""
        now_s = self._now_s()
        self._diag_due_s = now_s + self.DIAGNOSTICS_LATE * self._param("diagnostic_period")
        self._flush()
        try:
            self._update_seen(now_s)
            self._harvest_diagnosis()
            result = self.validator.results(diagnose=False)
            self._note_saturation(result)
            self.last_result = result
            self._schedule_diagnosis(result)
            array = self.diagnostic_array(self.statuses(result, now_s))
        except Exception as err:  # noqa: BLE001 - keep publishing next time
            self._log_once(f"diagnostics:{type(err).__name__}", "error", f"diagnostics failed: {one_line(err)}")
            return None
        self._diag_pub.publish(array)
        return array

    def _flush(self) -> None:
        """Push the router's pending samples to the validator; a failing batch is dropped and logged."""
        try:
            self.router.flush()
        except Exception as err:  # noqa: BLE001 - the estimator refused a batch: keep going without it
            self._log_once(f"flush:{type(err).__name__}", "error", f"samples dropped: {one_line(err)}")

    # ---------------------------------------------------------------- full diagnosis (worker thread)
    def _results_key(self, result: ValidationResult) -> tuple:
        return (self._generation,) + tuple(
            (name, ch.sweeps, ch.epsilon, ch.nu_gap, ch.points_excluded) for name, ch in result.channels.items())

    def _schedule_diagnosis(self, result: ValidationResult) -> None:
        period = self._param("diagnosis_period")
        if period <= 0 or (self._job is not None and not self._job.done()):
            return
        if not any(ch.epsilon is not None for ch in result.channels.values()):
            return
        key = self._results_key(result)
        if key == self._diagnosed_key:
            return
        sweeps_changed = self._diagnosed_key is None or key[0] != self._diagnosed_key[0] or any(
            a[1] != b[1] for a, b in zip(key[1:], self._diagnosed_key[1:]))
        if not (self._force_diagnosis or sweeps_changed or time.monotonic() - self._diagnosis_started >= period):
            return
        self._force_diagnosis = False
        self._diagnosed_key = key
        self._diagnosis_started = time.monotonic()
        state = _copy_tree(self.validator.state_dict())
        if self._worker is None:
            self._worker = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="gap_diagnosis")
        self._job = self._worker.submit(_diagnose_snapshot, self.config, state, self._generation)

    def _harvest_diagnosis(self) -> None:
        job = self._job
        if job is None or not job.done():
            return
        self._job = None
        try:
            generation, result = job.result()
        except Exception as err:  # noqa: BLE001
            self._log_once(f"diagnosis:{type(err).__name__}", "error", f"diagnosis failed: {one_line(err)}")
            return
        if generation == self._generation:
            self._take_diagnosis(result)

    def _take_diagnosis(self, result: ValidationResult) -> None:
        for name, ch in result.channels.items():
            if ch.epsilon is not None:
                self._top[name] = ch.diagnosis[0] if ch.diagnosis else None

    def wait_for_diagnosis(self, timeout_s: float = 60.0) -> bool:
        """Block until the running full diagnosis (if any) is done and take its result (tests, tools)."""
        job = self._job
        if job is None:
            return True
        try:
            concurrent.futures.wait([job], timeout=timeout_s)
        finally:
            if job.done():
                self._harvest_diagnosis()
        return job.done()

    # ---------------------------------------------------------------- model update, reset, save
    def reload(self, path: str | None = None) -> tuple[bool, str]:
        """Re-read the config (``path`` or the ``config_file`` parameter) and swap the models in.

        Returns
        -------
        (bool, str)
            Success and a one-line message (the error when the file is bad; the old config is kept then).
        """
        path = path or self._param("config_file")
        try:
            config = load_config(path)
            types = self._resolve_types(config)
        except GapValidationError as err:
            text = f"reload failed (the model of {self.config.source} stays): {one_line(err)}"
            self.get_logger().error(text)
            return False, text
        self._flush()
        try:
            restarted = self.validator.set_config(config)
        except Exception as err:  # noqa: BLE001
            text = f"reload failed (the model of {self.config.source} stays): {one_line(err)}"
            self.get_logger().error(text)
            return False, text
        self.config, self._types = config, types
        self._new_router()
        self._subscribe_all()
        self._generation += 1
        self._top.clear()
        self._force_diagnosis = True
        text = f"loaded {path}"
        if restarted:
            text += f"; spectra restarted for {', '.join(restarted)} (topics, fields or analysis settings changed)"
        self.get_logger().info(text)
        return True, text

    def _new_router(self) -> None:
        self.router = MessageRouter(self.config, self.validator)
        self._seen_count = {}

    def reset(self) -> str:
        """Forget every spectrum gathered (and the pending samples); checkpoints the empty state."""
        self.validator.reset()
        self._new_router()
        self._generation += 1
        self._top.clear()
        self._diagnosed_key = None
        self.checkpoint()
        return "spectra cleared"

    def _note_saturation(self, result: ValidationResult) -> None:
        """A swept surface pinned at an extreme: in the channel's message and bad counts; logged once."""
        for line in note_saturation(self.config, self.router, result):
            self._log_once(f"saturation:{line.split(':')[0]}", "warning", line)

    def save_results(self) -> Path:
        """Write the JSON (and report, when available) of what was gathered so far; returns the JSON path.

        Runs the full diagnosis synchronously (message callbacks wait meanwhile; the deep queue holds them).
        """
        self._flush()
        result = self.validator.results(diagnose=True)
        self._note_saturation(result)
        self._take_diagnosis(result)
        out_dir = Path(self._param("results_dir") or ".")
        try:
            out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise DataError(f"{out_dir}: cannot create results directory ({err.strerror or err})") from None
        stem = f"{self.hardware_id}_{time.strftime('%Y%m%d-%H%M%S')}"
        path, n = out_dir / f"{stem}.json", 1
        while path.exists():
            n += 1
            path = out_dir / f"{stem}_{n}.json"
        write_json(result.to_json_dict(), path)
        self._write_report(result, path.with_suffix(""))
        return path

    def _write_report(self, result: ValidationResult, target: Path) -> None:
        try:
            report = importlib.import_module("gap_validation.report")
        except ImportError:
            return
        write_report = getattr(report, "write_report", None)
        if write_report is None:
            return
        try:
            write_report(result, target)
        except Exception as err:  # noqa: BLE001 - the JSON is written; the report is a bonus
            self.get_logger().warning(f"report not written: {one_line(err)}")

    def _srv_reload(self, request, response):
        response.success, response.message = self.reload()
        return response

    def _srv_reset(self, request, response):
        response.success, response.message = True, self.reset()
        self.get_logger().info("spectra cleared (~/reset)")
        return response

    def _srv_save_results(self, request, response):
        try:
            response.message = str(self.save_results())
            response.success = True
        except Exception as err:  # noqa: BLE001
            response.success, response.message = False, f"save_results failed: {one_line(err)}"
            self.get_logger().error(response.message)
        return response

    def _on_set_parameters(self, params) -> "SetParametersResult":
        values = {p.name: p.value for p in params if p.name in PARAMETERS}
        current = {name: self._param(name) for name in ("warn_epsilon", "error_epsilon")}
        try:
            self._check_parameters({**current, **values})
        except ConfigError as err:
            return SetParametersResult(successful=False, reason=str(err))
        if "config_file" in values:
            ok, text = self.reload(values["config_file"])
            if not ok:
                return SetParametersResult(successful=False, reason=text)
        return SetParametersResult(successful=True)

    # ---------------------------------------------------------------- shutdown
    def _close_worker(self) -> None:
        worker = getattr(self, "_worker", None)
        if worker is not None:  # a running diagnosis works on its own copy: let it finish unawaited
            worker.shutdown(wait=False, cancel_futures=True)
            self._worker = None
            self._job = None

    def close(self) -> None:
        """Final checkpoint and worker shutdown (call before ``destroy_node``)."""
        self._close_worker()
        self.checkpoint()


class _RawTopic:
    """A raw subscription: message class, fast decoder (None: deserialise) and verifications left."""

    __slots__ = ("cls", "decoder", "verify_left")

    def __init__(self, cls: type, decoder):
        self.cls = cls
        self.decoder = decoder
        self.verify_left = VERIFY_MESSAGES


def _diagnose_snapshot(config: ValidationConfig, state: dict, generation: int) -> tuple[int, ValidationResult]:
    """Worker: full results (effect fitting) on a private copy of the validator."""
    return generation, OnlineValidator.from_state(config, state).results(diagnose=True)


# ============================================================================ console script
def _parser() -> argparse.ArgumentParser:
    lines = "\n".join(f"  {name:<18} {default!r:<12} {text}" for name, (default, _, text) in PARAMETERS.items())
    return argparse.ArgumentParser(
        prog="validator_node", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="ROS 2 node gap_validator: live nu-gap validation of linear aircraft models.",
        epilog="usage: validator_node --ros-args -p config_file:=/path/cfg.yaml [-p name:=value ...]\n"
               f"parameters:\n{lines}")


def _executor(node: ValidatorNode):
    """The executor the ``executor`` parameter asks for (EventsExecutor when rclpy has it)."""
    if node.get_parameter("use_sim_time").value:
        # rclpy Jazzy's EventsExecutor fires ROS-time timers wrongly when /clock drives them
        return rclpy.executors.SingleThreadedExecutor()
    if node.get_parameter("executor").value == "events":
        try:
            from rclpy.experimental import EventsExecutor

            return EventsExecutor()
        except ImportError:  # pragma: no cover - older rclpy
            node.get_logger().info("rclpy has no EventsExecutor: using the SingleThreadedExecutor")
    return rclpy.executors.SingleThreadedExecutor()


def main(args: list[str] | None = None) -> int:
    """Entry point of ``validator_node``; returns the exit status (2: bad config or parameters)."""
    if rclpy is None:  # pragma: no cover
        print(f"validator_node: error: rclpy is not available ({_ROS_IMPORT_ERROR}); source a ROS 2 setup",
              file=sys.stderr)
        return 2
    from rclpy.utilities import remove_ros_args

    argv = list(sys.argv[1:] if args is None else args)
    extra = remove_ros_args(["validator_node", *argv])[1:]
    try:
        _parser().parse_args(extra)
    except SystemExit as exit_:
        return int(exit_.code or 0)
    rclpy.init(args=["validator_node", *argv])
    try:
        node = ValidatorNode()
    except GapValidationError as err:
        print(f"validator_node: error: {one_line(err)}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    executor = _executor(node)
    executor.add_node(node)
    try:
        while rclpy.ok():  # spin_once loop: EventsExecutor.spin() of Jazzy neither runs timers nor stops
            executor.spin_once(timeout_sec=0.5)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.close()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
