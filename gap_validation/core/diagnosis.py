"""Where the model fails and which physical effect is missing (DESIGN.md, steps 2 and 3).

Where it fails
--------------
Per frequency the overbounding-disk distance ``epsilon(w) = |P2-P1|/|P2+P1|`` (paper eq. 14) between the model
P1 and the measured response P2 is compared with what the estimate's random error can explain. If the averaged
estimate is ``P2 = P0 (1 + d)`` with ``d`` complex, each component of standard deviation ``e_r`` (the normalised
random error of |H|, Bendat & Piersol; the phase error is about ``e_r`` rad), then for data that equal the model
``epsilon ~ |d| / |2 + d| ~ |d| / 2``: the noise-only epsilon has scale ``sigma = e_r / 2`` and ``epsilon / sigma``
is Rayleigh distributed (probability ``exp(-k^2/2)`` of exceeding ``k``). Bands where ``epsilon(w)`` passes the
threshold are **model-limited** when, with coherence above its threshold, epsilon exceeds ``k sigma`` there
(default ``k = 4``: about 1 % false alarms over 40 frequencies), and **data-limited** otherwise (fly better
sweeps there rather than change the model). ``e_r`` is the larger of the estimate's Bendat & Piersol error and
the scatter between sweeps (when three or more sweeps are confident at a frequency).

Which effect is missing
-----------------------
Each effect of the vocabulary (:mod:`gap_validation.core.effects`) is fitted in series with the current model to
the averaged measured response with the CIFER cost (Tischler & Remple, *Aircraft and Rotorcraft System
Identification*, 2nd ed., eq. 11.2)::

    J = 20/n sum_w W_g [ (|T_m| - |T_c|)^2  +  0.01745 (angle T_m - angle T_c)^2 ],   W_g = [1.58 (1 - exp(-g^2))]^2

(magnitudes in dB, phases in deg, ``g^2`` the coherence) over the confident frequencies: a coarse grid over
physically sensible parameter ranges, then a bounded local refinement (:func:`scipy.optimize.least_squares`)
from the best distinct grid points. Pairs of effects are fitted when no single effect explains the mismatch,
and the model's own coefficients are refitted as ``parameter_error``. Candidates are ranked by the epsilon they
would leave (averaged data, confident frequencies). Only candidates that bring epsilon down by clearly more than
the random error explains are reported; if the current epsilon is already within the random error the diagnosis
is empty. Among adequate explanations the simplest (fewest parameters) comes first.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import least_squares

from gap_validation.core import metrics
from gap_validation.core.effects import EFFECT_TYPES, describe_effect, effect_response, validate_effect
from gap_validation.core.models import LinearModel

__all__ = [
    "ChannelDiagnosis", "analyse_channel", "cifer_weight", "cifer_cost", "bendat_piersol_random_error",
    "effective_random_error", "epsilon_noise_scale", "frequency_flags", "find_bands", "fit_effects",
    "SIGMA_FACTOR", "MAX_DELAY_S",
]

#: Noise-only epsilon is Rayleigh with scale ``sigma = e_r/2``; ``P(eps > k sigma) = exp(-k^2/2)``: k = 4 gives
#: 3.4e-4 per frequency, about 1 % over 40 frequencies.
SIGMA_FACTOR = 4.0
#: An improvement must exceed this many ``sigma`` (random-error scale of epsilon) at the frequencies involved.
IMPROVEMENT_SIGMA_FACTOR = 3.0
#: ... and remove at least this fraction of epsilon (a 10 % improvement is no explanation).
MIN_RELATIVE_IMPROVEMENT = 0.25
#: A pair must leave at most this fraction of its best single member's epsilon.
PAIR_RELATIVE_IMPROVEMENT = 0.25
#: Largest delay the fit considers [s].
MAX_DELAY_S = 0.5
#: CIFER phase weight per deg^2 (1 dB ~ 7.6 deg).
_PHASE_WEIGHT = 0.01745
_DB_PER_NEPER = 20.0 / math.log(10.0)
_DEG_PER_RAD = 180.0 / math.pi
_N_STARTS = 3          # local refinements per candidate, from distinct grid points
_MIN_POINTS = 4        # fewer confident points: no fitting


@dataclass
class ChannelDiagnosis:
    """Where one channel's model fails and which effects would explain it.

    Attributes
    ----------
    limited_by : str
        ``"model"``, ``"data"`` or ``"none"`` (JSON ``limited_by``): the verdict of the band holding the worst
        frequency (the one that sets epsilon); ``"none"`` when epsilon passes the threshold nowhere;
        ``"data"`` as well when no frequency has enough coherence.
    frequency_flags : list of str
        Per frequency: ``"ok"``, ``"model"``, ``"data"`` or ``"excluded"`` (coherence below its threshold).
    bands : list of dict
        Contiguous confident frequencies where epsilon passes the threshold: ``min_rad_s``, ``max_rad_s``,
        ``peak_rad_s``, ``epsilon``, ``limited_by``, ``reason`` (plus ``coherence_min``, ``sigma_ratio``).
    candidates : list of dict
        JSON ``diagnosis``, best first: ``effect``, ``parameters``, ``effects``, ``epsilon``, ``nu_gap`` plus
        ``sentence``, ``improvement``, ``epsilon_before``, ``epsilon_raw``, ``worst_frequency_rad_s``,
        ``complexity``, ``cost`` (CIFER J after) and ``cost_before``.
    message : str
        One plain sentence for the terminal.
    """

    limited_by: str = "none"
    frequency_flags: list[str] = field(default_factory=list)
    bands: list[dict] = field(default_factory=list)
    candidates: list[dict] = field(default_factory=list)
    message: str = ""


# ------------------------------------------------------------------------------------------------ statistics


def cifer_weight(coherence) -> np.ndarray:
    """CIFER coherence weighting ``W_g = [1.58 (1 - exp(-g^2))]^2`` (Tischler & Remple, eq. 11.3).

    Parameters
    ----------
    coherence : array_like
        Squared coherence ``g^2`` in [0, 1].
    """
    g2 = np.clip(np.asarray(coherence, dtype=float), 0.0, 1.0)
    return (1.58 * (1.0 - np.exp(-g2))) ** 2


def _log_ratio(p_fit, p_meas) -> np.ndarray:
    """Complex log of ``p_fit / p_meas``: real part in nepers, imaginary part the wrapped phase [rad]."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log(p_fit / p_meas)


