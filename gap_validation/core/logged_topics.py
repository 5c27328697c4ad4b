"""Which topics a synthetic flight logs and how they are sampled, ROS-free: the topics, their message types
and fields from the config's signals (:func:`plan_topics`), and each topic published at its own rate with
timestamp jitter, dropped messages and a transport latency (bag time = ``header.stamp`` + latency), its values
in the config's raw units with the mistakes flown (:func:`sample_topics` -> :class:`TopicSeries`).
:func:`with_logged_excitation` adds the injected signal's topic (``--log-excitation``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from gap_validation.core.config import SignalSpec, ValidationConfig
from gap_validation.core.errors import ConfigError
from gap_validation.core.fields import FieldPath
from gap_validation.core.flight_options import FlightOptions
from gap_validation.core.layouts import JOINT_STATE, LAYOUTS, infer_type

__all__ = ["TopicPlan", "TopicSeries", "plan_topics", "sample_topics", "with_logged_excitation"]


@dataclass
class TopicSeries:
    """The messages of one topic: times and the value of every configured field (in message units).

    Attributes
    ----------
    topic, msgtype : str
        Topic name and ROS message type (e.g. ``sensor_msgs/msg/Imu``).
    stamp_s : ndarray
        ``header.stamp`` of each message, absolute [s].
    receive_s : ndarray
        Bag (receive) time of each message, absolute [s], non-decreasing.
    values : dict
        Field path text (as in the config) -> value per message, already divided by the signal's ``scale``.
    joint_names : tuple of str
        JointState ``name`` list (every message carries all of them).
    """

    topic: str
    msgtype: str
    stamp_s: np.ndarray
    receive_s: np.ndarray
    values: dict[str, np.ndarray] = field(default_factory=dict)
    joint_names: tuple[str, ...] = ()

    def __len__(self) -> int:
        return int(self.stamp_s.size)


@dataclass
class TopicPlan:
    """How one topic of a synthetic flight is filled (:func:`plan_topics`).

    Attributes
    ----------
    topic, msgtype : str
        Topic name and ROS message type.
    role : str
        ``"imu"`` (it carries an output: published at the IMU's rate) or ``"surface"``.
    entries : list of tuple
        ``(channel, stream, SignalSpec, FieldPath)`` of every configured signal on the topic.
    joint_names : tuple of str
        JointState ``name`` list (empty for other types).
    """

    topic: str
    msgtype: str
    role: str                                    # "imu" or "surface"
    entries: list[tuple[str, str, SignalSpec, FieldPath]]
    joint_names: tuple[str, ...] = ()


def _infer_type(spec: SignalSpec, path: FieldPath, stream: str) -> str | None:
    return spec.type or infer_type(path, stream)


def _check_field(plan_topic: str, msgtype: str, path: FieldPath) -> None:
    allowed = LAYOUTS[msgtype]
    attrs = path.attributes
    ok = attrs in allowed and all(s.kind == "attr" for s in path.steps)
    if msgtype == JOINT_STATE:
        ok = (len(path.steps) == 2 and attrs in allowed
              and path.steps[1].kind in ("key", "index") and (path.index is None or path.index >= 0))
    if not ok:
        raise ConfigError(f"cannot simulate field {path.text!r} on topic {plan_topic} ({msgtype}); "
                          f"supported: {_supported_text(msgtype)}")


def _supported_text(msgtype: str) -> str:
    if msgtype == JOINT_STATE:
        return "position[name], velocity[name], effort[name] or [index]"
    return ", ".join(sorted(".".join(a) for a in LAYOUTS[msgtype]))


def plan_topics(config: ValidationConfig) -> dict[str, TopicPlan]:
    """Topic -> message type, rate role and the fields to fill, from the config's signals.

    The type is the signal's ``type`` when given, else inferred from the field: ``angular_velocity.*`` and
    friends -> ``sensor_msgs/msg/Imu``, ``position[name]`` -> ``sensor_msgs/msg/JointState``, ``data`` ->
    ``std_msgs/msg/Float64`` (``std_msgs/msg/Bool`` for a trigger).

    Parameters
    ----------
    config : ValidationConfig
        The config whose signals the flight publishes.

    Raises
    ------
    ConfigError
        A topic whose type cannot be inferred or is not supported, or whose signals disagree on the type.
    """
    plans: dict[str, TopicPlan] = {}
    for topic, entries in config.topics().items():
        parsed = [(ch, stream, spec, FieldPath.parse(spec.field)) for ch, stream, spec in entries]
        types = {t for ch, stream, spec, path in parsed if (t := _infer_type(spec, path, stream)) is not None}
        if not types:
            raise ConfigError(f"cannot infer the message type of topic {topic} from field "
                              f"{parsed[0][3].text!r}; set 'type' ({', '.join(LAYOUTS)})")
        if len(types) > 1:
            raise ConfigError(f"topic {topic}: its signals need different message types "
                              f"({', '.join(sorted(types))})")
        msgtype = types.pop()
        if msgtype not in LAYOUTS:
            raise ConfigError(f"cannot simulate topic {topic} of type {msgtype} "
                              f"(supported: {', '.join(LAYOUTS)})")
        for _, _, _, path in parsed:
            _check_field(topic, msgtype, path)
        role = "imu" if any(stream.startswith("output") for _, stream, _, _ in parsed) else "surface"
        plans[topic] = TopicPlan(topic, msgtype, role, parsed, _joint_names(parsed) if msgtype == JOINT_STATE
                                  else ())
    return plans


def _joint_names(parsed) -> tuple[str, ...]:
    names: list[str] = []
    for _, _, _, path in parsed:
        if path.key is not None and path.key not in names:
            names.append(path.key)
    needed = max([path.index + 1 for *_, path in parsed if path.index is not None] or [0])
    k = 0
    while len(names) < needed:
        if f"joint{k}" not in names:
            names.append(f"joint{k}")
        k += 1
    return tuple(names)


def sample_topics(plans: dict, measured: dict, t_s: np.ndarray, duration_s: float, opt: FlightOptions,
                   rng: np.random.Generator) -> dict[str, TopicSeries]:
    """Topic -> :class:`TopicSeries`: each topic of ``plans`` sampled at its rate with jitter, drops and
    latency.

    Parameters
    ----------
    plans : dict
        From :func:`plan_topics`.
    measured : dict
        ``(channel, stream) -> (series on t_s, noise std, lsb)``: the physical quantity (SI units), the white
        sensor noise added at each sample and the quantisation step (0: none).
    t_s : ndarray
        The series' time grid from the flight start [s].
    duration_s : float
        Flight length [s].
    opt : FlightOptions
        Rates, jitter, drops, latency, start time.
    rng : numpy.random.Generator
        The flight's random stream.
    """
    topics = {}
    late = dict(opt.stamp_offsets)
    for topic, plan in plans.items():
        rate = opt.imu_rate_hz if plan.role == "imu" else opt.surface_rate_hz
        stamps, receive = _sample_times(duration_s, rate, opt, rng)
        values = {}
        for name, stream, spec, path in plan.entries:
            series, noise_std, lsb = measured[(name, stream)]
            if stream == "trigger":
                sampled = np.interp(stamps, t_s, series) >= 0.5
                values[spec.field] = sampled.astype(float) / spec.scale
                continue
            sampled = np.interp(stamps, t_s, series) + noise_std * rng.standard_normal(stamps.size)
            if lsb > 0:
                sampled = np.round(sampled / lsb) * lsb
            values[spec.field] = _logged(spec, sampled, name, stream, opt)
        # the config's own time offset is what the stamps lack; a stamp offset flown is a mistake on top of it
        shift = late.get(topic, 0.0) - _topic_time_offset(topic, plan.entries)
        topics[topic] = TopicSeries(topic, plan.msgtype, opt.start_time_s + stamps + shift,
                                    opt.start_time_s + receive, values, plan.joint_names)
    return topics


def _sample_times(duration_s: float, rate_hz: float, opt: FlightOptions, rng: np.random.Generator):
    """Nominal sample instants with jitter and drops, and receive times with latency (both relative) [s]."""
    period = 1.0 / rate_hz
    nominal = np.arange(float(rng.uniform(0.0, period)), duration_s, period)
    jitter = np.clip(rng.standard_normal(nominal.size) * opt.jitter_s, -period / 3, period / 3)
    stamps = nominal + jitter
    keep = rng.random(nominal.size) >= opt.drop_probability
    stamps = stamps[keep]
    latency = opt.latency_s + rng.exponential(opt.latency_jitter_s, stamps.size) if opt.latency_jitter_s > 0 \
        else np.full(stamps.size, opt.latency_s)
    receive = np.maximum.accumulate(stamps + latency)
    return stamps, receive


def _logged(spec: SignalSpec, value: np.ndarray, channel: str, stream: str, opt: FlightOptions) -> np.ndarray:
    """What a topic carries for a signal ``value`` (SI, the models' frame): the config's raw units
    (:meth:`SignalSpec.raw`), then the mistakes flown (:class:`FlightOptions`: a reversed stream, surfaces in
    degrees, rates in ROS's body frame)."""
    raw = spec.raw(value)
    if (channel, stream) in opt.flips:
        raw = -raw
    if opt.surfaces_in_degrees and stream == "input":
        raw = raw * (180.0 / math.pi)
    if opt.imu_frame == "flu" and stream == "output" and spec.field.rsplit(".", 1)[-1] in ("y", "z"):
        raw = -raw
    return raw


def _topic_time_offset(topic: str, entries) -> float:
    """The config's ``time_offset_s`` of a topic's streams (one value: the stamps are the topic's)."""
    offsets = {float(spec.time_offset_s) for _, stream, spec, _ in entries if stream != "trigger"}
    if len(offsets) > 1:
        raise ConfigError(
            f"simulate: the streams of {topic} have different time_offset_s ({sorted(offsets)}): a "
            f"simulated topic has one clock"
        )
    return offsets.pop() if offsets else 0.0


def with_logged_excitation(config: ValidationConfig, topic: str | None) -> ValidationConfig:
    """The config with every channel's injected signal logged on ``topic`` (``--log-excitation``): a channel
    without ``excitation`` gets one there, with its input's field (a JointState joint), else ``data`` on
    ``TOPIC/<channel>``.

    Parameters
    ----------
    config : ValidationConfig
        The config flown.
    topic : str, optional
        The ``--log-excitation`` topic (None: ``config`` as it is).
    """
    if not topic:
        return config
    topic = topic if topic.startswith("/") else "/" + topic
    channels = {}
    for name, ch in config.channels.items():
        if ch.excitation is None and ch.input is not None:
            path = FieldPath.parse(ch.input.field)
            spec = SignalSpec(topic, ch.input.field, ch.input.scale) if path.key is not None or \
                path.index is not None else SignalSpec(f"{topic}/{name}", "data", ch.input.scale)
            ch = replace(ch, excitation=spec)
        channels[name] = ch
    return replace(config, channels=channels)
