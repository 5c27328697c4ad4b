"""The node's topics: subscriptions that follow the graph, and the taking of their messages (rclpy).

:class:`Topics` is the part of :class:`gap_validation.ros.node.ValidatorNode` that owns its topics, as a
component holding a reference to the node (its public rclpy API: ``create_subscription``, the graph, logging;
its ``router``, ``validator`` and ``config``) and the services the node lends it (parameters, log-once, clock,
the executor's wait set: :class:`~gap_validation.ros.collaborators.NodeServices`):

* subscribing: every topic is subscribed at start-up (type from the config, else implied by its field paths,
  :func:`~gap_validation.ros.message_types.topic_types`; only topics whose fields imply nothing wait for the
  graph), with the reliability the publishers offer (``qos_reliability: auto``: both reliable and best effort
  until they are known, then theirs; re-checked by :meth:`Topics.check_graph` every ``discovery_period``,
  :mod:`gap_validation.ros.intake`);
* taking messages: the subscriptions are kept out of the executor's wait set and drained in one wake-up
  (:meth:`Topics.take_all`, from the node's intake timer); serialized messages go through the decoding step
  replay uses (:class:`gap_validation.messages.decoding.TopicDecoder`, with rclpy's ``deserialize_message`` as
  the full deserialisation), other messages to the router; a sample's time is its ``header.stamp``, else its
  reception time (DDS's, on the node clock). What each topic has seen (last arrival, :class:`StampGaps`) is
  kept here for the channels' statuses.

Importing it imports rclpy, never rosbags.
"""
from __future__ import annotations

import time
from functools import partial
from typing import Any

from gap_validation.core.errors import one_line
from gap_validation.core.fields import FieldError
from gap_validation.messages.decoding import TopicDecoder, Undecodable
from gap_validation.messages.router import stamp_seconds
from gap_validation.ros.collaborators import NodeServices
from gap_validation.ros.intake import BEST_EFFORT, RELIABLE, Intake, choose_reliability, publisher_note
from gap_validation.ros.message_types import TopicType, fields_fit, message_class
from gap_validation.ros.stamp_gaps import StampGaps

try:  # rclpy is only needed to run the node
    from rclpy.event_handler import SubscriptionEventCallbacks
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import deserialize_message
except ImportError:  # pragma: no cover - exercised only without ROS 2
    pass

__all__ = ["Topics"]

_SOURCES = {"config": "the config's type", "fields": "implied by its fields", "graph": "its publishers' type"}


