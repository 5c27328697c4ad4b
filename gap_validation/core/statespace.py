"""State-space tools for the MIMO nu-gap and the stability margin b(P, C): realizations as plain arrays.

A system is a tuple ``(A, B, C, D)`` of 2-D float arrays, ``G(s) = C (sI - A)^-1 B + D`` (``p`` outputs, ``m``
inputs, ``n`` states; ``n`` may be 0 for a static gain). The functions are small and pure:

* :func:`minimal_realization`: orthogonal staircase reduction (controllable, then observable part);
* :func:`right_ncf`, :func:`left_ncf`: normalised coprime factors from the two Riccati equations
  (Zhou, Doyle & Glover, *Robust and Optimal Control*, 1996, sec. 13.8; Vinnicombe, *Uncertainty and
  Feedback*, 2001, ch. 1-3): ``G = [N; M]`` with ``P = N M^-1``, ``G~ G = I``, and ``Gt = [-Mt, Nt]`` with
  ``P = Mt^-1 Nt``, ``Gt Gt~ = I``;
* :func:`hinf_norm`: the H-infinity norm of a stable system and the frequency where it is attained, by the
  Hamiltonian level-set iteration of Bruinsma & Steinbuch (1990) with a final bounded refinement of the
  frequency;
* :func:`freqresp`, :func:`series`, :func:`paraconjugate`, :func:`zeros_square`.

Only numpy and scipy (``scipy.linalg.solve_continuous_are``, eigenvalues of Hamiltonian matrices).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

#: A real realization (A, B, C, D) as 2-D arrays.
StateSpace = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

_RANK_RTOL = 1e-10  # staircase rank decisions, relative to the norm of [A, B]
_IMAG_RTOL = 1e-7  # Hamiltonian eigenvalues this close (relative) to the imaginary axis are on it
_HINF_RTOL = 1e-10  # relative accuracy of the level-set iteration
_REFINE_XATOL = 1e-8  # final refinement of the peak frequency, in ln(w) (the goal is 1e-6 relative)
_ACCURATE_MODAL_COND = 1e3  # eigenvectors this well conditioned: the modal form is accurate enough to refine


def as_state_space(a: ArrayLike, b: ArrayLike, c: ArrayLike, d: ArrayLike | None = None) -> StateSpace:
    """Check and convert matrices to a realization of 2-D float arrays.

    Parameters
    ----------
    a, b, c : array_like
        ``n x n``, ``n x m`` and ``p x n`` matrices (``n`` may be 0).
    d : array_like, optional
        ``p x m`` feedthrough (default zero).

    Returns
    -------
    tuple of ndarray
        ``(A, B, C, D)``.

    Raises
    ------
    ValueError
        When the shapes do not fit together.
    """
    a = np.atleast_2d(np.asarray(a, dtype=float))
    b = np.asarray(b, dtype=float)
    c = np.asarray(c, dtype=float)
    n = a.shape[0] if a.size else 0
    a = a.reshape(n, n)
    b = b.reshape(n, -1) if b.size else np.zeros((n, 0 if d is None else np.atleast_2d(d).shape[1]))
    c = c.reshape(-1, n) if c.size else np.zeros((0 if d is None else np.atleast_2d(d).shape[0], n))
    d = np.zeros((c.shape[0], b.shape[1])) if d is None else np.atleast_2d(np.asarray(d, dtype=float))
    if b.shape[0] != n or c.shape[1] != n or d.shape != (c.shape[0], b.shape[1]):
        raise ValueError(f"state space: shapes A {a.shape}, B {b.shape}, C {c.shape}, D {d.shape} do not fit")
    return a, b, c, d


def freqresp(system: StateSpace, w_rad_s: ArrayLike) -> np.ndarray:
    """Frequency response ``G(j w)`` at every frequency, shape ``(len(w), p, m)``.

    Uses the modal form when A is safely diagonalisable, else one linear solve per frequency (in blocks).

    Parameters
    ----------
    system : tuple of ndarray
        ``(A, B, C, D)``.
    w_rad_s : array_like
        Frequencies [rad/s].

    Returns
    -------
    ndarray of complex
        ``inf``/``nan`` entries at poles on the imaginary axis.
    """
    a, b, c, d = system
    w = np.atleast_1d(np.asarray(w_rad_s, dtype=float)).ravel()
    out = np.broadcast_to(d.astype(complex), (w.size,) + d.shape).copy()
    n = a.shape[0]
    if n == 0 or w.size == 0:
        return out
    lam, vec = np.linalg.eig(a)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if np.all(np.isfinite(lam)) and np.linalg.cond(vec) < 1e8:
            left = c @ vec                      # p x n
            right = np.linalg.solve(vec, b)     # n x m
            resolvent = 1.0 / (1j * w[:, None] - lam[None, :])   # N x n
            out += np.einsum("pk,nk,km->npm", left, resolvent, right)
            return out
        eye = np.eye(n)
        for start in range(0, w.size, 1024):
            chunk = w[start:start + 1024]
            mats = 1j * chunk[:, None, None] * eye - a
            try:
                x = np.linalg.solve(mats, np.broadcast_to(b, (chunk.size,) + b.shape))
            except np.linalg.LinAlgError:
                x = np.stack([_solve_or_inf(m, b) for m in mats])
            out[start:start + chunk.size] += c @ x
    return out


def _solve_or_inf(matrix: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.solve(matrix, rhs)
    except np.linalg.LinAlgError:
        return np.full(rhs.shape, np.inf, dtype=complex)


def _response_at(system: StateSpace, w: float) -> np.ndarray:
    """``G(j w)`` at one frequency (``w = inf``: D)."""
    a, b, c, d = system
    if math.isinf(w) or a.shape[0] == 0:
        return d.astype(complex)
    return c @ np.linalg.solve(1j * w * np.eye(a.shape[0]) - a, b) + d


def sigma_max(system: StateSpace, w: float) -> float:
    """Largest singular value of ``G(j w)`` (``w = inf``: of D).

    Parameters
    ----------
    system : tuple of ndarray
        ``(A, B, C, D)``; A must have no eigenvalue at ``j w``.
    w : float
        Frequency [rad/s].
    """
    g = _response_at(system, w)
    return float(np.linalg.norm(g, 2)) if g.size else 0.0


# ----------------------------------------------------------------------------------------------------------
# interconnections
# ----------------------------------------------------------------------------------------------------------


def series(first: StateSpace, second: StateSpace) -> StateSpace:
    """``second`` driven by the output of ``first``: the product ``G2(s) G1(s)``.

    Parameters
    ----------
    first, second : tuple of ndarray
        Realizations; outputs of ``first`` = inputs of ``second``.

    Returns
    -------
    tuple of ndarray
        States of ``first``, then of ``second``.
    """
    a1, b1, c1, d1 = first
    a2, b2, c2, d2 = second
    n1, n2 = a1.shape[0], a2.shape[0]
    a = np.zeros((n1 + n2, n1 + n2))
    a[:n1, :n1] = a1
    a[n1:, n1:] = a2
    a[n1:, :n1] = b2 @ c1
    return a, np.vstack([b1, b2 @ d1]), np.hstack([d2 @ c1, c2]), d2 @ d1


def paraconjugate(system: StateSpace) -> StateSpace:
    """Realization of ``G~(s) = G(-s)^T`` (on the imaginary axis the conjugate transpose).

    Parameters
    ----------
    system : tuple of ndarray
        ``(A, B, C, D)``.
    """
    a, b, c, d = system
    return -a.T, -c.T, b.T, d.T


def zeros_square(system: StateSpace) -> np.ndarray:
    """Zeros of ``det G(s)`` for a square G with invertible D: eigenvalues of ``A - B D^-1 C``.

    ``det G(s) = det D det(sI - A + B D^-1 C) / det(sI - A)`` for any realization, minimal or not.

    Parameters
    ----------
    system : tuple of ndarray
        ``(A, B, C, D)`` with square, invertible D.
    """
    a, b, c, d = system
    if a.shape[0] == 0:
        return np.zeros(0, dtype=complex)
    return np.linalg.eigvals(a - b @ np.linalg.solve(d, c))


# ----------------------------------------------------------------------------------------------------------
# minimal realization
# ----------------------------------------------------------------------------------------------------------


def _controllable(a: np.ndarray, b: np.ndarray, c: np.ndarray, tol: float) -> tuple[np.ndarray, ...]:
    """Controllable part by the orthogonal staircase: T^T A T = [[Ac, *], [0, Au]], T^T B = [Bc; 0]."""
    a, b, c = a.copy(), b.copy(), c.copy()
    n = a.shape[0]
    k = 0
    block = b
    while k < n and block.size:
        u, s, _ = np.linalg.svd(block, full_matrices=True)
        rank = int(np.sum(s > tol))
        if rank == 0:
            break
        a[k:] = u.T @ a[k:]
        a[:, k:] = a[:, k:] @ u
        b[k:] = u.T @ b[k:]
        c[:, k:] = c[:, k:] @ u
        block = a[k + rank:, k:k + rank]
        k += rank
    return a[:k, :k], b[:k], c[:, :k]


def minimal_realization(system: StateSpace) -> StateSpace:
    """A minimal realization: the controllable and observable part (orthogonal staircase reductions).

    Modes that the inputs cannot move or the outputs cannot see (e.g. a heading state of a lateral model
    whose outputs are rates) are removed; the transfer function is unchanged. Rank decisions are relative
    (``1e-10`` of the norm of ``[A, B]`` or ``[A; C]``) after balancing A.

    Parameters
    ----------
    system : tuple of ndarray
        ``(A, B, C, D)``.

    Returns
    -------
    tuple of ndarray
        ``(A, B, C, D)`` with no more states.
    """
    a, b, c, d = system
    n = a.shape[0]
    if n == 0:
        return system
    _, (scale, perm) = scipy.linalg.matrix_balance(a, permute=False, separate=True)
    a = a * scale[None, :] / scale[:, None]
    b = b / scale[:, None]
    c = c * scale[None, :]
    tol = _RANK_RTOL * max(np.linalg.norm(a, 1), np.linalg.norm(b, 1), 1e-300)
    a, b, c = _controllable(a, b, c, tol)
    if a.shape[0] == 0:
        return np.zeros((0, 0)), np.zeros((0, b.shape[1])), np.zeros((c.shape[0], 0)), d
    tol = _RANK_RTOL * max(np.linalg.norm(a, 1), np.linalg.norm(c, np.inf), 1e-300)
    at, ct, bt = _controllable(a.T, c.T, b.T, tol)
    return at.T, bt.T, ct.T, d


# ----------------------------------------------------------------------------------------------------------
# normalised coprime factors
# ----------------------------------------------------------------------------------------------------------


def _inv_sqrt(matrix: np.ndarray) -> np.ndarray:
    """``matrix^-1/2`` of a symmetric positive definite matrix."""
    values, vectors = np.linalg.eigh(matrix)
    return (vectors / np.sqrt(values)) @ vectors.T


def stabilising_riccati(a: np.ndarray, g: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Stabilising solution X of ``A^T X + X A - X G X + Q = 0`` (G, Q symmetric), by the ordered Schur form.

    The stable invariant subspace ``[U1; U2]`` of the Hamiltonian ``[[A, -G], [-Q, -A^T]]`` (real Schur form
    sorted left half plane first, Laub 1979) gives ``X = U2 U1^-1``; ``A - G X`` is then stable. Used for the
    normalised coprime factors, whose weights are well conditioned (``R = I + D^T D``); a fraction of the cost
    of ``scipy.linalg.solve_continuous_are``'s generalised-pencil method for the small systems here.

    Parameters
    ----------
    a, g, q : ndarray
        ``n x n`` matrices.

    Returns
    -------
    ndarray
        Symmetric ``n x n`` X.

    Raises
    ------
    numpy.linalg.LinAlgError
        When the Hamiltonian has eigenvalues on the imaginary axis (no stabilising solution: a mode on the
        axis that the inputs cannot move or the outputs cannot see) or U1 is singular.
    """
    n = a.shape[0]
    hamiltonian = np.block([[a, -g], [-q, -a.T]])
    _, u, stable = scipy.linalg.schur(hamiltonian, output="real", sort="lhp")
    if stable != n:
        raise np.linalg.LinAlgError(
            f"Riccati equation: {stable} stable Hamiltonian eigenvalues, expected {n} "
            "(a mode on the imaginary axis is uncontrollable or unobservable)"
        )
    x = np.linalg.solve(u[:n, :n].T, u[n:, :n].T).T
    if not np.all(np.isfinite(x)):
        raise np.linalg.LinAlgError("Riccati equation: no finite stabilising solution")
    return 0.5 * (x + x.T)


