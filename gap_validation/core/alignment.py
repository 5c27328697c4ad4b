"""Time alignment of the frequency-response estimator: each stream's timestamps onto one uniform grid.

Moved out of :mod:`gap_validation.core.estimator` (which describes the data path, step 1 "Alignment"):

* :class:`TimeBase` takes in one stream's timestamps: drops non-finite and absurd samples, drops steps back in
  time (reorders, duplicates) and stray stamps, and starts a new time base when time jumps back by more than
  ``max(JUMP_BACK_S, max_gap_s)`` and :data:`JUMP_CONFIRM` increasing samples confirm it (a looped bag).
* :class:`StreamResampler` interpolates one stream onto the grid ``k * dt`` (cubic Hermite, Catmull-Rom on
  uniform samples), keeping only three trailing samples; no interpolation across a gap of more than
  ``max_gap_s``.
* :class:`GridAligner` pairs the grid values of several streams (inputs, outputs, excitation) by grid index in
  bounded queues.

The time-order check itself (:func:`ordered_run`, :func:`increasing`, :func:`jump_back_s`) is shared with
:class:`gap_validation.messages.router.MessageRouter`, which drops reordered samples before batching them.
numpy only.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

__all__ = ["JUMP_BACK_S", "JUMP_CONFIRM", "jump_back_s", "ordered_run", "increasing", "NO_INDEX", "TimeBase",
           "StreamResampler", "GridAligner"]

NO_INDEX = -(2 ** 62)               # "no grid index yet"
#: A timestamp more than this [s] (or ``max_gap_s``, if larger) before the stream's latest starts a new time
#: base instead of being dropped (a looped bag); smaller steps back are reorders or duplicates.
JUMP_BACK_S = 1.0
#: Consecutive increasing samples after a jump back that confirm it (fewer: stray stamps, dropped).
JUMP_CONFIRM = 3
# beyond 3000 years from the epoch: a corrupt stamp (also keeps grid indices in int64)
_MAX_ABS_TIME_S = 1e11
_MAX_ABS_VALUE = 1e100           # a corrupt value (squares and slopes of larger ones overflow float64)


def jump_back_s(max_gap_s: float) -> float:
    """How far [s] time must step back to start a new time base rather than be a reordered or duplicate
    sample: ``max(JUMP_BACK_S, max_gap_s)`` (the estimator's threshold, which the message router applies too).

    Parameters
    ----------
    max_gap_s : float
        The channel's ``max_gap_s`` estimator option [s].
    """
    return max(JUMP_BACK_S, float(max_gap_s))


def ordered_run(t: np.ndarray, last_t: float, back_s: float,
                forward_s: float = math.inf) -> tuple[int, np.ndarray, np.ndarray]:
    """The time-order check, the one implementation the router and the estimator share.

    Parameters
    ----------
    t : ndarray
        Sample times [s] of a batch (finite).
    last_t : float
        Latest time accepted before the batch [s] (``-inf`` before any).
    back_s : float
        A sample more than this [s] before every earlier one is a jump back (:func:`jump_back_s`).
    forward_s : float
        A sample more than this [s] after every earlier one is a jump forward (``inf``: never).

    Returns
    -------
    j : int
        Index of the first jump (``t.size`` when there is none).
    ok : ndarray of bool
        For ``t[:j]``: the samples later than every earlier one; the others are out of order or duplicates.
    prev : ndarray
        Running maximum of the times before each sample (``last_t`` included).
    """
    prev = np.maximum.accumulate(np.concatenate(([last_t], t[:-1])))
    with np.errstate(invalid="ignore"):
        jump = np.flatnonzero((t < prev - back_s) | ((t > prev + forward_s) & (prev > -np.inf)))
    j = int(jump[0]) if jump.size else t.size
    return j, t[:j] > prev[:j], prev


def increasing(t: np.ndarray, last_t: float, back_s: float) -> tuple[np.ndarray, int]:
    """Mask of samples after every earlier one, where a step back of more than ``back_s`` [s] restarts the
    comparison (the estimator opens a new time base there); also the number of such jumps.

    Parameters
    ----------
    t : ndarray
        Sample times [s] (finite).
    last_t : float
        Latest time accepted before ``t`` [s] (``-inf`` before any).
    back_s : float
        Threshold of a jump back [s] (:func:`jump_back_s`).

    Returns
    -------
    keep : ndarray of bool
        Samples in time order; the first sample after each jump is kept (the estimator confirms the jump).
    jumps : int
        Jumps back found.
    """
    keep = np.zeros(t.size, bool)
    start, jumps = 0, 0
    while start < t.size:
        stop, ok, _ = ordered_run(t[start:], last_t, back_s)
        keep[start:start + stop] = ok
        if start + stop == t.size:
            break
        jumps += 1
        keep[start + stop] = True
        last_t = float(t[start + stop])
        start += stop + 1
    return keep, jumps


class TimeBase:
    """Intake of one stream's timestamps: drops bad samples, detects time jumping back, applies the shift.

    Times are kept raw (``last_t``: the latest accepted raw time of the current base); accepted samples are
    returned as ``raw + offset``. ``epoch`` counts the time bases this stream has entered; samples after a
    jump back wait in ``pend`` (at most :data:`JUMP_CONFIRM` - 1) until the jump is confirmed or refuted.
    """

    KEYS = ("last_t", "accepted", "nonfinite", "non_monotonic", "epoch", "offset", "pend", "pend_n", "jumps")

    def __init__(self) -> None:
        self.last_t = -np.inf
        self.accepted = self.nonfinite = self.non_monotonic = self.jumps = 0
        self.epoch = 0
        self.offset = 0.0
        self.pend = np.zeros((2, JUMP_CONFIRM))
        self.pend_n = 0

    @property
    def latest_s(self) -> float:
        """Latest accepted time on the shifted (continuous) time axis [s], -inf before any."""
        return self.last_t + self.offset

    def intake(self, t: np.ndarray, v: np.ndarray, tol_s: float, new_base: Callable[[TimeBase, float], None],
               forward_s: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
        """Accepted samples of a batch on the shifted axis.

        A step back of more than ``tol_s`` [s] that :data:`JUMP_CONFIRM` increasing samples confirm is a new
        time base (``new_base(self, t_raw)`` sets ``epoch``/``offset``); a step forward of more than
        ``forward_s`` [s] (a gap) needs the same confirmation, so one stray stamp far in the future does not
        hide the samples after it. Unconfirmed jumps are dropped as ``non_monotonic``.

        Parameters
        ----------
        t, v : ndarray
            Raw times [s] and values of the batch.
        tol_s : float
            A step back of at most this [s] is a reorder or duplicate, not a new time base.
        new_base : callable
            ``new_base(self, t_raw)``: called on a confirmed jump back; sets ``epoch`` and ``offset``.
        forward_s : float
            A step forward of more than this [s] needs confirmation.
        """
        finite = (np.abs(t) < _MAX_ABS_TIME_S) & (np.abs(v) < _MAX_ABS_VALUE)    # False for NaN too
        n_bad = int(t.size - np.count_nonzero(finite))
        if n_bad:
            self.nonfinite += n_bad
            t, v = t[finite], v[finite]
        if self.pend_n:
            t = np.concatenate((self.pend[0, : self.pend_n], t))
            v = np.concatenate((self.pend[1, : self.pend_n], v))
            self.pend_n = 0
        if t.size and self.last_t < t[0] and (t[0] <= self.last_t + forward_s or self.last_t == -np.inf) \
                and np.all(t[1:] > t[:-1]) \
                and (forward_s == math.inf or np.all(t[1:] - t[:-1] <= forward_s)):   # the usual case
            self.last_t = float(t[-1])
            self.accepted += t.size
            return t + self.offset, v
        out_t, out_v = [], []
        while t.size:
            j, ok, prev = ordered_run(t, self.last_t, tol_s, forward_s)
            self.non_monotonic += int(j - np.count_nonzero(ok))
            if np.any(ok):
                out_t.append(t[:j][ok] + self.offset)
                out_v.append(v[:j][ok])
                self.accepted += int(np.count_nonzero(ok))
                self.last_t = float(t[:j][ok][-1])
            if j == t.size:
                break
            back = t[j] < prev[j]
            n = self._confirmed(t[j:], -math.inf if back else prev[j] + forward_s,
                                prev[j] - tol_s if back else math.inf)
            if n == JUMP_CONFIRM and back:              # a new time base from sample j on
                self.jumps += 1
                new_base(self, float(t[j]))
                self.last_t = -np.inf
                t, v = t[j:], v[j:]
            elif n == JUMP_CONFIRM:                     # a real gap: accept the sample after it
                out_t.append(t[j:j + 1] + self.offset)
                out_v.append(v[j:j + 1])
                self.accepted += 1
                self.last_t = float(t[j])
                t, v = t[j + 1:], v[j + 1:]
            elif n == t.size - j:                       # undecided at the end of the batch: wait
                self.pend[0, :n], self.pend[1, :n] = t[j:], v[j:]
                self.pend_n = n
                break
            else:                                       # stray stamps: the next sample went back
                n = max(n, 1)
                self.non_monotonic += n
                t, v = t[j + n:], v[j + n:]
        if not out_t:
            return np.empty(0), np.empty(0)
        return np.concatenate(out_t), np.concatenate(out_v)

    @staticmethod
    def _confirmed(t: np.ndarray, above: float, below: float) -> int:
        """How many leading samples of ``t`` (at most JUMP_CONFIRM) increase and stay in (above, below)."""
        c = t[:JUMP_CONFIRM]
        good = (c > above) & (c < below) & np.concatenate(([True], c[1:] > c[:-1]))
        return int(np.argmin(good)) if not good.all() else int(c.size)

    def drop_pending(self) -> None:
        """End of data: samples still waiting for a confirmation are dropped (counted)."""
        self.non_monotonic += self.pend_n
        self.pend_n = 0

    def state_dict(self) -> dict:
        """The counters, the base and the pending samples (checkpoints)."""
        return {"last_t": self.last_t, "accepted": self.accepted, "nonfinite": self.nonfinite,
                "non_monotonic": self.non_monotonic, "epoch": self.epoch, "offset": self.offset,
                "pend": self.pend.copy(), "pend_n": self.pend_n, "jumps": self.jumps}

    def load_state(self, st: dict) -> None:
        """Inverse of :meth:`state_dict`.

        Parameters
        ----------
        st : dict
            A :meth:`state_dict` (checkpoints of older versions lack some keys).
        """
        self.last_t, self.offset = float(st["last_t"]), float(st.get("offset", 0.0))
        self.accepted, self.nonfinite = int(st["accepted"]), int(st["nonfinite"])
        self.non_monotonic, self.jumps = int(st["non_monotonic"]), int(st.get("jumps", 0))
        self.epoch, self.pend_n = int(st.get("epoch", 0)), int(st.get("pend_n", 0))
        self.pend[:] = st.get("pend", 0.0)


class StreamResampler:
    """One stream onto the grid ``k * dt`` (times relative to ``t0``), keeping only three trailing samples.

    Every grid instant is either emitted (interpolated) or skipped (it lies in a gap); all instants below
    ``k_next`` are decided.

    Parameters
    ----------
    dt : float
        Grid step [s].
    max_gap_s : float
        Samples further apart than this [s] leave the grid instants between them undecided (skipped).
    cubic : bool
        Cubic Hermite interpolation (slopes from the neighbouring samples); else linear.
    """

    def __init__(self, dt: float, max_gap_s: float, cubic: bool) -> None:
        self.dt, self.max_gap, self.cubic = dt, max_gap_s, cubic
        self.ht = np.zeros(3)
        self.hv = np.zeros(3)
        self.hn = 0
        self.k_next = NO_INDEX
        self.base = TimeBase()

    def add(self, t_rel: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The grid indices and values decided by a batch of samples.

        Parameters
        ----------
        t_rel : ndarray
            Times [s] relative to the grid's origin, increasing.
        v : ndarray
            Values.
        """
        T = np.concatenate((self.ht[: self.hn], t_rel))
        V = np.concatenate((self.hv[: self.hn], v))
        out = self._emit(T, V)
        self.hn = min(3, T.size)
        self.ht[: self.hn] = T[T.size - self.hn:]
        self.hv[: self.hn] = V[V.size - self.hn:]
        return out

    def flush(self) -> tuple[np.ndarray, np.ndarray]:
        """End of data: emit up to the last sample (one-sided slope there), then forget the history."""
        if self.hn < 2:
            self.hn = 0
            return np.empty(0, np.int64), np.empty(0)
        t_last, v_last = self.ht[self.hn - 1], self.hv[self.hn - 1]
        T = np.concatenate((self.ht[: self.hn], [t_last + 2.0 * self.max_gap + 1.0]))
        V = np.concatenate((self.hv[: self.hn], [0.0]))
        k, val = self._emit(T, V)
        k_last = int(round(t_last / self.dt))
        if k_last >= self.k_next and abs(k_last * self.dt - t_last) <= 1e-9 * self.dt:
            k, val = np.append(k, k_last), np.append(val, v_last)     # the last sample is on the grid
            self.k_next = k_last + 1
        self.hn = 0
        return k, val

    def _emit(self, T: np.ndarray, V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = T.size
        empty = (np.empty(0, np.int64), np.empty(0))
        if n < 3:
            return empty
        dt = self.dt
        m = n - 2                                   # intervals 0..m-1 have a known right neighbour
        h = np.diff(T)
        gap = h > self.max_gap
        k_ceil = np.ceil(T[: m + 1] * (1.0 / dt)).astype(np.int64)
        k_lo = np.maximum(k_ceil[:m], self.k_next)
        cnt = np.maximum(k_ceil[1:] - k_lo, 0)
        cnt[gap[:m]] = 0
        self.k_next = max(self.k_next, int(k_ceil[m]))
        if cnt.size == 0 or cnt.max() <= 1:         # at most one grid instant per interval (fast streams)
            iv = np.flatnonzero(cnt)
            k = k_lo[iv]
        else:
            total = int(cnt.sum())
            iv = np.repeat(np.arange(m), cnt)
            k = np.repeat(k_lo, cnt) + (np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt))
        if k.size == 0:
            return empty
        hi = h[iv]
        s = (k * dt - T[iv]) / hi
        v0, v1 = V[iv], V[iv + 1]
        if not self.cubic:
            return k, v0 + s * (v1 - v0)
        if 4 * k.size >= m:                          # slopes at every node, or only where needed
            slope = self._slopes(V, h, gap, np.arange(m + 1))
            m0, m1 = slope[iv], slope[iv + 1]
        else:
            m0, m1 = self._slopes(V, h, gap, iv), self._slopes(V, h, gap, iv + 1)
        s2 = s * s
        s3 = s2 * s
        val = ((2 * s3 - 3 * s2 + 1) * v0 + (s3 - 2 * s2 + s) * (m0 * hi) + (3 * s2 - 2 * s3) * v1
               + (s3 - s2) * (m1 * hi))
        return k, val

    @staticmethod
    def _slopes(V: np.ndarray, h: np.ndarray, gap: np.ndarray, nodes: np.ndarray) -> np.ndarray:
        """Slope at each node: derivative of the parabola through it and its neighbours (one-sided at
        gaps)."""
        left_node = np.maximum(nodes - 1, 0)
        hl, hr = h[left_node], h[nodes]
        dl = (V[nodes] - V[left_node]) / hl
        dr = (V[nodes + 1] - V[nodes]) / hr
        left = (nodes >= 1) & ~gap[left_node]
        right = ~gap[nodes]
        return np.where(left & right, (hr * dl + hl * dr) / (hl + hr), np.where(right, dr, dl))

    def state_dict(self) -> dict:
        """The trailing samples, the next grid index and the time base (checkpoints)."""
        return {"ht": self.ht.copy(), "hv": self.hv.copy(), "hn": self.hn, "k_next": self.k_next,
                **self.base.state_dict()}

    def load_state(self, st: dict) -> None:
        """Inverse of :meth:`state_dict`.

        Parameters
        ----------
        st : dict
            A :meth:`state_dict`.
        """
        self.ht[:] = st["ht"]
        self.hv[:] = st["hv"]
        self.hn, self.k_next = int(st["hn"]), int(st["k_next"])
        self.base.load_state(st)


class GridAligner:
    """Pairs the grid values of several streams by grid index; bounded queues of ``cap`` values each.

    Parameters
    ----------
    n_streams : int
        Number of streams.
    cap : int
        Most values queued per stream; older ones are dropped (counted in ``dropped``).
    """

    def __init__(self, n_streams: int, cap: int) -> None:
        self.n, self.cap = n_streams, cap
        self.k = [np.empty(0, np.int64) for _ in range(n_streams)]
        self.v = [np.empty(0) for _ in range(n_streams)]
        self.cursor = NO_INDEX               # every grid index below this has been combined or given up
        self.dropped = [0] * n_streams

    def push(self, s: int, k: np.ndarray, v: np.ndarray) -> None:
        """Queue stream ``s``'s grid values (indices ``k``).

        Parameters
        ----------
        s : int
            The stream.
        k : ndarray of int
            Grid indices, increasing.
        v : ndarray
            Values there.
        """
        if k.size == 0:
            return
        late = k < self.cursor
        if late.any():
            self.dropped[s] += int(np.count_nonzero(late))
            k, v = k[~late], v[~late]
        self.k[s] = np.concatenate((self.k[s], k))
        self.v[s] = np.concatenate((self.v[s], v))

    def combine(self, finals: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """Grid indices below ``min(finals)`` that every stream has, and the values there (streams x n).

        Parameters
        ----------
        finals : list of int
            Per stream, the grid index below which it has decided every instant.
        """
        m = min(finals)
        idx, vals = np.empty(0, np.int64), np.empty((self.n, 0))
        if m > self.cursor:
            cut = [int(np.searchsorted(k, m)) for k in self.k]
            ks = [k[:c] for k, c in zip(self.k, cut)]
            vs = [v[:c] for v, c in zip(self.v, cut)]
            if all(k.size for k in ks):
                if all(k[-1] - k[0] == k.size - 1 for k in ks):          # contiguous: slices
                    lo, hi = max(int(k[0]) for k in ks), min(int(k[-1]) for k in ks)
                    if lo <= hi:
                        idx = np.arange(lo, hi + 1, dtype=np.int64)
                        vals = np.stack([v[lo - k[0]: hi - k[0] + 1] for k, v in zip(ks, vs)])
                else:
                    idx = ks[0]
                    for k in ks[1:]:
                        idx = np.intersect1d(idx, k, assume_unique=True)
                    vals = np.stack([v[np.searchsorted(k, idx)] for k, v in zip(ks, vs)]) if idx.size \
                        else vals
            self.k = [k[c:] for k, c in zip(self.k, cut)]
            self.v = [v[c:] for v, c in zip(self.v, cut)]
            self.cursor = m
        for s in range(self.n):
            extra = self.k[s].size - self.cap
            if extra > 0:
                self.dropped[s] += extra
                self.k[s], self.v[s] = self.k[s][extra:], self.v[s][extra:]
                self.cursor = max(self.cursor, int(self.k[s][0]))
        return idx, vals

    def clear(self) -> None:
        """Forget the queued values (end of data)."""
        self.k = [k[:0] for k in self.k]
        self.v = [v[:0] for v in self.v]

    def state_dict(self) -> dict:
        """Fixed-size state (checkpoints)."""
        st = {"cursor": self.cursor, "dropped": np.array(self.dropped, np.int64)}
        k = np.zeros((self.n, self.cap), np.int64)
        v = np.zeros((self.n, self.cap))
        for s in range(self.n):
            k[s, : self.k[s].size] = self.k[s]
            v[s, : self.v[s].size] = self.v[s]
        st.update({"k": k, "v": v, "sizes": np.array([q.size for q in self.k], np.int64)})
        return st

    def load_state(self, st: dict) -> None:
        """Inverse of :meth:`state_dict`.

        Parameters
        ----------
        st : dict
            A :meth:`state_dict`.
        """
        self.cursor = int(st["cursor"])
        self.dropped = [int(d) for d in st["dropped"]]
        sizes = np.asarray(st["sizes"], np.int64)
        self.k = [np.asarray(st["k"][s, : sizes[s]], np.int64).copy() for s in range(self.n)]
        self.v = [np.asarray(st["v"][s, : sizes[s]], float).copy() for s in range(self.n)]
