"""Closed loop and coupled surfaces: what the numbers may not show when the input is not the only cause.

The estimator reads one surface against one rate and assumes the surface is the cause (open loop, one
surface moving). Two things break that in flight, and without the config keys that handle them (``excitation``,
``other_inputs``: :mod:`gap_validation.core.spectra` estimates with instruments or several inputs) this module
*warns instead of guessing*:

- **Coupled surfaces.** During a channel's manoeuvres another configured surface moves coherently with its input
  (a mixer or an aileron-rudder interconnect). :class:`CouplingMonitor` regresses each other configured surface
  on the channel's input over the channel's own manoeuvres (those its estimator found); a coherence above
  :data:`COUPLING_COHERENCE` with a gain above :data:`COUPLING_GAIN` in manoeuvres carrying
  :data:`COUPLING_SHARE` of the input's energy names that surface and the key to add.
- **Feedback.** A damper or an autopilot moves the surface with the measured rate: the direct estimate tends to
  ``-1/C`` where the disturbances drive the surface (Ljung, *System Identification*, ch. 13; Bendat and Piersol
  ch. 7). Two signs: between the manoeuvres the surface moves coherently with the rate
  (:class:`TrimCoherenceMonitor`: nothing is flown, yet the surface follows the rate), and, with a configured
  ``controller``, a measured response closer to ``-1/C`` than to the model (:func:`near_minus_inverse`).

Points a warning covers are *data-limited*, never model-limited, and no effect is named from them
(:func:`with_bias_allowance` gives the diagnosis an estimate whose error covers a bias as large as the response).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from gap_validation.core import metrics

if TYPE_CHECKING:
    from gap_validation.core.estimator import SpectralEstimate
    from gap_validation.core.models import LinearModel

__all__ = ["TrimCoherenceMonitor", "CouplingMonitor", "SurfaceHistory", "welch_coherence", "near_minus_inverse",
           "with_bias_allowance", "COUPLING_COHERENCE", "COUPLING_GAIN", "COUPLING_SHARE", "TRIM_COHERENCE",
           "KAPPA_MINUS_INVERSE", "BIAS_ALLOWANCE", "PENDING_RECORDS"]

#: Coherence (R^2) between a channel's input and another surface during its manoeuvres that names the surface.
COUPLING_COHERENCE = 0.6
#: ... with at least this gain (other surface / input): sensor noise and trim do not count.
COUPLING_GAIN = 0.05
#: ... in manoeuvres carrying at least this share of the input's energy.
COUPLING_SHARE = 0.25
#: Manoeuvres that wait for another surface's samples (whole histories fed one channel after the other).
PENDING_RECORDS = 64
#: Median coherence of surface and rate in a trim block (between manoeuvres) that counts as feedback.
TRIM_COHERENCE = 0.5
#: Chordal distance to ``-1/C`` under which a measured response looks like the inverse of the controller.
KAPPA_MINUS_INVERSE = 0.2
#: Relative error given to the points a warning covers (a bias as large as the response, and more).
BIAS_ALLOWANCE = 1e6


class TrimCoherenceMonitor:
    """Coherence of a channel's surface and rate in blocks of flight, kept for the blocks between manoeuvres.

    Both streams are interpolated onto a coarse uniform grid (``rate_hz``) a block (``block_s``, every half
    block) at a time; each block keeps its span and the median magnitude-squared coherence
    (:func:`welch_coherence`, segments of a quarter block, half overlapping: 7 of them) over
    ``band_rad_s``. Bounded: the last ``max_blocks`` blocks and the samples of one block.

    Parameters
    ----------
    band_rad_s : (float, float)
        Band of the coherence [rad/s] (above the pilot's re-trims, below the rate of the coarse grid).
    block_s : float
        Block length [s].
    rate_hz : float
        Rate of the coarse grid [Hz].
    max_blocks : int
        Blocks kept.
    """

    def __init__(self, band_rad_s: tuple[float, float] = (2.0, 20.0), block_s: float = 8.0,
                 rate_hz: float = 50.0, max_blocks: int = 1000) -> None:
        self.band_rad_s = band_rad_s
        self.block_s = float(block_s)
        self.rate_hz = float(rate_hz)
        self.blocks: deque = deque(maxlen=max_blocks)       # (start_s, end_s, median coherence, u std)
        self._t = {"u": np.empty(0), "y": np.empty(0)}
        self._v = {"u": np.empty(0), "y": np.empty(0)}
        self._start: float | None = None

    def add(self, stream: str, t_s: np.ndarray, values: np.ndarray) -> None:
        """Samples of the surface (``"u"``) or the rate (``"y"``) in time order.

        Parameters
        ----------
        stream : {"u", "y"}
            Which stream.
        t_s, values : ndarray
            Times [s] and values (SI).
        """
        t, v = np.asarray(t_s, float).ravel(), np.asarray(values, float).ravel()
        ok = np.isfinite(t) & np.isfinite(v)
        t, v = t[ok], v[ok]
        if t.size == 0:
            return
        if self._t[stream].size and t[0] < self._t[stream][-1]:      # time went back: start afresh
            self._t = {"u": np.empty(0), "y": np.empty(0)}
            self._v = {"u": np.empty(0), "y": np.empty(0)}
            self._start = None
        self._t[stream] = np.concatenate((self._t[stream], t))
        self._v[stream] = np.concatenate((self._v[stream], v))
        if self._start is None:
            self._start = float(t[0])
        self._blocks()

    def _blocks(self) -> None:
        while self._start is not None and all(self._t[s].size for s in "uy") and \
                min(self._t["u"][-1], self._t["y"][-1]) >= self._start + self.block_s:
            # a gap longer than a block holds no covered block: go to where both streams have data again (absurd
            # stamps such as 1e19 s would otherwise step half a block at a time across the gap)
            first = max(float(self._t[s][np.argmax(self._t[s] >= self._start)]) for s in "uy")
            if first > self._start + self.block_s:
                self._start = first
                continue
            start, end = self._start, self._start + self.block_s
            if not start + 0.5 * self.block_s > start:    # stamps too large to resolve a block: nothing to judge
                self._start = None
                break
            grid = start + np.arange(int(round(self.block_s * self.rate_hz))) / self.rate_hz
            u = np.interp(grid, self._t["u"], self._v["u"])
            y = np.interp(grid, self._t["y"], self._v["y"])
            covered = all(self._t[s][0] <= start + 1.0 and np.max(np.diff(np.concatenate(
                ([start], self._t[s][(self._t[s] >= start) & (self._t[s] <= end)], [end])))) < 1.0 for s in "uy")
            if covered:
                self.blocks.append((start, end, self._coherence(u, y), float(np.std(u))))
            self._start = start + 0.5 * self.block_s
            for s in "uy":
                keep = self._t[s] >= self._start - 1.0
                self._t[s], self._v[s] = self._t[s][keep], self._v[s][keep]

    def _coherence(self, u: np.ndarray, y: np.ndarray) -> float:
        f, c = welch_coherence(u, y, self.rate_hz, max(8, u.size // 4))
        w = 2.0 * math.pi * f
        band = (w >= self.band_rad_s[0]) & (w <= self.band_rad_s[1])
        return float(np.median(c[band])) if band.any() and np.all(np.isfinite(c[band])) else 0.0

    def trim_blocks(self, spans_s: list[tuple[float, float]], margin_s: float = 1.0) -> list[tuple]:
        """The blocks that overlap none of ``spans_s`` (the channel's manoeuvres) widened by ``margin_s``.

        Parameters
        ----------
        spans_s : list of (float, float)
            Start and end of each manoeuvre [s].
        margin_s : float
            Kept clear before and after each [s].
        """
        return [b for b in self.blocks if not any(b[0] < e + margin_s and s - margin_s < b[1] for s, e in spans_s)]

    def feedback_share(self, spans_s: list[tuple[float, float]], since_s: float = -math.inf) -> tuple[int, int]:
        """``(coherent, total)`` trim blocks: how many between the manoeuvres have the surface coherent with the
        rate (:data:`TRIM_COHERENCE`).

        Parameters
        ----------
        spans_s : list of (float, float)
            The channel's manoeuvres [s].
        since_s : float
            Only blocks that start at or after this time [s] (the manoeuvres before it are forgotten).
        """
        blocks = [b for b in self.trim_blocks(spans_s) if b[0] >= since_s]
        return sum(1 for b in blocks if b[2] >= TRIM_COHERENCE), len(blocks)


def welch_coherence(u: np.ndarray, y: np.ndarray, fs_hz: float, nperseg: int) -> tuple[np.ndarray, np.ndarray]:
    """Magnitude-squared coherence by Welch's method: Hann windows of ``nperseg`` samples, half overlapping, each
    segment's mean removed (what ``scipy.signal.coherence`` computes with its defaults, without its per-call
    overhead: the monitor calls it every few seconds of flight).

    Parameters
    ----------
    u, y : ndarray
        Two signals of the same length, uniformly sampled.
    fs_hz : float
        Sample rate [Hz].
    nperseg : int
        Segment length (at most the signals' length).

    Returns
    -------
    f_hz, coherence : ndarray
        Frequencies [Hz] and coherence in [0, 1].
    """
    step = nperseg // 2
    n_seg = 1 + (u.size - nperseg) // step
    idx = np.arange(nperseg)[None, :] + step * np.arange(n_seg)[:, None]
    window = np.hanning(nperseg + 1)[:-1]                  # periodic Hann, as scipy's get_window("hann")
    segments = np.stack([u[idx], y[idx]])
    segments = (segments - segments.mean(axis=2, keepdims=True)) * window
    spectra = np.fft.rfft(segments, axis=2)
    puu = np.mean(np.abs(spectra[0]) ** 2, axis=0)
    pyy = np.mean(np.abs(spectra[1]) ** 2, axis=0)
    puy = np.mean(np.conj(spectra[0]) * spectra[1], axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        coherence = np.abs(puy) ** 2 / (puu * pyy)
    return np.fft.rfftfreq(nperseg, 1.0 / fs_hz), np.where(np.isfinite(coherence), coherence, 0.0)


class SurfaceHistory:
    """The latest samples of one surface (``keep_s`` of them; everything for whole recorded histories), to be read
    at the grid times of another channel's manoeuvres.

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
        """Samples in time order (a step back starts afresh); ``whole``: a whole recorded history, kept entire.

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


class CouplingMonitor:
    """How much another configured surface moves with a channel's input, over the channel's own manoeuvres.

    The channel's estimator reports every manoeuvre that gives a response (its ``record_observer``): the grid
    samples of the input over the excited span. The other surface is read at the same times from its
    :class:`SurfaceHistory` and regressed on the input and its rate (a static or lagged interconnect): the
    multiple coherence ``R^2`` and the gain. An interconnect gives ``R^2`` near 1; a surface held at trim, or
    flown on other lines of an orthogonal multisine, near 0. A manoeuvre whose surface samples have not arrived
    yet waits (at most :data:`PENDING_RECORDS` of them).
    """

    def __init__(self) -> None:
        self.energy = 0.0            # input energy of every manoeuvre
        self.coupled_energy = 0.0    # ... of those where the surface follows the input
        self._r2 = 0.0               # energy-weighted sums over the coupled ones
        self._gain = 0.0
        self.records = 0
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
        t = t0_s + dt_s * np.arange(u.size)
        if u.size < 8:
            return
        if history.covers(t[0], t[-1]):
            self._add(np.asarray(u, float), history.at(t))
        elif not history.t.size or history.t[-1] < t[-1]:       # not arrived yet
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

    def _add(self, u: np.ndarray, other: np.ndarray) -> None:
        u, other = u - np.mean(u), other - np.mean(other)
        x = np.stack([u, np.gradient(u)])
        uu, oo = float(u @ u), float(other @ other)
        if uu <= 0 or oo <= 0:
            return
        try:
            xy = x @ other
            r2 = min(max(float(xy @ np.linalg.solve(x @ x.T, xy)) / oo, 0.0), 1.0)
        except np.linalg.LinAlgError:
            return
        gain = float(u @ other) / uu
        self.records += 1
        self.energy += uu
        if r2 >= COUPLING_COHERENCE and abs(gain) >= COUPLING_GAIN:
            self.coupled_energy += uu
            self._r2 += r2 * uu
            self._gain += gain * uu

    def coupled(self) -> tuple[bool, float, float]:
        """Whether the other surface moves with the input: in manoeuvres carrying at least
        :data:`COUPLING_SHARE` of the input's energy, the surface follows the input (multiple coherence ``R^2`` of
        the surface on the input and its rate >= :data:`COUPLING_COHERENCE`, gain >= :data:`COUPLING_GAIN`).

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
    variance = None if estimate.variance is None else np.where(
        mask, np.maximum(np.asarray(estimate.variance, float),
                         2.0 * (BIAS_ALLOWANCE * np.abs(np.nan_to_num(estimate.response))) ** 2), estimate.variance)
    return replace(estimate, random_error=error, variance=variance)