class Topics:
    """A node's subscriptions, kept out of the executor's wait set, and what their messages become.

    Parameters
    ----------
    node : rclpy.node.Node
        The node: its subscriptions, graph queries and logger, and its ``router``, ``validator`` and
        ``config`` (read when needed: they change on reload and reset).
    types : dict of str to TopicType
        Topic -> type wanted (:func:`~gap_validation.ros.message_types.topic_types`); updated by the graph.
    services : NodeServices
        The node's parameters (``qos_*``, ``raw_decoding``, ``stale_timeout``), log-once, clock, and the
        executor's wait set (the subscriptions are kept out of it, :attr:`NodeServices.poll`).

    Attributes
    ----------
    types : dict of str to TopicType
        Topic -> type wanted.
    intakes : dict of str to Intake
        Topic -> its subscription(s).
    raw : dict of str to TopicDecoder
        Topic -> decoding step of its raw subscription.
    last_arrival : dict of str to float
        Topic -> node time [s] of its last message (the transport's reception time: the age of the data).
    last_taken : dict of str to float
        Topic -> node time [s] at which the node last took a message of it (late after a stall of the node:
        the end of a run is silence the node heard, :meth:`ChannelTask.run_ended
        <gap_validation.ros.status.ChannelTask.run_ended>`).
    gaps : dict of str to StampGaps
        Topic -> messages missing from its stamps.
    graph_due : bool
        Whether the next intake wake-up checks the graph (after (re)subscribing).
    """

    #: Longest a QoS change keeps the previous subscription while the new one matches [s].
    CHANGE_TIMEOUT_S = 5.0

    def __init__(self, node: Any, types: dict[str, TopicType], services: NodeServices):
        self.node = node
        self.services = services
        self.types = types
        self.intakes: dict[str, Intake] = {}
        self.raw: dict[str, TopicDecoder] = {}
        self.last_arrival: dict[str, float] = {}
        self.last_taken: dict[str, float] = {}
        self.gaps: dict[str, StampGaps] = {}
        self.graph_due = False

    # ---------------------------------------------------------------- subscriptions
    def retype(self, types: dict[str, TopicType]) -> None:
        """Take the types of a new config (reload), keeping what the graph taught
        (call :meth:`subscribe_all`).

        Parameters
        ----------
        types : dict of str to TopicType
            The new config's topic types.
        """
        for topic, intake in self.intakes.items():
            if topic in types and types[topic].source != "config" and intake.type_source == "graph":
                types[topic] = TopicType(intake.type_name, "graph")
        self.types = types

    def subscribe_all(self) -> None:
        """Subscribe to every topic whose type is known (config or fields); drop topics no longer
        configured."""
        for topic in list(self.intakes):
            wanted = self.types.get(topic)
            intake = self.intakes[topic]
            if wanted is None or (wanted.name is not None and wanted.name != intake.type_name):
                self._unsubscribe(topic)
        for topic in list(self.raw):  # the fields may have changed (reload): new decoding steps
            self.raw[topic] = self._decoding(topic, self.intakes[topic].type_name)
        for topic, wanted in self.types.items():
            if topic in self.intakes:
                continue
            if wanted.name is None:
                self.services.log_once(
                    f"discover:{topic}",
                    "info",
                    f"topic {topic}: type neither in the config "
                    "nor implied by its fields, waiting for it on the graph",
                )
                continue
            self._subscribe(topic, wanted)
        self.graph_due = True

    @property
    def pending(self) -> list[str]:
        """Topics whose type is still to be discovered on the graph."""
        return [topic for topic in self.types if topic not in self.intakes]

    def notes(self) -> dict[str, str]:
        """Topic -> why its publishers cannot be matched (for the channels' statuses), for topics with a
        note."""
        return {topic: intake.note for topic, intake in self.intakes.items() if intake.note}

    def _publishers_on(self, topic: str) -> list[tuple[str, str]]:
        """(type, reliability) of each publisher on ``topic``."""
        out = []
        for info in self.node.get_publishers_info_by_topic(self.node.resolve_topic_name(topic)):
            best_effort = info.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
            out.append((info.topic_type, BEST_EFFORT if best_effort else RELIABLE))
        return out

    def _create(self, topic: str, type_name: str, reliability: str) -> Any:
        """A subscription drained by the intake timer (not in the executor's wait set)."""
        node = self.node
        decoding = self._decoding(topic, type_name) if self.services.param("raw_decoding") else None
        raw = decoding is not None and decoding.decoder is not None
        if raw:
            self.raw[topic] = decoding
        else:
            self.raw.pop(topic, None)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(self.services.param("qos_depth")),
                         reliability=ReliabilityPolicy.RELIABLE if reliability == RELIABLE
                         else ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
        # no QoS event handlers: they are waitables the executor would wait on, and rmw wakes those with every
        # message of the subscription (the SingleThreadedExecutor spun at 82 % of a core); the graph check
        # (discovery_period) sees matches and incompatible publishers instead
        events = SubscriptionEventCallbacks(use_default_callbacks=False)
        sub = node.create_subscription(
            message_class(type_name),
            topic,
            partial(self._on_executor_message, topic),
            qos,
            event_callbacks=events,
            raw=raw,
        )
        self.services.poll(sub)
        return sub

    def _subscribe(self, topic: str, wanted: TopicType) -> None:
        """Subscribe now; with ``qos_reliability: auto`` and no publisher known yet, both reliable and best
        effort (:class:`~gap_validation.ros.intake.Intake`: nothing missed from the first message, nothing
        twice)."""
        mode = self.services.param("qos_reliability")
        offered = [r for t, r in self._publishers_on(topic) if t == wanted.name]
        reliability = choose_reliability(mode, offered) if offered or mode != "auto" else None
        kinds = [reliability] if reliability else [RELIABLE, BEST_EFFORT]
        subs = {kind: self._create(topic, wanted.name, kind) for kind in kinds}
        self.intakes[topic] = Intake(topic, wanted.name, wanted.source, subs, reliability)
        self.node.get_logger().info(
            f"topic {topic}: subscribed as {wanted.name} ({_SOURCES[wanted.source]}), "
            f"{(reliability or 'reliable and best_effort until the publishers are known').upper()}")

    def _destroy(self, sub: Any) -> None:
        self.services.unpoll(sub)
        self.node.destroy_subscription(sub)

    def _unsubscribe(self, topic: str) -> None:
        intake = self.intakes.pop(topic)
        for sub in intake.subscriptions.values():
            self._destroy(sub)
        self.raw.pop(topic, None)

    def _decoding(self, topic: str, type_name: str) -> TopicDecoder:
        """The decoding step of a raw subscription, with rclpy's deserialisation behind the fast decoder."""
        return TopicDecoder(self.node.router, topic, type_name,
                            partial(deserialize_message, message_type=message_class(type_name)),
                            on_disagree=self._disagree)

    def _disagree(self, topic: str) -> None:
        self.services.log_once(f"fast:{topic}", "info", f"topic {topic}: fast decoding disagrees with rclpy; "
                                                        "deserialising instead")

    def check_graph(self) -> None:
        """Graph check: discover pending types, follow the publishers' type and reliability, note
        mismatches."""
        self.graph_due = False
        mode = self.services.param("qos_reliability")
        for topic, wanted in self.types.items():
            try:
                publishers = self._publishers_on(topic)
            except Exception as err:  # noqa: BLE001 - the graph is best effort; try again next time
                self.services.log_once(f"graph:{type(err).__name__}", "warning",
                                       f"graph query failed: {one_line(err)}")
                return
            intake = self.intakes.get(topic)
            if intake is None or intake.type_source != "config":
                self._follow_type(topic, intake, publishers)
                intake = self.intakes.get(topic)
                if intake is None:
                    continue
            offered = [r for t, r in publishers if t == intake.type_name]
            want = choose_reliability(mode, offered) if offered or mode != "auto" else intake.reliability
            # (two kinds only: a new one replaces a lone one)
            if want is not None and want != intake.reliability:
                self._settle(intake, want, len(offered))
            note = publisher_note(topic, mode, intake.reliability, intake.type_name, intake.type_source,
                                  publishers) if intake.reliability else None
            if note and note != intake.note:
                self.services.log_once(f"note:{topic}:{note}", "warning", note)
            intake.note = note

    def _follow_type(self, topic: str, intake: Intake | None, publishers: list[tuple[str, str]]) -> None:
        """Subscribe a pending topic with the publishers' type, or replace a type the fields implied
        wrongly."""
        types = sorted({t for t, _ in publishers})
        if not types or (intake is not None and intake.type_name in types):
            return
        type_name = types[0]
        if len(types) > 1:
            self.services.log_once(f"types:{topic}", "warning",
                                   f"topic {topic}: several types on the graph ({', '.join(types)}), "
                                   f"using {type_name}")
        if not fields_fit(topic, type_name, self.node.config.topics()[topic]):
            self.services.log_once(
                f"badtype:{topic}:{type_name}",
                "error",
                f"topic {topic}: its publishers' type {type_name} is not installed or lacks a "
                "configured field; not subscribed with it",
            )
            return
        if intake is not None:   # the guessed type has no publisher: nothing arrives on it, replace it
            self._unsubscribe(topic)
        self.types[topic] = TopicType(type_name, "graph")
        self._subscribe(topic, self.types[topic])

    def _settle(self, intake: Intake, reliability: str, publishers: int) -> None:
        """Keep ``reliability``: its subscription (new, make before break, when the topic has none) is drained
        with the others until it has matched the publishers (:meth:`Intake.settle`)."""
        new = None if reliability in intake.subscriptions else self._create(intake.topic, intake.type_name,
                                                                            reliability)
        intake.settle(reliability, publishers, time.monotonic() + self.CHANGE_TIMEOUT_S, subscription=new)
        self.node.get_logger().info(f"topic {intake.topic}: publishers offer {reliability.upper()}"
                                    f"{', re-subscribing' if new is not None else ''}")

    # ---------------------------------------------------------------- taking messages
    def take_all(self) -> None:
        """Drain every queue, retire replaced subscriptions, check the graph when due (the intake timer)."""
        services = self.services
        limit = int(services.param("qos_depth"))
        now_s = services.now_s()
        offset_s = now_s - time.time_ns() * 1e-9   # DDS reception stamps (system clock) -> node clock
        for topic, intake in list(self.intakes.items()):
            retire = intake.retire_due(time.monotonic())
            try:
                got = intake.drain(limit)
            except Exception as err:  # noqa: BLE001 - a subscription destroyed under us: next time
                services.log_once(
                    f"take:{topic}:{type(err).__name__}", "error", f"topic {topic}: {one_line(err)}"
                )
                continue
            if retire:
                for sub in intake.retired():
                    self._destroy(sub)
            if got:
                self.take_messages(topic, got, now_s, offset_s)
        if self.graph_due:
            self.check_graph()

    def take_messages(self, topic: str, items: list, now_s: float | None = None, offset_s: float | None = None
                      ) -> None:
        """Hand messages drained from ``topic``'s queue to the decoding step and the router (never raises).

        :meth:`TopicDecoder.decode <gap_validation.messages.decoding.TopicDecoder.decode>` reads only the
        configured fields, checks its first messages per topic against rclpy's deserialisation, and
        deserialises any message it cannot read (missing joint, short array, other encoding), which is then
        routed normally, so bad samples are counted the same way; an undecodable message is counted.

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
        now_s = self.services.now_s() if now_s is None else now_s
        offset_s = now_s - time.time_ns() * 1e-9 if offset_s is None else offset_s
        decoding = self.raw.get(topic)
        t_rx = now_s
        if decoding is None:
            for msg, info in items:
                rx = info.get("received_timestamp")
                t_rx = min(now_s, rx * 1e-9 + offset_s) if rx else now_s
                self.route(topic, msg, t_rx)
        else:
            decode, gaps, on_values = decoding.decode, self._gaps_of(topic), self.node.router.on_values
            for data, info in items:
                rx = info.get("received_timestamp")
                t_rx = min(now_s, rx * 1e-9 + offset_s) if rx else now_s
                try:
                    stamp, values, msg = decode(data)
                except Undecodable as err:  # a damaged message: counted as replay counts it
                    self.services.log_once(f"raw:{topic}:{type(err.error).__name__}", "error",
                                           f"topic {topic}: message skipped ({one_line(err.error)})")
                    continue
                if msg is not None:
                    self.route(topic, msg, t_rx)
                    continue
                if stamp is not None:
                    gaps.add(stamp)
                try:
                    on_values(topic, t_rx if stamp is None else stamp, values)
                except Exception as err:  # noqa: BLE001 - a message must never stop the node
                    self.services.log_once(f"raw:{topic}:{type(err).__name__}", "error",
                                           f"topic {topic}: message skipped ({one_line(err)})")
        self.last_arrival[topic] = t_rx
        self.last_taken[topic] = now_s

    def _on_executor_message(self, topic: str, msg: Any) -> None:
        """Subscription callback, should an executor still hand a message over (before it saw the subscription
        leave its wait set): taken like a drained one."""
        self.take_messages(topic, [(msg, {})])

    def _gaps_of(self, topic: str) -> StampGaps:
        gaps = self.gaps.get(topic)
        if gaps is None:
            gaps = self.gaps[topic] = StampGaps(self.services.param("stale_timeout"))
        return gaps

    def samples_dropped(self, topic: str) -> int:
        """Messages of ``topic`` missing from its header stamps so far (:class:`StampGaps`).

        Parameters
        ----------
        topic : str
            The topic.
        """
        gaps = self.gaps.get(topic)
        return gaps.dropped if gaps is not None else 0

    def route(self, topic: str, msg: Any, now_s: float) -> None:
        """One deserialised message of ``topic`` to the router (never raises); its stamp to the topic's gaps.

        Parameters
        ----------
        topic : str
            The topic.
        msg : message
            The deserialised message.
        now_s : float
            Its reception time on the node clock [s] (the sample's time when it has no ``header.stamp``).
        """
        stamp = stamp_seconds(msg)
        if stamp is not None:
            self._gaps_of(topic).add(stamp)
        try:
            self.node.router.on_message(topic, msg, now_s)
        except FieldError as err:  # the message type lacks a configured field: every message will fail
            for route in self.node.router.routes.get(topic, ()):
                self.node.validator.count_bad(route.channel, route.stream, err.reason)
            self.services.log_once(
                f"field:{topic}", "error", f"{one_line(err)} (check the config; counted as bad)"
            )
        except Exception as err:  # noqa: BLE001 - a message must never stop the node
            self.services.log_once(f"msg:{topic}:{type(err).__name__}", "error",
                                   f"topic {topic}: message skipped ({one_line(err)})")
