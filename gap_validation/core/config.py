"""Validation config: the schema of DESIGN.md as frozen dataclasses, with one-line errors.

The CLI, the node and the library read the same file (YAML, loaded by :func:`load_config`, which imports yaml
only when it reads a file; :func:`parse_config` validates an already-loaded mapping and needs neither yaml nor
ROS). Every error names the file,
the key path and the offending value, e.g. ``cfg.yaml: channels.pitch.input.field: expected a string, got 3``.
Unknown keys are errors (a typo must not silently fall back to a default).

A channel is SISO (``input``/``output``, a :class:`~gap_validation.core.models.LinearModel`) or MIMO
(``inputs``/``outputs`` lists, a :class:`~gap_validation.core.models.MimoModel` whose B columns and C rows
follow the lists). An optional ``controller`` (``u = -C y``, negative feedback) maps the outputs to the
inputs: a SISO model mapping, or for a MIMO channel a MIMO one (``B`` columns = outputs, ``C`` rows = inputs).
MIMO channels are compared model against model (``compare-models``) and validated from flight data (streams
``inputs[j]`` and ``outputs[i]``, :meth:`ChannelConfig.input_streams`).
"""
from __future__ import annotations

import copy
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gap_validation.core.atomic import atomic_write_text
from gap_validation.core.errors import ConfigError, DataError
from gap_validation.core.models import LinearModel, MimoModel
from gap_validation.core.numbers import FINITE, NONZERO, POSITIVE, Interval, check_number

#: Streams a channel has: the surface (input), the rate (output) and the optional sweep trigger.
STREAMS = ("input", "output", "trigger")

_TOP_KEYS = {"channels", "aircraft", "description", "history"}
_CHANNEL_KEYS = {
    "input",
    "output",
    "inputs",
    "outputs",
    "model",
    "frequencies",
    "coherence_threshold",
    "trigger",
    "estimator",
    "controller",
    "excitation",
    "other_inputs",
    "airspeed",
}
#: Stream name of the channel's injected excitation (closed-loop flights; the estimator's instrument).
EXCITATION_STREAM = "excitation"
#: Stream of a channel's ``airspeed`` (the flight condition: the inputs are scaled by the dynamic pressure
#: ratio).
AIRSPEED_STREAM = "airspeed"
#: Stream name of the j-th of a channel's ``other_inputs`` (``other_input0``, ``other_input1`` ...).
OTHER_INPUT_STREAM = "other_input{}"
_SIGNAL_KEYS = {"topic", "field", "scale", "type", "offset", "time_offset_s", "frame", "time_column"}
#: Body frames an IMU rate output may be given in (ROS REP 103: x forward, y left, z up; aircraft: x forward,
#: y right, z down); ``flu`` reverses the y and z components, to the models' FRD.
FRAMES = ("flu", "frd")
_GRID_KEYS = {"min_rad_s", "max_rad_s", "count"}


@dataclass(frozen=True)
class SignalSpec:
    """Where a signal comes from: ``topic``, ``field`` path into the message, ``scale`` to SI units, and the
    message ``type`` (e.g. ``sensor_msgs/msg/Imu``; ``None``: discovered from the bag or the graph).

    Issue 23's corrections of the usual mistakes: the value is ``(raw + offset) * scale`` (``offset`` in the
    raw units, e.g. a servo's PWM centre), times -1 for the y and z components of a rate given in the ROS body
    frame (``frame: flu``; the models are FRD), and ``time_offset_s`` is added to the stream's stamps (a topic
    stamped by another clock).

    ``time_column`` names a CSV log's time column (issue 24; default: the first of ``time``, ``t``,
    ``TimeUS``, ``timestamp`` the file has; :mod:`gap_validation.logs.csvlog` gives its unit from its name);
    other sources ignore it."""

    topic: str
    field: str
    scale: float = 1.0
    type: str | None = None
    offset: float = 0.0
    time_offset_s: float = 0.0
    frame: str | None = None
    time_column: str | None = None

    @property
    def gain(self) -> float:
        """What a raw value (plus ``offset``) is multiplied by: ``scale``, with the sign of the body frame."""
        return (
            -self.scale if self.frame == "flu" and self.field.rsplit(".", 1)[-1] in ("y", "z") else self.scale
        )

    def value(self, raw):
        """The signal in SI units and the models' frame from raw values (numbers or arrays).

        Parameters
        ----------
        raw : float or ndarray
            Values as read from the message.
        """
        return (raw + self.offset) * self.gain if self.offset else raw * self.gain

    def raw(self, value):
        """Inverse of :meth:`value` (what a simulated flight writes for a signal value).

        Parameters
        ----------
        value : float or ndarray
            Values in SI units and the models' frame.
        """
        return value / self.gain - self.offset


