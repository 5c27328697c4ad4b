"""Time response of a linear state-space model to sampled input (``LinearModel.simulate``'s engine).

The rational part is discretised exactly for the input between samples (linear: first-order hold as
``scipy.signal.lsim``; or held), with one matrix exponential per distinct step. Uniform grids (and uniform
runs between dropouts) are simulated in blocks with matrix products; irregular (jittered) steps exactly in
modal coordinates, vectorised; a per-step recursion only when A is not diagonalisable. A pure delay is applied
to the input exactly (:func:`delayed_input`), not by a Pade approximation.
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["simulate_state_space", "delayed_input"]

_UNIFORM_RTOL = 1e-8  # steps equal to this relative tolerance are treated as one uniform grid
_BLOCK = 256  # block length of the uniform-grid simulation


def simulate_state_space(
    a: np.ndarray,
    b: np.ndarray,
    c: np.ndarray,
    d: np.ndarray,
    t: np.ndarray,
    u: np.ndarray,
    x: np.ndarray,
    hold: str = "linear",
) -> np.ndarray:
    """Output samples of the SISO realization ``(a, b, c, d)`` for input ``u`` at the times ``t``.

    Parameters
    ----------
    a, b, c, d : ndarray
        The realization (n x n, n x 1, 1 x n, 1 x 1).
    t : ndarray
        Sample times [s], strictly increasing (checked by the caller).
    u : ndarray
        Input samples, same length.
    x : ndarray
        Initial state, n.
    hold : {"linear", "zero"}
        Input interpolation between samples.

    Returns
    -------
    ndarray
        y(t).
    """
    if a.shape[0] == 0:
        return d[0, 0] * u
    y = np.empty_like(u)
    for start, stop in _uniform_runs(np.diff(t)):
        x = _simulate_run(a, b, c, d, t[start:stop + 1], u[start:stop + 1], x, hold, y[start:stop + 1])
    return y


def delayed_input(t_s: np.ndarray, u: np.ndarray, delay_s: float, hold: str = "linear") -> np.ndarray:
    """Samples of u(t - T) at the times ``t_s``: interpolated input, zero before the first sample.

    Parameters
    ----------
    t_s, u : ndarray
        Sample times [s] (increasing) and input samples.
    delay_s : float
        Delay T [s].
    hold : {"linear", "zero"}
        Linear interpolation, or the last sample held.
    """
    shifted = t_s - delay_s
    if hold == "linear":
        return np.interp(shifted, t_s, u, left=0.0)
    index = np.searchsorted(t_s, shifted, side="right") - 1
    out = np.where(index >= 0, u[np.clip(index, 0, None)], 0.0)
    return out


def _uniform_runs(steps: np.ndarray, min_steps: int = 32) -> list[tuple[int, int]]:
    """Split samples into runs: (first, last) sample indices, consecutive runs sharing their end sample.

    Runs of at least ``min_steps`` (nearly) equal steps are simulated in blocks; shorter irregular stretches
    are merged into runs for the per-step recursion.
    """
    count = steps.size
    if count == 0 or np.all(np.abs(steps - steps[0]) <= _UNIFORM_RTOL * steps[0]):
        return [(0, count)]
    change = np.flatnonzero(np.abs(np.diff(steps)) > _UNIFORM_RTOL * steps[1:]) + 1
    edges = np.concatenate([[0], change, [count]])
    runs = []
    for first, last in zip(edges[:-1].tolist(), edges[1:].tolist()):
        long_run = last - first >= min_steps
        if runs and not long_run and not runs[-1][2]:
            runs[-1][1] = last
        else:
            runs.append([first, last, long_run])
    return [(first, last) for first, last, _ in runs]


def _discretise(
    a: np.ndarray, b: np.ndarray, h: float, hold: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact discretisation for input held (``zero``) or linear (``linear``) over a step h [s].

    Returns Phi, Ga, Gb with x[k+1] = Phi x[k] + Ga u[k] + Gb u[k+1].
    """
    import scipy.linalg

    n = a.shape[0]
    if hold == "zero":
        block = np.zeros((n + 1, n + 1))
        block[:n, :n] = a * h
        block[:n, n:] = b * h
        e = scipy.linalg.expm(block)
        return e[:n, :n], e[:n, n], np.zeros(n)
    block = np.zeros((n + 2, n + 2))
    block[:n, :n] = a * h
    block[:n, n] = b[:, 0] * h
    block[n, n + 1] = 1.0
    e = scipy.linalg.expm(block)
    phi, gamma1, gamma2 = e[:n, :n], e[:n, n], e[:n, n + 1]
    return phi, gamma1 - gamma2, gamma2


