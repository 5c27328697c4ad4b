"""Message types of the node's topics: rclpy message classes by name, and the configured fields checked on them.

The config may name a topic's ``type`` (else the node discovers it from the graph). A type must be installed
(its Python message package importable) and carry every configured field; both are checked before anything is
subscribed, so a wrong type or field is one line at startup or reload. Imports the message packages by name
(``sensor_msgs.msg`` ...), not rclpy.
"""
from __future__ import annotations

import importlib
from typing import Iterable

from gap_validation.core.config import SignalSpec, ValidationConfig
from gap_validation.core.errors import ConfigError, one_line
from gap_validation.core.fields import FieldError, FieldPath

__all__ = ["message_class", "check_fields", "resolve_types"]


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
                raise ConfigError(f"channels.{channel}.{stream}: topic {topic} ({cls.__name__}): {err}") from None


def resolve_types(config: ValidationConfig) -> dict[str, str | None]:
    """Topic -> type from the config's ``type`` keys (None: discover it from the graph), each type installed and
    carrying the configured fields.

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