def cifer_cost(p_fit, p_meas, coherence) -> float:
    """CIFER cost ``J = 20/n sum W_g [dB error^2 + 0.01745 deg error^2]`` (Tischler & Remple, eq. 11.2).

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
    log_q = _log_ratio(np.asarray(p_fit, dtype=complex), np.asarray(p_meas, dtype=complex))
    w_g = cifer_weight(coherence)
    err = (_DB_PER_NEPER * log_q.real) ** 2 + _PHASE_WEIGHT * (_DEG_PER_RAD * log_q.imag) ** 2
    return float(20.0 / max(len(w_g), 1) * np.sum(w_g * err))


def bendat_piersol_random_error(coherence, n_averages) -> np.ndarray:
    """Normalised random error of |H|: ``e_r = sqrt(1 - g^2) / (|g| sqrt(2 n_d))`` (Bendat & Piersol, 9.90).

    The phase error is about ``e_r`` rad. Infinite where the coherence is zero.
    """
    g2 = np.clip(np.asarray(coherence, dtype=float), 0.0, 1.0)
    n = np.maximum(np.asarray(n_averages, dtype=float), 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        e_r = np.sqrt(1.0 - g2) / (np.sqrt(g2) * np.sqrt(2.0 * n))
    return np.where(g2 > 0.0, e_r, np.inf)


def _random_error_of(estimate) -> np.ndarray:
    """The estimate's random error, from Bendat & Piersol where it does not carry one (or it is not finite)."""
    coherence = np.asarray(estimate.coherence, dtype=float)
    n_avg = np.broadcast_to(np.asarray(getattr(estimate, "n_averages", 1.0), dtype=float), coherence.shape)
    computed = bendat_piersol_random_error(coherence, n_avg)
    given = getattr(estimate, "random_error", None)
    if given is None:
        return computed
    given = np.asarray(given, dtype=float)
    return np.where(np.isfinite(given), given, computed)


