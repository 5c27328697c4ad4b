"""Which effect is missing: each effect of the vocabulary, and the model's own parameters, fitted to the
data.

Each effect of the vocabulary (:mod:`gap_validation.core.effects`) is fitted in series with the current model
to the averaged measured response with the CIFER cost (Tischler & Remple, *Aircraft and Rotorcraft System
Identification*, 2nd ed., ch. 11)::

    J = 20/n sum_w W_g [ (|T_m| - |T_c|)^2  +  0.01745 (angle T_m - angle T_c)^2 ],   W_g = [1.58 (1 -
    exp(-g^2))]^2

(magnitudes in dB, phases in deg, ``g^2`` the coherence) over the usable frequencies: a grid over physically
sensible parameter ranges, then a bounded local refinement (:func:`scipy.optimize.least_squares`) from the
best distinct grid points. Pairs of effects are fitted when no single effect explains the mismatch, and the
model's own coefficients are refitted as ``parameter_error``.

No fit at its bounds: a fit whose parameter sits on an edge of its search range (:data:`BOUND_TOLERANCE` of
the range; the ranges are the registry's, e.g. a structural mode inside the confident band with damping up to
1, a gain within +-20 dB of either sign) is *beyond the search range*: it is never offered as a fix, and said
so in the message when no offered candidate explains the mismatch. ``parameter_error`` searches each
coefficient within x10 of the model's and, when it lands on that bound, once more within x100
(:data:`COEFFICIENT_RANGES`). Each sentence says the epsilon the candidate leaves and whether it *explains*
the mismatch (the JSON's ``explains``: the data within their errors at every confident frequency), or how many
noise scales it leaves.

Each fit is scored on the data as an :class:`~gap_validation.core.evidence.Fit`; which fits are offered, and
in which order, is :mod:`gap_validation.core.ranking`'s. Part of the diagnosis
(:mod:`gap_validation.core.diagnosis`).
"""
from __future__ import annotations

import contextvars
import itertools
import math
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Callable, Iterator, Sequence

import numpy as np
from numpy.typing import ArrayLike

from gap_validation.core.effects import (
    EFFECTS,
    AmplitudeFitRange,
    EffectFit,
    EffectType,
    FitRange,
    validate_effect,
)
from gap_validation.core.evidence import BIAS_ERROR, SIGMA_FACTOR, Evidence, Fit, evidence_of, log_ratio
from gap_validation.core.models import LinearModel
from gap_validation.core.numbers import significant

if TYPE_CHECKING:  # pragma: no cover
    from gap_validation.core.estimator import SpectralEstimate

__all__ = [
    "cifer_weight",
    "cifer_cost",
    "FAMILIES",
    "PAIRS",
    "NONLINEAR_FAMILIES",
    "FittedCandidate",
    "fit_effects",
    "fit_candidates",
    "moves_own_mode",
    "paced",
    "pace",
    "MIN_POINTS",
    "BOUND_TOLERANCE",
    "COEFFICIENT_RANGES",
    "MODE_MATCH",
    "MODE_REACH",
    "MODE_RANGE",
    "MODE_DAMPING_RANGE",
    "CANCEL",
]

#: CIFER phase weight per deg^2 (1 dB ~ 7.6 deg).
_PHASE_WEIGHT = 0.01745
_DB_PER_NEPER = 20.0 / math.log(10.0)
_DEG_PER_RAD = 180.0 / math.pi
_N_STARTS = 3          # local refinements per candidate, from distinct grid points
#: A fitted parameter within this fraction of its search box (fit coordinates) from an edge sits on the bound.
BOUND_TOLERANCE = 1e-3
#: ``parameter_error`` searches each coefficient within x10 of the model's, then once within x100 (widened)
#: when the fit sits on a bound; still on it, the refit is beyond the search range.
COEFFICIENT_RANGES = (10.0, 100.0)
MIN_POINTS = 4        # fewer confident points: no fitting


def cifer_weight(coherence: ArrayLike) -> np.ndarray:
    """CIFER coherence weighting ``W_g = [1.58 (1 - exp(-g^2))]^2`` (Tischler & Remple, ch. 11).

    Parameters
    ----------
    coherence : array_like
        Squared coherence ``g^2`` in [0, 1].

    Returns
    -------
    ndarray
        Weights, 0 at zero coherence and 1.0 at ``g^2 = 1``.
    """
    g2 = np.clip(np.asarray(coherence, dtype=float), 0.0, 1.0)
    return (1.58 * (1.0 - np.exp(-g2))) ** 2


