"""A simulated flight written as an autopilot's flight log, and the config that reads it back.

:func:`~gap_validation.core.simulation.simulate_flight` flies the test card for a config whose streams are ROS
topics (an IMU, the control surfaces); :func:`write_flight_log` puts every stream under the autopilot's own
name, unit and frame (:func:`log_layout`) and writes the matching config (the same channels and models, the
streams renamed, with the ``offset`` and ``scale`` that turn the logged values back into radians), so a replay
of the log sees the same samples as a replay of the bag, up to the format's precision:

============  ==========================================  ==================================================
format        rates (output, rad/s, FRD body axes)        surfaces (input)
============  ==========================================  ==================================================
``ulog``      ``vehicle_angular_velocity`` ``xyz[0..2]``  ``actuator_servos`` ``control[k]``: -1..1, scale
                                                          :data:`SERVO_RANGE_RAD` rad per unit
``dataflash`` ``IMU`` ``GyrX``, ``GyrY``, ``GyrZ``         ``RCOU`` ``C1``, ``C2``, ``C4`` (aileron, elevator,
                                                          rudder): PWM, 1500 +- 500 us for +-
                                                          :data:`SERVO_RANGE_RAD`: offset -1500, scale 0.0007
``dataflash`` (with an injected excitation: the copter     ``RATE`` ``ROut``, ``POut``, ``YOut`` (-1..1, scale
              SystemID layout) ``IMU`` as above            :data:`SERVO_RANGE_RAD`); excitation ``SIDD``
                                                          ``Targ``
``csv``       one file per topic of the config: ``imu.csv`` ``control_surfaces.csv``: a column per joint [rad]
              with ``p``, ``q``, ``r``
============  ==========================================  ==================================================

Times are microseconds on the autopilot's clock: the flight starts :data:`BOOT_S` after boot (a log's clock
counts from power-on), each sample at its stamp. ``k`` of ``control[k]`` is the servo's index in the
airframe's control allocation (PX4 ``CA_SV_CS<k>_TYPE``); here aileron 0, elevator 1, rudder 2.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from gap_validation.core.config import EXCITATION_STREAM, SignalSpec, ValidationConfig
from gap_validation.core.errors import ConfigError
from gap_validation.core.fields import FieldPath
from gap_validation.core.logged_topics import with_logged_excitation
from gap_validation.core.simulation import SimulatedFlight
from gap_validation.logs.base import WriteTopic

__all__ = [
    "FORMATS",
    "SURFACE_RATE_HZ",
    "SERVO_RANGE_RAD",
    "BOOT_S",
    "LogSignal",
    "log_layout",
    "flight_topics",
    "as_autopilot_logs",
    "log_config",
    "config_text",
    "write_flight_log",
    "log_path",
    "with_logged_excitation",
]

#: Log formats a simulated flight can be written in (besides a bag).
FORMATS = ("ulog", "dataflash", "csv")
#: The surfaces' logging rate of each autopilot by default [Hz]: PX4's logger writes ``actuator_servos`` every
#: 100 ms; ArduPlane writes ``RCOU`` in its 25 Hz logging task. CSV: the simulator's own default.
SURFACE_RATE_HZ = {"ulog": 10.0, "dataflash": 25.0}
#: Full deflection of every surface [rad] (20 deg): a normalised servo command of 1, or 500 us of PWM.
SERVO_RANGE_RAD = 0.35
#: PWM centre and half range [us].
PWM_CENTRE_US, PWM_HALF_RANGE_US = 1500.0, 500.0
#: The log's clock at the flight's start [s]: the autopilot booted a minute before.
BOOT_S = 60.0

_AXES = ("roll", "pitch", "yaw")
_JOINT_AXIS = {"aileron": 0, "elevator": 1, "rudder": 2}
_PX4_SERVO = (0, 1, 2)                 # control[k] of aileron, elevator, rudder
_RCOU = ("C1", "C2", "C4")             # ArduPlane's default RC1 roll, RC2 pitch, RC4 yaw
_GYRO = ("GyrX", "GyrY", "GyrZ")
_RATE_OUT = ("ROut", "POut", "YOut")
_CSV_RATES = ("p", "q", "r")


@dataclass(frozen=True)
class LogSignal:
    """Where one stream goes in a log: topic, field, and what turns the logged value back into SI units,
    ``value = (raw + offset) * scale``.

    Attributes
    ----------
    topic, field : str
        As the log names them.
    scale, offset : float
        As in the config.
    unit : str
        The logged unit (for the config's comment and the log's units).
    source : str
        The config topic whose stamps the log topic takes.
    """

    topic: str
    field: str
    scale: float = 1.0
    offset: float = 0.0
    unit: str = ""
    source: str = ""

    def raw(self, value: np.ndarray) -> np.ndarray:
        """The logged values for SI ``value``.

        Parameters
        ----------
        value : numpy.ndarray
            Values in SI units (rad, rad/s, m/s).
        """
        return np.asarray(value, float) / self.scale - self.offset



def _streams(config: ValidationConfig):
    """``(channel, stream, spec, kind)`` of every stream; kind ``surface``, ``rate``, ``excitation``,
    ``trigger`` or ``airspeed``."""
    for name, ch in config.channels.items():
        for stream in ch.input_streams:
            yield name, stream, ch.signal(stream), "surface"
        for stream in ch.output_streams:
            yield name, stream, ch.signal(stream), "rate"
        if ch.trigger is not None:
            yield name, "trigger", ch.trigger, "trigger"
        for stream, spec in ch.extra_streams():
            kind = (
                "excitation"
                if stream == EXCITATION_STREAM
                else "airspeed"
                if stream == "airspeed"
                else "surface"
            )
            yield name, stream, spec, kind


def _rate_axis(channel: str, spec: SignalSpec) -> int:
    last = spec.field.rsplit(".", 1)[-1]
    if last in ("x", "y", "z"):
        return "xyz".index(last)
    if channel in _AXES:
        return _AXES.index(channel)
    raise ConfigError(
        f"channel {channel}: cannot tell which body axis {spec.topic} {spec.field!r} is (expected a "
        f"field ending in .x, .y or .z, or a channel named roll, pitch or yaw)"
    )


def _surface_axis(config: ValidationConfig, channel: str, stream: str, spec: SignalSpec) -> int:
    key = FieldPath.parse(spec.field).key
    if key in _JOINT_AXIS:
        return _JOINT_AXIS[key]
    ch = config.channels[channel]
    if ch.is_mimo and stream.startswith("inputs["):
        return int(stream[len("inputs["):-1]) % 3
    return _rate_axis(channel, ch.signal(ch.output_streams[0]))


def _surface_name(spec: SignalSpec, channel: str, stream: str) -> str:
    key = FieldPath.parse(spec.field).key
    return key if key else f"{channel}_{stream.replace('[', '').replace(']', '')}"


def log_layout(config: ValidationConfig, fmt: str) -> tuple[dict[tuple[str, str], LogSignal], str]:
    """Where every stream of ``config`` goes in a log of format ``fmt``, and the layout's name.

    Parameters
    ----------
    config : ValidationConfig
        The config the flight was flown for (with the logged excitation, :func:`with_logged_excitation`).
    fmt : str
        ``ulog``, ``dataflash`` or ``csv``.

    Returns
    -------
    layout : dict
        ``(channel, stream)`` -> :class:`LogSignal`.
    name : str
        ``PX4``, ``ArduPlane``, ``ArduCopter SystemID`` or ``CSV``.

    Raises
    ------
    ConfigError
        A stream the format has no place for (a trigger in an autopilot's log), a rate without a body axis,
        two different signals on one log field, a log topic from config topics of different stamps, several
        excitations in an ArduPilot SystemID log.
    """
    if fmt not in FORMATS:
        raise ConfigError(f"--format {fmt}: expected one of bag, {', '.join(FORMATS)}")
    excited = [name for name, ch in config.channels.items() if ch.excitation is not None]
    sysid = fmt == "dataflash" and bool(excited)
    if sysid and len(excited) > 1:
        raise ConfigError(
            f"simulate --format dataflash: channels {', '.join(excited)} each have an injected "
            f"excitation, but ArduPilot's SystemID mode excites one axis per run (SID_AXIS) and logs "
            f"it in one SIDD.Targ: simulate one channel (a config with only that channel), or write "
            f"ulog, csv or a bag"
        )
    name = {"ulog": "PX4", "csv": "CSV"}.get(fmt, "ArduCopter SystemID" if sysid else "ArduPlane")
    layout: dict[tuple[str, str], LogSignal] = {}
    taken: dict[tuple[str, str], tuple[str, str]] = {}          # log (topic, field) -> source (topic, field)
    clocks: dict[str, str] = {}                                  # log topic -> the config topic of its stamps
    for channel, stream, spec, kind in _streams(config):
        source = (spec.topic, spec.field)
        signal = _place(config, fmt, sysid, channel, stream, spec, kind)
        key = (signal.topic, signal.field)
        if kind == "surface" and key in taken and taken[key] != source:
            signal = _next_free(signal, taken, fmt, source)
            key = (signal.topic, signal.field)
        if key in taken and taken[key] != source and kind != "excitation":
            raise ConfigError(
                f"simulate --format {fmt}: {channel}.{stream} ({spec.topic} {spec.field!r}) and "
                f"{taken[key][0]} {taken[key][1]!r} both go to {signal.topic} {signal.field}"
            )
        taken.setdefault(key, source)
        if clocks.setdefault(signal.topic, spec.topic) != spec.topic:
            raise ConfigError(
                f"simulate --format {fmt}: log topic {signal.topic} would take {spec.topic} and "
                f"{clocks[signal.topic]}, whose stamps differ (a log topic has one clock); put those "
                f"signals on one topic in the config"
            )
        layout[(channel, stream)] = signal
    return layout, name


def _place(
    config, fmt: str, sysid: bool, channel: str, stream: str, spec: SignalSpec, kind: str
) -> LogSignal:
    """The :class:`LogSignal` of one stream (before clashes are resolved)."""
    src = spec.topic
    if fmt == "csv":
        topic = src.strip("/").replace("/", "_") or "topic"
        if kind == "rate":
            return LogSignal(topic, _CSV_RATES[_rate_axis(channel, spec)], unit="rad/s", source=src)
        if kind == "surface":
            return LogSignal(topic, _surface_name(spec, channel, stream), unit="rad", source=src)
        field = {"excitation": channel, "trigger": channel, "airspeed": "airspeed"}[kind]
        return LogSignal(topic, field, unit={"airspeed": "m/s", "trigger": "1"}.get(kind, "rad"), source=src)
    if kind == "trigger":
        raise ConfigError(
            f"simulate --format {fmt}: channel {channel} has a trigger, which an autopilot does not log; "
            f"drop channels.{channel}.trigger (manoeuvres are detected), or write csv or a bag"
        )
    if kind == "airspeed":
        return (
            LogSignal("airspeed_validated", "true_airspeed_m_s", unit="m/s", source=src)
            if fmt == "ulog"
            else LogSignal("ARSP", "Airspeed", unit="m/s", source=src)
        )
    if kind == "rate":
        axis = _rate_axis(channel, spec)
        return (
            LogSignal("vehicle_angular_velocity", f"xyz[{axis}]", unit="rad/s", source=src)
            if fmt == "ulog"
            else LogSignal("IMU", _GYRO[axis], unit="rad/s", source=src)
        )
    axis = _surface_axis(config, channel, stream, spec) if kind == "surface" else _rate_axis(
        channel, config.channels[channel].signal(config.channels[channel].output_streams[0]))
    if kind == "excitation":
        if fmt == "ulog":
            return LogSignal(
                "autotune_attitude_control_status", f"rate_sp[{axis}]", SERVO_RANGE_RAD, unit="1", source=src
            )
        return LogSignal("SIDD", "Targ", SERVO_RANGE_RAD, unit="1", source=src)
    if fmt == "ulog":
        return LogSignal(
            "actuator_servos", f"control[{_PX4_SERVO[axis]}]", SERVO_RANGE_RAD, unit="1", source=src
        )
    if sysid:
        return LogSignal("RATE", _RATE_OUT[axis], SERVO_RANGE_RAD, unit="1", source=src)
    return LogSignal(
        "RCOU", _RCOU[axis], SERVO_RANGE_RAD / PWM_HALF_RANGE_US, -PWM_CENTRE_US, unit="us", source=src
    )


def _next_free(signal: LogSignal, taken: dict, fmt: str, source: tuple[str, str]) -> LogSignal:
    """Another servo output for a surface whose usual one carries a different signal."""
    if fmt == "ulog":
        names = [f"control[{k}]" for k in range(8)]
    elif signal.topic == "RCOU":
        names = [f"C{k}" for k in range(1, 15)]
    else:
        return signal
    for name in names:
        if taken.get((signal.topic, name), source) == source:
            return replace(signal, field=name)
    return signal


def flight_topics(flight: SimulatedFlight, config: ValidationConfig, layout: dict[tuple[str, str], LogSignal]
                  ) -> list[WriteTopic]:
    """The flight's samples as log topics: each at its stamps on the log's clock (:data:`BOOT_S` after boot at
    the flight's start, microseconds), each value converted to SI by its config stream and to the log's unit
    by its :class:`LogSignal` (signals sharing a field, the SystemID excitation of every axis, are summed).

    Parameters
    ----------
    flight : SimulatedFlight
        The simulated flight.
    config : ValidationConfig
        The config it was flown for (with the logged excitation).
    layout : dict
        From :func:`log_layout`.

    Raises
    ------
    ConfigError
        A log topic whose fields come from config topics with different stamps (a log topic has one clock).
    """
    topics: dict[str, WriteTopic] = {}
    sources: dict[str, str] = {}
    counted: set[tuple[str, str, str, str]] = set()
    for channel, stream, spec, _ in _streams(config):
        signal = layout[(channel, stream)]
        series = flight.topics[spec.topic]
        if sources.setdefault(signal.topic, spec.topic) != spec.topic:
            raise ConfigError(
                f"simulate: log topic {signal.topic} would take {spec.topic} and "
                f"{sources[signal.topic]}, whose stamps differ (a log topic has one clock); put those "
                f"signals on one topic in the config"
            )
        if signal.topic not in topics:
            t_us = np.round((series.stamp_s - flight.start_time_s + BOOT_S) * 1e6).astype(np.int64)
            topics[signal.topic] = WriteTopic(signal.topic, t_us)
        topic = topics[signal.topic]
        once = (signal.topic, signal.field, spec.topic, spec.field)
        if once in counted:
            continue
        counted.add(once)
        value = spec.value(np.asarray(series.values[spec.field], float))
        raw = signal.raw(value)
        if signal.field in topic.fields:             # the SystemID excitation of each axis: one Targ
            topic.fields[signal.field] = topic.fields[signal.field] + value / signal.scale
        else:
            topic.fields[signal.field] = raw
        if signal.unit:
            topic.units[signal.field] = signal.unit
    return [topics[name] for name in sorted(topics)]


#: The fields of each autopilot topic the simulator writes, in the autopilot's order: a field the flight has
#: no signal for is NaN (a float: "no value", as PX4 marks an unused servo), or 0 for a PWM output.
_FULL_TOPICS = {
    "ulog": {"vehicle_angular_velocity": [f"xyz[{k}]" for k in range(3)],
             "actuator_servos": [f"control[{k}]" for k in range(8)],
             "autotune_attitude_control_status": [f"rate_sp[{k}]" for k in range(3)]},
    "dataflash": {"IMU": list(_GYRO), "RCOU": [f"C{k}" for k in range(1, 9)], "RATE": list(_RATE_OUT)},
}
#: ULog topics whose messages carry ``timestamp_sample`` (the sample's time, which replay reads).
_SAMPLED = ("vehicle_angular_velocity", "actuator_servos")


def as_autopilot_logs(topics: list[WriteTopic], fmt: str) -> list[WriteTopic]:
    """The topics with the autopilot's types and whole field sets: float32 values (PX4 and ArduPilot log
    floats as ``float``), every element of an array (``xyz[0..2]``, ``control[0..7]``) and PX4's
    ``timestamp_sample``; CSV as it is (float64).

    Parameters
    ----------
    topics : list of WriteTopic
        From :func:`flight_topics`.
    fmt : str
        ``ulog``, ``dataflash`` or ``csv``.
    """
    if fmt == "csv":
        return topics
    out = []
    for topic in topics:
        names = _FULL_TOPICS.get(fmt, {}).get(topic.name, [])
        names = names + [n for n in topic.fields if n not in names]
        n = topic.t_us.size
        fields: dict[str, np.ndarray] = {}
        if fmt == "ulog" and topic.name in _SAMPLED:
            fields["timestamp_sample"] = topic.t_us.astype(np.uint64)
        for name in names:
            if name in topic.fields:
                fields[name] = np.asarray(
                    topic.fields[name], np.float64 if topic.name == "RCOU" else np.float32
                )
            else:
                fields[name] = np.zeros(n) if topic.name == "RCOU" else np.full(n, np.nan, np.float32)
        out.append(WriteTopic(topic.name, topic.t_us, fields, dict(topic.units)))
    return out


def _signal_mapping(signal: LogSignal, spec: SignalSpec, extra: dict | None = None) -> dict:
    out = {"topic": signal.topic, "field": signal.field}
    if signal.scale != 1.0:
        out["scale"] = float(f"{signal.scale:.12g}")
    if signal.offset:
        out["offset"] = float(signal.offset)
    if spec.time_offset_s:
        out["time_offset_s"] = spec.time_offset_s
    out.update(extra or {})
    return out


def log_config(config: ValidationConfig, layout: dict[tuple[str, str], LogSignal], source: str = "") -> dict:
    """The config (as a mapping) that reads the log: ``config``'s channels, models and settings with every
    stream renamed to its :class:`LogSignal` (no ``type`` or ``frame``: the log's rates are FRD already).

    Parameters
    ----------
    config : ValidationConfig
        The config flown (with the logged excitation).
    layout : dict
        From :func:`log_layout`.
    source : str
        What it was written from (for its ``description``).
    """
    raw = copy.deepcopy(config.raw)
    for name, ch in config.channels.items():
        data = raw["channels"][name]
        for stream in ch.input_streams + ch.output_streams:
            spec = ch.signal(stream)
            mapping = _signal_mapping(layout[(name, stream)], spec)
            if ch.is_mimo:
                kind, index = stream.split("[")
                data[kind][int(index[:-1])] = mapping
            else:
                data[stream] = mapping
        if ch.trigger is not None:
            data["trigger"] = _signal_mapping(layout[(name, "trigger")], ch.trigger)
        for stream, spec in ch.extra_streams():
            mapping = _signal_mapping(layout[(name, stream)], spec)
            if stream == EXCITATION_STREAM:
                data["excitation"] = mapping
            elif stream == "airspeed":
                data["airspeed"] = {**mapping, "trim_m_s": ch.trim_airspeed_m_s}
            else:
                data["other_inputs"][int(stream[len("other_input"):])] = mapping
    if source:
        raw["description"] = f"written by gap-validate simulate from {source}"
    return raw


_HEADERS = {
    "PX4": [
        "PX4 ULog streams (gap-validate simulate --format ulog).",
        "vehicle_angular_velocity xyz[0], xyz[1], xyz[2]: body rates p, q, r [rad/s], FRD body axes (x "
        "forward,",
        "  y right, z down); time: timestamp_sample [us].",
        "actuator_servos control[k]: normalised servo command, -1..1; scale {range:g} rad per unit (+-1 is "
        "+-{deg:.0f}",
        "  deg of deflection: put your servos' range here); k as the airframe's CA_SV_CS<k>_TYPE orders them",
        "  (here 0 aileron, 1 elevator, 2 rudder). PX4 logs it every 100 ms (10 Hz) by default: its Nyquist",
        "  frequency bounds the band (sweeps validated up to 28.6 rad/s, with the gyro at 40 Hz or faster);",
        "  SDLOG_PROFILE's high-rate bit (+16) logs it at full rate.",
    ],
    "ArduPlane": [
        "ArduPilot (ArduPlane) DataFlash streams (gap-validate simulate --format dataflash).",
        "IMU GyrX, GyrY, GyrZ: body rates p, q, r [rad/s], FRD body axes (x forward, y right, z down);",
        "  time: TimeUS [us]. IMU[1] is the second IMU.",
        "RCOU C1, C2, C4: servo PWM [us] of RC1 (aileron), RC2 (elevator), RC4 (rudder); 1500 +- 500 us is",
        "  +-{range:g} rad: offset -1500 us, scale {pwm:g} rad/us (put your servos' centre and range here).",
        "  ArduPlane writes RCOU at 25 Hz (LOG_BITMASK RC): the band ends at 62.8 rad/s (sweeps validated up",
        "  to 57 rad/s, with IMU at 80 Hz or faster; else 35.7 rad/s).",
    ],
    "ArduCopter SystemID": [
        "ArduPilot (ArduCopter SystemID mode) DataFlash streams (gap-validate simulate --format dataflash "
        "with an",
        "injected excitation).",
        "IMU GyrX, GyrY, GyrZ: body rates p, q, r [rad/s], FRD body axes (x forward, y right, z down); time "
        "TimeUS",
        "  [us]. (SIDD Gx, Gy, Gz carry the same rates in deg/s: scale 0.0174533.)",
        "RATE ROut, POut, YOut: the rate controllers' outputs to the mixer, -1..1 (the plant's input, with "
        "the",
        "  injected signal of a mixer axis); scale {range:g} rad per unit here.",
        "SIDD Targ: the SystemID mode's injected signal (SID_AXIS 10-12: mixer roll, pitch, yaw), the "
        "estimator's",
        "  instrument: the plant is measured inside the closed rate loop without feedback bias. SystemID "
        "excites",
        "  one axis per run (SIDS Ax says which): one channel per config and log.",
    ],
    "CSV": [
        "CSV streams (gap-validate simulate --format csv): one file per topic, TimeUS [us] first.",
        "imu.csv p, q, r: body rates [rad/s], FRD body axes (x forward, y right, z down).",
        "control_surfaces.csv: one column per surface [rad].",
    ],
}


def config_text(raw: dict, layout_name: str) -> str:
    """The config as YAML text, its units and frames stated in a header comment.

    Parameters
    ----------
    raw : dict
        From :func:`log_config`.
    layout_name : str
        From :func:`log_layout`.
    """
    import yaml

    header = [line.format(range=SERVO_RANGE_RAD, deg=math.degrees(SERVO_RANGE_RAD),
                          pwm=SERVO_RANGE_RAD / PWM_HALF_RANGE_US) for line in _HEADERS[layout_name]]
    body = yaml.safe_dump(raw, sort_keys=False, default_flow_style=None, width=120)
    return "".join(f"# {line}\n" for line in header) + body


def log_path(out: str | Path, fmt: str) -> Path:
    """The log ``--out`` names for ``fmt``: ``.ulg``/``.bin`` added when missing; a CSV flight is a directory.

    Parameters
    ----------
    out : str or Path
        The ``--out`` argument.
    fmt : str
        ``ulog``, ``dataflash`` or ``csv``.
    """
    out = Path(out)
    suffix = {"ulog": ".ulg", "dataflash": ".bin"}.get(fmt)
    if suffix and out.suffix.lower() != suffix:
        out = out.with_name(out.name + suffix)
    return out


def write_flight_log(flight: SimulatedFlight, config: ValidationConfig, out: str | Path, fmt: str,
                     source: str = "") -> tuple[Path, Path, str]:
    """Write ``flight`` as a log of format ``fmt`` and its config beside it (``<log>.yaml``).

    Parameters
    ----------
    flight : SimulatedFlight
        The simulated flight.
    config : ValidationConfig
        The config it was flown for (the logged excitation is added from the flight's options).
    out : str or Path
        The log file (``.ulg``, ``.bin``) or, for CSV, the directory.
    fmt : str
        ``ulog``, ``dataflash`` or ``csv``.
    source : str
        The config's file (named in the written config's description).

    Returns
    -------
    log : Path
        The log written.
    config_path : Path
        Its config.
    layout : str
        The layout's name (``PX4``, ``ArduPlane``, ``ArduCopter SystemID``, ``CSV``).
    """
    config = with_logged_excitation(config, flight.options.log_excitation_topic)
    layout, name = log_layout(config, fmt)
    topics = as_autopilot_logs(flight_topics(flight, config, layout), fmt)
    out = log_path(out, fmt)
    start_us = int(round(BOOT_S * 1e6))
    if fmt == "ulog":
        from gap_validation.logs.ulog import write_ulog

        write_ulog(
            out, topics, start_us=start_us, info={"sys_name": "PX4", "ver_hw": "gap-validate simulate"}
        )
    elif fmt == "dataflash":
        from gap_validation.logs.dataflash import write_dataflash

        write_dataflash(out, topics)            # TimeUS = t_us: the boot clock already
    else:
        from gap_validation.logs.csvlog import write_csv

        write_csv(out, topics)
    cfg_path = Path(str(out) + ".yaml")
    from gap_validation.core.config import parse_config

    raw = log_config(config, layout, source)
    parse_config(copy.deepcopy(raw), str(cfg_path))          # never write a config that would not load
    cfg_path.write_text(config_text(raw, name), encoding="utf-8")
    return out, cfg_path, name