def _sweep_scatter_error(estimate, sweeps: Sequence, coherence_threshold: float) -> np.ndarray:
    """Relative random error of the average from the scatter between sweeps (NaN with fewer than 3 sweeps).

    ``e = sqrt(sum |H_i - mean H|^2 / (m - 1) / 2) / sqrt(m) / |H|`` per frequency, over the m sweeps whose
    coherence passes the threshold there: the per-component standard deviation of the mean, relative.
    """
    w = np.asarray(estimate.w_rad_s, dtype=float)
    out = np.full(w.shape, np.nan)
    usable = [s for s in sweeps if np.shape(s.response) == w.shape]
    if len(usable) < 3:
        return out
    h = np.array([np.asarray(s.response, dtype=complex) for s in usable])
    ok = np.array([np.asarray(s.coherence, dtype=float) >= coherence_threshold for s in usable]) & np.isfinite(h)
    m = ok.sum(axis=0)
    h0 = np.where(ok, h, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = h0.sum(axis=0) / m
        var = (np.abs(np.where(ok, h - mean, 0.0)) ** 2).sum(axis=0) / (m - 1)
        e = np.sqrt(var / 2.0) / np.sqrt(m) / np.abs(np.asarray(estimate.response, dtype=complex))
    return np.where(m >= 3, e, np.nan)


def effective_random_error(estimate, sweeps: Sequence = (), coherence_threshold: float = 0.0) -> np.ndarray:
    """Relative random error of the averaged response: the larger of the estimate's (Bendat & Piersol) error
    and the scatter between sweeps (used where at least three sweeps are confident).

    Parameters
    ----------
    estimate : SpectralEstimate
        Averaged estimate (``w_rad_s``, ``response``, ``coherence``, ``random_error``, ``n_averages``).
    sweeps : sequence of SpectralEstimate
        Per-sweep estimates on the same frequencies.
    coherence_threshold : float
        Sweeps count at a frequency only where their coherence passes it.
    """
    e_bp = _random_error_of(estimate)
    e_sc = _sweep_scatter_error(estimate, sweeps, coherence_threshold)
    return np.where(np.isfinite(e_sc), np.maximum(e_bp, e_sc), e_bp)


def epsilon_noise_scale(random_error) -> np.ndarray:
    """Scale ``sigma = e_r / 2`` of epsilon(w) between a model and noisy data that equal it.

    With ``P2 = P1 (1 + d)``, ``d`` complex with components of standard deviation ``e_r``,
    ``epsilon = |d| / |2 + d| ~ |d| / 2``: Rayleigh with scale ``e_r / 2``.
    """
    return 0.5 * np.asarray(random_error, dtype=float)


# ------------------------------------------------------------------------------------------------ where it fails


def frequency_flags(eps_w, sigma, confident, epsilon_threshold: float,
                    sigma_factor: float = SIGMA_FACTOR) -> list[str]:
    """Per-frequency verdict: ``"excluded"`` (not confident), ``"ok"`` (epsilon <= threshold), ``"model"``
    (epsilon > threshold and > ``sigma_factor`` sigma) or ``"data"`` (epsilon > threshold but within the
    random error)."""
    flags = []
    for e, s, c in zip(np.asarray(eps_w, float), np.asarray(sigma, float), np.asarray(confident, bool)):
        if not c or not np.isfinite(e):
            flags.append("excluded")
        elif e <= epsilon_threshold:
            flags.append("ok")
        elif np.isfinite(s) and e > sigma_factor * s:
            flags.append("model")
        else:
            flags.append("data")
    return flags


def find_bands(w_rad_s, eps_w, sigma, coherence, flags: Sequence[str], coherence_threshold: float,
               sigma_factor: float = SIGMA_FACTOR) -> list[dict]:
    """Contiguous runs of frequencies flagged ``model`` or ``data``, each with its verdict and reason.

    A band is model-limited when at least one of its frequencies is (epsilon well outside the random error with
    coherence OK); otherwise it is data-limited. Excluded frequencies end a band.
    """
    w = np.asarray(w_rad_s, float)
    bands, start = [], None
    for i, flag in enumerate(list(flags) + ["ok"]):
        inside = flag in ("model", "data")
        if inside and start is None:
            start = i
        elif not inside and start is not None:
            bands.append(_band(w, eps_w, sigma, coherence, flags, start, i, coherence_threshold, sigma_factor))
            start = None
    return bands


def _band(w, eps_w, sigma, coherence, flags, lo, hi, coherence_threshold, sigma_factor) -> dict:
    idx = np.arange(lo, hi)
    eps = np.asarray(eps_w, float)[idx]
    sig = np.asarray(sigma, float)[idx]
    peak = idx[int(np.argmax(eps))]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.max(eps / sig)
    model = any(flags[i] == "model" for i in idx)
    coh_min = float(np.min(np.asarray(coherence, float)[idx]))
    e_peak, s_peak = float(eps_w[peak]), float(sigma[peak])
    if model:
        reason = (f"confident data disagree with the model: epsilon {e_peak:.2f} is {ratio:.0f}x the random-error "
                  f"scale {s_peak:.3f} (coherence >= {coherence_threshold:g})")
    else:
        reason = (f"random error explains the mismatch: epsilon {e_peak:.2f} is within {sigma_factor:g}x the "
                  f"random-error scale {s_peak:.3f} (coherence down to {coh_min:.2f}); fly better sweeps there")
    return {"min_rad_s": float(w[lo]), "max_rad_s": float(w[hi - 1]), "peak_rad_s": float(w[peak]),
            "epsilon": e_peak, "limited_by": "model" if model else "data", "reason": reason,
            "coherence_min": coh_min, "sigma_ratio": float(ratio) if np.isfinite(ratio) else None}


# ------------------------------------------------------------------------------------------------ effect families


@dataclass(frozen=True)
class _Context:
    """Confident frequency range the fit sees [rad/s]."""

    w_lo: float
    w_hi: float


@dataclass(frozen=True)
class _Family:
    """One effect type, parametrised for fitting.

    ``grid(ctx, coarse)`` gives start points (M, p); ``bounds(x0, ctx)`` the box for the local refinement;
    ``response(X, w)`` the factor for M parameter rows (M, N); ``spec(x)`` the effect mapping.
    """

    name: str
    complexity: int
    grid: Callable[[_Context, bool], np.ndarray]
    bounds: Callable[[np.ndarray, _Context], tuple[np.ndarray, np.ndarray]]
    response: Callable[[np.ndarray, np.ndarray], np.ndarray]
    spec: Callable[[np.ndarray], dict]


def _product(*axes) -> np.ndarray:
    return np.array(list(itertools.product(*axes)), dtype=float)


def _delay_grid(ctx: _Context, coarse: bool) -> np.ndarray:
    step = (0.6 if coarse else 0.25) / ctx.w_hi          # phase step at the top frequency [rad]
    count = int(min(MAX_DELAY_S / step, 60 if coarse else 400)) + 1
    return np.linspace(0.0, MAX_DELAY_S, count)[:, None]


def _delay_response(x, w):
    return np.exp(-1j * np.outer(x[:, 0], w))


def _lag1_bounds(x0, ctx):
    return np.log([0.1 * ctx.w_lo]), np.log([30.0 * ctx.w_hi])


def _lag1_grid(ctx, coarse):
    lo, hi = _lag1_bounds(None, ctx)
    return np.linspace(lo[0], hi[0], 12 if coarse else 40)[:, None]


def _lag1_response(x, w):
    a = np.exp(x[:, :1])
    return a / (1j * w[None, :] + a)


_ZETA_RANGE = (0.02, 2.5)


def _lag2_bounds(x0, ctx):
    return (np.array([math.log(0.2 * ctx.w_lo), _ZETA_RANGE[0]]),
            np.array([math.log(10.0 * ctx.w_hi), _ZETA_RANGE[1]]))


def _lag2_grid(ctx, coarse):
    lo, hi = _lag2_bounds(None, ctx)
    wn = np.linspace(lo[0], hi[0], 10 if coarse else 28)
    zeta = [0.1, 0.3, 0.7, 1.5] if coarse else [0.05, 0.1, 0.2, 0.35, 0.5, 0.7, 1.0, 1.5, 2.2]
    return _product(wn, zeta)


def _lag2_response(x, w):
    wn, zeta = np.exp(x[:, :1]), x[:, 1:2]
    r = w[None, :] / wn
    return 1.0 / (1.0 - r ** 2 + 2j * zeta * r)


def _gain_bounds(x0, ctx):
    return (np.array([0.05]), np.array([20.0])) if x0[0] > 0 else (np.array([-20.0]), np.array([-0.05]))


def _gain_grid(ctx, coarse):
    k = np.geomspace(0.1, 10.0, 15 if coarse else 61)
    return np.concatenate([k, -k])[:, None]


def _gain_response(x, w):
    return np.broadcast_to(x[:, :1].astype(complex), (x.shape[0], w.size))


_MODE_ZETA = (0.005, 1.0)


def _mode_bounds(x0, ctx):
    return (np.array([math.log(0.5 * ctx.w_lo), _MODE_ZETA[0], math.log(0.2 * ctx.w_lo), _MODE_ZETA[0]]),
            np.array([math.log(1.5 * ctx.w_hi), _MODE_ZETA[1], math.log(5.0 * ctx.w_hi), _MODE_ZETA[1]]))


def _mode_grid(ctx, coarse):
    if coarse:
        wp = np.geomspace(0.8 * ctx.w_lo, 1.2 * ctx.w_hi, 8)
        axes = (np.log(wp), [0.05, 0.2], np.log([0.7, 0.9, 1.1, 1.4]), [0.05, 0.3])
    else:
        wp = np.geomspace(0.8 * ctx.w_lo, 1.2 * ctx.w_hi, 18)
        axes = (np.log(wp), [0.02, 0.05, 0.1, 0.2, 0.4], np.log([0.5, 0.7, 0.8, 0.9, 1.1, 1.25, 1.4, 2.0]),
                [0.02, 0.07, 0.2, 0.5])
    grid = _product(*axes)
    grid[:, 2] += grid[:, 0]                            # zero frequency = ratio x pole frequency
    lo, hi = _mode_bounds(None, ctx)
    return np.clip(grid, lo, hi)


def _mode_response(x, w):
    wp, zp, wz, zz = np.exp(x[:, :1]), x[:, 1:2], np.exp(x[:, 2:3]), x[:, 3:4]
    rp, rz = w[None, :] / wp, w[None, :] / wz
    return (1.0 - rz ** 2 + 2j * zz * rz) / (1.0 - rp ** 2 + 2j * zp * rp)


def _sig(value: float, digits: int = 4) -> float:
    """``value`` rounded to ``digits`` significant digits (config-friendly numbers)."""
    return float(f"{float(value):.{digits}g}")


FAMILIES: dict[str, _Family] = {
    "time_delay": _Family(
        "time_delay", 1, _delay_grid,
        lambda x0, ctx: (np.array([0.0]), np.array([MAX_DELAY_S])), _delay_response,
        lambda x: {"type": "time_delay", "seconds": _sig(max(x[0], 0.0))}),
    "first_order_lag": _Family(
        "first_order_lag", 1, _lag1_grid, _lag1_bounds, _lag1_response,
        lambda x: {"type": "first_order_lag", "bandwidth_rad_s": _sig(math.exp(x[0]))}),
    "second_order_lag": _Family(
        "second_order_lag", 2, _lag2_grid, _lag2_bounds, _lag2_response,
        lambda x: {"type": "second_order_lag", "natural_frequency_rad_s": _sig(math.exp(x[0])),
                   "damping": _sig(x[1], 3)}),
    "gain": _Family(
        "gain", 1, _gain_grid, _gain_bounds, _gain_response,
        lambda x: {"type": "gain", "factor": _sig(x[0])}),
    "structural_mode": _Family(
        "structural_mode", 4, _mode_grid, _mode_bounds, _mode_response,
        lambda x: {"type": "structural_mode", "frequency_rad_s": _sig(math.exp(x[0])), "damping": _sig(x[1], 3),
                   "zero_frequency_rad_s": _sig(math.exp(x[2])), "zero_damping": _sig(x[3], 3)}),
}

#: Pairs fitted when no single effect explains the mismatch, named by their sorted types joined with "+".
PAIRS: tuple[tuple[str, str], ...] = tuple(itertools.combinations(sorted(FAMILIES), 2))


# ------------------------------------------------------------------------------------------------ fitting


@dataclass
class _FitData:
    """Confident points of the averaged estimate, ready for the CIFER residuals."""

    w: np.ndarray
    p_meas: np.ndarray
    p_model: np.ndarray
    sqrt_w: np.ndarray        # sqrt of the CIFER weight
    coherence: np.ndarray
    ctx: _Context

    def residuals(self, factor: np.ndarray) -> np.ndarray:
        """CIFER residuals for factors (M, N) -> (M, 2N): sqrt(W) dB error and sqrt(W 0.01745) deg error."""
        log_q = _log_ratio(self.p_model * factor, self.p_meas)
        mag = self.sqrt_w * _DB_PER_NEPER * log_q.real
        phase = self.sqrt_w * math.sqrt(_PHASE_WEIGHT) * _DEG_PER_RAD * log_q.imag
        out = np.concatenate([mag, phase], axis=-1)
        return np.where(np.isfinite(out), out, 1e6)

    def cost(self, factor: np.ndarray) -> np.ndarray:
        """CIFER J for factors (M, N) -> (M,)."""
        return 20.0 / self.w.size * np.sum(self.residuals(factor) ** 2, axis=-1)


@dataclass
class _Combo:
    """A set of families fitted together (one effect, or a pair)."""

    families: tuple[_Family, ...]

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
            out = out * fam.response(part, w)
        return out

    def grid(self, ctx: _Context) -> np.ndarray:
        if len(self.families) == 1:
            return self.families[0].grid(ctx, False)
        grids = [f.grid(ctx, True) for f in self.families]
        rows = [np.concatenate(parts) for parts in itertools.product(*grids)]
        return np.array(rows)

    def bounds(self, x0: np.ndarray, ctx: _Context) -> tuple[np.ndarray, np.ndarray]:
        parts = [f.bounds(p, ctx) for f, p in zip(self.families, self._split(x0))]
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])

    def specs(self, x: np.ndarray) -> list[dict]:
        return [validate_effect(f.spec(p)) for f, p in zip(self.families, self._split(np.asarray(x, float)))]


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
        sol = least_squares(lambda x: data.residuals(combo.response(x, data.w))[0], x0, bounds=(lo, hi),
                            x_scale=(hi - lo) / 10.0, method="trf", max_nfev=200)
        cost = data.cost(combo.response(sol.x, data.w))[0]
        if cost < best_cost:
            best_x, best_cost = sol.x, cost
    return best_x


