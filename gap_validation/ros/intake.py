"""How the node takes messages: each topic's queue drained in one wake-up, QoS matched to the publishers.

No rclpy import: the node creates the subscriptions and hands them to an :class:`Intake`, which only calls
their ``handle.take_message``, ``get_publisher_count`` and ``msg_type`` / ``raw`` attributes.

Draining
--------
An executor callback per message costs more than the node's own work per message: at 1 kHz IMU + 100 Hz
surfaces rclpy's EventsExecutor spent about 10 % of a core dispatching callbacks that did nothing, the
SingleThreadedExecutor 55 %. The node therefore keeps its subscriptions out of the executor's wait set and
drains every queue from one timer (``intake_period``): :func:`take_all` takes the waiting messages in a loop
(``take_message``, the call the executors make per message), at most ``limit`` per topic and wake-up. The
KEEP_LAST queue (``qos_depth``) holds what arrives in between.

QoS that works by default
-------------------------
:func:`choose_reliability`: with ``qos_reliability: auto`` a topic is subscribed RELIABLE when every publisher
on it offers RELIABLE, and BEST_EFFORT when any offers BEST_EFFORT or none is known yet (a best-effort
subscription matches every publisher). The choice is re-checked when publishers appear (the node's graph
check, every ``discovery_period``); a change re-subscribes
*make before break* (:meth:`Intake.settle`): the new subscription is created, both are drained until the new
one has matched the publishers, and a message taken from one is skipped when it comes again from the other
(same source timestamp and publication sequence number), so the switch neither loses nor repeats a message.
While no publisher is known the topic has both a reliable and a best-effort subscription, drained the same
way: a reliable publisher that appears is received reliably from its first message (a best-effort subscription
alone loses messages of a burst when the machine is busy), a best-effort one is received at all.
:func:`publisher_note` says in the channel's status why a publisher cannot be matched.
"""
from __future__ import annotations

import time
from typing import Any, Iterable, Sequence

__all__ = [
    "Intake",
    "take_all",
    "choose_reliability",
    "publisher_note",
    "message_key",
    "RELIABLE",
    "BEST_EFFORT",
]

RELIABLE = "reliable"
BEST_EFFORT = "best_effort"


def choose_reliability(mode: str, offered: Sequence[str]) -> str:
    """The reliability to subscribe with.

    Parameters
    ----------
    mode : {"auto", "reliable", "best_effort"}
        The ``qos_reliability`` parameter.
    offered : sequence of {"reliable", "best_effort"}
        What each publisher on the topic offers (empty: none known yet).

    Returns
    -------
    str
        ``mode`` unless it is ``auto``; then ``reliable`` when every publisher offers it, else ``best_effort``
        (best effort matches any publisher: nothing is missed while the publishers are not known).
    """
    if mode != "auto":
        return mode
    return RELIABLE if offered and all(r == RELIABLE for r in offered) else BEST_EFFORT


def publisher_note(topic: str, mode: str, reliability: str, type_name: str | None, type_source: str | None,
                   publishers: Iterable[tuple[str, str]]) -> str | None:
    """Why some publisher on ``topic`` cannot reach the subscription, as one line for the channel's status.

    Parameters
    ----------
    topic : str
        The topic.
    mode : str
        The ``qos_reliability`` parameter.
    reliability : {"reliable", "best_effort"}
        What the subscription requests.
    type_name : str or None
        The type it is subscribed with.
    type_source : {"config", "fields", "graph"} or None
        Where that type comes from.
    publishers : iterable of (type, reliability)
        Each publisher on the topic.

    Returns
    -------
    str or None
        e.g. ``publisher on /imu offers BEST_EFFORT; set qos_reliability to auto or best_effort (the
        subscription is RELIABLE)``; None when every publisher can be matched.
    """
    publishers = list(publishers)
    other = sorted({t for t, _ in publishers if type_name is not None and t != type_name})
    if other:
        whose = "the config says" if type_source == "config" else "subscribed as"
        return (
            f"publisher on {topic} offers {', '.join(other)}; {whose} {type_name} (set the topic's `type:` "
            "in the config)"
        )
    if reliability == RELIABLE and any(r == BEST_EFFORT for _, r in publishers):
        n = sum(1 for _, r in publishers if r == BEST_EFFORT)
        who = "publisher" if n == 1 else f"{n} publishers"
        offers = "offers" if n == 1 else "offer"
        return (f"{who} on {topic} {offers} BEST_EFFORT; set qos_reliability to auto or best_effort (the "
                f"subscription is RELIABLE{'' if mode == RELIABLE else ', switching'})")
    return None


