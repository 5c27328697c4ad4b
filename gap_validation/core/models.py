"""SISO linear models of one aircraft channel: airframe (transfer function, zeros-poles-gain or state space)
with physical effects in series (:mod:`gap_validation.core.effects`) and an optional pure delay.

A :class:`LinearModel` is ``P(s) = num(s)/den(s) * exp(-s T)``; ``num``/``den`` include the rational effects
and ``T = delay_s`` sums the airframe delay and every ``time_delay`` effect. It gives the exact frequency
response and simulates time histories (hour-long flights in a fraction of a second), applying the delay
exactly by interpolating the delayed input rather than by a Pade approximation.

The config ``model:`` mapping (DESIGN.md) takes one of three airframe forms::

    numerator: [-133.7, -990.76]          # descending powers of s
    denominator: [1.0, 23.37, 235.93]

    zeros: []                             # numbers, [re, im] pairs or strings such as "-11.7+10j"
    poles: ["-11.7+10j", "-11.7-10j"]
    gain: -133.7                          # optional, default 1

    state_space: {A: [[...]], B: [[...]], C: [[...]], D: [[...]], input: 0, output: [0, 1, 0, 0]}

plus optional ``delay_s`` (airframe transport delay [s], default 0) and ``effects`` (a list, in series).
``input``/``output`` select a column of B / a row of C by index, or weight them (``input: [1, -1, 0]`` is
``B[:, 0] - B[:, 1]``, a symmetric aileron from left and right surfaces).
"""

from __future__ import annotations

import copy
import math
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike

from gap_validation.core.effects import (
    EFFECTS,
    apply_holds,
    apply_nonlinear,
    check_plausible,
    effect_factor,
    is_nonlinear,
    validate_effect,
)
from gap_validation.core.errors import ConfigError
from gap_validation.core.lsim import delayed_input, simulate_state_space
from gap_validation.core.numbers import NON_NEGATIVE, check_number
from gap_validation.core.statespace import StateSpace, series

_MODEL_KEYS = ("numerator", "denominator", "zeros", "poles", "gain", "state_space", "delay_s", "effects")
_SS_KEYS = ("A", "B", "C", "D", "input", "output")
_TRIM_RTOL = 1e-10  # leading numerator coefficients below this (frequency-scaled) are round-off of ss2tf

#: A real realization (A, B, C, D) as 2-D arrays.
#: A parsed airframe: numerator, denominator, its config mapping and its own state space (or None).
Airframe = tuple[np.ndarray, np.ndarray, dict, StateSpace | None]


# ----------------------------------------------------------------------------------------------------------
# parsing helpers (one-line ConfigError naming the path, key and value)
# ----------------------------------------------------------------------------------------------------------


def _number_list(value: Any, where: str, allow_empty: bool = False) -> np.ndarray:
    if not isinstance(value, (list, tuple, np.ndarray)) or isinstance(value, str):
        raise ConfigError(f"{where}: expected a list of numbers, got {value!r}")
    if len(value) == 0 and not allow_empty:
        raise ConfigError(f"{where}: expected a non-empty list of numbers, got []")
    out = np.array([check_number(v, f"{where}[{i}]", strings=True) for i, v in enumerate(value)], dtype=float)
    _check_magnitude(out, where, _MAX_COEFFICIENT)
    return out


#: Largest magnitude accepted for a polynomial coefficient and for a state-space matrix entry: beyond, the
#: numbers are a units or typing error and products of them overflow float64 in the frequency response.
_MAX_COEFFICIENT = 1e30
_MAX_MATRIX_ENTRY = 1e15


def _check_magnitude(values: np.ndarray, where: str, limit: float) -> None:
    big = np.flatnonzero(np.abs(values) > limit)
    if big.size:
        raise ConfigError(
            f"{where}: {values.ravel()[big[0]]!r} is beyond {limit:g} in magnitude (wrong units?)"
        )


def _complex_value(value: Any, where: str) -> complex:
    """A root given as a number, a ``[re, im]`` pair or a string like ``"-1+2j"`` (``i`` accepted too)."""
    expected = "a number, [re, im] or a string like '-1+2j'"
    if isinstance(value, (list, tuple)):
        if len(value) != 2:
            raise ConfigError(f"{where}: expected {expected}, got {value!r}")
        return complex(check_number(value[0], f"{where}[0]", strings=True),
                       check_number(value[1], f"{where}[1]", strings=True))
    if isinstance(value, str):
        text = value.strip().replace(" ", "").replace("i", "j")
        try:
            root = complex(text)
        except ValueError:
            raise ConfigError(f"{where}: expected {expected}, got {value!r}") from None
        if not (math.isfinite(root.real) and math.isfinite(root.imag)):
            raise ConfigError(f"{where}: expected {expected}, got {value!r}")
        return root
    return complex(check_number(value, where, strings=True, expected=expected), 0.0)


def _root_list(value: Any, where: str) -> np.ndarray:
    if not isinstance(value, (list, tuple)):
        raise ConfigError(f"{where}: expected a list of roots, got {value!r}")
    roots = np.array([_complex_value(v, f"{where}[{i}]") for i, v in enumerate(value)], dtype=complex)
    _check_conjugates(roots, where)
    return roots


def _check_conjugates(roots: np.ndarray, where: str) -> None:
    """Complex roots of a real model come in conjugate pairs; raise ConfigError naming the first lone one."""
    scale = max(1.0, float(np.max(np.abs(roots)))) if roots.size else 1.0
    tol = 1e-9 * scale
    unused = [r for r in roots if abs(r.imag) > tol]
    while unused:
        root = unused.pop(0)
        match = [
            i for i, other in enumerate(unused) if abs(other - np.conj(root)) <= 1e-6 * max(1.0, abs(root))
        ]
        if not match:
            raise ConfigError(
                f"{where}: complex root {_format_root(root)} has no conjugate {_format_root(np.conj(root))} "
                "(a real model needs conjugate pairs)"
            )
        unused.pop(match[0])


