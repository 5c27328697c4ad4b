"""Distances between models and data: chordal distance, nu-gap, overbounding epsilon, Theil coefficient.

Paper: "Validating Aircraft Models in the Gap Metric" (eqs. 1, 3, 13, 14); nu-gap after Vinnicombe
(*Uncertainty and Feedback: H-infinity loop-shaping and the nu-gap metric*, Imperial College Press, 2001).

Each metric returns its value and the frequency where it peaks [rad/s]. For frequency-response *data* the sup
is over the given points and the winding-number condition of the nu-gap is assumed (as the paper does). For
two models the results are exact. SISO :class:`~gap_validation.core.models.LinearModel` pairs (delays allowed):

* the winding-number condition is checked (algebraically from polynomial roots for rational models or equal
  delays, numerically along the frequency axis when the delays differ), and the nu-gap is 1 when it fails;
* the sup is located on a dense logarithmic grid spanning every feature frequency of the pair (poles, zeros,
  the corner frequencies and gain crossovers of each model, the zeros of P2 - P1 and P2 + P1), plus points
  around every lightly damped root, on both sides of every root on the imaginary axis and, with delays, a
  linear grid resolving the delay's phase; every promising local maximum is refined with a bounded scalar
  optimisation to about 1e-8 relative in frequency; w = 0 and w -> infinity are checked too.

MIMO pairs (:class:`~gap_validation.core.models.MimoModel`, or a MIMO model against a 1 x 1 one) go through
normalised coprime factors (:mod:`gap_validation.core.statespace`): kappa(w) is
``sigma_max((I + P2 P2*)^-1/2 (P2 - P1) (I + P1* P1)^-1/2)``, the sup is the H-infinity norm of
``Gt2 G1`` (level-set iteration, peak refined), and the winding-number condition is counted from the zeros of
``det(G2~ G1)``. For 1 x 1 models this is the SISO nu-gap.

Conventions: ``P1`` is the model, ``P2`` the measurement (or the second model), as in the paper.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np
from numpy.typing import ArrayLike

from gap_validation.core import statespace
from gap_validation.core.frd import paired_responses

if TYPE_CHECKING:  # pragma: no cover
    from gap_validation.core.models import LinearModel, MimoModel

#: A real function of frequency [rad/s], vectorised (kappa(w) or epsilon(w) of two models).
Response = Callable[[np.ndarray], np.ndarray]

_AXIS_RTOL = 1e-8  # roots closer than this (relative) to the imaginary axis are on it
_CANCEL_RTOL = 1e-6  # numerator and denominator roots closer than this (relative) cancel
_GRID_PER_DECADE = 300
_REFINE_XATOL = 1e-10  # bounded refinement tolerance in ln(w)
_MAX_CANDIDATES = 40
_TIE_RTOL = 1e-9  # peaks equal to this (relative) are the same height: the lowest frequency is reported
_HUGE_EPSILON = 1e10  # a refined epsilon peak above this is a crossing of P2 = -P1: reported as inf
_AXIS_OFFSETS = np.geomspace(1e-9, 0.5, 180)  # relative offsets sampled on both sides of roots on the axis
_SINGULAR_D_COND = 1e12  # det(G2~ G1) at infinity is taken as zero beyond this condition number


# ----------------------------------------------------------------------------------------------------------
# per-frequency quantities and frequency data
# ----------------------------------------------------------------------------------------------------------


def chordal_distance(p1: ArrayLike, p2: ArrayLike) -> np.ndarray:
    """Chordal distance between two frequency responses (paper eq. 13, pointwise; Vinnicombe's kappa).

    SISO: ``kappa = |P2 - P1| / sqrt((1 + |P1|^2) (1 + |P2|^2))``, between 0 and 1; an infinite response (a
    pole on the imaginary axis) is the point at infinity of the Riemann sphere.

    MIMO (arrays of 3 or more dimensions: stacks of ``p x m`` matrices in the last two axes):
    ``kappa = sigma_max((I + P2 P2*)^-1/2 (P2 - P1) (I + P1* P1)^-1/2)``; a matrix with a non-finite entry
    gives nan. For 1 x 1 matrices it is the SISO formula.

    Parameters
    ----------
    p1, p2 : array_like of complex
        Frequency responses at the same frequencies (broadcast): SISO values, or ``(..., p, m)`` matrices.

    Returns
    -------
    ndarray of float
        One value per frequency (the matrix axes removed).
    """
    p1 = np.asarray(p1, dtype=complex)
    p2 = np.asarray(p2, dtype=complex)
    if max(p1.ndim, p2.ndim) >= 3:
        return _chordal_distance_matrices(*np.broadcast_arrays(p1, p2))
    p1, p2 = np.broadcast_arrays(p1, p2)
    inf1, inf2 = ~np.isfinite(p1) & ~np.isnan(p1), ~np.isfinite(p2) & ~np.isnan(p2)
    with np.errstate(invalid="ignore", over="ignore"):
        a1, a2 = np.abs(p1), np.abs(p2)
        kappa = np.abs(p2 - p1) / np.sqrt((1.0 + a1 * a1) * (1.0 + a2 * a2))
        kappa = np.where(inf1 & ~inf2, 1.0 / np.sqrt(1.0 + a2 * a2), kappa)
        kappa = np.where(inf2 & ~inf1, 1.0 / np.sqrt(1.0 + a1 * a1), kappa)
    kappa = np.where(inf1 & inf2, 0.0, kappa)
    return np.minimum(kappa, 1.0)


def _inv_sqrt_gram(p: np.ndarray, side: str) -> np.ndarray:
    """``(I + P P*)^-1/2`` (side "left") or ``(I + P* P)^-1/2`` (side "right") of a stack of matrices, from the
    singular values of P (no cancellation when P is huge, e.g. next to a pole on the axis)."""
    u, s, vh = np.linalg.svd(p, full_matrices=True)
    basis = u if side == "left" else np.conj(np.swapaxes(vh, -1, -2))
    weights = np.ones(basis.shape[:-1])
    weights[..., :s.shape[-1]] = 1.0 / np.sqrt(1.0 + s * s)
    return (basis * weights[..., None, :]) @ np.conj(np.swapaxes(basis, -1, -2))


def _chordal_distance_matrices(p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Vinnicombe's pointwise chordal distance of stacks of p x m matrices (nan where an entry is not finite)."""
    shape = p1.shape[:-2]
    p1 = p1.reshape((-1,) + p1.shape[-2:])
    p2 = p2.reshape((-1,) + p2.shape[-2:])
    out = np.full(p1.shape[0], np.nan)
    ok = np.all(np.isfinite(p1), axis=(1, 2)) & np.all(np.isfinite(p2), axis=(1, 2))
    if np.any(ok):
        a, b = p1[ok], p2[ok]
        psi = _inv_sqrt_gram(b, "left") @ (b - a) @ _inv_sqrt_gram(a, "right")
        out[ok] = np.minimum(np.linalg.svd(psi, compute_uv=False)[:, 0], 1.0)
    return out.reshape(shape)


def epsilon_per_frequency(p1: ArrayLike, p2: ArrayLike) -> np.ndarray:
    """Smallest overbounding-disk radius per frequency (paper eq. 14): ``|P2 - P1| / |P2 + P1|``.

    The radius epsilon is the smallest with ``P2 = P1 (1 + d1)/(1 - d2)``, ``|d1|, |d2| <= epsilon``.
    Conventions: 0 where P1 = P2 (including both zero); ``inf`` where P2 = -P1 != 0 (no disk of radius < 1
    covers it). Any value >= 1 means that no stability margin is guaranteed.

    Parameters
    ----------
    p1, p2 : array_like of complex

    Returns
    -------
    ndarray of float
    """
    p1 = np.asarray(p1, dtype=complex)
    p2 = np.asarray(p2, dtype=complex)
    with np.errstate(divide="ignore", invalid="ignore"):
        diff = np.abs(p2 - p1)
        total = np.abs(p2 + p1)
        eps = diff / total
    eps = np.where(diff == 0.0, 0.0, eps)
    return np.where((total == 0.0) & (diff > 0.0), np.inf, eps)


def _sup_over_points(w_rad_s: ArrayLike, values: np.ndarray) -> tuple[float, float]:
    w = np.asarray(w_rad_s, dtype=float).ravel()
    values = np.asarray(values, dtype=float).ravel()
    valid = ~np.isnan(values)
    if not np.any(valid):
        return math.nan, math.nan
    index = int(np.flatnonzero(valid)[np.argmax(values[valid])])
    return float(values[index]), float(w[index])


def nugap_frequency_data(w_rad_s: ArrayLike, p1: ArrayLike, p2: ArrayLike) -> tuple[float, float]:
    """nu-gap over frequency points: sup of the chordal distance (eq. 13), condition assumed.

    Parameters
    ----------
    w_rad_s : array_like
        Frequencies [rad/s].
    p1, p2 : array_like of complex
        Model and measured responses at ``w_rad_s`` (SISO values, or ``(len(w), p, m)`` matrices: see
        :func:`chordal_distance`). NaN points are ignored.

    Returns
    -------
    value : float
        Largest chordal distance (nan when no valid point).
    w_peak_rad_s : float
        Frequency of that point.
    """
    return _sup_over_points(w_rad_s, chordal_distance(p1, p2))


def epsilon_frequency_data(w_rad_s: ArrayLike, p1: ArrayLike, p2: ArrayLike) -> tuple[float, float]:
    """epsilon over frequency points: sup of :func:`epsilon_per_frequency` (eq. 14).

    Parameters
    ----------
    w_rad_s, p1, p2 : array_like
        As for :func:`nugap_frequency_data`.

    Returns
    -------
    value : float
        Largest epsilon (may be >= 1 or inf: no guarantee).
    w_peak_rad_s : float
        Frequency of that point.
    """
    return _sup_over_points(w_rad_s, epsilon_per_frequency(p1, p2))


# ----------------------------------------------------------------------------------------------------------
# polynomial helpers
# ----------------------------------------------------------------------------------------------------------


def _strip(poly: ArrayLike) -> np.ndarray:
    poly = np.atleast_1d(np.asarray(poly, dtype=float))
    nonzero = np.flatnonzero(poly)
    return poly[nonzero[0]:] if nonzero.size else np.array([0.0])


def _mirror(poly: ArrayLike) -> np.ndarray:
    """Coefficients of p(-s) from those of p(s) (descending powers)."""
    poly = np.asarray(poly, dtype=float)
    signs = (-1.0) ** np.arange(len(poly) - 1, -1, -1)
    return poly * signs


def _roots(poly: ArrayLike) -> np.ndarray:
    poly = _strip(poly)
    return np.roots(poly) if len(poly) > 1 and poly[0] != 0.0 else np.array([], dtype=complex)


def _coprime(num: ArrayLike, den: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Cancel common roots of num and den (relative tolerance); P = 0 becomes 0/1."""
    num, den = _strip(num), _strip(den)
    if not np.any(num):
        return np.array([0.0]), np.array([1.0])
    zeros, poles = list(_roots(num)), list(_roots(den))
    cancelled = False
    for zero in list(zeros):
        distances = [abs(zero - pole) for pole in poles]
        if distances:
            k = int(np.argmin(distances))
            if distances[k] <= _CANCEL_RTOL * max(1.0, abs(poles[k])):
                poles.pop(k)
                zeros.remove(zero)
                cancelled = True
    if not cancelled:
        return num, den / den[0]
    gain = num[0] / den[0]
    return gain * np.real(np.poly(zeros)) if zeros else np.array([gain]), \
        np.real(np.poly(poles)) if poles else np.array([1.0])


def _eval_nd(model: LinearModel, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Numerator (delay included) and denominator of a model at s = j w, scaled per point.

    The common positive scale keeps products finite at high frequency; ratios are unchanged.
    """
    s = 1j * w
    n = np.polyval(model.num, s)
    d = np.polyval(model.den, s)
    if model.delay_s:
        n = n * np.exp(-s * model.delay_s)
    scale = np.maximum(np.abs(n), np.abs(d))
    scale = np.where(scale > 0.0, scale, 1.0)
    return n / scale, d / scale


def _kappa_models(m1: LinearModel, m2: LinearModel, w: np.ndarray) -> np.ndarray:
    n1, d1 = _eval_nd(m1, w)
    n2, d2 = _eval_nd(m2, w)
    num = np.abs(n2 * d1 - n1 * d2)
    den = np.sqrt((np.abs(n1) ** 2 + np.abs(d1) ** 2) * (np.abs(n2) ** 2 + np.abs(d2) ** 2))
    return np.minimum(num / den, 1.0)


def _epsilon_models(m1: LinearModel, m2: LinearModel, w: np.ndarray) -> np.ndarray:
    n1, d1 = _eval_nd(m1, w)
    n2, d2 = _eval_nd(m2, w)
    return epsilon_per_frequency(n1 * d2, n2 * d1)


def _high_frequency_form(model: LinearModel) -> tuple[float, int]:
    """(k, m): P(s) ~ k s^-m exp(-s T) as s -> infinity (k = 0 for P = 0)."""
    num, den = _strip(model.num), _strip(model.den)
    if not np.any(num):
        return 0.0, 0
    return float(num[0] / den[0]), len(den) - len(num)


def _kappa_at_infinity(m1: LinearModel, m2: LinearModel) -> float:
    """lim sup of kappa as w -> infinity."""
    (k1, r1), (k2, r2) = _high_frequency_form(m1), _high_frequency_form(m2)
    c1 = k1 if r1 == 0 else 0.0
    c2 = k2 if r2 == 0 else 0.0
    norm = math.sqrt((1.0 + c1 * c1) * (1.0 + c2 * c2))
    if c1 and c2 and m1.delay_s != m2.delay_s:
        return (abs(c1) + abs(c2)) / norm
    return abs(c2 - c1) / norm


def _low_frequency_form(model: LinearModel) -> tuple[float, int]:
    """(k, m): P(s) ~ k s^-m as s -> 0 (m > 0: poles at the origin; k = 0 for P = 0)."""
    num, den = _strip(model.num), _strip(model.den)
    if not np.any(num):
        return 0.0, 0
    num_zeros = len(num) - 1 - int(np.flatnonzero(num)[-1])
    den_zeros = len(den) - 1 - int(np.flatnonzero(den)[-1])
    return float(num[len(num) - 1 - num_zeros] / den[len(den) - 1 - den_zeros]), den_zeros - num_zeros


def _epsilon_at_zero(m1: LinearModel, m2: LinearModel) -> float:
    """lim of epsilon(w) as w -> 0 (defined also when both models have poles or zeros at the origin)."""
    (k1, r1), (k2, r2) = _low_frequency_form(m1), _low_frequency_form(m2)
    if k1 == 0.0 and k2 == 0.0:
        return 0.0
    if k1 == 0.0 or k2 == 0.0 or r1 != r2:
        return 1.0
    return math.inf if k2 == -k1 else abs(k2 - k1) / abs(k2 + k1)


def _epsilon_at_infinity(m1: LinearModel, m2: LinearModel) -> float:
    """lim sup of epsilon(w) as w -> infinity."""
    (k1, r1), (k2, r2) = _high_frequency_form(m1), _high_frequency_form(m2)
    if k1 == 0.0 and k2 == 0.0:
        return 0.0
    if k1 == 0.0 or k2 == 0.0 or r1 != r2:
        return 1.0
    ratio = k2 / k1
    if m1.delay_s != m2.delay_s:
        spread = abs(abs(ratio) - 1.0)
        return math.inf if spread == 0.0 else (abs(ratio) + 1.0) / spread
    return math.inf if ratio == -1.0 else abs(ratio - 1.0) / abs(ratio + 1.0)


# ----------------------------------------------------------------------------------------------------------
# winding-number condition
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class WindingCheck:
    """Outcome of the nu-gap winding-number condition for P1, P2.

    Attributes
    ----------
    satisfied : bool
        True when det(1 + P2~ P1)(jw) != 0 on the extended imaginary axis and its winding number (with the
        pole counts) is zero, i.e. the nu-gap is the sup of the chordal distance.
    frequency_rad_s : float
        Where 1 + P2~ P1 vanishes when that is the failure (``inf`` at infinity), else nan.
    reason : str
        One-line explanation (empty when satisfied).
    method : str
        ``"algebraic"`` (polynomial roots) or ``"numerical"`` (phase along the axis, models with different
        delays).
    """

    satisfied: bool
    frequency_rad_s: float = math.nan
    reason: str = ""
    method: str = "algebraic"


def winding_condition(m1: LinearModel | MimoModel, m2: LinearModel | MimoModel) -> WindingCheck:
    """Check Vinnicombe's winding-number condition of the nu-gap for two models (SISO or MIMO).

    SISO: with coprime P_i = n_i/d_i (delays aside), the condition is that the normalised coprime factors
    satisfy wno det(G2* G1) = 0 with G2* G1 nonsingular on the axis. On s = j w,
    ``G2* G1 = rho(s) / (q2(-s) q1(s))`` with ``rho(s) = d2(-s) d1(s) + n2(-s) n1(s) exp(s (T2 - T1))`` and
    q_i the Hurwitz spectral factors of ``d_i d_i~ + n_i n_i~`` (deg q_i = deg d_i). Since q1 contributes
    deg d1 / 2 turns and q2(-s) -deg d2 / 2, the condition is: rho has no zero on the extended imaginary axis
    and winds ``(deg d1 - deg d2) / 2`` times along it. This is equivalent to Vinnicombe's
    ``wno(1 + P2~ P1) + eta(P1) - eta(P2) - eta0(P2) = 0`` and needs no indentation around poles on the axis.

    For equal delays rho is a polynomial: the condition is that rho has full degree (1 + P2(inf) P1(inf) != 0),
    no root on the imaginary axis, exactly deg d1 roots in the open left and deg d2 in the open right half
    plane. With different delays the phase of rho is unwrapped on an adaptive grid over (0, w_hi), the tail
    beyond w_hi (past every root and where |P1 P2| < 1) is added analytically, and conjugate symmetry gives
    the whole axis.

    MIMO (method ``"state space"``): with minimal realizations and normalised right coprime factors G_i of
    order n_i (:func:`~gap_validation.core.statespace.right_ncf`), ``det(G2~ G1)`` has n1 stable and n2
    antistable poles; it must have no zero on the extended imaginary axis (``I + P2(inf)^T P1(inf)``
    nonsingular) and exactly n2 zeros in the open right half plane (the zeros of ``det`` are the eigenvalues of
    ``A - B D^-1 C`` of the product's realization). For 1 x 1 models this is the polynomial count above.

    Parameters
    ----------
    m1, m2 : LinearModel or MimoModel
        Models of the same shape (a 1 x 1 MimoModel counts as SISO).

    Returns
    -------
    WindingCheck
    """
    siso, systems = _siso_or_state_space(m1, m2)
    if systems is not None:
        g1, g2 = (statespace.right_ncf(system) for system in systems)
        return _winding_state_space(g1, g2, systems[1][0].shape[0])
    m1, m2 = siso
    n1, d1 = _coprime(m1.num, m1.den)
    n2, d2 = _coprime(m2.num, m2.den)
    delta_s = m2.delay_s - m1.delay_s
    if delta_s == 0.0:
        return _winding_algebraic(n1, d1, n2, d2)
    return _winding_numerical(n1, d1, n2, d2, delta_s)


def _winding_algebraic(n1: np.ndarray, d1: np.ndarray, n2: np.ndarray, d2: np.ndarray) -> WindingCheck:
    deg1, deg2 = len(d1) - 1, len(d2) - 1
    d_term = np.polymul(_mirror(d2), d1)
    n_term = np.polymul(_mirror(n2), n1)
    rho = np.polyadd(d_term, n_term)
    lead_scale = abs(d_term[0]) + (abs(n_term[0]) if len(n_term) == len(d_term) else 0.0)
    if len(rho) < len(d_term) or abs(rho[-(deg1 + deg2 + 1)]) <= 1e-12 * lead_scale:
        return WindingCheck(False, math.inf, "1 + P2~ P1 vanishes at infinity (P1(inf) P2(inf) = -1)")
    roots = _roots(rho)
    on_axis = _on_axis(roots)
    if np.any(on_axis):
        w = float(np.min(np.abs(roots[on_axis].imag)))
        return WindingCheck(False, w, f"1 + P2~ P1 vanishes at w = {w:.6g} rad/s")
    left = int(np.sum(roots.real < 0.0))
    right = roots.size - left
    if left == deg1 and right == deg2:
        return WindingCheck(True)
    return WindingCheck(False, math.nan, f"winding number {(left - right - deg1 + deg2) // 2} != 0 "
                                         f"(unstable pole/zero counts do not match)")


def _on_axis(roots: np.ndarray) -> np.ndarray:
    """Which roots lie on the imaginary axis (relative tolerance, absolute near the origin)."""
    scale = max(1.0, float(np.max(np.abs(roots)))) if roots.size else 1.0
    return np.abs(roots.real) <= _AXIS_RTOL * np.maximum(np.abs(roots), 1e-3 * scale)


def _winding_state_space(g1: statespace.StateSpace, g2: statespace.StateSpace, n2: int) -> WindingCheck:
    """The condition from the normalised right coprime factors G1, G2 (n2 states in G2)."""
    product = statespace.series(g1, statespace.paraconjugate(g2))   # G2~ G1, m x m
    d = product[3]
    if d.size and np.linalg.cond(d) > _SINGULAR_D_COND:
        return WindingCheck(False, math.inf, "det(I + P2~ P1) vanishes at infinity (I + P2(inf)^T P1(inf) is "
                                             "singular)", "state space")
    zeros = statespace.zeros_square(product)
    on_axis = _on_axis(zeros)
    if np.any(on_axis):
        w = float(np.min(np.abs(zeros[on_axis].imag)))
        return WindingCheck(False, w, f"det(I + P2~ P1) vanishes at w = {w:.6g} rad/s", "state space")
    right = int(np.sum(zeros.real > 0.0))
    if right == n2:
        return WindingCheck(True, method="state space")
    return WindingCheck(False, math.nan, f"winding number {n2 - right} != 0 (unstable pole/zero counts do not "
                                         f"match)", "state space")


def _winding_numerical(n1: np.ndarray, d1: np.ndarray, n2: np.ndarray, d2: np.ndarray,
                       delta_s: float) -> WindingCheck:
    deg1, deg2 = len(d1) - 1, len(d2) - 1
    k1 = n1[0] / d1[0] if len(n1) == len(d1) else 0.0
    k2 = n2[0] / d2[0] if len(n2) == len(d2) else 0.0
    if abs(k1 * k2) >= 1.0:
        return WindingCheck(False, math.inf, "|P1(inf) P2(inf)| >= 1 with different delays: the winding number "
                                             "is not defined", "numerical")
    # rho = d2(-s) d1(s) + n2(-s) n1(s) exp(s delta)
    turns, where = axis_turns(np.polymul(_mirror(d2), d1), np.polymul(_mirror(n2), n1), delta_s, k1 * k2,
                              np.concatenate([_roots(d1), -_roots(d2)]),
                              np.concatenate([_roots(p) for p in (d1, d2, n1, n2)]))
    if turns is None:
        if math.isnan(where):
            return WindingCheck(False, math.nan, "phase of 1 + P2~ P1 could not be resolved", "numerical")
        text = "at w = 0" if where == 0.0 else f"near w = {where:.6g} rad/s"
        return WindingCheck(False, where, f"1 + P2~ P1 vanishes {text}", "numerical")
    if abs(turns - (deg1 - deg2) / 2.0) < 0.25:
        return WindingCheck(True, method="numerical")
    return WindingCheck(False, math.nan, "winding number of 1 + P2~ P1 does not match the unstable poles",
                        "numerical")


def axis_turns(a: ArrayLike, b: ArrayLike, delta_s: float, k_inf: float, a_roots: ArrayLike,
               hint_roots: ArrayLike = ()) -> tuple[float | None, float]:
    """Turns of ``f(j w) = a(j w) + b(j w) exp(j w delta_s)`` around 0 as w runs over the whole real line.

    The quasi-polynomial's phase is unwrapped on an adaptive grid over (0, w_hi) (logarithmic, linear at
    pi/4 of the delay's phase, points around every root; intervals whose phase jumps by more than pi/3 are
    halved), the tail beyond w_hi, where ``|b/a| <= (1 + |k_inf|)/2 < 1``, is the phase of a alone
    (analytic from its roots), and conjugate symmetry (real coefficients) doubles the half line. By the
    argument principle a retarded quasi-polynomial of degree N with Z zeros in the open right half plane and
    none on the axis turns ``N/2 - Z`` times (the nu-gap's winding condition; a closed loop with a delay,
    Nyquist).

    Parameters
    ----------
    a, b : array_like
        Real polynomial coefficients, descending powers of s; ``deg b <= deg a``.
    delta_s : float
        The exponent's coefficient [s] (nonzero; negative for a delay ``exp(-s T)``).
    k_inf : float
        ``lim b(s)/a(s)`` as s -> infinity; ``|k_inf| < 1``.
    a_roots : array_like
        The roots of a (for the analytic tail).
    hint_roots : array_like
        Roots whose neighbourhoods the grid resolves (e.g. poles and zeros).

    Returns
    -------
    turns : float or None
        Turns over the whole axis; None when f vanishes on the axis (within the grid's resolution) or the
        phase cannot be resolved.
    w_zero_rad_s : float
        Where f vanishes (nan when it does not, or when the phase was unresolved).
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    a_roots = np.asarray(a_roots, dtype=complex)
    roots = np.concatenate([np.asarray(hint_roots, dtype=complex), a_roots])
    w_top = max(1.0, float(np.max(np.abs(roots)))) if roots.size else 1.0
    w_hi = 1e3 * w_top
    limit = 0.5 * (1.0 + abs(k_inf))

    def f_x(w: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        s = 1j * np.asarray(w, dtype=float)
        aa = np.polyval(a, s)
        bb = np.polyval(b, s) * np.exp(s * delta_s)
        with np.errstate(divide="ignore", invalid="ignore"):
            return aa + bb, bb / aa

    for _ in range(60):
        if abs(f_x(w_hi)[1]) <= limit:
            break
        w_hi *= 2.0
    if float(np.real(f_x(0.0)[0])) == 0.0:
        return None, 0.0
    w_lo = 1e-6 * min([abs(r) for r in roots if abs(r) > 0] + [1.0])
    grid = [np.array([0.0]), np.geomspace(w_lo, w_hi, int(_GRID_PER_DECADE * math.log10(w_hi / w_lo)) + 2)]
    step = math.pi / (4.0 * abs(delta_s))
    grid.append(np.linspace(0.0, w_hi, min(int(w_hi / step) + 2, 200_000)))
    grid.append(_resonance_points(roots))
    w = np.unique(np.concatenate(grid))
    w = w[(w >= 0.0) & (w <= w_hi)]
    phase = np.angle(f_x(w)[0])
    for _ in range(60):
        jump = np.abs(_wrap(np.diff(phase)))
        bad = np.flatnonzero(jump > math.pi / 3.0)
        if bad.size == 0:
            break
        width = w[bad + 1] - w[bad]
        if np.any(width <= 1e-13 * np.maximum(w[bad + 1], 1e-300)):
            return None, float(w[bad[np.argmin(width)]])
        mids = 0.5 * (w[bad] + w[bad + 1])
        w = np.insert(w, bad + 1, mids)
        phase = np.insert(phase, bad + 1, np.angle(f_x(mids)[0]))
    else:
        return None, math.nan
    total = float(np.sum(_wrap(np.diff(phase))))
    tail = float(sum(_wrap(math.pi / 2 - np.angle(1j * w_hi - r)) for r in a_roots))
    tail -= float(np.angle(1.0 + f_x(w_hi)[1]))
    return (total + tail) / math.pi, math.nan


def _wrap(angle: ArrayLike) -> np.ndarray:
    return (np.asarray(angle) + math.pi) % (2.0 * math.pi) - math.pi


def _resonance_points(roots: np.ndarray) -> np.ndarray:
    """Frequencies around every complex root: |Im| +- a few multiples of |Re|."""
    points = []
    for root in roots:
        if root.imag > 0.0 or (root.imag == 0.0 and root.real != 0.0):
            centre = abs(root.imag) if root.imag > 0.0 else abs(root.real)
            width = max(abs(root.real), 1e-9 * max(centre, 1.0))
            points.append(centre + width * np.linspace(-6.0, 6.0, 49))
            points.append(abs(root) * np.array([1.0]))
    if not points:
        return np.zeros(0)
    points = np.concatenate(points)
    return points[points > 0.0]


# ----------------------------------------------------------------------------------------------------------
# exact sup over frequency
# ----------------------------------------------------------------------------------------------------------


def _axis_points(roots: np.ndarray) -> np.ndarray:
    """Frequencies on both sides of every root on the positive imaginary axis, geometrically closer.

    Two models sharing an undamped pole can have their largest chordal distance a hair to either side of it;
    the offsets run from 1e-9 to 0.5 of the root's frequency.
    """
    roots = np.asarray(roots, dtype=complex)
    centres = np.unique(roots[(roots.imag > 0.0) & _on_axis(roots)].imag)
    if centres.size == 0:
        return np.zeros(0)
    return np.concatenate([centres[:, None] * (1.0 - _AXIS_OFFSETS), centres[:, None] * (1.0 + _AXIS_OFFSETS)],
                          axis=1).ravel()


def _combined(a: ArrayLike, b: ArrayLike, sign: float = 1.0) -> np.ndarray:
    """``a + sign b`` with every coefficient that cancels to round-off of its operands set to exactly 0.

    Leading coefficients that cancel (``P1(inf) = P2(inf)`` in ``n2 d1 - n1 d2``, ``|P(inf)| = 1`` in
    ``n n~ - d d~``) would otherwise give spurious roots near 1e15; trailing ones give exact roots at 0.
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    size = max(a.size, b.size)
    a = np.concatenate([np.zeros(size - a.size), a])
    b = np.concatenate([np.zeros(size - b.size), b])
    total = a + sign * b
    return np.where(np.abs(total) <= 64 * np.finfo(float).eps * (np.abs(a) + np.abs(b)), 0.0, total)


def _feature_roots(model: LinearModel) -> np.ndarray:
    """Poles, zeros and the roots of ``n n~ + d d~`` and ``n n~ - d d~`` of a model.

    ``|n(jw)|^2 + |d(jw)|^2`` is the denominator of the chordal distance (its roots are the corner
    frequencies of ``1 + |P|^2``) and the real roots of ``|n(jw)|^2 - |d(jw)|^2`` are the gain crossovers
    ``|P(jw)| = 1``, where two models' chordal distance peaks when their gains differ (1e-6/s vs 2e-6/s
    peaks at 1.4e-6 rad/s, far from any pole or zero).
    """
    num, den = _strip(model.num), _strip(model.den)
    nn = np.polymul(num, _mirror(num))
    dd = np.polymul(den, _mirror(den))
    return np.concatenate([model.poles(), model.zeros(), _roots(_combined(nn, dd)), _roots(_combined(nn, dd, -1.0))])


def _pair_roots(m1: LinearModel, m2: LinearModel) -> np.ndarray:
    """Every frequency feature of a pair: each model's :func:`_feature_roots` and, with equal delays, the zeros
    of ``P2 - P1`` and of ``P2 + P1`` (the numerator and denominator of epsilon, eq. 14)."""
    parts = [_feature_roots(m1), _feature_roots(m2)]
    if m1.delay_s == m2.delay_s:
        cross1, cross2 = np.polymul(m2.num, m1.den), np.polymul(m1.num, m2.den)
        parts += [_roots(_combined(cross1, cross2, -1.0)), _roots(_combined(cross1, cross2))]
    return np.concatenate(parts)


def _analysis_grid(roots: ArrayLike, delta_s: float = 0.0) -> np.ndarray:
    """Frequencies [rad/s] resolving every feature: a logarithmic grid from 1e-4 of the smallest to 1e4 times the
    largest root magnitude (and 1/delta_s), points around lightly damped roots and on both sides of roots on
    the imaginary axis, and a linear grid at pi/8 of the delay's phase."""
    roots = np.asarray(roots, dtype=complex)
    roots = roots[np.isfinite(roots)]
    magnitudes = np.abs(roots)
    magnitudes = magnitudes[magnitudes > 0.0]
    w_min = float(magnitudes.min()) if magnitudes.size else 1.0
    w_max = float(magnitudes.max()) if magnitudes.size else 1.0
    delta_s = abs(delta_s)
    if delta_s > 0.0:
        w_min = min(w_min, 1.0 / delta_s)
        w_max = max(w_max, 1.0 / delta_s)
    w_lo, w_hi = 1e-4 * w_min, 1e4 * w_max
    parts = [np.geomspace(w_lo, w_hi, int(_GRID_PER_DECADE * math.log10(w_hi / w_lo)) + 2),
             _resonance_points(roots), _axis_points(roots)]
    if delta_s > 0.0:
        step = math.pi / (8.0 * delta_s)
        parts.append(np.arange(1, min(int(w_hi / step), 100_000) + 1) * step)
    w = np.unique(np.concatenate(parts))
    w = w[(w >= w_lo) & (w <= w_hi)]
    # points within round-off of each other (the same root from several polynomials) would tie as false peaks
    return w[np.concatenate([[True], np.diff(w) > 1e-12 * w[1:]])] if w.size else w


def _grid_peaks(fun: Response, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Values of fun on the grid and the indices of its local maxima (NaN counts as -inf)."""
    values = fun(w)
    values = np.where(np.isnan(values), -np.inf, values)
    padded = np.concatenate([[-np.inf], values, [-np.inf]])
    is_peak = (padded[1:-1] >= padded[:-2]) & (padded[1:-1] >= padded[2:]) & np.isfinite(padded[1:-1]) | \
        (values == np.inf)
    return values, np.flatnonzero(is_peak)


def _refine(fun: Response, w: np.ndarray, values: np.ndarray, k: int) -> tuple[float, float]:
    """Maximise fun between the grid neighbours of index k (bounded scalar search in ln w).

    The bracket reaches out to the nearest neighbours with a lower value on each side: with equal neighbours
    (a grid point repeated within rounding, or a flat top) the peak may lie beyond the adjacent point.
    """
    i, j = max(k - 1, 0), min(k + 1, w.size - 1)
    while i > 0 and values[i] >= values[k]:
        i -= 1
    while j < w.size - 1 and values[j] >= values[k]:
        j += 1
    lo, hi = w[i], w[j]
    centre = w[k]
    value, where = float(values[k]), float(centre)
    if hi > lo and math.isfinite(value):
        from scipy.optimize import minimize_scalar   # scipy.optimize costs 0.6 s at import: only when used
        result = minimize_scalar(lambda x: -float(fun(np.array([centre * math.exp(x)]))[0]),
                                 bounds=(math.log(lo / centre), math.log(hi / centre)), method="bounded",
                                 options={"xatol": _REFINE_XATOL, "maxiter": 500})
        if -result.fun >= value:
            value, where = float(-result.fun), float(centre * math.exp(result.x))
    return value, where


def _refined_sup(fun: Response, w: np.ndarray) -> tuple[float, float]:
    """Sup of fun over the grid's range: local maxima refined by bounded scalar maximisation in ln(w).

    The grid local maxima within 30 % of the highest are refined (the 40 highest and the 10 lowest in
    frequency); among equal peaks (e.g. periodic in w because of a delay) the lowest frequency is reported.
    """
    values, peaks = _grid_peaks(fun, w)
    if peaks.size == 0:
        return -math.inf, math.nan
    top = values[peaks].max()
    if np.isinf(top):
        return math.inf, float(w[peaks[values[peaks] == np.inf][0]])
    close = peaks[values[peaks] >= top - 0.3 * abs(top) - 1e-12]
    highest = close[np.argsort(values[close])[::-1]][:_MAX_CANDIDATES]
    keep = np.union1d(highest, close[:10])  # also the lowest-frequency ones (equal periodic peaks)
    results = [_refine(fun, w, values, k) for k in keep]
    best_value = max(value for value, _ in results)
    ties = [where for value, where in results if value >= best_value - _TIE_RTOL * max(1.0, abs(best_value))]
    return best_value, min(ties)


def _first_huge(fun: Response, w: np.ndarray, threshold: float) -> float:
    """Lowest frequency where a refined local maximum of fun reaches ``threshold`` (nan if none)."""
    values, peaks = _grid_peaks(fun, w)
    for k in peaks[values[peaks] >= 1e3]:  # ascending frequency
        value, where = _refine(fun, w, values, k)
        if value >= threshold:
            return where
    return math.nan


def _sup_with_ends(fun: Response, at_zero: float, at_infinity: float, w: np.ndarray) -> tuple[float, float]:
    """Sup over the grid's range, w = 0 and w -> infinity: the largest of the three values. It is reported at
    w = 0 when that ties with the grid's peak (within 1e-9 relative), at infinity only when the limit there is
    above both by more than that (a peak creeping up to its limit keeps its frequency, with the limit's value)."""
    value, where = _refined_sup(fun, w)
    if not math.isnan(at_zero) and at_zero >= value - _TIE_RTOL * max(1.0, abs(value)):
        value, where = max(at_zero, value), 0.0
    if at_infinity > value + _TIE_RTOL * max(1.0, abs(value)):
        value, where = at_infinity, math.inf
    return max(value, at_infinity), where


def _shape(model: LinearModel | MimoModel) -> tuple[int, int]:
    return tuple(getattr(model, "shape", (1, 1)))


def _siso_or_state_space(m1: LinearModel | MimoModel, m2: LinearModel | MimoModel) -> tuple[
        tuple[LinearModel, LinearModel] | None, tuple[statespace.StateSpace, statespace.StateSpace] | None]:
    """Two SISO models, or minimal realizations of two MIMO models of the same shape."""
    shape1, shape2 = _shape(m1), _shape(m2)
    if shape1 != shape2:
        raise ValueError(f"models of different shapes ({shape1[0]}x{shape1[1]} and {shape2[0]}x{shape2[1]} "
                         f"outputs x inputs) have no nu-gap")
    if shape1 == (1, 1):
        return (_siso(m1), _siso(m2)), None
    return None, (m1.minimal_state_space(), m2.minimal_state_space())


def _siso(model: LinearModel | MimoModel) -> LinearModel:
    return model if not hasattr(model, "shape") else model.siso()


def nugap(m1: LinearModel | MimoModel, m2: LinearModel | MimoModel) -> tuple[float, float]:
    """Exact nu-gap of two LTI models (Vinnicombe 2001; paper eq. 13 with the winding-number condition).

    SISO models (delays allowed) use the exact polynomial path (module docstring); MIMO models the state-space
    path: ``sup_w kappa(w)`` with ``kappa(w) = sigma_max((I + P2 P2*)^-1/2 (P2 - P1) (I + P1* P1)^-1/2)``
    is the H-infinity norm of ``Gt2 G1`` (normalised coprime factors), located by the level-set iteration
    and refined to 1e-6 relative in frequency. The nu-gap is invariant under constant unitary changes of
    input and output coordinates (``U P V`` for both models); for block-diagonal models it is the largest of
    the blocks' nu-gaps unless two blocks fail the winding condition in opposite directions (the condition is
    on the determinant, so their winding numbers cancel).

    Either argument may be measured data instead (:mod:`~gap_validation.core.frd`: a ``(w_rad_s, response)``
    pair, an estimate, a ``ChannelResult``, a python-control FRD): then the sup is over the data's frequencies,
    the condition assumed (:func:`nugap_frequency_data`).

    Parameters
    ----------
    m1, m2 : LinearModel, MimoModel or measured data
        Model and second model (or data), of the same shape (outputs x inputs).

    Returns
    -------
    value : float
        sup over w >= 0 (and w -> inf) of the chordal distance when :func:`winding_condition` holds, else 1.
    w_peak_rad_s : float
        Frequency of the sup [rad/s] (``inf`` for the limit at infinity); when the condition fails, where
        1 + P2~ P1 vanishes, or nan when the failure is a winding-number mismatch.

    Raises
    ------
    ValueError
        Models of different shapes; data on different frequencies.

    Examples
    --------
    The paper's pitch model against the same model with a 20 % higher gain, exactly and over measured points:

    >>> from gap_validation.core.models import LinearModel
    >>> p1 = LinearModel.from_tf([40.0], [1.0, 12.0, 40.0])
    >>> p2 = LinearModel.from_tf([48.0], [1.0, 12.0, 40.0])
    >>> value, w_peak = nugap(p1, p2)
    >>> round(value, 4), round(w_peak, 3)
    (0.0909, 2.159)
    >>> w = np.logspace(-1, 2, 200)
    >>> round(nugap(p1, (w, p2.freqresp(w)))[0], 4)
    0.0909
    """
    pair = paired_responses(m1, m2)
    if pair is not None:
        return nugap_frequency_data(*pair)
    siso, systems = _siso_or_state_space(m1, m2)
    if systems is not None:
        value, where, _ = _nugap_state_space(*systems)
        return value, where
    m1, m2 = siso
    check = winding_condition(m1, m2)
    if not check.satisfied:
        return 1.0, check.frequency_rad_s
    w = _analysis_grid(_pair_roots(m1, m2), m2.delay_s - m1.delay_s)
    fun = lambda x: _kappa_models(m1, m2, x)  # noqa: E731
    value, where = _sup_with_ends(fun, float(fun(np.array([0.0]))[0]), _kappa_at_infinity(m1, m2), w)
    return min(max(value, 0.0), 1.0), where


def _nugap_state_space(s1: statespace.StateSpace, s2: statespace.StateSpace) -> tuple[float, float, WindingCheck]:
    """nu-gap of two minimal realizations: the winding condition on det(G2~ G1), then ||Gt2 G1||_inf."""
    g1 = statespace.right_ncf(s1)
    check = _winding_state_space(g1, statespace.right_ncf(s2), s2[0].shape[0])
    if not check.satisfied:
        return 1.0, check.frequency_rad_s, check
    value, where = statespace.hinf_norm(statespace.series(g1, statespace.left_ncf(s2)))
    return min(max(value, 0.0), 1.0), where, check


def epsilon(m1: LinearModel | MimoModel, m2: LinearModel | MimoModel) -> tuple[float, float]:
    """Exact sup over frequency of the overbounding-disk radius ``|P2 - P1| / |P2 + P1|`` (eq. 14).

    The disk of eq. 14 is a SISO notion; 1 x 1 MIMO models are taken as SISO. Either argument may be measured
    data (as for :func:`nugap`): the sup is then over the data's frequencies (:func:`epsilon_frequency_data`).

    Parameters
    ----------
    m1, m2 : LinearModel, MimoModel or measured data
        SISO models (or 1 x 1), or data.

    Returns
    -------
    value : float
        sup over w >= 0 (and w -> inf); ``inf`` when P2 = -P1 at some frequency. Values >= 1 mean that
        no stability margin is guaranteed.
    w_peak_rad_s : float
        Frequency of the sup [rad/s] (``inf`` for the limit at infinity).

    Raises
    ------
    ValueError
        For MIMO models (no epsilon disk: compare them by the nu-gap); data on different frequencies.
    """
    pair = paired_responses(m1, m2)
    if pair is not None:
        if np.ndim(pair[1]) > 1 or np.ndim(pair[2]) > 1:
            raise ValueError("epsilon (eq. 14) is defined for SISO responses; compare MIMO data by the nu-gap")
        return epsilon_frequency_data(*pair)
    if _shape(m1) != (1, 1) or _shape(m2) != (1, 1):
        raise ValueError("epsilon (eq. 14) is defined for SISO models; compare MIMO models by the nu-gap")
    m1, m2 = _siso(m1), _siso(m2)
    if m1.delay_s == m2.delay_s:
        total = np.polyadd(np.polymul(m2.num, m1.den), np.polymul(m1.num, m2.den))
        extra = _roots(total)
        on_axis = extra[np.abs(extra.real) <= _AXIS_RTOL * np.maximum(np.abs(extra), 1.0)]
        if on_axis.size:
            w = float(np.min(np.abs(on_axis.imag)))
            if np.isinf(_epsilon_models(m1, m2, np.array([w]))[0]) or \
                    _epsilon_models(m1, m2, np.array([w]))[0] > 1e6:
                return math.inf, w
    w = _analysis_grid(_pair_roots(m1, m2), m2.delay_s - m1.delay_s)
    fun = lambda x: _epsilon_models(m1, m2, x)  # noqa: E731
    value, where = _refined_sup(fun, w)
    if value >= _HUGE_EPSILON:
        first = _first_huge(fun, w, _HUGE_EPSILON)
        return math.inf, where if math.isnan(first) else first
    return _sup_with_ends(fun, _epsilon_at_zero(m1, m2), _epsilon_at_infinity(m1, m2), w)


# ----------------------------------------------------------------------------------------------------------
# Theil inequality coefficient
# ----------------------------------------------------------------------------------------------------------


def tic(y1: ArrayLike, y2: ArrayLike) -> float:
    """Theil inequality coefficient of two sampled time histories (paper eqs. 1-2).

    ``TIC = sqrt(mean((y1 - y2)^2)) / (sqrt(mean(y1^2)) + sqrt(mean(y2^2)))``, between 0 (identical) and 1.
    (The denominator is the sum of the two RMS values, equivalent to eq. 2; 0 when both are zero.)

    Parameters
    ----------
    y1, y2 : array_like
        Simulated and measured outputs at the same samples.

    Returns
    -------
    float
    """
    y1 = np.asarray(y1, dtype=float).ravel()
    y2 = np.asarray(y2, dtype=float).ravel()
    if y1.shape != y2.shape:
        raise ValueError(f"tic: y1 and y2 differ in length ({y1.size} != {y2.size})")
    denominator = math.sqrt(np.mean(y1 * y1)) + math.sqrt(np.mean(y2 * y2))
    if denominator == 0.0:
        return 0.0
    return float(math.sqrt(np.mean((y1 - y2) ** 2)) / denominator)


def tic_input_augmented(y1: ArrayLike, y2: ArrayLike, u: ArrayLike) -> float:
    """TIC of the input-output pairs [u; y1] and [u; y2] (paper eq. 3).

    ``||y1 - y2|| / (||[u; y1]|| + ||[u; y2]||)``: the common input only enlarges the denominator.

    Parameters
    ----------
    y1, y2 : array_like
        Simulated and measured outputs.
    u : array_like
        The input applied to both, same samples.

    Returns
    -------
    float
    """
    y1 = np.asarray(y1, dtype=float).ravel()
    y2 = np.asarray(y2, dtype=float).ravel()
    u = np.asarray(u, dtype=float).ravel()
    if not y1.shape == y2.shape == u.shape:
        raise ValueError("tic_input_augmented: y1, y2 and u must have the same length")
    uu = float(np.mean(u * u))
    denominator = math.sqrt(uu + np.mean(y1 * y1)) + math.sqrt(uu + np.mean(y2 * y2))
    if denominator == 0.0:
        return 0.0
    return float(math.sqrt(np.mean((y1 - y2) ** 2)) / denominator)
