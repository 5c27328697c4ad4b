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
:class:`~gap_validation.ros.topics.Topics` subscribes every topic at start-up (type from the config, else
implied by its field paths, else its publishers'), with the reliability the publishers offer (re-checked every
``discovery_period``), and keeps the subscriptions out of the executor's wait set: one timer
(``intake_period``, steady clock, so it runs before ``/clock`` does with ``use_sim_time``) drains every queue
in one wake-up (:mod:`gap_validation.ros.intake`), which costs a fraction of one executor callback per
message. A sample's time is its ``header.stamp``, else its reception time (DDS's, on the node clock).

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
``aircraft`` key, else the node's fully qualified name (fixed at start-up: a model update keeps it), filled by
the channel's :class:`~gap_validation.ros.status.ChannelTask` (levels and
values: :mod:`gap_validation.ros.status`).

Never blocking the executor
---------------------------
The cheap results are computed every tick. Full diagnoses (effect fitting) run in a worker thread on a copy of
the state (:mod:`gap_validation.ros.diagnosis_worker`); checkpoints and ``~/save_results`` (full diagnosis,
JSON, HTML report) run in another, on a snapshot
(:mod:`gap_validation.ros.jobs`, :mod:`gap_validation.ros.background`). ``~/save_results`` requests are taken
by the intake timer and answered when the files are written, so ``/diagnostics`` keeps its period.

