"""Distances between models and data: chordal distance, nu-gap, overbounding epsilon, Theil coefficient.

Paper: "Validating Aircraft Models in the Gap Metric" (eqs. 1, 3, 13, 14); nu-gap after Vinnicombe
(*Uncertainty and Feedback: H-infinity loop-shaping and the nu-gap metric*, Imperial College Press, 2001).

Each metric returns its value and the frequency where it peaks [rad/s]. For frequency-response *data* the sup
is over the given points and the winding-number condition of the nu-gap is assumed (as the paper does). For
two models the results are exact. SISO :class:`~gap_validation.core.models.LinearModel` pairs (delays
allowed):

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
import threading
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

from gap_validation.core import statespace
from gap_validation.core.frd import paired_responses
from gap_validation.core.models import LinearModel, MimoModel, strip_leading_zeros

#: A real function of frequency [rad/s], vectorised (kappa(w) or epsilon(w) of two models).
Response = Callable[[np.ndarray], np.ndarray]

_AXIS_RTOL = 1e-8  # roots closer than this (relative) to the imaginary axis are on it
_CANCEL_RTOL = 1e-6  # numerator and denominator roots closer than this (relative) cancel
_GRID_PER_DECADE = 300
_REFINE_XATOL = 1e-10  # bounded refinement tolerance in ln(w)
_MAX_CANDIDATES = 40
_GOLDEN = (3.0 - math.sqrt(5.0)) / 2.0  # golden-section fraction of Brent's method
_SQRT_EPS = math.sqrt(np.finfo(float).eps)
_CANCEL_EPS = 64 * np.finfo(float).eps  # sums of coefficients this small relative to their terms are 0
_TIE_RTOL = 1e-9  # peaks equal to this (relative) are the same height: the lowest frequency is reported
_HUGE_EPSILON = 1e10  # a refined epsilon peak above this is a crossing of P2 = -P1: reported as inf
_AXIS_OFFSETS = np.geomspace(1e-9, 0.5, 180)  # relative offsets sampled on both sides of roots on the axis
_AXIS_BELOW, _AXIS_ABOVE = 1.0 - _AXIS_OFFSETS, 1.0 + _AXIS_OFFSETS
_RESONANCE_OFFSETS = np.linspace(-6.0, 6.0, 49)  # multiples of |Re| sampled around complex roots
_J_SIGNS = np.array([1.0, 1.0, -1.0, -1.0] * 64)   # (-1)^(k // 2), k = 0 ... 255: the real sign of j^k
_SINGULAR_D_COND = 1e12  # det(G2~ G1) at infinity is taken as zero beyond this condition number
# |n|^2 + |d|^2 of both models within this range on a whole grid: kappa's products neither overflow nor lose
# digits to underflow (|n2 d1 - n1 d2|^2 <= the product of the two), the parts need no scaling
_SIZE_RANGE = (1e-75, 1e140)


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


def inv_sqrt_gram(p: np.ndarray, side: str) -> np.ndarray:
    """``(I + P P*)^-1/2`` (side "left") or ``(I + P* P)^-1/2`` (side "right") of a stack of matrices.

    From the singular values of P: no cancellation when P is huge (e.g. next to a pole on the axis).

    Parameters
    ----------
    p : ndarray of complex
        Matrices ``(..., rows, columns)``.
    side : {"left", "right"}
        ``(I + P P*)^-1/2`` (rows x rows) or ``(I + P* P)^-1/2`` (columns x columns).

    Returns
    -------
    ndarray of complex
        One Hermitian matrix per matrix of ``p``.
    """
    u, s, vh = np.linalg.svd(p, full_matrices=True)
    basis = u if side == "left" else np.conj(np.swapaxes(vh, -1, -2))
    weights = np.ones(basis.shape[:-1])
    weights[..., :s.shape[-1]] = 1.0 / np.sqrt(1.0 + s * s)
    return (basis * weights[..., None, :]) @ np.conj(np.swapaxes(basis, -1, -2))


def _chordal_distance_matrices(p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Vinnicombe's pointwise chordal distance of stacks of p x m matrices (nan where an entry is not
    finite)."""
    shape = p1.shape[:-2]
    p1 = p1.reshape((-1,) + p1.shape[-2:])
    p2 = p2.reshape((-1,) + p2.shape[-2:])
    out = np.full(p1.shape[0], np.nan)
    ok = np.all(np.isfinite(p1), axis=(1, 2)) & np.all(np.isfinite(p2), axis=(1, 2))
    if np.any(ok):
        a, b = p1[ok], p2[ok]
        psi = inv_sqrt_gram(b, "left") @ (b - a) @ inv_sqrt_gram(a, "right")
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


