"""The command line's own small languages, parsed into what the library takes: ``--hidden
CHANNEL:EFFECT:key=value[,key=value]``, ``--band-noise LOW:HIGH:RMS[:CHANNELS]``, ``--coupling FROM:TO:GAIN``
and ``--cross-response OUTPUT:SURFACE:GAIN[:WN[:DAMPING]]`` (``gap-validate simulate``). Each error is one
line naming the argument and its bad part. The simulator (:mod:`gap_validation.core.simulation`) takes the
parsed values.
"""
from __future__ import annotations

import math
from typing import Sequence

from gap_validation.core.config import ValidationConfig
from gap_validation.core.effects import validate_effect
from gap_validation.core.errors import ConfigError
from gap_validation.core.fields import FieldPath

__all__ = ["parse_hidden", "hidden_effects", "parse_band_noise", "parse_coupling", "parse_cross_response"]


def _finite(value: str, error: str) -> float:
    """``float(value)``, or a ConfigError with ``error`` when it is not a finite number."""
    try:
        number = float(value)
    except ValueError:
        number = float("nan")
    if not math.isfinite(number):
        raise ConfigError(error)
    return number

def _hidden_value(text: str, part: str, value: str) -> float:
    return _finite(value, f"--hidden {text!r}: bad part {part!r} (value must be a finite number)")

def parse_hidden(text: str, channels: list[str] | tuple[str, ...] | None = None) -> tuple[str, dict]:
    """Parse ``CHANNEL:EFFECT:key=value[,key=value]`` (e.g. ``pitch:time_delay:seconds=0.04``).

    Parameters
    ----------
    text : str
        The ``--hidden`` argument.
    channels : sequence of str, optional
        Channel names of the config; the channel must be one of them.

    Returns
    -------
    channel : str
    effect : dict
        A validated effect mapping (DESIGN.md effects vocabulary).

    Raises
    ------
    ConfigError
        One line naming the bad part.
    """
    parts = text.split(":", 2)
    if len(parts) < 2 or not parts[0].strip() or not parts[1].strip():
        raise ConfigError(f"--hidden {text!r}: expected CHANNEL:EFFECT:key=value[,key=value], "
                          "e.g. pitch:time_delay:seconds=0.04")
    channel, kind = parts[0].strip(), parts[1].strip()
    if channels is not None and channel not in channels:
        raise ConfigError(f"--hidden {text!r}: bad part {channel!r}: no such channel in the config "
                          f"(channels: {', '.join(channels)})")
    effect: dict = {"type": kind}
    params = parts[2] if len(parts) == 3 else ""
    for part in (p.strip() for p in params.split(",")):
        if not part:
            continue
        key, sep, value = part.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--hidden {text!r}: bad part {part!r} (expected key=value)")
        effect[key.strip()] = _hidden_value(text, part, value.strip())
    return channel, validate_effect(effect, where=f"--hidden {text!r}")

def hidden_effects(texts: Sequence[str] | None, config: ValidationConfig) -> dict[str, list[dict]]:
    """Parse every ``--hidden`` text; channel -> effects in the order given.

    Parameters
    ----------
    texts : sequence of str or None
        ``--hidden`` texts (``CHANNEL:EFFECT:key=value[,key=value]``).
    config : ValidationConfig
        The config whose channels they name.
    """
    out: dict[str, list[dict]] = {}
    for text in texts or ():
        channel, effect = parse_hidden(text, tuple(config.channels))
        out.setdefault(channel, []).append(effect)
    return out

def parse_band_noise(text: str, channels: list[str] | tuple[str, ...] | None = None
                     ) -> tuple[tuple[float, float], float, tuple[str, ...] | None]:
    """Parse ``LOW:HIGH:RMS[:CHANNEL[,CHANNEL]]`` (e.g. ``8:14:0.05`` or ``8:14:0.05:pitch``).

    Parameters
    ----------
    text : str
        The ``--band-noise`` argument: band edges [rad/s], RMS [rad/s], optionally the channels (default all).
    channels : sequence of str, optional
        Channel names of the config; named channels must be among them.

    Returns
    -------
    band_rad_s : (float, float)
    rms_rad_s : float
    channels : tuple of str or None
        For :class:`FlightOptions` ``band_noise_rad_s``, ``band_noise_rms_rad_s``, ``band_noise_channels``.

    Raises
    ------
    ConfigError
        One line naming the bad part.
    """
    usage = "expected LOW:HIGH:RMS[:CHANNEL[,CHANNEL]] in rad/s and rad/s rms, e.g. 8:14:0.05"
    parts = [p.strip() for p in text.split(":")]
    if len(parts) not in (3, 4):
        raise ConfigError(f"--band-noise {text!r}: {usage}")
    low, high, rms = (
        _finite(part, f"--band-noise {text!r}: bad part {part!r} ({usage})") for part in parts[:3]
    )
    if not 0 < low < high:
        raise ConfigError(f"--band-noise {text!r}: bad band {parts[0]}:{parts[1]} (expected 0 < LOW < HIGH)")
    if rms < 0:
        raise ConfigError(f"--band-noise {text!r}: bad part {parts[2]!r} (RMS must be >= 0)")
    chosen = None
    if len(parts) == 4:
        chosen = tuple(c.strip() for c in parts[3].split(",") if c.strip())
        if not chosen:
            raise ConfigError(f"--band-noise {text!r}: no channel after the last ':' ({usage})")
        unknown = [c for c in chosen if channels is not None and c not in channels]
        if unknown:
            raise ConfigError(
                f"--band-noise {text!r}: bad part {unknown[0]!r}: no such channel in the config "
                f"(channels: {', '.join(channels)})"
            )
    return (low, high), rms, chosen

