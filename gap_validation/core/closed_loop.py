"""Closed loop and coupled surfaces: what the numbers may not show when the input is not the only cause.

The estimator reads one surface against one rate and assumes the surface is the cause (open loop, one
surface moving). Two things break that in flight, and without the config keys that handle them
(``excitation``, ``other_inputs``: :mod:`gap_validation.core.spectra` estimates with instruments or several
inputs) this module
*warns instead of guessing*:

- **Coupled surfaces.** During a channel's manoeuvres another configured surface moves coherently with its
  input (a mixer or an aileron-rudder interconnect). :class:`CouplingMonitor` regresses each other configured
  surface on the channel's input over the channel's own manoeuvres (those its estimator found); a coherence
  above
  :data:`COUPLING_COHERENCE` with a gain above :data:`COUPLING_GAIN` in manoeuvres carrying
  :data:`COUPLING_SHARE` of the input's energy names that surface and the key to add.
- **Feedback.** A damper or an autopilot moves the surface with the measured rate: the direct estimate tends
  to ``-1/C`` where the disturbances drive the surface (Ljung, *System Identification*, ch. 13; Bendat and
  Piersol ch. 7). Coherence between surface and rate cannot tell it: an open-loop airframe answering a pilot's
  trim corrections is coherent too. What feedback changes is the response itself. Between the manoeuvres the
  surface moves with the trim motion (:class:`~gap_validation.core.background.TrimSpectrum`): in open loop the
  rate answers it as it answers the manoeuvres (the response between manoeuvres is the airframe's), in closed
  loop the loop drives it from the rate and the response between manoeuvres is ``-1/C``: where the loop gain
  exceeds one, on the
  *opposite side* of the airframe's response (``Re(H_trim / H_manoeuvre) < 0``), which no open-loop input can
  give.
  :func:`feedback_evidence` tests exactly that, frequency by frequency, against both estimates' random errors;
  with a configured ``controller`` a measured response closer to ``-1/C`` than to the model is a second sign
  (:func:`near_minus_inverse`).

A feedback loop biases a manoeuvre's estimate only by the share of the surface's motion that the manoeuvre
does not explain: ``b(w) = S_trim(w) / S_manoeuvre(w) |H_trim(w) - H(w)|`` (:func:`feedback_bias`). Points
where that bound passes the random error -- and every point a coupling warning covers -- are *data-limited*,
never model-limited, and no effect is named from them (:func:`with_bias_allowance` gives the diagnosis an
estimate whose error covers a bias as large as the response). A manoeuvre 20 dB above the trim motion is not
biased, whatever happens between manoeuvres.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from scipy.special import ndtri

from gap_validation.core import metrics
from gap_validation.core.background import LeadResult, TrimResponse

if TYPE_CHECKING:
    from gap_validation.core.estimator import SpectralEstimate
    from gap_validation.core.models import LinearModel

__all__ = [
    "CouplingMonitor",
    "SurfaceHistory",
    "FeedbackEvidence",
    "feedback_evidence",
    "feedback_bias",
    "near_minus_inverse",
    "with_bias_allowance",
    "COUPLING_COHERENCE",
    "COUPLING_GAIN",
    "COUPLING_SHARE",
    "FEEDBACK_FALSE_ALARM",
    "LEAD_SHARE",
    "rate_leads",
    "KAPPA_MINUS_INVERSE",
    "BIAS_ALLOWANCE",
    "PENDING_RECORDS",
]

#: Coherence (R^2) between a channel's input and another surface during its manoeuvres that names the surface.
COUPLING_COHERENCE = 0.6
#: ... with at least this gain (other surface / input): sensor noise and trim do not count.
COUPLING_GAIN = 0.05
#: ... in manoeuvres carrying at least this share of the input's energy.
COUPLING_SHARE = 0.25
#: Manoeuvres that wait for another surface's samples (whole histories fed one channel after the other).
PENDING_RECORDS = 64
#: Probability, per channel, that an open-loop flight is called closed loop by :func:`feedback_evidence`
#: (split over the frequencies tested: Bonferroni).
FEEDBACK_FALSE_ALARM = 1e-3
#: Share of the surface's unpredictable trim motion that the rate's past must explain before the lead test
#: (:class:`~gap_validation.core.background.LeadTest`) calls it a loop: a loop driving less moves an estimate
#: drowned in the trim motion by less than a tenth, the margin between a model that fits and one that does not
#: (epsilon 0.1-0.15). Resampling, gyro filters and deterministic inputs leave small shares in open loop
#: (measured: at most 2 % with the F test passed on the second simulator and JSBSim; see docs/JUDGEMENTS.md).
LEAD_SHARE = 0.1
#: Chordal distance to ``-1/C`` under which a measured response looks like the inverse of the controller.
KAPPA_MINUS_INVERSE = 0.2
#: Relative error given to the points a warning covers (a bias as large as the response, and more).
BIAS_ALLOWANCE = 1e6


class SurfaceHistory:
    """The latest samples of one surface (``keep_s`` of them; everything for whole recorded histories), to be
    read at the grid times of another channel's manoeuvres.

    Parameters
    ----------
    keep_s : float
        Span kept [s]: at least the longest record (``max_record_s``) plus the estimator's delays.
    """

    def __init__(self, keep_s: float = 420.0) -> None:
        self.keep_s = float(keep_s)
        self.t = np.empty(0)
        self.v = np.empty(0)

    def add(self, t_s: np.ndarray, values: np.ndarray, whole: bool = False) -> None:
        """Samples in time order (a step back starts afresh); ``whole``: a whole recorded history, kept
        entire.

        Parameters
        ----------
        t_s, values : ndarray
            Times [s] and values.
        whole : bool
            Keep everything (library use: the caller holds the arrays anyway).
        """
        t, v = np.asarray(t_s, float).ravel(), np.asarray(values, float).ravel()
        ok = np.isfinite(t) & np.isfinite(v)
        t, v = t[ok], v[ok]
        if t.size == 0:
            return
        if self.t.size and t[0] <= self.t[-1]:
            keep = self.t < t[0]
            self.t, self.v = self.t[keep], self.v[keep]
            if not self.t.size or t[0] < self.t[-1] - self.keep_s:
                self.t, self.v = np.empty(0), np.empty(0)
        self.t, self.v = np.concatenate((self.t, t)), np.concatenate((self.v, v))
        if not whole and self.t[-1] - self.t[0] > 2.0 * self.keep_s:
            keep = self.t >= self.t[-1] - self.keep_s
            self.t, self.v = self.t[keep], self.v[keep]

    def covers(self, t0_s: float, t1_s: float) -> bool:
        """True when the samples span ``[t0_s, t1_s]``.

        Parameters
        ----------
        t0_s, t1_s : float
            Start and end [s].
        """
        return bool(self.t.size) and self.t[0] <= t0_s and self.t[-1] >= t1_s

    def at(self, t_s: np.ndarray) -> np.ndarray:
        """Linearly interpolated values at ``t_s``.

        Parameters
        ----------
        t_s : ndarray
            Times [s] within the samples (:meth:`covers`).
        """
        return np.interp(t_s, self.t, self.v)


def _covered(u: np.ndarray, t0_s: float, dt_s: float, history: SurfaceHistory) -> np.ndarray | None:
    """The other surface at the times of ``u``'s samples (from ``t0_s``, step ``dt_s``); None for a manoeuvre
    too short to regress (under 8 samples) or one the surface's samples do not cover."""
    if u.size < 8:
        return None
    t = t0_s + dt_s * np.arange(u.size)
    return history.at(t) if history.covers(t[0], t[-1]) else None