def _format_root(root: complex) -> str:
    return f"{root.real:g}{root.imag:+g}j"


def _real_poly(roots: np.ndarray) -> np.ndarray:
    return np.real(np.poly(roots)) if roots.size else np.array([1.0])


def _matrix(value: Any, where: str, rows: int | None = None, cols: int | None = None) -> np.ndarray:
    """A 2-D matrix from nested lists; a flat list is a row when ``rows == 1``, a column when ``cols ==
    1``."""
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: expected a matrix (list of lists of numbers), got {value!r}") from None
    if array.ndim == 0:
        array = array.reshape(1, 1)
    elif array.ndim == 1:
        array = array.reshape(1, -1) if rows == 1 or (cols is not None and array.size == cols and cols != 1) \
            else array.reshape(-1, 1)
    if array.ndim != 2 or array.size == 0:
        raise ConfigError(f"{where}: expected a non-empty matrix (list of lists of numbers), got {value!r}")
    if not np.all(np.isfinite(array)):
        raise ConfigError(f"{where}: expected finite numbers, got {value!r}")
    _check_magnitude(array, where, _MAX_MATRIX_ENTRY)
    if rows is not None and array.shape[0] != rows:
        raise ConfigError(f"{where}: expected {rows} rows, got shape {array.shape[0]}x{array.shape[1]}")
    if cols is not None and array.shape[1] != cols:
        raise ConfigError(f"{where}: expected {cols} columns, got shape {array.shape[0]}x{array.shape[1]}")
    return array


def _selector(value: Any, count: int, where: str, what: str) -> np.ndarray:
    """Index or weight vector selecting one of ``count`` inputs/outputs."""
    if value is None:
        if count == 1:
            return np.array([1.0])
        raise ConfigError(
            f"{where}: missing key (the model has {count} {what}s: give an index or a weight list)"
        )
    if isinstance(value, (list, tuple)):
        weights = _number_list(value, where)
        if weights.size != count:
            raise ConfigError(f"{where}: expected {count} weights (one per {what}), got {value!r}")
        return weights
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value < count:
        raise ConfigError(
            f"{where}: expected an index 0..{count - 1} or a list of {count} weights, got {value!r}"
        )
    weights = np.zeros(count)
    weights[int(value)] = 1.0
    return weights


def strip_leading_zeros(poly: ArrayLike) -> np.ndarray:
    """Coefficients without their leading zeros (descending powers; the zero polynomial is ``[0.0]``).

    Parameters
    ----------
    poly : array_like of float
        Polynomial coefficients, descending powers of s.

    Returns
    -------
    ndarray of float
    """
    poly = np.asarray(poly, dtype=float)
    if poly.ndim != 1:
        poly = poly.ravel()
    if poly.size and poly[0] != 0.0:
        return poly
    nonzero = np.flatnonzero(poly)
    return poly[nonzero[0]:] if nonzero.size else np.array([0.0])


def _trim_leading(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """Drop leading numerator coefficients that are round-off relative to the model's frequency scale."""
    num = strip_leading_zeros(num)
    roots = np.roots(den) if len(den) > 1 else np.array([])
    w_c = max(1.0, float(np.max(np.abs(roots)))) if roots.size else 1.0
    powers = w_c ** np.arange(len(num) - 1, -1, -1, dtype=float)
    weighted = np.abs(num) * powers
    top = weighted.max()
    if top == 0.0:
        return np.array([0.0])
    first = int(np.flatnonzero(weighted > _TRIM_RTOL * top)[0])
    return num[first:]


def _ss2tf(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Numerator (2-D, one row) and denominator of the SISO ``c (sI - a)^-1 b + d``, computed as
    ``scipy.signal.ss2tf`` does (``den = det(sI - a)``, ``num = det(sI - a + b c) + (d - 1) den``, both by
    ``numpy.poly``) without importing scipy.signal: its import costs a replay's start-up about 0.7 s."""
    den = np.poly(a) if a.size else np.ones(1)
    num = (np.poly(a - b @ c) if a.size else np.ones(1)) + (float(d[0, 0]) - 1.0) * den
    return num[None, :], den


def _tf2ss(num: np.ndarray, den: np.ndarray) -> StateSpace:
    """Real realization (A, B, C, D) of a proper num/den with 2-D arrays (also for static gains).

    The controller canonical form ``scipy.signal.tf2ss`` gives, to the bit (both normalised by the leading
    denominator coefficient, numerator coefficients within 1e-14 of zero dropped from the front, A's first row
    ``-den[1:]`` over an identity shifted down, ``B = e1``, ``C = num[1:] - num[0] den[1:]``, ``D = num[0]``),
    without importing scipy.signal: its import costs a replay's start-up about 0.7 s.
    """
    den = np.atleast_1d(np.asarray(den, dtype=float))
    num = np.atleast_1d(np.asarray(num, dtype=float))
    if len(den) == 1:
        return np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.array([[num[-1] / den[0]]])
    nonzero = np.flatnonzero(den)
    if nonzero.size == 0:
        raise ValueError("_tf2ss: the denominator is zero")
    den = den[nonzero[0]:]
    num, den = num / den[0], den / den[0]
    big = np.flatnonzero(np.abs(num) > 1e-14)
    num = num[min(int(big[0]) if big.size else num.size - 1, num.size - 1):]
    k = len(den)
    if len(num) > k:
        raise ValueError("_tf2ss: improper transfer function (numerator longer than denominator)")
    num = np.concatenate((np.zeros(k - len(num)), num))
    if k == 1:
        return np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1)), np.array([[num[0]]])
    a = np.zeros((k - 1, k - 1))
    a[0] = -den[1:]
    a[1:, :-1] = np.eye(k - 2)
    c = (num[1:] - num[0] * den[1:])[None, :]
    return a, np.eye(k - 1, 1), c, np.array([[num[0]]])