def _coefficient_fit(model: LinearModel, data: _FitData) -> LinearModel | None:
    """Refit the airframe's numerator/denominator coefficients (same structure, monic denominator), each as
    ``c = c0 exp(x)`` started at the current values (x = 0), effects kept: the ``parameter_error`` candidate."""
    air = model.airframe
    num0, den0 = np.array(air.num, float), np.array(air.den, float)
    free_num = np.flatnonzero(num0 != 0.0)
    free_den = np.flatnonzero(den0[1:] != 0.0) + 1
    n_free = free_num.size + free_den.size
    if n_free == 0:
        return None
    s = 1j * data.w
    others = LinearModel([1.0], [1.0], air.delay_s, model.effects).freqresp(data.w)

    def build(x):
        num, den = num0.copy(), den0.copy()
        num[free_num] *= np.exp(x[:free_num.size])
        den[free_den] *= np.exp(x[free_num.size:])
        return num, den

    def residuals(x):
        num, den = build(x)
        p = np.polyval(num, s) / np.polyval(den, s) * others
        return data.residuals((p / data.p_model)[None, :])[0]

    bound = np.full(n_free, math.log(10.0))
    sol = least_squares(residuals, np.zeros(n_free), bounds=(-bound, bound), method="trf", max_nfev=100 * n_free)
    num, den = build(sol.x)
    num = np.array([_sig(v, 6) for v in num])
    den = np.array([_sig(v, 6) for v in den])
    return LinearModel(num, den, air.delay_s, model.effects)


