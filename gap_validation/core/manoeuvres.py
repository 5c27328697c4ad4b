"""Short manoeuvres (doublets) kept from the flight for the time-domain check (paper Fig. 6, eqs. 1 and 3).

The sweep detector (:mod:`gap_validation.core.sweeps`) also finds short excitations that are not sweeps:
doublets, pulses and trim steps. The estimator hands each one to a :class:`ManoeuvreRecorder`, which keeps
the aligned input and output around it (``pre_s`` before, ``post_s`` after, from a short ring of the grid
samples the estimator releases) and classifies it:

* it must **return to trim**: the input's mean over the last second differs from its trim (mean over the
  ``pre_s`` before) by less than a quarter of the peak excursion; a trim step does not;
* ``doublet`` when the input goes both ways (each sign at least 30 % of the peak), else ``pulse``.

The ``max_kept`` largest (by input RMS about trim) are kept, in fixed-size arrays: the state stays constant
in size however long the flight, and is part of the estimator checkpoint.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Manoeuvre", "ManoeuvreRecorder"]

_KINDS = ("pulse", "doublet")
_PENDING_CAP = 4


@dataclass(frozen=True)
class Manoeuvre:
    """Aligned input and output of one short manoeuvre, on the estimator grid (SI units, trim included).

    Attributes
    ----------
    kind : str
        ``doublet`` or ``pulse``.
    t_s : ndarray
        Sample times [s] (uniform).
    u, y : ndarray
        Input (surface, rad) and output (rate, rad/s) samples.
    start_s, end_s : float
        The excited stretch found by the detector [s].
    trim_samples : int
        Leading samples before the excitation (used as the trim).
    """

    kind: str
    t_s: np.ndarray
    u: np.ndarray
    y: np.ndarray
    start_s: float
    end_s: float
    trim_samples: int

    def deviations(self) -> tuple[np.ndarray, np.ndarray]:
        """Input and output about their trim (means over the leading ``trim_samples``)."""
        n = max(1, self.trim_samples)
        return self.u - np.mean(self.u[:n]), self.y - np.mean(self.y[:n])


class ManoeuvreRecorder:
    """Keeps the largest short manoeuvres of one channel (see the module docstring).

    Parameters
    ----------
    sample_rate_hz : float
        Grid rate of the samples fed.
    max_excitation_s : float
        Longest excited stretch reported (the estimator's ``min_sweep_s``: longer ones are sweeps).
    pre_s, post_s : float
        Kept before and after the excited stretch [s].
    max_kept : int
        Manoeuvres kept (largest input RMS first).
    """

    def __init__(self, sample_rate_hz: float, max_excitation_s: float, pre_s: float = 1.0, post_s: float = 3.0,
                 max_kept: int = 3) -> None:
        self.pre_n = int(round(pre_s * sample_rate_hz))
        self.post_n = int(round(post_s * sample_rate_hz))
        self.cap = self.pre_n + int(round((max_excitation_s + 1.0) * sample_rate_hz)) + self.post_n
        self.one_s = int(round(sample_rate_hz))
        self.max_kept = int(max_kept)
        self._ring_k = 0                                 # grid index of ring[0]
        self._ring = np.zeros((2, 0))
        self._pending: list[list[int]] = []              # [k_from, k_run0, k_run1, k_to]
        self._kept = np.zeros((self.max_kept, 2, self.cap))
        self._meta = np.zeros((self.max_kept, 6), np.int64)   # k_from, n, k_run0, k_run1, kind, used
        self._score = np.zeros(self.max_kept)

    # ------------------------------------------------------------------ data in
    def record(self, k_a: int, x: np.ndarray, y: np.ndarray) -> None:
        """Contiguous released grid samples from index ``k_a`` (in time order).

        Parameters
        ----------
        k_a : int
            Grid index of the first sample.
        x, y : ndarray
            Input and output grid samples.
        """
        if x.size == 0:
            return
        if self._ring.shape[1] and k_a != self._ring_k + self._ring.shape[1]:
            self.end_run()                               # a break in the data: nothing spans it
        if self._ring.shape[1] == 0:
            self._ring_k = k_a
        for lo in range(0, x.size, self.cap):            # pieces: pending captures complete in between
            hi = min(x.size, lo + self.cap)
            ring = np.concatenate((self._ring, np.vstack((x[lo:hi], y[lo:hi]))), axis=1)
            drop = max(0, ring.shape[1] - 2 * self.cap)
            self._ring, self._ring_k = ring[:, drop:], self._ring_k + drop
            self._complete(final=False)

    def excitation(self, k_run0: int, k_run1: int) -> None:
        """The detector found a short excited stretch ``[k_run0, k_run1)`` (not a sweep).

        Parameters
        ----------
        k_run0, k_run1 : int
            Grid indices of the start and end (exclusive) of the excitation.
        """
        if k_run1 - k_run0 + self.pre_n + self.post_n > self.cap or len(self._pending) >= _PENDING_CAP:
            return
        self._pending.append([k_run0 - self.pre_n, k_run0, k_run1, k_run1 + self.post_n])
        self._complete(final=False)

    def cut(self, k: int) -> None:
        """A sweep starts at ``k``: pending manoeuvres end there at the latest.

        Parameters
        ----------
        k : int
            Grid index where the sweep starts.
        """
        for p in self._pending:
            p[3] = min(p[3], max(k, p[2]))
        self._complete(final=False)

    def end_run(self) -> None:
        """The data break (gap, end of flight): complete what is pending with what there is."""
        self._complete(final=True)
        self._ring = np.zeros((2, 0))

    # ------------------------------------------------------------------ results
    @property
    def key(self) -> bytes:
        """Changes exactly when the kept manoeuvres change (for caching what is computed from them)."""
        return self._meta.tobytes()

    def manoeuvres(self, t0_s: float, dt_s: float) -> list[Manoeuvre]:
        """Kept manoeuvres, in time order, with times ``t0_s + k dt_s``.

        Parameters
        ----------
        t0_s : float
            Time of grid index 0 [s].
        dt_s : float
            Grid step [s].
        """
        out = []
        for i in np.argsort(self._meta[:, 0]):
            k_from, n, k_run0, k_run1, kind, used = (int(v) for v in self._meta[i])
            if not used:
                continue
            t = t0_s + (k_from + np.arange(n)) * dt_s
            out.append(Manoeuvre(_KINDS[kind], t, self._kept[i, 0, :n].copy(), self._kept[i, 1, :n].copy(),
                                 t0_s + k_run0 * dt_s, t0_s + k_run1 * dt_s, k_run0 - k_from))
        return out

    # ------------------------------------------------------------------ internals
    def _complete(self, final: bool) -> None:
        ring_end = self._ring_k + self._ring.shape[1]
        keep = []
        for p in self._pending:
            if ring_end >= p[3] or final:
                self._capture(*p)
            else:
                keep.append(p)
        self._pending = keep

    def _capture(self, k_from: int, k_run0: int, k_run1: int, k_to: int) -> None:
        lo, hi = max(k_from, self._ring_k), min(k_to, self._ring_k + self._ring.shape[1])
        if lo > k_run0 - self.one_s // 2 or hi < k_run1 + self.one_s:
            return                                       # no trim before it, or not enough after
        seg = self._ring[:, lo - self._ring_k: hi - self._ring_k]
        trim_n = k_run0 - lo
        du = seg[0] - np.mean(seg[0, :trim_n])
        run = du[trim_n: k_run1 - lo]
        peak = float(np.max(np.abs(run))) if run.size else 0.0
        if not peak > 0 or abs(float(np.mean(du[-self.one_s:]))) > 0.25 * peak:
            return                                       # no excitation, or a trim change
        kind = 1 if run.max() > 0.3 * peak and run.min() < -0.3 * peak else 0
        score = float(np.sqrt(np.mean(run * run)))
        free = np.flatnonzero(self._meta[:, 5] == 0)
        slot = int(free[0]) if free.size else int(np.argmin(self._score))
        if not free.size and self._score[slot] >= score:
            return
        n = seg.shape[1]
        self._kept[slot, :, :n] = seg
        self._meta[slot] = (lo, n, k_run0, k_run1, kind, 1)
        self._score[slot] = score

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict:
        """The recorder's state: numpy arrays and numbers of a size independent of flight length."""
        ring = np.zeros((2, 2 * self.cap))
        ring[:, : self._ring.shape[1]] = self._ring
        pending = np.zeros((_PENDING_CAP, 4), np.int64)
        for i, p in enumerate(self._pending):
            pending[i] = p
        return {"ring_k": self._ring_k, "ring_n": self._ring.shape[1], "ring": ring, "pending": pending,
                "n_pending": len(self._pending), "kept": self._kept.copy(), "meta": self._meta.copy(),
                "score": self._score.copy()}

    def load_state(self, st: dict) -> None:
        """Continue from :meth:`state_dict`.

        Parameters
        ----------
        st : dict
            From :meth:`state_dict`.
        """
        self._ring_k = int(st["ring_k"])
        self._ring = np.asarray(st["ring"], float)[:, : int(st["ring_n"])].copy()
        self._pending = [[int(v) for v in row] for row in np.asarray(st["pending"])[: int(st["n_pending"])]]
        self._kept[:] = st["kept"]
        self._meta[:] = st["meta"]
        self._score[:] = st["score"]