def _resolve_surface(config: ValidationConfig, name: str, text: str) -> str:
    """The channel whose input is the surface ``name``: a channel name, or the joint of its input field."""
    if name in config.channels:
        return name
    for channel, ch in config.channels.items():
        if ch.input is not None and FieldPath.parse(ch.input.field).key == name:
            return channel
    joints = [FieldPath.parse(ch.input.field).key for ch in config.channels.values() if ch.input is not None]
    raise ConfigError(
        f"{text}: bad part {name!r}: no channel or input joint of that name in the config "
        f"(channels: {', '.join(config.channels)}; joints: {', '.join(str(j) for j in joints if j)})"
    )

def parse_coupling(text: str, config: ValidationConfig) -> tuple[str, str, float]:
    """Parse ``--coupling FROM:TO:GAIN`` (e.g. ``aileron:rudder:0.3``): the surface TO also moves by GAIN
    times the surface FROM's deflection (an aileron-rudder interconnect). Surfaces are channel names or input
    joints.

    Parameters
    ----------
    text : str
        The argument.
    config : ValidationConfig
        The config whose channels carry the surfaces.

    Returns
    -------
    (from_channel, to_channel, gain)

    Raises
    ------
    ConfigError
        One line naming the bad part.
    """
    where = f"--coupling {text!r}"
    parts = [p.strip() for p in text.split(":")]
    if len(parts) != 3:
        raise ConfigError(f"{where}: expected FROM:TO:GAIN, e.g. aileron:rudder:0.3")
    source, target = _resolve_surface(config, parts[0], where), _resolve_surface(config, parts[1], where)
    if source == target:
        raise ConfigError(f"{where}: a surface coupled to itself")
    gain = _finite(parts[2], f"{where}: bad part {parts[2]!r} (GAIN must be a finite number)")
    return source, target, gain

def parse_cross_response(text: str, config: ValidationConfig) -> tuple[str, str, float, float, float]:
    """Parse ``--cross-response OUTPUT:SURFACE:GAIN[:WN[:DAMPING]]`` (e.g. ``roll:rudder:-0.8:3:0.2``): the
    rate of channel OUTPUT also responds to SURFACE through ``GAIN wn^2 / (s^2 + 2 zeta wn s + wn^2)``
    (default ``wn`` 3 rad/s, damping 0.2: a Dutch-roll-like cross response).

    Parameters
    ----------
    text : str
        The argument.
    config : ValidationConfig
        The config.

    Returns
    -------
    (output_channel, surface_channel, gain, wn_rad_s, damping)
    """
    where = f"--cross-response {text!r}"
    parts = [p.strip() for p in text.split(":")]
    if not 3 <= len(parts) <= 5:
        raise ConfigError(
            f"{where}: expected OUTPUT:SURFACE:GAIN[:WN[:DAMPING]], e.g. roll:rudder:-0.8:3:0.2"
        )
    if parts[0] not in config.channels:
        raise ConfigError(
            f"{where}: bad part {parts[0]!r}: no such channel (channels: {', '.join(config.channels)})"
        )
    surface = _resolve_surface(config, parts[1], where)
    numbers = [_finite(p, f"{where}: bad part {p!r} (expected a finite number)") for p in parts[2:]]
    gain, wn, damping = (numbers + [3.0, 0.2][len(numbers) - 1:])[:3]
    if wn <= 0 or damping <= 0:
        raise ConfigError(f"{where}: WN and DAMPING must be > 0")
    return parts[0], surface, gain, wn, damping