# ------------------------------------------------------------------------------------------------ candidates


@dataclass
class _Scored:
    """A fitted candidate with its epsilon on the averaged data."""

    name: str
    complexity: int
    effects: list[dict]
    model: LinearModel
    eps: float
    eps_w: np.ndarray
    worst_idx: int
    members: tuple[str, ...] = ()
    replacement: bool = False
    chi2: float = math.nan


def _score(name, complexity, effects, model, est_w, p_meas, confident, members=(), replacement=False):
    eps_w = metrics.epsilon_per_frequency(model.freqresp(est_w), p_meas)
    masked = np.where(confident & np.isfinite(eps_w), eps_w, -np.inf)
    k = int(np.argmax(masked))
    return _Scored(name, complexity, effects, model, float(eps_w[k]), eps_w, k, tuple(members), replacement)


def fit_effects(model: LinearModel, w_rad_s, p_meas, coherence, confident, *, pairs: bool | None = None,
                parameter_error: bool = True) -> list[_Scored]:
    """Fit every effect family (and optionally pairs and the coefficient refit) to the measured response.

    Parameters
    ----------
    model : LinearModel
        Current model; effects are fitted in series with it.
    w_rad_s, p_meas, coherence : array_like
        Frequencies [rad/s], measured complex response and squared coherence.
    confident : array_like of bool
        Frequencies the fit uses.
    pairs : bool
        Fit all pairs too (``None``: no pairs here; :func:`analyse_channel` decides).
    parameter_error : bool
        Refit the model's own coefficients as well.

    Returns
    -------
    list
        Scored candidates (unsorted, unfiltered).
    """
    w = np.asarray(w_rad_s, float)
    p_meas = np.asarray(p_meas, complex)
    confident = np.asarray(confident, bool) & np.isfinite(p_meas) & (np.abs(p_meas) > 0)
    data = _fit_data(model, w, p_meas, coherence, confident)
    if data is None:
        return []
    out = [_score_combo(_Combo((fam,)), model, data, w, p_meas, confident) for fam in FAMILIES.values()]
    if pairs:
        out += [_score_combo(_Combo((FAMILIES[a], FAMILIES[b])), model, data, w, p_meas, confident)
                for a, b in PAIRS]
    if parameter_error:
        refit = _coefficient_fit(model, data)
        if refit is not None:
            n_free = int(np.count_nonzero(model.airframe.num) + np.count_nonzero(model.airframe.den[1:]))
            out.append(_score("parameter_error", n_free, [], refit, w, p_meas, confident, replacement=True))
    return out