def _simulate_run(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, t: np.ndarray, u: np.ndarray,
                  x: np.ndarray, hold: str, y_out: np.ndarray) -> np.ndarray:
    """Simulate samples t[0..] starting from state x at t[0]; writes y_out, returns the state at t[-1]."""
    count = t.size
    if count == 1:
        y_out[0] = c[0] @ x + d[0, 0] * u[0]
        return x
    steps = np.diff(t)
    if count >= 32 and np.all(np.abs(steps - steps[0]) <= _UNIFORM_RTOL * steps[0]):
        h = float(np.mean(steps))
        return _simulate_uniform(a, b, c, d, h, u, x, hold, y_out)
    x_end = _simulate_modal(a, b, c, d, t, u, x, hold, y_out)
    if x_end is not None:
        return x_end
    return _simulate_steps(a, b, c, d, t, u, x, hold, y_out)


def _simulate_steps(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, t: np.ndarray, u: np.ndarray,
                    x: np.ndarray, hold: str, y_out: np.ndarray) -> np.ndarray:
    """Per-step recursion with exact matrices for each distinct step (any A; slow: tens of us per step)."""
    count = t.size
    steps = np.diff(t)
    unique, inverse = np.unique(steps, return_inverse=True)
    mats = [_discretise(a, b, float(h), hold) for h in unique]
    c0, d0 = c[0], d[0, 0]
    states = np.empty((count, x.size))
    for k in range(count - 1):
        states[k] = x
        phi, ga, gb = mats[inverse[k]]
        x = phi @ x + ga * u[k] + gb * u[k + 1]
    states[-1] = x
    y_out[:] = states @ c0 + d0 * u
    return x


