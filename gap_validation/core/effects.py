"""Physical effects that are added to a model in series (DESIGN.md, "Effects vocabulary").

Each effect is a plain mapping such as ``{"type": "time_delay", "seconds": 0.05}``. Its *factor* in series
with the model is a rational part (numerator, denominator in descending powers of s) times a pure delay
``exp(-s T)``:

==================  ===============================================================  ==============================
type                parameters                                                       factor
==================  ===============================================================  ==============================
time_delay          seconds                                                          exp(-s T)
first_order_lag     bandwidth_rad_s                                                  a / (s + a)
second_order_lag    natural_frequency_rad_s, damping                                 wn^2 / (s^2 + 2 z wn s + wn^2)
gain                factor                                                           k
structural_mode     frequency_rad_s, damping, zero_frequency_rad_s, zero_damping     (s^2/wz^2 + 2 zz s/wz + 1) /
                                                                                     (s^2/wp^2 + 2 zp s/wp + 1)
==================  ===============================================================  ==============================

All factors except ``gain`` have unit gain at s = 0. The names and parameters are a user contract: they are
written in configs and reported by the diagnosis, so they are never renamed.
"""

import math
from numbers import Real

import numpy as np

from gap_validation.core.errors import ConfigError

#: Effect type -> required parameter names, in the order of DESIGN.md's table.
EFFECT_TYPES = {
    "time_delay": ("seconds",),
    "first_order_lag": ("bandwidth_rad_s",),
    "second_order_lag": ("natural_frequency_rad_s", "damping"),
    "gain": ("factor",),
    "structural_mode": ("frequency_rad_s", "damping", "zero_frequency_rad_s", "zero_damping"),
}

# Parameter name -> (test, description used in "expected ..." messages).
_RULES = {
    "seconds": (lambda v: v >= 0.0, "a number >= 0"),
    "bandwidth_rad_s": (lambda v: v > 0.0, "a number > 0"),
    "natural_frequency_rad_s": (lambda v: v > 0.0, "a number > 0"),
    "frequency_rad_s": (lambda v: v > 0.0, "a number > 0"),
    "zero_frequency_rad_s": (lambda v: v > 0.0, "a number > 0"),
    "damping": (lambda v: v >= 0.0, "a number >= 0"),
    "zero_damping": (lambda v: v >= 0.0, "a number >= 0"),
    "factor": (lambda v: v != 0.0, "a nonzero number"),
}


def _fail(where, expected, value):
    raise ConfigError(f"{where}: expected {expected}, got {value!r}")


def as_number(value, where, expected="a finite number"):
    """Convert a config value to a finite float, or raise a one-line ConfigError.

    Parameters
    ----------
    value : object
        The raw config value. Booleans are rejected; numeric strings (``"5e-2"``, which YAML 1.1 loads as a
        string) are accepted.
    where : str
        Path of the value in the config, e.g. ``"model.effects[1].seconds"``.
    expected : str
        Description of what is expected, used in the message.

    Returns
    -------
    float
    """
    if isinstance(value, bool):
        _fail(where, expected, value)
    if isinstance(value, Real):
        number = float(value)
    elif isinstance(value, str):
        try:
            number = float(value.strip())
        except ValueError:
            _fail(where, expected, value)
    else:
        _fail(where, expected, value)
    if not math.isfinite(number):
        _fail(where, expected, value)
    return number


def validate_effect(spec, where="effects[0]"):
    """Check one effect mapping and return a normalised copy.

    Parameters
    ----------
    spec : mapping
        ``{"type": <name>, <parameter>: <number>, ...}`` with exactly the parameters of :data:`EFFECT_TYPES`.
    where : str
        Path of the effect in the config, used in error messages (e.g. ``"model.effects[1]"``).

    Returns
    -------
    dict
        ``{"type": name, parameter: float, ...}`` with parameters in the table's order.

    Raises
    ------
    ConfigError
        One line naming the path, the key and the offending value: unknown type, missing or unknown
        parameter, non-numeric or non-finite value, value out of range (frequencies > 0, damping >= 0,
        delay >= 0, gain factor nonzero).
    """
    if not isinstance(spec, dict):
        raise ConfigError(f"{where}: expected a mapping with a 'type' key, got {spec!r}")
    if "type" not in spec:
        raise ConfigError(f"{where}: missing key 'type' (one of {', '.join(EFFECT_TYPES)})")
    kind = spec["type"]
    if not isinstance(kind, str) or kind not in EFFECT_TYPES:
        raise ConfigError(f"{where}.type: unknown effect type {kind!r} (expected one of {', '.join(EFFECT_TYPES)})")
    names = EFFECT_TYPES[kind]
    unknown = [key for key in spec if key != "type" and key not in names]
    if unknown:
        raise ConfigError(
            f"{where}.{unknown[0]}: unknown parameter for {kind} (expected {', '.join(names)}), "
            f"got {unknown[0]!r}: {spec[unknown[0]]!r}"
        )
    missing = [name for name in names if name not in spec]
    if missing:
        raise ConfigError(f"{where}: missing parameter {missing[0]!r} for {kind} (needs {', '.join(names)})")
    result = {"type": kind}
    for name in names:
        test, expected = _RULES[name]
        value = as_number(spec[name], f"{where}.{name}", f"{expected}")
        if not test(value):
            _fail(f"{where}.{name}", expected, spec[name])
        result[name] = value
    return result