def _fit_data(model, w, p_meas, coherence, confident) -> _FitData | None:
    if np.count_nonzero(confident) < _MIN_POINTS:
        return None
    wc = w[confident]
    coh = np.asarray(coherence, float)[confident]
    return _FitData(w=wc, p_meas=p_meas[confident], p_model=model.freqresp(wc), sqrt_w=np.sqrt(cifer_weight(coh)),
                    coherence=coh, ctx=_Context(float(wc.min()), float(wc.max())))


def _score_combo(combo: _Combo, model, data, w, p_meas, confident) -> _Scored:
    x = _fit_combo(combo, data)
    effects = combo.specs(x)
    members = tuple(f.name for f in combo.families)
    return _score(combo.name, combo.complexity, effects, model.with_effects(effects), w, p_meas, confident,
                  members if len(members) > 1 else ())


# ------------------------------------------------------------------------------------------------ analysis


@dataclass
class _Baseline:
    w: np.ndarray
    p_meas: np.ndarray
    coherence: np.ndarray
    confident: np.ndarray
    eps_w: np.ndarray
    sigma: np.ndarray
    eps: float
    worst_idx: int
    chi2: float = math.nan


def _chi2(p_fit, p_meas, sigma, confident) -> float:
    """Normalised squared mismatch ``sum |ln(P_fit / P_meas)|^2 / e_r^2`` over the confident frequencies
    (``e_r = 2 sigma``; about 2 per frequency when the fit equals the truth: chi-square with 2 n degrees of
    freedom)."""
    log_q = _log_ratio(np.asarray(p_fit, complex)[confident], np.asarray(p_meas, complex)[confident])
    e_r = 2.0 * np.asarray(sigma, float)[confident]
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.abs(log_q) ** 2 / e_r ** 2
    return float(np.sum(np.where(np.isfinite(terms), terms, 0.0)))


def _significant(eps_w, sigma, confident, sigma_factor) -> bool:
    """True when epsilon exceeds ``sigma_factor`` sigma at some confident frequency."""
    return _max_ratio(eps_w, sigma, confident) > sigma_factor


