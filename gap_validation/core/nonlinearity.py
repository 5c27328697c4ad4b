"""Amplitude-dependent (nonlinear) behaviour: the amplitude flown per frequency, and sweeps that disagree.

A linear system's response does not depend on the input amplitude; a surface rate limit, free play (backlash)
or saturation does. Two things here:

* :func:`flown_amplitude`: per analysis frequency, the input amplitude the pooled estimate saw: the records'
  amplitudes (:attr:`SpectralEstimate.amplitude`, ``sqrt(2)`` x the RMS of the input over the manoeuvre,
  exactly the amplitude of a constant-amplitude chirp) weighted by each record's input power at that frequency
  (the pooled local fit weighs the records the same way). The describing functions of ``rate_limit`` and
  ``backlash`` (:mod:`gap_validation.core.effects`) are evaluated there.
* :func:`amplitude_dependence`: when the flight has sweeps at clearly different amplitudes (largest over
  smallest at least :data:`AMPLITUDE_RATIO`), the low- and high-amplitude groups' responses are compared
  frequency by frequency against their errors: ``z^2 = |H_lo - H_hi|^2 / (v_lo + v_hi + floor)``, each group
  the inverse-variance mean of its records, its variance scaled by the group's Birge ratio (scatter between
  its own records beyond their errors) and a systematic floor of
  :data:`~gap_validation.core.evidence.BIAS_ERROR` on each. The variances are themselves estimated (the
  records' degrees of freedom d, combined by Welch-Satterthwaite), so for a linear system z^2 is F(2, 2 d) at
  each frequency: its tail probability p gives the *surprise* ``-ln p``, Exp(1) for a linear response, and the
  summed surprise is Gamma(n, 1). Nonlinearity is called only when the sum is beyond it with probability below
  :data:`FALSE_ALARM` *and* at least
  :data:`MIN_FREQUENCIES` frequencies each have a surprise above 16 (p < 1e-7, as k = 4 noise scales), differ
  by more than :data:`MIN_RELATIVE_DIFFERENCE` of the response and by less than 90 deg in phase (a rate limit,
  free play or saturation shifts the phase between two amplitudes by less than that; more is a bad record).
  Conservative: a linear model must never be called nonlinear; measured on linear flights by
  ``benchmarks/false_alarms.py``.

A flight whose sweeps all have one amplitude cannot show amplitude dependence this way (the describing
function at that amplitude is then one more frequency response, which the diagnosis still fits as
``rate_limit`` or ``backlash``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from gap_validation.core import wording
from gap_validation.core.spectra import sweep_points

__all__ = ["NONLINEARITY", "AMPLITUDE_RATIO", "FALSE_ALARM", "MIN_FREQUENCIES", "MIN_RELATIVE_DIFFERENCE",
           "AmplitudeDependence", "flown_amplitude", "amplitude_function", "amplitude_dependence"]

#: What the sentence and JSON ``nonlinearity`` say when sweeps at different amplitudes disagree.
NONLINEARITY = "nonlinear, amplitude-dependent (rate limit, backlash or saturation?)"
#: Sweeps are compared by amplitude only when the largest amplitude is at least this times the smallest.
AMPLITUDE_RATIO = 1.4
#: Probability that a linear response's groups disagree as much by chance (Gamma tail of the summed z^2).
FALSE_ALARM = 1e-6
#: Frequencies that must each disagree beyond 4 noise scales.
MIN_FREQUENCIES = 2
#: ... by at least this fraction of the response (3 x the 1 % systematic floor).
MIN_RELATIVE_DIFFERENCE = 0.03
_Z2_SINGLE = 16.0           # k = 4 noise scales at one frequency


@dataclass
class AmplitudeDependence:
    """The comparison of the sweeps flown at low and at high amplitude.

    Attributes
    ----------
    detected : bool
        The groups disagree beyond their errors (see the module notes).
    low_amplitude, high_amplitude : float
        Mean input amplitude of each group [input units].
    frequencies : int
        Frequencies compared.
    disagreeing : int
        Frequencies with a surprise above 16 that differ by more than :data:`MIN_RELATIVE_DIFFERENCE` and by
        less than 90 deg.
    probability : float
        Chance that a linear response gives a summed z^2 this large.
    worst_rad_s : float
        Frequency of the largest z^2 [rad/s].
    gain_ratio, phase_deg : float
        High- over low-amplitude response there: magnitude ratio and phase difference [deg].
    """

    detected: bool
    low_amplitude: float
    high_amplitude: float
    frequencies: int
    disagreeing: int
    probability: float
    worst_rad_s: float = math.nan
    gain_ratio: float = math.nan
    phase_deg: float = math.nan

    def sentence(self) -> str:
        """The evidence in words (for the message and JSON ``nonlinearity_evidence``)."""
        return wording.amplitude_sentence(
            self.low_amplitude, self.high_amplitude, detected=self.detected, frequencies=self.frequencies,
            probability=self.probability, disagreeing=self.disagreeing, worst_rad_s=self.worst_rad_s,
            gain_ratio=self.gain_ratio, phase_deg=self.phase_deg,
        )


def flown_amplitude(w_rad_s: Sequence[float], sweeps: Sequence) -> np.ndarray | None:
    """Input amplitude per frequency: the records' amplitudes weighted by their input power there.

    Parameters
    ----------
    w_rad_s : array_like
        The analysis frequencies [rad/s].
    sweeps : sequence of SpectralEstimate
        Raw per-record estimates (``amplitude``, ``gxx``, ``response`` on the same frequencies).

    Returns
    -------
    ndarray or None
        Amplitude per frequency; where no record counted, the power-weighted mean over all frequencies. None
        when no record has a known amplitude.
    """
    w = np.asarray(w_rad_s, float)
    rows, amps = [], []
    for s in sweeps:
        a = float(getattr(s, "amplitude", math.nan))
        if not (math.isfinite(a) and a > 0) or np.shape(s.response) != w.shape:
            continue
        ok = np.isfinite(np.asarray(s.response, complex))
        rows.append(np.where(ok, np.nan_to_num(np.asarray(s.gxx, float)), 0.0))
        amps.append(a)
    if not amps:
        return None
    weight = np.array(rows)
    amps_arr = np.array(amps)[:, None]
    total = weight.sum(axis=0)
    overall = float(np.sum(weight * amps_arr) / weight.sum()) if weight.sum() > 0 else float(np.mean(amps))
    with np.errstate(invalid="ignore", divide="ignore"):
        per = np.sum(weight * amps_arr, axis=0) / total
    return np.where(total > 0, per, overall)


def amplitude_function(
    w_rad_s: Sequence[float], amplitude: Sequence[float]
) -> Callable[[np.ndarray], np.ndarray]:
    """``amplitude(w)`` at any frequency: interpolated in log frequency, constant beyond the ends.

    Parameters
    ----------
    w_rad_s, amplitude : array_like
        Frequencies [rad/s] (> 0, increasing) and the amplitude there (:func:`flown_amplitude`).
    """
    lw = np.log(np.asarray(w_rad_s, float))
    a = np.asarray(amplitude, float)

    def at(w: np.ndarray) -> np.ndarray:
        w = np.asarray(w, float)
        with np.errstate(divide="ignore"):
            return np.interp(np.log(np.maximum(np.abs(w), 1e-300)), lw, a)

    return at


def _group(sweeps: Sequence, points: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse-variance mean response, its variance (scaled by the Birge ratio when it is above one) and the
    degrees of freedom of that variance (summed over the records)."""
    h = np.array([np.asarray(s.response, complex) for s in sweeps])
    var = np.array([np.asarray(s.variance, float) for s in sweeps])
    dof_r = np.array([np.broadcast_to(np.asarray(getattr(s, "n_averages", np.inf), float), h.shape[1:])
                      for s in sweeps])
    ok = np.array(points) & np.isfinite(var) & (var > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = np.where(ok, 1.0 / np.where(ok, var, 1.0), 0.0)
        total = weight.sum(axis=0)
        mean = np.sum(weight * np.where(ok, h, 0.0), axis=0) / total
        variance = 1.0 / total
        m = ok.sum(axis=0)
        chi2 = np.sum(weight * np.abs(np.where(ok, h - mean, 0.0)) ** 2, axis=0)
    dof = float(np.sum(np.maximum(m - 1, 0)))
    birge = float(np.sum(chi2[m >= 2]) / dof) if dof > 0 else 1.0
    d = np.sum(np.where(ok, dof_r, 0.0), axis=0)
    return (np.where(total > 0, mean, np.nan), np.where(total > 0, variance * max(birge, 1.0), np.inf),
            np.where(total > 0, np.maximum(d, 1.0), np.nan))


def amplitude_dependence(sweeps: Sequence, average_confident: np.ndarray, coherence_threshold: float,
                         bias_error: float = 0.01) -> AmplitudeDependence | None:
    """Compare the sweeps flown at low and at high amplitude (see the module notes).

    Parameters
    ----------
    sweeps : sequence of SpectralEstimate
        Raw per-record estimates with ``amplitude`` and ``variance``.
    average_confident : ndarray of bool
        Confident frequencies of the pooled estimate (the validation's frequency set).
    coherence_threshold : float
        A record counts at a frequency where its own coherence passes it.
    bias_error : float
        Systematic error floor of each group's response, relative.

    Returns
    -------
    AmplitudeDependence or None
        None when the sweeps do not span :data:`AMPLITUDE_RATIO` in amplitude or nothing can be compared.
    """
    from scipy.special import fdtrc, gammaincc

    usable = [s for s in sweeps if math.isfinite(float(getattr(s, "amplitude", math.nan)))
              and float(s.amplitude) > 0 and getattr(s, "variance", None) is not None]
    if len(usable) < 2:
        return None
    amps = np.array([float(s.amplitude) for s in usable])
    if amps.max() < AMPLITUDE_RATIO * amps.min():
        return None
    split = math.sqrt(amps.max() * amps.min())
    low = [s for s, a in zip(usable, amps) if a < split]
    high = [s for s, a in zip(usable, amps) if a >= split]
    h_lo, v_lo, d_lo = _group(low, [sweep_points(s, average_confident, coherence_threshold) for s in low])
    h_hi, v_hi, d_hi = _group(high, [sweep_points(s, average_confident, coherence_threshold) for s in high])
    both = np.isfinite(h_lo) & np.isfinite(h_hi) & np.isfinite(v_lo) & np.isfinite(v_hi)
    n = int(np.count_nonzero(both))
    result = AmplitudeDependence(
        False, float(np.mean(amps[amps < split])), float(np.mean(amps[amps >= split])), n, 0, 1.0
    )
    if n == 0:
        return result
    diff = np.abs(h_lo - h_hi)
    floor = (bias_error * np.abs(h_lo)) ** 2 + (bias_error * np.abs(h_hi)) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        z2 = np.where(both, diff ** 2 / (v_lo + v_hi + floor), 0.0)
        relative = np.where(both, diff / np.abs(h_hi), 0.0)
        # the variances are estimated (d degrees of freedom, Welch-Satterthwaite): z^2 is F(2, 2 d), not
        # Exp(1); its tail probability p turned into -ln p, which is Exp(1) for a linear response
        d = np.where(both, (v_lo + v_hi) ** 2 / (v_lo ** 2 / d_lo + v_hi ** 2 / d_hi), 1.0)
        tail = np.where(both, fdtrc(2.0, 2.0 * np.maximum(d, 1.0), z2), 1.0)
        surprise = -np.log(np.maximum(tail, 1e-300))
        phase = np.abs(np.angle(np.where(both, h_hi / h_lo, 1.0)))
    result.probability = float(gammaincc(n, float(np.sum(surprise))))      # Gamma(n, 1) tail
    # a rate limit, free play or saturation changes the phase between amplitudes by less than 90 deg
    strong = (surprise > _Z2_SINGLE) & (relative > MIN_RELATIVE_DIFFERENCE) & (phase < math.pi / 2)
    result.disagreeing = int(np.count_nonzero(strong))
    worst = int(np.argmax(surprise))
    w = np.asarray(usable[0].w_rad_s, float)
    ratio = h_hi[worst] / h_lo[worst]
    result.worst_rad_s, result.gain_ratio = float(w[worst]), float(abs(ratio))
    result.phase_deg = float(np.degrees(np.angle(ratio)))
    result.detected = bool(result.probability < FALSE_ALARM and result.disagreeing >= MIN_FREQUENCIES)
    return result