def _ncf_data(system: StateSpace) -> tuple[np.ndarray, ...]:
    """``A - B R^-1 D^T C``, ``B R^-1 B^T``, ``C^T Rt^-1 C`` and the weights of both normalised
    factorisations."""
    a, b, c, d = system
    r = np.eye(b.shape[1]) + d.T @ d
    rt = np.eye(c.shape[0]) + d @ d.T
    a_tilde = a - b @ np.linalg.solve(r, d.T @ c)
    return a_tilde, b @ np.linalg.solve(r, b.T), c.T @ np.linalg.solve(rt, c), r, rt


def right_ncf(system: StateSpace) -> StateSpace:
    """Normalised right coprime factors ``G = [N; M]`` of ``P = N M^-1`` (``G~ G = I``, G stable).

    With ``R = I + D^T D``, ``Rt = I + D D^T``, ``At = A - B R^-1 D^T C`` and X the stabilising solution of
    ``At^T X + X At - X B R^-1 B^T X + C^T Rt^-1 C = 0``, ``F = -R^-1 (B^T X + D^T C)``:
    ``N = (A + BF, B R^-1/2, C + DF, D R^-1/2)``, ``M = (A + BF, B R^-1/2, F, R^-1/2)``
    (Zhou, Doyle & Glover 1996, Theorem 13.37). P must be minimal (no hidden modes on the imaginary axis).

    Parameters
    ----------
    system : tuple of ndarray
        Minimal ``(A, B, C, D)`` of P (p x m).

    Returns
    -------
    tuple of ndarray
        Realization of G: ``p + m`` outputs (N first, then M), ``m`` inputs.

    Raises
    ------
    numpy.linalg.LinAlgError
        When the Riccati equation has no stabilising solution.
    """
    a, b, c, d = system
    m = b.shape[1]
    a_tilde, g, q, r, _ = _ncf_data(system)
    r_half = _inv_sqrt(r)
    if a.shape[0] == 0:
        return a, np.zeros((0, m)), np.zeros((c.shape[0] + m, 0)), np.vstack([d @ r_half, r_half])
    x = stabilising_riccati(a_tilde, g, q)
    f = -np.linalg.solve(r, b.T @ x + d.T @ c)
    return a + b @ f, b @ r_half, np.vstack([c + d @ f, f]), np.vstack([d @ r_half, r_half])


