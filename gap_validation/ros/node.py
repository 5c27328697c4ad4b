"""ROS 2 node ``gap_validator``: live model validation beside the flight stack.

A thin shell (docs/ARCHITECTURE.md, "one data path"): every subscribed message goes to
:class:`gap_validation.messages.router.MessageRouter`, exactly as :mod:`gap_validation.bag.replay` feeds a bag
(serialized messages through the same decoding step, :class:`gap_validation.messages.decoding.TopicDecoder`,
with rclpy's ``deserialize_message`` as the full deserialisation; other subscriptions deserialised by rclpy),
and the router feeds :class:`gap_validation.core.validator.OnlineValidator`. The node owns no estimation,
metrics or status wording (:mod:`gap_validation.ros.status`); it wires topics, timers, parameters and services
to the validator and publishes its channels' statuses as ``diagnostic_msgs/msg/DiagnosticArray`` on
``/diagnostics``. Importing it imports rclpy, never rosbags.

Run::

    ros2 run gap_validation validator_node --ros-args -p config_file:=/path/cfg.yaml
    ros2 launch gap_validation validator.launch.py config_file:=/path/cfg.yaml
    validator_node --ros-args -p config_file:=/path/cfg.yaml        # pip install, no colcon

Parameters, with the reasons for the QoS and executor defaults and the node's CPU cost:
:mod:`gap_validation.ros.parameters` (``config/validator.params.yaml`` lists them with their defaults).

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
``gap_validator: <channel>``, filled by the channel's :class:`~gap_validation.ros.status.ChannelTask` (levels
STALE / WARN / ERROR / OK and the values: :mod:`gap_validation.ros.status`).

The cheap results are computed every tick; full diagnoses (effect fitting) run in a worker thread
(:mod:`gap_validation.ros.diagnosis_worker`), and the last top candidate is kept for the message.

Live model update
-----------------
Setting ``config_file`` or calling ``~/reload`` (std_srvs/Trigger) re-reads the config and calls
``OnlineValidator.set_config``: the spectra already gathered are kept, and the next diagnostics show the new
epsilon with the previous one (``epsilon_previous``, "epsilon 0.12 (was 0.62)"). A bad file is refused (the
old model stays; the service answers success=False, the parameter set fails, with the one-line error).
``~/reset`` forgets the spectra; ``~/save_results`` writes the JSON (and the HTML report when
:mod:`gap_validation.report.html` is available) of what was gathered so far to ``results_dir`` and answers with
the path. Bad messages (NaN, missing joint, short arrays) are counted by the router and shown in
``bad_samples``; nothing in a message can stop the node.
"""
from __future__ import annotations

import os
import time
from functools import partial
from pathlib import Path
from typing import Any

from gap_validation.config import load_config
from gap_validation.core.checkpoint import load_state, save_state
from gap_validation.core.errors import ConfigError, DataError, GapValidationError, one_line
from gap_validation.core.fields import FieldError
from gap_validation.core.results import ValidationResult
from gap_validation.core.validator import OnlineValidator
from gap_validation.messages.decoding import TopicDecoder, Undecodable
from gap_validation.messages.router import MessageRouter, note_saturation, stamp_seconds
from gap_validation.report.terminal import write_json
from gap_validation.ros.diagnosis_worker import DiagnosisWorker
from gap_validation.ros.message_types import check_fields, message_class, resolve_types
from gap_validation.ros.parameters import PARAMETERS, check_parameters
from gap_validation.ros.stamp_gaps import StampGaps
from gap_validation.ros.status import ChannelStatus, ChannelTask

try:  # rclpy is only needed to run the node
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
    from rclpy.exceptions import ParameterException
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import deserialize_message
    from std_srvs.srv import Trigger
    _ROS_IMPORT_ERROR: ImportError | None = None
except ImportError as _err:  # pragma: no cover - exercised only without ROS 2
    rclpy = None
    Node = object
    _ROS_IMPORT_ERROR = _err

__all__ = ["NODE_NAME", "ValidatorNode"]

