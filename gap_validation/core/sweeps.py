"""Sweep detection: which stretches of a flight are frequency sweeps (paper Fig. 4: one light curve each).

The paper estimates one frequency response per sinusoidal sweep experiment and averages them. In a recorded or
live flight nobody marks the sweeps, so they are found in the control-surface (input) signal:

* **Excitation energy** ``e[n]``: the standard deviation of the input over the trailing ``energy_window_s``
  (default 2 s) *after removing a least-squares straight line*. Removing the line makes a trim offset, a slow
  trim ramp and the slow part of a sweep invisible, so only oscillation counts; a step (trim change) shows up
  for about one window only.
* **Quiet level** ``q``: the 10th percentile (:data:`QUIET_QUANTILE`) of the one-second means of ``e`` over
  the last ``quiet_window_s`` (default 300 s) of trim: blocks whose mean stays below the on-threshold (blocks
  loud for ``quiet_window_s`` become the new trim). It adapts to units and sensor noise, so thresholds are
  ratios; a low quantile rather than the minimum, because trim motion is random and its quietest second is
  several times below its ordinary ones; quiet blocks only, because a manoeuvre that fills most of the first
  minutes would otherwise raise the level above itself.
* **Hysteresis**: a sweep starts when ``e > on_ratio * q`` (default 4) and ends when ``e < off_ratio * q``
  (default 2) has held for ``hold_s`` (default 2 s); short dips (zero crossings of the slow start of a sweep)
  do not end it. ``min_excitation`` (input units, default 1e-6) is an absolute floor for noise-free inputs.
* **Timing**: the start is dated half a window before the first loud window (the excitation begins inside
  it), the end at the first quiet window. Both are known at most ``lookahead_samples`` after the fact, which
  is why the estimator delays its transform by that much (no data is stored beyond that delay).
* **Minimum length** (applied by the caller, see :func:`detect_sweeps` and the estimator's ``min_sweep_s``,
  default 10 s): a doublet (1-3 s) or a trim step gives an excited stretch of about its length plus 1.5
  energy windows (< 10 s) and is not a sweep.

An explicit trigger (a ``std_msgs/Bool`` topic, :class:`TriggerTracker`) overrides detection: the estimator
then takes sweeps exactly where the trigger is true.

Known limits: a flight that starts in the middle of a sweep has no quiet level yet, so that first sweep is
missed; a sweep longer than ``quiet_window_s`` raises the quiet level and is cut; sweeps below about
``1 / (energy_window_s)`` Hz are only detected where they are curved enough (use a longer window or the
trigger).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from gap_validation.core.errors import ConfigError, DataError
from gap_validation.core.numbers import POSITIVE, check_number

__all__ = ["SweepDetector", "TriggerTracker", "detect_sweeps", "DETECTOR_DEFAULTS"]

#: Defaults of the detector options (also estimator options of the same names).
DETECTOR_DEFAULTS = {
    "energy_window_s": 2.0,
    "hold_s": 2.0,
    "on_ratio": 4.0,
    "off_ratio": 2.0,
    "min_excitation": 1e-6,
    "quiet_window_s": 300.0,
}

#: The quiet level is this quantile of the one-second block energies of the last ``quiet_window_s``, not their
#: minimum: trim motion (a pilot's corrections, turbulence answered by the surfaces) is a random process whose
#: energy over a 2 s window fluctuates by a factor of several (a chi-square on few degrees of freedom), so its
#: own quietest second, taken as the floor, lets its ordinary seconds cross ``on_ratio`` times it (seen on the
#: second simulator: 20 "sweeps" of trim on a channel flown 3). A low quantile keeps the floor below any
#: manoeuvre as long as trim fills a tenth of the window.
QUIET_QUANTILE = 0.1
_QUIET_BLOCK_S = 1.0        # the quiet level is tracked on one-second means of the excitation energy
_CHUNK = 8192               # windowed sums are formed over at most this many samples (float64 precision)


def _positive(name: str, value: Any) -> float:
    """A detector option's number, > 0 (numeric strings accepted)."""
    return check_number(
        value, f"estimator option {name}", POSITIVE, strings=True, expected="a positive finite number"
    )