def left_ncf(system: StateSpace) -> StateSpace:
    """Normalised left coprime factors ``Gt = [-Mt, Nt]`` of ``P = Mt^-1 Nt`` (``Gt Gt~ = I``, Gt stable).

    With Y the stabilising solution of the dual equation ``At Y + Y At^T - Y C^T Rt^-1 C Y + B R^-1 B^T = 0``
    and ``L = -(B D^T + Y C^T) Rt^-1``: ``Nt = (A + LC, B + LD, Rt^-1/2 C, Rt^-1/2 D)``,
    ``Mt = (A + LC, L, Rt^-1/2 C, Rt^-1/2)``. Then ``Gt G' = 0`` for the right factors G' of the same P, and
    ``Gt2 G1 = Mt2 (P2 - P1) M1``, the matrix of the chordal distance (Vinnicombe 2001, ch. 3).

    Parameters
    ----------
    system : tuple of ndarray
        Minimal ``(A, B, C, D)`` of P (p x m).

    Returns
    -------
    tuple of ndarray
        Realization of Gt: ``p`` outputs, ``p + m`` inputs (the output y first, then the input u).
    """
    a, b, c, d = system
    p = c.shape[0]
    a_tilde, g, q, _, rt = _ncf_data(system)
    rt_half = _inv_sqrt(rt)
    d_out = np.hstack([-rt_half, rt_half @ d])
    if a.shape[0] == 0:
        return a, np.zeros((0, p + b.shape[1])), np.zeros((p, 0)), d_out
    y = stabilising_riccati(a_tilde.T, q, g)
    gain = -np.linalg.solve(rt, c @ y + d @ b.T).T   # L, n x p
    return a + gain @ c, np.hstack([-gain, b + gain @ d]), rt_half @ c, d_out


