"""Recursive (online) frequency-response estimator: the measured responses of the paper's Fig. 4.

Samples of the control surface (input ``x``) and of the body rate (output ``y``) arrive one by one or in
batches, each stream at its own irregular rate. Per completed sweep the estimator keeps a *raw* estimate (the
light curves of Fig. 4) and it pools all sweeps into the *averaged* estimate (the dark curve), with coherence
and random error per frequency. Nothing grows with flight length: the state is a fixed set of arrays.

Data path (one pass, bounded delay)
-----------------------------------
1. **Alignment** (:mod:`gap_validation.core.alignment`). Each stream is interpolated on its own onto one
   uniform grid ``t_k = t0 + k / sample_rate_hz`` (default 100 Hz; must be >= 5x the highest
   frequency). Cubic Hermite interpolation with three-point (parabola) slopes, which on uniform samples is
   Catmull-Rom: a 50 Hz surface stream read on the 100 Hz grid loses < 0.4 % of magnitude at 5 Hz (linear:
   5 %). Only the last three samples per stream are kept. Grid values wait in a bounded queue until the other
   stream has reached the same instant (``max_lag_s``, default 30 s; beyond it the oldest are dropped and
   counted). A spacing larger than ``max_gap_s`` (default 0.5 s) is a gap: no interpolation across it; the
   run of data, its open segments and its sweep end there. Time jumping *back* (a looped bag, two recordings
   with overlapping clocks fed in sequence) by more than ``max(JUMP_BACK_S, max_gap_s)`` starts a new time
   base (``_TimeBase``): once ``JUMP_CONFIRM`` increasing samples confirm it, the stream's times are
   shifted to continue just after the latest sample of any stream (a gap, so the run and its sweep end), and
   the other streams adopt the same shift when they jump too; each jump is counted (``time_jumps_back``).
   Smaller steps back and duplicate stamps are dropped and counted (``non_monotonic``), and so is a single
   stray stamp far back that the next samples do not follow.
2. **Sweep membership** (:mod:`gap_validation.core.sweeps`). The detector sees the newest grid samples; the
   transform sees them ``lookahead_samples`` later (about 2 s, a fixed delay line), by which time it is known
   whether they belong to a sweep. An explicit trigger (:meth:`add_trigger`) overrides detection.
3. **Recursive windowed DFT** (:class:`_SegmentTransform`), run only inside sweeps. Per frequency ``w`` a Hann
   window of ``window_cycles`` periods (default 8; clipped to [``min_window_s``, ``max_window_s``] = [2, 20]
   s; rounded to whole blocks of ``block_s`` = 0.2 s), hop ``(1 - overlap)`` of it (default 50 %), segments
   anchored at the sweep start. The Hann-windowed DFT of a segment starting at sample ``s`` (length ``N``,
   ``Omega = 2 pi / N``) is exactly three plain DFTs::

       X(w) = 0.5 S(w) - 0.25 e^{-j Omega (s - r)} S(w - Omega/dt) - 0.25 e^{+j Omega (s - r)} S(w + Omega/dt)

   with ``S(v) = sum_n x[n] e^{-j v (n - r) dt}`` over the segment and ``r`` the sweep start. ``S`` of every
   segment is a difference of two cumulative sums, and the cumulative sums over whole blocks of ``b`` samples
   are one real matrix product of the block with a precomputed ``b x 6F`` cos/sin table followed by a
   per-block phase from a precomputed table: about ``2 * 3F`` multiply-adds per sample and stream, no
   transcendental function per sample. Cumulative sums are re-based after every batch, phases are relative to
   the sweep start, so float64 precision holds for hours. The segment mean is removed exactly (trim and
   bias, like ``scipy.signal.csd(detrend='constant')``) with one more running sum.
4. **Spectra** (Bendat and Piersol, Random Data, 4th ed., ch. 9). Per frequency, averaged over segments:
   ``Gxx = 2 dt/sum(h^2) |X|^2``, ``Gyy``, ``Gxy = 2 dt/sum(h^2) conj(X) Y`` (one-sided densities, scipy's
   ``scaling='density'``), ``H = Gxy / Gxx`` (the H1 estimator: unbiased by output noise),
   ``gamma^2 = |Gxy|^2 / (Gxx Gyy)``, random error of ``|H|``
   ``eps = sqrt(1 - gamma^2) / (|gamma| sqrt(2 n_d))`` (also the phase error in rad), ``n_d`` = segments.

Why windows of a few cycles, and why coherence means something for one sweep
--------------------------------------------------------------------------
A single DFT of a whole sweep has coherence exactly 1 (one average), so it cannot say which frequencies are
noise. Welch-type averaging over overlapping windows inside the sweep gives ``n_d`` > 1 averages per
frequency and therefore a real coherence and a random error for *each* sweep, as Fig. 4 shows; the same
segments pooled over all sweeps give the average. Windows are sized to the frequency because one length
cannot serve 1-60 rad/s: a window long enough for the lowest frequency leaves a 60-90 s sweep one or two
averages, a window short enough for many averages at high frequency holds less than a cycle at the lowest.

The number of cycles trades random error against *resolution bias*: inside one window a log sweep is nearly
a tone at its instantaneous frequency, so the estimate at ``w`` is a weighted mean of ``H`` over the window's
main lobe (about ``w (1 +/- 2 / window_cycles)``). Measured on the paper's pitch model with a 20 ms delay and
three 60-80 s log sweeps (noise-free): 5 cycles with a 1 s minimum window give up to 5 % error at
20-45 rad/s, 8 cycles with a 2 s minimum 1.5 % (median 0.4 %), at the cost of 1.6 times fewer averages.
Hence the defaults 8 cycles in [2, 20] s: the bias stays below the random error of typical flight data.

A log sweep excites each frequency only for part of the sweep; windows without excitation at a frequency add
output noise to ``Gyy`` and so lower the coherence, while ``n_d`` counts them: the error formula stays
consistent (the variance of ``H`` is ``(1 - gamma^2)/(gamma^2 n_d)`` either way). Pooling *spectra* over
sweeps (rather than averaging the responses) is Welch's average over all segments of all sweeps; it keeps the
H1 estimator unbiased and gives ``n_d`` = total segments. With 50 % overlap of Hann windows neighbouring
segments are correlated by 1/6, which with the approximate formula makes the actual scatter of ``H`` about
5-25 % larger than ``random_error`` states (checked in the tests with a 3-sigma band). Where ``n_d < 2``
coherence is reported as 0 (not meaningful) and the random error as infinite; where ``n_d = 0`` the response
is NaN.

Use
---
Feed the streams roughly in time order (live, or a replay in bag order); one stream may run ahead of the
other by at most ``max_lag_s``; for two whole recorded arrays use
:meth:`FrequencyResponseEstimator.add_time_histories`. Small calls (one message each) are buffered and
processed every ``batch_s`` (0.1 s) of data, so a message costs microseconds, not a pass through the pipeline.
Results cover completed sweeps: a sweep is committed about two seconds (the detector's
look-ahead) after it ends, or at :meth:`FrequencyResponseEstimator.flush`.

Performance (measured by ``benchmarks/bench_estimator.py``): see the README table.
"""
from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from gap_validation.core.alignment import (JUMP_CONFIRM, _NONE, _GridAligner, _StreamResampler, _TimeBase,
                                           jump_back_s)
