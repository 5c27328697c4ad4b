"""The node's test card and its injection (issue 25): ``~/plan``, ``~/excite`` and ``~/abort`` (rclpy).

:class:`Excitation` is the part of :class:`gap_validation.ros.node.ValidatorNode` that holds the card and
flies it, as a component holding a reference to the node (its public rclpy API, clock and logger, and its
``config``, ``validator``, ``router`` and ``generation``), the services the node lends it (parameters,
log-once, flush, the executor's wait set: :class:`~gap_validation.ros.collaborators.NodeServices`) and the
node's background jobs:

* ``~/plan`` (std_srvs/Trigger, always there): the current card as YAML in ``message``, the document
  ``gap-validate plan --out`` writes (:func:`gap_validation.cards.card_yaml`). With the parameter
  ``plan_card`` the card of that file (re-read); without, the card planned from the node's current results:
  the JSON ``~/save_results`` would write, planned as ``gap-validate plan`` plans that file, in a child
  process (:func:`gap_validation.ros.background.plan_from_results`; taken and answered by the intake timer,
  like ``~/save_results``, so the executor never waits). The card answered is the one ``~/excite`` flies.
* With ``excitation_enabled``: a timer at ``excitation_rate_hz`` on the node clock publishes the surface
  offsets (:class:`~gap_validation.ros.injection.Player`: zeros, or the manoeuvre's samples, each clipped to
  ``excitation_max_amplitude_rad``), ``~/excite`` (Trigger) starts the manoeuvre the parameters
  ``excite_channel`` and ``excite_index`` select (:func:`~gap_validation.ros.injection.select_manoeuvre`) and
  ``~/abort`` (Trigger) stops it at once. The config the node runs has each flyable channel's ``excitation``
  on the node's own topic (:func:`~gap_validation.ros.injection.with_injection`): the samples come back
  through the subscription like any stream.

Importing it imports rclpy (when available), never rosbags.
"""
from __future__ import annotations

from typing import Any

from gap_validation.cards import card_yaml, read_card
from gap_validation.core.config import ValidationConfig
from gap_validation.core.errors import ConfigError, one_line
from gap_validation.core.plan import TestCard
from gap_validation.ros import background
from gap_validation.ros.background import Background
from gap_validation.ros.collaborators import NodeServices
from gap_validation.ros.injection import (
    JOINT_STATE,
    InjectionPoint,
    Player,
    Sample,
    injection_points,
    select_manoeuvre,
    with_injection,
)
from gap_validation.ros.message_types import message_class

try:  # rclpy is only needed to run the node
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from std_srvs.srv import Trigger
except ImportError:  # pragma: no cover - exercised only without ROS 2
    pass

__all__ = ["Excitation", "PUBLISHER_DEPTH"]

#: KEEP_LAST depth of the offsets' publishers (RELIABLE, VOLATILE): 2 s at 50 Hz.
PUBLISHER_DEPTH = 100


