"""Field paths into ROS messages: ``angular_velocity.y``, ``position[elevator]`` (JointState by name),
``[2]``, ``data``. Pure attribute access, so the same :class:`FieldPath` reads rosbags and rclpy message
objects (and the config schema checks the syntax); no ROS import.
"""
from __future__ import annotations

import operator
import re
from dataclasses import dataclass
from typing import Any, Callable

from gap_validation.core.errors import ConfigError, DataError

__all__ = ["FieldError", "FieldPath", "NAME_FIELDS"]

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

    Parameters
    ----------
    message : str
        The one-line message (names the field, joint or index).
    reason : str
        Short tag for bad-sample counts.
    structural : bool
        The message type lacks the field.
    """

    def __init__(self, message: str, reason: str, structural: bool = False) -> None:
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
                raise ConfigError(
                    f"field {text!r}: name lookup [{step.value}] needs the array field before it, "
                    "e.g. position[elevator]"
                )
            steps.append(step)
    return tuple(steps)


def _attr_getter(names: list[str], text: str) -> Callable[[Any], Any]:
    getter = operator.attrgetter(".".join(names))

    def get(obj: Any) -> Any:
        try:
            return getter(obj)
        except AttributeError:
            missing, parent = _first_missing(obj, names)
            where = f"{'.'.join(missing.split('.')[:-1])} " if "." in missing else ""
            raise FieldError(f"field {text!r}: message {type_name(obj)} has no field {missing!r} "
                             f"({where}has: {', '.join(field_names(parent)) or 'no fields'})",
                             "missing field", structural=True) from None

    return get


def _first_missing(obj: Any, names: list[str]) -> tuple[str, Any]:
    """The first missing dotted prefix of ``names`` and the object that lacks it."""
    path = []
    for name in names:
        path.append(name)
        if not hasattr(obj, name):
            return ".".join(path), obj
        obj = getattr(obj, name)
    return ".".join(path), obj  # pragma: no cover (attrgetter failed, so some name was missing)


def type_name(obj: Any) -> str:
    """ROS-style name of a message's type: ``sensor_msgs/msg/Imu`` for rosbags classes, else the class name.

    Parameters
    ----------
    obj : object
        A message object.
    """
    name = type(obj).__name__
    return name.replace("__", "/") if name.count("__") == 2 else name


def field_names(obj: Any) -> list[str]:
    """The fields of a message object: rosbags dataclasses, rclpy messages, or plain objects.

    Parameters
    ----------
    obj : object
        A message object.
    """
    fields = getattr(type(obj), "__dataclass_fields__", None)
    if fields:
        return [name for name in fields if not name.startswith("_")]
    getter = getattr(obj, "get_fields_and_field_types", None)
    if callable(getter):
        try:
            return list(getter())
        except Exception:  # noqa: BLE001 - best effort for the error message only
            pass
    names = getattr(obj, "__dict__", None)
    if isinstance(names, dict):
        return [name for name in names if not name.startswith("_")]
    return []


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
    """``parent.<array>[name]``: index of ``name`` in ``parent.name`` (cached while the order is
    unchanged)."""

    def __init__(self, array: str, key: str, text: str) -> None:
        self.array = array
        self.key = key
        self.text = text
        self.cached = -1

    def __call__(self, parent: Any) -> Any:
        names = self._names(parent)
        try:
            values = getattr(parent, self.array)
        except AttributeError:
            raise FieldError(f"field {self.text!r}: message {type_name(parent)} has no field "
                             f"{self.array!r} (has: {', '.join(field_names(parent)) or 'no fields'})",
                             "missing field", structural=True) from None
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
        raise FieldError(f"field {self.text!r}: message {type_name(parent)} has no 'name' list for the "
                         f"lookup [{self.key}] (has: {', '.join(field_names(parent)) or 'no fields'})",
                         "missing field", structural=True)


class FieldPath:
    """A parsed field path (``angular_velocity.y``, ``position[elevator]``, ``[2]``, ``data``).

    Parameters
    ----------
    text : str
        The path as written in the config (see the module docstring for the syntax).
    steps : tuple
        Its parsed steps (attribute, index or name lookup).

    Notes
    -----
    Construct with :meth:`parse`. :meth:`extract` works on any message object that exposes its fields as
    attributes (rosbags dataclasses, rclpy messages) and arrays that support ``len`` and indexing.
    """

    __slots__ = ("text", "steps", "_getters")

    def __init__(self, text: str, steps: tuple[_Step, ...]) -> None:
        self.text = text
        self.steps = steps
        self._getters = self._compile()

    @classmethod
    def parse(cls, text: str) -> "FieldPath":
        """Parse ``text``.

        Parameters
        ----------
        text : str
            A field path (``angular_velocity.y``, ``position[elevator]``, ``[2]``, ``data``).

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

        Parameters
        ----------
        msg : object
            A rosbags or rclpy message object (or any object with attributes).

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