class CouplingMonitor:
    """How much another configured surface moves with a channel's input, over the channel's own manoeuvres.

    The channel's estimator reports every manoeuvre that gives a response (its ``record_observer``): the grid
    samples of the input over the excited span. The other surface is read at the same times from its
    :class:`SurfaceHistory` and regressed on the input and its rate (a static or lagged interconnect): the
    multiple coherence ``R^2`` and the gain. An interconnect gives ``R^2`` near 1; a surface held at trim, or
    flown on other lines of an orthogonal multisine, near 0. A manoeuvre whose surface samples have not
    arrived yet waits (at most :data:`PENDING_RECORDS` of them).
    """

    def __init__(self) -> None:
        self.energy = 0.0            # input energy of every manoeuvre
        self.coupled_energy = 0.0    # ... of those where the surface follows the input
        self._r2 = 0.0               # energy-weighted sums over the coupled ones
        self._gain = 0.0
        self.records = 0
        self.coupled_records = 0     # manoeuvres in which the surface follows the input
        self.followed_records = 0    # ... in which the input follows the surface: the surface's manoeuvres
        self._followed_r2 = 0.0      # energy-weighted sums over those
        self._followed_gain = 0.0
        self._followed_energy = 0.0
        self.followed_s = 0.0        # their length [s]
        self.pending: deque = deque(maxlen=PENDING_RECORDS)

    def observe(self, u: np.ndarray, t0_s: float, dt_s: float, history: SurfaceHistory) -> None:
        """A manoeuvre of the channel: its input ``u`` on the grid from ``t0_s`` with step ``dt_s``.

        Parameters
        ----------
        u : ndarray
            The channel's input over the manoeuvre's excited span.
        t0_s, dt_s : float
            Time of the first sample and grid step [s].
        history : SurfaceHistory
            The other surface.
        """
        if u.size < 8:
            return
        other = _covered(u, t0_s, dt_s, history)
        if other is not None:
            self._add(np.asarray(u, float), other)
        elif not history.t.size or history.t[-1] < t0_s + dt_s * (u.size - 1):       # not arrived yet
            self.pending.append((np.asarray(u, float).copy(), t0_s, dt_s))

    def catch_up(self, history: SurfaceHistory) -> None:
        """Use the waiting manoeuvres the surface's samples now cover.

        Parameters
        ----------
        history : SurfaceHistory
            The other surface.
        """
        waiting, self.pending = list(self.pending), deque(maxlen=PENDING_RECORDS)
        for u, t0_s, dt_s in waiting:
            self.observe(u, t0_s, dt_s, history)

    @staticmethod
    def _fit(u: np.ndarray, other: np.ndarray) -> tuple[float, float, float] | None:
        """``(R^2, gain, input energy)`` of the other surface regressed on the input and its rate (None:
        either flat)."""
        u, other = u - np.mean(u), other - np.mean(other)
        x = np.stack([u, np.gradient(u)])
        uu, oo = float(u @ u), float(other @ other)
        if uu <= 0 or oo <= 0:
            return None
        try:
            xy = x @ other
            r2 = min(max(float(xy @ np.linalg.solve(x @ x.T, xy)) / oo, 0.0), 1.0)
        except np.linalg.LinAlgError:
            return None
        return r2, float(u @ other) / uu, uu

    def leads(self, u: np.ndarray, t0_s: float, dt_s: float, history: SurfaceHistory, own_trim: float,
              other_trim: float) -> bool:
        """Whether a manoeuvre of the channel is the other surface's: the other surface moves with the input
        (``R^2`` >= :data:`COUPLING_COHERENCE`, gain >= :data:`COUPLING_GAIN`) and moves more, each in units
        of its own trim motion between the manoeuvres (in its own units while either is unknown): the input
        follows the other surface through an interconnect (an aileron-rudder interconnect moves the rudder in
        the aileron's sweeps), as ``other_inputs`` keep a manoeuvre for the input most excited over its trim.
        Such a manoeuvre is counted here (:meth:`followed`) and nowhere else. False where the surface's
        samples do not cover the manoeuvre yet (it is then judged as any other, by :meth:`observe`).

        Parameters
        ----------
        u : ndarray
            The channel's input over the manoeuvre's excited span.
        t0_s, dt_s : float
            Time of the first sample and grid step [s].
        history : SurfaceHistory
            The other surface.
        own_trim, other_trim : float
            Standard deviations of the input's and the other surface's trim motion between manoeuvres (0:
            unknown).
        """
        other = _covered(u, t0_s, dt_s, history)
        if other is None:
            return False
        fit = self._fit(np.asarray(u, float), other)
        if fit is None:
            return False
        r2, gain, uu = fit
        if r2 < COUPLING_COHERENCE or abs(gain) < COUPLING_GAIN:
            return False
        scale_u, scale_o = (own_trim, other_trim) if own_trim > 0 and other_trim > 0 else (1.0, 1.0)
        if float(np.std(other)) / scale_o <= float(np.std(u)) / scale_u:
            return False
        self.followed_records += 1
        self.followed_s += u.size * dt_s
        self._followed_energy += uu
        self._followed_r2 += r2 * uu
        self._followed_gain += gain * uu
        return True

    def followed(self) -> tuple[int, float, float]:
        """The channel's manoeuvres that were the other surface's (:meth:`leads`): how many, and their
        energy-weighted ``R^2`` and gain (other surface / input; 0 when none)."""
        if not self._followed_energy:
            return self.followed_records, 0.0, 0.0
        return (self.followed_records, self._followed_r2 / self._followed_energy,
                self._followed_gain / self._followed_energy)

    def _add(self, u: np.ndarray, other: np.ndarray) -> None:
        fit = self._fit(u, other)
        if fit is None:
            return
        r2, gain, uu = fit
        self.records += 1
        self.energy += uu
        if r2 >= COUPLING_COHERENCE and abs(gain) >= COUPLING_GAIN:
            self.coupled_records += 1
            self.coupled_energy += uu
            self._r2 += r2 * uu
            self._gain += gain * uu

    def coupled(self) -> tuple[bool, float, float]:
        """Whether the other surface moves with the input: in manoeuvres carrying at least
        :data:`COUPLING_SHARE` of the input's energy, the surface follows the input (multiple coherence
        ``R^2`` of the surface on the input and its rate >= :data:`COUPLING_COHERENCE`, gain >=
        :data:`COUPLING_GAIN`).

        Returns
        -------
        coupled : bool
        r2, gain : float
            Energy-weighted mean ``R^2`` and gain over those manoeuvres (0 when none).
        """
        if not self.coupled_energy:
            return False, 0.0, 0.0
        r2, gain = self._r2 / self.coupled_energy, self._gain / self.coupled_energy
        return self.coupled_energy >= COUPLING_SHARE * self.energy, r2, gain