def effect_factor(spec):
    """Rational part and delay of an effect's factor.

    Parameters
    ----------
    spec : mapping
        An effect (validated by :func:`validate_effect`, which is applied again here).

    Returns
    -------
    num : ndarray
        Numerator coefficients, descending powers of s.
    den : ndarray
        Denominator coefficients, descending powers of s, monic.
    delay_s : float
        Pure delay T [s] of the factor ``exp(-s T)`` (zero except for ``time_delay``).
    """
    spec = validate_effect(spec, where="effect")
    kind = spec["type"]
    if kind == "time_delay":
        return np.array([1.0]), np.array([1.0]), spec["seconds"]
    if kind == "first_order_lag":
        a = spec["bandwidth_rad_s"]
        return np.array([a]), np.array([1.0, a]), 0.0
    if kind == "second_order_lag":
        wn, zeta = spec["natural_frequency_rad_s"], spec["damping"]
        return np.array([wn * wn]), np.array([1.0, 2.0 * zeta * wn, wn * wn]), 0.0
    if kind == "gain":
        return np.array([spec["factor"]]), np.array([1.0]), 0.0
    wp, zp = spec["frequency_rad_s"], spec["damping"]
    wz, zz = spec["zero_frequency_rad_s"], spec["zero_damping"]
    # (s^2/wz^2 + 2 zz s/wz + 1)/(s^2/wp^2 + 2 zp s/wp + 1), multiplied through by wp^2 (monic denominator).
    scale = (wp / wz) ** 2
    return scale * np.array([1.0, 2.0 * zz * wz, wz * wz]), np.array([1.0, 2.0 * zp * wp, wp * wp]), 0.0


def effect_response(spec, w_rad_s):
    """Complex factor of an effect at s = j w, delay included exactly.

    Parameters
    ----------
    spec : mapping
        An effect.
    w_rad_s : array_like
        Frequencies [rad/s].

    Returns
    -------
    ndarray of complex
        Same shape as ``w_rad_s``.
    """
    num, den, delay_s = effect_factor(spec)
    w = np.asarray(w_rad_s, dtype=float)
    s = 1j * w
    return np.polyval(num, s) / np.polyval(den, s) * np.exp(-s * delay_s)


def _hz(w_rad_s):
    return w_rad_s / (2.0 * math.pi)


def describe_effect(spec):
    """Human text for an effect, used in the diagnosis sentence.

    Parameters
    ----------
    spec : mapping
        An effect.

    Returns
    -------
    str
        e.g. ``"time delay of 45 ms"``, ``"first-order lag at 37.7 rad/s (6.0 Hz)"``, ``"gain error x1.25"``.
    """
    spec = validate_effect(spec, where="effect")
    kind = spec["type"]
    if kind == "time_delay":
        ms = spec["seconds"] * 1e3
        return f"time delay of {ms:.3g} ms" if ms < 10.0 else f"time delay of {ms:.0f} ms"
    if kind == "first_order_lag":
        a = spec["bandwidth_rad_s"]
        return f"first-order lag at {a:.1f} rad/s ({_hz(a):.1f} Hz)"
    if kind == "second_order_lag":
        wn, zeta = spec["natural_frequency_rad_s"], spec["damping"]
        return f"second-order lag at {wn:.1f} rad/s ({_hz(wn):.1f} Hz), damping {zeta:.2f}"
    if kind == "gain":
        return f"gain error x{spec['factor']:.3g}"
    wp, zp = spec["frequency_rad_s"], spec["damping"]
    wz, zz = spec["zero_frequency_rad_s"], spec["zero_damping"]
    return (
        f"structural mode at {wp:.1f} rad/s ({_hz(wp):.1f} Hz), damping {zp:.3g}, "
        f"with zeros at {wz:.1f} rad/s ({_hz(wz):.1f} Hz), damping {zz:.3g}"
    )