def _max_ratio(eps_w, sigma, confident) -> float:
    """Largest ``epsilon(w) / sigma(w)`` over the confident frequencies (how many noise scales the worst
    mismatch is)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(confident, eps_w / sigma, 0.0)
    ratio = np.where(np.isnan(ratio), 0.0, ratio)
    return float(np.max(ratio)) if ratio.size else 0.0


def _chi2_improvement(before, after: _Scored, confident) -> bool:
    """The aggregate test: ``after`` removes at least half of ``before``'s chi-square excess over its expected
    value (2 per frequency) and more than a fitted noise spike could (``10 + 3 p`` for p extra parameters).

    A noise spike fitted by a many-parameter effect lowers the sup of epsilon but barely the chi-square; a real
    effect removes most of it.
    """
    if not (np.isfinite(before.chi2) and np.isfinite(after.chi2)):
        return True
    n = int(np.count_nonzero(confident))
    extra = after.complexity - getattr(before, "complexity", 0)
    gain = before.chi2 - after.chi2
    return gain >= max(0.5 * (before.chi2 - 2.0 * n), 10.0 + 3.0 * max(extra, 1))


def _real_improvement(before: _Scored | _Baseline, after: _Scored, sigma, confident, sigma_factor,
                      min_relative) -> bool:
    """True when ``after`` leaves an epsilon clearly below ``before``'s, beyond what the random error explains.

    Always: at least ``min_relative`` of epsilon removed. And either the sup falls by more than
    IMPROVEMENT_SIGMA_FACTOR sigma (at both worst frequencies), or ``before`` is far outside the random error
    (ratio > sigma_factor + 1) and ``after`` is within it (ratio <= sigma_factor): the candidate explains it.
    """
    e0, e1 = before.eps, after.eps
    if not e1 <= (1.0 - min_relative) * e0:
        return False
    if not _chi2_improvement(before, after, confident):
        return False
    s = max(sigma[before.worst_idx], sigma[after.worst_idx])
    if e0 - e1 > IMPROVEMENT_SIGMA_FACTOR * s:
        return True
    return (_max_ratio(before.eps_w, sigma, confident) > sigma_factor + 1.0
            and _max_ratio(after.eps_w, sigma, confident) <= sigma_factor)


def _select(base: _Baseline, fitted: list[_Scored], sigma_factor: float) -> list[_Scored]:
    """Keep the candidates with a real improvement; pairs only when clearly better than their best member;
    order: adequate explanations (simplest first), then the rest by epsilon."""
    for cand in fitted:
        cand.chi2 = _chi2(cand.model.freqresp(base.w), base.p_meas, base.sigma, base.confident)
    singles = {c.name: c for c in fitted if not c.members}
    kept = []
    for cand in fitted:
        if not _real_improvement(base, cand, base.sigma, base.confident, sigma_factor, MIN_RELATIVE_IMPROVEMENT):
            continue
        if cand.members:
            best = min((singles[m] for m in cand.members if m in singles), key=lambda c: c.eps, default=None)
            if best is not None and not _real_improvement(best, cand, base.sigma, base.confident, sigma_factor,
                                                          PAIR_RELATIVE_IMPROVEMENT):
                continue
        kept.append(cand)
    if not kept:
        return []
    best_eps = min(c.eps for c in kept)

    def adequate(c: _Scored) -> bool:
        if not _significant(c.eps_w, base.sigma, base.confident, sigma_factor):
            return True
        tolerance = max(IMPROVEMENT_SIGMA_FACTOR * base.sigma[c.worst_idx], MIN_RELATIVE_IMPROVEMENT * best_eps)
        return c.eps <= best_eps + tolerance

    return sorted(kept, key=lambda c: (0, c.complexity, c.eps) if adequate(c) else (1, 0, c.eps))


def _candidate_dict(c: _Scored, base: _Baseline, model: LinearModel, sweeps: Sequence,
                    coherence_threshold: float) -> dict:
    conf = base.confident
    p_fit = c.model.freqresp(base.w)
    nu_gap = float(np.max(metrics.chordal_distance(p_fit[conf], base.p_meas[conf])))
    out = {
        "effect": c.name,
        "parameters": _parameters(c),
        "effects": [dict(e) for e in c.effects],
        "epsilon": c.eps,
        "nu_gap": nu_gap,
        "sentence": _sentence(c, base.eps),
        "improvement": base.eps - c.eps,
        "epsilon_before": base.eps,
        "epsilon_raw": _raw_epsilon(c.model, sweeps, coherence_threshold),
        "worst_frequency_rad_s": float(base.w[c.worst_idx]),
        "complexity": c.complexity,
        "cost": cifer_cost(p_fit[conf], base.p_meas[conf], base.coherence[conf]),
        "cost_before": cifer_cost(model.freqresp(base.w)[conf], base.p_meas[conf], base.coherence[conf]),
    }
    if c.replacement:
        out["model"] = c.model.to_spec()
        out["note"] = ("parameter error: the model's own coefficients refitted (same structure); nothing to "
                       "append to effects: replace the model by 'model'")
    return out


def _parameters(c: _Scored) -> dict:
    if c.replacement:
        air = c.model.airframe
        return {"numerator": [float(v) for v in air.num], "denominator": [float(v) for v in air.den]}
    if len(c.effects) == 1:
        return {k: v for k, v in c.effects[0].items() if k != "type"}
    merged: dict = {}
    keys = [k for e in c.effects for k in e if k != "type"]
    clash = len(keys) != len(set(keys))
    for e in c.effects:
        for k, v in e.items():
            if k != "type":
                merged[f"{e['type']}.{k}" if clash else k] = v
    return merged


def _sentence(c: _Scored, before: float) -> str:
    if c.replacement:
        return (f"parameter error: refitting the model's coefficients (same structure) brings epsilon from "
                f"{before:.2f} to {c.eps:.2f}")
    what = " and ".join(describe_effect(e) for e in c.effects)
    verb = "adding it" if len(c.effects) == 1 else "adding both"
    return f"missing: {what}; {verb} brings epsilon from {before:.2f} to {c.eps:.2f}"


def _raw_epsilon(model: LinearModel, sweeps: Sequence, coherence_threshold: float) -> float | None:
    """Sup of epsilon over every sweep's confident points for ``model`` (raw epsilon, Table 1)."""
    best = None
    for s in sweeps:
        w = np.asarray(s.w_rad_s, float)
        p = np.asarray(s.response, complex)
        ok = (np.asarray(s.coherence, float) >= coherence_threshold) & np.isfinite(p)
        if np.any(ok):
            e = float(np.max(metrics.epsilon_per_frequency(model.freqresp(w[ok]), p[ok])))
            best = e if best is None else max(best, e)
    return best


def _baseline(model, estimate, sweeps, coherence_threshold) -> _Baseline:
    w = np.asarray(estimate.w_rad_s, float)
    p_meas = np.asarray(estimate.response, complex)
    coherence = np.asarray(estimate.coherence, float)
    confident = (coherence >= coherence_threshold) & np.isfinite(p_meas) & (np.abs(p_meas) > 0)
    eps_w = metrics.epsilon_per_frequency(model.freqresp(w), p_meas)
    confident &= np.isfinite(eps_w)
    sigma = epsilon_noise_scale(effective_random_error(estimate, sweeps, coherence_threshold))
    masked = np.where(confident, eps_w, -np.inf)
    k = int(np.argmax(masked)) if np.any(confident) else -1
    return _Baseline(w, p_meas, coherence, confident, eps_w, sigma, float(eps_w[k]) if k >= 0 else math.nan, k,
                     _chi2(model.freqresp(w), p_meas, sigma, confident))