def detrended_std(x: np.ndarray, window_n: int) -> np.ndarray:
    """Standard deviation of ``x`` about a least-squares line, over every trailing window of ``window_n``.

    Parameters
    ----------
    x : ndarray
        Uniformly sampled signal.
    window_n : int
        Window length in samples (>= 3).

    Returns
    -------
    ndarray
        ``len(x) - window_n + 1`` values; value ``i`` is for the window ``x[i : i + window_n]``.
    """
    x = np.asarray(x, dtype=float)
    count = x.size - window_n + 1
    if count <= 0:
        return np.empty(0)
    out = np.empty(count)
    m1 = window_n * (window_n - 1) / 2.0
    m2 = (window_n - 1) * window_n * (2 * window_n - 1) / 6.0
    sxx_m = m2 - m1 * m1 / window_n
    for first in range(0, count, _CHUNK):
        last = min(count, first + _CHUNK)
        seg = x[first:last + window_n - 1]
        pos = np.arange(seg.size, dtype=float)
        # removing any straight line leaves the result unchanged; the chord keeps the sums small (precision)
        z = seg - (seg[0] + (seg[-1] - seg[0]) * pos / max(seg.size - 1, 1))
        c1 = np.concatenate(([0.0], np.cumsum(z)))
        c2 = np.concatenate(([0.0], np.cumsum(z * z)))
        ci = np.concatenate(([0.0], np.cumsum(pos * z)))
        s = c1[window_n:] - c1[:-window_n]
        q = c2[window_n:] - c2[:-window_n]
        start = np.arange(s.size, dtype=float)
        sm = ci[window_n:] - ci[:-window_n] - start * s            # sum of (local index) * z
        ss = q - s * s / window_n - (sm - m1 * s / window_n) ** 2 / sxx_m
        out[first:last] = np.sqrt(np.maximum(ss, 0.0) / window_n)
    return out


def _growing_detrended_std(x: np.ndarray, min_n: int) -> np.ndarray:
    """Standard deviation about a least-squares line of every prefix ``x[: i + 1]`` (NaN below ``min_n``
    samples): the excitation energy at the start of a run, before a whole window of data exists, so that a
    manoeuvre flown a second after the data begin (a short flight-test record) is found and dated.

    Parameters
    ----------
    x : ndarray
        The first samples of a run.
    min_n : int
        Shortest prefix given an energy.
    """
    x = np.asarray(x, dtype=float)
    out = np.full(x.size, np.nan)
    if x.size < min_n:
        return out
    z = x - x[0]
    pos = np.arange(x.size, dtype=float)
    n = pos + 1.0
    s = np.cumsum(z)
    q = np.cumsum(z * z)
    sm = np.cumsum(pos * z)
    m1 = n * (n - 1.0) / 2.0
    m2 = (n - 1.0) * n * (2.0 * n - 1.0) / 6.0
    with np.errstate(divide="ignore", invalid="ignore"):
        sxx_m = m2 - m1 * m1 / n
        ss = q - s * s / n - (sm - m1 * s / n) ** 2 / sxx_m
        e = np.sqrt(np.maximum(ss, 0.0) / n)
    out[min_n - 1:] = e[min_n - 1:]
    return out


def quiet_quantile(blocks: np.ndarray) -> np.ndarray:
    """The quiet level of each row of one-second block energies: their :data:`QUIET_QUANTILE` over the finite
    entries (inf where there are none).

    Parameters
    ----------
    blocks : ndarray, (rows, n)
        Block means of the excitation energy; inf for blocks not seen yet.
    """
    blocks = np.sort(np.asarray(blocks, dtype=float), axis=1)
    count = np.sum(np.isfinite(blocks), axis=1)
    index = np.floor(QUIET_QUANTILE * np.maximum(count - 1, 0)).astype(np.int64)
    level = blocks[np.arange(blocks.shape[0]), index]
    return np.where(count > 0, level, np.inf)