def _phi_functions(z: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """phi1(z) = (e^z - 1)/z and phi2(z) = (e^z - 1 - z)/z^2 for complex arrays, accurate near z = 0."""
    z = np.asarray(z, dtype=complex)
    small = np.abs(z) < 0.1
    with np.errstate(divide="ignore", invalid="ignore"):
        phi1 = np.expm1(z) / z
        phi2 = (phi1 - 1.0) / z
    zs = z[small]
    series1 = np.zeros_like(zs)
    series2 = np.zeros_like(zs)
    term = np.ones_like(zs)
    for k in range(12):  # sum z^k/(k+1)! and z^k/(k+2)!
        series1 += term / math.factorial(k + 1)
        series2 += term / math.factorial(k + 2)
        term = term * zs
    phi1[small] = series1
    phi2[small] = series2
    return phi1, phi2


def _simulate_modal(
    a: np.ndarray,
    b: np.ndarray,
    c: np.ndarray,
    d: np.ndarray,
    t: np.ndarray,
    u: np.ndarray,
    x: np.ndarray,
    hold: str,
    y_out: np.ndarray,
    max_condition: float = 1e6,
) -> np.ndarray | None:
    """Irregular steps in modal coordinates, vectorised; None when A is not safely diagonalisable.

    With A = V diag(lam) V^-1 every mode obeys z[k+1] = exp(lam h_k) z[k] + f_k (f from the phi functions
    of lam h_k and the held/linear input), solved in blocks by cumulative sums of exp(-lam t) f.
    """
    lam, vec = np.linalg.eig(a)
    if not np.all(np.isfinite(lam)) or np.linalg.cond(vec) > max_condition:
        return None
    inv = np.linalg.inv(vec)
    b_modal = inv @ b[:, 0]
    c_modal = c[0] @ vec
    z0 = inv @ x
    steps = np.diff(t)
    y = d[0, 0] * u.astype(complex)
    z_end = np.empty(lam.size, dtype=complex)
    for i, root in enumerate(lam):
        phi1, phi2 = _phi_functions(root * steps)
        if hold == "zero":
            forcing = steps * phi1 * b_modal[i] * u[:-1]
        else:
            forcing = steps * b_modal[i] * ((phi1 - phi2) * u[:-1] + phi2 * u[1:])
        z = _scalar_scan(root, t, forcing, z0[i])
        y += c_modal[i] * z
        z_end[i] = z[-1]
    y_out[:] = y.real
    return (vec @ z_end).real


def _scalar_scan(root: complex, t: np.ndarray, forcing: np.ndarray, z0: complex) -> np.ndarray:
    """z[0] = z0, z[k+1] = exp(root (t[k+1] - t[k])) z[k] + forcing[k], vectorised in blocks.

    Within a block z = exp(root s) cumsum(exp(-root s) f), s the time from the block start; the block length
    keeps |Re(root)| s below 500 (no overflow). Block start values follow a short scalar recursion.
    """
    count = forcing.size
    h_max = float(np.max(np.diff(t)))
    rate = abs(root.real) * h_max
    length = 256 if rate * 256 <= 500.0 else max(1, int(500.0 / rate))
    blocks = -(-count // length)
    padded_t = np.concatenate([t, np.full(blocks * length + 1 - t.size, t[-1])])
    padded_f = np.zeros(blocks * length, dtype=complex)
    padded_f[:count] = forcing
    starts = padded_t[:-1:length][:blocks]
    rel = padded_t[1:].reshape(blocks, length) - starts[:, None]  # time from block start to each step's end
    grow = np.exp(root * rel)
    local = grow * np.cumsum(np.exp(-root * rel) * padded_f.reshape(blocks, length), axis=1)
    end_grow, end_local = grow[:, -1].tolist(), local[:, -1].tolist()
    carry = np.empty(blocks, dtype=complex)
    state = complex(z0)
    for k in range(blocks):
        carry[k] = state
        state = end_grow[k] * state + end_local[k]
    z = (local + grow * carry[:, None]).ravel()[:count]
    return np.concatenate([[z0], z])


def _simulate_uniform(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, h: float, u: np.ndarray,
                      x0: np.ndarray, hold: str, y_out: np.ndarray) -> np.ndarray:
    """Uniform-step simulation in blocks of L samples with matrix products.

    With w[k] = x[k] - Gb u[k] the discrete system is w[k+1] = Phi w[k] + Bd u[k], y[k] = C w[k] + Dd u[k].
    Within each block the zero-state output is a Toeplitz product with the Markov parameters; block start
    states follow a short sequential recursion over blocks.
    """
    phi, ga, gb = _discretise(a, b, h, hold)
    cc = c[0]
    bd = phi @ gb + ga
    dd = d[0, 0] + cc @ gb
    count = u.size
    n = phi.shape[0]
    length = min(_BLOCK, count)
    # O[j] = C Phi^j and markov[j] = C Phi^(j-1) Bd (j >= 1), markov[0] = Dd; R[:, i] = Phi^(L-1-i) Bd.
    observ = np.empty((length, n))
    powers_b = np.empty((length, n))
    row = cc.copy()
    col = bd.copy()
    for j in range(length):
        observ[j] = row
        powers_b[j] = col
        row = row @ phi
        col = phi @ col
    phi_block = np.linalg.matrix_power(phi, length)
    markov = np.concatenate([[dd], observ[:-1] @ bd])
    index = np.arange(length)
    lag = index[:, None] - index[None, :]
    toeplitz = np.where(lag >= 0, markov[np.clip(lag, 0, None)], 0.0)  # y_local = toeplitz @ u_block
    reach = powers_b[::-1].T  # n x L
    blocks = -(-count // length)
    padded = np.zeros(blocks * length)
    padded[:count] = u
    u_blocks = padded.reshape(blocks, length)
    y_local = u_blocks @ toeplitz.T
    drive = u_blocks @ reach.T  # blocks x n
    starts = np.empty((blocks, n))
    w = x0 - gb * u[0]
    for k in range(blocks):
        starts[k] = w
        w = phi_block @ w + drive[k]
    y = (y_local + starts @ observ.T).ravel()[:count]
    y_out[:] = y
    # state at the last sample: propagate from the start of the last block
    last_block = (count - 1) // length
    w = starts[last_block]
    for k in range(last_block * length, count - 1):
        w = phi @ w + bd * u[k]
    return w + gb * u[-1]