class Excitation:
    """A node's card, ``~/plan``, and (``excitation_enabled``) the injection of the card's manoeuvres.

    Parameters
    ----------
    node : rclpy.node.Node
        The node: its publishers, timer, services, clock and logger, and its ``config``, ``validator``,
        ``router`` and ``generation`` (read when needed: they change on reload and reset).
    services : NodeServices
        The node's parameters (``excitation_*``, ``excite_*``, ``plan_card``, ``config_file``), log-once,
        flush, and the executor's wait set (``~/plan`` is kept out of it, :attr:`NodeServices.poll`).
    runner : Background
        The node's jobs off the executor (a ``~/plan`` without ``plan_card`` is planned there; the node's
        :class:`~gap_validation.ros.jobs.Jobs` harvests it and calls :meth:`finish`).

    Attributes
    ----------
    enabled : bool
        ``excitation_enabled``.
    card : TestCard or None
        The current card (``plan_card``'s, or the last ``~/plan`` answered).
    flown : set of int
        Indices of the current card flown to their end.
    points : dict
        Channel -> :class:`~gap_validation.ros.injection.InjectionPoint` (enabled only).
    player : Player or None
        The sample grid and the manoeuvre on it (enabled only).
    topic : str or None
        ``excitation_topic``, resolved.

    Raises
    ------
    ConfigError
        A bad ``plan_card`` file or ``excitation_topic`` (one line; the node does not start).
    """

    def __init__(self, node: Any, services: NodeServices, runner: Background):
        self.node = node
        self.services = services
        self.runner = runner
        param = services.param
        self.enabled = bool(param("excitation_enabled"))
        self.type_name = str(param("excitation_type"))
        self.card: TestCard | None = None
        self._origin: tuple[str | None, str | None] = (None, None)
        self.flown: set[int] = set()
        self.points: dict[str, InjectionPoint] = {}
        self.player: Player | None = None
        self.topic: str | None = None
        self._pubs: dict[str, Any] = {}
        self._joints: list[str] = []
        self._noted: Any = None
        if param("plan_card"):
            self.load_card(param("plan_card"))
        if self.enabled:
            self.topic = self._resolve(param("excitation_topic"), "excitation_topic")
            self.player = Player(float(param("excitation_rate_hz")))
        self._plan_srv = node.create_service(Trigger, "~/plan", self._srv_plan)
        services.poll(self._plan_srv)

    # ---------------------------------------------------------------- the card
    def load_card(self, path: str) -> TestCard:
        """Read the card of ``path`` (``plan_card``) and make it the current card; ConfigError (one line) when
        bad.

        Parameters
        ----------
        path : str
            A card file of ``gap-validate plan --out``.
        """
        card, results, config = read_card(path)
        self._take_card(card, results, config)
        return card

    def _take_card(self, card: TestCard, results: str | None, config: str | None) -> None:
        if self.card is None or card.to_dict() != self.card.to_dict():
            self.flown = set()
        self.card, self._origin = card, (results, config)

    def card_text(self) -> str:
        """The current card as ``gap-validate plan --out`` writes it ("" without one)."""
        return "" if self.card is None else card_yaml(self.card, *self._origin)

    # ---------------------------------------------------------------- config
    def _resolve(self, topic: str, what: str) -> str:
        try:
            return self.node.resolve_topic_name(topic)
        except Exception as err:  # noqa: BLE001 - rclpy's name errors: one line
            raise ConfigError(
                f"parameter {what}: {topic!r} is not a valid topic name ({one_line(err)})"
            ) from None

    def injection(self, config: ValidationConfig) -> tuple[ValidationConfig, dict[str, InjectionPoint]]:
        """The config the node runs (each flyable channel's ``excitation`` on the node's topic) and the
        injection points; ``config`` itself when excitation is off. Nothing changes until :meth:`adopt`.

        Parameters
        ----------
        config : ValidationConfig
            The config as loaded.

        Raises
        ------
        ConfigError
            A channel name that makes no topic name (Float64: ``<excitation_topic>/<channel>``).
        """
        if not self.enabled:
            return config, {}
        points = injection_points(config, self.topic, self.type_name)
        for point in points.values():
            self._resolve(point.topic, f"excitation_topic (channel {point.channel})")
        return with_injection(config, points), points

    def adopt(self, points: dict[str, InjectionPoint]) -> None:
        """Publish to ``points`` from now on (publishers made or dropped; a manoeuvre of a channel that left
        the config is aborted).

        Parameters
        ----------
        points : dict
            From :meth:`injection`.
        """
        if not self.enabled:
            return
        flying = self.player.flying
        if flying is not None and flying.manoeuvre.channel not in points:
            self.player.abort("its channel left the config")
        self.points = points
        wanted = {p.topic for p in points.values()}
        for topic in set(self._pubs) - wanted:
            self.node.destroy_publisher(self._pubs.pop(topic))
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=PUBLISHER_DEPTH,
                         reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
        for topic in sorted(wanted - set(self._pubs)):
            self._pubs[topic] = self.node.create_publisher(message_class(self.type_name), topic, qos)
        self._joints = list(dict.fromkeys(p.joint for p in points.values() if p.joint is not None))

    def start(self) -> None:
        """The timer and ``~/excite``, ``~/abort`` (excitation enabled only; after the node's setup)."""
        if not self.enabled:
            return
        node = self.node
        # node clock: follows /clock
        self._timer = node.create_timer(1.0 / self.player.rate_hz, self.tick)
        node.create_service(Trigger, "~/excite", self._srv_excite)
        node.create_service(Trigger, "~/abort", self._srv_abort)
        flown = ", ".join(
            f"{p.channel} ({p.spec.field})" if p.joint else p.channel for p in self.points.values()
        )
        own = [p.channel for p in self.points.values() if not p.estimated]
        cap = self.services.param("excitation_max_amplitude_rad")
        node.get_logger().info(
            f"excitation enabled: {self.type_name} on {self.topic}"
            f"{'/<channel>' if self.type_name != JOINT_STATE else ''} at {self.player.rate_hz:g} Hz, "
            f"cap {cap:g} rad; flyable: {flown or 'none'}; these estimate against what the node injects "
            "(their excitation)"
            + (f", except {', '.join(own)} (the config's own excitation)" if own else ""))

    # ---------------------------------------------------------------- the samples
    def tick(self) -> None:
        """Timer: publish every sample due (never raises)."""
        try:
            now_ns = self.node.get_clock().now().nanoseconds
            if now_ns <= 0:        # use_sim_time before the first /clock: no time yet
                return
            for sample in self.player.due(now_ns, float(self.services.param("excitation_max_amplitude_rad"))):
                self._publish(sample)
            self._note_end()
        except Exception as err:  # noqa: BLE001 - the injection must never stop the node
            self.services.log_once(
                f"excite:{type(err).__name__}", "error", f"excitation failed: {one_line(err)}"
            )

    def _publish(self, sample: Sample) -> None:
        point = self.points.get(sample.channel) if sample.channel is not None else None
        cls = message_class(self.type_name)
        if self.type_name == JOINT_STATE:
            msg = cls()
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(sample.stamp_ns), 1_000_000_000)
            msg.name = list(self._joints)
            msg.position = [sample.value if point is not None and joint == point.joint else 0.0
                            for joint in self._joints]
            for pub in self._pubs.values():
                pub.publish(msg)
            return
        for p in self.points.values():
            self._pubs[p.topic].publish(cls(data=sample.value if p.channel == sample.channel else 0.0))

    def _note_end(self) -> None:
        flight = self.player.flight
        if flight is None or flight.state == "flying" or flight is self._noted:
            return
        self._noted = flight
        if flight.state == "done":
            self.flown.add(flight.manoeuvre.index)
            self.node.get_logger().info(f"excitation: {flight.text()}")
        else:
            self.node.get_logger().warning(f"excitation: {flight.text()}")

    def stop(self) -> None:
        """At shutdown: a manoeuvre in flight is aborted and one zero sample is published now."""
        if not self.enabled or self.player.flying is None:
            return
        self.player.abort("the node shut down")
        try:
            self._publish(Sample(self.node.get_clock().now().nanoseconds, None, 0.0))
        except Exception:  # noqa: BLE001 - shutting down
            pass
        self._note_end()

    def status_values(self, channel: str) -> list[tuple[str, str]]:
        """The values the node adds to ``channel``'s status: ``excitation_enabled`` and
        ``excitation_manoeuvre`` (``pitch #0 12.3/60.0 s`` while it flies, then ``done`` or ``aborted``;
        ``none``); none when off.

        Parameters
        ----------
        channel : str
            The channel.
        """
        if not self.enabled:
            return []
        return [("excitation_enabled", "true"), ("excitation_manoeuvre", self.player.status(channel))]

    # ---------------------------------------------------------------- services
    def _srv_excite(self, request, response):
        node, param = self.node, self.services.param
        try:
            flying = self.player.flying
            if flying is not None:
                raise ConfigError(f"already flying {flying.text()}: call ~/abort first")
            m = select_manoeuvre(self.card, str(param("excite_channel")), int(param("excite_index")),
                                 self.flown, self.points)
            cap = float(param("excitation_max_amplitude_rad"))
            if m.amplitude_rad > cap:
                raise ConfigError(
                    f"manoeuvre {m.index} ({m.channel}): amplitude {m.amplitude_rad:.4g} rad is above "
                    f"excitation_max_amplitude_rad {cap:g} (plan with --max-amplitude-rad {cap:g}, or "
                    f"raise the cap)"
                )
            now_ns = node.get_clock().now().nanoseconds
            if now_ns <= 0:
                raise ConfigError("the node clock has not started (use_sim_time and no /clock yet)")
            flight = self.player.start(m, now_ns)
        except ConfigError as err:
            response.success, response.message = False, f"excite refused: {err}"
            node.get_logger().warning(response.message)
            return response
        response.success = True
        response.message = (
            f"flying {m.channel} #{m.index}: {m.f_start_hz:.4g}-{m.f_stop_hz:.4g} Hz, "
            f"{m.amplitude_rad:.4g} rad, {m.repeats} x {m.duration_s:g} s; {flight.duration_s:.1f} s "
            f"from stamp {flight.start_stamp_ns * 1e-9:.3f} s"
        )
        node.get_logger().info(response.message)
        return response

    def _srv_abort(self, request, response):
        flight = self.player.abort("~/abort")
        response.success = True
        if flight is None:
            response.message = "nothing was flying"
            return response
        self.tick()                                   # the zeros go out now, not at the next tick
        response.message = f"{flight.text()}: zero from the next sample on"
        return response

    # ---------------------------------------------------------------- ~/plan
    def serve_requests(self) -> None:
        """Take ``~/plan`` requests (the service is drained by the intake timer, not the executor)."""
        srv = self._plan_srv
        while True:
            with srv.handle:
                request, header = srv.handle.service_take_request(srv.srv_type.Request)
            if header is None:
                return
            self._plan(header)

    def _plan(self, header: Any) -> None:
        """Answer a ``~/plan`` request: the ``plan_card`` file now, else plan from the results in the
        background."""
        path = self.services.param("plan_card")
        if path:
            try:
                self.load_card(path)
                self._respond(header, True, self.card_text())
            except ConfigError as err:
                self._respond(header, False, f"plan failed: {err}")
            return
        self.runner.submit(
            "plan",
            header,
            background.plan_from_results,
            self._snapshot(),
            self._results_name(),
            self._config_name(),
            process=True,
        )

    def _snapshot(self) -> background.Snapshot:
        """The node's state now (pending samples flushed first), for planning off the executor."""
        node = self.node
        self.services.flush()
        return background.snapshot(node.config, node.validator, node.router, node.generation)

    def _config_name(self) -> str:
        return self.services.param("config_file") or self.node.config.source

    def _results_name(self) -> str:
        return f"{self.node.get_fully_qualified_name()} (live results)"

    def finish(self, outcome: Any, tag: Any) -> None:
        """A finished ``~/plan`` job: take its card and answer (the error, on one line, when it failed).

        Parameters
        ----------
        outcome : (str, TestCard) or BaseException
            :func:`~gap_validation.ros.background.plan_from_results`'s result, or its error.
        tag : object
            The request's header (None: nobody to answer).
        """
        if isinstance(outcome, BaseException):
            self._respond(tag, False, f"plan failed: {one_line(outcome)}")
            return
        text, card = outcome
        self._take_card(card, self._results_name(), self._config_name())
        self._respond(tag, True, text)

    def _respond(self, header: Any, success: bool, message: str) -> None:
        if header is None:
            return
        response = Trigger.Response()
        response.success, response.message = success, message
        if not success:
            self.node.get_logger().error(message)
        try:
            self._plan_srv.send_response(response, header)
        except Exception as err:  # noqa: BLE001 - the client left
            self.services.log_once(f"respond:{type(err).__name__}", "warning",
                                   f"~/plan: could not answer ({one_line(err)})")

    def _srv_plan(self, request, response):
        """Callback of ``~/plan`` should an executor serve it (the intake timer normally takes the requests):
        the file's card, or planned here and now."""
        try:
            if self.services.param("plan_card"):
                self.load_card(self.services.param("plan_card"))
                text = self.card_text()
            else:
                text, card = background.plan_from_results(self._snapshot(), self._results_name(),
                                                          self._config_name())
                self._take_card(card, self._results_name(), self._config_name())
            response.success, response.message = True, text
        except Exception as err:  # noqa: BLE001
            response.success, response.message = False, f"plan failed: {one_line(err)}"
        return response