from gap_validation.core.errors import ConfigError, DataError
from gap_validation.core.manoeuvres import Manoeuvre, ManoeuvreRecorder
from gap_validation.core.numbers import NON_NEGATIVE, POSITIVE, check_number
from gap_validation.core.sweeps import DETECTOR_DEFAULTS, SweepDetector, TriggerTracker

__all__ = ["FrequencyResponseEstimator", "SpectralEstimate", "ESTIMATOR_DEFAULTS"]

#: Options of :class:`FrequencyResponseEstimator` and their defaults (units in the names).
ESTIMATOR_DEFAULTS = {
    "sample_rate_hz": 100.0,      # uniform grid the streams are aligned on; >= 5x the top frequency
    "window_cycles": 8.0,         # Hann window length in periods of each frequency
    "min_window_s": 2.0,
    "max_window_s": 20.0,
    "overlap": 0.5,               # 0, 1/2, 2/3, 3/4, ... (1 - 1/m)
    "block_s": 0.2,               # segment boundaries are on this block grid
    "detrend": True,              # remove each segment's mean (trim, bias)
    "cubic_interpolation": True,  # False: linear interpolation onto the grid
    "max_gap_s": 0.5,             # a larger sample spacing breaks the data
    "max_lag_s": 30.0,            # how far one stream may run ahead of the other before data are dropped
    "batch_s": 0.1,               # samples arriving in small calls are processed in batches of this span
    "detect_sweeps": True,        # False: only an explicit trigger defines sweeps
    **DETECTOR_DEFAULTS,          # energy_window_s, hold_s, on_ratio, off_ratio, min_excitation, quiet_window_s
    "min_sweep_s": 10.0,          # detected excitations shorter than this are not sweeps (doublets, steps)
    "max_raw_sweeps": 50,         # per-sweep estimates kept (most recent); the average pools all sweeps
}
_BOOL_OPTIONS = ("detrend", "cubic_interpolation", "detect_sweeps")
_INT_OPTIONS = ("max_raw_sweeps",)
_MATMUL_SIZE = 1e6               # multiply-adds per matrix product: below where OpenBLAS goes multi-threaded
                                 # (on a loaded 2-core machine that was 4-10x slower), large enough to amortise
_EVENT_CAP = 64                  # pending sweep edges
_BUFFER_CAP = 256                # samples per stream buffered before processing (amortises per-call cost)
_ENERGY, _TRIGGER = 0, 1         # source of a sweep
_STATE_VERSION = 2                 # 2: doublets kept (``man.*``); version 1 checkpoints still load


def _upgrade_state(state: dict) -> dict:
    """A checkpoint written before time bases existed, with their neutral values filled in."""
    if "epoch" in state:
        return state
    st = {"epoch": 0, "epoch_offset": 0.0, **state}
    for prefix in ("in.", "out."):
        st.update({prefix + "epoch": 0, prefix + "offset": 0.0, prefix + "pend": np.zeros((2, JUMP_CONFIRM)),
                   prefix + "pend_n": 0, prefix + "jumps": 0})
    counts = [int(c) for c in state.get("trig_counts", (0, 0, 0))]
    st.update({"tbase.last_t": float(state.get("trig_last_t", -np.inf)), "tbase.accepted": counts[0],
               "tbase.nonfinite": counts[1], "tbase.non_monotonic": counts[2], "tbase.epoch": 0,
               "tbase.offset": 0.0, "tbase.pend": np.zeros((2, JUMP_CONFIRM)), "tbase.pend_n": 0,
               "tbase.jumps": 0})
    return st


# ---------------------------------------------------------------------------------------------- results
@dataclass(frozen=True)
class SpectralEstimate:
    """Spectra and frequency response at the channel's frequencies (one sweep, or pooled over sweeps).

    Attributes
    ----------
    w_rad_s : ndarray
        Frequencies [rad/s].
    gxx, gyy : ndarray
        One-sided auto-spectral densities of input and output [unit^2/Hz].
    gxy : ndarray
        One-sided cross-spectral density, ``conj(X) Y`` convention (complex) [unit_x unit_y/Hz].
    n_averages : ndarray
        Number of window segments averaged per frequency (``n_d``).
    response : ndarray
        ``H = Gxy / Gxx`` (complex; NaN where ``n_averages == 0``).
    coherence : ndarray
        ``|Gxy|^2 / (Gxx Gyy)`` in [0, 1]; 0 where ``n_averages < 2``.
    random_error : ndarray
        Normalised random error of ``|H|`` (and phase error in rad), Bendat and Piersol:
        ``sqrt(1 - gamma^2) / (|gamma| sqrt(2 n_d))``; inf where ``n_averages < 2`` or coherence is 0.
    start_s, end_s : float
        Time span of the sweep (pooled: first start, last end) [s].
    n_sweeps : int
        Sweeps pooled in this estimate (1 for a raw estimate).
    """

    w_rad_s: np.ndarray
    gxx: np.ndarray
    gyy: np.ndarray
    gxy: np.ndarray
    n_averages: np.ndarray
    response: np.ndarray
    coherence: np.ndarray
    random_error: np.ndarray
    start_s: float = float("nan")
    end_s: float = float("nan")
    n_sweeps: int = 1

    @classmethod
    def from_sums(cls, w_rad_s: ArrayLike, sum_xx: ArrayLike, sum_yy: ArrayLike, sum_xy: ArrayLike, n: ArrayLike,
                  start_s: float = float("nan"), end_s: float = float("nan"),
                  n_sweeps: int = 1) -> "SpectralEstimate":
        """Estimate from sums over segments of scaled ``|X|^2``, ``|Y|^2``, ``conj(X) Y`` and their count.

        Parameters
        ----------
        w_rad_s : array_like
            Frequencies [rad/s].
        sum_xx, sum_yy : array_like
            Sums of the scaled ``|X|^2`` and ``|Y|^2`` per frequency.
        sum_xy : array_like of complex
            Sum of the scaled ``conj(X) Y`` per frequency.
        n : array_like of int
            Segments summed per frequency (``n_d``).
        start_s, end_s : float
            Time span of the sweep(s) [s].
        n_sweeps : int
            Sweeps pooled.
        """
        n = np.asarray(n, dtype=np.int64)
        with np.errstate(divide="ignore", invalid="ignore"):
            safe_n = np.maximum(n, 1)
            gxx = np.where(n > 0, np.asarray(sum_xx, float) / safe_n, 0.0)
            gyy = np.where(n > 0, np.asarray(sum_yy, float) / safe_n, 0.0)
            gxy = np.where(n > 0, np.asarray(sum_xy, complex) / safe_n, 0.0)
            response = np.where((n > 0) & (gxx > 0), gxy / gxx, np.nan + 0j)
            coh = np.abs(gxy) ** 2 / (gxx * gyy)
            coh = np.where((n >= 2) & np.isfinite(coh), np.clip(coh, 0.0, 1.0), 0.0)
            err = np.sqrt(1.0 - coh) / (np.sqrt(coh) * np.sqrt(2.0 * safe_n))
            err = np.where((n >= 2) & (coh > 0), err, np.inf)
        return cls(np.asarray(w_rad_s, float).copy(), gxx, gyy, gxy, n.copy(), response, coh, err,
                   float(start_s), float(end_s), int(n_sweeps))


