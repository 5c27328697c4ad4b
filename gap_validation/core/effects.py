"""Physical effects that are added to a model in series (DESIGN.md, "Effects vocabulary"): one registry.

Each effect is a plain mapping such as ``{"type": "time_delay", "seconds": 0.05}``. Its *factor* in series
with the model is a rational part (numerator, denominator in descending powers of s) times a pure delay
``exp(-s T)``:

==================  ==================================  ==============================
type                parameters                          factor
==================  ==================================  ==============================
time_delay          seconds                             exp(-s T)
first_order_lag     bandwidth_rad_s                     a / (s + a)
second_order_lag    natural_frequency_rad_s, damping    wn^2 / (s^2 + 2 z wn s + wn^2)
gain                factor                              k
structural_mode     frequency_rad_s, damping,           (s^2/wz^2 + 2 zz s/wz + 1) /
                    zero_frequency_rad_s, zero_damping  (s^2/wp^2 + 2 zp s/wp + 1)
rate_limit          rad_s                               describing function N(A w / R)
backlash            width_rad                           describing function N(b / A)
zero_order_hold     rate_hz                             exp(-s T/2) sinc(w T/2),
                                                        T = 1 / rate_hz
==================  ==================================  ==============================

All factors except ``gain`` have unit gain at s = 0. The names and parameters are a user contract: they are
written in configs and reported by the diagnosis, so they are never renamed.

The registry
------------
:data:`EFFECTS` holds one :class:`EffectType` per effect, the one place that knows it: its parameters with the
values a config may give (:attr:`Parameter.valid`, checked by :func:`validate_effect`) and the values that
make physical sense (:attr:`Parameter.plausible`, checked by :func:`check_plausible` when a model is read from
a config), its factor ``(num, den, delay_s)`` and response, its words (:func:`describe_effect`) and how the
diagnosis fits it (:class:`EffectFit`: start grid, bounds and vectorised response in fit coordinates, e.g. log
frequencies). :mod:`gap_validation.core.models`, the config checks and :mod:`gap_validation.core.diagnosis`
all read it.

Amplitude-dependent (nonlinear) effects
---------------------------------------
``rate_limit`` (a surface rate limit R [rad/s]) and ``backlash`` (free play of total width b [rad]) act on the
surface command before the airframe. They have no linear factor (``factor=None``); in the frequency domain
they are their *describing functions* (the first harmonic of the output for a sinusoid of amplitude A at w,
divided by the input's), evaluated at the amplitude flown at each frequency (:func:`rate_limit_df`,
:func:`backlash_df`). :meth:`EffectType.response` then needs the amplitude; a
:class:`~gap_validation.core.models.LinearModel` holding one needs it too (``at_amplitude``), and simulates it
in the time domain (:func:`rate_limited`, :func:`backlash_output`). Their fits
(:attr:`EffectType.describing_fit`) take the flown amplitude per frequency as a third argument of the
response.

A hold is not rational
----------------------
``zero_order_hold`` (a servo or an output stage that takes a new command ``rate_hz`` times a second and holds
it: analog servos at their 50 Hz frame, a slow autopilot output loop) is linear, but its factor
``(1 - exp(-s T)) / (s T) = exp(-s T/2) sinc(w T/2)`` is not rational: half a period of delay (its
:attr:`EffectType.factor`, exact) times a real, zero-phase droop (:attr:`EffectType.shape`), which reaches
0.64 at half the hold rate. The frequency response is exact; in the time domain the element samples and holds
(:func:`held`), so a model holding one is simulated exactly (not as its delay). The droop is what tells a hold
from a delay: over a band reaching a quarter of the hold rate it is 10 %.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from gap_validation.core.errors import ConfigError
from gap_validation.core.numbers import NON_NEGATIVE, NONZERO, POSITIVE, Interval, check_number, significant

__all__ = [
    "Parameter",
    "FitRange",
    "EffectFit",
    "EffectType",
    "EFFECTS",
    "EFFECT_TYPES",
    "MAX_DELAY_S",
    "validate_effect",
    "check_plausible",
    "effect_factor",
    "effect_response",
    "describe_effect",
    "is_nonlinear",
    "rate_limit_df",
    "backlash_df",
    "rate_limited",
    "backlash_output",
    "apply_nonlinear",
    "held",
    "apply_holds",
]

#: Largest delay the diagnosis fits [s].
MAX_DELAY_S = 0.5

Factor = tuple[np.ndarray, np.ndarray, float]


@dataclass(frozen=True)
class Parameter:
    """One parameter of an effect.

    Attributes
    ----------
    name : str
        Key in the effect mapping (with its unit: ``seconds``, ``bandwidth_rad_s``).
    valid : Interval
        Values a config may give (:func:`validate_effect`).
    plausible : Interval
        Values that make physical sense; outside, a typo or wrong units (:func:`check_plausible`).
    magnitude : bool
        The plausible range applies to the magnitude (a gain factor may be negative).
    """

    name: str
    valid: Interval
    plausible: Interval
    magnitude: bool = False

    def check_plausible(self, value: float, where: str) -> None:
        """ConfigError naming ``where`` when ``value`` is outside the plausible range.

        Parameters
        ----------
        value : float
            A valid value of the parameter.
        where : str
            Path of the value in the config.
        """
        if (abs(value) if self.magnitude else value) not in self.plausible:
            raise ConfigError(f"{where}: {value!r} is outside the plausible range [{self.plausible.low:g}, "
                              f"{self.plausible.high:g}] (wrong units?)")


@dataclass(frozen=True)
class EffectFit:
    """How the diagnosis fits one effect, in fit coordinates ``x`` (one row per parameter set).

    Attributes
    ----------
    grid : callable
        ``grid(fit_range, coarse) -> (M, p)`` start points (coarse: for pairs of effects).
    bounds : callable
        ``bounds(x0, fit_range) -> (lo, hi)``, the box of the local refinement from ``x0``.
    response : callable
        ``response(X, w_rad_s) -> (M, N)`` complex factor for M parameter rows.
    spec : callable
        ``spec(x) -> dict``, the effect mapping of one row (parameters rounded for the config).
    """

    grid: Callable[[FitRange, bool], np.ndarray]
    bounds: Callable[[np.ndarray, FitRange], tuple[np.ndarray, np.ndarray]]
    response: Callable[[np.ndarray, np.ndarray], np.ndarray]
    spec: Callable[[np.ndarray], dict]


@dataclass(frozen=True)
class EffectType:
    """One entry of the effects vocabulary: everything the package knows about an effect.

    Attributes
    ----------
    name : str
        The ``type`` of the effect mapping.
    parameters : tuple of Parameter
        In the order of DESIGN.md's table.
    factor : callable or None
        ``factor(params) -> (num, den, delay_s)``, the linear factor in series with the model; None for an
        amplitude-dependent effect.
    describe : callable
        ``describe(params) -> str``, the words of the diagnosis sentence.
    fit : EffectFit or None
        How the diagnosis fits it (None: never proposed by the diagnosis).
    describing_function : callable or None
        ``describing_function(params, w_rad_s, amplitude) -> complex array`` of an amplitude-dependent effect.
    describing_fit : EffectFit or None
        How the diagnosis fits an amplitude-dependent effect: as :attr:`fit`, but its ``response(X, w,
        amplitude)`` takes the flown amplitude at each frequency.
    time_domain : callable or None
        ``time_domain(params, t_s, u) -> y``: the element on sampled signals (simulation).
    shape : callable or None
        ``shape(params, w_rad_s) -> real array``: the non-rational, zero-phase part of a linear effect's
        factor (the droop of a hold), multiplying :attr:`factor`'s response; :attr:`time_domain` then
        simulates the whole effect, its delay included.
    """

    name: str
    parameters: tuple[Parameter, ...]
    factor: Callable[[Mapping[str, float]], Factor] | None
    describe: Callable[[Mapping[str, float]], str]
    fit: EffectFit | None = None
    describing_function: Callable[[Mapping[str, float], np.ndarray, Any], np.ndarray] | None = None
    describing_fit: EffectFit | None = None
    time_domain: Callable[[Mapping[str, float], np.ndarray, np.ndarray], np.ndarray] | None = None
    shape: Callable[[Mapping[str, float], np.ndarray], np.ndarray] | None = None

    @property
    def names(self) -> tuple[str, ...]:
        """Parameter names, in order."""
        return tuple(p.name for p in self.parameters)

    @property
    def complexity(self) -> int:
        """Number of parameters (what a fit of this effect adjusts)."""
        return len(self.parameters)

    def parameter(self, name: str) -> Parameter:
        """The :class:`Parameter` called ``name``.

        Parameters
        ----------
        name : str
            A parameter name of this effect.
        """
        return next(p for p in self.parameters if p.name == name)

    def response(self, params: Mapping[str, float], w_rad_s: Any, amplitude: Any = None) -> np.ndarray:
        """Complex factor at s = j w (delay included exactly), or the describing function at ``amplitude``.

        Parameters
        ----------
        params : mapping
            Parameter values (a validated effect mapping).
        w_rad_s : array_like
            Frequencies [rad/s].
        amplitude : array_like, optional
            Amplitude of the flown input at each frequency, for an amplitude-dependent effect (ignored by the
            linear ones).

        Returns
        -------
        ndarray of complex
            Same shape as ``w_rad_s``.
        """
        w = np.asarray(w_rad_s, dtype=float)
        if self.factor is None:
            if amplitude is None or self.describing_function is None:
                raise ConfigError(f"effect {self.name}: depends on the input amplitude, which is not given")
            return self.describing_function(params, w, np.broadcast_to(np.asarray(amplitude, float), w.shape))
        num, den, delay_s = self.factor(params)
        s = 1j * w
        out = np.polyval(num, s) / np.polyval(den, s) * np.exp(-s * delay_s)
        return out if self.shape is None else out * self.shape(params, w)


# ------------------------------------------------------------------------------------------------ factors,
# words
def _hz(w_rad_s: float) -> float:
    return w_rad_s / (2.0 * math.pi)


def _delay_factor(p: Mapping[str, float]) -> Factor:
    return np.array([1.0]), np.array([1.0]), p["seconds"]


def _delay_words(p: Mapping[str, float]) -> str:
    ms = p["seconds"] * 1e3
    return f"time delay of {ms:.3g} ms" if ms < 10.0 else f"time delay of {ms:.0f} ms"


def _lag1_factor(p: Mapping[str, float]) -> Factor:
    a = p["bandwidth_rad_s"]
    return np.array([a]), np.array([1.0, a]), 0.0


def _lag1_words(p: Mapping[str, float]) -> str:
    a = p["bandwidth_rad_s"]
    return f"first-order lag at {a:.1f} rad/s ({_hz(a):.1f} Hz)"


def _lag2_factor(p: Mapping[str, float]) -> Factor:
    wn, zeta = p["natural_frequency_rad_s"], p["damping"]
    return np.array([wn * wn]), np.array([1.0, 2.0 * zeta * wn, wn * wn]), 0.0


def _lag2_words(p: Mapping[str, float]) -> str:
    wn, zeta = p["natural_frequency_rad_s"], p["damping"]
    return f"second-order lag at {wn:.1f} rad/s ({_hz(wn):.1f} Hz), damping {zeta:.2f}"


def _gain_factor(p: Mapping[str, float]) -> Factor:
    return np.array([p["factor"]]), np.array([1.0]), 0.0


def _gain_words(p: Mapping[str, float]) -> str:
    return f"gain error x{p['factor']:.3g}"


def _mode_factor(p: Mapping[str, float]) -> Factor:
    wp, zp = p["frequency_rad_s"], p["damping"]
    wz, zz = p["zero_frequency_rad_s"], p["zero_damping"]
    # (s^2/wz^2 + 2 zz s/wz + 1)/(s^2/wp^2 + 2 zp s/wp + 1), multiplied through by wp^2 (monic denominator).
    scale = (wp / wz) ** 2
    return scale * np.array([1.0, 2.0 * zz * wz, wz * wz]), np.array([1.0, 2.0 * zp * wp, wp * wp]), 0.0


def _mode_words(p: Mapping[str, float]) -> str:
    wp, zp = p["frequency_rad_s"], p["damping"]
    wz, zz = p["zero_frequency_rad_s"], p["zero_damping"]
    return (
        f"structural mode at {wp:.1f} rad/s ({_hz(wp):.1f} Hz), damping {zp:.3g}, "
        f"with zeros at {wz:.1f} rad/s ({_hz(wz):.1f} Hz), damping {zz:.3g}"
    )


def _hold_factor(p: Mapping[str, float]) -> Factor:
    return np.array([1.0]), np.array([1.0]), 0.5 / p["rate_hz"]


def _hold_shape(p: Mapping[str, float], w: np.ndarray) -> np.ndarray:
    return np.sinc(np.asarray(w, float) / (2.0 * math.pi * p["rate_hz"]))     # sin(w T/2) / (w T/2)


def _hold_words(p: Mapping[str, float]) -> str:
    rate = p["rate_hz"]
    return (f"zero-order hold at {rate:.3g} Hz (the surface takes a new command every {1e3 / rate:.3g} ms: "
            f"{500.0 / rate:.3g} ms of delay and the hold's droop)")


def held(t_s: Any, u: Any, rate_hz: float) -> np.ndarray:
    """A signal through a zero-order hold: at each time, the (linearly interpolated) signal at the last tick
    of a ``rate_hz`` clock that starts at the first sample.

    Parameters
    ----------
    t_s : array_like
        Sample times [s], increasing.
    u : array_like
        Commanded signal.
    rate_hz : float
        Rate of the hold [Hz].
    """
    t = np.asarray(t_s, float).ravel()
    u = np.asarray(u, float).ravel()
    if u.size == 0:
        return u.copy()
    ticks = t[0] + np.floor((t - t[0]) * rate_hz + 1e-9) / rate_hz
    return np.interp(ticks, t, u)


def apply_holds(effects: Sequence[Mapping[str, Any]], t_s: Any, u: Any) -> tuple[np.ndarray, float]:
    """The command ``u`` through the holds of ``effects`` (:attr:`EffectType.shape`), and the delay their
    factors carry (which the held samples already have: a simulation applies the rest of the model's delay
    only).

    Parameters
    ----------
    effects : sequence of mapping
        Validated effects; the others are skipped.
    t_s : array_like
        Sample times [s].
    u : array_like
        Samples of the command.

    Returns
    -------
    u : ndarray
        The held command.
    delay_s : float
        The holds' factor delay [s].
    """
    out = np.asarray(u, float).ravel()
    delay = 0.0
    for e in effects:
        entry = EFFECTS[e["type"]]
        if entry.shape is not None and entry.time_domain is not None:
            out = entry.time_domain(e, np.asarray(t_s, float).ravel(), out)
            delay += entry.factor(e)[2]
    return out, delay


# ------------------------------------------------------------------------------------------------ fits
@dataclass(frozen=True)
class FitRange:
    """Range of the usable frequencies a fit sees [rad/s]."""

    w_lo: float
    w_hi: float


def _product(*axes: Sequence[float]) -> np.ndarray:
    return np.array(list(itertools.product(*axes)), dtype=float)


def _delay_grid(ctx: FitRange, coarse: bool) -> np.ndarray:
    step = (0.6 if coarse else 0.25) / ctx.w_hi          # phase step at the top frequency [rad]
    count = int(min(MAX_DELAY_S / step, 60 if coarse else 400)) + 1
    return np.linspace(0.0, MAX_DELAY_S, count)[:, None]


def _delay_bounds(x0: np.ndarray, ctx: FitRange) -> tuple[np.ndarray, np.ndarray]:
    return np.array([0.0]), np.array([MAX_DELAY_S])


def _delay_response(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    return np.exp(-1j * np.outer(x[:, 0], w))


def _delay_spec(x: np.ndarray) -> dict:
    return {"type": "time_delay", "seconds": significant(max(x[0], 0.0))}


def _lag1_bounds(x0: np.ndarray | None, ctx: FitRange) -> tuple[np.ndarray, np.ndarray]:
    # a corner below the confident band is a gain and phase offset there, not an identifiable lag
    return np.log([0.5 * ctx.w_lo]), np.log([30.0 * ctx.w_hi])


def _lag1_grid(ctx: FitRange, coarse: bool) -> np.ndarray:
    lo, hi = _lag1_bounds(None, ctx)
    return np.linspace(lo[0], hi[0], 12 if coarse else 40)[:, None]


def _lag1_response(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    a = np.exp(x[:, :1])
    return a / (1j * w[None, :] + a)


def _lag1_spec(x: np.ndarray) -> dict:
    return {"type": "first_order_lag", "bandwidth_rad_s": significant(math.exp(x[0]))}


def _hold_bounds(x0: np.ndarray | None, ctx: FitRange) -> tuple[np.ndarray, np.ndarray]:
    # from the rate whose first null (w = 2 pi rate) is the band's top (slower holds alias the band away) up
    # to the rate whose half-period delay turns the top by 0.01 rad; and no slower than the largest delay
    # fitted
    lo = max(ctx.w_hi / (2.0 * math.pi), 0.5 / MAX_DELAY_S)
    return np.log([lo]), np.log([max(50.0 * ctx.w_hi, 2.0 * lo)])


def _hold_grid(ctx: FitRange, coarse: bool) -> np.ndarray:
    lo, hi = _hold_bounds(None, ctx)
    return np.linspace(lo[0], hi[0], 12 if coarse else 60)[:, None]


def _hold_response(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    rate = np.exp(x[:, :1])
    return np.exp(-0.5j * w[None, :] / rate) * np.sinc(w[None, :] / (2.0 * math.pi * rate))


def _hold_spec(x: np.ndarray) -> dict:
    return {"type": "zero_order_hold", "rate_hz": significant(math.exp(x[0]))}


_ZETA_RANGE = (0.02, 2.5)


def _lag2_bounds(x0: np.ndarray | None, ctx: FitRange) -> tuple[np.ndarray, np.ndarray]:
    return (np.array([math.log(0.5 * ctx.w_lo), _ZETA_RANGE[0]]),
            np.array([math.log(10.0 * ctx.w_hi), _ZETA_RANGE[1]]))


def _lag2_grid(ctx: FitRange, coarse: bool) -> np.ndarray:
    lo, hi = _lag2_bounds(None, ctx)
    wn = np.linspace(lo[0], hi[0], 10 if coarse else 28)
    zeta = [0.1, 0.3, 0.7, 1.5] if coarse else [0.05, 0.1, 0.2, 0.35, 0.5, 0.7, 1.0, 1.5, 2.2]
    return _product(wn, zeta)


def _lag2_response(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    wn, zeta = np.exp(x[:, :1]), x[:, 1:2]
    r = w[None, :] / wn
    return 1.0 / (1.0 - r ** 2 + 2j * zeta * r)


def _lag2_spec(x: np.ndarray) -> dict:
    return {"type": "second_order_lag", "natural_frequency_rad_s": significant(math.exp(x[0])),
            "damping": significant(x[1], 3)}


def _gain_bounds(x0: np.ndarray, ctx: FitRange) -> tuple[np.ndarray, np.ndarray]:
    # the search range is the grid's, +-20 dB of either sign: a fit on its edge is beyond it (never offered)
    return (np.array([0.1]), np.array([10.0])) if x0[0] > 0 else (np.array([-10.0]), np.array([-0.1]))


def _gain_grid(ctx: FitRange, coarse: bool) -> np.ndarray:
    k = np.geomspace(0.1, 10.0, 15 if coarse else 61)
    return np.concatenate([k, -k])[:, None]


def _gain_response(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    return np.broadcast_to(x[:, :1].astype(complex), (x.shape[0], w.size))


def _gain_spec(x: np.ndarray) -> dict:
    return {"type": "gain", "factor": significant(x[0])}


_MODE_ZETA = (0.005, 1.0)


def _mode_bounds(x0: np.ndarray | None, ctx: FitRange) -> tuple[np.ndarray, np.ndarray]:
    # the mode (poles) must lie inside the confident band: outside it a pole-zero pair is only a gain or a
    # phase tilt there, which simpler effects explain
    return (np.array([math.log(ctx.w_lo), _MODE_ZETA[0], math.log(0.5 * ctx.w_lo), _MODE_ZETA[0]]),
            np.array([math.log(ctx.w_hi), _MODE_ZETA[1], math.log(2.0 * ctx.w_hi), _MODE_ZETA[1]]))


def _mode_grid(ctx: FitRange, coarse: bool) -> np.ndarray:
    if coarse:
        wp = np.geomspace(ctx.w_lo, ctx.w_hi, 8)
        axes = (np.log(wp), [0.05, 0.2], np.log([0.7, 0.9, 1.1, 1.4]), [0.05, 0.3])
    else:
        wp = np.geomspace(ctx.w_lo, ctx.w_hi, 18)
        axes = (np.log(wp), [0.02, 0.05, 0.1, 0.2, 0.4], np.log([0.5, 0.7, 0.8, 0.9, 1.1, 1.25, 1.4, 2.0]),
                [0.02, 0.07, 0.2, 0.5])
    grid = _product(*axes)
    grid[:, 2] += grid[:, 0]                            # zero frequency = ratio x pole frequency
    lo, hi = _mode_bounds(None, ctx)
    return np.clip(grid, lo, hi)


def _mode_response(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    wp, zp, wz, zz = np.exp(x[:, :1]), x[:, 1:2], np.exp(x[:, 2:3]), x[:, 3:4]
    rp, rz = w[None, :] / wp, w[None, :] / wz
    return (1.0 - rz ** 2 + 2j * zz * rz) / (1.0 - rp ** 2 + 2j * zp * rp)


def _mode_spec(x: np.ndarray) -> dict:
    return {"type": "structural_mode", "frequency_rad_s": significant(math.exp(x[0])),
            "damping": significant(x[1], 3), "zero_frequency_rad_s": significant(math.exp(x[2])),
            "zero_damping": significant(x[3], 3)}


# ------------------------------------------------------------------------------------------------ nonlinear
# effects
#: Largest R / (A w) of a rate limit whose output is a pure triangle wave (it never catches the sinusoid):
#: 1 / sqrt(1 + pi^2 / 4).
_RHO_TRIANGLE = 1.0 / math.sqrt(1.0 + math.pi ** 2 / 4.0)


def rate_limit_df(rho: Any) -> np.ndarray:
    """Describing function of a rate limit as a function of ``rho = R / (A w)`` (exact, closed form).

    For ``x = A sin(w t)`` through ``|dy/dt| <= R``: ``rho >= 1``, the limit is never reached (N = 1);
    ``rho <= 1 / sqrt(1 + pi^2/4)``, the output is a triangle wave of slope R that never catches the input:
    ``N = (4 rho / pi) exp(-j acos(pi rho / 2))``; in between the output follows the sinusoid near its peaks
    (where ``|dx/dt| <= R``) and slews at R from ``theta_2 = pi - acos(rho)`` until it meets the input again
    at ``theta_m + pi``, with ``sqrt(1 - rho^2) + sin(theta_m) = rho (theta_m + acos(rho))``; N is the first
    Fourier coefficient of that output, integrated piecewise in closed form.

    Parameters
    ----------
    rho : array_like
        ``R / (A w)`` (> 0).

    Returns
    -------
    ndarray of complex
        N, same shape as ``rho`` (``|N| <= 1``, phase a lag).
    """
    rho = np.asarray(rho, float)
    out = np.ones(rho.shape, complex)
    tri = rho <= _RHO_TRIANGLE
    r = rho[tri]
    out[tri] = 4.0 * r / math.pi * np.exp(-1j * np.arccos(np.minimum(math.pi * r / 2.0, 1.0)))
    mid = (rho > _RHO_TRIANGLE) & (rho < 1.0)
    if np.any(mid):
        r = rho[mid]
        a = np.arccos(r)
        c = np.sqrt(1.0 - r * r)
        lo, hi = a.copy(), math.pi - a           # f(theta) = r (theta + a) - c - sin(theta) rises on [lo, hi]
        for _ in range(60):
            m = 0.5 * (lo + hi)
            up = r * (m + a) - c - np.sin(m) > 0.0
            hi, lo = np.where(up, m, hi), np.where(up, lo, m)
        tm = 0.5 * (lo + hi)
        t2 = math.pi - a
        t3 = tm + math.pi
        # following: y = sin(theta) on [tm, t2]
        i_s = (t2 - tm) / 2.0 - (np.sin(2 * t2) - np.sin(2 * tm)) / 4.0
        i_c = (np.sin(t2) ** 2 - np.sin(tm) ** 2) / 2.0
        # slewing: y = c - r (theta - t2) on [t2, t3]
        i_s += c * (np.cos(t2) - np.cos(t3)) - r * (-(t3 - t2) * np.cos(t3) + np.sin(t3) - np.sin(t2))
        i_c += c * (np.sin(t3) - np.sin(t2)) - r * ((t3 - t2) * np.sin(t3) + np.cos(t3) - np.cos(t2))
        out[mid] = (2.0 / math.pi) * (i_s + 1j * i_c)
    return out


def backlash_df(ratio: Any) -> np.ndarray:
    """Describing function of backlash (free play) as a function of ``ratio = b / A`` (textbook, exact).

    With half-width ``h = b / 2`` and ``r = h / A < 1`` (Gelb & Vander Velde, *Multiple-Input Describing
    Functions and Nonlinear System Design*, 1968)::

        Re N = (pi/2 + asin(1 - 2 r) + 2 (1 - 2 r) sqrt(r (1 - r))) / pi,    Im N = -4 r (1 - r) / pi

    and N = 0 when the amplitude does not cross the free play (``r >= 1``).

    Parameters
    ----------
    ratio : array_like
        Total free play over the input amplitude, ``b / A`` (>= 0).

    Returns
    -------
    ndarray of complex
        N, same shape as ``ratio``.
    """
    r = np.clip(np.asarray(ratio, float) / 2.0, 0.0, 1.0)
    q = 1.0 - 2.0 * r
    re = (math.pi / 2.0 + np.arcsin(q) + 2.0 * q * np.sqrt(r * (1.0 - r))) / math.pi
    return re - 1j * 4.0 * r * (1.0 - r) / math.pi


def _amplitude(amplitude: Any) -> np.ndarray:
    a = np.asarray(amplitude, float)
    return np.where(np.isfinite(a) & (a > 0.0), a, np.nan)


def _rate_df(p: Mapping[str, float], w: np.ndarray, amplitude: Any) -> np.ndarray:
    with np.errstate(divide="ignore"):
        rho = p["rad_s"] / (_amplitude(amplitude) * np.abs(w))
    return np.where(np.isfinite(rho), rate_limit_df(np.where(np.isfinite(rho), rho, 1.0)), 1.0 + 0j)


def _backlash_df(p: Mapping[str, float], w: np.ndarray, amplitude: Any) -> np.ndarray:
    ratio = p["width_rad"] / _amplitude(amplitude)
    return np.where(np.isfinite(ratio), backlash_df(np.where(np.isfinite(ratio), ratio, 0.0)), 1.0 + 0j)


def rate_limited(t_s: Any, u: Any, rad_s: float) -> np.ndarray:
    """A signal through a rate limit: ``y_k = y_(k-1) + clip(u_k - y_(k-1), -R dt_k, R dt_k)``, ``y_0 = u_0``.

    Parameters
    ----------
    t_s : array_like
        Sample times [s], increasing.
    u : array_like
        Commanded signal [rad].
    rad_s : float
        Rate limit R [rad/s].
    """
    u = np.asarray(u, float).ravel()
    y = np.empty_like(u)
    if u.size == 0:
        return y
    steps = (rad_s * np.diff(np.asarray(t_s, float).ravel())).tolist()
    prev = float(u[0])
    y[0] = prev
    for k, (target, step) in enumerate(zip(u[1:].tolist(), steps), start=1):
        delta = target - prev
        prev = prev + (step if delta > step else -step if delta < -step else delta)
        y[k] = prev
    return y


def backlash_output(u: Any, width_rad: float) -> np.ndarray:
    """A signal through free play of total width b: the output moves only when the input pushes it,
    ``y_k = clip(y_(k-1), u_k - b/2, u_k + b/2)``, ``y_0 = u_0``.

    Parameters
    ----------
    u : array_like
        Input signal [rad].
    width_rad : float
        Total free play b [rad].
    """
    u = np.asarray(u, float).ravel()
    y = np.empty_like(u)
    if u.size == 0:
        return y
    h = 0.5 * width_rad
    prev = float(u[0])
    for k, x in enumerate(u.tolist()):
        prev = x - h if prev < x - h else x + h if prev > x + h else prev
        y[k] = prev
    return y


def is_nonlinear(spec: Mapping[str, Any]) -> bool:
    """True for an amplitude-dependent effect (no linear factor).

    Parameters
    ----------
    spec : mapping
        An effect mapping with a known ``type``.
    """
    return EFFECTS[spec["type"]].factor is None


def apply_nonlinear(effects: Sequence[Mapping[str, Any]], t_s: Any, u: Any) -> np.ndarray:
    """The surface command ``u`` through the amplitude-dependent effects of ``effects``, in their order (the
    linear ones are skipped: they act in the linear part).

    Parameters
    ----------
    effects : sequence of mapping
        Validated effects.
    t_s : array_like
        Sample times [s].
    u : array_like
        Samples of the command.
    """
    out = np.asarray(u, float).ravel()
    for e in effects:
        entry = EFFECTS[e["type"]]
        if entry.factor is None and entry.time_domain is not None:
            out = entry.time_domain(e, np.asarray(t_s, float).ravel(), out)
    return out


def _rate_words(p: Mapping[str, float]) -> str:
    return f"surface rate limit of {p['rad_s']:.3g} rad/s (nonlinear, amplitude-dependent)"


def _backlash_words(p: Mapping[str, float]) -> str:
    return f"backlash (free play) of {p['width_rad']:.3g} rad (nonlinear, amplitude-dependent)"


@dataclass(frozen=True)
class AmplitudeFitRange(FitRange):
    """A :class:`FitRange` with the smallest and largest amplitude flown at the usable frequencies."""

    a_lo: float = math.nan
    a_hi: float = math.nan


def _rate_bounds(x0: np.ndarray | None, ctx: AmplitudeFitRange) -> tuple[np.ndarray, np.ndarray]:
    # below 0.02 A w_lo the surface barely moves; above A w_hi the limit is never reached (no effect)
    return np.log([0.02 * ctx.a_lo * ctx.w_lo]), np.log([1.5 * ctx.a_hi * ctx.w_hi])


def _rate_grid(ctx: AmplitudeFitRange, coarse: bool) -> np.ndarray:
    lo, hi = _rate_bounds(None, ctx)
    return np.linspace(lo[0], hi[0], 12 if coarse else 48)[:, None]


def _rate_response(x: np.ndarray, w: np.ndarray, amplitude: np.ndarray) -> np.ndarray:
    rho = np.exp(x[:, :1]) / (np.asarray(amplitude, float)[None, :] * w[None, :])
    return rate_limit_df(rho)


def _rate_spec(x: np.ndarray) -> dict:
    return {"type": "rate_limit", "rad_s": significant(math.exp(x[0]))}


def _backlash_bounds(x0: np.ndarray | None, ctx: AmplitudeFitRange) -> tuple[np.ndarray, np.ndarray]:
    # free play as wide as the smallest amplitude's double swing stops the surface
    return np.log([1e-3 * ctx.a_lo]), np.log([1.9 * ctx.a_lo])


def _backlash_grid(ctx: AmplitudeFitRange, coarse: bool) -> np.ndarray:
    lo, hi = _backlash_bounds(None, ctx)
    return np.linspace(lo[0], hi[0], 12 if coarse else 48)[:, None]


def _backlash_response(x: np.ndarray, w: np.ndarray, amplitude: np.ndarray) -> np.ndarray:
    ratio = np.exp(x[:, :1]) / np.asarray(amplitude, float)[None, :]
    return np.broadcast_to(backlash_df(ratio), (x.shape[0], w.size))


def _backlash_spec(x: np.ndarray) -> dict:
    return {"type": "backlash", "width_rad": significant(math.exp(x[0]))}


# ------------------------------------------------------------------------------------------------ the
# registry
_FREQUENCY = dict(valid=POSITIVE, plausible=Interval(1e-4, 1e5))
_DAMPING = dict(valid=NON_NEGATIVE, plausible=Interval(0.0, 100.0))

#: Effect type -> its :class:`EffectType`, in the order of DESIGN.md's table.
EFFECTS: dict[str, EffectType] = {
    e.name: e
    for e in (
        EffectType(
            "time_delay",
            (Parameter("seconds", NON_NEGATIVE, Interval(0.0, 10.0)),),
            _delay_factor,
            _delay_words,
            EffectFit(_delay_grid, _delay_bounds, _delay_response, _delay_spec),
        ),
        EffectType(
            "first_order_lag",
            (Parameter("bandwidth_rad_s", **_FREQUENCY),),
            _lag1_factor,
            _lag1_words,
            EffectFit(_lag1_grid, _lag1_bounds, _lag1_response, _lag1_spec),
        ),
        EffectType(
            "second_order_lag",
            (Parameter("natural_frequency_rad_s", **_FREQUENCY), Parameter("damping", **_DAMPING)),
            _lag2_factor,
            _lag2_words,
            EffectFit(_lag2_grid, _lag2_bounds, _lag2_response, _lag2_spec),
        ),
        EffectType(
            "gain",
            (Parameter("factor", NONZERO, Interval(1e-6, 1e6), magnitude=True),),
            _gain_factor,
            _gain_words,
            EffectFit(_gain_grid, _gain_bounds, _gain_response, _gain_spec),
        ),
        EffectType(
            "structural_mode",
            (
                Parameter("frequency_rad_s", **_FREQUENCY),
                Parameter("damping", **_DAMPING),
                Parameter("zero_frequency_rad_s", **_FREQUENCY),
                Parameter("zero_damping", **_DAMPING),
            ),
            _mode_factor,
            _mode_words,
            EffectFit(_mode_grid, _mode_bounds, _mode_response, _mode_spec),
        ),
        EffectType(
            "rate_limit",
            (Parameter("rad_s", POSITIVE, Interval(1e-3, 1e3)),),
            None,
            _rate_words,
            describing_function=_rate_df,
            describing_fit=EffectFit(_rate_grid, _rate_bounds, _rate_response, _rate_spec),
            time_domain=lambda p, t, u: rate_limited(t, u, p["rad_s"]),
        ),
        EffectType(
            "backlash",
            (Parameter("width_rad", POSITIVE, Interval(1e-6, 1.0)),),
            None,
            _backlash_words,
            describing_function=_backlash_df,
            describing_fit=EffectFit(_backlash_grid, _backlash_bounds, _backlash_response, _backlash_spec),
            time_domain=lambda p, t, u: backlash_output(u, p["width_rad"]),
        ),
        EffectType(
            "zero_order_hold",
            (Parameter("rate_hz", POSITIVE, Interval(0.1, 1e5)),),
            _hold_factor,
            _hold_words,
            EffectFit(_hold_grid, _hold_bounds, _hold_response, _hold_spec),
            time_domain=lambda p, t, u: held(t, u, p["rate_hz"]),
            shape=_hold_shape,
        ),
    )
}

#: Effect type -> required parameter names, in the order of DESIGN.md's table (a view of :data:`EFFECTS`).
EFFECT_TYPES: dict[str, tuple[str, ...]] = {name: e.names for name, e in EFFECTS.items()}


# ------------------------------------------------------------------------------------------------ effect
# mappings
def validate_effect(spec: Any, where: str = "effects[0]") -> dict:
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
        raise ConfigError(f"{where}: missing key 'type' (one of {', '.join(EFFECTS)})")
    kind = spec["type"]
    if not isinstance(kind, str) or kind not in EFFECTS:
        raise ConfigError(
            f"{where}.type: unknown effect type {kind!r} (expected one of {', '.join(EFFECTS)})"
        )
    entry = EFFECTS[kind]
    names = entry.names
    unknown = [key for key in spec if key != "type" and key not in names]
    if unknown:
        raise ConfigError(
            f"{where}.{unknown[0]}: unknown parameter for {kind} (expected {', '.join(names)}), "
            f"got {unknown[0]!r}: {spec[unknown[0]]!r}"
        )
    missing = [name for name in names if name not in spec]
    if missing:
        raise ConfigError(f"{where}: missing parameter {missing[0]!r} for {kind} (needs {', '.join(names)})")
    result: dict = {"type": kind}
    for p in entry.parameters:
        result[p.name] = check_number(spec[p.name], f"{where}.{p.name}", p.valid, strings=True,
                                      expected=p.valid.text())
    return result


def check_plausible(spec: Mapping[str, Any], where: str) -> None:
    """ConfigError naming the key when a validated effect has an absurd parameter (a typo or wrong units).

    Parameters
    ----------
    spec : mapping
        An effect validated by :func:`validate_effect`.
    where : str
        Path of the effect in the config (``model.effects[1]``).
    """
    for p in EFFECTS[spec["type"]].parameters:
        p.check_plausible(spec[p.name], f"{where}.{p.name}")


def effect_factor(spec: Any) -> Factor:
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

    Raises
    ------
    ConfigError
        For an amplitude-dependent effect, which has no linear factor.
    """
    spec = validate_effect(spec, where="effect")
    entry = EFFECTS[spec["type"]]
    if entry.factor is None:
        raise ConfigError(f"effect {entry.name}: depends on the input amplitude and has no linear factor")
    return entry.factor(spec)


def effect_response(spec: Any, w_rad_s: Any, amplitude: Any = None) -> np.ndarray:
    """Complex factor of an effect at s = j w, delay included exactly (:meth:`EffectType.response`).

    Parameters
    ----------
    spec : mapping
        An effect.
    w_rad_s : array_like
        Frequencies [rad/s].
    amplitude : array_like, optional
        Flown input amplitude, for an amplitude-dependent effect.

    Returns
    -------
    ndarray of complex
        Same shape as ``w_rad_s``.
    """
    spec = validate_effect(spec, where="effect")
    return EFFECTS[spec["type"]].response(spec, w_rad_s, amplitude)


def describe_effect(spec: Any) -> str:
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
    return EFFECTS[spec["type"]].describe(spec)