Flying the card (issue 25)
--------------------------
``~/plan`` (std_srvs/Trigger, always) answers the test card as YAML: the ``plan_card`` file's, else the card
planned from the node's current results (in a child process, answered by the intake timer like
``~/save_results``). With ``excitation_enabled`` (off by default) the node publishes surface offsets on
``excitation_topic`` at ``excitation_rate_hz`` (zeros between manoeuvres), ``~/excite`` flies the card's
manoeuvre that ``excite_channel`` / ``excite_index`` select, ``~/abort`` stops it at once, every sample is
capped at ``excitation_max_amplitude_rad``, and each flyable channel's ``excitation`` is the node's own topic,
so what it injected comes back through its subscription into the estimator (closed-loop estimation); the
statuses gain ``excitation_enabled`` and ``excitation_manoeuvre`` (``pitch #0 12.3/60.0 s``).
:mod:`gap_validation.ros.excitation`,
:mod:`gap_validation.ros.injection`, docs/PLAN.md.

Live model update
-----------------
Setting ``config_file`` or calling ``~/reload`` (std_srvs/Trigger) re-reads the config and calls
``OnlineValidator.set_config``: the spectra already gathered are kept, and the next diagnostics show the new
epsilon with the previous one (``epsilon_previous``, "epsilon 0.12 (was 0.62)"). A bad file is refused (the
old model stays; the service answers success=False, the parameter set fails, with the one-line error).
``~/reset`` forgets the spectra; ``~/save_results`` writes the JSON (and the HTML report when
:mod:`gap_validation.report.html` is available) of what was gathered so far to ``results_dir`` and answers
with the path. Bad messages (NaN, missing joint, short arrays) are counted by the router and shown in
``bad_samples``; nothing in a message can stop the node.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from gap_validation.core.config import load_config
from gap_validation.core.errors import ConfigError, GapValidationError, one_line
from gap_validation.core.results import ValidationResult
from gap_validation.messages.router import MessageRouter, note_saturation
from gap_validation.ros.background import Background
from gap_validation.ros.collaborators import NodeServices
from gap_validation.ros.diagnosis_worker import DiagnosisWorker
from gap_validation.ros.excitation import Excitation
from gap_validation.ros.jobs import Jobs
from gap_validation.ros.message_types import topic_types
from gap_validation.ros.parameters import PARAMETERS, check_parameters, unknown_parameters
from gap_validation.ros.plots import PlotTopics
from gap_validation.ros.status import ChannelStatus, ChannelTask
from gap_validation.ros.topics import Topics

try:  # rclpy is only needed to run the node
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
    from rclpy.clock import Clock, ClockType
    from rclpy.exceptions import InvalidParameterValueException, ParameterException
    from rclpy.node import Node
    from std_srvs.srv import Trigger
    _ROS_IMPORT_ERROR: ImportError | None = None
except ImportError as _err:  # pragma: no cover - exercised only without ROS 2
    rclpy = None
    Node = object
    _ROS_IMPORT_ERROR = _err

__all__ = ["NODE_NAME", "ValidatorNode"]

#: Node name (DESIGN.md); remapping (``-r __node:=...``) renames the node and its statuses.
NODE_NAME = "gap_validator"


class ValidatorNode(Node):
    """The ``gap_validator`` node (see the module docstring for parameters, QoS, levels and services).

    Parameters
    ----------
    **kwargs
        Passed to :class:`rclpy.node.Node` (``context``, ``parameter_overrides``, ``cli_args`` ...).

    Attributes
    ----------
    config, validator, router : ValidationConfig, OnlineValidator, MessageRouter
        The running config, its validator and the router feeding it (reload and reset replace them).
    topics, jobs, excitation : Topics, Jobs, Excitation
        The components owning the subscriptions, the files and the card; they get what they need of the node
        besides its public API as :class:`~gap_validation.ros.collaborators.NodeServices`.
    plots, diagnosis_worker : PlotTopics, DiagnosisWorker
        The plottable topics and the full diagnoses' thread.

    Raises
    ------
    ConfigError
        Bad startup config or parameter (one line; ``main`` exits with status 2).
    """

    #: Diagnostics periods after the last publication when the intake timer publishes in the timer's stead.
    DIAGNOSTICS_LATE = 1.5

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
        # what the components (topics, jobs, excitation) need of the node besides its public API
        services = NodeServices(
            param=self._param,
            log_once=self._log_once,
            now_s=self._now_s,
            flush=self._flush,
            poll=self._poll,
            unpoll=self._polled.discard,
        )
        runner = Background()   # the jobs off the executor: checkpoints, saves (Jobs) and plans (Excitation)
        self.excitation = Excitation(self, services, runner)
        self.config, points = self.excitation.injection(load_config(config_file))
        self.excitation.adopt(points)
        self.topics = Topics(self, topic_types(self.config), services)
        self._hardware_id = self._default_hardware_id()
        self.jobs = Jobs(self, services, runner, self._take_saved_diagnoses, self.excitation.finish)
        self.validator = self.jobs.initial_validator()
        self.router = MessageRouter(self.config, self.validator)
        self.last_result: ValidationResult | None = None
        self._tasks: dict[str, ChannelTask] = {}     # channel -> its diagnostic task
        self._sync_tasks()
        self._generation = 0
        self.diagnosis_worker = DiagnosisWorker()
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.topics.subscribe_all()
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.plots = PlotTopics(self)
        self.create_service(Trigger, "~/reload", self._srv_reload)
        self.create_service(Trigger, "~/reset", self._srv_reset)
        self.jobs.open_service()   # ~/save_results, taken by the intake timer
        self._diag_due_s = self._now_s() + self.DIAGNOSTICS_LATE * self._param("diagnostic_period")
        self._diag_timer = self.create_timer(self._param("diagnostic_period"), self._diagnostics_tick)
        self._intake_timer = self.create_timer(
            self._param("intake_period"), self._intake_tick, clock=self._steady
        )
        self._graph_timer = self.create_timer(self._param("discovery_period"), self.topics.check_graph,
                                              clock=self._steady)
        self._ckpt_timer = None
        if self._param("state_file"):
            self._ckpt_timer = self.create_timer(self._param("checkpoint_period"),
                                              self.jobs.checkpoint_in_background)
        self.excitation.start()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.get_logger().info(
            f"validating {', '.join(self.config.channels)} from {config_file} on "
            f"{', '.join(self.router.topics)} "
            f"(QoS {self._param('qos_reliability')}, depth {self._param('qos_depth')}; statuses "
            f"'{self.get_name()}: <channel>', hardware_id {self.hardware_id})"
        )

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
                raise ConfigError(
                    f"parameter {name}: expected a number in [{low:g}, {high:g}], got {got!r}"
                ) from None
            except ParameterException as err:
                kind = (
                    type(param.default)
                    .__name__.replace("str", "string")
                    .replace("float", "double (e.g. 1.0)")
                )
                raise ConfigError(f"parameter {name}: expected a {kind} ({one_line(err)})") from None

    def _param(self, name: str) -> Any:
        return self.get_parameter(name).value

    def _poll(self, entity: Any) -> None:
        """Keep a subscription or service out of the executor's wait set (drained by the intake timer) and
        wake the executor, so it waits on its new set."""
        self._polled.add(entity)
        if self.executor is not None:
            self.executor.wake()

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
        """The ``hardware_id`` parameter, else the startup config's ``aircraft``, else the node's full
        name."""
        return self._param("hardware_id") or self._hardware_id

    @property
    def generation(self) -> int:
        """Reloads and resets so far: a diagnosis or save of an older generation is not shown."""
        return self._generation

    # ---------------------------------------------------------------- files (gap_validation.ros.jobs)
    def checkpoint(self) -> str | None:
        """Write the validator state to ``state_file`` now, in this thread (atomically); the path or None
        (:meth:`Jobs.checkpoint <gap_validation.ros.jobs.Jobs.checkpoint>`)."""
        return self.jobs.checkpoint()

    def wait_for_background(self, timeout_s: float = 60.0) -> bool:
        """Block until the background jobs (checkpoints, saves) are written and answered (tests, tools).

        Parameters
        ----------
        timeout_s : float
            Longest wait [s].
        """
        return self.jobs.wait(timeout_s)

    # ---------------------------------------------------------------- topics (gap_validation.ros.topics)
    @property
    def pending(self) -> list[str]:
        """Topics whose type is still to be discovered on the graph."""
        return self.topics.pending

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _intake_tick(self) -> None:
        """Intake timer: drain every queue, retire replaced subscriptions, serve ~/save_results, keep
        /diagnostics on time."""
        self.topics.take_all()
        self.jobs.serve_requests()
        self.excitation.serve_requests()
        self.jobs.harvest()
        self._diagnostics_overdue(self._now_s())

    def take_messages(self, topic: str, items: list, now_s: float | None = None, offset_s: float | None = None
                      ) -> None:
        """Hand messages drained from ``topic``'s queue to the decoding step and the router (never raises);
        :meth:`Topics.take_messages <gap_validation.ros.topics.Topics.take_messages>`.

        Parameters
        ----------
        topic : str
            The topic.
        items : list of (bytes or message, dict)
            ``take_message`` results, oldest first (see Topics.take_messages).
        now_s : float, optional
            Node time [s] of the drain (default: now).
        offset_s : float, optional
            Node time minus system time [s] (default: now).
        """
        self.topics.take_messages(topic, items, now_s, offset_s)

    def on_raw(self, topic: str, data: bytes) -> None:
        """One serialized message of ``topic``, as a raw subscription delivers it (tests, benchmarks): the
        decoding step replay uses, then the router (never raises); publishes overdue diagnostics.

        Parameters
        ----------
        topic : str
            The topic.
        data : bytes
            The serialized (CDR) message.
        """
        if topic not in self.topics.raw:
            return
        now_s = self._now_s()
        self.topics.take_messages(topic, [(data, {})], now_s, 0.0)
        self._diagnostics_overdue(now_s)

    def on_message(self, topic: str, msg: Any) -> None:
        """One deserialised message of ``topic`` (tests, tools): to the router (never raises); publishes
        overdue diagnostics.

        Parameters
        ----------
        topic : str
            The topic.
        msg : object
            The deserialised message.
        """
        now_s = self._now_s()
        self.topics.last_arrival[topic] = self.topics.last_taken[topic] = now_s
        self.topics.route(topic, msg, now_s)
        self._diagnostics_overdue(now_s)

    def samples_dropped(self, topic: str) -> int:
        """Messages of ``topic`` missing from its header stamps so far (:class:`StampGaps`).

        Parameters
        ----------
        topic : str
            The topic.
        """
        return self.topics.samples_dropped(topic)

    # ---------------------------------------------------------------- diagnostics
    def _update_seen(self, now_s: float) -> None:
        ended = []
        for name, task in self._tasks.items():
            task.update_seen(self.router, self.topics.last_arrival, now_s, self.topics.last_taken)
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
        """Per-channel :class:`ChannelStatus` for ``result`` at node time ``now_s``.

        Parameters
        ----------
        result : ValidationResult
            The results.
        now_s : float, optional
            Node time [s] (default: now).
        """
        now_s = self._now_s() if now_s is None else now_s
        notes = self.topics.notes()
        statuses = [self._tasks[name].run(ch, now_s, self.router, self.samples_dropped,
                                          stale_timeout_s=self._param("stale_timeout"),
                                          warn_epsilon=self._param("warn_epsilon"),
                                          error_epsilon=self._param("error_epsilon"), pending=self.pending,
                                          diagnosis_off=self._param("diagnosis_period") <= 0, notes=notes)
                    for name, ch in result.channels.items()]
        for status in statuses:           # excitation_enabled, excitation_manoeuvre (none when it is off)
            status.values.extend(self.excitation.status_values(status.channel))
        return statuses

    def status_name(self, channel: str) -> str:
        """``<node name>: <channel>``, with the node's actual (remapped) name, as diagnostic_updater names
        tasks.

        Parameters
        ----------
        channel : str
            The channel.
        """
        return f"{self.get_name()}: {channel}"

    def diagnostic_array(self, statuses: list[ChannelStatus]) -> "DiagnosticArray":
        """The ``DiagnosticArray`` message of ``statuses`` (levels are the DiagnosticStatus byte constants).

        Parameters
        ----------
        statuses : list of ChannelStatus
            From :meth:`statuses`.
        """
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
        """Flush, compute the cheap results, schedule a diagnosis, publish /diagnostics (timer callback, or
        the intake timer when the timer is :attr:`DIAGNOSTICS_LATE` periods late)."""
        now_s = self._now_s()
        self._diag_due_s = now_s + self.DIAGNOSTICS_LATE * self._param("diagnostic_period")
        self._flush()
        try:
            self._update_seen(now_s)
            self._harvest_diagnosis()
            result = self.validator.results(diagnose=False)
            self._note_saturation(result)
            self.last_result = result
            self.diagnosis_worker.schedule(
                result,
                self.validator,
                self.config,
                self._generation,
                self._param("diagnosis_period"),
                self._param("diagnosis_cpu_share"),
            )
            statuses = self.statuses(result, now_s)
            array = self.diagnostic_array(statuses)
        except Exception as err:  # noqa: BLE001 - keep publishing next time
            self._log_once(
                f"diagnostics:{type(err).__name__}", "error", f"diagnostics failed: {one_line(err)}"
            )
            return None
        self._diag_pub.publish(array)
        try:
            self.plots.publish(result, statuses)
        except Exception as err:  # noqa: BLE001 - the plots never stop the diagnostics
            self._log_once(f"plots:{type(err).__name__}", "error", f"plot topics failed: {one_line(err)}")
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
            result = self.diagnosis_worker.harvest(self._generation)
        except Exception as err:  # noqa: BLE001
            self._log_once(f"diagnosis:{type(err).__name__}", "error", f"diagnosis failed: {one_line(err)}")
            return
        if result is not None:
            self._take_diagnosis(result)

    def _take_saved_diagnoses(self, top: dict[str, Any]) -> None:
        """The channels' top candidates of a save (:class:`~gap_validation.ros.jobs.Jobs`) to their tasks."""
        for name, candidate in top.items():
            if name in self._tasks:
                self._tasks[name].take_diagnosis(candidate)

    def _take_diagnosis(self, result: ValidationResult) -> None:
        for name, ch in result.channels.items():
            if (
                ch.epsilon is not None or (ch.mimo is not None and ch.nu_gap is not None)
            ) and name in self._tasks:
                self._tasks[name].take_diagnosis(ch.diagnosis[0] if ch.diagnosis else None, ch.nonlinearity,
                                                 ch.warnings, ch.margins_caveat, ch.within_tolerance)

    def wait_for_diagnosis(self, timeout_s: float = 60.0) -> bool:
        """Block until the running full diagnosis (if any) is done and take its result (tests, tools).

        Parameters
        ----------
        timeout_s : float
            Longest wait [s].
        """
        done = self.diagnosis_worker.wait(timeout_s)
        self._harvest_diagnosis()
        return done

    # ---------------------------------------------------------------- model update, reset, save
    def reload(self, path: str | None = None) -> tuple[bool, str]:
        """Re-read the config (``path`` or the ``config_file`` parameter) and swap the models in.

        Parameters
        ----------
        path : str, optional
            The config file (default: the ``config_file`` parameter).

        Returns
        -------
        (bool, str)
            Success and a one-line message (the error when the file is bad; the old config is kept then).
        """
        path = path or self._param("config_file")
        try:
            config, points = self.excitation.injection(load_config(path))
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
        self.topics.retype(types)   # keeps what the graph taught about types
        self.config = config
        self.excitation.adopt(points)
        self._sync_tasks()
        self.plots.sync(self.config.channels)
        self._new_router()
        self.topics.subscribe_all()
        self._generation += 1
        self._forget_diagnoses()
        self.diagnosis_worker.force = True
        text = f"loaded {path}"
        if restarted:
            text += (f"; spectra restarted for {', '.join(restarted)} (topics, fields or analysis settings "
                     "changed)")
        self.get_logger().info(text)
        return True, text

    def _new_router(self) -> None:
        self.router = MessageRouter(self.config, self.validator)
        for decoding in self.topics.raw.values():   # same topics and fields: the decoding steps carry on
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
        self.diagnosis_worker.forget()
        self.jobs.checkpoint_in_background(force=True)
        return "spectra cleared"

    def _note_saturation(self, result: ValidationResult) -> None:
        """A swept surface pinned at an extreme: in the channel's message and bad counts; logged once."""
        for line in note_saturation(self.config, self.router, result):
            self._log_once(f"saturation:{line.split(':')[0]}", "warning", line)

    def save_results(self) -> Path:
        """Write the JSON (and report, when available) of what was gathered so far, and wait for it; the JSON
        path.

        The service ``~/save_results`` does the same without waiting (the executor goes on meanwhile).
        """
        return self.jobs.save_results()

    def _srv_reload(self, request, response):
        response.success, response.message = self.reload()
        return response

    def _srv_reset(self, request, response):
        response.success, response.message = True, self.reset()
        self.get_logger().info("spectra cleared (~/reset)")
        return response

    def _on_set_parameters(self, params) -> "SetParametersResult":
        values = {p.name: p.value for p in params if p.name in PARAMETERS}
        current = {name: self._param(name) for name in ("warn_epsilon", "error_epsilon")}
        try:
            check_parameters({**current, **values})
        except ConfigError as err:
            return SetParametersResult(successful=False, reason=str(err))
        if values.get("plan_card"):
            try:
                self.excitation.load_card(values["plan_card"])
            except ConfigError as err:
                return SetParametersResult(successful=False, reason=str(err))
        if "config_file" in values:
            ok, text = self.reload(values["config_file"])
            if not ok:
                return SetParametersResult(successful=False, reason=text)
        return SetParametersResult(successful=True)

    # ---------------------------------------------------------------- shutdown
    def _close_workers(self) -> None:
        worker = getattr(self, "diagnosis_worker", None)
        if worker is not None:  # a running diagnosis works on its own copy: let it finish unawaited
            worker.close()

    def close(self) -> None:
        """Finish the background writes (answering pending ``~/save_results``), write the final checkpoint and
        stop the workers (call before ``destroy_node``)."""
        if getattr(self, "excitation", None) is not None:
            self.excitation.stop()
        self._close_workers()
        if getattr(self, "jobs", None) is not None:
            self.jobs.background.wait(120.0)
            self.jobs.harvest()
            self.checkpoint()
            self.jobs.background.close(0.0)