# ----------------------------------------------------------------------------------------------------------
# H-infinity norm
# ----------------------------------------------------------------------------------------------------------


def _level_set_pencil(system: StateSpace, gamma: float) -> tuple[np.ndarray, np.ndarray]:
    """Pencil (M, E) whose finite generalised eigenvalues j w are the frequencies where gamma is a singular
    value of G(j w): ``G u = gamma y`` and ``G* y = gamma u`` with the states x of G and z of G~.

    The extended form needs no inverse of ``D^T D - gamma^2 I``, so it stays accurate when gamma approaches
    sigma_max(D) (a peak barely above the high-frequency asymptote), where the Hamiltonian matrix of
    Bruinsma & Steinbuch is ill-conditioned.
    """
    a, b, c, d = system
    n, m, p = a.shape[0], b.shape[1], c.shape[0]
    size = 2 * n + m + p
    pencil = np.zeros((size, size))
    pencil[:n, :n] = a
    pencil[:n, 2 * n:2 * n + m] = b
    pencil[n:2 * n, n:2 * n] = -a.T
    pencil[n:2 * n, 2 * n + m:] = -c.T
    pencil[2 * n:2 * n + m, n:2 * n] = b.T
    pencil[2 * n:2 * n + m, 2 * n:2 * n + m] = -gamma * np.eye(m)
    pencil[2 * n:2 * n + m, 2 * n + m:] = d.T
    pencil[2 * n + m:, :n] = c
    pencil[2 * n + m:, 2 * n:2 * n + m] = d
    pencil[2 * n + m:, 2 * n + m:] = -gamma * np.eye(p)
    e = np.zeros((size, size))
    e[:2 * n, :2 * n] = np.eye(2 * n)
    return pencil, e


