"""ROS 2 node ``gap_validator``: live model validation beside the flight stack.

A thin shell (docs/ARCHITECTURE.md, "one data path"): every message taken from a subscription goes to
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

Parameters, with the reasons for the QoS and intake defaults and the node's CPU cost:
:mod:`gap_validation.ros.parameters` (``config/validator.params.yaml`` lists them with their defaults).

Taking messages
---------------
Every topic is subscribed at start-up (type from the config, else implied by its field paths,
:func:`~gap_validation.ros.message_types.topic_types`; only topics whose fields imply nothing wait for the graph),
with the reliability the publishers offer (``qos_reliability: auto``: both reliable and best effort until they
are known, then theirs; re-checked every ``discovery_period``). The subscriptions are kept out of the executor's
wait set: one timer (``intake_period``, steady clock, so it runs before ``/clock`` does with ``use_sim_time``)
drains every queue in one wake-up (:mod:`gap_validation.ros.intake`), which costs a fraction of one executor
callback per message. A sample's time is its ``header.stamp``, else its reception time (DDS's, on the node clock).

Time
----
With ``ros2 bag play --clock`` and ``use_sim_time:=true`` the node sees the same samples and stamps as
``gap-validate replay`` on the bag and gives the same numbers (topics without a header, e.g.
``std_msgs/Float64``, are stamped with the reception time, which differs slightly from the bag time).
Staleness and the diagnostics and checkpoint timers use the node clock: with ``use_sim_time`` they follow
``/clock``, so nothing is published before the bag plays or while it is paused.

Diagnostics
-----------
Published every ``diagnostic_period`` by a timer; when the timer is 1.5 periods late the intake timer (or a
direct message callback) publishes instead, so ``/diagnostics`` stays on time under load. One status per
channel, named ``<node name>: <channel>`` with the node's actual name (remapped with ``-r __node:=gv2``:
``gv2: pitch``, as diagnostic_updater names its tasks), ``hardware_id`` from the parameter, else the config's
``aircraft`` key, else the node's fully qualified name (fixed at start-up: a model update keeps it), filled by the
channel's :class:`~gap_validation.ros.status.ChannelTask` (levels and values: :mod:`gap_validation.ros.status`).

Never blocking the executor
---------------------------
The cheap results are computed every tick. Full diagnoses (effect fitting) run in a worker thread on a copy of
the state (:mod:`gap_validation.ros.diagnosis_worker`); checkpoints and ``~/save_results`` (full diagnosis, JSON,
HTML report) run in another, on a snapshot (:mod:`gap_validation.ros.background`). ``~/save_results`` requests
are taken by the intake timer and answered when the files are written, so ``/diagnostics`` keeps its period.

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
from gap_validation.ros import background
from gap_validation.ros.background import Background
from gap_validation.ros.diagnosis_worker import DiagnosisWorker
from gap_validation.ros.intake import BEST_EFFORT, RELIABLE, Intake, choose_reliability, publisher_note
from gap_validation.ros.message_types import TopicType, fields_fit, message_class, topic_types
from gap_validation.ros.parameters import PARAMETERS, check_parameters, unknown_parameters
from gap_validation.ros.stamp_gaps import StampGaps
from gap_validation.ros.status import ChannelStatus, ChannelTask

try:  # rclpy is only needed to run the node
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
    from rclpy.clock import Clock, ClockType
    from rclpy.event_handler import SubscriptionEventCallbacks
    from rclpy.exceptions import InvalidParameterValueException, ParameterException
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

#: Node name (DESIGN.md); remapping (``-r __node:=...``) renames the node and its statuses.
NODE_NAME = "gap_validator"

_SOURCES = {"config": "the config's type", "fields": "implied by its fields", "graph": "its publishers' type"}


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

    #: Diagnostics periods after the last publication when the intake timer publishes in the timer's stead.
    DIAGNOSTICS_LATE = 1.5
    #: Longest a QoS change keeps the previous subscription while the new one matches [s].
    CHANGE_TIMEOUT_S = 5.0

    #: Subscriptions and services the node drains itself (kept out of the executor's wait set).
    _polled: frozenset | set = frozenset()

    def __init__(self, **kwargs):
        if rclpy is None:  # pragma: no cover
            raise ConfigError(f"rclpy is not available ({_ROS_IMPORT_ERROR})")
        super().__init__(NODE_NAME, **kwargs)
        self._polled = set()
        try:
            self._setup()
        except BaseException:
            self._close_workers()
            self.destroy_node()
            raise

    # ---------------------------------------------------------------- what the executor waits on
    @property
    def subscriptions(self):
        """The node's subscriptions the executor waits on (not those drained by the intake timer)."""
        return (s for s in super().subscriptions if s not in self._polled)

    @property
    def services(self):
        """The node's services the executor serves (not ``~/save_results``, answered by the intake timer)."""
        return (s for s in super().services if s not in self._polled)

    # ---------------------------------------------------------------- setup
    def _setup(self) -> None:
        self._logged: set[str] = set()
        self._declare_parameters()
        for line in unknown_parameters(getattr(self, "_parameter_overrides", {}), PARAMETERS):
            self.get_logger().warning(line)
        check_parameters({name: self._param(name) for name in PARAMETERS})
        config_file = self._param("config_file")
        if not config_file:
            raise ConfigError("parameter config_file is not set (ros2 run gap_validation validator_node "
                              "--ros-args -p config_file:=/path/cfg.yaml)")
        self.config = load_config(config_file)
        self._types: dict[str, TopicType] = topic_types(self.config)
        self._hardware_id = self._default_hardware_id()
        self._umask = background.umask()
        self.validator = self._initial_validator()
        self.router = MessageRouter(self.config, self.validator)
        self.last_result: ValidationResult | None = None
        self._intakes: dict[str, Intake] = {}       # topic -> its subscription(s)
        self._raw: dict[str, TopicDecoder] = {}      # topic -> decoding step of its raw subscription
        self._last_arrival: dict[str, float] = {}    # topic -> node time [s] of its last message
        self._gaps: dict[str, StampGaps] = {}        # topic -> messages missing from its stamps
        self._tasks: dict[str, ChannelTask] = {}     # channel -> its diagnostic task
        self._sync_tasks()
        self._generation = 0
        self._graph_due = False
        self._diagnosis = DiagnosisWorker()
        self._background = Background()
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._subscribe_all()
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_service(Trigger, "~/reload", self._srv_reload)
        self.create_service(Trigger, "~/reset", self._srv_reset)
        self._save_srv = self.create_service(Trigger, "~/save_results", self._srv_save_results)
        self._polled.add(self._save_srv)
        self._diag_due_s = self._now_s() + self.DIAGNOSTICS_LATE * self._param("diagnostic_period")
        self._diag_timer = self.create_timer(self._param("diagnostic_period"), self._diagnostics_tick)
        self._intake_timer = self.create_timer(self._param("intake_period"), self._intake_tick, clock=self._steady)
        self._graph_timer = self.create_timer(self._param("discovery_period"), self._check_graph,
                                              clock=self._steady)
        self._ckpt_timer = None
        if self._param("state_file"):
            self._ckpt_timer = self.create_timer(self._param("checkpoint_period"), self._checkpoint_tick)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.get_logger().info(
            f"validating {', '.join(self.config.channels)} from {config_file} on {', '.join(self.router.topics)} "
            f"(QoS {self._param('qos_reliability')}, depth {self._param('qos_depth')}; statuses "
            f"'{self.get_name()}: <channel>', hardware_id {self.hardware_id})")

    def _declare_parameters(self) -> None:
        for name, param in PARAMETERS.items():
            descriptor = ParameterDescriptor(description=param.description, read_only=param.read_only)
            if param.range is not None and isinstance(param.default, float):
                descriptor.floating_point_range = [FloatingPointRange(
                    from_value=float(param.range[0]), to_value=float(param.range[1]), step=0.0)]
            elif param.range is not None and isinstance(param.default, int):
                descriptor.integer_range = [IntegerRange(
                    from_value=int(param.range[0]), to_value=int(param.range[1]), step=1)]
            if param.choices:
                descriptor.additional_constraints = f"one of: {', '.join(param.choices)}"
            try:
                self.declare_parameter(name, param.default, descriptor)
            except InvalidParameterValueException:   # outside the descriptor's range
                got = getattr(getattr(self, "_parameter_overrides", {}).get(name), "value", None)
                low, high = param.range if param.range is not None else (None, None)
                raise ConfigError(f"parameter {name}: expected a number in [{low:g}, {high:g}], got {got!r}") \
                    from None
            except ParameterException as err:
                kind = type(param.default).__name__.replace("str", "string").replace("float", "double (e.g. 1.0)")
                raise ConfigError(f"parameter {name}: expected a {kind} ({one_line(err)})") from None

    def _param(self, name: str) -> Any:
        return self.get_parameter(name).value

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

    def _default_hardware_id(self) -> str:
        aircraft = self.config.raw.get("aircraft") if isinstance(self.config.raw, dict) else None
        return str(aircraft) if aircraft else self.get_fully_qualified_name()

    @property
    def hardware_id(self) -> str:
        """The ``hardware_id`` parameter, else the startup config's ``aircraft``, else the node's full name."""
        return self._param("hardware_id") or self._hardware_id

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

    def _checkpoint_meta(self) -> dict:
        return {"node": self.get_fully_qualified_name(), "config_file": self.config.source}

    def checkpoint(self) -> str | None:
        """Write the validator state to ``state_file`` now, in this thread (atomically); the path or None.

        The checkpoint timer writes in the background instead (:meth:`_checkpoint_tick`); this waits for those.
        """
        path = self._param("state_file")
        if not path:
            return None
        self._flush()
        self._background.wait(60.0)
        try:
            save_state(self.validator.state_dict(), path, meta={**self._checkpoint_meta(), "saved_unix_s": time.time()})
        except (DataError, TypeError) as err:
            self._log_once(f"checkpoint:{err}", "error", f"checkpoint failed: {one_line(err)}")
            return None
        background.fix_modes([Path(path)], self._umask)
        return path

    def _checkpoint_tick(self) -> None:
        """Checkpoint timer: snapshot now, write in the background (skipped while the previous one writes)."""
        self._checkpoint_in_background()

    def _checkpoint_in_background(self, force: bool = False) -> None:
        """Snapshot now, write in the background thread (after the writes before it); skipped while the previous
        checkpoint is still being written, unless ``force`` (a reset must reach the file)."""
        path = self._param("state_file")
        if not path or (self._background.busy("checkpoint") and not force):
            return
        self._flush()
        snap = background.snapshot(self.config, self.validator, None, self._generation, self._checkpoint_meta())
        self._background.submit("checkpoint", path, background.write_checkpoint, snap, path, self._umask)

    def wait_for_background(self, timeout_s: float = 60.0) -> bool:
        """Block until the background jobs (checkpoints, saves) are written and answered (tests, tools)."""
        done = self._background.wait(timeout_s)
        self._harvest_background()
        return done

    # ---------------------------------------------------------------- subscriptions
    def _subscribe_all(self) -> None:
        """Subscribe to every topic whose type is known (config or fields); drop topics no longer configured."""
        for topic in list(self._intakes):
            wanted = self._types.get(topic)
            intake = self._intakes[topic]
            if wanted is None or (wanted.name is not None and wanted.name != intake.type_name):
                self._unsubscribe(topic)
        for topic in list(self._raw):  # the fields may have changed (reload): new decoding steps
            self._raw[topic] = self._decoding(topic, self._intakes[topic].type_name)
        for topic, wanted in self._types.items():
            if topic in self._intakes:
                continue
            if wanted.name is None:
                self._log_once(f"discover:{topic}", "info", f"topic {topic}: type neither in the config nor "
                                                            "implied by its fields, waiting for it on the graph")
                continue
            self._subscribe(topic, wanted)
        self._graph_due = True

    @property
    def pending(self) -> list[str]:
        """Topics whose type is still to be discovered on the graph."""
        return [topic for topic in self._types if topic not in self._intakes]

    def _publishers_on(self, topic: str) -> list[tuple[str, str]]:
        """(type, reliability) of each publisher on ``topic``."""
        out = []
        for info in self.get_publishers_info_by_topic(self.resolve_topic_name(topic)):
            best_effort = info.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
            out.append((info.topic_type, BEST_EFFORT if best_effort else RELIABLE))
        return out

    def _create(self, topic: str, type_name: str, reliability: str) -> Any:
        """A subscription drained by the intake timer (not in the executor's wait set)."""
        decoding = self._decoding(topic, type_name) if self._param("raw_decoding") else None
        raw = decoding is not None and decoding.decoder is not None
        if raw:
            self._raw[topic] = decoding
        else:
            self._raw.pop(topic, None)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(self._param("qos_depth")),
                         reliability=ReliabilityPolicy.RELIABLE if reliability == RELIABLE
                         else ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
        # no QoS event handlers: they are waitables the executor would wait on, and rmw wakes those with every
        # message of the subscription (the SingleThreadedExecutor spun at 82 % of a core); the graph check
        # (discovery_period) sees matches and incompatible publishers instead
        events = SubscriptionEventCallbacks(use_default_callbacks=False)
        sub = self.create_subscription(message_class(type_name), topic, partial(self._on_executor_message, topic),
                                       qos, event_callbacks=events, raw=raw)
        self._polled.add(sub)
        self._wake_executor()
        return sub

    def _subscribe(self, topic: str, wanted: TopicType) -> None:
        """Subscribe now; with ``qos_reliability: auto`` and no publisher known yet, both reliable and best effort
        (:class:`~gap_validation.ros.intake.Intake`: nothing missed from the first message, nothing twice)."""
        mode = self._param("qos_reliability")
        offered = [r for t, r in self._publishers_on(topic) if t == wanted.name]
        reliability = choose_reliability(mode, offered) if offered or mode != "auto" else None
        kinds = [reliability] if reliability else [RELIABLE, BEST_EFFORT]
        subs = {kind: self._create(topic, wanted.name, kind) for kind in kinds}
        self._intakes[topic] = Intake(topic, wanted.name, wanted.source, subs, reliability)
        self.get_logger().info(f"topic {topic}: subscribed as {wanted.name} ({_SOURCES[wanted.source]}), "
                               f"{(reliability or 'reliable and best_effort until the publishers are known').upper()}")

    def _destroy(self, sub: Any) -> None:
        self._polled.discard(sub)
        self.destroy_subscription(sub)

    def _unsubscribe(self, topic: str) -> None:
        intake = self._intakes.pop(topic)
        for sub in intake.subscriptions.values():
            self._destroy(sub)
        self._raw.pop(topic, None)

    def _decoding(self, topic: str, type_name: str) -> TopicDecoder:
        """The decoding step of a raw subscription, with rclpy's deserialisation behind the fast decoder."""
        return TopicDecoder(self.router, topic, type_name,
                            partial(deserialize_message, message_type=message_class(type_name)),
                            on_disagree=self._disagree)

    def _disagree(self, topic: str) -> None:
        self._log_once(f"fast:{topic}", "info", f"topic {topic}: fast decoding disagrees with rclpy; "
                                                "deserialising instead")

    def _check_graph(self) -> None:
        """Graph check: discover pending types, follow the publishers' type and reliability, note mismatches."""
        self._graph_due = False
        mode = self._param("qos_reliability")
        for topic, wanted in self._types.items():
            try:
                publishers = self._publishers_on(topic)
            except Exception as err:  # noqa: BLE001 - the graph is best effort; try again next time
                self._log_once(f"graph:{type(err).__name__}", "warning", f"graph query failed: {one_line(err)}")
                return
            intake = self._intakes.get(topic)
            if intake is None or intake.type_source != "config":
                self._follow_type(topic, intake, publishers)
                intake = self._intakes.get(topic)
                if intake is None:
                    continue
            offered = [r for t, r in publishers if t == intake.type_name]
            want = choose_reliability(mode, offered) if offered or mode != "auto" else intake.reliability
            if want is not None and want != intake.reliability:   # (two kinds only: a new one replaces a lone one)
                self._settle(intake, want, len(offered))
            note = publisher_note(topic, mode, intake.reliability, intake.type_name, intake.type_source,
                                  publishers) if intake.reliability else None
            if note and note != intake.note:
                self._log_once(f"note:{topic}:{note}", "warning", note)
            intake.note = note

    def _follow_type(self, topic: str, intake: Intake | None, publishers: list[tuple[str, str]]) -> None:
        """Subscribe a pending topic with the publishers' type, or replace a type the fields implied wrongly."""
        types = sorted({t for t, _ in publishers})
        if not types or (intake is not None and intake.type_name in types):
            return
        type_name = types[0]
        if len(types) > 1:
            self._log_once(f"types:{topic}", "warning",
                           f"topic {topic}: several types on the graph ({', '.join(types)}), using {type_name}")
        if not fields_fit(topic, type_name, self.config.topics()[topic]):
            self._log_once(f"badtype:{topic}:{type_name}", "error",
                           f"topic {topic}: its publishers' type {type_name} is not installed or lacks a "
                           "configured field; not subscribed with it")
            return
        if intake is not None:   # the guessed type has no publisher: nothing arrives on it, replace it
            self._unsubscribe(topic)
        self._types[topic] = TopicType(type_name, "graph")
        self._subscribe(topic, self._types[topic])

    def _settle(self, intake: Intake, reliability: str, publishers: int) -> None:
        """Keep ``reliability``: its subscription (new, make before break, when the topic has none) is drained with
        the others until it has matched the publishers (:meth:`Intake.settle`)."""
        new = None if reliability in intake.subscriptions else self._create(intake.topic, intake.type_name,
                                                                            reliability)
        intake.settle(reliability, publishers, time.monotonic() + self.CHANGE_TIMEOUT_S, subscription=new)
        self.get_logger().info(f"topic {intake.topic}: publishers offer {reliability.upper()}"
                               f"{', re-subscribing' if new is not None else ''}")

    # ---------------------------------------------------------------- taking messages
    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _intake_tick(self) -> None:
        """Intake timer: drain every queue, retire replaced subscriptions, serve ~/save_results, keep
        /diagnostics on time."""
        limit = int(self._param("qos_depth"))
        now_s = self._now_s()
        offset_s = now_s - time.time_ns() * 1e-9   # DDS reception stamps (system clock) -> node clock
        for topic, intake in list(self._intakes.items()):
            retire = intake.retire_due(time.monotonic())
            try:
                got = intake.drain(limit)
            except Exception as err:  # noqa: BLE001 - a subscription destroyed under us: next time
                self._log_once(f"take:{topic}:{type(err).__name__}", "error", f"topic {topic}: {one_line(err)}")
                continue
            if retire:
                for sub in intake.retired():
                    self._destroy(sub)
            if got:
                self.take_messages(topic, got, now_s, offset_s)
        if self._graph_due:
            self._check_graph()
        self._serve_save_requests()
        self._harvest_background()
        self._diagnostics_overdue(self._now_s())

    def take_messages(self, topic: str, items: list, now_s: float | None = None, offset_s: float | None = None
                      ) -> None:
        """Hand messages drained from ``topic``'s queue to the decoding step and the router (never raises).

        Parameters
        ----------
        topic : str
            The topic.
        items : list of (bytes or message, dict)
            ``take_message`` results: serialized messages for raw subscriptions, else messages, each with its
            message info (``received_timestamp`` [ns, system clock] stamps messages without a header).
        now_s : float, optional
            Node time [s] of the drain (default: now).
        offset_s : float, optional
            Node time minus system time [s] (default: now).
        """
        now_s = self._now_s() if now_s is None else now_s
        offset_s = now_s - time.time_ns() * 1e-9 if offset_s is None else offset_s
        decoding = self._raw.get(topic)
        t_rx = now_s
        if decoding is None:
            for msg, info in items:
                rx = info.get("received_timestamp")
                t_rx = min(now_s, rx * 1e-9 + offset_s) if rx else now_s
                self._route(topic, msg, t_rx)
        else:
            decode, gaps, on_values = decoding.decode, self._gaps_of(topic), self.router.on_values
            for data, info in items:
                rx = info.get("received_timestamp")
                t_rx = min(now_s, rx * 1e-9 + offset_s) if rx else now_s
                try:
                    stamp, values, msg = decode(data)
                except Undecodable as err:  # a damaged message: counted as replay counts it
                    self._log_once(f"raw:{topic}:{type(err.error).__name__}", "error",
                                   f"topic {topic}: message skipped ({one_line(err.error)})")
                    continue
                if msg is not None:
                    self._route(topic, msg, t_rx)
                    continue
                if stamp is not None:
                    gaps.add(stamp)
                try:
                    on_values(topic, t_rx if stamp is None else stamp, values)
                except Exception as err:  # noqa: BLE001 - a message must never stop the node
                    self._log_once(f"raw:{topic}:{type(err).__name__}", "error",
                                   f"topic {topic}: message skipped ({one_line(err)})")
        self._last_arrival[topic] = t_rx

    def _on_executor_message(self, topic: str, msg: Any) -> None:
        """Subscription callback, should an executor still hand a message over (before it saw the subscription
        leave its wait set): taken like a drained one."""
        self.take_messages(topic, [(msg, {})])

    def on_raw(self, topic: str, data: bytes) -> None:
        """One serialized message of ``topic``, as a raw subscription delivers it (tests, benchmarks): the
        decoding step replay uses, then the router (never raises); publishes overdue diagnostics.

        :meth:`TopicDecoder.decode <gap_validation.messages.decoding.TopicDecoder.decode>` reads only the
        configured fields, checks its first messages per topic against rclpy's deserialisation, and
        deserialises any message it cannot read (missing joint, short array, other encoding), which is then
        routed normally, so bad samples are counted the same way; an undecodable message is counted.
        """
        if topic not in self._raw:
            return
        now_s = self._now_s()
        self.take_messages(topic, [(data, {})], now_s, 0.0)
        self._diagnostics_overdue(now_s)

    def on_message(self, topic: str, msg: Any) -> None:
        """One deserialised message of ``topic`` (tests, tools): to the router (never raises); publishes
        overdue diagnostics."""
        now_s = self._now_s()
        self._last_arrival[topic] = now_s
        self._route(topic, msg, now_s)
        self._diagnostics_overdue(now_s)

    def _gaps_of(self, topic: str) -> StampGaps:
        gaps = self._gaps.get(topic)
        if gaps is None:
            gaps = self._gaps[topic] = StampGaps(self._param("stale_timeout"))
        return gaps

    def samples_dropped(self, topic: str) -> int:
        """Messages of ``topic`` missing from its header stamps so far (:class:`StampGaps`)."""
        gaps = self._gaps.get(topic)
        return gaps.dropped if gaps is not None else 0

    def _route(self, topic: str, msg: Any, now_s: float) -> None:
        stamp = stamp_seconds(msg)
        if stamp is not None:
            self._gaps_of(topic).add(stamp)
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
        ended = []
        for name, task in self._tasks.items():
            task.update_seen(self.router, self._last_arrival, now_s)
            if task.run_ended(now_s, self._param("end_of_data_timeout")):
                ended.append(name)
        if ended:       # inputs silent for end_of_data_timeout: close the last manoeuvre of the flight
            self.validator.finish(ended)

    def _sync_tasks(self) -> None:
        """One :class:`ChannelTask` per channel of the config (kept by name across reloads)."""
        self._tasks = {name: self._tasks.get(name) or ChannelTask(name, channel)
                       for name, channel in self.config.channels.items()}
        for name, channel in self.config.channels.items():
            self._tasks[name].channel = channel

    def statuses(self, result: ValidationResult, now_s: float | None = None) -> list[ChannelStatus]:
        """Per-channel :class:`ChannelStatus` for ``result`` at node time ``now_s``."""
        now_s = self._now_s() if now_s is None else now_s
        notes = {topic: intake.note for topic, intake in self._intakes.items() if intake.note}
        return [self._tasks[name].run(ch, now_s, self.router, self.samples_dropped,
                                      stale_timeout_s=self._param("stale_timeout"),
                                      warn_epsilon=self._param("warn_epsilon"),
                                      error_epsilon=self._param("error_epsilon"), pending=self.pending,
                                      diagnosis_off=self._param("diagnosis_period") <= 0, notes=notes)
                for name, ch in result.channels.items()]

    def status_name(self, channel: str) -> str:
        """``<node name>: <channel>``, with the node's actual (remapped) name, as diagnostic_updater names tasks."""
        return f"{self.get_name()}: {channel}"

    def diagnostic_array(self, statuses: list[ChannelStatus]) -> "DiagnosticArray":
        """The ``DiagnosticArray`` message of ``statuses`` (levels are the DiagnosticStatus byte constants)."""
        levels = {"OK": DiagnosticStatus.OK, "WARN": DiagnosticStatus.WARN, "ERROR": DiagnosticStatus.ERROR,
                  "STALE": DiagnosticStatus.STALE}
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        hardware_id = self.hardware_id
        for status in statuses:
            array.status.append(DiagnosticStatus(
                level=levels[status.level], name=self.status_name(status.channel), message=status.message,
                hardware_id=hardware_id, values=[KeyValue(key=k, value=v) for k, v in status.values]))
        return array

    def _diagnostics_tick(self) -> None:
        """Timer callback: publish, unless the intake timer just did (the timer was late, see below)."""
        period = self._param("diagnostic_period")
        if self._now_s() >= self._diag_due_s - (self.DIAGNOSTICS_LATE - 0.5) * period:
            self.publish_diagnostics()

    def _diagnostics_overdue(self, now_s: float) -> None:
        """From the intake timer and message callbacks: publish when the diagnostics timer is late."""
        if now_s > self._diag_due_s:
            self.publish_diagnostics()

    def publish_diagnostics(self) -> "DiagnosticArray":
        """Flush, compute the cheap results, schedule a diagnosis, publish /diagnostics (timer callback, or the
        intake timer when the timer is :attr:`DIAGNOSTICS_LATE` periods late)."""
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
            if (ch.epsilon is not None or (ch.mimo is not None and ch.nu_gap is not None)) and name in self._tasks:
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
            types = topic_types(config)
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
        for topic, intake in self._intakes.items():   # keep what the graph taught about types
            if topic in types and types[topic].source != "config" and intake.type_source == "graph":
                types[topic] = TopicType(intake.type_name, "graph")
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
        """Forget every spectrum gathered (and the pending samples); checkpoints the empty state (in the
        background)."""
        self.validator.reset()
        self._new_router()
        self._generation += 1
        self._forget_diagnoses()
        self._diagnosis.forget()
        self._checkpoint_in_background(force=True)
        return "spectra cleared"

    def _note_saturation(self, result: ValidationResult) -> None:
        """A swept surface pinned at an extreme: in the channel's message and bad counts; logged once."""
        for line in note_saturation(self.config, self.router, result):
            self._log_once(f"saturation:{line.split(':')[0]}", "warning", line)

    def save_results_in_background(self, tag: Any = None) -> None:
        """Snapshot now; the full diagnosis, JSON and report are written by the background thread (the answer to
        ``~/save_results`` is sent when they are, :meth:`_harvest_background`)."""
        self._flush()
        snap = background.snapshot(self.config, self.validator, self.router, self._generation)
        out_dir = Path(self._param("results_dir") or ".").resolve()
        self._background.submit("save_results", tag, background.save_results, snap, out_dir,
                                background.file_stem(self.hardware_id), self._umask, process=True)

    def save_results(self) -> Path:
        """Write the JSON (and report, when available) of what was gathered so far, and wait for it; the JSON path.

        The service ``~/save_results`` does the same without waiting (the executor goes on meanwhile).
        """
        self.save_results_in_background(tag=None)
        self._background.wait(600.0)
        path = None
        for kind, future, tag in self._background.harvest():
            outcome = self._finish_job(kind, future, tag)
            if kind == "save_results" and tag is None:
                path = outcome
        if isinstance(path, BaseException):
            raise path
        return path

    def _finish_job(self, kind: str, future: Any, tag: Any) -> Any:
        """A finished background job: log a failure, take a save's diagnosis, answer its request."""
        try:
            outcome = future.result()
        except Exception as err:  # noqa: BLE001 - reported, never raised into the executor
            self._log_once(f"{kind}:{one_line(err)}", "error", f"{kind} failed: {one_line(err)}")
            outcome = err
        if kind == "save_results":
            if not isinstance(outcome, BaseException):
                for line in outcome.warnings:
                    self.get_logger().warning(one_line(line))
                if outcome.generation == self._generation:   # no reload or reset since the snapshot
                    for name, top in outcome.top.items():
                        if name in self._tasks:
                            self._tasks[name].take_diagnosis(top)
                outcome = outcome.path
            if tag is not None:
                response = Trigger.Response()
                if isinstance(outcome, BaseException):
                    response.success, response.message = False, f"save_results failed: {one_line(outcome)}"
                else:
                    response.success, response.message = True, str(outcome)
                try:
                    self._save_srv.send_response(response, tag)
                except Exception as err:  # noqa: BLE001 - the client left
                    self._log_once(f"respond:{type(err).__name__}", "warning",
                                   f"~/save_results: could not answer ({one_line(err)})")
        return outcome

    def _harvest_background(self) -> None:
        for kind, future, tag in self._background.harvest():
            self._finish_job(kind, future, tag)

    def _serve_save_requests(self) -> None:
        """Take ``~/save_results`` requests (the service is drained here, not by the executor)."""
        srv = self._save_srv
        while True:
            with srv.handle:
                request, header = srv.handle.service_take_request(srv.srv_type.Request)
            if header is None:
                return
            self.save_results_in_background(tag=header)

    def _srv_reload(self, request, response):
        response.success, response.message = self.reload()
        return response

    def _srv_reset(self, request, response):
        response.success, response.message = True, self.reset()
        self.get_logger().info("spectra cleared (~/reset)")
        return response

    def _srv_save_results(self, request, response):
        """Callback of ``~/save_results`` should an executor serve it (the intake timer normally takes the
        requests): waits for the files."""
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
    def _close_workers(self) -> None:
        worker = getattr(self, "_diagnosis", None)
        if worker is not None:  # a running diagnosis works on its own copy: let it finish unawaited
            worker.close()

    def close(self) -> None:
        """Finish the background writes (answering pending ``~/save_results``), write the final checkpoint and
        stop the workers (call before ``destroy_node``)."""
        self._close_workers()
        if getattr(self, "_background", None) is not None:
            self._background.wait(120.0)
            self._harvest_background()
            self.checkpoint()
            self._background.close(0.0)