def cifer_cost(p_fit: ArrayLike, p_meas: ArrayLike, coherence: ArrayLike) -> float:
    """CIFER cost ``J = 20/n sum W_g [dB error^2 + 0.01745 deg error^2]`` (Tischler & Remple, ch. 11).

    Parameters
    ----------
    p_fit, p_meas : array_like of complex
        Model and measured responses at the same n frequencies.
    coherence : array_like
        Squared coherence at those frequencies.

    Returns
    -------
    float
        J (about 100 or less: acceptable fit; 50 or less: nearly indistinguishable).
    """
    log_q = log_ratio(np.asarray(p_fit, dtype=complex), np.asarray(p_meas, dtype=complex))
    w_g = cifer_weight(coherence)
    err = (_DB_PER_NEPER * log_q.real) ** 2 + _PHASE_WEIGHT * (_DEG_PER_RAD * log_q.imag) ** 2
    return float(20.0 / max(len(w_g), 1) * np.sum(w_g * err))


#: Effect type -> how it is fitted (:class:`~gap_validation.core.effects.EffectFit`), a view of the registry.
FAMILIES: dict[str, EffectFit] = {name: e.fit for name, e in EFFECTS.items() if e.fit is not None}
#: Pairs fitted when no single effect explains the mismatch, named by their sorted types joined with "+".
PAIRS: tuple[tuple[str, str], ...] = tuple(itertools.combinations(sorted(FAMILIES), 2))
#: Amplitude-dependent effects the diagnosis fits through their describing functions (a view of the registry).
NONLINEAR_FAMILIES: dict[str, EffectType] = {
    name: e for name, e in EFFECTS.items() if e.describing_fit is not None
}


@dataclass
class _FitData:
    """Usable points of the averaged estimate, ready for the CIFER residuals."""

    w: np.ndarray
    p_meas: np.ndarray
    p_model: np.ndarray
    sqrt_w: np.ndarray        # sqrt of the CIFER weight
    coherence: np.ndarray
    ctx: FitRange

    def residuals(self, factor: np.ndarray) -> np.ndarray:
        """CIFER residuals for factors (M, N) -> (M, 2N): sqrt(W) dB error and sqrt(W 0.01745) deg error."""
        log_q = log_ratio(self.p_model * factor, self.p_meas)
        mag = self.sqrt_w * _DB_PER_NEPER * log_q.real
        phase = self.sqrt_w * math.sqrt(_PHASE_WEIGHT) * _DEG_PER_RAD * log_q.imag
        out = np.concatenate([mag, phase], axis=-1)
        return np.where(np.isfinite(out), out, 1e6)

    def cost(self, factor: np.ndarray) -> np.ndarray:
        """CIFER J for factors (M, N) -> (M,)."""
        return 20.0 / self.w.size * np.sum(self.residuals(factor) ** 2, axis=-1)


@dataclass
class _Combo:
    """A set of effects fitted together (one effect, or a pair)."""

    families: tuple[EffectType, ...]

    @property
    def name(self) -> str:
        return "+".join(sorted(f.name for f in self.families))

    @property
    def complexity(self) -> int:
        return sum(f.complexity for f in self.families)

    def _split(self, x: np.ndarray) -> list[np.ndarray]:
        sizes = np.cumsum([f.complexity for f in self.families])[:-1]
        return np.split(x, sizes, axis=-1)

    def response(self, x: np.ndarray, w: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(x)
        out = np.ones((x.shape[0], w.size), dtype=complex)
        for fam, part in zip(self.families, self._split(x)):
            out = out * fam.fit.response(part, w)
        return out

    def grid(self, ctx: FitRange) -> np.ndarray:
        if len(self.families) == 1:
            return self.families[0].fit.grid(ctx, False)
        grids = [f.fit.grid(ctx, True) for f in self.families]
        rows = [np.concatenate(parts) for parts in itertools.product(*grids)]
        return np.array(rows)

    def bounds(self, x0: np.ndarray, ctx: FitRange) -> tuple[np.ndarray, np.ndarray]:
        parts = [f.fit.bounds(p, ctx) for f, p in zip(self.families, self._split(x0))]
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])

    def specs(self, x: np.ndarray) -> list[dict]:
        return [
            validate_effect(f.fit.spec(p)) for f, p in zip(self.families, self._split(np.asarray(x, float)))
        ]