def _hamiltonian(system: StateSpace, gamma: float) -> np.ndarray:
    """Bruinsma & Steinbuch's Hamiltonian: imaginary eigenvalues j w where gamma is a singular value of G(j
    w)."""
    a, b, c, d = system
    p, m = d.shape
    r = d.T @ d - gamma * gamma * np.eye(m)
    s = d @ d.T - gamma * gamma * np.eye(p)
    r_inv_dt = np.linalg.solve(r, d.T)
    top = np.hstack([a - b @ r_inv_dt @ c, -gamma * b @ np.linalg.solve(r, b.T)])
    bottom = np.hstack([gamma * c.T @ np.linalg.solve(s, c), -a.T + c.T @ r_inv_dt.T @ b.T])
    return np.vstack([top, bottom])


def _crossings(system: StateSpace, gamma: float) -> np.ndarray:
    """Sorted frequencies (both signs) where gamma is a singular value of G(j w).

    The Hamiltonian matrix when gamma is well above sigma_max(D) (cheap), else the inverse-free pencil.
    """
    d = system[3]
    with np.errstate(divide="ignore", invalid="ignore"):
        if not d.size or gamma > 1.1 * np.linalg.norm(d, 2):
            eig = np.linalg.eigvals(_hamiltonian(system, gamma))
        else:
            eig = scipy.linalg.eigvals(*_level_set_pencil(system, gamma))
    eig = eig[np.isfinite(eig)]
    on_axis = np.abs(eig.real) <= _IMAG_RTOL * np.maximum(np.abs(eig), 1.0)
    return np.sort(eig[on_axis].imag)


