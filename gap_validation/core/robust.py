"""The controller check: Vinnicombe's generalised stability margin b(P, C) and the guarantee b(P1, C) >
nu-gap.

Sign convention: the config's ``controller`` closes a *negative* feedback loop, ``u = -C y`` (DESIGN.md; the
convention of MATLAB's ``ncfmargin``). Vinnicombe (*Uncertainty and Feedback*, 2001) writes the loop with
positive feedback, ``u = C_v y``, so ``C_v = -C`` and

    b(P, C) = 1 / || [P; I] (I - C_v P)^-1 [-C_v, I] ||_inf = 1 / || [P; I] (I + C P)^-1 [C, I] ||_inf

when the loop of P and C is internally stable, and 0 otherwise. For SISO loops the matrix has rank one and
``b(w) = |1 + P C| / sqrt((1 + |P|^2) (1 + |C|^2))``: the chordal distance (eq. 13) between P and ``-1/C``,
the critical point of the Nyquist plot seen on the Riemann sphere. b is at most 1; 0.3 to 0.4 is a typical
good design. Robust stability (Vinnicombe 2001, the nu-gap's central theorem): a controller that stabilises
the model P1 with margin b(P1, C) stabilises every plant P2 with ``nu-gap(P1, P2) < b(P1, C)``. So
``guaranteed_stable = b(P1, C) > nu-gap(P1, P2)``.

SISO loops (delays allowed) are checked with polynomials: internal stability from the closed-loop
characteristic (quasi-)polynomial ``d_P d_C + n_P n_C exp(-s T)`` (roots, or the argument principle along the
axis with a delay), and the inf of b(w) located like the nu-gap's sup (:mod:`gap_validation.core.metrics`:
a grid over every feature frequency, refined to 1e-8 relative). MIMO loops (state space, minimal
realizations): the closed-loop A's eigenvalues, and the H-infinity norm of the closed loop
(:func:`gap_validation.core.statespace.hinf_norm`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gap_validation.core import statespace
from gap_validation.core.metrics import (
    analysis_grid,
    axis_turns,
    combined,
    coprime,
    feature_roots,
    mirror,
    on_axis,
    polynomial_roots,
    sup_with_ends,
)
from gap_validation.core.models import LinearModel, MimoModel, strip_leading_zeros

#: A model as the metrics take it.
Model = LinearModel | MimoModel

# I + D_C D_P (or 1 + P(inf) C(inf)) beyond this condition number: the loop is ill-posed
_ILL_POSED_COND = 1e12
_UNSTABLE_RTOL = 1e-9  # closed-loop poles with Re >= -1e-9 |pole| (or on the axis) are not stable


@dataclass(frozen=True)
class StabilityMargin:
    """b(P, C) with where it is attained and, when it is 0, why.

    Attributes
    ----------
    b : float
        The generalised stability margin, 0 <= b <= 1 (0: the loop is not internally stable).
    frequency_rad_s : float
        Where ``sigma_max`` of the closed-loop matrix peaks, i.e. where b is attained [rad/s] (``inf``: the
        limit at infinity; nan when b = 0 because the loop is unstable).
    stable : bool
        Whether the loop of P and C is internally stable.
    reason : str
        Why it is not (one line; empty when stable).
    """

    b: float
    frequency_rad_s: float
    stable: bool = True
    reason: str = ""


@dataclass(frozen=True)
class ControllerCheck:
    """The controller check of one channel: b(P1, C) against the nu-gap.

    Attributes
    ----------
    stability_margin_b : float
        b(P1, C) (:func:`stability_margin`).
    frequency_rad_s : float or None
        Where b is attained [rad/s] (None when unstable or at infinity).
    nu_gap : float or None
        The nu-gap compared with (None: none yet).
    guaranteed_stable : bool or None
        ``b(P1, C) > nu-gap`` (None without a nu-gap).
    sentence : str
        ``the controller is guaranteed to stabilise the aircraft: b = 0.71 > nu-gap 0.09`` (or why not).
    """

    stability_margin_b: float
    frequency_rad_s: float | None
    nu_gap: float | None
    guaranteed_stable: bool | None
    sentence: str


def stability_margin(plant: Model, controller: Model) -> tuple[float, float]:
    """Generalised stability margin b(P, C) of the negative-feedback loop ``u = -C y`` (module docstring).

    Parameters
    ----------
    plant : LinearModel or MimoModel
        P, p outputs x m inputs (delays allowed for SISO).
    controller : LinearModel or MimoModel
        C, m outputs x p inputs: reads the plant's outputs, drives its inputs.

    Returns
    -------
    b : float
        ``1 / ||[P; I] (I + C P)^-1 [C, I]||_inf`` for an internally stable loop, else 0.
    w_rad_s : float
        Frequency where b is attained [rad/s] (``inf`` for the limit at infinity, nan for an unstable loop).

    Raises
    ------
    ValueError
        When the controller's shape does not fit the plant's.
    """
    margin = margin_of(plant, controller)
    return margin.b, margin.frequency_rad_s


def margin_of(plant: Model, controller: Model) -> StabilityMargin:
    """:func:`stability_margin` with the reason when the loop is unstable.

    Parameters
    ----------
    plant, controller : LinearModel or MimoModel
        As for :func:`stability_margin`.
    """
    shape_p = getattr(plant, "shape", (1, 1))
    shape_c = getattr(controller, "shape", (1, 1))
    if tuple(shape_c) != tuple(shape_p)[::-1]:
        raise ValueError(f"a {shape_p[0]}x{shape_p[1]} plant needs a {shape_p[1]}x{shape_p[0]} controller "
                         f"(outputs x inputs), got {shape_c[0]}x{shape_c[1]}")
    if tuple(shape_p) == (1, 1):
        return _siso_margin(_siso(plant), _siso(controller))
    return _state_space_margin(plant.minimal_state_space(), controller.minimal_state_space())


def _siso(model: Model) -> LinearModel:
    return model.siso() if isinstance(model, MimoModel) else model


# ----------------------------------------------------------------------------------------------------------
# SISO: polynomials (delays allowed)
# ----------------------------------------------------------------------------------------------------------


def _value_at_infinity(num: np.ndarray, den: np.ndarray) -> float:
    num, den = strip_leading_zeros(num), strip_leading_zeros(den)
    return float(num[0] / den[0]) if len(num) == len(den) and np.any(num) else 0.0


def _siso_margin(plant: LinearModel, controller: LinearModel) -> StabilityMargin:
    n_p, d_p = coprime(plant.num, plant.den)
    n_c, d_c = coprime(controller.num, controller.den)
    delay_s = plant.delay_s + controller.delay_s
    loop_den, loop_num = np.polymul(d_p, d_c), np.polymul(n_p, n_c)
    k_inf = _value_at_infinity(n_p, d_p) * _value_at_infinity(n_c, d_c)
    unstable = _siso_instability(loop_den, loop_num, k_inf, delay_s,
                                 np.concatenate([polynomial_roots(p) for p in (d_p, d_c, n_p, n_c)]))
    if unstable is not None:
        return unstable

    def b_of(w: np.ndarray) -> np.ndarray:
        s = 1j * np.asarray(w, dtype=float)
        values = []
        for num, den in ((n_p, d_p), (n_c, d_c)):
            n, d = np.polyval(num, s), np.polyval(den, s)
            scale = np.maximum(np.abs(n), np.abs(d))
            scale = np.where(scale > 0.0, scale, 1.0)
            values += [n / scale, d / scale]
        np_, dp_, nc_, dc_ = values
        closed = dp_ * dc_ + np_ * nc_ * np.exp(-s * delay_s)
        return np.abs(closed) / np.sqrt(
            (np.abs(np_) ** 2 + np.abs(dp_) ** 2) * (np.abs(nc_) ** 2 + np.abs(dc_) ** 2)
        )

    nn, dd = np.polymul(loop_num, mirror(loop_num)), np.polymul(loop_den, mirror(loop_den))
    roots = [feature_roots(plant), feature_roots(controller), polynomial_roots(combined(nn, dd, -1.0)),
             polynomial_roots(combined(nn, dd))]
    if delay_s == 0.0:
        roots.append(polynomial_roots(combined(loop_den, loop_num)))
    w = analysis_grid(np.concatenate(roots), delay_s)
    kp, kc = _value_at_infinity(n_p, d_p), _value_at_infinity(n_c, d_c)
    norm = math.sqrt((1.0 + kp * kp) * (1.0 + kc * kc))
    at_infinity = (abs(1.0 - abs(kp * kc)) if delay_s and kp * kc else abs(1.0 + kp * kc)) / norm
    value, where = sup_with_ends(lambda x: -b_of(x), -float(b_of(np.array([0.0]))[0]), -at_infinity, w)
    return StabilityMargin(min(max(-value, 0.0), 1.0), where)


def _siso_instability(loop_den: np.ndarray, loop_num: np.ndarray, k_inf: float, delay_s: float,
                      hints: np.ndarray) -> StabilityMargin | None:
    """None when the loop is internally stable, else b = 0 with the reason."""
    if abs(1.0 + k_inf) <= 1.0 / _ILL_POSED_COND and not delay_s:
        return StabilityMargin(
            0.0, math.inf, False, "1 + P C vanishes at infinity (P(inf) C(inf) = -1: the loop is ill-posed)"
        )
    if delay_s == 0.0:
        roots = polynomial_roots(np.polyadd(loop_den, loop_num))
        bad = (roots.real >= -_UNSTABLE_RTOL * np.abs(roots)) | on_axis(roots)
        if np.any(bad):
            worst = roots[bad][np.argmax(roots[bad].real)]
            return StabilityMargin(
                0.0,
                math.nan,
                False,
                f"the closed loop of model and controller is unstable (pole at {_format_root(worst)})",
            )
        return None
    if abs(k_inf) >= 1.0:
        return StabilityMargin(0.0, math.inf, False, "|P(inf) C(inf)| >= 1 with a delay in the loop: not "
                                                     "robustly stable")
    degree = len(strip_leading_zeros(loop_den)) - 1
    turns, where = axis_turns(loop_den, loop_num, -delay_s, k_inf, polynomial_roots(loop_den), hints)
    if turns is None:
        text = "" if math.isnan(where) else f" (1 + P C vanishes near w = {where:.6g} rad/s)"
        return StabilityMargin(
            0.0, where, False, f"the closed loop of model and controller is not stable{text}"
        )
    right = int(round(degree / 2.0 - turns))
    if abs(turns - degree / 2.0) < 0.25:
        return None
    return StabilityMargin(
        0.0,
        math.nan,
        False,
        f"the closed loop of model and controller is unstable ({right} "
        f"pole{'s' * (right != 1)} in the right half plane)",
    )


def _format_root(root: complex) -> str:
    return f"{root.real:.4g}" if root.imag == 0.0 else f"{root.real:.4g}{root.imag:+.4g}j"


# ----------------------------------------------------------------------------------------------------------
# MIMO: state space
# ----------------------------------------------------------------------------------------------------------


def closed_loop(
    plant: statespace.StateSpace, controller: statespace.StateSpace
) -> statespace.StateSpace | None:
    """Realization of ``[P; I] (I + C P)^-1 [C, I]``: inputs ``[v1; v2]``, outputs ``[y; u]``.

    The loop ``y = P u``, ``u = v2 + C (v1 - y)`` (negative feedback, v1 a reference or sensor noise at the
    controller's input, v2 a disturbance at the plant's input); its A holds the plant's states, then the
    controller's.

    Parameters
    ----------
    plant : tuple of ndarray
        ``(A, B, C, D)`` of P, p x m.
    controller : tuple of ndarray
        ``(A, B, C, D)`` of C, m x p.

    Returns
    -------
    tuple of ndarray or None
        None when the loop is ill-posed (``I + D_C D_P`` singular).
    """
    ap, bp, cp, dp = plant
    ac, bc, cc, dc = controller
    p, m = dp.shape
    n_p, n_c = ap.shape[0], ac.shape[0]
    well_posed = np.eye(m) + dc @ dp
    if np.linalg.cond(well_posed) > _ILL_POSED_COND:
        return None
    e = np.linalg.inv(well_posed)
    u_x = e @ np.hstack([-dc @ cp, cc])                 # u from the states
    u_v = e @ np.hstack([dc, np.eye(m)])                # u from [v1; v2]
    y_x = np.hstack([cp, np.zeros((p, n_c))]) + dp @ u_x
    y_v = dp @ u_v
    a = np.zeros((n_p + n_c, n_p + n_c))
    a[:n_p, :n_p] = ap
    a[n_p:, n_p:] = ac
    a[:n_p] += bp @ u_x
    a[n_p:] -= bc @ y_x
    b = np.vstack([bp @ u_v, bc @ np.hstack([np.eye(p), np.zeros((p, m))]) - bc @ y_v])
    return a, b, np.vstack([y_x, u_x]), np.vstack([y_v, u_v])


def _state_space_margin(plant: statespace.StateSpace, controller: statespace.StateSpace) -> StabilityMargin:
    loop = closed_loop(plant, controller)
    if loop is None:
        return StabilityMargin(0.0, math.inf, False, "I + D_C D_P is singular: the loop is ill-posed")
    poles = np.linalg.eigvals(loop[0]) if loop[0].size else np.zeros(0, dtype=complex)
    bad = (poles.real >= -_UNSTABLE_RTOL * np.abs(poles)) | on_axis(poles)
    if np.any(bad):
        worst = poles[bad][np.argmax(poles[bad].real)]
        return StabilityMargin(
            0.0,
            math.nan,
            False,
            f"the closed loop of model and controller is unstable (pole at {_format_root(worst)})",
        )
    gamma, where = statespace.hinf_norm(loop)
    return StabilityMargin(min(1.0 / gamma, 1.0) if gamma > 0.0 else 1.0, where)


# ----------------------------------------------------------------------------------------------------------
# the check and its sentence
# ----------------------------------------------------------------------------------------------------------


def _pair_text(b: float, gap: float) -> tuple[str, str]:
    """b and the nu-gap with two decimals (two significant digits below 0.01), more while they read equal."""
    smallest = min((abs(x) for x in (b, gap) if x), default=1.0)
    first = 2 if smallest >= 0.01 else min(1 - math.floor(math.log10(smallest)), 6)
    for digits in range(first, 7):
        left, right = f"{b:.{digits}f}", f"{gap:.{digits}f}"
        if left != right:
            return left, right
    return f"{b:.6f}", f"{gap:.6f}"


def stability_sentence(margin: StabilityMargin, nu_gap: float | None, measured: bool = False) -> str:
    """The controller check in words, for the terminal and the report.

    Parameters
    ----------
    margin : StabilityMargin
        b(P1, C) (:func:`margin_of`).
    nu_gap : float or None
        nu-gap between the model and the aircraft (or the second model); None when there is none yet.
    measured : bool
        The nu-gap is from flight data (over the measured band, winding-number condition assumed): said so.

    Returns
    -------
    str
        ``the controller is guaranteed to stabilise the aircraft: b = 0.71 > nu-gap 0.09``, or why not.
    """
    if not margin.stable:
        return f"the controller does not stabilise the model: b = 0 ({margin.reason})"
    if nu_gap is None or math.isnan(nu_gap):
        return f"b = {_pair_text(margin.b, margin.b)[0]}: no nu-gap yet to compare with"
    b_text, gap_text = _pair_text(margin.b, nu_gap)
    if margin.b > nu_gap:
        text = f"the controller is guaranteed to stabilise the aircraft: b = {b_text} > nu-gap {gap_text}"
    else:
        text = (
            f"no guarantee that the controller stabilises the aircraft: b = {b_text} <= nu-gap {gap_text} "
            f"(the model is not close enough for this controller)"
        )
    if measured:
        text += " (nu-gap over the measured band, winding-number condition assumed)"
    return text


def controller_check(plant: Model, controller: Model, nu_gap: float | None, measured: bool = False,
                     margin: StabilityMargin | None = None) -> ControllerCheck:
    """b(P1, C) against the nu-gap: ``guaranteed_stable = b(P1, C) > nu-gap`` (Vinnicombe's robust stability).

    Parameters
    ----------
    plant : LinearModel or MimoModel
        The model P1 the controller was designed on.
    controller : LinearModel or MimoModel
        C, negative feedback ``u = -C y``.
    nu_gap : float or None
        nu-gap(P1, P2) (exact between models, or measured); None when there is none yet.
    measured : bool
        The nu-gap is from flight data (the sentence says what it assumes).
    margin : StabilityMargin, optional
        b(P1, C) when already computed (e.g. cached): skips :func:`margin_of`.

    Returns
    -------
    ControllerCheck
    """
    margin = margin if margin is not None else margin_of(plant, controller)
    has_gap = nu_gap is not None and not math.isnan(nu_gap)
    where = margin.frequency_rad_s if margin.stable and math.isfinite(margin.frequency_rad_s) else None
    return ControllerCheck(stability_margin_b=float(margin.b), frequency_rad_s=where,
                           nu_gap=float(nu_gap) if has_gap else None,
                           guaranteed_stable=bool(margin.b > nu_gap) if has_gap else None,
                           sentence=stability_sentence(margin, nu_gap if has_gap else None, measured))