# ---------------------------------------------------------------------------------------------- options
def _number(name: str, value: Any, positive: bool = True) -> float:
    """An estimator option's number (numeric strings accepted), > 0 or (``positive=False``) >= 0."""
    return check_number(value, f"estimator option {name}", POSITIVE if positive else NON_NEGATIVE, strings=True,
                        expected=f"a {'positive' if positive else 'non-negative'} finite number")


def _validate_options(w_rad_s: np.ndarray, options: dict) -> dict:
    unknown = sorted(set(options) - set(ESTIMATOR_DEFAULTS))
    if unknown:
        raise ConfigError(f"estimator option {unknown[0]!r} is unknown "
                          f"(known: {', '.join(ESTIMATOR_DEFAULTS)})")
    opts = {**ESTIMATOR_DEFAULTS, **options}
    out = {}
    for name, value in opts.items():
        if name in _BOOL_OPTIONS:
            if not isinstance(value, (bool, np.bool_, int, np.integer)) or value not in (0, 1):
                raise ConfigError(f"estimator option {name}: expected true or false, got {value!r}")
            out[name] = bool(value)
        elif name in _INT_OPTIONS:
            number = _number(name, value)
            if not number.is_integer():
                raise ConfigError(f"estimator option {name}: expected a positive integer, got {value!r}")
            out[name] = int(number)
        elif name in ("overlap", "min_sweep_s", "batch_s"):
            out[name] = _number(name, value, positive=False)
        else:
            out[name] = _number(name, value)
    if not out["overlap"] < 1.0:
        raise ConfigError(f"estimator option overlap: expected 0 <= overlap < 1, got {opts['overlap']!r}")
    slots = 1.0 / (1.0 - out["overlap"])
    if abs(slots - round(slots)) > 1e-3:
        raise ConfigError(f"estimator option overlap: {opts['overlap']!r} is not 1 - 1/m "
                          f"(use 0, 0.5, 0.6667, 0.75, ...)")
    if out["max_window_s"] < out["min_window_s"]:
        raise ConfigError(f"estimator option max_window_s: {opts['max_window_s']!r} is below "
                          f"min_window_s {opts['min_window_s']!r}")
    f_max = float(np.max(w_rad_s)) / (2.0 * math.pi)
    if out["sample_rate_hz"] < 5.0 * f_max:
        raise ConfigError(f"estimator option sample_rate_hz: {opts['sample_rate_hz']!r} Hz is below 5x the "
                          f"highest frequency ({f_max:.4g} Hz)")
    return out