def _initial_candidates(poles: np.ndarray) -> np.ndarray:
    """Frequencies to start from: 0, each pole's natural and damped frequency, and a coarse logarithmic grid
    over the poles' range (so the first lower bound is a finite peak rather than sigma_max(D))."""
    magnitudes = np.abs(poles)
    out = [np.zeros(1), magnitudes, np.abs(poles.imag[poles.imag > 0.0])]
    positive = magnitudes[magnitudes > 0.0]
    if positive.size:
        low, high = positive.min() / 10.0, positive.max() * 10.0
        out.append(np.geomspace(low, high, max(8, int(8 * math.log10(high / low)))))
    return np.unique(np.concatenate(out))


def _norm2_many(g: np.ndarray) -> np.ndarray:
    """Largest singular values of a stack of small complex matrices ``(N, p, m)``."""
    gh = np.conj(np.swapaxes(g, 1, 2))
    gram = gh @ g if g.shape[2] <= g.shape[1] else g @ gh
    if gram.shape[1] == 1:
        return np.sqrt(np.maximum(gram[:, 0, 0].real, 0.0))
    if gram.shape[1] == 2:
        a, c = gram[:, 0, 0].real, gram[:, 1, 1].real
        return np.sqrt(np.maximum(0.5 * (a + c) + np.hypot(0.5 * (a - c), np.abs(gram[:, 0, 1])), 0.0))
    return np.sqrt(np.maximum(np.linalg.eigvalsh(gram)[:, -1], 0.0))


def _norm2(g: np.ndarray) -> float:
    """Largest singular value of a small complex matrix (closed form up to 2 x 2 Gram matrices)."""
    gram = g.conj().T @ g if g.shape[1] <= g.shape[0] else g @ g.conj().T
    if gram.shape[0] == 1:
        return math.sqrt(max(gram[0, 0].real, 0.0))
    if gram.shape[0] == 2:
        a, c = gram[0, 0].real, gram[1, 1].real
        return math.sqrt(max(0.5 * (a + c) + math.hypot(0.5 * (a - c), abs(gram[0, 1])), 0.0))
    return float(np.sqrt(max(np.linalg.eigvalsh(gram)[-1], 0.0)))


class _Sigma:
    """``w -> sigma_max(G(j w))`` for repeated evaluation: modal form when A is safely diagonalisable."""

    def __init__(self, system: StateSpace) -> None:
        a, b, c, d = system
        self.system = system
        self.eye = None
        self.poles, vectors = np.linalg.eig(a)
        condition = np.linalg.cond(vectors) if np.all(np.isfinite(self.poles)) else np.inf
        self.modal = bool(condition < 1e8)
        self.accurate = bool(condition < _ACCURATE_MODAL_COND)
        if self.modal:
            self.left, self.right = c @ vectors, np.linalg.solve(vectors, b)
            self.d = d.astype(complex)
        else:
            self.poles = np.linalg.eigvals(a)

    def __call__(self, w: float) -> float:
        if not self.modal:
            return self.solved(w)
        return _norm2(self.left @ (self.right / (1j * w - self.poles)[:, None]) + self.d)

    def solved(self, w: float) -> float:
        """sigma_max by a linear solve (backward stable whatever the eigenvectors)."""
        a, b, c, d = self.system
        if self.eye is None:
            self.eye = np.eye(a.shape[0])
        return _norm2(c @ np.linalg.solve(1j * w * self.eye - a, b) + d)

    def many(self, w: np.ndarray) -> np.ndarray:
        if not self.modal:
            return np.array([self.solved(float(x)) for x in w])
        resolvent = 1.0 / (1j * w[:, None] - self.poles[None, :])
        return _norm2_many(np.einsum("pk,nk,km->npm", self.left, resolvent, self.right) + self.d)