@dataclass
class _DescribingCombo(_Combo):
    """One amplitude-dependent effect, fitted through its describing function at the flown amplitude."""

    amplitude: object = None          # amplitude(w) -> array

    def response(self, x: np.ndarray, w: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(x)
        out = np.ones((x.shape[0], w.size), dtype=complex)
        for fam, part in zip(self.families, self._split(x)):
            out = out * fam.describing_fit.response(part, w, self.amplitude(w))
        return out

    def grid(self, ctx: FitRange) -> np.ndarray:
        return self.families[0].describing_fit.grid(ctx, False)

    def bounds(self, x0: np.ndarray, ctx: FitRange) -> tuple[np.ndarray, np.ndarray]:
        return self.families[0].describing_fit.bounds(x0, ctx)

    def specs(self, x: np.ndarray) -> list[dict]:
        return [validate_effect(self.families[0].describing_fit.spec(np.asarray(x, float)))]


def _distinct_starts(grid: np.ndarray, costs: np.ndarray, span: np.ndarray, count: int) -> list[np.ndarray]:
    """The best ``count`` grid points that differ by more than 5 % of the parameter range from each other."""
    chosen: list[np.ndarray] = []
    for i in np.argsort(costs):
        if not np.isfinite(costs[i]):
            break
        x = grid[i]
        if all(np.max(np.abs(x - c) / span) > 0.05 for c in chosen):
            chosen.append(x)
        if len(chosen) == count:
            break
    return chosen


def _fit_combo(combo: _Combo, data: _FitData) -> np.ndarray:
    """Coarse grid, then bounded least squares from distinct grid points; returns the best parameters."""
    grid = combo.grid(data.ctx)
    costs = np.concatenate([data.cost(combo.response(chunk, data.w))
                            for chunk in np.array_split(grid, max(1, grid.shape[0] // 2000))])
    lo_all, hi_all = combo.bounds(grid[int(np.argmin(costs))], data.ctx)
    span = np.where(np.isfinite(hi_all - lo_all), hi_all - lo_all, 1.0)
    best_x, best_cost = None, np.inf
    for x0 in _distinct_starts(grid, costs, span, _N_STARTS):
        lo, hi = combo.bounds(x0, data.ctx)
        x0 = np.clip(x0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        from scipy.optimize import least_squares  # scipy.optimize costs 0.6 s at import: only when used
        sol = least_squares(lambda x: data.residuals(combo.response(x, data.w))[0], x0, bounds=(lo, hi),
                            x_scale=(hi - lo) / 10.0, method="trf", max_nfev=200)
        cost = data.cost(combo.response(sol.x, data.w))[0]
        if cost < best_cost:
            best_x, best_cost = sol.x, cost
    return best_x


def _coefficient_fit(model: LinearModel, data: _FitData, factor: float = COEFFICIENT_RANGES[0],
                     start: LinearModel | None = None) -> tuple[LinearModel, str] | None:
    """Refit the airframe's numerator/denominator coefficients (same structure, monic denominator), each as
    ``c = c0 exp(x)`` within ``|x| <= ln(factor)``, started at the current values (x = 0) or at ``start``,
    effects kept: the ``parameter_error`` candidate, and which coefficients sit on the bound (empty: none)."""
    air = model.airframe
    num0, den0 = np.array(air.num, float), np.array(air.den, float)
    free_num = np.flatnonzero(num0 != 0.0)
    free_den = np.flatnonzero(den0[1:] != 0.0) + 1
    n_free = free_num.size + free_den.size
    if n_free == 0:
        return None
    s = 1j * data.w
    others = LinearModel([1.0], [1.0], air.delay_s, model.effects).freqresp(data.w)

    def build(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        num, den = num0.copy(), den0.copy()
        num[free_num] *= np.exp(x[:free_num.size])
        den[free_den] *= np.exp(x[free_num.size:])
        return num, den

    def residuals(x: np.ndarray) -> np.ndarray:
        num, den = build(x)
        p = np.polyval(num, s) / np.polyval(den, s) * others
        return data.residuals((p / data.p_model)[None, :])[0]

    bound = np.full(n_free, math.log(factor))
    x0 = np.zeros(n_free)
    if start is not None and len(start.airframe.num) == len(num0) and len(start.airframe.den) == len(den0):
        with np.errstate(divide="ignore", invalid="ignore"):
            x0 = np.log(np.concatenate([np.asarray(start.airframe.num, float)[free_num] / num0[free_num],
                                        np.asarray(start.airframe.den, float)[free_den] / den0[free_den]]))
        x0 = np.clip(np.where(np.isfinite(x0), x0, 0.0), -0.999 * bound, 0.999 * bound)
    from scipy.optimize import least_squares  # scipy.optimize costs 0.6 s at import: only when used
    sol = least_squares(residuals, x0, bounds=(-bound, bound), method="trf", max_nfev=100 * n_free)
    num, den = build(sol.x)
    num = np.array([significant(v, 6) for v in num])
    den = np.array([significant(v, 6) for v in den])
    names = [f"numerator[{i}]" for i in free_num] + [f"denominator[{i}]" for i in free_den]
    ratios = [f"x{math.exp(v):.3g}" for v in sol.x]
    edge = [f"{n} {r}" for n, r, v in zip(names, ratios, sol.x)
            if abs(abs(v) - bound[0]) <= BOUND_TOLERANCE * 2.0 * bound[0]]
    return LinearModel(num, den, air.delay_s, model.effects), ", ".join(edge)


@dataclass
class FittedCandidate:
    """A fitted explanation: effects in series with the model (or a refitted model), scored on the data.

    Attributes
    ----------
    name : str
        Effect type, ``"a+b"`` for a pair (sorted names) or ``"parameter_error"``.
    complexity : int
        Number of fitted parameters.
    effects : list of dict
        Effects to append to the model (empty for ``parameter_error``).
    model : LinearModel
        The model with the candidate applied.
    members : tuple of str
        The two effect types of a pair (empty otherwise).
    replacement : bool
        True for ``parameter_error`` (the model's coefficients changed; nothing to append).
    at_bound : str
        Which parameter sits on which edge of its search range (``"damping at 1 (upper bound)"``), empty when
        none does: such a fit is beyond the search range and never offered as a fix.
    criterion : float or None
        Its information criterion among the candidates ranked with it (:func:`information_criteria`).
    indistinguishable : list of str
        For the top-ranked candidate: the others the data cannot tell from it (:data:`INDISTINGUISHABLE`).
    detail : str
        ``parameter_error`` refitted by its modes: the moves in words (``gain x1.3, mode 4.24 -> 5.1 rad/s
        ...``).
    """

    name: str
    complexity: int
    effects: list[dict]
    model: LinearModel
    members: tuple[str, ...] = ()
    replacement: bool = False
    score: Fit | None = None
    at_bound: str = ""
    # information criterion (:func:`information_criteria`), when ranked
    criterion: float | None = None
    indistinguishable: list[str] = field(default_factory=list)   # the ranked top's equals
    detail: str = ""                        # a refit's changes in words


def _fit_data(model: LinearModel, ev: Evidence) -> _FitData | None:
    if np.count_nonzero(ev.confident) < MIN_POINTS:
        return None
    u = ev.confident
    wc = ev.w[u]
    return _FitData(w=wc, p_meas=ev.p_meas[u], p_model=model.freqresp(wc),
                    sqrt_w=np.sqrt(cifer_weight(ev.coherence[u])), coherence=ev.coherence[u],
                    ctx=FitRange(float(wc.min()), float(wc.max())))


def _fit_combo_candidate(combo: _Combo, model: LinearModel, data: _FitData) -> FittedCandidate:
    x = _fit_combo(combo, data)
    effects = combo.specs(x)
    members = tuple(f.name for f in combo.families)
    lo, hi = combo.bounds(x, data.ctx)
    names = [
        f"{f.name}.{p.name}" if len(members) > 1 else p.name for f in combo.families for p in f.parameters
    ]
    values = [v for e in effects for k, v in e.items() if k != "type"]
    return FittedCandidate(combo.name, combo.complexity, effects, model.with_effects(effects),
                           members if len(members) > 1 else (),
                           at_bound=_on_bound(x, lo, hi, names, values))


def _on_bound(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, names: Sequence[str], values: Sequence) -> str:
    """Words for the parameters of ``x`` that sit on an edge of the box ``[lo, hi]`` (empty when none
    does)."""
    x, lo, hi = (np.asarray(v, float) for v in (x, lo, hi))
    tol = BOUND_TOLERANCE * np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    words = []
    for i in range(x.size):
        edge = "lower" if x[i] <= lo[i] + tol[i] else "upper" if x[i] >= hi[i] - tol[i] else None
        if edge is not None:
            name = names[i] if i < len(names) else f"parameter {i}"
            value = f" {values[i]:.3g}" if i < len(values) else ""
            words.append(f"{name} at{value} ({edge} bound)")
    return ", ".join(words)


def _fit_parameter_error(model: LinearModel, data: _FitData) -> FittedCandidate | None:
    """The model's own parameters refitted as a flight condition or a mis-estimated derivative moves them: its
    modes near the band moved and its gain scaled (:func:`_mode_fit`, each within :data:`MODE_RANGE` and
    :data:`MODE_DAMPING_RANGE`). A free refit of every coefficient (:func:`_coefficient_fit`) can reshape the
    response as it likes (on a rate-limited elevator it dropped the high-frequency gain by 63 % while moving
    the short period up 29 %, which no condition change does) and so soaks up dynamics the model lacks: it is
    the candidate only where the mode fit cannot reach (the model has no mode near the band, or a mode or the
    gain sits on its range's bound; the coefficients are searched within x10, then x100)."""
    modes = _mode_fit(model, data)
    candidate = None
    if modes is not None:
        moved, words, free, bound = modes
        candidate = FittedCandidate("parameter_error", free, [], moved, replacement=True, at_bound=bound,
                                    detail=words)
        if not bound:
            return candidate
    refit, at_bound = None, ""
    for factor in COEFFICIENT_RANGES:       # widened once when the fit sits on the bound
        fitted = _coefficient_fit(model, data, factor, start=refit)
        if fitted is None:
            break
        refit, at_bound = fitted
        if not at_bound:
            break
    air = model.airframe
    n_free = int(np.count_nonzero(air.num) + np.count_nonzero(air.den[1:]))
    if refit is not None and not at_bound:
        beyond = _modes_beyond_range(model, refit, data)
        at_bound = f"{beyond}: beyond what a parameter error moves" if beyond else ""
    elif at_bound:
        at_bound = f"{at_bound} of the model's, after widening the search to x{COEFFICIENT_RANGES[-1]:g}"
    coefficients = None if refit is None else FittedCandidate("parameter_error", n_free, [], refit,
                                                              replacement=True, at_bound=at_bound)
    return coefficients if coefficients is not None else candidate


def _modes_beyond_range(model: LinearModel, refit: LinearModel, data: _FitData) -> str:
    """Which of the model's modes near the band (poles and zeros within :data:`MODE_REACH` of it) a
    coefficient refit moved beyond the ranges of :func:`_mode_fit` (frequency x :data:`MODE_RANGE`, damping
    :data:`MODE_DAMPING_RANGE`), or turned from a pair into real roots or back: in words, empty when none."""
    lo, hi = data.ctx.w_lo / MODE_REACH, data.ctx.w_hi * MODE_REACH
    words = []
    for kind, before, after in (("zero", model.airframe.num, refit.airframe.num),
                                ("mode", model.airframe.den, refit.airframe.den)):
        old = _roots_as_modes(np.roots(np.trim_zeros(np.asarray(before, float), "f")))
        new = _roots_as_modes(np.roots(np.trim_zeros(np.asarray(after, float), "f")))
        for w, zeta in old:
            if not lo <= abs(w) <= hi:
                continue
            same = [(w1, z1) for w1, z1 in new if (z1 is None) == (zeta is None) and w1 > 0]
            if not same:
                words.append(f"{kind} {abs(w):.3g} rad/s changed its kind")
                continue
            w1, z1 = min(same, key=lambda m: abs(math.log(m[0] / abs(w))))
            if max(w1 / abs(w), abs(w) / w1) > MODE_RANGE or (
                zeta is not None and abs(z1 - zeta) > MODE_DAMPING_RANGE
            ):
                words.append(f"{kind} {abs(w):.3g} -> {w1:.3g} rad/s" + (
                    "" if zeta is None else f" (damping {zeta:.2g} -> {z1:.2g})"))
    return ", ".join(words)


#: A structural mode whose zeros lie this close to one of the model's own pole pairs (relative frequency, and
#: damping) cancels that pole and puts it where its own poles are: the model's mode moved, not a new mode
#: (:func:`moves_own_mode`).
MODE_MATCH = 0.25


def moves_own_mode(candidate: FittedCandidate, model: LinearModel) -> bool:
    """Whether a candidate's structural mode only moves one of the model's own modes.

    Its zeros sit on a pole pair of the model (within :data:`MODE_MATCH`). A linearisation at another speed
    has the same modes, moved; a structural mode fitted there is that move, and ``parameter_error`` (a refit
    of the model's modes) says it as such.

    Parameters
    ----------
    candidate : FittedCandidate
        A fitted candidate.
    model : LinearModel
        The channel's model.

    Returns
    -------
    bool
    """
    poles = [
        (w, z) for w, z in _roots_as_modes(np.roots(np.asarray(model.airframe.den, float))) if z is not None
    ]
    for effect in candidate.effects:
        if effect.get("type") != "structural_mode":
            continue
        wz, zz = float(effect["zero_frequency_rad_s"]), float(effect["zero_damping"])
        if any(abs(wz / w - 1.0) <= MODE_MATCH and abs(zz - z) <= MODE_MATCH for w, z in poles if w > 0):
            return True
    return False


#: A mode of the model (a pole or zero, a complex pair or a real root) is refitted by :func:`_mode_fit` when
#: its natural frequency lies within this factor of the confident band ...
MODE_REACH = 3.0
#: ... each frequency and the gain within this factor of the model's, each damping within this of the model's.
MODE_RANGE = 3.0
MODE_DAMPING_RANGE = 0.5
#: A pole and a zero closer than this (relative frequency, and damping) cancel: they are left as they are.
CANCEL = 0.02


def _roots_as_modes(roots: np.ndarray) -> list[tuple[float, float | None]]:
    """Roots as modes: ``(w, zeta)`` per complex pair (upper half-plane root), ``(a, None)`` per real root
    -a."""
    out = []
    for r in roots:
        if abs(r.imag) > 1e-9 * max(abs(r), 1e-300):
            if r.imag > 0:
                w = abs(r)
                out.append((w, -r.real / w))
        else:
            out.append((-r.real, None))
    return out


def _modes_poly(modes: list[tuple[float, float | None]]) -> np.ndarray:
    poly = np.array([1.0])
    for w, zeta in modes:
        factor = [1.0, w] if zeta is None else [1.0, 2.0 * zeta * w, w * w]
        poly = np.polymul(poly, factor)
    return poly


def _mode_fit(model: LinearModel, data: _FitData) -> tuple[LinearModel, str, int, str] | None:
    """Refit the model's gain and the modes near the confident band: each pole and zero whose natural
    frequency lies within :data:`MODE_REACH` of the band, a complex pair by its frequency and damping, a real
    root by its corner (within :data:`MODE_RANGE` and :data:`MODE_DAMPING_RANGE`); the effects kept. What a
    linearisation at another speed or weight gives: the same modes, moved, and the gains scaled -- not new
    modes. Returns the refitted model, the moves in words, the parameters fitted, and which sit on their bound
    (empty: none); None when no mode is near the band."""
    air = model.airframe
    num, den = np.asarray(air.num, float), np.asarray(air.den, float)
    if not np.any(num):
        return None
    lead = num[np.flatnonzero(num)[0]]
    zeros, poles = _roots_as_modes(np.roots(num)), _roots_as_modes(np.roots(den))
    lo, hi = data.ctx.w_lo / MODE_REACH, data.ctx.w_hi * MODE_REACH

    def near(w: float) -> bool:
        return lo <= abs(w) <= hi

    # a pole and a zero that (nearly) cancel carry no response (a mode of another axis, barely coupled): they
    # stay
    def cancels(a: tuple, b: tuple) -> bool:
        (wa, za), (wb, zb) = a, b
        return (za is None) == (zb is None) and abs(wa - wb) <= CANCEL * max(abs(wb), 1e-12) and \
            (za is None or abs(za - zb) <= CANCEL)

    cancelled = {("z", i) for i, z in enumerate(zeros) if any(cancels(z, p) for p in poles)}
    cancelled |= {("p", i) for i, p in enumerate(poles) if any(cancels(z, p) for z in zeros)}
    free = [(kind, i) for kind, modes in (("z", zeros), ("p", poles)) for i, (w, _) in enumerate(modes)
            if near(w) and (kind, i) not in cancelled]
    if not free:
        return None
    x0, lo_b, hi_b, names = [0.0], [-math.log(MODE_RANGE)], [math.log(MODE_RANGE)], ["gain"]
    for kind, i in free:
        w, zeta = (zeros if kind == "z" else poles)[i]
        x0.append(0.0)
        lo_b.append(-math.log(MODE_RANGE))
        hi_b.append(math.log(MODE_RANGE))
        names.append(f"{'zero' if kind == 'z' else 'pole'} at {abs(w):.3g} rad/s")
        if zeta is not None:
            x0.append(zeta)
            lo_b.append(max(-1.0, zeta - MODE_DAMPING_RANGE))
            hi_b.append(min(2.0, zeta + MODE_DAMPING_RANGE))
            names.append(f"damping of the {'zero' if kind == 'z' else 'pole'} at {abs(w):.3g} rad/s")
    x0, lo_b, hi_b = np.array(x0), np.array(lo_b), np.array(hi_b)
    x0 = np.clip(x0, lo_b + 1e-9 * (hi_b - lo_b), hi_b - 1e-9 * (hi_b - lo_b))
    s = 1j * data.w
    others = LinearModel([1.0], [1.0], air.delay_s, model.effects).freqresp(data.w)

    def build(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        z, p = list(zeros), list(poles)
        pos = 1
        for kind, i in free:
            target = z if kind == "z" else p
            w, zeta = target[i]
            w = w * math.exp(x[pos])
            pos += 1
            if zeta is not None:
                zeta = x[pos]
                pos += 1
            target[i] = (w, zeta)
        num_new = _modes_poly(z)
        gain = (
            lead
            * math.exp(x[0])
            * np.prod([w * w if zt is not None else w for w, zt in zeros] or [1.0])
            / np.prod([w * w if zt is not None else w for w, zt in z] or [1.0])
        )
        return gain * num_new, _modes_poly(p)

    def residuals(x: np.ndarray) -> np.ndarray:
        n_new, d_new = build(x)
        p = np.polyval(n_new, s) / np.polyval(d_new, s) * others
        return data.residuals((p / data.p_model)[None, :])[0]

    from scipy.optimize import least_squares  # scipy.optimize costs 0.6 s at import: only when used
    sol = least_squares(residuals, x0, bounds=(lo_b, hi_b), method="trf", max_nfev=100 * x0.size)
    n_new, d_new = build(sol.x)
    refit = LinearModel(
        np.array([significant(v, 6) for v in n_new]),
        np.array([significant(v, 6) for v in d_new]),
        air.delay_s,
        model.effects,
    )
    tol = BOUND_TOLERANCE * (hi_b - lo_b)
    edge = [
        f"{n} ({'lower' if v <= a + t else 'upper'} bound)"
        for n, v, a, b_, t in zip(names, sol.x, lo_b, hi_b, tol)
        if v <= a + t or v >= b_ - t
    ]
    words = [f"gain x{math.exp(sol.x[0]):.3g}"]
    pos = 1
    for kind, i in free:
        w, zeta = (zeros if kind == "z" else poles)[i]
        w_new = w * math.exp(sol.x[pos])
        pos += 1
        what = f"{'zero' if kind == 'z' else 'mode'} {abs(w):.3g} -> {abs(w_new):.3g} rad/s"
        if zeta is not None:
            what += f" (damping {zeta:.2f} -> {sol.x[pos]:.2f})"
            pos += 1
        words.append(what)
    return refit, ", ".join(words), int(x0.size), ", ".join(edge)


def fit_effects(model: LinearModel, estimate: SpectralEstimate, coherence_threshold: float = 0.6, *,
                sweeps: Sequence[SpectralEstimate] = (),
                pairs: bool = False, parameter_error: bool = True,
                bias_error: float = BIAS_ERROR) -> list[FittedCandidate]:
    """Fit every effect of the vocabulary (optionally all pairs, and the coefficient refit) to the data.

    Parameters
    ----------
    model : LinearModel
        Current model; effects are fitted in series with it.
    estimate : SpectralEstimate
        Averaged measured response (``w_rad_s``, ``response``, ``coherence``, ``n_averages``).
    coherence_threshold : float
        Only usable frequencies (coherence and averages, :func:`minimum_averages`) enter the fit.
    sweeps : sequence of SpectralEstimate
        Per-sweep estimates (random error from their scatter).
    pairs : bool
        Fit every pair of effects too.
    parameter_error : bool
        Refit the model's own coefficients as well.
    bias_error : float
        Systematic error floor (scores only).

    Returns
    -------
    list of FittedCandidate
        Unranked and unfiltered, each with its ``score`` on the data (empty with fewer than 4 usable points).
    """
    ev = evidence_of(estimate, sweeps, coherence_threshold, bias_error, SIGMA_FACTOR)
    return _fit_all(model, ev, pairs=pairs, parameter_error=parameter_error)


#: Called between two candidate fits, when set (:func:`paced`; per thread: a context variable).
_PACE: contextvars.ContextVar[Callable[[], None] | None] = contextvars.ContextVar("gap_validation_pace",
                                                                                  default=None)


@contextmanager
def paced(callback: Callable[[], None]) -> Iterator[None]:
    """Within this block (in this thread), the diagnosis calls ``callback`` between two candidate fits: the
    node's diagnosis worker sleeps there to hold the fitting to a share of a core. The results are the same.

    Parameters
    ----------
    callback : callable
        Called with no argument; may sleep, or raise to abandon the diagnosis.
    """
    token = _PACE.set(callback)
    try:
        yield
    finally:
        _PACE.reset(token)


def pace() -> None:
    """Call the callback set by :func:`paced`, if any (between two candidate fits)."""
    callback = _PACE.get()
    if callback is not None:
        callback()


def _fit_all(model, ev: Evidence, *, pairs: bool, parameter_error: bool, singles: bool = True):
    data = _fit_data(model, ev)
    if data is None:
        return []
    combos = [(EFFECTS[name],) for name in FAMILIES] if singles else []
    if pairs:
        combos += [(EFFECTS[a], EFFECTS[b]) for a, b in PAIRS]
    out = []
    for combo in combos:
        pace()
        out.append(_fit_combo_candidate(_Combo(combo), model, data))
    if parameter_error:
        pace()
        refit = _fit_parameter_error(model, data)
        if refit is not None:
            out.append(refit)
    for cand in out:
        cand.score = ev.fit(cand.model.freqresp)
    return out


def _fit_nonlinear(model: LinearModel, ev: Evidence, amplitude) -> list[FittedCandidate]:
    """``rate_limit`` and ``backlash`` fitted in series with the model (describing functions at the flown
    amplitude), scored like the others."""
    data = _fit_data(model, ev)
    if data is None:
        return []
    a = np.asarray(amplitude(data.w), float)
    if not np.all(np.isfinite(a) & (a > 0)):
        return []
    data = replace(data, ctx=AmplitudeFitRange(data.ctx.w_lo, data.ctx.w_hi, float(a.min()), float(a.max())))
    out = []
    for family in NONLINEAR_FAMILIES.values():
        combo = _DescribingCombo((family,), amplitude)
        x = _fit_combo(combo, data)
        effects = combo.specs(x)
        lo, hi = combo.bounds(x, data.ctx)
        values = [v for e in effects for k, v in e.items() if k != "type"]
        cand = FittedCandidate(
            combo.name,
            combo.complexity,
            effects,
            model.with_effects(effects).at_amplitude(amplitude),
            at_bound=_on_bound(x, lo, hi, [k for e in effects for k in e if k != "type"], values),
        )
        cand.score = ev.fit(cand.model.freqresp)
        out.append(cand)
    return out


def fit_candidates(model: LinearModel, ev: Evidence,
                   amplitude: Callable[[np.ndarray], np.ndarray] | None = None) -> list[FittedCandidate]:
    """Every fit the diagnosis ranks: the single effects and the refit of the model, then the pairs.

    The amplitude-dependent effects are fitted too when ``amplitude`` is given (only where amplitude
    dependence was seen); the pairs only when no single effect leaves a mismatch within the errors.

    Parameters
    ----------
    model : LinearModel
        The channel's model.
    ev : Evidence
        The averaged estimate and its statistics.
    amplitude : callable or None
        Input amplitude flown per frequency, ``amplitude(w)``.

    Returns
    -------
    list of FittedCandidate
        Unranked, each with its ``score``.
    """
    fitted = _fit_all(model, ev, pairs=False, parameter_error=True)
    if amplitude is not None:
        fitted += _fit_nonlinear(model, ev, amplitude)
    explained = any(c.score.k_max <= ev.sigma_factor for c in fitted if not c.replacement and not c.at_bound)
    if fitted and not explained:
        fitted += _fit_all(model, ev, pairs=True, parameter_error=False, singles=False)
    return fitted