@dataclass(frozen=True)
class FrequencyGrid:
    """Log-spaced analysis frequencies of a channel [rad/s].

    ``configured`` is False for the grid a channel without ``frequencies`` gets: a wide grid
    (:func:`flown_grid`) whose results are cut to the band the flight excited.
    """

    min_rad_s: float = 1.0
    max_rad_s: float = 60.0
    count: int = 40
    configured: bool = True

    def values(self) -> np.ndarray:
        """The ``count`` log-spaced frequencies from ``min_rad_s`` to ``max_rad_s`` [rad/s]."""
        return np.geomspace(self.min_rad_s, self.max_rad_s, self.count)


@dataclass(frozen=True)
class ChannelConfig:
    """One input-output pair (e.g. elevator to pitch rate) with its model and analysis settings.

    A MIMO channel (e.g. aileron and rudder to roll and yaw rate) has ``input``/``output`` None and its
    signals in ``inputs``/``outputs``; its model is a :class:`~gap_validation.core.models.MimoModel`.
    ``controller`` is the feedback ``u = -C y`` of the controller check b(P1, C) > nu-gap (None without one).
    """

    name: str
    input: SignalSpec | None
    output: SignalSpec | None
    model: LinearModel | MimoModel
    model_spec: dict
    frequencies: FrequencyGrid = field(default_factory=FrequencyGrid)
    coherence_threshold: float = 0.6
    trigger: SignalSpec | None = None
    estimator: dict = field(default_factory=dict)
    inputs: tuple[SignalSpec, ...] = ()
    outputs: tuple[SignalSpec, ...] = ()
    controller: LinearModel | MimoModel | None = None
    controller_spec: dict | None = None
    excitation: SignalSpec | None = None
    other_inputs: tuple[SignalSpec, ...] = ()
    airspeed: SignalSpec | None = None
    trim_airspeed_m_s: float | None = None

    @property
    def is_mimo(self) -> bool:
        """True for a channel with ``inputs``/``outputs`` lists."""
        return bool(self.inputs)

    def signal(self, stream: str) -> SignalSpec | None:
        """The :class:`SignalSpec` of ``stream`` (``input``, ``output`` or ``trigger``; for a MIMO channel
        also ``inputs[j]`` and ``outputs[i]``, and ``input``/``output`` are its first input/output).

        Parameters
        ----------
        stream : str
            The stream.
        """
        if stream == EXCITATION_STREAM:
            return self.excitation
        if stream == AIRSPEED_STREAM:
            return self.airspeed
        if stream.startswith("other_input") and stream[len("other_input"):].isdigit():
            j = int(stream[len("other_input"):])
            return self.other_inputs[j] if j < len(self.other_inputs) else None
        if self.is_mimo:
            for prefix, specs in (("inputs", self.inputs), ("outputs", self.outputs)):
                if stream.startswith(prefix + "["):
                    return specs[int(stream[len(prefix) + 1:-1])]
            if stream in ("input", "output"):
                return (self.inputs if stream == "input" else self.outputs)[0]
        return {"input": self.input, "output": self.output, "trigger": self.trigger}[stream]

    def extra_streams(self) -> list[tuple[str, SignalSpec]]:
        """The channel's streams beyond :data:`STREAMS`: each of ``other_inputs`` (``other_input0`` ...), the
        ``excitation`` and the ``airspeed``, as ``(stream, spec)`` in that order (empty without those
        keys)."""
        out = [(OTHER_INPUT_STREAM.format(j), spec) for j, spec in enumerate(self.other_inputs)]
        if self.excitation is not None:
            out.append((EXCITATION_STREAM, self.excitation))
        if self.airspeed is not None:
            out.append((AIRSPEED_STREAM, self.airspeed))
        return out

    @property
    def input_streams(self) -> tuple[str, ...]:
        """Names of the input streams: ``("input",)``, or ``("inputs[0]", "inputs[1]", ...)`` for MIMO."""
        return (
            tuple(mimo_stream("inputs", j) for j in range(len(self.inputs))) if self.is_mimo else ("input",)
        )

    @property
    def output_streams(self) -> tuple[str, ...]:
        """Names of the output streams: ``("output",)``, or ``("outputs[0]", ...)`` for MIMO."""
        return (
            tuple(mimo_stream("outputs", i) for i in range(len(self.outputs)))
            if self.is_mimo
            else ("output",)
        )


