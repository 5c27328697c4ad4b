"""Short manoeuvres (doublets) kept from the flight for the time-domain check (paper Fig. 6, eqs. 1 and 3).

The estimator splits the flight into manoeuvres (:mod:`gap_validation.core.records`) and offers the short ones
(doublets, pulses and multisteps such as a 3-2-1-1, at most 20 s of excitation) to a
:class:`ManoeuvreRecorder` with the aligned input and output around them (the trim before, the response
after). It keeps one when it
**returns to trim** (the input's mean over the last second differs from its trim, the mean before the
excitation, by less than a quarter of the peak excursion) and there is at least half a second of trim before
it and a second after.

The ``max_kept`` largest (by input RMS about trim) are kept, in fixed-size arrays: the state stays constant in
size however long the flight, and is part of the estimator checkpoint.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Manoeuvre", "ManoeuvreRecorder"]

_KINDS = ("pulse", "doublet", "multistep")


@dataclass(frozen=True)
class Manoeuvre:
    """Aligned input and output of one short manoeuvre, on the estimator grid (SI units, trim included).

    Attributes
    ----------
    kind : str
        ``doublet``, ``pulse`` or ``multistep``.
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
        Grid rate of the samples offered.
    max_s : float
        Longest record kept (trim and response included) [s].
    max_kept : int
        Manoeuvres kept (largest input RMS first).
    """

    def __init__(self, sample_rate_hz: float, max_s: float = 30.0, max_kept: int = 3) -> None:
        self.cap = int(round(max_s * sample_rate_hz))
        self.one_s = int(round(sample_rate_hz))
        self.max_kept = int(max_kept)
        self._kept = np.zeros((self.max_kept, 2, self.cap))
        self._meta = np.zeros((self.max_kept, 6), np.int64)   # k_from, n, k_run0, k_run1, kind, used
        self._score = np.zeros(self.max_kept)

    # ------------------------------------------------------------------ data in
    def offer(self, k_from: int, u: np.ndarray, y: np.ndarray, k_run0: int, k_run1: int, kind: str) -> bool:
        """Offer a short manoeuvre; returns whether it is kept (see the module docstring).

        Parameters
        ----------
        k_from : int
            Grid index of the first sample.
        u, y : ndarray
            Input and output grid samples (trim before, response after).
        k_run0, k_run1 : int
            Grid indices of the start and end (exclusive) of the excitation.
        kind : str
            ``doublet``, ``pulse`` or ``multistep``.
        """
        u, y = np.asarray(u, float), np.asarray(y, float)
        n = min(u.size, self.cap)
        trim_n = k_run0 - k_from
        if kind not in _KINDS or trim_n < self.one_s // 2 or k_from + n < k_run1 + self.one_s:
            return False                                  # no trim before it, or not enough after
        du = u[:n] - np.mean(u[:trim_n])
        run = du[trim_n: k_run1 - k_from]
        peak = float(np.max(np.abs(run))) if run.size else 0.0
        if not peak > 0 or abs(float(np.mean(du[n - self.one_s: n]))) > 0.25 * peak:
            return False                                  # no excitation, or a trim change
        score = float(np.sqrt(np.mean(run * run)))
        free = np.flatnonzero(self._meta[:, 5] == 0)
        slot = int(free[0]) if free.size else int(np.argmin(self._score))
        if not free.size and self._score[slot] >= score:
            return False
        self._kept[slot, 0, :n], self._kept[slot, 1, :n] = u[:n], y[:n]
        self._meta[slot] = (k_from, n, k_run0, k_run1, _KINDS.index(kind), 1)
        self._score[slot] = score
        return True

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

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict:
        """The recorder's state: numpy arrays of a size independent of flight length."""
        return {"kept": self._kept.copy(), "meta": self._meta.copy(), "score": self._score.copy()}

    def load_state(self, st: dict) -> None:
        """Continue from :meth:`state_dict`.

        Parameters
        ----------
        st : dict
            From :meth:`state_dict`.
        """
        self._kept[:] = st["kept"]
        self._meta[:] = st["meta"]
        self._score[:] = st["score"]