# ----------------------------------------------------------------------------------------------------------
# the model
# ----------------------------------------------------------------------------------------------------------


def _check_plausible(delay_s: float, effects: list[dict], where: str) -> None:
    """ConfigError naming the key for absurd delays [s], frequencies [rad/s], dampings or gains (the plausible
    ranges of the effects registry; the airframe delay is held to a ``time_delay``'s)."""
    EFFECTS["time_delay"].parameter("seconds").check_plausible(delay_s, f"{where}.delay_s")
    for i, effect in enumerate(effects):
        check_plausible(effect, f"{where}.effects[{i}]")


class LinearModel:
    """A SISO linear model ``P(s) = num(s)/den(s) * exp(-s delay_s)``, immutable.

    Parameters
    ----------
    num, den : array_like
        Airframe numerator and denominator, descending powers of s (proper: ``deg num <= deg den``).
    delay_s : float
        Airframe transport delay [s], >= 0.
    effects : sequence of dict
        Effects in series (:mod:`gap_validation.core.effects`), validated here.

    Attributes
    ----------
    num, den : ndarray
        Rational part *including* the rational effects; ``den`` is monic.
    delay_s : float
        Total pure delay [s]: airframe delay plus every ``time_delay`` effect.
    effects : tuple of dict
        The validated effects.

    Notes
    -----
    Build models from a config mapping with :meth:`from_spec`; :meth:`to_spec` gives it back.

    Amplitude-dependent effects (``rate_limit``, ``backlash``) act on the input before everything else: they
    are not in ``num``/``den`` (the linear part); :meth:`simulate` applies them in the time domain, and
    :meth:`freqresp` multiplies by their describing functions at the amplitude given to :meth:`at_amplitude`
    (a ConfigError without one). A model without them behaves as a plain linear model.

    A ``zero_order_hold`` is linear but not rational: ``num``/``den``/``delay_s`` hold its half-period delay,
    :meth:`freqresp` multiplies by its droop exactly, and :meth:`simulate` samples and holds the input (its
    delay then comes from the hold, not from ``delay_s``).

    Examples
    --------
    A short-period-like mode, then the same with a 20 ms actuator delay added in series:

    >>> model = LinearModel.from_tf([40.0], [1.0, 12.0, 40.0])
    >>> model.order, round(model.dc_gain(), 6)
    (2, 1.0)
    >>> delayed = model.with_effects([{"type": "time_delay", "seconds": 0.02}])
    >>> bool(abs(delayed.freqresp([10.0])[0]) == abs(model.freqresp([10.0])[0])), delayed.delay_s
    (True, 0.02)
    """

    __slots__ = ("_air_num", "_air_den", "_air_delay_s", "_air_ss", "_air_spec", "_effects", "_num", "_den",
                 "_delay_s", "_realization", "_amplitude")

    def __init__(self, num: ArrayLike, den: ArrayLike, delay_s: float = 0.0, effects: Sequence[dict] = (), *,
                 _airframe_spec: dict | None = None, _airframe_ss: StateSpace | None = None) -> None:
        num = strip_leading_zeros(np.asarray(num, dtype=float))
        den = strip_leading_zeros(np.asarray(den, dtype=float))
        if not (np.all(np.isfinite(num)) and np.all(np.isfinite(den))):
            raise ConfigError(f"model: expected finite coefficients, got numerator {num.tolist()}, "
                              f"denominator {den.tolist()}")
        if den[0] == 0.0:
            raise ConfigError(f"model.denominator: expected a nonzero polynomial, got {den.tolist()}")
        if len(num) > len(den) and not (len(num) == 1 and num[0] == 0.0):
            raise ConfigError(
                f"model.numerator: improper model (numerator degree {len(num) - 1} > denominator degree "
                f"{len(den) - 1}), got {num.tolist()}"
            )
        delay_s = check_number(delay_s, "model.delay_s", NON_NEGATIVE, strings=True, expected="a number >= 0")
        self._air_num = num / den[0]
        self._air_den = den / den[0]
        self._air_delay_s = delay_s
        self._air_ss = _airframe_ss
        self._air_spec = _airframe_spec
        self._effects = tuple(validate_effect(e, f"model.effects[{i}]") for i, e in enumerate(effects))
        total_num, total_den, total_delay = self._air_num, self._air_den, self._air_delay_s
        for effect in self._effects:
            if is_nonlinear(effect):
                continue
            e_num, e_den, e_delay = effect_factor(effect)
            total_num = np.polymul(total_num, e_num)
            total_den = np.polymul(total_den, e_den)
            total_delay += e_delay
        self._num, self._den, self._delay_s = total_num, total_den, total_delay
        for array in (self._air_num, self._air_den, self._num, self._den):
            array.setflags(write=False)
        self._realization = None
        self._amplitude = None

    # -- construction from / to the config mapping ----------------------------------------------------------

    @classmethod
    def from_spec(cls, spec: Any, where: str = "model") -> LinearModel:
        """Build a model from the config ``model:`` mapping (DESIGN.md).

        Parameters
        ----------
        spec : mapping
            One airframe form (``numerator``/``denominator``, ``zeros``/``poles``/``gain`` or
            ``state_space``), optional ``delay_s`` [s] and optional ``effects`` list.
        where : str
            Path of the mapping in the config, for error messages.

        Returns
        -------
        LinearModel

        Raises
        ------
        ConfigError
            One line naming the path, key and value: unknown keys, wrong types, empty lists, non-finite
            numbers, unpaired complex roots, wrong matrix shapes, improper models, bad effects.
        """
        if not isinstance(spec, dict):
            raise ConfigError(f"{where}: expected a mapping (numerator/denominator, zeros/poles/gain or "
                              f"state_space), got {spec!r}")
        unknown = [key for key in spec if key not in _MODEL_KEYS]
        if unknown:
            raise ConfigError(f"{where}.{unknown[0]}: unknown key (expected {', '.join(_MODEL_KEYS)}), "
                              f"got {unknown[0]!r}: {spec[unknown[0]]!r}")
        forms = [name for name, keys in (("transfer function", ("numerator", "denominator")),
                                         ("zeros-poles-gain", ("zeros", "poles", "gain")),
                                         ("state space", ("state_space",)))
                 if any(key in spec for key in keys)]
        if len(forms) != 1:
            raise ConfigError(
                f"{where}: expected exactly one of numerator/denominator, zeros/poles/gain or "
                f"state_space, got keys {sorted(k for k in spec if k not in ('delay_s', 'effects'))}"
            )
        delay_s = 0.0
        if "delay_s" in spec:
            delay_s = check_number(spec["delay_s"], f"{where}.delay_s", NON_NEGATIVE, strings=True,
                                   expected="a number >= 0")
        effects = spec.get("effects", [])
        if effects is None:
            effects = []
        if not isinstance(effects, (list, tuple)):
            raise ConfigError(f"{where}.effects: expected a list of effects, got {effects!r}")
        effects = [validate_effect(e, f"{where}.effects[{i}]") for i, e in enumerate(effects)]
        _check_plausible(delay_s, effects, where)
        if forms[0] == "transfer function":
            num, den, air_spec, air_ss = _parse_tf(spec, where)
        elif forms[0] == "zeros-poles-gain":
            num, den, air_spec, air_ss = _parse_zpk(spec, where)
        else:
            num, den, air_spec, air_ss = _parse_ss(spec["state_space"], f"{where}.state_space")
        _check_proper(num, den, where)
        return cls(num, den, delay_s, effects, _airframe_spec=air_spec, _airframe_ss=air_ss)

    @classmethod
    def from_tf(cls, num: ArrayLike, den: ArrayLike, delay_s: float = 0.0,
                effects: Sequence[dict] = ()) -> LinearModel:
        """Model from numerator/denominator coefficients (descending powers of s) and a delay [s].

        Parameters
        ----------
        num, den : array_like
            Numerator and denominator, descending powers of s.
        delay_s : float
            Airframe delay [s].
        effects : sequence of dict
            Effects in series.
        """
        return cls(num, den, delay_s, effects)

    def to_spec(self) -> dict:
        """Config ``model:`` mapping that :meth:`from_spec` turns back into this model.

        Returns
        -------
        dict
            The airframe in the user's original form (numerator/denominator when built from arrays), plus
            ``delay_s`` when nonzero and ``effects`` when there are any. Plain lists and floats (YAML/JSON
            friendly).
        """
        if self._air_spec is not None:
            spec = copy.deepcopy(self._air_spec)
        else:
            spec = {
                "numerator": [float(v) for v in self._air_num],
                "denominator": [float(v) for v in self._air_den],
            }
        if self._air_delay_s:
            spec["delay_s"] = float(self._air_delay_s)
        if self._effects:
            spec["effects"] = [dict(e) for e in self._effects]
        return spec

    def with_effects(self, effects: Sequence[dict]) -> LinearModel:
        """A copy with ``effects`` appended in series (validated; ConfigError on problems).

        Parameters
        ----------
        effects : sequence of dict
            Effect mappings (:mod:`gap_validation.core.effects`), appended after the model's own.
        """
        effects = list(self._effects) + list(effects)
        out = LinearModel(self._air_num, self._air_den, self._air_delay_s, effects,
                          _airframe_spec=self._air_spec, _airframe_ss=self._air_ss)
        out._amplitude = self._amplitude
        return out

    @property
    def nonlinear(self) -> bool:
        """True when an effect is amplitude-dependent (``rate_limit``, ``backlash``)."""
        return any(is_nonlinear(e) for e in self._effects)

    def at_amplitude(self, amplitude: Any) -> LinearModel:
        """A copy whose :meth:`freqresp` evaluates the amplitude-dependent effects' describing functions at
        the flown input amplitude (the model itself is unchanged; without such effects it is returned as is).

        Parameters
        ----------
        amplitude : float or callable
            Input amplitude [input units], or ``amplitude(w_rad_s) -> array`` per frequency.
        """
        if not self.nonlinear:
            return self
        out = LinearModel(self._air_num, self._air_den, self._air_delay_s, self._effects,
                          _airframe_spec=self._air_spec, _airframe_ss=self._air_ss)
        out._amplitude = (
            amplitude if callable(amplitude) else (lambda w, a=float(amplitude): np.full(np.shape(w), a))
        )
        return out

    @property
    def airframe(self) -> LinearModel:
        """The model without its effects (airframe delay kept)."""
        return LinearModel(self._air_num, self._air_den, self._air_delay_s, (),
                           _airframe_spec=self._air_spec, _airframe_ss=self._air_ss)

    # -- attributes -----------------------------------------------------------------------------------------

    @property
    def num(self) -> np.ndarray:
        """Numerator of the rational part incl. rational effects, descending powers of s."""
        return self._num

    @property
    def den(self) -> np.ndarray:
        """Monic denominator of the rational part incl. rational effects, descending powers of s."""
        return self._den

    @property
    def delay_s(self) -> float:
        """Total pure delay [s] (airframe delay + ``time_delay`` effects)."""
        return self._delay_s

    @property
    def effects(self) -> tuple[dict, ...]:
        """The validated effects, in series order."""
        return self._effects

    @property
    def order(self) -> int:
        """Number of poles of the rational part."""
        return len(self._den) - 1

    def poles(self) -> np.ndarray:
        """Poles of the rational part [rad/s] (common factors with the numerator are not cancelled)."""
        return np.roots(self._den) if len(self._den) > 1 else np.array([], dtype=complex)

    def zeros(self) -> np.ndarray:
        """Finite zeros of the rational part [rad/s]."""
        return np.roots(self._num) if len(self._num) > 1 else np.array([], dtype=complex)

    def dc_gain(self) -> float:
        """P(0) (inf when a pole is at the origin)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return float(self._num[-1] / self._den[-1]) if self._den[-1] != 0 else math.inf

    def __repr__(self) -> str:
        parts = [
            f"num={np.array2string(self._num, precision=6)}",
            f"den={np.array2string(self._den, precision=6)}",
        ]
        if self._delay_s:
            parts.append(f"delay_s={self._delay_s:g}")
        if self._effects:
            parts.append(f"effects={[e['type'] for e in self._effects]}")
        return f"LinearModel({', '.join(parts)})"

    # -- frequency response ---------------------------------------------------------------------------------

    def freqresp(self, w_rad_s: ArrayLike) -> np.ndarray:
        """Complex frequency response P(j w), the delay included exactly as exp(-j w T).

        Parameters
        ----------
        w_rad_s : array_like
            Frequencies [rad/s] (>= 0 in practice; any real value works).

        Returns
        -------
        ndarray of complex
            Same shape as ``w_rad_s``; ``inf`` at a pole on the imaginary axis.
        """
        w = np.asarray(w_rad_s, dtype=float)
        s = 1j * w
        with np.errstate(divide="ignore", invalid="ignore"):
            response = np.polyval(self._num, s) / np.polyval(self._den, s)
        if self._delay_s:
            response = response * np.exp(-s * self._delay_s)
        for i, effect in enumerate(self._effects):
            shape = EFFECTS[effect["type"]].shape
            if shape is not None:                  # a hold's droop (its delay is in the factor)
                response = response * shape(effect, w)
            if is_nonlinear(effect):
                if self._amplitude is None:
                    raise ConfigError(
                        f"model.effects[{i}] ({effect['type']}) depends on the input amplitude: "
                        "its response needs the flown amplitude"
                    )
                response = response * EFFECTS[effect["type"]].response(effect, w, self._amplitude(w))
        return response

    # -- time response --------------------------------------------------------------------------------------

    def state_space(self) -> StateSpace:
        """Real realization (A, B, C, D) of the rational part: airframe states, then each effect's states.

        The airframe uses the config's own state-space matrices when it was given that way (reduced to the
        selected input/output), else the controllable canonical form of num/den (``scipy.signal.tf2ss``).
        This is the realization whose state ``x0`` of :meth:`simulate` refers to.
        """
        if self._realization is None:
            system = self._air_ss if self._air_ss is not None else _tf2ss(self._air_num, self._air_den)
            for effect in (e for e in self._effects if not is_nonlinear(e)):
                e_num, e_den, _ = effect_factor(effect)
                if len(e_den) > 1 or e_num[0] != 1.0:
                    system = series(system, _tf2ss(e_num, e_den))
            self._realization = tuple(np.array(m, dtype=float) for m in system)
        return self._realization

    def simulate(
        self, t_s: ArrayLike, u: ArrayLike, x0: ArrayLike | None = None, hold: str = "linear"
    ) -> np.ndarray:
        """Output for input samples ``u`` at times ``t_s`` (possibly irregular), delay applied exactly.

        The input between samples is linear (first-order hold, as ``scipy.signal.lsim``) or constant
        (``hold="zero"``). The rational part is discretised exactly for that input (matrix exponential per
        distinct step). The pure delay is applied exactly: the rational part is driven by u(t - T), obtained
        by interpolating ``u`` at ``t_s - T`` (zero before the first sample), so a delayed ramp or sine is
        reproduced to interpolation accuracy, not a Pade approximation.
        Amplitude-dependent effects (``rate_limit``, ``backlash``) are applied first, in the time domain, to
        the samples of ``u`` (:func:`~gap_validation.core.effects.apply_nonlinear`); then the holds
        (:func:`~gap_validation.core.effects.apply_holds`), whose delay the held samples carry.

        Uniform grids (and uniform runs between dropouts) are simulated in blocks with matrix products
        (10^6 samples of a 5th-order model in about 0.2 s). Irregular (jittered) steps are solved exactly in
        modal coordinates, vectorised (10^6 samples in about 2 s); only when A is not diagonalisable
        (repeated poles, e.g. two identical lags) a per-step recursion is used (tens of microseconds per
        sample).

        Parameters
        ----------
        t_s : array_like
            Sample times [s], strictly increasing.
        u : array_like
            Input samples, same length.
        x0 : array_like, optional
            Initial state of the :meth:`state_space` realization (default zero).
        hold : {"linear", "zero"}
            Input interpolation between samples.

        Returns
        -------
        ndarray
            Output samples y(t_s).
        """
        t = np.asarray(t_s, dtype=float).ravel()
        u = np.asarray(u, dtype=float).ravel()
        if t.shape != u.shape:
            raise ValueError(f"simulate: t_s and u differ in length ({t.size} != {u.size})")
        if hold not in ("linear", "zero"):
            raise ValueError(f"simulate: hold must be 'linear' or 'zero', got {hold!r}")
        if t.size == 0:
            return np.zeros(0)
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(u))):
            raise ValueError("simulate: t_s and u must be finite")
        steps = np.diff(t)
        if np.any(steps <= 0.0):
            raise ValueError("simulate: t_s must be strictly increasing")
        if self.nonlinear:        # on the surface command, before the linear part
            u = apply_nonlinear(self._effects, t, u)
        # sampled and held: their delay is in the samples
        u, held_delay_s = apply_holds(self._effects, t, u)
        delay_s = self._delay_s - held_delay_s
        if delay_s > 1e-12:
            u = delayed_input(t, u, delay_s, hold)
        a, b, c, d = self.state_space()
        n = a.shape[0]
        x = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float).ravel()
        if x.size != n:
            raise ValueError(f"simulate: x0 needs {n} states, got {x.size}")
        return simulate_state_space(a, b, c, d, t, u, x, hold)


# ----------------------------------------------------------------------------------------------------------
# parsing of the airframe forms
# ----------------------------------------------------------------------------------------------------------


def _parse_tf(spec: dict, where: str) -> Airframe:
    for key in ("numerator", "denominator"):
        if key not in spec:
            raise ConfigError(
                f"{where}: missing key {key!r} (a transfer function needs numerator and denominator)"
            )
    num = _number_list(spec["numerator"], f"{where}.numerator")
    den = _number_list(spec["denominator"], f"{where}.denominator")
    if not np.any(den):
        raise ConfigError(f"{where}.denominator: expected a nonzero polynomial, got {spec['denominator']!r}")
    air_spec = {"numerator": num.tolist(), "denominator": den.tolist()}
    return num, den, air_spec, None


def _parse_zpk(spec: dict, where: str) -> Airframe:
    if "poles" not in spec:
        raise ConfigError(f"{where}: missing key 'poles' (zeros-poles-gain form; use [] for none)")
    zeros = _root_list(spec.get("zeros", []), f"{where}.zeros")
    poles = _root_list(spec["poles"], f"{where}.poles")
    gain = check_number(spec.get("gain", 1.0), f"{where}.gain", strings=True)
    num = gain * _real_poly(zeros)
    den = _real_poly(poles)
    air_spec = {
        "zeros": [_root_spec(r) for r in zeros],
        "poles": [_root_spec(r) for r in poles],
        "gain": gain,
    }
    return num, den, air_spec, None


def _root_spec(root: complex) -> float | list[float]:
    return float(root.real) if root.imag == 0.0 else [float(root.real), float(root.imag)]


def _parse_ss(spec: Any, where: str) -> Airframe:
    if not isinstance(spec, dict):
        raise ConfigError(
            f"{where}: expected a mapping with A, B, C (D, input, output optional), got {spec!r}"
        )
    unknown = [key for key in spec if key not in _SS_KEYS]
    if unknown:
        raise ConfigError(f"{where}.{unknown[0]}: unknown key (expected {', '.join(_SS_KEYS)}), got "
                          f"{unknown[0]!r}")
    for key in ("A", "B", "C"):
        if key not in spec:
            raise ConfigError(f"{where}: missing key {key!r}")
    a, b, c = _abc(spec, where)
    n, m, p = a.shape[0], b.shape[1], c.shape[0]
    d = np.zeros((p, m)) if spec.get("D") is None else _matrix(spec["D"], f"{where}.D", rows=p, cols=m)
    w_in = _selector(spec.get("input"), m, f"{where}.input", "input")
    w_out = _selector(spec.get("output"), p, f"{where}.output", "output")
    b1 = (b @ w_in).reshape(n, 1)
    c1 = (w_out @ c).reshape(1, n)
    d1 = np.array([[float(w_out @ d @ w_in)]])
    with np.errstate(all="ignore"):
        try:
            num, den = _ss2tf(a, b1, c1, d1)
        except (np.linalg.LinAlgError, ValueError) as err:
            raise ConfigError(f"{where}: cannot form the transfer function ({err})") from None
    if not (np.all(np.isfinite(num)) and np.all(np.isfinite(den))):
        raise ConfigError(f"{where}: the transfer function of these matrices is not finite in float64 "
                          f"(entries too large?)")
    num = _trim_leading(num[0], den)
    air_spec = {"state_space": {key: _plain(spec[key]) for key in _SS_KEYS if spec.get(key) is not None}}
    return num, den, air_spec, (a, b1, c1, d1)


def _abc(spec: dict, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The A (square), B (a row per state) and C (a column per state) matrices of a state-space mapping (SISO
    or MIMO), or a one-line ConfigError naming the key."""
    a = _matrix(spec["A"], f"{where}.A")
    n = a.shape[0]
    if a.shape != (n, n):
        raise ConfigError(f"{where}.A: expected a square matrix, got shape {a.shape[0]}x{a.shape[1]}")
    return a, _matrix(spec["B"], f"{where}.B", rows=n), _matrix(spec["C"], f"{where}.C", cols=n)