def mimo_stream(kind: str, index: int) -> str:
    """The stream name of a MIMO channel's ``inputs[index]`` or ``outputs[index]``.

    Parameters
    ----------
    kind : {"inputs", "outputs"}
        Which list.
    index : int
        Position in the list.
    """
    return f"{kind}[{index}]"


@dataclass(frozen=True)
class ValidationConfig:
    """A whole validation config: channels by name, where it came from, and the raw mapping (for
    rewriting)."""

    channels: dict[str, ChannelConfig]
    source: str | None = None
    raw: dict = field(default_factory=dict)

    def topics(self) -> dict[str, list[tuple[str, str, SignalSpec]]]:
        """Topic -> every ``(channel, stream, spec)`` it feeds, in config order.

        A MIMO channel's streams are ``inputs[j]`` and ``outputs[i]`` (:func:`mimo_stream`).
        """
        out: dict[str, list[tuple[str, str, SignalSpec]]] = {}
        for name, channel in self.channels.items():
            streams = (
                channel.input_streams + channel.output_streams + ("trigger",) if channel.is_mimo else STREAMS
            )
            for stream in streams:
                spec = channel.signal(stream)
                if spec is not None:
                    out.setdefault(spec.topic, []).append((name, stream, spec))
            for stream, spec in channel.extra_streams():
                out.setdefault(spec.topic, []).append((name, stream, spec))
        return out

    def with_channel_effects(self, channel: str, effects: list[dict]) -> "ValidationConfig":
        """A copy with ``effects`` appended to ``channels.<channel>.model.effects`` (for --apply-diagnosis).

        Parameters
        ----------
        channel : str
            A channel of the config.
        effects : list of dict
            Effect mappings (:mod:`gap_validation.core.effects`), appended in series.
        """
        if channel not in self.channels:
            raise ConfigError(f"{self.source or '<config>'}: no channel {channel!r}")
        if self.channels[channel].is_mimo:
            raise ConfigError(
                f"{self.source or '<config>'}: channels.{channel}.model.effects: effects on a MIMO "
                f"model are not available yet"
            )
        raw = copy.deepcopy(self.raw)
        model = raw["channels"][channel]["model"]
        model["effects"] = list(model.get("effects") or []) + [dict(e) for e in effects]
        return parse_config(raw, self.source or "<config>")


def _fail(source: str, path: str, message: str) -> ConfigError:
    return ConfigError(f"{source}: {path}: {message}")


def _mapping(value: Any, source: str, path: str, allowed: set[str] | None) -> dict:
    if not isinstance(value, dict):
        raise _fail(source, path, f"expected a mapping, got {value!r}")
    if allowed is not None:
        unknown = sorted(str(k) for k in value if k not in allowed)
        if unknown:
            raise _fail(source, f"{path}.{unknown[0]}",
                        f"unknown key (allowed: {', '.join(sorted(allowed))})")
    return value