def analyse_channel(model: LinearModel, estimate, sweeps: list, coherence_threshold: float, *, fit: bool = True,
                    epsilon_threshold: float = 0.15, sigma_factor: float = SIGMA_FACTOR,
                    channel: str = "") -> ChannelDiagnosis:
    """Where the model fails (model- or data-limited bands) and which effects would explain it.

    Parameters
    ----------
    model : LinearModel
        The channel's current model (airframe plus effects).
    estimate : SpectralEstimate
        Averaged estimate: ``w_rad_s``, complex ``response``, ``coherence`` (squared), ``random_error``
        (relative, Bendat & Piersol), ``n_averages``.
    sweeps : list of SpectralEstimate
        Per-sweep estimates on the same frequencies (raw epsilon, scatter-based random error).
    coherence_threshold : float
        Frequencies with lower coherence are excluded.
    fit : bool
        Fit the effect candidates; ``False`` gives only where it fails (cheap, for the live node).
    epsilon_threshold : float
        epsilon(w) above it makes a band.
    sigma_factor : float
        Multiple of the random-error scale ``sigma = e_r/2`` of epsilon beyond which a mismatch is
        model-limited (and beyond which the current epsilon needs a diagnosis at all).
    channel : str
        Channel name to start the message with (optional).

    Returns
    -------
    ChannelDiagnosis
    """
    base = _baseline(model, estimate, sweeps, coherence_threshold)
    flags = frequency_flags(base.eps_w, base.sigma, base.confident, epsilon_threshold, sigma_factor)
    bands = find_bands(base.w, base.eps_w, base.sigma, base.coherence, flags, coherence_threshold, sigma_factor)
    result = ChannelDiagnosis(limited_by=_limited_by(base, bands), frequency_flags=flags, bands=bands)
    if fit and base.worst_idx >= 0 and _significant(base.eps_w, base.sigma, base.confident, sigma_factor):
        fitted = fit_effects(model, base.w, base.p_meas, base.coherence, base.confident, pairs=False)
        singles_ok = [c for c in fitted if not c.replacement
                      and not _significant(c.eps_w, base.sigma, base.confident, sigma_factor)]
        if not singles_ok:  # no single effect explains the mismatch: try pairs
            data = _fit_data(model, base.w, base.p_meas, base.coherence, base.confident)
            fitted += [_score_combo(_Combo((FAMILIES[a], FAMILIES[b])), model, data, base.w, base.p_meas,
                                    base.confident) for a, b in PAIRS]
        chosen = _select(base, fitted, sigma_factor)
        result.candidates = [_candidate_dict(c, base, model, sweeps, coherence_threshold) for c in chosen]
    result.message = _message(base, result, coherence_threshold, epsilon_threshold, channel)
    return result


def _limited_by(base: _Baseline, bands: list[dict]) -> str:
    if base.worst_idx < 0:
        return "data"
    w_worst = base.w[base.worst_idx]
    for band in bands:
        if band["min_rad_s"] <= w_worst <= band["max_rad_s"]:
            return band["limited_by"]
    return "none"


def _range(lo: float, hi: float) -> str:
    return f"{lo:.3g} rad/s" if lo == hi else f"{lo:.3g}-{hi:.3g} rad/s"


def _message(base: _Baseline, result: ChannelDiagnosis, coherence_threshold: float, epsilon_threshold: float,
             channel: str) -> str:
    prefix = f"{channel}: " if channel else ""
    if base.worst_idx < 0:
        return (f"{prefix}data-limited: no frequency with coherence >= {coherence_threshold:g}; "
                f"fly sweeps with more excitation")
    w_worst = base.w[base.worst_idx]
    band = next((b for b in result.bands if b["min_rad_s"] <= w_worst <= b["max_rad_s"]), None)
    if band is None:
        text = (f"{prefix}model fits: epsilon {base.eps:.2f} at {w_worst:.3g} rad/s, below {epsilon_threshold:g} "
                f"at every confident frequency")
    elif band["limited_by"] == "model":
        text = (f"{prefix}model-limited at {_range(band['min_rad_s'], band['max_rad_s'])}: epsilon {base.eps:.2f} "
                f"at {w_worst:.3g} rad/s is well outside the random error")
    else:
        text = (f"{prefix}data-limited at {_range(band['min_rad_s'], band['max_rad_s'])}: epsilon {base.eps:.2f} "
                f"at {w_worst:.3g} rad/s is within the random error; fly better sweeps there")
    others = [b for b in result.bands if b is not band]
    if others:
        text += "; also " + ", ".join(f"{b['limited_by']}-limited at {_range(b['min_rad_s'], b['max_rad_s'])}"
                                      for b in others)
    if result.candidates:
        top = result.candidates[0]
        text += f"; {top['sentence']}"
    excluded = int(np.count_nonzero(~base.confident))
    if excluded:
        text += f" ({excluded} of {base.w.size} frequencies excluded: coherence < {coherence_threshold:g})"
    return text