def _plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    return copy.deepcopy(value)


def _check_proper(num: np.ndarray, den: np.ndarray, where: str) -> None:
    num, den = strip_leading_zeros(num), strip_leading_zeros(den)
    if len(num) > len(den) and np.any(num):
        raise ConfigError(f"{where}: improper model (numerator degree {len(num) - 1} > denominator degree "
                          f"{len(den) - 1}), got numerator {num.tolist()}")


# ----------------------------------------------------------------------------------------------------------
# MIMO models
# ----------------------------------------------------------------------------------------------------------

_MIMO_KEYS = ("state_space", "transfer_matrix")
_MIMO_SS_KEYS = ("A", "B", "C", "D")


class MimoModel:
    """A MIMO linear model ``P(s) = C (sI - A)^-1 B + D`` with p outputs and m inputs, immutable.

    The model of a channel with ``inputs:``/``outputs:`` lists (DESIGN.md): column j of B (and of D) belongs
    to ``inputs[j]``, row i of C (and of D) to ``outputs[i]``. No delays or effects (yet); rational effects
    may be put into the elements of the ``transfer_matrix`` form.

    Parameters
    ----------
    a, b, c : array_like
        ``n x n``, ``n x m``, ``p x n`` (``n`` may be 0: a static gain).
    d : array_like, optional
        ``p x m`` feedthrough (default zero).

    Notes
    -----
    Build models from a config mapping with :meth:`from_spec`; :meth:`to_spec` gives it back. The metrics
    (:func:`~gap_validation.core.metrics.nugap`) and :func:`~gap_validation.core.robust.stability_margin`
    accept a MimoModel wherever they accept a :class:`LinearModel`.
    """

    __slots__ = ("_system", "_spec", "_minimal")

    def __init__(self, a: ArrayLike, b: ArrayLike, c: ArrayLike, d: ArrayLike | None = None, *,
                 _spec: dict | None = None) -> None:
        from gap_validation.core.statespace import as_state_space

        system = as_state_space(a, b, c, d)
        if not all(np.all(np.isfinite(m)) for m in system):
            raise ConfigError("model.state_space: expected finite matrices")
        for matrix in system:
            matrix.setflags(write=False)
        self._system = system
        self._spec = _spec
        self._minimal = None

    # -- construction from / to the config mapping ----------------------------------------------------------

    @classmethod
    def from_spec(
        cls,
        spec: Any,
        where: str = "model",
        inputs: int | None = None,
        outputs: int | None = None,
        *,
        inputs_are: str = "input",
        outputs_are: str = "output",
    ) -> MimoModel:
        """Build a MIMO model from a config ``model:`` (or ``controller:``) mapping.

        Forms::

            state_space: {A: [[...]], B: [[...]], C: [[...]], D: [[...]]}   # D optional; or only D (a gain)
            transfer_matrix:                                                 # rows: outputs, columns: inputs
              - [{numerator: [...], denominator: [...]}, 0.0]               # an element: a number or any
              - [0.0, {zeros: [], poles: [-2.0], gain: 1.0}]                # SISO model mapping (no delay)

        Parameters
        ----------
        spec : mapping
            The mapping.
        where : str
            Its path in the config, for error messages.
        inputs, outputs : int, optional
            Required numbers of inputs (columns of B and D) and outputs (rows of C and D).
        inputs_are, outputs_are : str
            What one input / output is, for error messages (``"entry of channels.lateral.inputs"``).

        Returns
        -------
        MimoModel

        Raises
        ------
        ConfigError
            One line naming the path, key and value: unknown keys, wrong shapes (B columns not matching the
            inputs, ...), non-finite or absurd numbers, delays.
        """
        if not isinstance(spec, dict):
            raise ConfigError(f"{where}: expected a mapping (state_space or transfer_matrix), got {spec!r}")
        for key in spec:
            if key in ("delay_s", "effects"):
                raise ConfigError(
                    f"{where}.{key}: not available for a MIMO model yet (put rational effects into "
                    f"the elements of a transfer_matrix), got {spec[key]!r}"
                )
            if key not in _MIMO_KEYS:
                raise ConfigError(f"{where}.{key}: unknown key for a MIMO model (expected state_space or "
                                  f"transfer_matrix), got {key!r}: {spec[key]!r}")
        if len(spec) != 1:
            raise ConfigError(f"{where}: expected exactly one of state_space or transfer_matrix, got keys "
                              f"{sorted(spec)}")
        shape = (outputs, inputs, outputs_are, inputs_are)
        if "state_space" in spec:
            system = _parse_mimo_ss(spec["state_space"], f"{where}.state_space", *shape)
        else:
            system = _parse_transfer_matrix(spec["transfer_matrix"], f"{where}.transfer_matrix", *shape)
        return cls(*system, _spec={key: _plain(value) for key, value in spec.items()})

    @classmethod
    def from_linear(cls, model: LinearModel) -> MimoModel:
        """The 1 x 1 MimoModel of a SISO model without delay.

        Parameters
        ----------
        model : LinearModel
            A model with ``delay_s == 0``.

        Raises
        ------
        ValueError
            When the model has a delay (no finite state space).
        """
        if model.delay_s:
            raise ValueError(f"a model with a delay ({model.delay_s:g} s) has no finite state space")
        return cls(*model.state_space())

    def to_spec(self) -> dict:
        """Config ``model:`` mapping that :meth:`from_spec` turns back into this model (plain lists)."""
        if self._spec is not None:
            return copy.deepcopy(self._spec)
        a, b, c, d = self._system
        return {"state_space": {"A": a.tolist(), "B": b.tolist(), "C": c.tolist(), "D": d.tolist()}}

    # -- attributes -----------------------------------------------------------------------------------------

    @property
    def shape(self) -> tuple[int, int]:
        """(outputs, inputs)."""
        return self._system[3].shape

    @property
    def order(self) -> int:
        """Number of states of the realization as given."""
        return self._system[0].shape[0]

    @property
    def delay_s(self) -> float:
        """Pure delay [s]: always 0 for a MIMO model."""
        return 0.0

    @property
    def effects(self) -> tuple[dict, ...]:
        """Effects in series: none for a MIMO model."""
        return ()

    def with_effects(self, effects: Sequence[dict]) -> MimoModel:
        """Effects in series are not available for a MIMO model yet: the model itself when ``effects`` is
        empty.

        Parameters
        ----------
        effects : sequence of dict
            Effect mappings.

        Raises
        ------
        ConfigError
            When ``effects`` is not empty.
        """
        if effects:
            names = ", ".join(str(e.get("type", e)) if isinstance(e, dict) else repr(e) for e in effects)
            raise ConfigError(f"model.effects: effects on a MIMO model are not available yet, got {names}")
        return self

    def state_space(self) -> StateSpace:
        """The realization (A, B, C, D) as given (read-only arrays)."""
        return self._system

    def minimal_state_space(self) -> StateSpace:
        """A minimal realization (controllable and observable part; cached)."""
        if self._minimal is None:
            from gap_validation.core.statespace import minimal_realization

            self._minimal = minimal_realization(self._system)
        return self._minimal

    def poles(self) -> np.ndarray:
        """Poles of the transfer matrix [rad/s]: eigenvalues of the minimal realization's A."""
        a = self.minimal_state_space()[0]
        return np.linalg.eigvals(a) if a.size else np.zeros(0, dtype=complex)

    def siso(self) -> LinearModel:
        """The :class:`LinearModel` of a 1 x 1 model (transfer function of the minimal realization).

        Raises
        ------
        ValueError
            When the model is not 1 x 1.
        """
        if self.shape != (1, 1):
            raise ValueError(f"a {self.shape[0]}x{self.shape[1]} model is not SISO")
        a, b, c, d = self.minimal_state_space()
        if a.shape[0] == 0:
            return LinearModel([d[0, 0]], [1.0])
        num, den = _ss2tf(a, b, c, d)
        return LinearModel(_trim_leading(num[0], den), den)

    def __repr__(self) -> str:
        return f"MimoModel({self.shape[0]}x{self.shape[1]}, {self.order} states)"

    # -- frequency response ---------------------------------------------------------------------------------

    def freqresp(self, w_rad_s: ArrayLike) -> np.ndarray:
        """Complex frequency response matrices P(j w), from the minimal realization (a hidden mode on the
        axis, e.g. an unobserved heading integrator, does not make P(j0) infinite).

        Parameters
        ----------
        w_rad_s : array_like
            Frequencies [rad/s].

        Returns
        -------
        ndarray of complex
            Shape ``(len(w), outputs, inputs)``.
        """
        from gap_validation.core.statespace import freqresp

        return freqresp(self.minimal_state_space(), w_rad_s)


