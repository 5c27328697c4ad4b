"""MIMO validation from flight data: the whole response matrix against a MIMO model (issue 14).

Single-axis manoeuvres flown in turn (aileron sweeps, then rudder sweeps) each excite one input of a MIMO
channel; the estimator pools their local polynomial sums,
and :func:`~gap_validation.core.spectra.solve_matrix` solves them for the whole p x m matrix ``H = G_yu
G_uu^-1`` with a variance per element (as CIFER does). This module compares that matrix with the
channel's :class:`~gap_validation.core.models.MimoModel`:

- **kappa(w)**: Vinnicombe's MIMO chordal distance ``sigma_max((I + H H*)^-1/2 (H - P) (I + P* P)^-1/2)``
  (:func:`~gap_validation.core.metrics.chordal_distance`); the **nu-gap** is its sup over the confident
  frequencies (the winding-number condition assumed, as for SISO data).
- **Confident frequencies**: every element estimated, at least one degree of freedom, and the *multiple
  coherence of every output* (the fraction of that output explained by all inputs together) at least the
  channel's threshold and beyond what noise alone gives (the SISO rule of
  :func:`~gap_validation.core.evidence.confident_points` with ``m (order + 1)`` coefficients). The
  per-element
  *partial coherence* (what input j explains of output i once the other inputs are accounted for) is reported
  for plots and words, not used to exclude points: a small cross-coupling element has a low partial coherence
  on perfectly good data.
- **Random error of kappa**: exactly ``kappa(H, H + dH) = sigma_max((I + (H+dH)(H+dH)*)^-1/2 dH
  (I + H* H)^-1/2) <= sigma_max(dH)``, so to first order the noise scale of kappa is the rms of the Frobenius
  norm of ``L dH R`` (weights ``L``, ``R`` of the measured and model matrices, independent element errors of
  the estimated variances plus the 1 % systematic floor :data:`~gap_validation.core.evidence.BIAS_ERROR`):
  :func:`kappa_noise_scale`; Frobenius bounds ``sigma_max``.
- **Model- or data-limited**: where kappa passes ``kappa_threshold`` (0.15) a confident point is model-limited
  when the data differ from the model *seen through the estimator*
  (:func:`~gap_validation.core.spectra.expected_matrix`, which removes the estimator's smoothing bias) by more
  than :data:`~gap_validation.core.evidence.SIGMA_FACTOR` noise scales, else data-limited.
- **Where it fails**: at the worst frequency, the kappa each element's mismatch alone would give
  (``|H_ij - P_ij| |L e_i| |e_j^T R|``), ranked; the largest names the element that dominates.
- **Diagnosis per input column**: an actuator effect belongs to an input, so a ``gain`` and a ``time_delay``
  are fitted on each input column (the model's column j times the factor) and reported when they bring the
  nu-gap down for real (:func:`diagnose_columns`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from gap_validation.core import metrics, wording
from gap_validation.core.evidence import BIAS_ERROR, SIGMA_FACTOR, confident_mask
from gap_validation.core.models import MimoModel
from gap_validation.core.results import Band, Candidate, MimoDetail
from gap_validation.core.spectra import MatrixEstimate

__all__ = ["MimoDetail", "MimoAnalysis", "analyse_mimo", "element_kappa", "kappa_noise_scale",
           "diagnose_columns", "take_frequencies", "KAPPA_THRESHOLD", "MIN_RELATIVE_IMPROVEMENT"]

#: kappa(w) above it makes a band (the SISO diagnosis' epsilon threshold; kappa <= epsilon for SISO).
KAPPA_THRESHOLD = 0.15
#: A column effect must remove at least this fraction of the nu-gap (and leave the data within their errors
#: where it was model-limited) to be reported.
MIN_RELATIVE_IMPROVEMENT = 0.25


@dataclass
class MimoAnalysis:
    """What :func:`analyse_mimo` finds (the validator copies it into the channel's result)."""

    w_rad_s: np.ndarray
    detail: MimoDetail
    kappa: np.ndarray
    coherence: np.ndarray
    dof: np.ndarray
    confident: np.ndarray
    flags: list[str]
    bands: list[Band]
    limited_by: str
    nu_gap: float | None
    nu_gap_frequency_rad_s: float | None
    message: str
    diagnosis: list[Candidate] = field(default_factory=list)


def take_frequencies(matrix: MatrixEstimate, index: slice | np.ndarray) -> MatrixEstimate:
    """The estimate at the frequencies ``index`` only.

    Parameters
    ----------
    matrix : MatrixEstimate
        A solved matrix.
    index : slice or array_like
        Frequencies to keep.
    """
    return MatrixEstimate(*(np.asarray(getattr(matrix, f))[index] for f in matrix.__dataclass_fields__))


def _weights(h: np.ndarray, p_model: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column norms of ``L = (I + H H*)^-1/2`` (per output row i: ``|L e_i|``) and row norms of
    ``R = (I + P* P)^-1/2`` (per input j: ``|e_j^T R|``), per frequency."""
    left = metrics.inv_sqrt_gram(h, "left")
    right = metrics.inv_sqrt_gram(p_model, "right")
    return np.linalg.norm(left, axis=-2), np.linalg.norm(right, axis=-1)


def element_kappa(p_model: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The kappa each element's mismatch alone gives: ``|H_ij - P_ij| |L e_i| |e_j^T R|`` (F, p, m).

    ``kappa <= sum_ij element_kappa`` (triangle inequality); the largest element is the one that dominates
    kappa.

    Parameters
    ----------
    p_model, h : ndarray, (F, p, m) complex
        Model and measured matrices (finite).
    """
    left, right = _weights(h, p_model)
    return np.abs(h - p_model) * left[:, :, None] * right[:, None, :]


def kappa_noise_scale(p_model: np.ndarray, h: np.ndarray, variance: np.ndarray,
                      bias_error: float = BIAS_ERROR) -> np.ndarray:
    """Noise scale of kappa(w): ``sqrt(sum_ij sigma_ij^2 |L e_i|^2 |e_j^T R|^2)``, the rms of ``|| L dH
    R ||_F`` for independent element errors of standard deviation ``sigma_ij`` (the measured element's, with
    the relative floor ``bias_error |H_ij|``); to first order in the error it bounds the rms of kappa(H, H +
    dH) (Frobenius bounds sigma_max; see the module docstring), per frequency.

    Parameters
    ----------
    p_model, h : ndarray, (F, p, m) complex
        Model and measured matrices.
    variance : ndarray, (F, p, m)
        Variance of each measured element.
    bias_error : float
        Systematic floor relative to ``|H_ij|``.
    """
    left, right = _weights(h, p_model)
    sigma2 = np.asarray(variance, float) + (bias_error * np.abs(h)) ** 2
    return np.sqrt(np.sum(sigma2 * (left[:, :, None] * right[:, None, :]) ** 2, axis=(1, 2)))


def _confident(matrix: MatrixEstimate, coherence_threshold: float, coefficients: int) -> tuple[np.ndarray,
                                                                                                 np.ndarray]:
    """Confident frequencies (every output's multiple coherence passes, as
    :func:`~gap_validation.core.evidence.confident_points` for SISO) and the worst output's coherence."""
    finite = np.all(np.isfinite(matrix.response), axis=(1, 2))
    coherence = np.min(matrix.multiple_coherence, axis=1)
    size = np.where(finite, np.linalg.norm(np.where(np.isfinite(matrix.response), matrix.response, 0.0),
                                           axis=(1, 2)), np.nan)
    return confident_mask(size, coherence, matrix.dof, coefficients, coherence_threshold) & finite, coherence


def _bands(w: np.ndarray, kappa: np.ndarray, flags: list[str], k: np.ndarray, coherence: np.ndarray,
           dof: np.ndarray) -> list[Band]:
    """Runs of adjacent frequencies flagged ``model`` or ``data``; a band's ``epsilon`` holds its peak kappa
    (of a model-limited band: over its model-limited points)."""
    bands, i = [], 0
    while i < len(flags):
        if flags[i] not in ("model", "data"):
            i += 1
            continue
        j = i
        while j + 1 < len(flags) and flags[j + 1] in ("model", "data"):
            j += 1
        idx = np.arange(i, j + 1)
        verdict = "model" if any(flags[t] == "model" for t in idx) else "data"
        # a model-limited band peaks where it is model-limited
        judged = idx[[flags[t] == verdict for t in idx]]
        peak = int(judged[np.nanargmax(kappa[judged])])
        reason = wording.mimo_band_reason(verdict, float(kappa[peak]), float(w[peak]),
                                          float(np.nanmax(k[idx])) if verdict == "model" else math.nan)
        bands.append(
            Band(
                float(w[i]),
                float(w[j]),
                float(w[peak]),
                float(kappa[peak]),
                verdict,
                reason,
                float(np.nanmin(coherence[idx])),
                float(np.nanmax(k[idx])),
                float(np.min(dof[idx])),
            )
        )
        i = j + 1
    return bands


def analyse_mimo(model: MimoModel, matrix: MatrixEstimate, w_rad_s: np.ndarray, coherence_threshold: float,
                 inputs: Sequence[str], outputs: Sequence[str], *, coefficients: int,
                 expected: Callable[[Callable], np.ndarray] | None = None, excited: np.ndarray | None = None,
                 kappa_threshold: float = KAPPA_THRESHOLD, sigma_factor: float = SIGMA_FACTOR,
                 diagnose: bool = True) -> MimoAnalysis:
    """Compare a MIMO model with the measured response matrix: kappa, nu-gap, model- or data-limited, where.

    Parameters
    ----------
    model : MimoModel
        The channel's model (``freqresp`` gives (F, p, m)).
    matrix : MatrixEstimate
        The pooled measured matrix (:func:`~gap_validation.core.spectra.solve_matrix`).
    w_rad_s : ndarray, (F,)
        Frequencies [rad/s].
    coherence_threshold : float
        The channel's threshold (on every output's multiple coherence).
    inputs, outputs : sequence of str
        Names of the columns and rows.
    coefficients : int
        Response coefficients per output (``m (order + 1)``): the chance test of the coherence.
    expected : callable, optional
        ``expected(model_response) -> (F, p, m)``: the model seen through the estimator
        (:func:`~gap_validation.core.spectra.expected_matrix`); default the model itself.
    excited : ndarray of bool, optional
        Frequencies the flight excited (else: where the matrix is finite).
    kappa_threshold, sigma_factor : float
        kappa(w) above ``kappa_threshold`` makes a band; model-limited beyond ``sigma_factor`` noise scales.
    diagnose : bool
        Fit the column effects (:func:`diagnose_columns`) when model-limited.

    Returns
    -------
    MimoAnalysis
    """
    w = np.asarray(w_rad_s, float)
    h = np.asarray(matrix.response, complex)
    p_model = np.asarray(model.freqresp(w), complex)
    confident, coherence = _confident(matrix, coherence_threshold, coefficients)
    finite = np.all(np.isfinite(h), axis=(1, 2))
    h_safe = np.where(np.isfinite(h), h, 0.0)
    var_safe = np.where(np.isfinite(matrix.variance), matrix.variance, 0.0)
    kappa = np.where(finite, metrics.chordal_distance(p_model, h_safe), np.nan)
    noise = np.where(finite, kappa_noise_scale(p_model, h_safe, var_safe), np.inf)
    seen = p_model if expected is None else np.asarray(expected(model.freqresp), complex)
    seen = np.where(np.isfinite(seen), seen, p_model)
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.where(finite, metrics.chordal_distance(seen, h_safe) / noise, 0.0)
    excited = finite if excited is None else np.asarray(excited, bool)
    flags = []
    for i in range(w.size):
        if not excited[i] or not finite[i]:
            flags.append("not_excited")
        elif kappa[i] <= kappa_threshold:
            flags.append("ok" if confident[i] else "excluded")
        elif confident[i] and k[i] > sigma_factor:
            flags.append("model")
        else:
            flags.append("data")
    bands = _bands(w, kappa, flags, k, coherence, matrix.dof)
    verdicts = {b.limited_by for b in bands}
    limited_by = ("data" if not confident.any() else "model" if "model" in verdicts else
                  "data" if verdicts else "none")
    nu_gap, w_peak = (None, None)
    if confident.any():
        value, w_peak = metrics.nugap_frequency_data(w[confident], p_model[confident], h[confident])
        nu_gap, w_peak = (float(value), float(w_peak)) if np.isfinite(value) else (None, None)
    detail = MimoDetail(inputs=list(inputs), outputs=list(outputs), measured=h, model=p_model,
                        variance=np.asarray(matrix.variance, float),
                        partial_coherence=np.asarray(matrix.partial_coherence, float),
                        multiple_coherence=np.asarray(matrix.multiple_coherence, float), kappa_noise=noise)
    lead = max((b for b in bands if b.limited_by == "model"), key=lambda b: b.epsilon, default=None)
    where = lead.peak_rad_s if lead is not None and limited_by == "model" else w_peak
    if where is not None:
        at = int(np.flatnonzero(w == where)[0])
        detail.worst_elements_frequency_rad_s = float(where)
        alone = element_kappa(p_model[at:at + 1], h[at:at + 1])[0]
        order = np.argsort(alone, axis=None)[::-1]
        detail.worst_elements = [{"output": outputs[i], "input": inputs[j], "output_index": int(i),
                                  "input_index": int(j), "kappa_alone": float(alone[i, j])}
                                 for i, j in (np.unravel_index(o, alone.shape) for o in order)]
    analysis = MimoAnalysis(
        w,
        detail,
        kappa,
        coherence,
        np.asarray(matrix.dof, float),
        confident,
        flags,
        bands,
        limited_by,
        nu_gap,
        w_peak,
        "",
    )
    if diagnose and limited_by == "model":
        model_points = np.array([f == "model" for f in flags])
        analysis.diagnosis = diagnose_columns(
            model, w, h, confident, inputs, noise, sigma_factor, model_points
        )
    analysis.message = _message(analysis, kappa_threshold)
    return analysis


def _message(a: MimoAnalysis, kappa_threshold: float) -> str:
    """One line (:func:`~gap_validation.core.wording.mimo_message`)."""
    element = element_rad_s = kappa_all = None
    if a.nu_gap is not None and a.limited_by != "none" and a.detail.worst_elements:
        element, element_rad_s = a.detail.worst_elements[0], a.detail.worst_elements_frequency_rad_s
        kappa_all = float(a.kappa[np.flatnonzero(a.w_rad_s == element_rad_s)[0]])
    return wording.mimo_message(
        nu_gap=a.nu_gap, limited_by=a.limited_by, bands=a.bands, kappa_threshold=kappa_threshold,
        element=element, element_rad_s=element_rad_s, kappa_all=kappa_all,
        top_sentence=a.diagnosis[0].sentence if a.diagnosis else None,
    )


# ------------------------------------------------------------------------------------- diagnosis per column
def _column_factor(kind: str, value: float, w: np.ndarray) -> np.ndarray:
    """The factor an effect puts on an input column: ``gain`` k, ``time_delay`` exp(-j w T)."""
    return np.full(w.shape, value, complex) if kind == "gain" else np.exp(-1j * w * value)


def _with_column(p_model: np.ndarray, j: int, factor: np.ndarray) -> np.ndarray:
    out = p_model.copy()
    out[:, :, j] = out[:, :, j] * factor[:, None]
    return out


#: Column effects fitted (DESIGN.md vocabulary): bounds of the parameter searched.
_COLUMN_EFFECTS = {"gain": ("factor", (0.1, 10.0)), "time_delay": ("seconds", (0.0, 0.3))}


def diagnose_columns(
    model: MimoModel,
    w: np.ndarray,
    h: np.ndarray,
    confident: np.ndarray,
    inputs: Sequence[str],
    noise: np.ndarray,
    sigma_factor: float = SIGMA_FACTOR,
    model_points: np.ndarray | None = None,
) -> list[Candidate]:
    """Actuator effects per input column (an effect of a surface acts on its column of the matrix): a ``gain``
    and a ``time_delay`` on each column, fitted to minimise the sum of kappa(w)^2 over the confident
    frequencies (a grid of 61 values, then a bounded scalar search around the best), ranked by how much of
    kappa they remove where the model is model-limited.

    A candidate is reported when, over the model-limited frequencies (``model_points``; default every
    confident one), it removes at least :data:`MIN_RELATIVE_IMPROVEMENT` of the sup of kappa and more than
    ``sigma_factor`` noise scales of kappa where that sup was. Its ``parameters`` name the ``input``;
    its ``effects`` are the mapping to put on that input (MIMO models take no ``effects`` in the config yet:
    apply it to the B column, or D, by hand).

    Parameters
    ----------
    model : MimoModel
        The channel's model.
    w : ndarray, (F,)
        Frequencies [rad/s].
    h : ndarray, (F, p, m) complex
        Measured matrix.
    confident : ndarray of bool, (F,)
        Frequencies used.
    inputs : sequence of str
        Column names.
    noise : ndarray, (F,)
        Noise scale of kappa (:func:`kappa_noise_scale`).
    sigma_factor : float
        Noise scales an improvement must exceed.
    model_points : ndarray of bool, (F,), optional
        The model-limited frequencies (where the improvement is judged).

    Returns
    -------
    list of Candidate
        Best first; empty when nothing helps for real.
    """
    from scipy.optimize import minimize_scalar

    if np.count_nonzero(confident) < 2:
        return []
    wc, hc = w[confident], h[confident]
    pc = np.asarray(model.freqresp(wc), complex)
    judged = (np.ones(wc.size, bool) if model_points is None else np.asarray(model_points, bool)[confident])
    judged = judged if judged.any() else np.ones(wc.size, bool)
    kappa0 = metrics.chordal_distance(pc, hc)
    nu_before = float(np.max(kappa0))
    before = float(np.max(kappa0[judged]))
    at = int(np.flatnonzero(judged)[np.argmax(kappa0[judged])])
    out = []
    for j, name in enumerate(inputs):
        for kind, (param, (lo, hi)) in _COLUMN_EFFECTS.items():
            def cost(x: float) -> float:
                value = math.exp(x) if kind == "gain" else x
                return float(
                    np.sum(
                        metrics.chordal_distance(_with_column(pc, j, _column_factor(kind, value, wc)), hc)
                        ** 2
                    )
                )

            # a grid first (a delay's cost has local minima), then a bounded search between the best point's
            # neighbours
            grid = np.linspace(*((math.log(lo), math.log(hi)) if kind == "gain" else (lo, hi)), 61)
            best = int(np.argmin([cost(x) for x in grid]))
            bounds = (grid[max(best - 1, 0)], grid[min(best + 1, grid.size - 1)])
            found = minimize_scalar(cost, bounds=bounds, method="bounded", options={"xatol": 1e-6})
            value = math.exp(found.x) if kind == "gain" else float(found.x)
            kappa = metrics.chordal_distance(_with_column(pc, j, _column_factor(kind, value, wc)), hc)
            after = float(np.max(kappa[judged]))
            gained = before - after
            if gained < MIN_RELATIVE_IMPROVEMENT * before or gained <= sigma_factor * float(
                noise[confident][at]
            ):
                continue
            value = float(f"{value:.4g}")
            spec = {"type": kind, param: value}
            nu_after = float(np.max(kappa))
            out.append(
                Candidate(
                    effect=kind,
                    parameters={param: value, "input": name, "input_index": j},
                    effects=[spec],
                    epsilon=None,
                    nu_gap=nu_after,
                    sentence=wording.mimo_column_sentence(
                        name, kind, value, kappa_before=before, kappa_after=after, nu_gap_before=nu_before,
                        nu_gap_after=nu_after,
                    ),
                    improvement=gained,
                    worst_frequency_rad_s=float(wc[int(np.argmax(kappa))]),
                    complexity=1,
                    explains=bool(np.all(kappa <= sigma_factor * noise[confident])),
                    note=None,
                )
            )
    return sorted(out, key=lambda c: (c.improvement is None, -(c.improvement or 0.0)))
