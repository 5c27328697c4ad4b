"""From messages to samples: the router that feeds :class:`OnlineValidator`.

One data path (docs/ARCHITECTURE.md): bag replay (rosbags message objects) and the ROS 2 node (rclpy message
objects) both hand their messages to :class:`MessageRouter` (after the one decoding step of
:mod:`gap_validation.messages.decoding`), which extracts every configured signal with
:class:`~gap_validation.core.fields.FieldPath`, applies the signal's ``scale``, stamps it with
``header.stamp`` (or the receive time) and pushes time-ordered batches to the validator. Nothing here imports
rclpy or rosbags: messages are only read through attributes, indexing and ``len``, which both kinds of message
objects support (rclpy arrays may be ``array.array`` or numpy arrays, rosbags arrays are numpy arrays).

Field path syntax (DESIGN.md, "Validation config"):

=========================  ===========================================================================
``angular_velocity.y``     dotted attribute path
``data``                   ``std_msgs/msg/Float64`` (``Bool`` gives 0.0 / 1.0)
``position[elevator]``     JointState lookup by name: ``i = msg.name.index('elevator')``, ``msg.position[i]``
``position[2]``, ``[2]``   plain index (negative counts from the end); ``position['2']`` is a name
=========================  ===========================================================================
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from gap_validation.core.alignment import JUMP_BACK_S, increasing, jump_back_s
from gap_validation.core.estimator import ESTIMATOR_DEFAULTS
from gap_validation.core.fields import FieldError, FieldPath

if TYPE_CHECKING:  # pragma: no cover
    from gap_validation.core.config import ValidationConfig
    from gap_validation.core.validator import OnlineValidator

__all__ = ["MessageRouter", "Route", "stamp_seconds", "note_saturation"]


def stamp_seconds(msg: Any) -> float | None:
    """``header.stamp`` of ``msg`` in seconds, or None when there is no header or the stamp is zero (unset).

    Works for rosbags and rclpy ``builtin_interfaces/msg/Time`` (``sec``, ``nanosec``).
    """
    header = getattr(msg, "header", None)
    if header is None:
        return None
    stamp = getattr(header, "stamp", None)
    if stamp is None:
        return None
    sec = getattr(stamp, "sec", 0)
    nanosec = getattr(stamp, "nanosec", 0)
    if not sec and not nanosec:
        return None
    return sec + nanosec * 1e-9


@dataclass(frozen=True)
class Route:
    """One configured signal a topic feeds: channel, stream, parsed path, the gain to SI units and the models'
    body frame (``SignalSpec.gain``), the raw ``offset`` added before it and the ``time_offset_s`` added to
    the stamps."""

    channel: str
    stream: str
    path: FieldPath
    scale: float
    spec: Any = None
    offset: float = 0.0
    time_offset_s: float = 0.0


class _TopicBuffer:
    """Pending messages of one topic: times and one raw value per route (NaN where extraction failed), queued
    one by one (``t``, ``rows``) or as arrays (``chunks``, in arrival order before the ones queued one by
    one)."""

    __slots__ = ("t", "rows", "chunks", "chunked")

    def __init__(self):
        self.t: list[float] = []
        self.rows: list = []
        self.chunks: list[tuple[np.ndarray, np.ndarray]] = []
        self.chunked = 0

    def __len__(self) -> int:
        return self.chunked + len(self.t)

    def _seal(self) -> None:
        """Turn the messages queued one by one into a chunk (keeps the arrival order before a new chunk)."""
        n = len(self.t)
        self.chunks.append(
            (np.asarray(self.t, dtype=float), np.asarray(self.rows, dtype=float).reshape(n, -1))
        )
        self.chunked += n
        self.t, self.rows = [], []

    def add(self, t: np.ndarray, rows: np.ndarray) -> None:
        """Queue many messages: times and one row of raw values each."""
        if self.t:
            self._seal()
        self.chunks.append((t, rows))
        self.chunked += t.size

    def last_t(self) -> float:
        """Time of the last message queued (the buffer is not empty)."""
        return self.t[-1] if self.t else float(self.chunks[-1][0][-1])

    def take(self) -> tuple[np.ndarray, np.ndarray]:
        """Every pending message as ``(t, raw values)`` arrays; the buffer is emptied."""
        if not self.chunks:
            t = np.asarray(self.t, dtype=float)
            raw = np.asarray(self.rows, dtype=float).reshape(t.size, -1)
        else:
            if self.t:
                self._seal()
            t = np.concatenate([c[0] for c in self.chunks])
            raw = np.concatenate([c[1] for c in self.chunks])
            self.chunks, self.chunked = [], 0
        self.t, self.rows = [], []
        return t, raw


class _StreamState:
    """Per (channel, stream): last accepted time, samples pushed, NaNs already counted as bad, and how far
    back [s] time must jump to be a new time base (a looped bag) rather than a reordered sample."""

    __slots__ = ("last_t", "good", "precounted", "jump_s")

    def __init__(self, jump_s: float = JUMP_BACK_S):
        self.last_t = -math.inf
        self.good = 0
        self.precounted = 0
        self.jump_s = jump_s


class _Saturation:
    """Whether a surface sits pinned at an extreme of its range (flat-topped input: a saturated actuator).

    Counts, since the range last grew by more than 5 %, the samples within 0.2 % of the range of the maximum
    (minimum) and the samples in the outer half of the upper (lower) half-range. A sine-like sweep spends a
    few per cent of its outer samples that close to its peak, a clipped one most of them. Constant size.
    """

    __slots__ = ("hi", "lo", "n_hi", "n_lo", "outer_hi", "outer_lo")
    BAND, SHARE, MIN_SAMPLES = 2e-3, 0.25, 25

    def __init__(self):
        self.hi, self.lo = -math.inf, math.inf
        self.n_hi = self.n_lo = self.outer_hi = self.outer_lo = 0

    def update(self, v: np.ndarray) -> None:
        hi, lo = max(self.hi, float(v.max())), min(self.lo, float(v.min()))
        if not (hi - lo <= 1.05 * (self.hi - self.lo)):          # grew (or first batch): count afresh
            self.n_hi = self.n_lo = self.outer_hi = self.outer_lo = 0
        self.hi, self.lo = hi, lo
        band, mid, quarter = self.BAND * (hi - lo), 0.5 * (hi + lo), 0.25 * (hi - lo)
        self.n_hi += int(np.count_nonzero(v >= hi - band))
        self.n_lo += int(np.count_nonzero(v <= lo + band))
        self.outer_hi += int(np.count_nonzero(v > mid + quarter))
        self.outer_lo += int(np.count_nonzero(v < mid - quarter))

    def pinned(self) -> list[tuple[str, float, int]]:
        """``(side, value, samples)`` for each extreme the input sits pinned at."""
        if not self.hi > self.lo:
            return []
        out = []
        for side, value, n, outer in (("maximum", self.hi, self.n_hi, self.outer_hi),
                                      ("minimum", self.lo, self.n_lo, self.outer_lo)):
            if n >= self.MIN_SAMPLES and n >= self.SHARE * outer:
                out.append((side, value, n))
        return out


class MessageRouter:
    """Routes messages of configured topics to :class:`OnlineValidator` as batches of samples.

    Parameters
    ----------
    config : ValidationConfig
        Which topics feed which ``(channel, stream)`` with which field path and scale.
    validator : OnlineValidator
        Receives ``add_samples(channel, stream, t_s, values)`` batches and ``count_bad`` calls.
    batch : int
        Messages per topic held before pushing (larger batches amortise the estimator's vectorised update).
    max_batch_s : float
        Longest time span [s] samples are held: then every stream is pushed, so input and output reach the
        estimator interleaved (it lets one stream run ahead of the other only by ``max_lag_s``).

    Notes
    -----
    Time [s] is ``header.stamp`` when the message has a nonzero one, else ``receive_time_s``, plus
    :attr:`time_offset_s` (replay of several bags whose clocks overlap). Samples that are not finite, lack
    their joint, or do not advance in time are dropped and counted with ``validator.count_bad`` (a step back
    of more than ``max(JUMP_BACK_S, max_gap_s)`` is a new time base instead: passed on, counted). A field the
    *message type* does not have raises :class:`FieldError` (``structural``) once, after the message's other
    signals were queued; that signal is skipped from then on (:attr:`broken`), the others go on.
    Per message only the raw values are queued; scaling and the checks run vectorised when a batch is pushed.
    """

    def __init__(self, config: "ValidationConfig", validator: "OnlineValidator", batch: int = 2048,
                 max_batch_s: float = 2.0):
        self.config = config
        self.validator = validator
        self.batch = max(1, int(batch))
        self.max_batch_s = float(max_batch_s)
        self.time_offset_s = 0.0
        self.routes: dict[str, tuple[Route, ...]] = {
            topic: tuple(Route(channel, stream, FieldPath.parse(spec.field), float(spec.gain), spec,
                               float(spec.offset), float(spec.time_offset_s))
                         for channel, stream, spec in entries)
            for topic, entries in config.topics().items()
        }
        self._pending = {topic: _TopicBuffer() for topic in self.routes}
        self._flush_order = sorted(
            self.routes, key=lambda t: not any(r.stream == "trigger" for r in self.routes[t])
        )
        self._streams = {(r.channel, r.stream): _StreamState(self._jump_s(r.channel))
                         for routes in self.routes.values() for r in routes}
        self._flush_t: float | None = None
        self._saturation = {r.channel: _Saturation() for routes in self.routes.values() for r in routes
                            if r.stream == "input"}
        self.bad: dict[tuple[str, str], dict[str, int]] = {}
        self.first_error: dict[tuple[str, str], str] = {}
        #: (channel, stream) -> why its field cannot be read from the topic's message type (skipped).
        self.broken: dict[tuple[str, str], str] = {}
        self.messages: dict[str, int] = {topic: 0 for topic in self.routes}
        self.last_time_s = -math.inf

    def _jump_s(self, channel: str) -> float:
        """The channel estimator's threshold for a jump back in time [s] (see ``core.estimator``)."""
        options = self.config.channels[channel].estimator
        return jump_back_s(options.get("max_gap_s", ESTIMATOR_DEFAULTS["max_gap_s"]))

    @property
    def topics(self) -> tuple[str, ...]:
        """The topics the config reads."""
        return tuple(self.routes)

    def on_message(self, topic: str, msg: Any, receive_time_s: float) -> None:
        """Extract every signal ``topic`` feeds from ``msg`` and queue the samples.

        Parameters
        ----------
        topic : str
            Topic the message arrived on (others are ignored).
        msg : object
            A rosbags or rclpy message object.
        receive_time_s : float
            Bag or receive time [s], used when the message has no (nonzero) ``header.stamp``.

        Raises
        ------
        FieldError
            The first time the message type lacks a configured field (a config / type mismatch), after the
            message's other signals were queued; that signal is skipped from then on (:attr:`broken`).
        """
        routes = self.routes.get(topic)
        if routes is None:
            return
        stamp = stamp_seconds(msg)
        values = []
        broken = None
        for route in routes:
            key = (route.channel, route.stream)
            if key in self.broken:                       # the message type lacks this field: skip it quietly
                self._streams[key].precounted += 1
                values.append(math.nan)
                continue
            try:
                values.append(route.path.extract(msg))
            except FieldError as err:
                self.first_error.setdefault(key, f"topic {topic}: {err}")
                if err.structural:                       # this signal only: the topic's others still count
                    self.broken[key] = f"topic {topic}: {err}"
                    broken = broken or FieldError(self.broken[key], err.reason, structural=True)
                else:
                    self._count_bad(route, err.reason)
                self._streams[key].precounted += 1
                values.append(math.nan)
        self._queue(topic, receive_time_s if stamp is None else stamp, values)
        if broken is not None:
            raise broken

    def on_values(self, topic: str, t_s: float, values: Any) -> None:
        """Queue already extracted raw values (one per route of ``topic``, in :attr:`routes` order).

        The fast decoders of :mod:`gap_validation.messages.cdr` use this entry; ``t_s`` is the message time
        (stamp or receive time) before :attr:`time_offset_s`, values are before ``scale``.

        Parameters
        ----------
        topic : str
            The topic.
        t_s : float
            Message time [s] before the time offset.
        values : sequence
            One raw value per route of the topic.
        """
        if topic in self.routes:
            self._queue(topic, t_s, values)

    def on_values_batch(self, topics: Sequence[str], which: np.ndarray, t_s: np.ndarray,
                        values: Sequence[np.ndarray]) -> None:
        """Queue a run of fast-decoded messages of several topics, in arrival order, as :meth:`on_values`
        would one by one: the same batches reach the validator, pushed at the same messages.

        Parameters
        ----------
        topics : sequence of str
            The topics of the run (each one the router reads).
        which : numpy.ndarray of int
            Per message, its topic's index in ``topics``.
        t_s : numpy.ndarray of float
            Per message, its time (stamp or receive time) before :attr:`time_offset_s`.
        values : sequence of numpy.ndarray
            Per topic, one row of raw values (one per route, before ``scale``) per message of that topic, in
            arrival order.
        """
        t = np.asarray(t_s, dtype=float) + self.time_offset_s
        n = int(t.size)
        if not n:
            return
        where = [np.flatnonzero(which == k) for k in range(len(topics))]
        buffers = [self._pending[topic] for topic in topics]
        for topic, positions in zip(topics, where):
            self.messages[topic] += int(positions.size)
        queued = [0] * len(topics)           # rows of each topic queued so far
        i = 0
        while i < n:
            if self._flush_t is None:
                self._flush_t = float(t[i])
            start = self._flush_t
            # the first message from i on at which _queue would push (its topic's batch full, or the time span
            # reached) or restart the span (time jumped back)
            ahead = t[i:]
            jumps = (ahead - start >= self.max_batch_s) | (ahead < start - JUMP_BACK_S)
            stop = i + int(np.argmax(jumps)) if jumps.any() else n
            full = False
            for k, positions in enumerate(where):
                need = self.batch - len(buffers[k])          # messages of topic k until its batch is full
                at = queued[k] + max(need, 1) - 1
                if at < positions.size and positions[at] <= stop:
                    stop, full = int(positions[at]), True
            for k, positions in enumerate(where):
                upto = int(np.searchsorted(positions, min(stop, n - 1), side="right"))
                if upto > queued[k]:
                    take = positions[queued[k]:upto]
                    buffers[k].add(t[take], values[k][queued[k]:upto])
                    queued[k] = upto
            if stop >= n:
                break
            if full or t[stop] - start >= self.max_batch_s:
                self.flush()
            self._flush_t = float(t[stop])
            i = stop + 1

    def _queue(self, topic: str, t_s: float, values) -> None:
        t_s += self.time_offset_s
        self.messages[topic] += 1
        buf = self._pending[topic]
        buf.t.append(t_s)
        buf.rows.append(values)
        if self._flush_t is None:
            self._flush_t = t_s
        if len(buf) >= self.batch or t_s - self._flush_t >= self.max_batch_s:
            self.flush()
            self._flush_t = t_s
        elif t_s < self._flush_t - JUMP_BACK_S:      # time went back (a looped bag): batch from here on
            self._flush_t = t_s

    def count_bad_message(self, topic: str, reason: str) -> None:
        """Count one message of ``topic`` that could not be read at all (e.g. a damaged record) as a bad
        sample of every signal the topic feeds.

        Parameters
        ----------
        topic : str
            The topic.
        reason : str
            Why it could not be read.
        """
        for route in self.routes.get(topic, ()):
            self._count_bad(route, reason)

    def _count_bad(self, route: Route, reason: str, count: int = 1) -> None:
        if count <= 0:
            return
        counts = self.bad.setdefault((route.channel, route.stream), {})
        counts[reason] = counts.get(reason, 0) + count
        if count == 1:
            self.validator.count_bad(route.channel, route.stream, reason)
        else:
            self.validator.count_bad(route.channel, route.stream, reason, count)

    def _send_topic(self, topic: str, buf: _TopicBuffer) -> None:
        t_all, raw = buf.take()
        for j, route in enumerate(self.routes[topic]):
            state = self._streams[(route.channel, route.stream)]
            values = (raw[:, j] + route.offset) * route.scale if route.offset else raw[:, j] * route.scale
            t_route = t_all + route.time_offset_s if route.time_offset_s else t_all
            finite = np.isfinite(values) & np.isfinite(t_route)
            n_bad = int(finite.size - np.count_nonzero(finite))
            precounted, state.precounted = state.precounted, 0
            self._count_bad(route, "not finite", n_bad - precounted)
            t, values = t_route[finite], values[finite]
            if t.size == 0:
                continue
            in_order, jumps = increasing(t, state.last_t, state.jump_s)
            self._count_bad(route, "time not increasing", int(t.size - np.count_nonzero(in_order)))
            self._count_bad(route, "time jumped back (new segment)", jumps)
            t, values = t[in_order], values[in_order]
            if t.size == 0:
                continue
            state.last_t = float(t[-1])
            state.good += int(t.size)
            if route.stream == "input":
                self._saturation[route.channel].update(values)
            self.last_time_s = max(self.last_time_s, state.last_t)
            self.validator.add_samples(route.channel, route.stream, t,
                                       values != 0.0 if route.stream == "trigger" else values)

    def flush(self) -> None:
        """Push every pending batch to the validator (trigger topics first: a sweep edge must reach the
        estimator before the samples of the same instant)."""
        for topic in self._flush_order:
            buf = self._pending[topic]
            if len(buf):
                self._send_topic(topic, buf)

    def saturation(self, channel: str) -> list[tuple[str, float, int]]:
        """Where ``channel``'s input sits pinned at an extreme: ``(side, value in SI units, samples)``.

        Parameters
        ----------
        channel : str
            The channel.
        """
        sat = self._saturation.get(channel)
        return sat.pinned() if sat is not None else []

    def samples(self, channel: str, stream: str) -> int:
        """Samples of ``(channel, stream)`` pushed so far plus the messages still pending for it.

        Parameters
        ----------
        channel : str
            The channel.
        stream : str
            The stream (``input``, ``output``, ...).
        """
        state = self._streams.get((channel, stream))
        if state is None:
            return 0
        pending = sum(len(self._pending[topic]) for topic, routes in self.routes.items()
                      if any((r.channel, r.stream) == (channel, stream) for r in routes))
        return state.good + pending

    def latest_time_s(self) -> float:
        """Latest sample time [s] queued on any topic (``-inf`` before the first sample)."""
        pending = [buf.last_t() for buf in self._pending.values() if len(buf)]
        return max([self.last_time_s, *pending])


def note_saturation(config, router: MessageRouter, result) -> list[str]:
    """Warn (and say in the channel's message and bad counts) where a swept surface sits pinned at an extreme:
    a saturated actuator clips the input, and the estimate near those amplitudes is biased. Used by replay and
    the node alike; returns one warning line per pinned extreme."""
    warnings = []
    for name, ch in result.channels.items():
        if not ch.sweeps:
            continue
        for side, value, n in router.saturation(name):
            spec = config.channels[name].input
            text = (f"input {spec.topic} {spec.field!r} pinned at its {side} {value:.4g} for {n} samples "
                    "(saturated surface? the estimate is biased where it clips)")
            warnings.append(f"channel {name}: {text}")
            ch.message = f"{ch.message}; {text}" if ch.message else text
            ch.bad_samples[f"input: saturated at {side}"] = n
    return warnings