# ---------------------------------------------------------------------------------------------- transform
class _SegmentTransform:
    """Hann-windowed DFTs of overlapping segments inside one sweep, by block-wise running sums.

    Parameters
    ----------
    w_rad_s : ndarray
        Frequencies [rad/s] (F).
    sample_rate_hz : float
        Grid rate [Hz].
    block_n : int
        Samples per block ``b``; segment boundaries lie on blocks counted from the sweep start.
    window_cycles, min_window_s, max_window_s : float
        Window length per frequency (see module docstring).
    n_slots : int
        Segments overlapping at any time (2 for 50 % overlap).
    detrend : bool
        Remove each segment's mean.
    """

    def __init__(self, w_rad_s: np.ndarray, sample_rate_hz: float, block_n: int, window_cycles: float,
                 min_window_s: float, max_window_s: float, n_slots: int, detrend: bool) -> None:
        w = np.asarray(w_rad_s, dtype=float)
        F = w.size
        dt = 1.0 / sample_rate_hz
        self.F, self.b, self.n_slots, self.detrend = F, block_n, n_slots, detrend
        length_s = np.clip(window_cycles * 2.0 * np.pi / w, min_window_s, max_window_s)
        self.hop_blocks = np.maximum(1, np.rint(length_s / (n_slots * block_n * dt))).astype(np.int64)
        self.win_n = self.hop_blocks * n_slots * block_n            # samples per segment
        omega = 2.0 * np.pi / (self.win_n * dt)                      # Hann side-bin spacing [rad/s]
        nu = np.stack((w - omega, w, w + omega), axis=1).ravel()     # 3F bins
        tt = np.arange(block_n) * dt
        tab = np.zeros((block_n, 6 * F + 2))
        tab[:, 0:6 * F:2] = np.cos(np.outer(tt, nu))
        tab[:, 1:6 * F:2] = -np.sin(np.outer(tt, nu))
        tab[:, 6 * F] = 1.0                                          # running sum for the segment mean
        self._tab = tab
        self._nu_block = nu * block_n * dt
        self._kmax = int(np.clip(_MATMUL_SIZE / (2 * tab.shape[1] * block_n), 8, 256))
        self._ptab = np.exp(-1j * np.outer(np.arange(self._kmax + 1), self._nu_block))
        self._cols = np.column_stack((3 * np.arange(F), 3 * np.arange(F) + 1, 3 * np.arange(F) + 2,
                                      np.full(F, 3 * F)))
        self._wbin = 3 * np.arange(F) + 1
        wf0 = np.empty(F, complex)
        for f in range(F):
            m = np.arange(self.win_n[f])
            hann = 0.5 - 0.5 * np.cos(2.0 * np.pi * m / self.win_n[f])
            wf0[f] = np.sum(hann * np.exp(-1j * w[f] * m * dt))
        self._wf0_per_n = wf0 / self.win_n
        self.scale = 2.0 * dt / (0.375 * self.win_n)                 # 2 dt / sum(hann^2), periodic Hann
        self._sig = np.exp(-2j * np.pi * np.arange(n_slots) / n_slots)
        self.active = False
        self._pbuf = np.zeros((2, block_n))
        self._pb_n = 0
        self._blocks = 0
        self._ring = np.zeros((F, n_slots, 8), complex)
        self._ring_ph = np.ones((F, n_slots), complex)
        self._acc = np.zeros((4, F))                                 # sum xx, yy, Re xy, Im xy
        self._acc_n = np.zeros(F, np.int64)

    def start(self) -> None:
        self.active = True
        self._pb_n = 0
        self._blocks = 0
        self._ring[:] = 0.0
        self._ring_ph[:] = 1.0
        self._acc[:] = 0.0
        self._acc_n[:] = 0

    def end(self) -> tuple[np.ndarray, np.ndarray]:
        """Close the sweep; return (sums (4, F), counts (F,)) and reset."""
        self.active = False
        out = self._acc.copy(), self._acc_n.copy()
        self._acc[:] = 0.0
        self._acc_n[:] = 0
        self._pb_n = 0
        return out

    def feed(self, x: np.ndarray, y: np.ndarray) -> None:
        """Contiguous grid samples of the sweep in progress."""
        b = self.b
        if self._pb_n:
            x = np.concatenate((self._pbuf[0, : self._pb_n], x))
            y = np.concatenate((self._pbuf[1, : self._pb_n], y))
        nb = x.size // b
        if nb:
            xb = x[: nb * b].reshape(nb, b)
            yb = y[: nb * b].reshape(nb, b)
            for c in range(0, nb, self._kmax):
                self._process_blocks(xb[c:c + self._kmax], yb[c:c + self._kmax])
        rest = x.size - nb * b
        self._pbuf[0, :rest] = x[nb * b:]
        self._pbuf[1, :rest] = y[nb * b:]
        self._pb_n = rest

    def _process_blocks(self, xb: np.ndarray, yb: np.ndarray) -> None:
        K, F, n = xb.shape[0], self.F, self.n_slots
        B0 = self._blocks
        # block sums at 3F bins (+ plain sum), phase relative to the sweep start, cumulative over blocks
        prod = np.concatenate((xb, yb)) @ self._tab                  # (2K, 6F + 2)
        blk = prod.view(np.complex128)                               # (2K, 3F + 1)
        ph = self._ptab[: K + 1] * np.exp(-1j * self._nu_block * B0)  # (K + 1, 3F)
        blk[:K, : 3 * F] *= ph[:K]
        blk[K:, : 3 * F] *= ph[:K]
        cx = np.zeros((K + 1, 3 * F + 1), complex)
        cy = np.zeros((K + 1, 3 * F + 1), complex)
        np.cumsum(blk[:K], axis=0, out=cx[1:])
        np.cumsum(blk[K:], axis=0, out=cy[1:])
        # segment boundaries (every hop) inside this batch: j = jl .. jh for each frequency
        H = self.hop_blocks
        jl = B0 // H + 1
        jh = (B0 + K) // H
        cnt = np.maximum(jh - jl + 1, 0)
        fr = np.arange(F)
        if cnt.any():
            E = int(cnt.sum())
            ev_f = np.repeat(fr, cnt)
            first = np.cumsum(cnt) - cnt
            rank = np.arange(E) - np.repeat(first, cnt)
            ev_j = jl[ev_f] + rank
            ev_k = ev_j * H[ev_f] - B0
            cols = self._cols[ev_f]
            now = np.empty((E, 8), complex)
            now[:, :4] = cx[ev_k[:, None], cols]
            now[:, 4:] = cy[ev_k[:, None], cols]
            now_ph = ph[ev_k, self._wbin[ev_f]]
            # per frequency: its n_slots stored boundaries followed by this batch's boundaries
            off = np.cumsum(n + cnt) - (n + cnt)
            slots = np.arange(n)
            ring_pos = (off[:, None] + slots).ravel()
            ring_slot = (jl[:, None] - n + slots) % n
            ext = np.empty((F * n + E, 8), complex)
            ext_ph = np.empty(F * n + E, complex)
            ext[ring_pos] = self._ring[fr[:, None], ring_slot].reshape(F * n, 8)
            ext_ph[ring_pos] = self._ring_ph[fr[:, None], ring_slot].ravel()
            ev_pos = off[ev_f] + n + rank
            ext[ev_pos] = now
            ext_ph[ev_pos] = now_ph
            done = ev_j >= n
            if done.any():
                self._accumulate(ext, ext_ph, ev_pos[done], ev_f[done], ev_j[done] - n)
            last_pos = (off[:, None] + cnt[:, None] + slots).ravel()
            last_slot = (jh[:, None] - n + 1 + slots) % n
            self._ring[fr[:, None], last_slot] = ext[last_pos].reshape(F, n, 8)
            self._ring_ph[fr[:, None], last_slot] = ext_ph[last_pos].reshape(F, n)
        # re-base: cumulative sums restart from zero at the end of this batch
        self._ring[:, :, :4] -= cx[K, self._cols][:, None, :]
        self._ring[:, :, 4:] -= cy[K, self._cols][:, None, :]
        self._blocks = B0 + K

    def _accumulate(self, ext, ext_ph, pos, f, j_start) -> None:
        d = ext[pos] - ext[pos - self.n_slots]                       # plain DFT sums over each segment
        sg = self._sig[j_start % self.n_slots]
        sgc = np.conj(sg)
        X = 0.5 * d[:, 1] - 0.25 * (sg * d[:, 0] + sgc * d[:, 2])
        Y = 0.5 * d[:, 5] - 0.25 * (sg * d[:, 4] + sgc * d[:, 6])
        if self.detrend:
            w_mean = ext_ph[pos - self.n_slots] * self._wf0_per_n[f]   # DFT of the window / N at start
            X = X - d[:, 3].real * w_mean
            Y = Y - d[:, 7].real * w_mean
        sc = self.scale[f]
        xy = np.conj(X) * Y
        F = self.F
        self._acc[0] += np.bincount(f, (X.real ** 2 + X.imag ** 2) * sc, F)
        self._acc[1] += np.bincount(f, (Y.real ** 2 + Y.imag ** 2) * sc, F)
        self._acc[2] += np.bincount(f, xy.real * sc, F)
        self._acc[3] += np.bincount(f, xy.imag * sc, F)
        self._acc_n += np.bincount(f, minlength=F)

    def state_dict(self) -> dict:
        return {"active": int(self.active), "pbuf": self._pbuf.copy(), "pb_n": self._pb_n,
                "blocks": self._blocks, "ring": self._ring.copy(), "ring_ph": self._ring_ph.copy(),
                "acc": self._acc.copy(), "acc_n": self._acc_n.copy()}

    def load_state(self, st: dict) -> None:
        self.active = bool(st["active"])
        self._pbuf[:] = st["pbuf"]
        self._pb_n, self._blocks = int(st["pb_n"]), int(st["blocks"])
        self._ring[:] = st["ring"]
        self._ring_ph[:] = st["ring_ph"]
        self._acc[:] = st["acc"]
        self._acc_n[:] = st["acc_n"]