def _parse_mimo_ss(spec: Any, where: str, outputs: int | None, inputs: int | None, outputs_are: str,
                   inputs_are: str) -> StateSpace:
    if not isinstance(spec, dict):
        raise ConfigError(f"{where}: expected a mapping with A, B, C (D optional) or only D, got {spec!r}")
    for key in spec:
        if key in ("input", "output"):
            raise ConfigError(
                f"{where}.{key}: not used by a MIMO model (columns of B follow the inputs list, rows "
                f"of C the outputs list), got {spec[key]!r}"
            )
        if key not in _MIMO_SS_KEYS:
            raise ConfigError(
                f"{where}.{key}: unknown key (expected {', '.join(_MIMO_SS_KEYS)}), got {key!r}"
            )
    given = [key for key in ("A", "B", "C") if key in spec]
    if not given:
        if "D" not in spec:
            raise ConfigError(f"{where}: missing key 'A' (A, B, C, or only D for a static gain)")
        d = _matrix(spec["D"], f"{where}.D", rows=outputs if outputs == 1 else None,
                    cols=inputs if inputs == 1 else None)
        _check_shape(d, f"{where}.D", outputs, inputs, outputs_are, inputs_are)
        return np.zeros((0, 0)), np.zeros((0, d.shape[1])), np.zeros((d.shape[0], 0)), d
    for key in ("A", "B", "C"):
        if key not in spec:
            raise ConfigError(f"{where}: missing key {key!r} (A, B, C, or only D for a static gain)")
    a, b, c = _abc(spec, where)
    _check_shape(b, f"{where}.B", None, inputs, outputs_are, inputs_are)
    _check_shape(c, f"{where}.C", outputs, None, outputs_are, inputs_are)
    p, m = c.shape[0], b.shape[1]
    d = np.zeros((p, m)) if spec.get("D") is None else _matrix(spec["D"], f"{where}.D")
    _check_shape(d, f"{where}.D", p, m, outputs_are, inputs_are)
    return a, b, c, d