#: Node name (DESIGN.md).
NODE_NAME = "gap_validator"


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
        check_parameters({name: self.get_parameter(name).value for name in PARAMETERS})
        config_file = self.get_parameter("config_file").value
        if not config_file:
            raise ConfigError("parameter config_file is not set (ros2 run gap_validation validator_node "
                              "--ros-args -p config_file:=/path/cfg.yaml)")
        self.config = load_config(config_file)
        self._types = resolve_types(self.config)
        self.validator = self._initial_validator()
        self.router = MessageRouter(self.config, self.validator)
        self.last_result: ValidationResult | None = None
        self._subs: dict[str, Any] = {}              # topic -> subscription
        self._sub_types: dict[str, str] = {}         # topic -> type subscribed with
        self._raw: dict[str, TopicDecoder] = {}      # topic -> decoding step of its raw subscription
        self._pending: dict[str, None] = {}          # topics whose type is still to be discovered
        self._last_arrival: dict[str, float] = {}    # topic -> node time [s] of its last message
        self._gaps: dict[str, StampGaps] = {}        # topic -> messages missing from its stamps
        self._tasks: dict[str, ChannelTask] = {}     # channel -> its diagnostic task
        self._sync_tasks()
        self._generation = 0
        self._diagnosis = DiagnosisWorker()
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
    def _subscribe_all(self) -> None:
        for topic in list(self._subs):
            if topic not in self._types or (self._types[topic] and self._types[topic] != self._sub_types[topic]):
                self.destroy_subscription(self._subs.pop(topic))
                self._sub_types.pop(topic)
                self._raw.pop(topic, None)
        for topic in self._raw:  # the fields may have changed (reload): new decoding steps
            self._raw[topic] = self._decoding(topic, self._sub_types[topic])
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
        decoding = self._decoding(topic, type_name) if self._param("raw_decoding") else None
        if decoding is None or decoding.decoder is None:
            self._subs[topic] = self.create_subscription(cls, topic, partial(self.on_message, topic), self._qos)
        else:
            self._raw[topic] = decoding
            self._subs[topic] = self.create_subscription(cls, topic, partial(self.on_raw, topic), self._qos,
                                                         raw=True)
        self._sub_types[topic] = type_name

    def _decoding(self, topic: str, type_name: str) -> TopicDecoder:
        """The decoding step of a raw subscription, with rclpy's deserialisation behind the fast decoder."""
        return TopicDecoder(self.router, topic, type_name,
                            partial(deserialize_message, message_type=message_class(type_name)),
                            on_disagree=self._disagree)

    def _disagree(self, topic: str) -> None:
        self._log_once(f"fast:{topic}", "info", f"topic {topic}: fast decoding disagrees with rclpy; "
                                                "deserialising instead")

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
                check_fields(topic, cls, self.config.topics()[topic])
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
        """Callback of raw subscriptions: the decoding step replay uses, then the router (never raises).

        :meth:`TopicDecoder.decode <gap_validation.messages.decoding.TopicDecoder.decode>` reads only the
        configured fields, checks its first messages per topic against rclpy's deserialisation, and
        deserialises any message it cannot read (missing joint, short array, other encoding), which is then
        routed normally, so bad samples are counted the same way; an undecodable message is counted.
        """
        now_s = self._arrived(topic)
        decoding = self._raw.get(topic)
        if decoding is None:
            return
        try:
            stamp, values, msg = decoding.decode(data)
        except Undecodable as err:  # a damaged message: counted as replay counts it
            self._log_once(f"raw:{topic}:{type(err.error).__name__}", "error",
                           f"topic {topic}: message skipped ({one_line(err.error)})")
            return
        if msg is not None:
            self._route(topic, msg, now_s)
            return
        if stamp is not None:
            self._stamp_gaps(topic, stamp)
        try:
            self.router.on_values(topic, now_s if stamp is None else stamp, values)
        except Exception as err:  # noqa: BLE001 - a message must never stop the node
            self._log_once(f"raw:{topic}:{type(err).__name__}", "error",
                           f"topic {topic}: message skipped ({one_line(err)})")

    def on_message(self, topic: str, msg: Any) -> None:
        """Subscription callback: hand the message to the router (never raises)."""
        self._route(topic, msg, self._arrived(topic))

    def _arrived(self, topic: str) -> float:
        """Note a message's arrival on ``topic``; publish overdue diagnostics; return the node time [s]."""
        now_s = self._now_s()
        self._last_arrival[topic] = now_s
        self._diagnostics_overdue(now_s)
        return now_s

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
        for task in self._tasks.values():
            task.update_seen(self.router, self._last_arrival, now_s)

    def _sync_tasks(self) -> None:
        """One :class:`ChannelTask` per channel of the config (kept by name across reloads)."""
        self._tasks = {name: self._tasks.get(name) or ChannelTask(name, channel)
                       for name, channel in self.config.channels.items()}
        for name, channel in self.config.channels.items():
            self._tasks[name].channel = channel

    def statuses(self, result: ValidationResult, now_s: float | None = None) -> list[ChannelStatus]:
        """Per-channel :class:`ChannelStatus` for ``result`` at node time ``now_s``."""
        now_s = self._now_s() if now_s is None else now_s
        return [self._tasks[name].run(ch, now_s, self.router, self.samples_dropped,
                                      stale_timeout_s=self._param("stale_timeout"),
                                      warn_epsilon=self._param("warn_epsilon"),
                                      error_epsilon=self._param("error_epsilon"), pending=self._pending,
                                      diagnosis_off=self._param("diagnosis_period") <= 0)
                for name, ch in result.channels.items()]

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
            self._diagnosis.schedule(result, self.validator, self.config, self._generation,
                                     self._param("diagnosis_period"))
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
    def _harvest_diagnosis(self) -> None:
        try:
            result = self._diagnosis.harvest(self._generation)
        except Exception as err:  # noqa: BLE001
            self._log_once(f"diagnosis:{type(err).__name__}", "error", f"diagnosis failed: {one_line(err)}")
            return
        if result is not None:
            self._take_diagnosis(result)

    def _take_diagnosis(self, result: ValidationResult) -> None:
        for name, ch in result.channels.items():
            if ch.epsilon is not None and name in self._tasks:
                self._tasks[name].take_diagnosis(ch.diagnosis[0] if ch.diagnosis else None)

    def wait_for_diagnosis(self, timeout_s: float = 60.0) -> bool:
        """Block until the running full diagnosis (if any) is done and take its result (tests, tools)."""
        done = self._diagnosis.wait(timeout_s)
        self._harvest_diagnosis()
        return done

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
            types = resolve_types(config)
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
        self._sync_tasks()
        self._new_router()
        self._subscribe_all()
        self._generation += 1
        self._forget_diagnoses()
        self._diagnosis.force = True
        text = f"loaded {path}"
        if restarted:
            text += f"; spectra restarted for {', '.join(restarted)} (topics, fields or analysis settings changed)"
        self.get_logger().info(text)
        return True, text

    def _new_router(self) -> None:
        self.router = MessageRouter(self.config, self.validator)
        for decoding in self._raw.values():   # same topics and fields: the decoding steps carry on
            decoding.router = self.router
        for task in self._tasks.values():
            task.new_router()

    def _forget_diagnoses(self) -> None:
        for task in self._tasks.values():
            task.forget_diagnosis()

    def reset(self) -> str:
        """Forget every spectrum gathered (and the pending samples); checkpoints the empty state."""
        self.validator.reset()
        self._new_router()
        self._generation += 1
        self._forget_diagnoses()
        self._diagnosis.forget()
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
            from gap_validation.report.html import write_report
        except ImportError:  # no matplotlib: the JSON is written, the report is a bonus
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
            check_parameters({**current, **values})
        except ConfigError as err:
            return SetParametersResult(successful=False, reason=str(err))
        if "config_file" in values:
            ok, text = self.reload(values["config_file"])
            if not ok:
                return SetParametersResult(successful=False, reason=text)
        return SetParametersResult(successful=True)

    # ---------------------------------------------------------------- shutdown
    def _close_worker(self) -> None:
        worker = getattr(self, "_diagnosis", None)
        if worker is not None:  # a running diagnosis works on its own copy: let it finish unawaited
            worker.close()

    def close(self) -> None:
        """Final checkpoint and worker shutdown (call before ``destroy_node``)."""
        self._close_worker()
        self.checkpoint()