def _number(value: Any, source: str, path: str, allowed: Interval = FINITE) -> float:
    return check_number(value, f"{source}: {path}", allowed)


def _string(value: Any, source: str, path: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise _fail(source, path, f"expected a non-empty string, got {value!r}")
    return value.strip()


def _signal(value: Any, source: str, path: str) -> SignalSpec:
    data = _mapping(value, source, path, _SIGNAL_KEYS)
    for key in ("topic", "field"):
        if key not in data:
            raise _fail(source, f"{path}.{key}", "missing")
    topic = _string(data["topic"], source, f"{path}.topic")
    if not topic.startswith("/"):
        topic = "/" + topic
    spec_field = _string(data["field"], source, f"{path}.field")
    from gap_validation.core.fields import FieldPath

    try:
        FieldPath.parse(spec_field)
    except ConfigError as err:
        raise _fail(source, f"{path}.field", str(err)) from None
    scale = _number(data.get("scale", 1.0), source, f"{path}.scale", NONZERO)
    offset = _number(data.get("offset", 0.0), source, f"{path}.offset")
    time_offset = _number(data.get("time_offset_s", 0.0), source, f"{path}.time_offset_s")
    frame = data.get("frame")
    if frame is not None:
        if not isinstance(frame, str) or frame.strip().lower() not in FRAMES:
            raise _fail(
                source,
                f"{path}.frame",
                f"expected one of {', '.join(FRAMES)} (ROS REP 103 body frame: flu; "
                f"aircraft: frd), got {frame!r}",
            )
        frame = frame.strip().lower()
        if spec_field.rsplit(".", 1)[-1] not in ("x", "y", "z"):
            raise _fail(source, f"{path}.frame", f"applies to a rate's x, y or z component, not to field "
                                                 f"{spec_field!r}")
    msg_type = data.get("type")
    if msg_type is not None:
        msg_type = _string(msg_type, source, f"{path}.type")
        if msg_type.count("/") == 1:  # sensor_msgs/Imu -> sensor_msgs/msg/Imu
            pkg, name = msg_type.split("/")
            msg_type = f"{pkg}/msg/{name}"
    time_column = (
        _string(data["time_column"], source, f"{path}.time_column") if "time_column" in data else None
    )
    return SignalSpec(topic=topic, field=spec_field, scale=scale, type=msg_type, offset=offset,
                      time_offset_s=time_offset, frame=frame, time_column=time_column)


#: Points per decade of the grid a channel without ``frequencies`` gets (:func:`flown_grid`).
FLOWN_GRID_PER_DECADE = 20


def flown_grid(sample_rate_hz: float = 100.0) -> FrequencyGrid:
    """The analysis grid of a channel without ``frequencies``: 0.3 rad/s up to what the estimator's grid rate
    supports (a fifth of ``sample_rate_hz``, at most 100 rad/s), 20 points per decade; the results keep the
    span the flight excited (``configured`` False).

    Parameters
    ----------
    sample_rate_hz : float
        The estimator's ``sample_rate_hz`` [Hz].
    """
    high = min(100.0, 0.99 * 2.0 * np.pi * sample_rate_hz / 5.0)
    low = min(0.3, high / 10.0)
    count = int(round(FLOWN_GRID_PER_DECADE * np.log10(high / low))) + 1
    return FrequencyGrid(low, high, count, configured=False)


def _grid(value: Any, source: str, path: str) -> FrequencyGrid:
    data = _mapping(value, source, path, _GRID_KEYS)
    default = FrequencyGrid()
    low = _number(data.get("min_rad_s", default.min_rad_s), source, f"{path}.min_rad_s", POSITIVE)
    high = _number(data.get("max_rad_s", default.max_rad_s), source, f"{path}.max_rad_s",
                   Interval(low, low_open=True))
    count = data.get("count", default.count)
    if isinstance(count, bool) or not isinstance(count, int) or not 2 <= count <= 1000:
        raise _fail(source, f"{path}.count", f"expected an integer from 2 to 1000, got {count!r}")
    return FrequencyGrid(low, high, count)


def _signals(value: Any, source: str, path: str) -> tuple[SignalSpec, ...]:
    """A MIMO channel's ``inputs`` or ``outputs``: a non-empty list of signal specs, no signal twice."""
    if not isinstance(value, (list, tuple)) or not value:
        raise _fail(
            source, path, f"expected a non-empty list of signals ({{topic, field}} mappings), got {value!r}"
        )
    specs = tuple(_signal(item, source, f"{path}[{i}]") for i, item in enumerate(value))
    seen: dict[tuple[str, str], int] = {}
    for i, spec in enumerate(specs):
        first = seen.setdefault((spec.topic, spec.field), i)
        if first != i:
            raise _fail(
                source, f"{path}[{i}]", f"the same signal as {path}[{first}] ({spec.topic} {spec.field})"
            )
    return specs


def _model(
    spec: Any,
    source: str,
    path: str,
    inputs: tuple[SignalSpec, ...] | None,
    outputs: tuple[SignalSpec, ...] | None,
    controller: bool = False,
) -> tuple[LinearModel | MimoModel, dict]:
    """The channel's model (or controller): SISO without signal lists, MIMO with them (shapes checked)."""
    spec = _mapping(spec, source, path, None)
    try:
        if inputs is None:
            return LinearModel.from_spec(spec, where=path), copy.deepcopy(spec)
        channel = path.rsplit(".", 1)[0]
        if controller:  # u = -C y: the controller reads the outputs and drives the inputs
            model = MimoModel.from_spec(spec, path, inputs=len(outputs), outputs=len(inputs),
                                        inputs_are=f"entry of {channel}.outputs (the controller reads them)",
                                        outputs_are=f"entry of {channel}.inputs (the controller drives them)")
        else:
            model = MimoModel.from_spec(spec, path, inputs=len(inputs), outputs=len(outputs),
                                        inputs_are=f"entry of {channel}.inputs",
                                        outputs_are=f"entry of {channel}.outputs")
    except ConfigError as err:
        raise ConfigError(f"{source}: {err}") from None
    return model, copy.deepcopy(spec)


def _channel(name: str, value: Any, source: str) -> ChannelConfig:
    path = f"channels.{name}"
    data = _mapping(value, source, path, _CHANNEL_KEYS)
    mimo = "inputs" in data or "outputs" in data
    for key in ("input", "output") if mimo else ():
        if key in data:
            raise _fail(
                source, f"{path}.{key}", "give input/output (SISO) or inputs/outputs lists (MIMO), not both"
            )
    for key in ("inputs", "outputs", "model") if mimo else ("input", "output", "model"):
        if key not in data:
            raise _fail(source, f"{path}.{key}", "missing")
    inputs = _signals(data["inputs"], source, f"{path}.inputs") if mimo else None
    outputs = _signals(data["outputs"], source, f"{path}.outputs") if mimo else None
    model, model_spec = _model(data["model"], source, f"{path}.model", inputs, outputs)
    controller, controller_spec = None, None
    if data.get("controller") is not None:
        controller, controller_spec = _model(
            data["controller"], source, f"{path}.controller", inputs, outputs, controller=True
        )
    estimator = _mapping(data.get("estimator", {}) or {}, source, f"{path}.estimator", None)
    _check_estimator_options(estimator, source, f"{path}.estimator")
    # checked before it is compared
    input_spec = None if mimo else _signal(data["input"], source, f"{path}.input")
    excitation, other_inputs = _closed_loop_signals(data, source, path, mimo, input_spec)
    airspeed, trim_airspeed = _airspeed(data.get("airspeed"), source, f"{path}.airspeed")
    return ChannelConfig(
        name=name,
        input=input_spec,
        output=None if mimo else _signal(data["output"], source, f"{path}.output"),
        model=model,
        model_spec=model_spec,
        frequencies=(
            _grid(data["frequencies"] or {}, source, f"{path}.frequencies")
            if "frequencies" in data
            else flown_grid(float(estimator.get("sample_rate_hz", 100.0)))
        ),
        coherence_threshold=_number(
            data.get("coherence_threshold", 0.6), source, f"{path}.coherence_threshold", Interval(0.0, 0.999)
        ),
        trigger=_signal(data["trigger"], source, f"{path}.trigger")
        if data.get("trigger") is not None
        else None,
        estimator=dict(estimator),
        inputs=inputs or (),
        outputs=outputs or (),
        controller=controller,
        controller_spec=controller_spec,
        excitation=excitation,
        other_inputs=other_inputs,
        airspeed=airspeed,
        trim_airspeed_m_s=trim_airspeed,
    )


def _airspeed(value: Any, source: str, path: str) -> tuple[SignalSpec | None, float | None]:
    """A channel's ``airspeed``: a signal spec plus ``trim_m_s``, the airspeed the model is for (in the
    signal's SI units, m/s)."""
    if value is None:
        return None, None
    data = dict(_mapping(value, source, path, _SIGNAL_KEYS | {"trim_m_s"}))
    if "trim_m_s" not in data:
        raise _fail(
            source,
            f"{path}.trim_m_s",
            "missing (the airspeed the model is for, m/s: the inputs are scaled by (airspeed / trim_m_s)^2)",
        )
    trim = _number(data.pop("trim_m_s"), source, f"{path}.trim_m_s", POSITIVE)
    spec = _signal(data, source, path)
    if spec.frame is not None:
        raise _fail(source, f"{path}.frame", "applies to a body rate, not to an airspeed")
    return spec, trim


def _closed_loop_signals(data: dict, source: str, path: str, mimo: bool, own_input: SignalSpec | None = None
                         ) -> tuple[SignalSpec | None, tuple[SignalSpec, ...]]:
    """A SISO channel's ``excitation`` (the injected signal) and ``other_inputs`` (surfaces that may move with
    its input), checked: no signal twice, and with both keys at least as many excitations as inputs (the
    instrumental-variable estimate needs q >= m)."""
    excitation = data.get("excitation")
    others = data.get("other_inputs")
    if mimo and (excitation is not None or others is not None):
        key = "excitation" if excitation is not None else "other_inputs"
        raise _fail(source, f"{path}.{key}", "not available for a MIMO channel yet")
    spec = _signal(excitation, source, f"{path}.excitation") if excitation is not None else None
    specs = _signals(others, source, f"{path}.other_inputs") if others is not None else ()
    own = {(own_input.topic.lstrip("/"), own_input.field)} if own_input is not None else set()
    for i, other in enumerate(specs):
        if (other.topic.lstrip("/"), other.field) in own:
            raise _fail(
                source, f"{path}.other_inputs[{i}]", f"the channel's own input ({other.topic} {other.field})"
            )
    if spec is not None and specs:
        raise _fail(
            source,
            f"{path}.other_inputs",
            f"{len(specs) + 1} inputs but 1 excitation: the instrumental-variable estimate needs at least as "
            f"many excitations as inputs (q >= m); give other_inputs without excitation, or excitation alone",
        )
    return spec, specs


def _check_estimator_options(options: dict, source: str, path: str) -> None:
    """Unknown estimator options are errors naming the key (the estimator lists what it accepts)."""
    from gap_validation.core.estimator import FrequencyResponseEstimator

    allowed = set(getattr(FrequencyResponseEstimator, "OPTIONS", ()) or ())
    if allowed:
        _mapping(options, source, path, allowed)
    for key, value in options.items():
        if not isinstance(value, bool):
            check_number(value, f"{source}: {path}.{key}", expected="a finite number or boolean")


def parse_config(data: Any, source: str = "<config>") -> ValidationConfig:
    """Validate a loaded config mapping and build the :class:`ValidationConfig`.

    Parameters
    ----------
    data : mapping
        The config as loaded from YAML (DESIGN.md, "Validation config").
    source : str
        Name of the file, used in error messages.

    Raises
    ------
    ConfigError
        One line naming ``source``, the key path and the value.

    Examples
    --------
    One pitch channel: the elevator's joint in, the pitch rate out, a second-order model:

    >>> cfg = parse_config({"channels": {"pitch": {
    ...     "input": {"topic": "/servos", "field": "position[elevator]"},
    ...     "output": {"topic": "/imu", "field": "angular_velocity.y"},
    ...     "model": {"numerator": [40.0], "denominator": [1.0, 12.0, 40.0]}}}}, "example.yaml")
    >>> cfg.channels["pitch"].model, sorted(cfg.topics())
    (LinearModel(num=[40.], den=[ 1. 12. 40.]), ['/imu', '/servos'])
    >>> parse_config({"channels": {"pitch": {"input": {"topic": "/servos", "field": "position[elevator]"}}}},
    ...              "example.yaml")
    Traceback (most recent call last):
    ...
    gap_validation.core.errors.ConfigError: example.yaml: channels.pitch.output: missing
    """
    top = _mapping(data, source, "<top level>", _TOP_KEYS)
    if "channels" not in top:
        raise _fail(source, "channels", "missing (the config needs at least one channel)")
    channels_raw = _mapping(top["channels"], source, "channels", None)
    if not channels_raw:
        raise _fail(source, "channels", "empty (the config needs at least one channel)")
    if "history" in top and top["history"] is not None:
        _string(top["history"], source, "history")
    channels = {}
    for name, value in channels_raw.items():
        if not isinstance(name, str) or not name.replace("_", "").replace("-", "").isalnum():
            raise _fail(source, f"channels.{name}", "channel names are letters, digits, '_' or '-'")
        channels[name] = _channel(name, value, source)
    return ValidationConfig(channels=channels, source=source, raw=copy.deepcopy(dict(top)))


def load_config(path: str | os.PathLike) -> ValidationConfig:
    """Read a validation config file.

    Parameters
    ----------
    path : str or PathLike
        The YAML file.

    Raises
    ------
    ConfigError
        One line naming the file and the problem (missing file, YAML syntax with line number, bad key).
    """
    path = Path(path)
    return parse_config(read_yaml(path, "config file", "config"), str(path))


def read_yaml(path: str | os.PathLike, what: str, short: str | None = None) -> Any:
    """The YAML document of a file (configs, campaign manifests), or a one-line :class:`ConfigError`.

    ``what`` names the kind of file in the messages (``"config file"``: "config file not found", "is a
    directory, not a config file"); ``short`` in "cannot read <short>" (default ``what``).

    Parameters
    ----------
    path : str or PathLike
        The YAML file.
    what : str
        The kind of file, for the messages.
    short : str, optional
        The kind of file in "cannot read <short>" (default ``what``).
    """
    import yaml  # only when a file is read: importing the schema needs no yaml

    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: {what} not found") from None
    except UnicodeDecodeError as err:
        raise ConfigError(f"{path}: not a text (UTF-8) file (byte {err.start}: {err.reason})") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, not a {what}") from None
    except OSError as err:
        raise ConfigError(f"{path}: cannot read {short or what} ({err.strerror or err})") from None
    try:
        return yaml.safe_load(text)
    except RecursionError:
        raise ConfigError(f"{path}: YAML error: nested too deeply") from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or "invalid YAML"
        raise ConfigError(f"{path}: YAML error{where}: {problem}") from None


def dump_config(config: ValidationConfig | dict, path: str | os.PathLike) -> None:
    """Write a config (its raw mapping) as YAML, atomically (:mod:`gap_validation.core.atomic`: temporary
    file, then rename; a crash never leaves a half-written config).

    Parameters
    ----------
    config : ValidationConfig or dict
        The config (its ``raw`` mapping is written) or a mapping.
    path : str or PathLike
        The file written.

    Raises
    ------
    DataError
        One line naming the file when it cannot be written (the old file, if any, is kept).
    """
    import yaml

    data = config.raw if isinstance(config, ValidationConfig) else config
    text = yaml.safe_dump(data, sort_keys=False, default_flow_style=None)
    try:
        atomic_write_text(path, text)
    except OSError as err:
        raise DataError(f"{path}: cannot write config ({err.strerror or err})") from None