@dataclass(frozen=True)
class FeedbackEvidence:
    """Where the response between manoeuvres points away from the response during them.

    Attributes
    ----------
    detected : bool
        Some frequency tested is on the opposite side beyond chance (:func:`feedback_evidence`).
    opposite : ndarray of bool
        Those frequencies.
    tested : int
        Frequencies where both estimates were confident.
    z : ndarray
        ``(1 - Re(H_trim / H)) / sigma`` per frequency (NaN where not tested).
    """

    detected: bool
    opposite: np.ndarray
    tested: int
    z: np.ndarray


def feedback_evidence(trim: TrimResponse, response: np.ndarray, variance: np.ndarray, confident: np.ndarray,
                      model: np.ndarray | None = None,
                      false_alarm: float = FEEDBACK_FALSE_ALARM) -> FeedbackEvidence:
    """Test for a feedback loop: the response between the manoeuvres on the opposite side of the response
    during them.

    With the loop gain ``L = C P`` above one and the disturbances driving the surface, the estimate between
    manoeuvres is ``-1/C = -P/L``: ``Re(H_trim / P) < 0`` wherever ``Re(L) > 0``. In open loop both estimates
    see the same airframe: ``H_trim / H = 1 + noise``, whose real part is about normal with mean 1 and
    standard deviation ``sigma = sqrt((v_trim + v)/2)`` (the two estimates' relative variances). A frequency
    counts as evidence when ``Re(H_trim / H) < 0`` and ``z = (1 - Re(H_trim / H)) / sigma`` passes the
    one-sided normal quantile of ``false_alarm / n`` (n frequencies tested, Bonferroni): an open-loop flight
    is called closed loop with probability at most ``false_alarm``. An amplitude-dependent airframe (a rate
    limit, free play) changes the gain between small trim motion and a manoeuvre, not the sign: it gives no
    evidence.

    Where the manoeuvres give no confident response (a loop answering turbulence may leave them only part of
    the band: the trim motion is largest where the loop gain is), the reference ``H`` is the ``model``, scaled
    by the manoeuvres' response over the model at the nearest frequency where they give one (so that a model
    of the wrong sign or with a missing delay is corrected by what the manoeuvres measured), with that
    frequency's variance.

    Parameters
    ----------
    trim : TrimResponse
        The response between manoeuvres.
    response, variance : ndarray
        The manoeuvres' pooled response and its variance ``E |dH|^2``.
    confident : ndarray of bool
        Frequencies where the manoeuvres' estimate counts.
    model : ndarray, optional
        The model's response at the same frequencies (None: only the manoeuvres' frequencies are tested).
    false_alarm : float
        Probability of a false call per channel.
    """
    h = np.asarray(response, complex)
    confident = np.asarray(confident, bool) & np.isfinite(h) & (np.abs(h) > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(confident, np.asarray(variance, float) / np.abs(h) ** 2, np.inf)
    reference = np.where(confident, h, np.nan + 0j)
    if model is not None:
        p = np.asarray(model, complex)
        known = np.flatnonzero(confident & np.isfinite(p) & (np.abs(p) > 0))
        if known.size:
            nearest = known[np.argmin(np.abs(np.arange(h.size)[:, None] - known[None, :]), axis=1)]
            with np.errstate(divide="ignore", invalid="ignore"):
                scaled = p * (h[nearest] / p[nearest])
            reference = np.where(confident, h, scaled)
            rel = np.where(confident, rel, rel[nearest])
        else:
            reference, rel = p, np.zeros(h.shape)
    tested = trim.confident() & np.isfinite(reference) & (np.abs(reference) > 0) & np.isfinite(rel)
    z = np.full(h.shape, np.nan)
    opposite = np.zeros(h.shape, bool)
    n = int(np.count_nonzero(tested))
    if n:
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = trim.response[tested] / reference[tested]
            v = trim.relative_variance()[tested] + rel[tested]
            z[tested] = (1.0 - ratio.real) / np.sqrt(0.5 * v)
        critical = float(-ndtri(false_alarm / n))
        opposite[tested] = (ratio.real < 0.0) & (z[tested] > critical)
    return FeedbackEvidence(bool(opposite.any()), opposite, n, z)


def rate_leads(lead: LeadResult | None, false_alarm: float = FEEDBACK_FALSE_ALARM) -> bool:
    """Whether the lead test (:class:`~gap_validation.core.background.LeadResult`, None before enough trim)
    says a loop moves the surface between the manoeuvres: the rate's past explains at least :data:`LEAD_SHARE`
    of what the surface's own past does not, beyond chance (``p_value < false_alarm``).

    Parameters
    ----------
    lead : LeadResult or None
        The estimator's :meth:`~gap_validation.core.estimator.FrequencyResponseEstimator.surface_led`.
    false_alarm : float
        Chance of the F statistic under "the rate does not lead".
    """
    return lead is not None and lead.p_value < false_alarm and lead.share >= LEAD_SHARE


def feedback_bias(trim: TrimResponse, response: np.ndarray, variance: np.ndarray,
                  manoeuvre_power: np.ndarray) -> np.ndarray:
    """Frequencies whose pooled estimate a feedback loop may bias beyond its random error.

    During a manoeuvre the surface moves with the manoeuvre and, as between manoeuvres, with the loop
    answering the disturbances; the estimate is the power-weighted mix of the airframe and ``H_trim``: its
    bias is at most ``S_trim / S_manoeuvre |H_trim - H|`` (where the trim response is unknown, ``2 |H|``: a
    ``-1/C`` as large as the response). Biased where that passes the random error ``sqrt(variance)``, or where
    the trim motion was not measured.

    Parameters
    ----------
    trim : TrimResponse
        The response between manoeuvres and the input's trim motion.
    response, variance : ndarray
        The manoeuvres' pooled response and its variance.
    manoeuvre_power : ndarray
        The input's mean ``|X|^2`` per bin over the manoeuvres, same units as ``trim.input_power``.
    """
    h = np.asarray(response, complex)
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.asarray(trim.input_power, float) / np.asarray(manoeuvre_power, float)
        gap = np.where(np.isfinite(trim.response), np.abs(trim.response - h), 2.0 * np.abs(h))
        bias = share * gap
        biased = ~(bias <= np.sqrt(np.asarray(variance, float)))      # NaN (not measured) counts as biased
    return biased & np.isfinite(h)


def near_minus_inverse(controller: "LinearModel", w_rad_s: np.ndarray, measured: np.ndarray,
                       model: np.ndarray) -> np.ndarray:
    """Frequencies where the measured response looks like ``-1/C`` (the controller's inverse, what a direct
    estimate tends to where feedback drives the surface): closer to ``-1/C`` than to the model in the chordal
    distance (eq. 13), and within :data:`KAPPA_MINUS_INVERSE` of it.

    Parameters
    ----------
    controller : LinearModel
        ``u = -C y``.
    w_rad_s : ndarray
        Frequencies [rad/s].
    measured, model : ndarray
        Measured and model responses (complex).
    """
    c = np.asarray(controller.freqresp(w_rad_s), complex)
    with np.errstate(divide="ignore", invalid="ignore"):
        minus_inverse = -1.0 / c
        to_inverse = metrics.chordal_distance(minus_inverse, measured)
        to_model = metrics.chordal_distance(model, measured)
        return np.isfinite(to_inverse) & (to_inverse < KAPPA_MINUS_INVERSE) & (to_inverse < to_model)


def with_bias_allowance(estimate: "SpectralEstimate", mask: np.ndarray) -> "SpectralEstimate":
    """The estimate with a relative error of :data:`BIAS_ALLOWANCE` at ``mask`` (the points a warning covers):
    the diagnosis then calls them data-limited and fits nothing to them.

    Parameters
    ----------
    estimate : SpectralEstimate
        Averaged estimate.
    mask : ndarray of bool
        Points whose response may be biased.
    """
    mask = np.asarray(mask, bool)
    if not mask.any():
        return estimate
    error = np.where(mask, np.maximum(np.asarray(estimate.random_error, float), BIAS_ALLOWANCE),
                     estimate.random_error)
    variance = (
        None
        if estimate.variance is None
        else np.where(
            mask,
            np.maximum(
                np.asarray(estimate.variance, float),
                2.0 * (BIAS_ALLOWANCE * np.abs(np.nan_to_num(estimate.response))) ** 2,
            ),
            estimate.variance,
        )
    )
    return replace(estimate, random_error=error, variance=variance)