class SweepDetector:
    """Online detector of excited stretches of a uniformly sampled input (hysteresis on detrended energy).

    Feed contiguous chunks with :meth:`process`; it returns the sweep edges found, as ``(k, on)`` pairs with
    ``k`` the grid index where the sweep starts (``on=True``) or ends (``on=False``, exclusive). Call
    :meth:`end_run` at a data gap or the end of data. The state has a fixed size.

    Parameters
    ----------
    sample_rate_hz : float
        Rate of the uniform grid [Hz].
    energy_window_s, hold_s, on_ratio, off_ratio, min_excitation, quiet_window_s
        See the module docstring (defaults in :data:`DETECTOR_DEFAULTS`).
    """

    def __init__(self, sample_rate_hz: float, energy_window_s: float = 2.0, hold_s: float = 2.0,
                 on_ratio: float = 4.0, off_ratio: float = 2.0, min_excitation: float = 1e-6,
                 quiet_window_s: float = 300.0) -> None:
        fs = _positive("sample_rate_hz", sample_rate_hz)
        self.on_ratio = _positive("on_ratio", on_ratio)
        self.off_ratio = _positive("off_ratio", off_ratio)
        if self.off_ratio > self.on_ratio:
            raise ConfigError(
                f"estimator option off_ratio: {off_ratio!r} must not exceed on_ratio {on_ratio!r}"
            )
        self.min_excitation = _positive("min_excitation", min_excitation)
        self.window_n = max(3, int(round(_positive("energy_window_s", energy_window_s) * fs)))
        self.hold_n = max(1, int(round(_positive("hold_s", hold_s) * fs)))
        self.block_n = max(1, int(round(_QUIET_BLOCK_S * fs)))
        self.quiet_blocks = max(1, int(round(_positive("quiet_window_s", quiet_window_s) / _QUIET_BLOCK_S)))
        self._hist = np.zeros(self.window_n - 1)
        self._hist_n = 0
        self._blk_sum = 0.0            # sum / count of defined energies in the block in progress
        self._blk_def = 0
        self._blk_len = 0              # samples in the block in progress
        self._quiet = np.full(self.quiet_blocks, np.inf)   # one-second means at trim, oldest first
        self._quiet_n = 0
        self._loud_blocks = 0          # consecutive blocks above the on-threshold
        self._level = math.inf         # the quiet level in force (:func:`quiet_quantile` of the ring)
        self._active = False
        self._quiet_count = 0          # length of the quiet stretch in progress while active [samples]
        self._quiet_start_k = 0
        self._run_start_k = 0
        self._last_edge_k = -(2 ** 62)

    @property
    def lookahead_samples(self) -> int:
        """Every edge at grid index ``k`` is reported once samples up to ``k + lookahead_samples`` were
        fed."""
        return max(self.window_n // 2, self.hold_n) + 1

    @property
    def active(self) -> bool:
        """True while inside a detected excitation."""
        return self._active

    @property
    def quiet_level(self) -> float:
        """Current quiet level ``q`` (input units; inf before one second of data)."""
        return self._level

    # ------------------------------------------------------------------ processing
    def start_run(self, k0: int) -> None:
        """Begin a contiguous run of samples at grid index ``k0`` (after a gap or at the start).

        Parameters
        ----------
        k0 : int
            Grid index of the first sample of the run.
        """
        self._hist_n = 0
        self._blk_sum, self._blk_def, self._blk_len = 0.0, 0, 0
        self._active = False
        self._quiet_count = 0
        self._run_start_k = int(k0)

    def end_run(self, k_end: int) -> list[tuple[int, bool]]:
        """Data stops before grid index ``k_end``: an excitation in progress ends there.

        Parameters
        ----------
        k_end : int
            Grid index after the last sample of the run.
        """
        edges = []
        if self._active:
            edges.append((max(int(k_end), self._last_edge_k), False))
            self._last_edge_k = edges[-1][0]
        self._active = False
        self._quiet_count = 0
        self._hist_n = 0
        self._blk_sum, self._blk_def, self._blk_len = 0.0, 0, 0
        return edges

    def process(self, k0: int, x: np.ndarray) -> list[tuple[int, bool]]:
        """Feed contiguous input samples starting at grid index ``k0``; return the sweep edges found.

        Parameters
        ----------
        k0 : int
            Grid index of ``x[0]``; must continue the samples fed before (else call :meth:`start_run`).
        x : ndarray
            Input samples on the uniform grid.

        Returns
        -------
        list of (int, bool)
            ``(k, True)`` for a start, ``(k, False)`` for an end (exclusive), in time order.
        """
        x = np.asarray(x, dtype=float)
        n = x.size
        if n == 0:
            return []
        xx = np.concatenate((self._hist[: self._hist_n], x))
        energy = np.full(n, np.nan)
        e = detrended_std(xx, self.window_n)
        if e.size:
            energy[n - e.size:] = e
        if self._hist_n < self.window_n - 1:          # the run is younger than a window: growing windows
            young = _growing_detrended_std(xx[: self.window_n - 1], max(3, self.window_n // 4))
            first = self._hist_n                      # xx index of x[0]
            part = young[first:first + n]
            energy[: part.size] = np.where(np.isfinite(energy[: part.size]), energy[: part.size], part)
        keep = min(self.window_n - 1, xx.size)
        self._hist[:keep] = xx[xx.size - keep:]
        self._hist_n = keep
        # the quiet level changes only when a one-second block completes: each block's level, in turn
        bn = self.block_n
        # 0: the block in progress at the chunk start
        block = (self._blk_len + np.arange(n)) // bn
        n_done = int((self._blk_len + n) // bn)
        defined = np.isfinite(energy)
        sums = np.bincount(block, weights=np.where(defined, energy, 0.0), minlength=n_done + 1)
        counts = np.bincount(block, weights=defined.astype(float), minlength=n_done + 1)
        sums[0] += self._blk_sum
        counts[0] += self._blk_def
        levels = np.empty(n_done + 1)
        for b in range(n_done + 1):
            levels[b] = self._level
            if b < n_done:
                self._end_block(float(sums[b]), int(counts[b]))
        self._blk_len = int((self._blk_len + n) % bn)
        self._blk_sum = float(sums[n_done]) if self._blk_len else 0.0
        self._blk_def = int(counts[n_done]) if self._blk_len else 0
        q = levels[block]
        on_thr = np.maximum(self.on_ratio * q, self.min_excitation)
        off_thr = np.maximum(self.off_ratio * q, self.min_excitation * self.off_ratio / self.on_ratio)
        return self._hysteresis(int(k0), defined & (energy > on_thr), ~defined | (energy < off_thr))

    def _end_block(self, total: float, count: int) -> None:
        """A one-second block completed (``total`` of its ``count`` defined energies): its mean joins the
        quiet ring if it stays below the on-threshold in force during it -- the quiet level is the trim
        motion's, not the manoeuvres' (a manoeuvre filling most of the first minutes would otherwise raise it
        above itself), while trim that a chance-low level let start an excitation still raises it back -- or
        once blocks have been loud for ``quiet_window_s`` (the new trim)."""
        mean = total / count if count else math.nan
        loud = not mean < max(self.on_ratio * self._level, self.min_excitation)
        self._loud_blocks = self._loud_blocks + 1 if loud else 0
        if count and (not loud or self._loud_blocks >= self.quiet_blocks):
            if self._quiet_n < self.quiet_blocks:
                self._quiet[self._quiet_n] = mean
                self._quiet_n += 1
            else:
                self._quiet[:-1] = self._quiet[1:]
                self._quiet[-1] = mean
            self._level = float(quiet_quantile(self._quiet[None, : self._quiet_n])[0])

    def _hysteresis(self, k0: int, above: np.ndarray, below: np.ndarray) -> list[tuple[int, bool]]:
        n = above.size
        edges: list[tuple[int, bool]] = []
        on_idx = np.flatnonzero(above)
        d = np.diff(np.concatenate(([0], below.astype(np.int8), [0])))
        rs = np.flatnonzero(d == 1)                 # quiet runs [rs, re)
        re = np.flatnonzero(d == -1)
        long_runs = np.flatnonzero((re - rs >= self.hold_n) | (re == n))
        hold = self.hold_n
        p = 0
        if self._active and self._quiet_count > 0:          # a quiet stretch continues from the last chunk
            if rs.size and rs[0] == 0:
                length = int(re[0])
                carried = self._quiet_count
                if carried + length >= hold:
                    edges.append(self._off(self._quiet_start_k))
                    p = hold - carried
                elif re[0] == n:
                    self._quiet_count += n
                    return edges
                else:
                    p = re[0]
            self._quiet_count = 0
        while p < n:
            if not self._active:
                j = np.searchsorted(on_idx, p)
                if j >= on_idx.size:
                    break
                i = int(on_idx[j])
                k_on = max(k0 + i - self.window_n // 2, self._run_start_k, self._last_edge_k)
                edges.append((k_on, True))
                self._last_edge_k = k_on
                self._active = True
                self._quiet_count = 0
                p = i + 1
                continue
            r = int(np.searchsorted(re, p, side="right"))    # first quiet run ending after p
            found = False
            while r < rs.size:
                s = max(int(rs[r]), p)
                length = int(re[r]) - s
                if length >= hold:
                    edges.append(self._off(k0 + s))
                    p = s + hold
                    found = True
                    break
                if re[r] == n:
                    self._quiet_count = length
                    self._quiet_start_k = k0 + s
                    p = n
                    found = True
                    break
                j = np.searchsorted(long_runs, r + 1)
                if j >= long_runs.size:
                    break
                r = int(long_runs[j])
            if not found:
                p = n
        return edges

    def _off(self, k: int) -> tuple[int, bool]:
        k = max(int(k), self._last_edge_k)
        self._last_edge_k = k
        self._active = False
        self._quiet_count = 0
        return (k, False)

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict:
        """State as numpy arrays and numbers (fixed size)."""
        return {
            "hist": self._hist.copy(), "hist_n": self._hist_n, "blk_sum": self._blk_sum,
            "blk_def": self._blk_def, "blk_len": self._blk_len, "quiet": self._quiet.copy(),
            "quiet_n": self._quiet_n, "active": int(self._active), "quiet_count": self._quiet_count,
            "quiet_start_k": self._quiet_start_k, "run_start_k": self._run_start_k,
            "last_edge_k": self._last_edge_k, "loud_blocks": self._loud_blocks,
        }

    def load_state(self, state: dict) -> None:
        """Restore :meth:`state_dict` (of a detector with the same options).

        Parameters
        ----------
        state : dict
            From :meth:`state_dict`.
        """
        self._hist[:] = np.asarray(state["hist"], dtype=float)
        self._quiet[:] = np.asarray(state["quiet"], dtype=float)
        self._hist_n = int(state["hist_n"])
        self._blk_sum = float(state["blk_sum"])
        self._blk_def = int(state["blk_def"])
        self._blk_len = int(state["blk_len"])
        self._quiet_n = int(state["quiet_n"])
        self._active = bool(state["active"])
        self._quiet_count = int(state["quiet_count"])
        self._quiet_start_k = int(state["quiet_start_k"])
        self._run_start_k = int(state["run_start_k"])
        self._last_edge_k = int(state["last_edge_k"])
        self._loud_blocks = int(state.get("loud_blocks", 0))
        self._level = (
            float(quiet_quantile(self._quiet[None, : self._quiet_n])[0]) if self._quiet_n else math.inf
        )


class TriggerTracker:
    """Turns samples of an explicit boolean sweep trigger into edges ``(k, on)`` on the grid.

    The trigger is piecewise constant: true from a sample that reads true until the next sample that reads
    false. Before the first sample it is false.
    """

    def __init__(self) -> None:
        self.state = False
        self.seen = False

    def edges(self, k: np.ndarray, active: np.ndarray) -> list[tuple[int, bool]]:
        """Edges in the time-ordered samples ``active`` at grid indices ``k`` (first index at/after each).

        Parameters
        ----------
        k : ndarray of int
            Grid indices of the samples.
        active : ndarray of bool
            Trigger values (True: in a sweep).
        """
        k = np.asarray(k, dtype=np.int64)
        active = np.asarray(active, dtype=bool)
        if k.size == 0:
            return []
        self.seen = True
        prev = np.concatenate(([self.state], active[:-1]))
        change = np.flatnonzero(active != prev)
        self.state = bool(active[-1])
        return [(int(k[i]), bool(active[i])) for i in change]

    def state_dict(self) -> dict:
        """State as numbers (whether the trigger is on, whether any sample was seen)."""
        return {"state": int(self.state), "seen": int(self.seen)}

    def load_state(self, state: dict) -> None:
        """Restore :meth:`state_dict`.

        Parameters
        ----------
        state : dict
            From :meth:`state_dict`.
        """
        self.state = bool(state["state"])
        self.seen = bool(state["seen"])


def detect_sweeps(t_s: ArrayLike, u: ArrayLike, min_sweep_s: float = 10.0,
                  **options: Any) -> list[tuple[float, float]]:
    """Sweeps in a uniformly sampled input record (offline use of :class:`SweepDetector`).

    Parameters
    ----------
    t_s : array_like
        Uniform sample times [s].
    u : array_like
        Input (control-surface) samples.
    min_sweep_s : float
        Excited stretches shorter than this are not sweeps (doublets, trim steps) [s].
    **options
        :class:`SweepDetector` options (see :data:`DETECTOR_DEFAULTS`).

    Returns
    -------
    list of (float, float)
        ``(start_s, end_s)`` of each sweep.
    """
    t_s = np.asarray(t_s, dtype=float).ravel()
    u = np.asarray(u, dtype=float).ravel()
    if t_s.size != u.size:
        raise DataError(f"detect_sweeps: {t_s.size} times but {u.size} values")
    if t_s.size < 2:
        return []
    dt = float(np.median(np.diff(t_s)))
    if not (np.all(np.isfinite(t_s)) and dt > 0.0):
        raise DataError("detect_sweeps: times must be finite and increasing (uniform samples)")
    det = SweepDetector(1.0 / dt, **options)
    det.start_run(0)
    edges = det.process(0, u) + det.end_run(u.size)
    out, start = [], None
    for k, on in edges:
        if on:
            start = k
        elif start is not None:
            if (k - start) * dt >= min_sweep_s:
                out.append((float(t_s[0] + start * dt), float(t_s[0] + k * dt)))
            start = None
    return out