def take_all(subscription: Any, limit: int) -> list:
    """Take up to ``limit`` waiting messages of ``subscription``: ``[(message or bytes, info), ...]``.

    Parameters
    ----------
    subscription : rclpy.subscription.Subscription
        Its ``handle.take_message(msg_type, raw)`` returns ``(message, info)`` or None when the queue is
        empty.
    limit : int
        Most messages taken (a flood cannot keep the wake-up going).
    """
    handle = subscription.handle
    take, msg_type, raw = handle.take_message, subscription.msg_type, subscription.raw
    out = []
    append = out.append
    with handle:
        for _ in range(limit):
            got = take(msg_type, raw)
            if got is None:
                break
            append(got)
    return out


def message_key(info: dict) -> tuple | None:
    """What identifies a message across two subscriptions: (source timestamp, publication sequence number)."""
    source, sequence = info.get("source_timestamp"), info.get("publication_sequence_number")
    return None if source is None and sequence is None else (source, sequence)


def _publication_order(item: tuple) -> tuple:
    """Sort key of a taken message: its source timestamp, then its sequence number (0 where missing)."""
    info = item[1]
    return (info.get("source_timestamp") or 0, info.get("publication_sequence_number") or 0)


class Intake:
    """One topic's subscriptions, drained in one wake-up: one, or two while the reliability is being settled.

    Parameters
    ----------
    topic : str
        The topic.
    type_name : str
        Its message type.
    type_source : {"config", "fields", "graph"}
        Where the type comes from (:class:`gap_validation.ros.message_types.TopicType`).
    subscriptions : dict
        Reliability -> subscription (taken from with :func:`take_all`). Two (``reliable`` and ``best_effort``)
        while the publishers are not known (``qos_reliability: auto``): a reliable publisher's messages then
        arrive reliably, a best-effort publisher's still arrive, and a message both deliver is taken once.
    reliability : {"reliable", "best_effort"} or None
        The reliability that stays (None: not known yet, both kept).

    Attributes
    ----------
    note : str or None
        Why a publisher cannot reach the subscription (:func:`publisher_note`), for the channel's status.
    duplicates : int
        Messages skipped because another subscription of the topic had already delivered them.
    """

    #: Drains after the last extra subscription went during which duplicates are still looked for.
    LINGER = 2
    #: Longest a message waits for the reliable queue to pass it [s] (:meth:`drain`).
    HOLD_S = 1.0

    def __init__(self, topic: str, type_name: str, type_source: str, subscriptions: dict[str, Any],
                 reliability: str | None):
        self.topic = topic
        self.type_name = type_name
        self.type_source = type_source
        self.subscriptions = dict(subscriptions)
        self.reliability = reliability
        self.note: str | None = None
        self.duplicates = 0
        self._expect = 0
        self._deadline = float("inf")
        self._keys: set | None = set() if len(self.subscriptions) > 1 else None
        self._linger = 0
        # (monotonic time taken, message) waiting for the reliable queue
        self._held: list = []
        self._reliable_last: tuple = (0, 0)     # publication order of the reliable queue's latest message

    @property
    def current(self) -> Any:
        """The subscription that stays (None while the reliability is not settled)."""
        return self.subscriptions.get(self.reliability) if self.reliability else None

    def settle(self, reliability: str, publishers: int, deadline: float, subscription: Any = None) -> None:
        """Keep ``reliability`` from now on: its subscription (``subscription`` when it is new: make before
        break) is drained with the others until it has matched ``publishers`` publishers or the monotonic time
        ``deadline`` [s] passes (:meth:`retire_due`); then the others go (:meth:`retired`).

        Parameters
        ----------
        reliability : str
            The reliability that stays.
        publishers : int
            Publishers its subscription should match before the others go.
        deadline : float
            Monotonic time [s] after which the others go anyway (a publisher left meanwhile).
        subscription : object, optional
            A new subscription with ``reliability`` (when the topic has none yet).
        """
        if subscription is not None:
            if reliability in self.subscriptions:
                raise RuntimeError(f"topic {self.topic} already has a {reliability} subscription")
            self.subscriptions[reliability] = subscription
        self.reliability = reliability
        self._expect, self._deadline = publishers, deadline
        if len(self.subscriptions) > 1 and self._keys is None:
            self._keys, self._linger = set(), 0

    def retire_due(self, now: float) -> bool:
        """Whether the other subscriptions can go: the one that stays matched every publisher, or time is up.

        Parameters
        ----------
        now : float
            Monotonic time [s].
        """
        if self.reliability is None or len(self.subscriptions) < 2:
            return False
        return self.current.get_publisher_count() >= self._expect or now >= self._deadline

    def retired(self) -> list:
        """The subscriptions that go, to destroy now (after a last :meth:`drain`); duplicates are looked for
        in
        :attr:`LINGER` more drains."""
        gone = [sub for reliability, sub in self.subscriptions.items() if reliability != self.reliability]
        self.subscriptions = {self.reliability: self.current}
        self._linger = self.LINGER
        return gone

    @property
    def changing(self) -> bool:
        """More than one subscription is drained (or duplicates of one just gone are still looked for)."""
        return self._keys is not None

    def drain(self, limit: int, now: float | None = None) -> list:
        """Every waiting message, ``[(message or bytes, info), ...]``, each once, in the order they were
        published (with several subscriptions: their source timestamps).

        While a reliable subscription with a publisher is drained beside another, a message only the other one
        delivered and published after the reliable queue's latest waits (at most :attr:`HOLD_S`): a reliable
        queue delivers in order, so after a loss on the wire it holds every later message back until the lost
        one is resent, and the best-effort queue runs ahead. Handed out at once, the resent message would come
        after later ones: a time jump back to the router (a manoeuvre cut in two).

        Parameters
        ----------
        limit : int
            Most messages taken per subscription.
        now : float, optional
            Monotonic time [s] of the drain (default: now), for :attr:`HOLD_S`.
        """
        if self._keys is None:
            (only,) = self.subscriptions.values()
            return take_all(only, limit)
        now = time.monotonic() if now is None else now
        got = []
        order = [r for r in self.subscriptions if r != self.reliability] + (
            [self.reliability] if self.current else []
        )
        for reliability in order:   # the one that stays last
            taken = take_all(self.subscriptions[reliability], limit)
            if reliability == RELIABLE and taken:
                self._reliable_last = max(self._reliable_last, *map(_publication_order, taken))
            got += taken
        reliable = self.subscriptions.get(RELIABLE)
        keys = self._keys
        for item in got:
            key = message_key(item[1])
            if key is None:
                self._held.append((now, item))
            elif key in keys:
                self.duplicates += 1
            else:
                keys.add(key)
                self._held.append((now, item))
        waiting = reliable is not None and reliable.get_publisher_count() > 0
        out, held = [], []
        for since, item in self._held:
            if waiting and now - since < self.HOLD_S and message_key(item[1]) is not None \
                    and _publication_order(item) > self._reliable_last:
                held.append((since, item))
            else:
                out.append(item)
        self._held = held
        # in the order they were published: a message one queue dropped (best effort under load) and the other
        # delivered would otherwise come after later ones
        out.sort(key=_publication_order)
        if len(self.subscriptions) == 1:
            self._linger -= 1
            if self._linger <= 0 and not self._held:
                self._keys = None
        return out