# ---------------------------------------------------------------------------------------------- estimator
class FrequencyResponseEstimator:
    """Online frequency response from separate input and output streams, per sweep and pooled (Fig. 4).

    Parameters
    ----------
    w_rad_s : array_like
        Frequencies to estimate [rad/s] (e.g. log-spaced, ``FrequencyGrid.values()``).
    **options
        See :data:`ESTIMATOR_DEFAULTS` and the module docstring. Unknown names raise
        :class:`~gap_validation.core.errors.ConfigError` naming the key.

    Notes
    -----
    Feed the streams roughly interleaved in time (live, or a replay in bag order): one stream may run ahead
    of the other by at most ``max_lag_s``. For two whole recorded arrays use :meth:`add_time_histories`.
    Results cover completed sweeps; :meth:`flush` closes the sweep in progress at the end of data.
    """

    #: Accepted option names (the config checks them against this).
    OPTIONS = tuple(ESTIMATOR_DEFAULTS)

    def __init__(self, w_rad_s: ArrayLike, **options: Any) -> None:
        w = np.atleast_1d(np.asarray(w_rad_s, dtype=float))
        if w.ndim != 1 or w.size == 0 or not np.all(np.isfinite(w)) or np.any(w <= 0):
            raise ConfigError(f"estimator frequencies: expected positive finite rad/s values, got {w_rad_s!r}")
        opts = _validate_options(w, options)
        self._w = w.copy()
        self._opts = opts
        fs = opts["sample_rate_hz"]
        self._dt = 1.0 / fs
        self._n_slots = int(round(1.0 / (1.0 - opts["overlap"])))
        block_n = max(1, int(round(opts["block_s"] * fs)))
        self._xf = _SegmentTransform(w, fs, block_n, opts["window_cycles"], opts["min_window_s"],
                                     opts["max_window_s"], self._n_slots, opts["detrend"])
        self._det = SweepDetector(fs, **{k: opts[k] for k in DETECTOR_DEFAULTS})
        self._man = ManoeuvreRecorder(fs, opts["min_sweep_s"])
        self._trig = TriggerTracker()
        self._streams = [_StreamResampler(self._dt, opts["max_gap_s"], opts["cubic_interpolation"])
                         for _ in range(2)]
        self._align = _GridAligner(max(16, int(math.ceil(opts["max_lag_s"] * fs))))
        self._delay_n = self._det.lookahead_samples
        self._dl = np.zeros((2, self._delay_n))
        self._dl_n = 0
        self._dl_k0 = 0
        self._buf = np.zeros((2, 2, _BUFFER_CAP))          # stream, (t, value), sample
        self._buf_n = [0, 0]
        self._t0 = float("nan")
        self._last_k: int | None = None
        self._trigger_mode = not opts["detect_sweeps"]
        self._trig_base = _TimeBase()
        self._jump_tol_s = jump_back_s(opts["max_gap_s"])
        self._jump_gap_s = 2.0 * opts["max_gap_s"] + 1.0     # between the old and the new time base [s]
        self._epoch = 0
        self._epoch_offset = 0.0
        self._events: list[tuple[int, bool, int]] = []
        self._events_dropped = 0
        self._desired = False
        self._desired_src = _ENERGY
        self._sweep_k0 = 0
        self._sweep_src = _ENERGY
        R, F = opts["max_raw_sweeps"], w.size
        self._raw = np.zeros((R, 4, F))
        self._raw_n = np.zeros((R, F), np.int64)
        self._raw_span = np.zeros((R, 2), np.int64)
        self._n_sweeps = 0
        self._tot = np.zeros((4, F))
        self._tot_n = np.zeros(F, np.int64)
        self._span = [0, 0]

    # ------------------------------------------------------------------ properties
    @property
    def w_rad_s(self) -> np.ndarray:
        """Frequencies [rad/s]."""
        return self._w.copy()

    @property
    def options(self) -> dict:
        """All options in effect (defaults filled in)."""
        return dict(self._opts)

    @property
    def window_s(self) -> np.ndarray:
        """Hann window length per frequency [s] (after clipping and rounding to blocks)."""
        return self._xf.win_n * self._dt

    @property
    def hop_s(self) -> np.ndarray:
        """Distance between segment starts per frequency [s]."""
        return self._xf.hop_blocks * self._xf.b * self._dt

    @property
    def n_sweeps(self) -> int:
        """Sweeps completed and pooled so far (raw estimates kept: at most ``max_raw_sweeps``)."""
        return self._n_sweeps

    @property
    def in_sweep(self) -> bool:
        """True while the transform is inside a sweep (delayed by ``lookahead_samples``)."""
        return self._xf.active

    @property
    def t0_s(self) -> float:
        """Time origin of the grid [s] (NaN before the first sample)."""
        return self._t0

    @property
    def bad_sample_counts(self) -> dict:
        """Counts of samples not used, by stream and reason.

        ``nonfinite`` (NaN/inf time or value, or absurd: ``|t| >= 1e11`` s, ``|value| >= 1e100``), ``non_monotonic`` (time not after an earlier sample, within
        ``max(JUMP_BACK_S, max_gap_s)``, or a stray stamp further back), ``time_jumps_back`` (new time bases
        started: not samples lost, the data before and after both count), ``dropped_lag`` (grid values given up because the other stream fell more than ``max_lag_s`` behind
        or had no data), and ``events_dropped`` (sweep edges beyond the bounded queue).
        """
        out = {}
        for s, name in ((0, "input"), (1, "output")):
            b = self._streams[s].base
            out[name] = {"accepted": b.accepted, "nonfinite": b.nonfinite, "non_monotonic": b.non_monotonic,
                         "time_jumps_back": b.jumps, "dropped_lag": self._align.dropped[s]}
        b = self._trig_base
        out["trigger"] = {"accepted": b.accepted, "nonfinite": b.nonfinite, "non_monotonic": b.non_monotonic,
                          "time_jumps_back": b.jumps}
        out["events_dropped"] = self._events_dropped
        return out

    # ------------------------------------------------------------------ data in
    def add_input(self, t_s: ArrayLike, u: ArrayLike) -> None:
        """Feed control-surface samples: times [s] (increasing) and values, any rate, jitter or drops.

        Parameters
        ----------
        t_s : array_like
            Sample times [s], increasing.
        u : array_like
            Surface deflections [rad].
        """
        self._add_stream(0, t_s, u, "input")

    def add_output(self, t_s: ArrayLike, y: ArrayLike) -> None:
        """Feed response (e.g. IMU body-rate) samples: times [s] and values, as :meth:`add_input`.

        Parameters
        ----------
        t_s, y : array_like
            Sample times [s] (increasing) and body rates [rad/s].
        """
        self._add_stream(1, t_s, y, "output")

    def add_time_histories(self, t_input_s: ArrayLike, u: ArrayLike, t_output_s: ArrayLike, y: ArrayLike,
                           chunk_s: float | None = None) -> None:
        """Feed two whole recorded streams, interleaved in chunks of ``chunk_s`` [s].

        The chunk is at most ``max_lag_s / 2`` (default ``max_lag_s / 3``) so that nothing is dropped.

        Parameters
        ----------
        t_input_s, u : array_like
            Input sample times [s] and values.
        t_output_s, y : array_like
            Output sample times [s] and values.
        chunk_s : float, optional
            Interleaving chunk [s] (default ``max_lag_s / 3``).
        """
        t_input_s, u = np.asarray(t_input_s, float).ravel(), np.asarray(u, float).ravel()
        t_output_s, y = np.asarray(t_output_s, float).ravel(), np.asarray(y, float).ravel()
        if t_input_s.shape != u.shape or t_output_s.shape != y.shape:
            raise DataError(f"add_time_histories: {t_input_s.size} input times for {u.size} values, "
                            f"{t_output_s.size} output times for {y.size} values")
        finite = np.concatenate((t_input_s[np.isfinite(t_input_s)], t_output_s[np.isfinite(t_output_s)]))
        if t_input_s.size == 0 or t_output_s.size == 0 or finite.size == 0:
            self.add_input(t_input_s, u)
            self.add_output(t_output_s, y)
            return
        lag = self._opts["max_lag_s"]
        step = lag / 3.0 if chunk_s is None else min(_number("chunk_s", chunk_s), lag / 2.0)
        lo = float(finite.min())
        # only the chunk ends that close a non-empty chunk (empty chunks are no-ops): at most one per sample,
        # however far apart the timestamps are (a stray zero stamp among epoch times would be 1e8 chunks)
        edges = lo + np.unique(np.maximum(np.ceil((finite - lo) / step), 1.0)) * step
        ia = np.searchsorted(t_input_s, edges, side="right")
        ib = np.searchsorted(t_output_s, edges, side="right")
        pa = pb = 0
        for a, b in zip(ia, ib):
            self.add_input(t_input_s[pa:a], u[pa:a])
            self.add_output(t_output_s[pb:b], y[pb:b])
            pa, pb = a, b
        self.add_input(t_input_s[pa:], u[pa:])
        self.add_output(t_output_s[pb:], y[pb:])

    def add_trigger(self, t_s: ArrayLike, active: ArrayLike) -> None:
        """Feed samples of an explicit sweep trigger (``std_msgs/Bool``): sweeps are where it is true.

        The first trigger sample switches sweep detection off for the rest of the flight.

        Parameters
        ----------
        t_s : array_like
            Sample times [s].
        active : array_like of bool
            True inside a sweep.
        """
        t = np.atleast_1d(np.asarray(t_s, dtype=float)).ravel()
        a = np.atleast_1d(np.asarray(active)).ravel()
        if t.shape != a.shape:
            raise DataError(f"trigger: {t.size} times but {a.size} values")
        t, a = self._trig_base.intake(t, a.astype(float), self._jump_tol_s, self._new_base)
        if t.size == 0:
            return
        self._ensure_t0(t[0])
        k = np.ceil((t - self._t0) / self._dt - 1e-9).astype(np.int64)
        if not self._trigger_mode:
            self._drain(0)
            self._drain(1)
            self._enter_trigger_mode(int(k[0]))
        for kk, on in self._trig.edges(k, a != 0):
            self._push_event(kk, on, _TRIGGER)

    def flush(self) -> None:
        """End of data (or a pause): process everything received and close the sweep in progress."""
        self._drain(0)
        self._drain(1)
        self._trig_base.drop_pending()
        for s in (0, 1):
            self._streams[s].base.drop_pending()
            k, v = self._streams[s].flush()
            self._align.push(s, k, v)
        idx, x, y = self._align.combine(self._streams[0].k_next, self._streams[1].k_next)
        self._process_combined(idx, x, y)
        self._align.clear()
        if self._last_k is not None:
            self._end_run()

    # ------------------------------------------------------------------ results
    @property
    def sweeps(self) -> list[SpectralEstimate]:
        """Raw estimate of each completed sweep (the most recent ``max_raw_sweeps``), oldest first."""
        R = self._raw.shape[0]
        kept = min(self._n_sweeps, R)
        out = []
        for i in range(self._n_sweeps - kept, self._n_sweeps):
            r = i % R
            acc = self._raw[r]
            out.append(SpectralEstimate.from_sums(
                self._w, acc[0], acc[1], acc[2] + 1j * acc[3], self._raw_n[r],
                self._time(self._raw_span[r, 0]), self._time(self._raw_span[r, 1]), 1))
        return out

    @property
    def manoeuvres(self) -> list[Manoeuvre]:
        """Short manoeuvres (doublets) found between sweeps, kept for the time-domain check (largest 3)."""
        return self._man.manoeuvres(self._t0, self._dt)

    @property
    def manoeuvres_key(self) -> bytes:
        """Changes exactly when :attr:`manoeuvres` changes."""
        return self._man.key

    def averaged(self) -> SpectralEstimate | None:
        """Estimate pooled over all completed sweeps (None before the first)."""
        if self._n_sweeps == 0:
            return None
        acc = self._tot
        return SpectralEstimate.from_sums(self._w, acc[0], acc[1], acc[2] + 1j * acc[3], self._tot_n,
                                          self._time(self._span[0]), self._time(self._span[1]),
                                          self._n_sweeps)

    def _time(self, k: int) -> float:
        return float(self._t0 + k * self._dt)

    # ------------------------------------------------------------------ internals: streams
    def _ensure_t0(self, t: float) -> None:
        if math.isnan(self._t0):
            self._t0 = float(math.floor(t))

    def _add_stream(self, s: int, t_s, values, name: str) -> None:
        t = np.atleast_1d(np.asarray(t_s, dtype=float)).ravel()
        v = np.atleast_1d(np.asarray(values, dtype=float)).ravel()
        if t.shape != v.shape:
            raise DataError(f"{name}: {t.size} times but {v.size} values")
        n = self._buf_n[s]
        if n + t.size > _BUFFER_CAP or t.size > _BUFFER_CAP // 2:
            self._drain(s)                                  # keep time order: older samples first
            n = 0
        if t.size > _BUFFER_CAP // 2:
            self._process_stream(s, t, v)
            return
        buf = self._buf[s]
        buf[0, n:n + t.size] = t
        buf[1, n:n + t.size] = v
        self._buf_n[s] = n = n + t.size
        if n and not buf[0, n - 1] - buf[0, 0] < self._opts["batch_s"]:     # also on NaN times
            self._drain(s)

    def _drain(self, s: int) -> None:
        n = self._buf_n[s]
        if n:
            self._buf_n[s] = 0
            self._process_stream(s, self._buf[s, 0, :n].copy(), self._buf[s, 1, :n].copy())

    def _process_stream(self, s: int, t: np.ndarray, v: np.ndarray) -> None:
        st = self._streams[s]
        t, v = st.base.intake(t, v, self._jump_tol_s, self._new_base, self._jump_tol_s)
        if t.size == 0:
            return
        self._ensure_t0(t[0])
        k, vals = st.add(t - self._t0, v)
        self._align.push(s, k, vals)
        idx, x, y = self._align.combine(self._streams[0].k_next, self._streams[1].k_next)
        self._process_combined(idx, x, y)

    def _new_base(self, base: _TimeBase, t_raw: float) -> None:
        """``base``'s time jumped back to ``t_raw`` [s] (confirmed): adopt the new time base another stream
        already opened, or open one just after the latest sample of every stream (a gap: the run ends)."""
        if self._epoch > base.epoch and t_raw + self._epoch_offset > base.latest_s + self._opts["max_gap_s"]:
            base.epoch, base.offset = self._epoch, self._epoch_offset
            return
        latest = max(b.latest_s for b in (self._streams[0].base, self._streams[1].base, self._trig_base))
        self._epoch += 1
        # a whole number of grid steps: the new base samples the data at the same grid phase as before
        self._epoch_offset = math.ceil((latest + self._jump_gap_s - t_raw) / self._dt) * self._dt
        base.epoch, base.offset = self._epoch, self._epoch_offset

    def _process_combined(self, idx: np.ndarray, x: np.ndarray, y: np.ndarray) -> None:
        if idx.size == 0:
            return
        cuts = np.flatnonzero(np.diff(idx) != 1) + 1
        bounds = np.concatenate(([0], cuts, [idx.size]))
        for a, b in zip(bounds[:-1], bounds[1:]):
            k0 = int(idx[a])
            if self._last_k is not None and k0 != self._last_k + 1:
                self._end_run()
            if self._last_k is None:
                self._det.start_run(k0)
            self._run_chunk(k0, x[a:b], y[a:b])
            self._last_k = int(idx[b - 1])

    def _run_chunk(self, k0: int, x: np.ndarray, y: np.ndarray) -> None:
        if not self._trigger_mode:
            for k, on in self._det.process(k0, x):
                self._push_event(k, on, _ENERGY)
        D = self._delay_n
        if self._dl_n:
            xs = np.concatenate((self._dl[0, : self._dl_n], x))
            ys = np.concatenate((self._dl[1, : self._dl_n], y))
            ks = self._dl_k0
        else:
            xs, ys, ks = x, y, k0
        release = xs.size - D
        if release > 0:
            self._consume(ks, xs[:release], ys[:release])
            self._dl[0], self._dl[1] = xs[release:], ys[release:]
            self._dl_n, self._dl_k0 = D, ks + release
        else:
            self._dl[0, : xs.size], self._dl[1, : xs.size] = xs, ys
            self._dl_n, self._dl_k0 = xs.size, ks

    def _end_run(self) -> None:
        """The current run of contiguous data ended (gap or end of data)."""
        k_end = self._last_k + 1
        if not self._trigger_mode:
            for k, on in self._det.end_run(k_end):
                self._push_event(k, on, _ENERGY)
        if self._dl_n:
            self._consume(self._dl_k0, self._dl[0, : self._dl_n].copy(), self._dl[1, : self._dl_n].copy())
            self._dl_n = 0
        while self._events and self._events[0][0] <= k_end:
            _, on, src = self._events.pop(0)
            self._desired, self._desired_src = on, src
        if self._xf.active:
            self._finish_sweep(k_end)
        self._man.end_run()
        self._last_k = None

    # ------------------------------------------------------------------ internals: sweeps
    def _push_event(self, k: int, on: bool, src: int) -> None:
        keys = [e[0] for e in self._events]
        self._events.insert(bisect.bisect_right(keys, k), (int(k), bool(on), int(src)))
        if len(self._events) > _EVENT_CAP:
            self._events.pop(0)
            self._events_dropped += 1

    def _enter_trigger_mode(self, k_switch: int) -> None:
        self._trigger_mode = True
        self._events = [e for e in self._events if e[0] < k_switch]
        on = self._events[-1][1] if self._events else self._desired
        if on:
            self._push_event(k_switch, False, _ENERGY)

    def _consume(self, k_a: int, xs: np.ndarray, ys: np.ndarray) -> None:
        """Released (delayed) contiguous grid samples from index ``k_a``: split at sweep edges, transform."""
        end = k_a + xs.size
        pos = k_a
        if self._desired and not self._xf.active:
            self._start_sweep(pos, self._desired_src)
        while self._events and self._events[0][0] < end:
            k, on, src = self._events.pop(0)
            k = max(k, pos)
            if k > pos:
                self._feed(pos, xs[pos - k_a: k - k_a], ys[pos - k_a: k - k_a])
            pos = k
            self._desired, self._desired_src = on, src
            if on and not self._xf.active:
                self._start_sweep(k, src)
            elif not on and self._xf.active:
                self._finish_sweep(k)
        if end > pos:
            self._feed(pos, xs[pos - k_a:], ys[pos - k_a:])

    def _feed(self, k_a: int, xs: np.ndarray, ys: np.ndarray) -> None:
        """Released samples between two sweep edges: to the manoeuvre ring, and to the transform in a sweep."""
        self._man.record(k_a, xs, ys)
        if self._xf.active:
            self._xf.feed(xs, ys)

    def _start_sweep(self, k: int, src: int) -> None:
        self._xf.start()
        self._sweep_k0, self._sweep_src = int(k), int(src)
        self._man.cut(self._sweep_k0)

    def _finish_sweep(self, k_end: int) -> None:
        acc, n = self._xf.end()
        long_enough = (k_end - self._sweep_k0) * self._dt >= self._opts["min_sweep_s"] - 1e-9
        if self._sweep_src == _ENERGY and not long_enough:
            self._man.excitation(self._sweep_k0, k_end)       # a doublet, a pulse or a trim step
            return
        if n.sum() == 0:
            return
        R = self._raw.shape[0]
        r = self._n_sweeps % R
        self._raw[r] = acc
        self._raw_n[r] = n
        self._raw_span[r] = (self._sweep_k0, k_end)
        if self._n_sweeps == 0:
            self._span[0] = self._sweep_k0
        self._span[1] = k_end
        self._n_sweeps += 1
        self._tot += acc
        self._tot_n += n

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict:
        """Complete state as a flat dict of numpy arrays and numbers (size independent of flight length).

        :meth:`from_state` rebuilds an estimator that continues exactly where this one stopped.
        """
        st: dict = {"version": _STATE_VERSION, "w_rad_s": self._w.copy()}
        for name, value in self._opts.items():
            st["opt." + name] = int(value) if name in _BOOL_OPTIONS + _INT_OPTIONS else float(value)
        ev = np.zeros((_EVENT_CAP, 3), np.int64)
        for i, e in enumerate(self._events):
            ev[i] = e
        st.update({
            "t0": self._t0, "last_k": _NONE if self._last_k is None else self._last_k,
            "trigger_mode": int(self._trigger_mode), "epoch": self._epoch, "epoch_offset": self._epoch_offset,
            "events": ev, "n_events": len(self._events), "events_dropped": self._events_dropped,
            "desired": int(self._desired), "desired_src": self._desired_src,
            "sweep_k0": self._sweep_k0, "sweep_src": self._sweep_src,
            "dl": self._dl.copy(), "dl_n": self._dl_n, "dl_k0": self._dl_k0,
            "buf": self._buf.copy(), "buf_n": np.array(self._buf_n, np.int64),
            "raw": self._raw.copy(), "raw_n": self._raw_n.copy(), "raw_span": self._raw_span.copy(),
            "n_sweeps": self._n_sweeps, "tot": self._tot.copy(), "tot_n": self._tot_n.copy(),
            "span": np.array(self._span, np.int64),
        })
        parts = {"in": self._streams[0], "out": self._streams[1], "align": self._align, "xf": self._xf,
                 "det": self._det, "trig": self._trig, "tbase": self._trig_base, "man": self._man}
        for prefix, part in parts.items():
            for key, value in part.state_dict().items():
                st[f"{prefix}.{key}"] = value
        return st

    @classmethod
    def from_state(cls, state: dict) -> "FrequencyResponseEstimator":
        """Rebuild an estimator from :meth:`state_dict` (e.g. a checkpoint loaded from disk).

        Parameters
        ----------
        state : dict
            From :meth:`state_dict` (version 1 or 2).
        """
        version = state.get("version") if isinstance(state, dict) else None
        if version is None or int(version) not in (1, _STATE_VERSION):
            raise DataError(f"estimator state: unsupported version {version!r} (expected {_STATE_VERSION})")
        try:
            opts = {}
            for name in ESTIMATOR_DEFAULTS:
                value = state["opt." + name]
                opts[name] = (bool(value) if name in _BOOL_OPTIONS else
                              int(value) if name in _INT_OPTIONS else float(value))
            self = cls(np.asarray(state["w_rad_s"], float), **opts)
            state = _upgrade_state(state)
            if int(version) == 1:      # before doublets were kept: none kept yet
                state = {**{f"man.{k}": v for k, v in self._man.state_dict().items()}, **state}
            missing = sorted(set(self.state_dict()) - set(state))
            if missing:
                raise KeyError(missing[0])
            self._load(state)
        except KeyError as err:
            raise DataError(f"estimator state: missing key {err.args[0]!r}") from None
        except ConfigError:
            raise
        except (TypeError, ValueError, IndexError) as err:    # arrays of the wrong shape or type
            reason = str(err).splitlines()[0] if str(err) else type(err).__name__
            raise DataError(f"estimator state: inconsistent ({reason})") from None
        return self

    def _load(self, st: dict) -> None:
        self._t0 = float(st["t0"])
        last_k = int(st["last_k"])
        self._last_k = None if last_k == _NONE else last_k
        self._trigger_mode = bool(st["trigger_mode"])
        self._epoch, self._epoch_offset = int(st["epoch"]), float(st["epoch_offset"])
        ev = np.asarray(st["events"], np.int64)
        self._events = [(int(k), bool(on), int(src)) for k, on, src in ev[: int(st["n_events"])]]
        self._events_dropped = int(st["events_dropped"])
        self._desired, self._desired_src = bool(st["desired"]), int(st["desired_src"])
        self._sweep_k0, self._sweep_src = int(st["sweep_k0"]), int(st["sweep_src"])
        self._buf[:] = st["buf"]
        self._buf_n = [int(n) for n in st["buf_n"]]
        self._dl[:] = st["dl"]
        self._dl_n, self._dl_k0 = int(st["dl_n"]), int(st["dl_k0"])
        self._raw[:] = st["raw"]
        self._raw_n[:] = st["raw_n"]
        self._raw_span[:] = st["raw_span"]
        self._n_sweeps = int(st["n_sweeps"])
        self._tot[:] = st["tot"]
        self._tot_n[:] = st["tot_n"]
        self._span = [int(v) for v in st["span"]]
        parts = {"in": self._streams[0], "out": self._streams[1], "align": self._align, "xf": self._xf,
                 "det": self._det, "trig": self._trig, "tbase": self._trig_base, "man": self._man}
        for prefix, part in parts.items():
            n = len(prefix) + 1
            part.load_state({k[n:]: v for k, v in st.items() if k.startswith(prefix + ".")})
