"""From messages to samples: field paths and the router that feeds :class:`OnlineValidator`.

One data path (docs/ARCHITECTURE.md): bag replay (rosbags message objects) and the ROS 2 node (rclpy message
objects) both hand their messages to :class:`MessageRouter`, which extracts every configured signal with
:class:`FieldPath`, applies the signal's ``scale``, stamps it with ``header.stamp`` (or the receive time) and
pushes time-ordered batches to the validator. Nothing here imports rclpy or rosbags: messages are only read
through attributes, indexing and ``len``, which both kinds of message objects support (rclpy arrays may be
``array.array`` or numpy arrays, rosbags arrays are numpy arrays).

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
import operator
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from gap_validation.core.errors import ConfigError, DataError

if TYPE_CHECKING:  # pragma: no cover
    from gap_validation.core.config import ValidationConfig
    from gap_validation.core.validator import OnlineValidator

__all__ = ["FieldError", "FieldPath", "MessageRouter", "Route", "stamp_seconds"]

#: Sibling fields that hold the names a ``field[name]`` lookup searches (JointState, MultiDOFJointState).
NAME_FIELDS = ("name", "joint_names")

_IDENT = r"[A-Za-z_][A-Za-z0-9_]*"
_SEGMENT = re.compile(rf"\s*(?P<attr>{_IDENT})?\s*(?P<brackets>(\[[^\[\]]*\]\s*)*)\s*")
_BRACKET = re.compile(r"\[([^\[\]]*)\]")
_INTEGER = re.compile(r"[+-]?\d+")


class FieldError(DataError):
    """A message lacks a configured field, joint or index, or the value is not a number.

    ``reason`` is a short tag for bad-sample counts (``missing field``, ``missing joint``,
    ``index out of range``, ``not a number``); ``structural`` is True when the *message type* lacks the field
    (every message will fail: a config or type mismatch), False when only this message is bad.
    """

    def __init__(self, message: str, reason: str, structural: bool = False):
        super().__init__(message)
        self.reason = reason
        self.structural = structural


@dataclass(frozen=True)
class _Step:
    """One step of a path: ``attr`` (attribute name), ``index`` (integer) or ``key`` (name lookup)."""

    kind: str
    value: Any


def _parse_bracket(content: str, text: str) -> _Step:
    content = content.strip()
    if not content:
        raise ConfigError(f"field {text!r}: empty brackets '[]' (use an index such as [2] or a name such as "
                          "[elevator])")
    if _INTEGER.fullmatch(content):
        return _Step("index", int(content))
    if len(content) >= 2 and content[0] == content[-1] and content[0] in "'\"":
        content = content[1:-1]
        if not content:
            raise ConfigError(f"field {text!r}: empty name in brackets")
    return _Step("key", content)


def _parse_steps(text: str) -> tuple[_Step, ...]:
    if not isinstance(text, str) or not text.strip():
        raise ConfigError(f"field {text!r}: expected a path such as angular_velocity.y or position[elevator]")
    steps: list[_Step] = []
    for number, segment in enumerate(text.split(".")):
        match = _SEGMENT.fullmatch(segment)
        if match is None or (not match.group("attr") and not match.group("brackets")):
            raise ConfigError(f"field {text!r}: bad part {segment.strip()!r} (expected a name such as "
                              "angular_velocity, optionally followed by [index] or [joint_name])")
        if match.group("attr"):
            steps.append(_Step("attr", match.group("attr")))
        elif number > 0:
            raise ConfigError(f"field {text!r}: bad part {segment.strip()!r} (brackets need a field name "
                              "before them after a dot)")
        for content in _BRACKET.findall(match.group("brackets")):
            step = _parse_bracket(content, text)
            if step.kind == "key" and (not steps or steps[-1].kind != "attr"):
                raise ConfigError(f"field {text!r}: name lookup [{step.value}] needs the array field before it, "
                                  "e.g. position[elevator]")
            steps.append(step)
    return tuple(steps)


def _attr_getter(names: list[str], text: str) -> Callable[[Any], Any]:
    getter = operator.attrgetter(".".join(names))

    def get(obj: Any) -> Any:
        try:
            return getter(obj)
        except AttributeError:
            missing = _first_missing(obj, names)
            raise FieldError(f"field {text!r}: message {type(obj).__name__} has no field {missing!r}",
                             "missing field", structural=True) from None

    return get


def _first_missing(obj: Any, names: list[str]) -> str:
    path = []
    for name in names:
        path.append(name)
        if not hasattr(obj, name):
            return ".".join(path)
        obj = getattr(obj, name)
    return ".".join(path)  # pragma: no cover (attrgetter failed, so some name was missing)


def _index_getter(index: int, text: str) -> Callable[[Any], Any]:
    def get(obj: Any) -> Any:
        try:
            return obj[index]
        except IndexError:
            raise FieldError(f"field {text!r}: index {index} out of range (length {len(obj)})",
                             "index out of range") from None
        except (TypeError, KeyError):
            raise FieldError(f"field {text!r}: {type(obj).__name__} value cannot be indexed with [{index}]",
                             "not an array", structural=True) from None

    return get


class _NameLookup:
    """``parent.<array>[name]``: index of ``name`` in ``parent.name`` (cached while the order is unchanged)."""

    def __init__(self, array: str, key: str, text: str):
        self.array = array
        self.key = key
        self.text = text
        self.cached = -1

    def __call__(self, parent: Any) -> Any:
        names = self._names(parent)
        try:
            values = getattr(parent, self.array)
        except AttributeError:
            raise FieldError(f"field {self.text!r}: message {type(parent).__name__} has no field "
                             f"{self.array!r}", "missing field", structural=True) from None
        i = self.cached
        if not (0 <= i < len(names) and names[i] == self.key):
            try:
                i = list(names).index(self.key)
            except ValueError:
                raise FieldError(f"field {self.text!r}: no joint {self.key!r} in message (names: "
                                 f"{', '.join(map(str, names)) or 'none'})", "missing joint") from None
            self.cached = i
        if i >= len(values):
            raise FieldError(f"field {self.text!r}: joint {self.key!r} is name {i} but {self.array} has only "
                             f"{len(values)} values", "wrong length")
        return values[i]

    def _names(self, parent: Any) -> Any:
        for field_name in NAME_FIELDS:
            names = getattr(parent, field_name, None)
            if names is not None:
                return names
        raise FieldError(f"field {self.text!r}: message {type(parent).__name__} has no 'name' list for the "
                         f"lookup [{self.key}]", "missing field", structural=True)


class FieldPath:
    """A parsed field path (``angular_velocity.y``, ``position[elevator]``, ``[2]``, ``data``).

    Parameters
    ----------
    text : str
        The path as written in the config (see the module docstring for the syntax).

    Notes
    -----
    Construct with :meth:`parse`. :meth:`extract` works on any message object that exposes its fields as
    attributes (rosbags dataclasses, rclpy messages) and arrays that support ``len`` and indexing.
    """

    __slots__ = ("text", "steps", "_getters")

    def __init__(self, text: str, steps: tuple[_Step, ...]):
        self.text = text
        self.steps = steps
        self._getters = self._compile()

    @classmethod
    def parse(cls, text: str) -> "FieldPath":
        """Parse ``text``.

        Raises
        ------
        ConfigError
            One line naming the path and the bad part.
        """
        return cls(text.strip() if isinstance(text, str) else text, _parse_steps(text))

    def __repr__(self) -> str:
        return f"FieldPath({self.text!r})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, FieldPath) and other.steps == self.steps

    def __hash__(self) -> int:
        return hash(self.steps)

    @property
    def attributes(self) -> tuple[str, ...]:
        """The attribute names along the path (``('position',)`` for ``position[elevator]``)."""
        return tuple(s.value for s in self.steps if s.kind == "attr")

    @property
    def key(self) -> str | None:
        """The name of a ``[name]`` lookup, if the path has one (the last one)."""
        keys = [s.value for s in self.steps if s.kind == "key"]
        return keys[-1] if keys else None

    @property
    def index(self) -> int | None:
        """The integer index of the last ``[i]`` step, if any."""
        idx = [s.value for s in self.steps if s.kind == "index"]
        return idx[-1] if idx else None

    def _compile(self) -> list[Callable[[Any], Any]]:
        getters: list[Callable[[Any], Any]] = []
        pending: list[str] = []
        steps = self.steps
        for pos, step in enumerate(steps):
            if step.kind == "attr":
                following = steps[pos + 1] if pos + 1 < len(steps) else None
                if following is not None and following.kind == "key":
                    continue  # the lookup reads this attribute from the parent itself
                pending.append(step.value)
                continue
            if pending:
                getters.append(_attr_getter(pending, self.text))
                pending = []
            if step.kind == "index":
                getters.append(_index_getter(step.value, self.text))
            else:
                getters.append(_NameLookup(steps[pos - 1].value, step.value, self.text))
        if pending:
            getters.append(_attr_getter(pending, self.text))
        return getters

    def extract(self, msg: Any) -> float:
        """The value at this path in ``msg`` as a float.

        Raises
        ------
        FieldError
            (a :class:`DataError`) naming the field, the missing joint or the bad index.
        """
        value = msg
        for get in self._getters:
            value = get(value)
        try:
            return float(value)
        except (TypeError, ValueError):
            raise FieldError(f"field {self.text!r}: value is {type(value).__name__}, not a number",
                             "not a number", structural=True) from None


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
    """One configured signal a topic feeds: channel, stream, parsed path and scale (to SI units)."""

    channel: str
    stream: str
    path: FieldPath
    scale: float
    spec: Any = None


class _TopicBuffer:
    """Pending messages of one topic: times and one raw value per route (NaN where extraction failed)."""

    __slots__ = ("t", "rows")

    def __init__(self):
        self.t: list[float] = []
        self.rows: list = []


class _StreamState:
    """Per (channel, stream): last accepted time, samples pushed, NaNs already counted as bad."""

    __slots__ = ("last_t", "good", "precounted")

    def __init__(self):
        self.last_t = -math.inf
        self.good = 0
        self.precounted = 0


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
    their joint, or do not advance in time are dropped and counted with ``validator.count_bad``. A field the
    *message type* does not have raises :class:`FieldError` (``structural``): every message would fail.
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
            topic: tuple(Route(channel, stream, FieldPath.parse(spec.field), float(spec.scale), spec)
                         for channel, stream, spec in entries)
            for topic, entries in config.topics().items()
        }
        self._pending = {topic: _TopicBuffer() for topic in self.routes}
        self._flush_order = sorted(self.routes, key=lambda t: not any(r.stream == "trigger" for r in self.routes[t]))
        self._streams = {(r.channel, r.stream): _StreamState() for routes in self.routes.values() for r in routes}
        self._flush_t: float | None = None
        self.bad: dict[tuple[str, str], dict[str, int]] = {}
        self.first_error: dict[tuple[str, str], str] = {}
        self.messages: dict[str, int] = {topic: 0 for topic in self.routes}
        self.last_time_s = -math.inf

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
            When the message type lacks a configured field (a config / type mismatch).
        """
        routes = self.routes.get(topic)
        if routes is None:
            return
        stamp = stamp_seconds(msg)
        values = []
        for route in routes:
            try:
                values.append(route.path.extract(msg))
            except FieldError as err:
                if err.structural:
                    raise FieldError(f"topic {topic}: {err}", err.reason, structural=True) from None
                key = (route.channel, route.stream)
                self.first_error.setdefault(key, f"topic {topic}: {err}")
                self._count_bad(route, err.reason)
                self._streams[key].precounted += 1
                values.append(math.nan)
        self._queue(topic, receive_time_s if stamp is None else stamp, values)

    def on_values(self, topic: str, t_s: float, values: Any) -> None:
        """Queue already extracted raw values (one per route of ``topic``, in :attr:`routes` order).

        The fast decoders of :mod:`gap_validation.bagio` use this entry; ``t_s`` is the message time (stamp
        or receive time) before :attr:`time_offset_s`, values are before ``scale``.
        """
        if topic in self.routes:
            self._queue(topic, t_s, values)

    def _queue(self, topic: str, t_s: float, values) -> None:
        t_s += self.time_offset_s
        self.messages[topic] += 1
        buf = self._pending[topic]
        buf.t.append(t_s)
        buf.rows.append(values)
        if self._flush_t is None:
            self._flush_t = t_s
        if len(buf.t) >= self.batch or t_s - self._flush_t >= self.max_batch_s:
            self.flush()
            self._flush_t = t_s

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
        t_all = np.asarray(buf.t, dtype=float)
        raw = np.asarray(buf.rows, dtype=float).reshape(t_all.size, -1)
        buf.t, buf.rows = [], []
        for j, route in enumerate(self.routes[topic]):
            state = self._streams[(route.channel, route.stream)]
            values = raw[:, j] * route.scale
            finite = np.isfinite(values) & np.isfinite(t_all)
            n_bad = int(finite.size - np.count_nonzero(finite))
            precounted, state.precounted = state.precounted, 0
            self._count_bad(route, "not finite", n_bad - precounted)
            t, values = t_all[finite], values[finite]
            if t.size == 0:
                continue
            previous = np.maximum.accumulate(np.concatenate(([state.last_t], t[:-1])))
            increasing = t > previous
            self._count_bad(route, "time not increasing", int(t.size - np.count_nonzero(increasing)))
            t, values = t[increasing], values[increasing]
            if t.size == 0:
                continue
            state.last_t = float(t[-1])
            state.good += int(t.size)
            self.last_time_s = max(self.last_time_s, state.last_t)
            self.validator.add_samples(route.channel, route.stream, t,
                                       values != 0.0 if route.stream == "trigger" else values)

    def flush(self) -> None:
        """Push every pending batch to the validator (trigger topics first: a sweep edge must reach the
        estimator before the samples of the same instant)."""
        for topic in self._flush_order:
            buf = self._pending[topic]
            if buf.t:
                self._send_topic(topic, buf)

    def samples(self, channel: str, stream: str) -> int:
        """Samples of ``(channel, stream)`` pushed so far plus the messages still pending for it."""
        state = self._streams.get((channel, stream))
        if state is None:
            return 0
        pending = sum(len(self._pending[topic].t) for topic, routes in self.routes.items()
                      if any((r.channel, r.stream) == (channel, stream) for r in routes))
        return state.good + pending

    def latest_time_s(self) -> float:
        """Latest sample time [s] queued on any topic (``-inf`` before the first sample)."""
        pending = [buf.t[-1] for buf in self._pending.values() if buf.t]
        return max([self.last_time_s, *pending])