def _polymul(a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """:func:`numpy.polymul` of coefficient arrays (leading zeros dropped, as it does), without its poly1d."""
    return np.convolve(strip_leading_zeros(a), strip_leading_zeros(b))


def mirror(poly: ArrayLike) -> np.ndarray:
    """Coefficients of p(-s) from those of p(s) (descending powers).

    Parameters
    ----------
    poly : array_like of float
        Coefficients of p(s), descending powers of s.

    Returns
    -------
    ndarray of float
    """
    out = np.array(poly, dtype=float)
    if out.ndim == 1:
        out[-2::-2] *= -1.0   # the odd powers
        return out
    return out * (-1.0) ** np.arange(out.shape[-1] - 1, -1, -1)


def polynomial_roots(poly: ArrayLike) -> np.ndarray:
    """Roots of a real polynomial: the eigenvalues of its companion matrix, as :func:`numpy.roots` has them.

    Parameters
    ----------
    poly : array_like of float
        Coefficients, descending powers of s (leading zeros ignored).

    Returns
    -------
    ndarray
        The roots (real when all are; empty, complex, for a constant); trailing zero coefficients give exact
        roots at 0.
    """
    poly = strip_leading_zeros(poly)
    if len(poly) <= 1 or poly[0] == 0.0:
        return np.array([], dtype=complex)
    degree = len(poly) - 1   # then without the roots at 0
    while poly[degree] == 0.0:
        degree -= 1
    if degree == 0:
        roots = np.zeros(0)
    elif degree == 1:
        roots = np.array([-poly[1] / poly[0]])
    else:
        companion = _shift(degree)
        np.divide(poly[1:degree + 1], -poly[0], out=companion[0])
        roots = _eigenvalues(companion)
    trailing = len(poly) - 1 - degree
    return np.concatenate([roots, np.zeros(trailing)]) if trailing else roots


_SHIFTS: dict[int, np.ndarray] = {}


def _shift(size: int) -> np.ndarray:
    """A fresh copy of ``numpy.eye(size, k=-1)`` (the companion matrix's ones below the diagonal)."""
    shift = _SHIFTS.get(size)
    if shift is None:
        shift = _SHIFTS[size] = np.eye(size, k=-1)
    return shift.copy()


def _eigenvalues(matrix: np.ndarray) -> np.ndarray:
    """:func:`numpy.linalg.eigvals` of a real square matrix (real when every eigenvalue is), by the same
    LAPACK routine (dgeev) called directly: without numpy's checks, half the time for the small companion
    matrices of the nu-gap."""
    if np.isfinite(matrix).all():
        real, imag, _, _, info = scipy.linalg.lapack.dgeev(matrix, compute_vl=0, compute_vr=0)
        if info == 0:
            return real if not imag.any() else _complex(real, imag)
    return np.linalg.eigvals(matrix)   # raises numpy's errors (non-finite entries, no convergence)


def _even_roots(poly: np.ndarray) -> np.ndarray:
    """Roots of a polynomial in s whose odd powers are round-off (``n(s) n(-s) +- d(s) d(-s)``): the square
    roots of the roots of its even part as a polynomial in s^2 (half the degree, the +-s symmetry exact)."""
    poly = strip_leading_zeros(poly)
    if len(poly) <= 1:
        return np.array([], dtype=complex)
    even = poly[(len(poly) - 1) % 2::2]
    # odd degree: its leading coefficient is round-off, its roots near infinity spurious
    if len(poly) % 2 == 0:
        even = strip_leading_zeros(even)
    half = np.sqrt(polynomial_roots(even).astype(complex))
    return np.concatenate([half, -half])


def coprime(num: ArrayLike, den: ArrayLike, zeros: ArrayLike | None = None,
            poles: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Cancel the common roots of num and den (relative tolerance 1e-6); P = 0 becomes 0/1.

    Parameters
    ----------
    num, den : array_like of float
        Numerator and denominator, descending powers of s.
    zeros, poles : array_like, optional
        Their roots (:func:`polynomial_roots`) when already computed.

    Returns
    -------
    num, den : ndarray of float
        Without the common factors; ``den`` monic.
    """
    num, den = strip_leading_zeros(num), strip_leading_zeros(den)
    if not num.any():
        return np.array([0.0]), np.array([1.0])
    zeros = polynomial_roots(num) if zeros is None else np.asarray(zeros)
    poles = polynomial_roots(den) if poles is None else np.asarray(poles)
    if not zeros.size or not poles.size or not (
            np.abs(zeros[:, None] - poles) <= _CANCEL_RTOL * np.maximum(np.abs(poles), 1.0)).any():
        return num, den / den[0]   # no zero close enough to any pole
    zeros, poles = list(zeros), list(poles)
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


def _even_odd(poly: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """E and O with ``p(j w) = E(w^2) + j w O(w^2)`` (descending powers of w^2), p in descending powers of s.

    Half the operations of Horner's rule in s, and in real arithmetic.
    """
    coefficients = np.asarray(poly, dtype=float).ravel()[::-1]   # ascending powers k
    size = coefficients.size   # j^k = (-1)^(k // 2) j^(k % 2)
    signed = coefficients * (_J_SIGNS[:size] if size <= _J_SIGNS.size else np.resize(_J_SIGNS[:4], size))
    return signed[0::2][::-1], signed[1::2][::-1]


def _complex(real: np.ndarray, imag: np.ndarray) -> np.ndarray:
    out = np.empty(real.shape, dtype=complex)
    out.real, out.imag = real, imag
    return out


_CHUNK = 8192   # frequencies evaluated at once by a _PairResponse
_SCRATCH = threading.local()


def _scratch(rows: int) -> np.ndarray:
    """This thread's scratch array of :class:`_PairResponse`, at least ``rows`` x 8192 (1.6 MB; kept:
    fresh arrays of this size cost page faults on every call, more than the arithmetic)."""
    array = getattr(_SCRATCH, "array", None)
    if array is None or array.shape[0] < rows:
        array = _SCRATCH.array = np.empty((max(rows, 24), _CHUNK))
    return array


class _PairResponse:
    """kappa(w) (eq. 13) or epsilon(w) (eq. 14) of two SISO models: vectorised over a grid (``__call__``) and
    at single frequencies (:meth:`at`, for the refinement).

    The numerators and denominators are evaluated on s = j w from their even and odd parts
    (:func:`_even_odd`): on a grid as one matrix product with the powers of w^2, at one frequency by Horner's
    rule. Each model's numerator (delay included) and denominator are divided by the largest magnitude of
    their real and imaginary parts at every frequency: the products stay finite at high frequency, the ratios
    are unchanged (on a grid whose ``|n|^2 + |d|^2`` all lie within 1e-75 .. 1e140, kappa needs no such
    scaling and is computed without it). On the grid the eight real rows are laid out by part, then by model
    (n1 re, n2 re, n1 im, n2 im, d1 re, d2 re, d1 im, d2 im): each step is one operation on both models.
    """

    __slots__ = ("_epsilon", "_matrix", "_columns", "_delays")

    def __init__(self, m1: LinearModel, m2: LinearModel, epsilon_of: bool = False) -> None:
        self._epsilon = epsilon_of
        # rows n1 even, n2 even, n1 odd, n2 odd, d1 even, d2 even, d1 odd, d2 odd (leading zeros keep the
        # values of Horner's rule); columns descending powers of w^2
        polys = [np.asarray(poly, dtype=float).ravel() for poly in (m1.num, m2.num, m1.den, m2.den)]
        self._matrix = np.zeros((8, max(1, max((poly.size + 1) // 2 for poly in polys))))
        for row, poly in zip((0, 1, 4, 5), polys):
            for k, part in enumerate(_even_odd(poly)):
                if part.size:
                    self._matrix[row + 2 * k, -part.size:] = part
        self._columns = [tuple(column) for column in self._matrix.T.tolist()]
        self._delays = (m1.delay_s, m2.delay_s)

    def __call__(self, w: np.ndarray) -> np.ndarray:
        w = np.asarray(w, dtype=float).ravel()
        out = np.empty(w.size)
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            for start in range(0, w.size, _CHUNK):
                self._evaluate(w[start:start + _CHUNK], out[start:start + _CHUNK])
        return out

    def _evaluate(self, w: np.ndarray, out: np.ndarray) -> None:
        """The values at up to 8192 frequencies, into ``out``: in-place operations on rows of the scratch
        array, both models at once."""
        length, size = self._matrix.shape[1], w.size
        full = _scratch(max(12 + length, 20))   # few rows: they stay in the cache
        parts = full[:8, :size]
        by_part = full[:8].reshape(4, 2, _CHUNK)[:, :, :size]   # [n re, n im, d re, d im][model]
        work = full[8:12, :size]
        powers = full[12:12 + length, :size]   # the spare rows once the parts are evaluated
        spare = full[12:20].reshape(4, 2, _CHUNK)[:, :, :size]
        u = powers[-2] if length > 1 else work[0]
        np.multiply(w, w, out=u)
        top = float(u.max()) if size else 0.0
        if top <= 1.0 or (length - 1) * math.log10(top) < 300.0:
            for k in range(length - 3, -1, -1):   # rows u^(length - 1), ..., u^2, u, 1
                np.multiply(powers[k + 1], u, out=powers[k])
            powers[-1].fill(1.0)
            np.matmul(self._matrix, powers, out=parts)
        else:   # powers of w^2 that overflow: Horner's rule, row by row
            for part, coefficients in zip(parts, self._matrix):
                part.fill(0.0)
                for c in coefficients:
                    part *= u
                    part += c
        by_part[1] *= w   # the odd parts: imaginary parts
        by_part[3] *= w
        for k, delay_s in enumerate(self._delays):
            if delay_s:   # (re + j im) exp(-j w T)
                real, imag = parts[k], parts[2 + k]
                cos, sin = np.cos(w * delay_s), np.sin(w * delay_s)
                real[:], imag[:] = real * cos + imag * sin, imag * cos - real * sin
        if not self._epsilon:
            sizes = work[2:4]   # |n|^2 + |d|^2 of each model
            np.multiply(by_part, by_part, out=spare)
            np.add(spare[0], spare[1], out=sizes)
            sizes += spare[2]
            sizes += spare[3]
            if size and _SIZE_RANGE[0] <= sizes.min() and sizes.max() <= _SIZE_RANGE[1]:
                self._kappa(parts, spare, work, out)   # no overflow or underflow to fear: no scaling
                return
        scale = work[:2]   # each model's parts divided by their largest magnitude
        np.abs(by_part, out=spare)
        np.maximum.reduce(spare, axis=0, out=scale)
        np.copyto(scale, 1.0, where=scale == 0.0)
        np.divide(1.0, scale, out=scale)
        by_part *= scale
        if self._epsilon:
            n1r, n2r, n1i, n2i, d1r, d2r, d1i, d2i = parts
            p1 = _complex(n1r * d2r - n1i * d2i, n1r * d2i + n1i * d2r)
            p2 = _complex(n2r * d1r - n2i * d1i, n2r * d1i + n2i * d1r)
            out[:] = epsilon_per_frequency(p1, p2)
            return
        sizes = work[2:4]
        np.multiply(by_part, by_part, out=spare)
        np.add(spare[0], spare[1], out=sizes)
        sizes += spare[2]
        sizes += spare[3]
        self._kappa(parts, spare, work, out)

    @staticmethod
    def _kappa(parts: np.ndarray, spare: np.ndarray, work: np.ndarray, out: np.ndarray) -> None:
        """kappa from the eight parts and each model's ``|n|^2 + |d|^2`` (``work[2:4]``), into ``out``."""
        rr, ii, ri, ir = spare   # n2 d1 - n1 d2: the products [n1 x d2, n2 x d1] of each pair of parts
        np.multiply(parts[0:2], parts[5:3:-1], out=rr)
        np.multiply(parts[2:4], parts[7:5:-1], out=ii)
        np.multiply(parts[0:2], parts[7:5:-1], out=ri)
        np.multiply(parts[2:4], parts[5:3:-1], out=ir)
        cross = work[:2]
        real, imag = cross
        np.subtract(rr[1], ii[1], out=real)
        real -= rr[0]
        real += ii[0]
        np.add(ri[1], ir[1], out=imag)
        imag -= ri[0]
        imag -= ir[0]
        cross *= cross
        real += imag                              # |n2 d1 - n1 d2|^2
        work[2] *= work[3]
        np.divide(real, work[2], out=out)
        np.sqrt(out, out=out)
        np.minimum(out, 1.0, out=out)

    def at(self, w: float) -> float:
        """The value at one frequency [rad/s] (plain floats, Horner's rule; the vectorised path where they
        would overflow).

        Parameters
        ----------
        w : float
            Frequency [rad/s].

        Returns
        -------
        float
        """
        try:
            u = w * w
            # the eight parts at u by Horner's rule, together (leading zeros of the shorter ones keep them 0)
            n1r = n2r = n1i = n2i = d1r = d2r = d1i = d2i = 0.0
            for c0, c1, c2, c3, c4, c5, c6, c7 in self._columns:
                n1r, n2r, n1i, n2i = n1r * u + c0, n2r * u + c1, n1i * u + c2, n2i * u + c3
                d1r, d2r, d1i, d2i = d1r * u + c4, d2r * u + c5, d1i * u + c6, d2i * u + c7
            n1i, n2i, d1i, d2i = n1i * w, n2i * w, d1i * w, d2i * w   # the odd parts: imaginary parts
            delay1, delay2 = self._delays
            if delay1:   # (re + j im) exp(-j w T)
                cos, sin = math.cos(w * delay1), math.sin(w * delay1)
                n1r, n1i = n1r * cos + n1i * sin, n1i * cos - n1r * sin
            if delay2:
                cos, sin = math.cos(w * delay2), math.sin(w * delay2)
                n2r, n2i = n2r * cos + n2i * sin, n2i * cos - n2r * sin
            # each model's parts divided by their largest magnitude
            scale = max(abs(n1r), abs(n1i), abs(d1r), abs(d1i))
            if scale > 0.0:
                n1r, n1i, d1r, d1i = n1r / scale, n1i / scale, d1r / scale, d1i / scale
            scale = max(abs(n2r), abs(n2i), abs(d2r), abs(d2i))
            if scale > 0.0:
                n2r, n2i, d2r, d2i = n2r / scale, n2i / scale, d2r / scale, d2i / scale
            # n2 d1 -+ n1 d2
            a_r, a_i = n2r * d1r - n2i * d1i, n2r * d1i + n2i * d1r
            b_r, b_i = n1r * d2r - n1i * d2i, n1r * d2i + n1i * d2r
            cross_r, cross_i = a_r - b_r, a_i - b_i
            if self._epsilon:
                diff = math.hypot(cross_r, cross_i)
                total = math.hypot(a_r + b_r, a_i + b_i)
                return 0.0 if diff == 0.0 else diff / total if total != 0.0 else math.inf
            sizes = (n1r * n1r + n1i * n1i + d1r * d1r + d1i * d1i) * \
                (n2r * n2r + n2i * n2i + d2r * d2r + d2i * d2i)
            return min(math.sqrt((cross_r * cross_r + cross_i * cross_i) / sizes), 1.0)
        except (OverflowError, ZeroDivisionError, ValueError):
            with np.errstate(all="ignore"):
                return float(self(np.array([w]))[0])


def _high_frequency_form(model: LinearModel) -> tuple[float, int]:
    """(k, m): P(s) ~ k s^-m exp(-s T) as s -> infinity (k = 0 for P = 0)."""
    num, den = strip_leading_zeros(model.num), strip_leading_zeros(model.den)
    if num[0] == 0.0:
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
    num, den = strip_leading_zeros(model.num), strip_leading_zeros(model.den)
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

    For equal delays rho is a polynomial: the condition is that rho has full degree (1 + P2(inf) P1(inf) !=
    0), no root on the imaginary axis, exactly deg d1 roots in the open left and deg d2 in the open right half
    plane. With different delays the phase of rho is unwrapped on an adaptive grid over (0, w_hi), the tail
    beyond w_hi (past every root and where |P1 P2| < 1) is added analytically, and conjugate symmetry gives
    the whole axis.

    MIMO (method ``"state space"``): with minimal realizations and normalised right coprime factors G_i of
    order n_i (:func:`~gap_validation.core.statespace.right_ncf`), ``det(G2~ G1)`` has n1 stable and n2
    antistable poles; it must have no zero on the extended imaginary axis (``I + P2(inf)^T P1(inf)``
    nonsingular) and exactly n2 zeros in the open right half plane (the zeros of ``det`` are the eigenvalues
    of ``A - B D^-1 C`` of the product's realization). For 1 x 1 models this is the polynomial count above.

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
    return _winding_siso(*siso, _poles_zeros(siso[0]), _poles_zeros(siso[1]))


def _poles_zeros(model: LinearModel) -> tuple[np.ndarray, np.ndarray]:
    """Roots of a SISO model's denominator and numerator (computed once per nu-gap or epsilon)."""
    return polynomial_roots(model.den), polynomial_roots(model.num)


def _winding_siso(m1: LinearModel, m2: LinearModel, roots1: tuple[np.ndarray, np.ndarray],
                  roots2: tuple[np.ndarray, np.ndarray]) -> WindingCheck:
    """:func:`winding_condition` of two SISO models, given their (poles, zeros)."""
    n1, d1 = coprime(m1.num, m1.den, roots1[1], roots1[0])
    n2, d2 = coprime(m2.num, m2.den, roots2[1], roots2[0])
    delta_s = m2.delay_s - m1.delay_s
    if delta_s == 0.0:
        return _winding_algebraic(n1, d1, n2, d2)
    return _winding_numerical(n1, d1, n2, d2, delta_s)


def _winding_algebraic(n1: np.ndarray, d1: np.ndarray, n2: np.ndarray, d2: np.ndarray) -> WindingCheck:
    deg1, deg2 = len(d1) - 1, len(d2) - 1
    d_term = _polymul(mirror(d2), d1)
    n_term = _polymul(mirror(n2), n1)
    rho = np.add(*_aligned(d_term, n_term))
    lead_scale = abs(d_term[0]) + (abs(n_term[0]) if len(n_term) == len(d_term) else 0.0)
    if len(rho) < len(d_term) or abs(rho[-(deg1 + deg2 + 1)]) <= 1e-12 * lead_scale:
        return WindingCheck(False, math.inf, "1 + P2~ P1 vanishes at infinity (P1(inf) P2(inf) = -1)")
    roots = polynomial_roots(rho)
    axis = on_axis(roots)
    if axis.any():
        w = float(np.min(np.abs(roots[axis].imag)))
        return WindingCheck(False, w, f"1 + P2~ P1 vanishes at w = {w:.6g} rad/s")
    left = int(np.count_nonzero(roots.real < 0.0))
    right = roots.size - left
    if left == deg1 and right == deg2:
        return WindingCheck(True)
    return WindingCheck(False, math.nan, f"winding number {(left - right - deg1 + deg2) // 2} != 0 "
                                         f"(unstable pole/zero counts do not match)")


def on_axis(roots: np.ndarray) -> np.ndarray:
    """Which roots lie on the imaginary axis (relative tolerance 1e-8, absolute near the origin).

    Parameters
    ----------
    roots : ndarray of complex
        Roots (of a polynomial, or eigenvalues).

    Returns
    -------
    ndarray of bool
        One flag per root: ``|Re| <= 1e-8 max(|root|, 1e-3 max(1, max |root|))``.
    """
    magnitudes = np.abs(roots)
    scale = max(1.0, float(magnitudes.max())) if roots.size else 1.0
    return np.abs(roots.real) <= _AXIS_RTOL * np.maximum(magnitudes, 1e-3 * scale)


def _winding_state_space(g1: statespace.StateSpace, g2: statespace.StateSpace, n2: int) -> WindingCheck:
    """The condition from the normalised right coprime factors G1, G2 (n2 states in G2)."""
    product = statespace.series(g1, statespace.paraconjugate(g2))   # G2~ G1, m x m
    d = product[3]
    if d.size and np.linalg.cond(d) > _SINGULAR_D_COND:
        return WindingCheck(False, math.inf, "det(I + P2~ P1) vanishes at infinity (I + P2(inf)^T P1(inf) is "
                                             "singular)", "state space")
    zeros = statespace.zeros_square(product)
    axis = on_axis(zeros)
    if np.any(axis):
        w = float(np.min(np.abs(zeros[axis].imag)))
        return WindingCheck(False, w, f"det(I + P2~ P1) vanishes at w = {w:.6g} rad/s", "state space")
    right = int(np.sum(zeros.real > 0.0))
    if right == n2:
        return WindingCheck(True, method="state space")
    return WindingCheck(
        False,
        math.nan,
        f"winding number {n2 - right} != 0 (unstable pole/zero counts do not match)",
        "state space",
    )


def _winding_numerical(n1: np.ndarray, d1: np.ndarray, n2: np.ndarray, d2: np.ndarray,
                       delta_s: float) -> WindingCheck:
    deg1, deg2 = len(d1) - 1, len(d2) - 1
    k1 = n1[0] / d1[0] if len(n1) == len(d1) else 0.0
    k2 = n2[0] / d2[0] if len(n2) == len(d2) else 0.0
    if abs(k1 * k2) >= 1.0:
        return WindingCheck(
            False,
            math.inf,
            "|P1(inf) P2(inf)| >= 1 with different delays: the winding number is not defined",
            "numerical",
        )
    # rho = d2(-s) d1(s) + n2(-s) n1(s) exp(s delta)
    turns, where = axis_turns(_polymul(mirror(d2), d1), _polymul(mirror(n2), n1), delta_s, k1 * k2,
                              np.concatenate([polynomial_roots(d1), -polynomial_roots(d2)]),
                              np.concatenate([polynomial_roots(p) for p in (d1, d2, n1, n2)]))
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


def _resonance_points(roots: np.ndarray, axis_scale: float | None = None) -> np.ndarray:
    """Frequencies around every complex root: |Im| +- a few multiples of |Re|, and |root| (unsorted; some may
    be negative: callers keep their range). Roots r and -conj(r) give the same points, computed once.

    With ``axis_scale`` (the largest root magnitude, at least 1: :func:`on_axis`'s scale) the points on both
    sides of every root on the positive imaginary axis (:func:`_axis_points`) are included.
    """
    roots = np.asarray(roots, dtype=complex)
    imag = roots.imag
    roots = roots[(imag > 0.0) | ((imag == 0.0) & (roots.real != 0.0))]
    if roots.size == 0:
        return np.zeros(0)
    keys = np.unique(_complex(np.abs(roots.real), roots.imag))   # r and -conj(r) give the same points
    real, imag, magnitude = keys.real, keys.imag, np.abs(keys)
    centre = np.where(imag > 0.0, imag, real)
    width = np.maximum(real, 1e-9 * np.maximum(centre, 1.0))
    points = [(centre[:, None] + width[:, None] * _RESONANCE_OFFSETS).ravel(), magnitude]
    if axis_scale is not None:
        axis = (imag > 0.0) & (real <= _AXIS_RTOL * np.maximum(magnitude, 1e-3 * axis_scale))
        if axis.any():
            points.append(_axis_points(imag[axis]))
    return np.concatenate(points)


# ----------------------------------------------------------------------------------------------------------
# exact sup over frequency
# ----------------------------------------------------------------------------------------------------------


def _axis_points(centres: np.ndarray) -> np.ndarray:
    """Frequencies on both sides of roots on the positive imaginary axis (``centres``: their frequencies),
    geometrically closer.

    Two models sharing an undamped pole can have their largest chordal distance a hair to either side of it;
    the offsets run from 1e-9 to 0.5 of the root's frequency.
    """
    centres = np.unique(centres)[:, None]
    return np.concatenate([(centres * _AXIS_BELOW).ravel(), (centres * _AXIS_ABOVE).ravel()])


def combined(a: ArrayLike, b: ArrayLike, sign: float = 1.0) -> np.ndarray:
    """``a + sign b`` with every coefficient that cancels to round-off of its operands set to exactly 0.

    Leading coefficients that cancel (``P1(inf) = P2(inf)`` in ``n2 d1 - n1 d2``, ``|P(inf)| = 1`` in
    ``n n~ - d d~``) would otherwise give spurious roots near 1e15; trailing ones give exact roots at 0.

    Parameters
    ----------
    a, b : array_like of float
        Polynomial coefficients, descending powers of s (aligned at the constant term).
    sign : float
        1 for the sum, -1 for the difference.

    Returns
    -------
    ndarray of float
    """
    return _combined_both(a, b, (sign,))[0]


def _combined_both(a: ArrayLike, b: ArrayLike, signs: tuple[float, ...] = (1.0, -1.0)) -> list[np.ndarray]:
    """:func:`combined` for each sign, sharing the alignment and the round-off threshold."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.size != b.size:
        a, b = _aligned(a, b)
    threshold = np.abs(a)
    threshold += np.abs(b)
    threshold *= _CANCEL_EPS
    out = []
    for sign in signs:
        total = a + sign * b
        total[np.abs(total) <= threshold] = 0.0
        out.append(total)
    return out


def _aligned(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two coefficient arrays padded with leading zeros to the same length."""
    size = max(a.size, b.size)
    if a.size < size:
        a = np.concatenate([np.zeros(size - a.size), a])
    if b.size < size:
        b = np.concatenate([np.zeros(size - b.size), b])
    return a, b


def feature_roots(model: LinearModel, poles_zeros: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Poles, zeros and the roots of ``n n~ + d d~`` and ``n n~ - d d~`` of a model.

    ``|n(jw)|^2 + |d(jw)|^2`` is the denominator of the chordal distance (its roots are the corner
    frequencies of ``1 + |P|^2``) and the real roots of ``|n(jw)|^2 - |d(jw)|^2`` are the gain crossovers
    ``|P(jw)| = 1``, where two models' chordal distance peaks when their gains differ (1e-6/s vs 2e-6/s
    peaks at 1.4e-6 rad/s, far from any pole or zero).

    Parameters
    ----------
    model : LinearModel
        A SISO model (its rational part).
    poles_zeros : tuple of ndarray, optional
        Its poles and zeros when already computed.

    Returns
    -------
    ndarray of complex
        Every root, in the order poles, zeros, ``n n~ + d d~``, ``n n~ - d d~``.
    """
    poles, zeros = _poles_zeros(model) if poles_zeros is None else poles_zeros
    num, den = strip_leading_zeros(model.num), strip_leading_zeros(model.den)
    nn = _polymul(num, mirror(num))
    dd = _polymul(den, mirror(den))
    total, difference = _combined_both(nn, dd)
    return np.concatenate([poles, zeros, _even_roots(total), _even_roots(difference)])


def _pair_roots(m1: LinearModel, m2: LinearModel, roots1: tuple[np.ndarray, np.ndarray],
                roots2: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Every frequency feature of a pair: each model's :func:`feature_roots` and, with equal delays, the zeros
    of ``P2 - P1`` and of ``P2 + P1`` (the numerator and denominator of epsilon, eq. 14)."""
    parts = [feature_roots(m1, roots1), feature_roots(m2, roots2)]
    if m1.delay_s == m2.delay_s:
        difference, total = _combined_both(_polymul(m2.num, m1.den), _polymul(m1.num, m2.den), (-1.0, 1.0))
        parts += [polynomial_roots(difference), polynomial_roots(total)]
    return np.concatenate(parts)


def analysis_grid(roots: ArrayLike, delta_s: float = 0.0) -> np.ndarray:
    """Frequencies [rad/s] resolving every feature of a pair of responses.

    A logarithmic grid (300 points per decade) from 1e-4 of the smallest to 1e4 times the largest root
    magnitude (and 1/delta_s), 49 points around every complex or real root (its frequency +- 6 times its
    damping), points on both sides of roots on the imaginary axis (1e-9 to 0.5 of their frequency), and a
    linear grid at pi/8 of the delay's phase.

    Parameters
    ----------
    roots : array_like of complex
        The features (e.g. :func:`feature_roots` of both models); non-finite ones are ignored.
    delta_s : float
        Difference of the delays [s] (0 for none).

    Returns
    -------
    ndarray of float
        Increasing frequencies, without points within 1e-12 (relative) of each other.
    """
    roots = np.asarray(roots, dtype=complex)
    roots = roots[np.isfinite(roots)]
    magnitudes = np.abs(roots)
    nonzero = magnitudes[magnitudes > 0.0]
    w_min = float(nonzero.min()) if nonzero.size else 1.0
    w_max = float(nonzero.max()) if nonzero.size else 1.0
    axis_scale = max(1.0, w_max)   # on_axis's scale
    delta_s = abs(delta_s)
    if delta_s > 0.0:
        w_min = min(w_min, 1.0 / delta_s)
        w_max = max(w_max, 1.0 / delta_s)
    w_lo, w_hi = 1e-4 * w_min, 1e4 * w_max
    count = int(_GRID_PER_DECADE * math.log10(w_hi / w_lo)) + 2
    log_grid = np.exp(np.linspace(math.log(w_lo), math.log(w_hi), count))
    log_grid[0], log_grid[-1] = w_lo, w_hi
    extra = [_resonance_points(roots, axis_scale)]   # with the points beside the roots on the axis
    if delta_s > 0.0:
        step = math.pi / (8.0 * delta_s)
        extra.append(np.arange(1, min(int(w_hi / step), 100_000) + 1) * step)
    extra = np.concatenate(extra)
    extra = np.sort(extra[(extra >= w_lo) & (extra <= w_hi)], kind="stable")   # runs: each root's points
    w = np.sort(np.concatenate([log_grid, extra]), kind="stable")   # merges the two sorted runs
    # equal points, or within round-off of each other (the same root from several polynomials), would tie as
    # false peaks: the first of each cluster is kept
    keep = np.empty(w.size, dtype=bool)
    if w.size:
        keep[0] = True
        np.greater(np.diff(w), 1e-12 * w[1:], out=keep[1:])
    return w[keep]


def _grid_peaks(fun: Response, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Values of fun on the grid and the indices of its local maxima (NaN counts as -inf)."""
    values = np.asarray(fun(w), dtype=float)
    if values.size == 0:
        return values, np.zeros(0, dtype=np.intp)
    finite = math.isfinite(values.max()) and math.isfinite(values.min())   # no nan, no infinity
    if not finite:
        values[np.isnan(values)] = -np.inf
    is_peak = np.ones(values.size, dtype=bool)
    if values.size > 1:
        is_peak[1:] = values[1:] >= values[:-1]   # not below the left neighbour
        is_peak[:-1] &= values[:-1] >= values[1:]   # nor the right one
    if not finite:
        is_peak &= np.isfinite(values)
        is_peak |= values == np.inf
    return values, np.flatnonzero(is_peak)


def _bounded_maximum(fun: Callable[[float], float], a: float, b: float, xatol: float,
                     known: tuple[float, float, float] | None = None,
                     max_steps: int = 500) -> tuple[float, float]:
    """Maximum of a scalar function on [a, b] by Brent's method (golden sections, parabolic steps when they
    behave), to ``xatol`` plus 1.5e-8 relative; plain floats (a quarter of the time of scipy's per step).

    ``known``: the values at a, at 0 (inside, the best known point) and at b; the search then starts with the
    parabola through them. Returns (x, fun(x)) of the best point evaluated.
    """
    if known is not None and a < 0.0 < b:
        x, fx = 0.0, -known[1]   # minimise -fun
        (w, fw), (v, fv) = (a, -known[0]), (b, -known[2])
        step = last = b - a
    else:
        x = w = v = a + _GOLDEN * (b - a)
        fx = fw = fv = -fun(x)
        step = last = 0.0
    sqrt_eps, third = _SQRT_EPS, xatol / 3.0
    for _ in range(max_steps):
        middle = 0.5 * (a + b)
        tol = sqrt_eps * abs(x) + third
        if abs(x - middle) <= 2.0 * tol - 0.5 * (b - a):
            break
        golden = True
        if abs(last) > tol:   # a parabola through x, w, v
            r = (x - w) * (fx - fv)
            q = (x - v) * (fx - fw)
            p = (x - v) * q - (x - w) * r
            q = 2.0 * (q - r)
            if q > 0.0:
                p = -p
            q = abs(q)
            before, last = last, step
            if abs(p) < abs(0.5 * q * before) and q * (a - x) < p < q * (b - x):
                step = p / q
                if x + step - a < 2.0 * tol or b - (x + step) < 2.0 * tol:
                    step = tol if x < middle else -tol
                golden = False
        if golden:
            last = (b - x) if x < middle else (a - x)
            step = _GOLDEN * last
        u = x + (step if abs(step) >= tol else math.copysign(tol, step))
        fu = -fun(u)
        if fu <= fx:
            if u >= x:
                a = x
            else:
                b = x
            v, fv, w, fw, x, fx = w, fw, x, fx, u, fu
        else:
            if u < x:
                a = u
            else:
                b = u
            if fu <= fw or w == x:
                v, fv, w, fw = w, fw, u, fu
            elif fu <= fv or v in (x, w):
                v, fv = u, fu
    return x, -fx


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
    centre = float(w[k])
    value, where = float(values[k]), centre
    if hi > lo and math.isfinite(value):
        point = getattr(fun, "at", None)
        of_x = (lambda x: point(centre * math.exp(x))) if point is not None else \
            (lambda x: float(fun(np.array([centre * math.exp(x)]))[0]))
        x, best = _bounded_maximum(of_x, math.log(lo / centre), math.log(hi / centre), _REFINE_XATOL,
                                   (float(values[i]), value, float(values[j])))
        if best >= value:
            value, where = float(best), centre * math.exp(x)
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
    if close.size <= _MAX_CANDIDATES:
        keep = close   # all of them (ascending, as the union below)
    else:
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


def sup_with_ends(fun: Response, at_zero: float, at_infinity: float, w: np.ndarray) -> tuple[float, float]:
    """Sup over the grid's range, w = 0 and w -> infinity: the largest of the three values.

    The grid's local maxima are refined by a bounded search in ln(w) (to about 1e-10). The sup is reported at
    w = 0 when that ties with the grid's peak (within 1e-9 relative), at infinity only when the limit there is
    above both by more than that (a peak creeping up to its limit keeps its frequency, with the limit's
    value).

    Parameters
    ----------
    fun : callable
        The real function of frequency, vectorised (an optional ``fun.at(w)`` evaluates one frequency faster).
    at_zero : float
        Its value at w = 0 (nan: not defined there).
    at_infinity : float
        Its limit (sup) as w -> infinity.
    w : ndarray of float
        The grid (:func:`analysis_grid`).

    Returns
    -------
    value : float
        The sup.
    w_peak_rad_s : float
        Where it is attained [rad/s] (0, or ``inf`` for the limit at infinity).
    """
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
    pair, an estimate, a ``ChannelResult``, a python-control FRD): then the sup is over the data's
    frequencies, the condition assumed (:func:`nugap_frequency_data`).

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
    roots1, roots2 = _poles_zeros(m1), _poles_zeros(m2)
    check = _winding_siso(m1, m2, roots1, roots2)
    if not check.satisfied:
        return 1.0, check.frequency_rad_s
    w = analysis_grid(_pair_roots(m1, m2, roots1, roots2), m2.delay_s - m1.delay_s)
    fun = _PairResponse(m1, m2)
    value, where = sup_with_ends(fun, fun.at(0.0), _kappa_at_infinity(m1, m2), w)
    return min(max(value, 0.0), 1.0), where


def _nugap_state_space(
    s1: statespace.StateSpace, s2: statespace.StateSpace
) -> tuple[float, float, WindingCheck]:
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

    Examples
    --------
    A 20 % gain error is an epsilon of 0.2 / 2.2 at every frequency; a 20 ms delay makes the model its own
    negative at pi / 0.02 rad/s, where no disk contains it:

    >>> from gap_validation.core.models import LinearModel
    >>> p1 = LinearModel.from_tf([40.0], [1.0, 12.0, 40.0])
    >>> round(epsilon(p1, LinearModel.from_tf([48.0], [1.0, 12.0, 40.0]))[0], 4)
    0.0909
    >>> value, w_peak = epsilon(p1, p1.with_effects([{"type": "time_delay", "seconds": 0.02}]))
    >>> value, round(w_peak, 2)
    (inf, 157.08)
    """
    pair = paired_responses(m1, m2)
    if pair is not None:
        if np.ndim(pair[1]) > 1 or np.ndim(pair[2]) > 1:
            raise ValueError(
                "epsilon (eq. 14) is defined for SISO responses; compare MIMO data by the nu-gap"
            )
        return epsilon_frequency_data(*pair)
    if _shape(m1) != (1, 1) or _shape(m2) != (1, 1):
        raise ValueError("epsilon (eq. 14) is defined for SISO models; compare MIMO models by the nu-gap")
    m1, m2 = _siso(m1), _siso(m2)
    fun = _PairResponse(m1, m2, epsilon_of=True)
    if m1.delay_s == m2.delay_s:
        total = np.polyadd(_polymul(m2.num, m1.den), _polymul(m1.num, m2.den))
        extra = polynomial_roots(total)
        axis_roots = extra[np.abs(extra.real) <= _AXIS_RTOL * np.maximum(np.abs(extra), 1.0)]
        if axis_roots.size:
            w = float(np.min(np.abs(axis_roots.imag)))
            if np.isinf(fun(np.array([w]))[0]) or fun(np.array([w]))[0] > 1e6:
                return math.inf, w
    w = analysis_grid(_pair_roots(m1, m2, _poles_zeros(m1), _poles_zeros(m2)), m2.delay_s - m1.delay_s)
    value, where = _refined_sup(fun, w)
    if value >= _HUGE_EPSILON:
        first = _first_huge(fun, w, _HUGE_EPSILON)
        return math.inf, where if math.isnan(first) else first
    return sup_with_ends(fun, _epsilon_at_zero(m1, m2), _epsilon_at_infinity(m1, m2), w)


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