def hinf_norm(system: StateSpace) -> tuple[float, float]:
    """H-infinity norm of a stable system, ``sup_w sigma_max(G(j w))``, and where it is attained.

    Level-set iteration of Bruinsma & Steinbuch ("A fast algorithm to compute the H-infinity norm of a
    transfer function matrix", Systems & Control Letters 14, 1990): from a lower bound gamma (the best of a
    few candidate frequencies), the imaginary eigenvalues of a level-set pencil give the intervals where
    sigma_max(G(j w)) > gamma (1 + 2 tol); their midpoints raise the bound; no interval left means gamma is
    the norm to the relative tolerance. The pencil is the extended (inverse-free) form, accurate also when the
    norm is barely above sigma_max(D). The peak frequency is then refined by a bounded scalar search in ln(w)
    inside the last interval (to about 1e-8 in ln w).

    Parameters
    ----------
    system : tuple of ndarray
        ``(A, B, C, D)`` with A Hurwitz (every eigenvalue in the open left half plane).

    Returns
    -------
    norm : float
    w_peak_rad_s : float
        Frequency of the peak [rad/s]; ``inf`` when the sup is the limit at infinity (sigma_max(D)).
    """
    a, _, _, d = system
    at_infinity = float(np.linalg.norm(d, 2)) if d.size else 0.0
    if a.shape[0] == 0:
        return at_infinity, math.inf
    sigma = _Sigma(system)
    candidates = _initial_candidates(sigma.poles)
    values = sigma.many(candidates)
    k = int(np.argmax(values))
    best, where = (
        (float(values[k]), float(candidates[k])) if values[k] > at_infinity else (at_infinity, math.inf)
    )
    if math.isfinite(where) and where > 0.0:  # a refined first bound: the level set then usually confirms it
        neighbours = (float(candidates[max(k - 1, 0)]), float(candidates[min(k + 1, candidates.size - 1)]))
        best, where = _refine_peak(sigma, best, where, neighbours)
    for _ in range(60):
        if best <= 0.0:
            break
        points = _crossings(system, best * (1.0 + 2.0 * _HINF_RTOL))
        if points.size == 0:
            break
        mids = np.abs(0.5 * (points[:-1] + points[1:])) if points.size > 1 else np.abs(points)
        values = sigma.many(mids)
        k = int(np.argmax(values))
        if values[k] <= best * (1.0 + _HINF_RTOL):
            break
        interval = (abs(points[k]), abs(points[k + 1])) if points.size > 1 else (0.0, abs(points[0]))
        best, where = _refine_peak(sigma, float(values[k]), float(mids[k]), interval)
    return best, where


def _refine_peak(sigma: _Sigma, best: float, where: float,
                 interval: tuple[float, float] | None) -> tuple[float, float]:
    """Maximise sigma_max(G(j w)) in ln(w) around ``where`` (inside ``interval`` when known).

    A smooth peak is located only to the square root of the evaluation's relative error, and the modal form's
    error grows with the condition number of A's eigenvectors: the search uses the modal form only when they
    are well conditioned, else a (backward stable) linear solve per frequency.
    """
    if not math.isfinite(where) or where <= 0.0:
        return best, where
    evaluate = sigma if sigma.accurate else sigma.solved
    best = evaluate(where)
    lo, hi = (min(interval), max(interval)) if interval else (where / 1.5, where * 1.5)
    lo, hi = min(lo, where), max(hi, where)
    lo = max(lo, where * 1e-3)
    if hi <= lo:
        return best, where
    from scipy.optimize import minimize_scalar  # scipy.optimize costs 0.6 s at import: only when used
    result = minimize_scalar(lambda x: -evaluate(where * math.exp(x)),
                             bounds=(math.log(lo / where), math.log(hi / where)), method="bounded",
                             options={"xatol": _REFINE_XATOL, "maxiter": 200})
    if -result.fun > best:
        return float(-result.fun), float(where * math.exp(result.x))
    return best, where
