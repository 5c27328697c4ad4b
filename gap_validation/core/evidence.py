"""Where the model fails, against what the data can tell: the statistics of a measured response.

Per frequency the overbounding-disk distance ``epsilon(w) = |P2-P1|/|P2+P1|`` (paper eq. 14) between the model
P1 and the averaged measured response P2 is compared with what the estimate's errors can explain. The estimate
is the local polynomial fit of :mod:`gap_validation.core.spectra`: its variance comes from the fit's residuals
on ``d`` degrees of freedom (bins minus every fitted coefficient, summed over manoeuvres), so the normalised
squared error of the response is exactly F(2, 2d) distributed; :func:`normalised_mismatch` turns ``epsilon /
sigma`` into the equivalent Rayleigh ``k``. The model is compared *as the estimator sees it*: its response
expanded over the same band (:meth:`SpectralEstimate.expected`), so the estimator's own smoothing of a sharp
feature is not a mismatch (the expansion's error widens sigma).

``sigma`` is the estimate's random error, or the scatter between manoeuvres where three or more are confident
(a Birge ratio above one raises it), combined with a small systematic floor :data:`BIAS_ERROR` (1 %). A
frequency is *confident* (:func:`confident_points`, the one definition the validator uses too) when its
coherence passes the threshold and pure noise would reach that coherence with probability at most
:data:`COHERENCE_FALSE_ALARM` (a Beta law in the fit's coefficients and degrees of freedom,
:func:`minimum_averages`); only confident frequencies count for epsilon, the nu-gap and the fits. Frequencies
the flight did not excite are ``not_excited`` and never model-limited; a coherent frequency with too few
degrees of freedom is data-limited where epsilon passes the threshold.

Bands where ``epsilon(w)`` passes the threshold are **model-limited** when at a usable frequency of the band
the mismatch exceeds ``k = SIGMA_FACTOR`` (4), and **data-limited** otherwise: low coherence, too few degrees
of freedom or random error comparable to the mismatch (fly the manoeuvre again there rather than change the
model). Measured: model-limited on 0.3 % of the channels of 240 simulated flights whose truth is the model
(``benchmarks/false_alarms.py``).

The decisions read an :class:`Evidence` (the averaged estimate with its confident frequencies, noise scales
and degrees of freedom, :func:`evidence_of`) and score a model on it as a :class:`Fit` (epsilon(w), its sup,
the mismatch and the chi-square). Part of the diagnosis (:mod:`gap_validation.core.diagnosis`); the
sentences are :mod:`gap_validation.core.wording`'s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike
from scipy.special import betainc

from gap_validation.core import metrics, wording
from gap_validation.core.results import Band

if TYPE_CHECKING:  # pragma: no cover
    from gap_validation.core.estimator import SpectralEstimate

__all__ = [
    "SIGMA_FACTOR",
    "BOUND_CHECK",
    "BIAS_ERROR",
    "COHERENCE_FALSE_ALARM",
    "bendat_piersol_random_error",
    "averages_of",
    "effective_random_error",
    "epsilon_noise_scale",
    "minimum_averages",
    "confident_points",
    "confident_mask",
    "normalised_mismatch",
    "log_ratio",
    "frequency_flags",
    "find_bands",
    "Evidence",
    "Fit",
    "masked_sup",
    "evidence_of",
]

#: Noise-only epsilon is Rayleigh with scale ``sigma = e/2``; ``P(eps > k sigma) = exp(-k^2/2)``: k = 4 gives
#: 3.4e-4 per frequency, about 1 % over 40 frequencies.
SIGMA_FACTOR = 4.0
#: A noise scale more than this many times wider than the coherence allows (the classical random error with
#: the systematic floor) is no random error: :func:`find_bands` says so rather than "the random error explains
#: it".
BOUND_CHECK = 10.0
#: Systematic error floor of a measured response, relative (1 % of |H|, 0.6 deg): interpolation of the
#: streams onto the grid and timestamp offsets between them. The estimator's own smoothing bias is not in it:
#: the decisions compare the data with the model seen through the estimator (``estimate.expected``).
BIAS_ERROR = 0.01
#: Probability that noise alone (zero true coherence) gives a coherence estimate above the threshold, used to
#: set the minimum number of averages of a usable frequency (:func:`minimum_averages`).
COHERENCE_FALSE_ALARM = 1e-3


def bendat_piersol_random_error(coherence: ArrayLike, n_averages: ArrayLike) -> np.ndarray:
    """Normalised random error of |H|: ``e_r = sqrt(1 - g^2) / (|g| sqrt(2 n_d))`` (Bendat & Piersol, ch. 9).

    The phase error is about ``e_r`` rad. Infinite where the coherence is zero.

    Parameters
    ----------
    coherence : array_like
        Squared coherence ``g^2``.
    n_averages : array_like
        Number of averaged segments ``n_d``.
    """
    g2 = np.clip(np.asarray(coherence, dtype=float), 0.0, 1.0)
    n = np.maximum(np.asarray(n_averages, dtype=float), 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        e_r = np.sqrt(1.0 - g2) / (np.sqrt(g2) * np.sqrt(2.0 * n))
    return np.where(g2 > 0.0, e_r, np.inf)


def averages_of(estimate: SpectralEstimate) -> np.ndarray:
    """Averages (degrees of freedom) per frequency, inf when the estimate does not say.

    Parameters
    ----------
    estimate : SpectralEstimate
        An estimate with ``coherence`` and, optionally, ``n_averages``.

    Returns
    -------
    ndarray
    """
    shape = np.shape(estimate.coherence)
    n = getattr(estimate, "n_averages", None)
    if n is None:
        return np.full(shape, np.inf)
    return np.broadcast_to(np.asarray(n, dtype=float), shape).copy()


def _random_error_of(estimate) -> np.ndarray:
    """The estimate's random error; Bendat & Piersol's formula where it carries none (or a non-finite one)."""
    computed = bendat_piersol_random_error(estimate.coherence, np.minimum(averages_of(estimate), 1e12))
    given = getattr(estimate, "random_error", None)
    if given is None:
        return computed
    given = np.asarray(given, dtype=float)
    return np.where(np.isfinite(given), given, computed)


def _sweep_scatter_error(estimate, sweeps: Sequence, coherence_threshold: float) -> np.ndarray:
    """Relative random error of the average from the scatter between manoeuvres (NaN with fewer than 3).

    Per frequency, over the m manoeuvres whose own estimate is coherent there and has a variance: the
    inverse-variance weighted mean and ``chi^2 = sum |H_i - mean|^2 / var_i`` (about m - 1 when the manoeuvres
    agree within their errors, Birge); the average's error is its own scaled by ``sqrt(chi^2 / (m - 1))``. A
    flight whose manoeuvres disagree more than their noise says (turbulence that changed, a nonlinear
    response to different amplitudes) widens the error instead of calling the difference model-limited.
    """
    w = np.asarray(estimate.w_rad_s, dtype=float)
    out = np.full(w.shape, np.nan)
    usable = [
        s for s in sweeps if np.shape(s.response) == w.shape and getattr(s, "variance", None) is not None
    ]
    if len(usable) < 3:
        return out
    h = np.array([np.asarray(s.response, dtype=complex) for s in usable])
    var = np.array([np.asarray(s.variance, dtype=float) for s in usable])
    ok = (np.array([np.asarray(s.coherence, dtype=float) >= coherence_threshold for s in usable])
          & np.isfinite(h) & np.isfinite(var) & (var > 0))
    m = ok.sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = np.where(ok, 1.0 / np.where(ok, var, 1.0), 0.0)
        mean = np.sum(weight * np.where(ok, h, 0.0), axis=0) / np.sum(weight, axis=0)
        chi2 = np.sum(weight * np.abs(np.where(ok, h - mean, 0.0)) ** 2, axis=0)
        birge = np.sqrt(np.maximum(chi2 / (m - 1), 1.0))
        e = birge * _random_error_of(estimate)
    return np.where(m >= 3, e, out)


def effective_random_error(estimate: SpectralEstimate, sweeps: Sequence[SpectralEstimate] = (),
                           coherence_threshold: float = 0.0, bias_error: float = 0.0) -> np.ndarray:
    """Relative error of the averaged response the diagnosis allows for.

    The larger of the estimate's random error (Bendat & Piersol) and the scatter between sweeps (where at
    least three sweeps are confident), combined with a systematic floor as ``sqrt(e_r^2 + bias_error^2)``.

    Parameters
    ----------
    estimate : SpectralEstimate
        Averaged estimate (``w_rad_s``, ``response``, ``coherence``, ``random_error``, ``n_averages``).
    sweeps : sequence of SpectralEstimate
        Per-sweep estimates on the same frequencies.
    coherence_threshold : float
        Sweeps count at a frequency only where their coherence passes it.
    bias_error : float
        Relative systematic error of any spectral estimate (:data:`BIAS_ERROR` in :func:`analyse_channel`).

    Returns
    -------
    ndarray
        Relative error per frequency (magnitude fraction; phase in rad).
    """
    e_bp = _random_error_of(estimate)
    e_sc = _sweep_scatter_error(estimate, sweeps, coherence_threshold)
    e_r = np.where(np.isfinite(e_sc), np.maximum(e_bp, e_sc), e_bp)
    return np.hypot(e_r, bias_error)


def epsilon_noise_scale(relative_error: ArrayLike) -> np.ndarray:
    """Scale ``sigma = e / 2`` of epsilon(w) between a model and noisy data that equal it.

    With ``P2 = P1 (1 + d)``, ``d`` complex with components of standard deviation ``e``,
    ``epsilon = |d| / |2 + d| ~ |d| / 2`` (eq. 14): Rayleigh with scale ``e / 2``.

    Parameters
    ----------
    relative_error : array_like
        Relative error ``e`` of the measured response per frequency (:func:`effective_random_error`).
    """
    return 0.5 * np.asarray(relative_error, dtype=float)


def minimum_averages(coherence_threshold: float, false_alarm: float = COHERENCE_FALSE_ALARM,
                     coefficients: int = 2) -> int:
    """Fewest degrees of freedom for which a coherence above the threshold is not plausibly noise.

    The coherence of a local polynomial fit with ``nh`` complex coefficients and ``d`` residual degrees of
    freedom is, for pure noise, Beta(nh, d) distributed (the share of the output a random regression
    explains); the result is the smallest ``d`` making ``P(coherence > c)`` at most ``false_alarm`` (10 for c
    = 0.6 and the default first-order polynomial, nh = 2), within [4, 64].

    Parameters
    ----------
    coherence_threshold : float
        Coherence a confident frequency must reach.
    false_alarm : float
        Allowed probability that noise alone passes.
    coefficients : int
        Complex coefficients of the response polynomial (``order + 1``).
    """
    c = min(max(float(coherence_threshold), 1e-6), 0.999)
    for d in range(4, 65):
        if 1.0 - betainc(coefficients, d, c) <= false_alarm:
            return d
    return 64


def confident_points(estimate: SpectralEstimate, coherence_threshold: float) -> np.ndarray:
    """Frequencies whose estimate counts for epsilon, the nu-gap and the diagnosis (the one definition).

    A point is confident when its coherence passes the threshold *and* means something: pure noise would reach
    the coherence it has with probability at most :data:`COHERENCE_FALSE_ALARM` (a Beta(nh, d) law for ``nh``
    response coefficients and ``d`` degrees of freedom, see :func:`minimum_averages`); and its response is
    finite and nonzero. At the threshold (0.6) that takes 12 degrees of freedom; a coherence of 0.99 needs
    three (one clean 8 s record).

    Parameters
    ----------
    estimate : SpectralEstimate
        Averaged estimate (``response``, ``coherence``, ``n_averages``: degrees of freedom).
    coherence_threshold : float
        The channel's coherence threshold.
    """
    return confident_mask(
        estimate.response,
        estimate.coherence,
        averages_of(estimate),
        _coefficients(estimate),
        coherence_threshold,
    )


def confident_mask(response: ArrayLike, coherence: ArrayLike, dof: ArrayLike, coefficients: int,
                   coherence_threshold: float) -> np.ndarray:
    """:func:`confident_points` on arrays (a MIMO matrix's worst output, for instance).

    Parameters
    ----------
    response : array_like, complex
        The response per frequency (a point needs it finite and nonzero).
    coherence : array_like
        Coherence per frequency.
    dof : array_like
        Degrees of freedom per frequency (inf: not limited).
    coefficients : int
        Complex coefficients of the response polynomial per frequency (the Beta law's ``nh``).
    coherence_threshold : float
        The channel's coherence threshold.
    """
    p_meas = np.asarray(response, complex)
    coherence = np.asarray(coherence, float)
    dof = np.broadcast_to(np.asarray(dof, float), coherence.shape)
    nh = int(coefficients)
    with np.errstate(invalid="ignore"):
        chance = np.where(np.isfinite(dof) & (dof >= 1), 1.0 - betainc(nh, np.maximum(dof, 1.0),
                                                                         np.clip(coherence, 0.0, 1.0)), 0.0)
    return ((coherence >= coherence_threshold) & np.isfinite(p_meas) & (np.abs(p_meas) > 0)
            & (dof >= 1) & (chance <= COHERENCE_FALSE_ALARM))


def _coefficients(estimate) -> int:
    """Complex coefficients of the estimate's response polynomial (2 when it does not say)."""
    return int(getattr(estimate, "coefficients", 2))


def normalised_mismatch(eps_w: ArrayLike, sigma: ArrayLike, dof: ArrayLike = np.inf) -> np.ndarray:
    """How many noise scales the mismatch is: the Rayleigh-equivalent ``k`` of ``epsilon / sigma``.

    With the noise variance estimated on ``d`` (complex) degrees of freedom the normalised squared error of
    the response is ``F(2, 2 d)`` distributed: ``P = (1 + r^2 / (2 d))^-d`` for ``r = epsilon / sigma``, and
    ``k = sqrt(-2 ln P) = sqrt(2 d ln(1 + r^2 / (2 d)))``, which tends to ``r`` (Rayleigh) for many degrees of
    freedom.

    Parameters
    ----------
    eps_w, sigma : array_like
        epsilon(w) and its noise scale.
    dof : array_like
        Degrees of freedom per frequency (inf: the Rayleigh limit).
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.asarray(eps_w, float) / np.asarray(sigma, float)
        d = np.maximum(np.asarray(dof, float), 0.5)
        k = np.sqrt(2.0 * d * np.log1p(r ** 2 / (2.0 * d)))
        k = np.where(np.isfinite(d), k, r)
    return np.where(np.isfinite(r), k, np.where(np.isnan(r), 0.0, np.inf))


def log_ratio(p_fit: ArrayLike, p_meas: ArrayLike) -> np.ndarray:
    """Complex log of ``p_fit / p_meas``: real part in nepers, imaginary part the wrapped phase [rad].

    Parameters
    ----------
    p_fit, p_meas : array_like of complex
        Two responses at the same frequencies.

    Returns
    -------
    ndarray
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log(p_fit / p_meas)


def frequency_flags(eps_w: ArrayLike, mismatch: ArrayLike, coherent: ArrayLike, confident: ArrayLike,
                    epsilon_threshold: float,
                    sigma_factor: float = SIGMA_FACTOR) -> list[str]:
    """Per-frequency verdict.

    ``coherent``: coherence passes the threshold; ``confident``: also enough degrees of freedom
    (:func:`confident_points`). Returns ``"not_excited"`` (no estimate: the input is not excited there, or the
    manoeuvres cannot resolve the frequency; never model-limited), ``"excluded"`` (coherence below the
    threshold and epsilon within it), ``"ok"``
    (epsilon within the threshold), ``"model"`` (epsilon above it and the normalised mismatch beyond
    ``sigma_factor`` at a confident frequency) or ``"data"`` (above it, but low coherence, too few averages or
    within the errors: the data cannot tell, fly better sweeps there). Only confident frequencies count for
    epsilon; a ``"data"`` flag at low coherence marks where a mismatch may hide in the noise.

    Parameters
    ----------
    eps_w : array_like
        epsilon(w) of the model against the averaged data (eq. 14).
    mismatch : array_like
        Normalised mismatch k per frequency (:func:`normalised_mismatch`).
    coherent : array_like of bool
        Coherence passes the threshold.
    confident : array_like of bool
        Also enough averages (:func:`confident_points`).
    epsilon_threshold : float
        epsilon(w) above it is flagged ``model`` or ``data``.
    sigma_factor : float
        Normalised mismatch beyond which a confident frequency is model-limited.
    """
    flags = []
    for e, k, c, u in zip(np.asarray(eps_w, float), np.asarray(mismatch, float), np.asarray(coherent, bool),
                          np.asarray(confident, bool)):
        if not np.isfinite(e):
            flags.append("not_excited")
        elif not c and e <= epsilon_threshold:
            flags.append("excluded")
        elif not c:
            flags.append("data")
        elif e <= epsilon_threshold:
            flags.append("ok")
        elif u and k > sigma_factor:
            flags.append("model")
        else:
            flags.append("data")
    return flags


def find_bands(
    w_rad_s: ArrayLike,
    eps_w: ArrayLike,
    mismatch: ArrayLike,
    coherence: ArrayLike,
    n_averages: ArrayLike,
    flags: Sequence[str],
    coherence_threshold: float,
    min_averages: int = 0,
    sigma_factor: float = SIGMA_FACTOR,
    sigma: ArrayLike | None = None,
) -> list[Band]:
    """Runs of adjacent frequencies flagged ``model`` or ``data``, each with its verdict and reason.

    A band is model-limited when at least one of its frequencies is; otherwise data-limited. Excluded and
    not-excited frequencies end a band.

    Parameters
    ----------
    w_rad_s : array_like
        Frequencies [rad/s].
    eps_w, mismatch : array_like
        epsilon(w) and the normalised mismatch k per frequency.
    coherence, n_averages : array_like
        Coherence and degrees of freedom per frequency.
    flags : sequence of str
        Per-frequency verdicts (:func:`frequency_flags`).
    coherence_threshold : float
        The channel's coherence threshold (for the reasons).
    min_averages : int
        Degrees of freedom a usable frequency needs (:func:`minimum_averages`).
    sigma_factor : float
        As for :func:`frequency_flags`.
    sigma : array_like, optional
        The noise scale of epsilon(w) each point was judged with: where it is far wider than the coherence
        allows (:data:`BOUND_CHECK` times the classical bound with the systematic floor) and the classical
        bound alone puts the mismatch beyond ``sigma_factor``, a data-limited band says it is a bias
        allowance, not random error.
    """
    bands, start = [], None
    for i, flag in enumerate(list(flags) + ["ok"]):
        inside = flag in ("model", "data")
        if inside and start is None:
            start = i
        elif not inside and start is not None:
            bands.append(_band(np.arange(start, i), w_rad_s, eps_w, mismatch, coherence, n_averages, flags,
                               coherence_threshold, min_averages, sigma_factor, sigma))
            start = None
    return bands


def _band(idx, w_rad_s, eps_w, mismatch, coherence, n_averages, flags, coherence_threshold, min_averages,
          sigma_factor, sigma=None) -> Band:
    w, eps = np.asarray(w_rad_s, float), np.asarray(eps_w, float)
    peak = idx[int(np.argmax(eps[idx]))]
    k_max = float(np.max(np.asarray(mismatch, float)[idx]))
    coh_min = float(np.min(np.asarray(coherence, float)[idx]))
    n_min = float(np.min(np.asarray(n_averages, float)[idx]))
    model = any(flags[i] == "model" for i in idx)
    if model:
        reason = wording.model_band_reason(k_max, coherence_threshold)
    elif coh_min < coherence_threshold:
        reason = wording.low_coherence_reason(coh_min, coherence_threshold)
    elif n_min < min_averages:
        reason = wording.few_dof_reason(n_min, min_averages)
    elif sigma is not None and (k_coherence := _coherence_mismatch(
            eps[idx], np.asarray(coherence, float)[idx], np.asarray(n_averages, float)[idx],
            np.asarray(sigma, float)[idx])) > sigma_factor:
        reason = wording.bias_allowance_reason(coh_min, k_coherence)
    else:
        reason = wording.random_error_reason(k_max, coh_min)
    return Band(min_rad_s=float(w[idx[0]]), max_rad_s=float(w[idx[-1]]), peak_rad_s=float(w[peak]),
                epsilon=float(eps[peak]), limited_by="model" if model else "data", reason=reason,
                coherence_min=coh_min, mismatch_sigma=k_max if math.isfinite(k_max) else None,
                min_averages=n_min if math.isfinite(n_min) else None)


def _coherence_mismatch(
    eps_w: np.ndarray, coherence: np.ndarray, dof: np.ndarray, sigma: np.ndarray
) -> float:
    """The largest normalised mismatch, by the classical coherence bound (Bendat and Piersol's random error of
    a response with this coherence on these degrees of freedom, :func:`bendat_piersol_random_error`, with the
    systematic floor :data:`BIAS_ERROR`; half of it the noise scale of epsilon), at the points whose noise
    scale ``sigma`` is more than :data:`BOUND_CHECK` times wider: a check on an error a point was given beyond
    what its coherence allows (a bias allowance). 0 where none is."""
    classical = epsilon_noise_scale(
        np.hypot(bendat_piersol_random_error(coherence, np.maximum(dof, 1.0)), BIAS_ERROR)
    )
    wide = np.asarray(sigma, float) > BOUND_CHECK * classical
    k = normalised_mismatch(eps_w, classical, dof)
    k = np.where(wide & np.isfinite(k), k, 0.0)
    return float(np.max(k)) if k.size else 0.0


@dataclass
class Evidence:
    """The averaged estimate with the statistics the decisions need."""

    w: np.ndarray
    p_meas: np.ndarray
    coherence: np.ndarray
    n_averages: np.ndarray     # degrees of freedom of the noise estimate per frequency
    confident: np.ndarray      # counts for epsilon (as in the validator)
    sigma: np.ndarray          # noise scale of epsilon(w): random error, scatter and the systematic floor
    sigma_factor: float
    estimate: object = None    # for ``expected``: the model seen through the estimator
    min_dof: int = 10          # degrees of freedom a confident frequency needs (:func:`minimum_averages`)

    def mismatch(self, eps_w: ArrayLike, expansion_error: ArrayLike = 0.0) -> np.ndarray:
        """Normalised mismatch k per frequency (:func:`normalised_mismatch`).

        Parameters
        ----------
        eps_w : array_like
            epsilon(w) per frequency.
        expansion_error : array_like
            Relative error of the model's expansion over a band (:meth:`expected`): it widens the noise scale
            where the expansion is inexact.

        Returns
        -------
        ndarray
        """
        sigma = np.hypot(self.sigma, 0.5 * np.asarray(expansion_error, float))
        return normalised_mismatch(eps_w, sigma, self.n_averages)

    def expected(self, response: Callable[[np.ndarray], ArrayLike]) -> tuple[np.ndarray, np.ndarray]:
        """A model's response through the estimator, and the expansion error.

        :meth:`SpectralEstimate.expected`; the plain response where the estimate cannot say.

        Parameters
        ----------
        response : callable
            ``response(w) -> complex`` of the model.

        Returns
        -------
        (ndarray, ndarray)
            The response seen through the estimator, and the relative expansion error.
        """
        direct = np.asarray(response(self.w), complex)
        method = getattr(self.estimate, "expected", None)
        if method is None:
            return direct, np.zeros(self.w.shape)
        through, error = method(response)
        through = np.asarray(through, complex)
        return np.where(np.isfinite(through), through, direct), np.where(np.isfinite(error), error, 0.0)

    def fit(self, response: Callable[[np.ndarray], ArrayLike]) -> "Fit":
        """epsilon(w) of a model (``response(w) -> complex``) against the data, with its sups and statistics.

        epsilon(w) is the paper's (the model at w against the estimate); the mismatch ``k`` and the
        chi-square, which decide, compare the estimate with the model seen through the estimator, so the
        estimator's own smoothing does not count as a mismatch.

        Parameters
        ----------
        response : callable
            ``response(w) -> complex`` of the model.

        Returns
        -------
        Fit
        """
        p_fit = np.asarray(response(self.w), complex)
        eps_w = np.asarray(metrics.epsilon_per_frequency(p_fit, self.p_meas), float)
        eps, worst = masked_sup(eps_w, self.confident)
        through, error = self.expected(response)
        k = self.mismatch(metrics.epsilon_per_frequency(through, self.p_meas), error)
        k_max = float(np.max(np.where(self.confident, k, 0.0))) if self.confident.any() else 0.0
        return Fit(eps_w, eps, worst, k_max, self._chi2(through, error), k)

    def _chi2(self, p_fit, expansion_error) -> float:
        """``sum |ln(P_fit / P_meas)|^2 / e^2`` over the usable frequencies (about 2 per frequency when the
        fit equals the truth: chi-square with 2 n degrees of freedom)."""
        u = self.confident
        log_q = log_ratio(np.asarray(p_fit, complex)[u], self.p_meas[u])
        e2 = (2.0 * self.sigma[u]) ** 2 + np.asarray(expansion_error, float)[u] ** 2
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            terms = np.abs(log_q) ** 2 / e2
        return float(np.sum(np.where(np.isfinite(terms), terms, 1e12)))


def masked_sup(values: np.ndarray, mask: np.ndarray) -> tuple[float, int]:
    """The largest finite value where ``mask`` holds, and its index (NaN and -1 when there is none).

    Parameters
    ----------
    values : ndarray
        Values per frequency.
    mask : ndarray of bool
        The frequencies that count.

    Returns
    -------
    (float, int)
    """
    masked = np.where(mask & np.isfinite(values), values, -np.inf)
    if not np.any(np.isfinite(masked)):
        return math.nan, -1
    k = int(np.argmax(masked))
    return float(values[k]), k


@dataclass
class Fit:
    """A model scored on the data (:meth:`Evidence.fit`): epsilon(w), its sup, the statistics that decide."""

    eps_w: np.ndarray
    eps: float             # sup over confident frequencies (what a replay reports)
    worst: int
    k_max: float           # largest normalised mismatch at a usable frequency
    chi2: float
    k: np.ndarray          # normalised mismatch per frequency


def evidence_of(estimate: SpectralEstimate, sweeps: Sequence[SpectralEstimate], coherence_threshold: float,
                bias_error: float, sigma_factor: float) -> Evidence:
    """The averaged estimate with the statistics the decisions need.

    Parameters
    ----------
    estimate : SpectralEstimate
        The averaged estimate.
    sweeps : sequence of SpectralEstimate
        Per-sweep estimates on the same frequencies (their scatter, :func:`effective_random_error`).
    coherence_threshold : float
        The channel's coherence threshold (:func:`confident_points`).
    bias_error : float
        Systematic error floor, relative (:data:`BIAS_ERROR`).
    sigma_factor : float
        Normalised mismatch beyond which a confident frequency is model-limited.

    Returns
    -------
    Evidence
    """
    w = np.asarray(estimate.w_rad_s, float)
    p_meas = np.asarray(estimate.response, complex)
    coherence = np.asarray(estimate.coherence, float)
    n_avg = averages_of(estimate)
    confident = confident_points(estimate, coherence_threshold)
    sigma = epsilon_noise_scale(effective_random_error(estimate, sweeps, coherence_threshold, bias_error))
    min_dof = minimum_averages(coherence_threshold, coefficients=_coefficients(estimate))
    return Evidence(w, p_meas, coherence, n_avg, confident, sigma, sigma_factor, estimate, min_dof)
