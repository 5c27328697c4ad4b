"""Message types of the node's topics: rclpy message classes by name, and the configured fields checked on
them.

The node subscribes to every topic at start-up, so that no message is lost from the first one on
(:func:`topic_types`): with the type the config names (``type:``), else the type the field paths imply
(:func:`gap_validation.core.layouts.infer_type`: ``angular_velocity.*`` -> ``sensor_msgs/msg/Imu``,
``position[...]`` -> ``sensor_msgs/msg/JointState``, ``data`` -> ``std_msgs/msg/Float64``); only a topic whose
fields imply nothing waits for its type to appear on the graph. An implied type is a guess: when the graph
shows publishers of another type, the node re-subscribes with theirs. A type must be installed (its Python
message package importable) and carry every configured field; both are checked before anything is subscribed,
so a wrong type or field is one line at startup or reload. Imports the message packages by name
(``sensor_msgs.msg`` ...), not rclpy.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Iterable

from gap_validation.core.config import SignalSpec, ValidationConfig
from gap_validation.core.errors import ConfigError, one_line
from gap_validation.core.fields import FieldError, FieldPath
from gap_validation.core.layouts import infer_type

__all__ = ["message_class", "check_fields", "resolve_types", "topic_types", "TopicType", "fields_fit"]


@dataclass(frozen=True)
class TopicType:
    """The type a topic is subscribed with, and where it comes from.

    Attributes
    ----------
    name : str or None
        ``pkg/msg/Name``; None: not known yet (discovered from the graph).
    source : {"config", "fields", "graph", None}
        The config's ``type``, implied by the field paths, or seen on the graph.
    """

    name: str | None
    source: str | None = None


def message_class(type_name: str) -> type:
    """The rclpy message class of ``pkg/msg/Name`` (``pkg/Name`` accepted).

    Parameters
    ----------
    type_name : str
        The message type.

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


def check_fields(topic: str, cls: type, entries: Iterable[tuple[str, str, SignalSpec]]) -> None:
    """ConfigError when ``cls`` lacks a configured field (checked on a default message).

    Parameters
    ----------
    topic : str
        The topic (for the message).
    cls : type
        Its message class.
    entries : iterable of (channel, stream, SignalSpec)
        What the topic feeds (:meth:`ValidationConfig.topics`).
    """
    sample = cls()
    for channel, stream, spec in entries:
        try:
            FieldPath.parse(spec.field).extract(sample)
        except FieldError as err:
            if err.structural:
                raise ConfigError(
                    f"channels.{channel}.{stream}: topic {topic} ({cls.__name__}): {err}"
                ) from None


def resolve_types(config: ValidationConfig) -> dict[str, str | None]:
    """Topic -> type from the config's ``type`` keys (None: discover it from the graph), each type installed
    and carrying the configured fields.

    Parameters
    ----------
    config : ValidationConfig
        The validation config.

    Raises
    ------
    ConfigError
        Two signals of a topic naming different types; a type not installed or lacking a configured field.
    """
    topics = config.topics()
    out: dict[str, str | None] = {}
    for topic, entries in topics.items():
        types = {spec.type for _, _, spec in entries if spec.type}
        if len(types) > 1:
            raise ConfigError(f"{config.source}: topic {topic}: conflicting types {', '.join(sorted(types))}")
        out[topic] = types.pop() if types else None
    for topic, type_name in out.items():
        if type_name is not None:
            check_fields(topic, message_class(type_name), topics[topic])
    return out


def fields_fit(topic: str, type_name: str, entries: Iterable[tuple[str, str, SignalSpec]]) -> bool:
    """Whether ``type_name`` is installed and carries every configured field of ``topic`` (no exception).

    Parameters
    ----------
    topic : str
        The topic.
    type_name : str
        A message type (``pkg/msg/Name``).
    entries : iterable of (channel, stream, SignalSpec)
        What the topic feeds (:meth:`ValidationConfig.topics`).
    """
    try:
        check_fields(topic, message_class(type_name), entries)
    except ConfigError:
        return False
    return True


def topic_types(config: ValidationConfig) -> dict[str, TopicType]:
    """Topic -> the type to subscribe with at once: the config's ``type``, else the one the fields imply.

    Parameters
    ----------
    config : ValidationConfig
        The validation config.

    Returns
    -------
    dict
        Topic -> :class:`TopicType` (``name`` None when neither the config nor the fields say; the node then
        discovers it from the graph).

    Raises
    ------
    ConfigError
        As :func:`resolve_types` (conflicting or uninstalled config types, fields a config type lacks).
    """
    named = resolve_types(config)
    topics = config.topics()
    out: dict[str, TopicType] = {}
    for topic, type_name in named.items():
        if type_name is not None:
            out[topic] = TopicType(type_name, "config")
            continue
        implied = set()
        for _, stream, spec in topics[topic]:
            try:
                implied.add(infer_type(FieldPath.parse(spec.field), stream))
            except ConfigError:
                implied.add(None)
        guess = implied.pop() if len(implied) == 1 else None
        if guess is not None and fields_fit(topic, guess, topics[topic]):
            out[topic] = TopicType(guess, "fields")
        else:
            out[topic] = TopicType(None)
    return out