def _check_shape(matrix: np.ndarray, where: str, rows: int | None, cols: int | None, rows_are: str,
                 cols_are: str) -> None:
    """ConfigError naming the key, the expected count and the shape given."""
    got = f"got shape {matrix.shape[0]}x{matrix.shape[1]}"
    if cols is not None and matrix.shape[1] != cols:
        raise ConfigError(f"{where}: expected {cols} column{'s' * (cols != 1)} (one per {cols_are}), {got}")
    if rows is not None and matrix.shape[0] != rows:
        raise ConfigError(f"{where}: expected {rows} row{'s' * (rows != 1)} (one per {rows_are}), {got}")


def _parse_transfer_matrix(spec: Any, where: str, outputs: int | None, inputs: int | None, outputs_are: str,
                           inputs_are: str) -> StateSpace:
    """A transfer matrix (rows of elements) as one realization: every element's states side by side."""
    if not isinstance(spec, (list, tuple)) or not spec or \
            not all(isinstance(row, (list, tuple)) and row for row in spec):
        raise ConfigError(f"{where}: expected a non-empty list of rows (one per output), each a list of "
                          f"elements (one per input), got {spec!r}")
    if outputs is not None and len(spec) != outputs:
        raise ConfigError(
            f"{where}: expected {outputs} row{'s' * (outputs != 1)} (one per {outputs_are}), got {len(spec)}"
        )
    m = len(spec[0])
    if inputs is not None and m != inputs:
        raise ConfigError(
            f"{where}[0]: expected {inputs} element{'s' * (inputs != 1)} (one per {inputs_are}), got {m}"
        )
    blocks = []
    for i, row in enumerate(spec):
        if len(row) != m:
            raise ConfigError(f"{where}[{i}]: expected {m} elements like row 0, got {len(row)}")
        for j, element in enumerate(row):
            blocks.append((i, j, _element(element, f"{where}[{i}][{j}]")))
    n = sum(block[0].shape[0] for _, _, block in blocks)
    a, b, c, d = np.zeros((n, n)), np.zeros((n, m)), np.zeros((len(spec), n)), np.zeros((len(spec), m))
    k = 0
    for i, j, (ae, be, ce, de) in blocks:
        size = ae.shape[0]
        a[k:k + size, k:k + size] = ae
        b[k:k + size, j] = be[:, 0]
        c[i, k:k + size] = ce[0]
        d[i, j] = de[0, 0]
        k += size
    return a, b, c, d


def _element(value: Any, where: str) -> StateSpace:
    """One element of a transfer matrix: a number (static gain) or a SISO model mapping without delay."""
    if isinstance(value, dict):
        model = LinearModel.from_spec(value, where)
        if model.delay_s:
            raise ConfigError(f"{where}: delays are not available in a MIMO model yet, got a delay of "
                              f"{model.delay_s:g} s")
        return model.state_space()
    gain = check_number(value, where, strings=True, expected="a number or a model mapping (numerator/"
                                                              "denominator, zeros/poles/gain)")
    return np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.array([[gain]])
