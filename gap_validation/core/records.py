"""Manoeuvres as they are flown: where one ends and the next begins, and what kind each is.

The sweep detector (:mod:`gap_validation.core.sweeps`) marks coarse excited stretches of a channel's
excitation signal (the input, or the injected excitation). The estimator buffers each stretch with the trim
around it and hands it here, where it is split into the manoeuvres a pilot flew and each is classified.

Splitting (:func:`split_record`)
--------------------------------
* **Trim in between.** A stretch of at least ``min_quiet_s`` (1 s) during which the excitation stays at trim
  -- within ``max(4 noise, 10 % of the excursion)`` of the level before the stretch or of the level after it
  -- separates two manoeuvres. A slow sine is not "at trim" for long (it crosses the trim level quickly; its
  peaks are far from it), so the slow start of a sweep is not split.
* **A restart of the swept frequency.** Sweeps flown back to back without a pause: the zero crossings of the
  excitation about trim give its instantaneous frequency; where a monotonic trend (at least eight
  half-periods rising, or falling) is followed by a half-period at least four times longer (shorter), and the
  median of the next three (of those left in the group) is too (a new sweep stays at its start frequency;
  crossings lost in noise give one long half-period among short ones: seen splitting the top of low-SNR
  chirps), a new sweep starts -- unless the excitation is periodic: a Schroeder-phased multisine sweeps within
  each of its periods, and identical sweeps flown back to back *are* a periodic excitation; either stays one
  record (a multisine of several periods, the best record there is for a frequency response). Fly a second of
  trim between identical sweeps to have them counted one by one.
Each manoeuvre keeps the trim before it from half the pause on, and the trim after it up to the next
manoeuvre's start (its response settles in the pause: the records of two manoeuvres share the pause's second
half, where the first one's response ends and the next one has not begun); the estimator's transient term
takes what has not settled.

Kinds (:func:`classify`)
------------------------
``chirp`` (instantaneous frequency monotonic over at least a 3:1 range), ``multisine`` (periodic: the
excitation repeats with a period of 1 s or more at least twice, correlation >= 0.8), ``multistep`` (at least
three plateaus, e.g. 3-2-1-1), ``doublet`` (two plateaus of opposite sign), ``pulse`` (one plateau, back to
trim), ``step`` (a trim change: the level after differs from the level before; not used for frequency
responses), else ``broadband`` (random or hand-flown excitation).

Saturation (:func:`saturated_share`)
------------------------------------
A smooth manoeuvre (chirp, multisine, broadband: steps have plateaus by design) whose excitation sits pinned
at the same value at its largest or smallest excursion (repeated to round-off, in runs of three samples or
more: a clipped command, a surface logged at its stop) for
:data:`SATURATED_SHARE` (5 %) of its samples or more is *saturated*: the loop held a nonlinearity the linear
model does not have, so the estimator does not use it and says so. A noisy signal never repeats its extreme
value exactly, so noise alone cannot trigger this.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "Piece",
    "split_record",
    "classify",
    "trim_noise",
    "period",
    "KINDS",
    "RESPONSE_KINDS",
    "SWEEP_KINDS",
    "trim_tolerance",
    "saturated_share",
    "SATURATED_SHARE",
    "TRIM_MOTION_SHARE",
]

#: Every kind :func:`classify` returns.
KINDS = ("chirp", "multisine", "multistep", "doublet", "pulse", "broadband", "step")
#: Kinds whose records give frequency responses (a trim step does not: it moves the equilibrium).
RESPONSE_KINDS = ("chirp", "multisine", "multistep", "doublet", "pulse", "broadband")
#: Kinds that are identification experiments: *sweeps* (raw estimates, Table 1). Doublets and pulses are
#: checks; they add to the pooled estimate.
SWEEP_KINDS = ("chirp", "multisine", "multistep", "broadband")
_TREND_HALF_PERIODS = 20
_TREND_WINDOW = 100          # the trend before a restart is judged on at most this many half-periods
_RESTART_RATIO = 4.0
# ... and the median of the next this many half-periods too (of those left, if fewer)
_RESTART_CONFIRM = 3
_MIN_PLATEAU_S = 0.15


@dataclass(frozen=True)
class Piece:
    """One manoeuvre inside a buffered stretch (sample indices into the stretch).

    Attributes
    ----------
    start, end : int
        The record: ``[start, end)`` (trim before and after included).
    active_start, active_end : int
        The excited part ``[active_start, active_end)``.
    group : int
        Manoeuvres flown back to back (split only at a restart of the swept frequency) share a group; trim
        separates groups.
    """

    start: int
    end: int
    active_start: int
    active_end: int
    group: int = 0


#: The trim motion widens the band about trim to at most this share of the excursion: a manoeuvre only a few
#: times larger than the trim motion is still a manoeuvre, and its slow parts must not read as trim.
TRIM_MOTION_SHARE = 0.25


def trim_tolerance(excursion: float, noise_std: float, trim_std: float = 0.0) -> float:
    """Half-width of the band about trim that counts as "at trim": ``max(4 noise, 10 % of the excursion)``,
    widened to four standard deviations of the trim motion (a pilot's corrections, a damper answering
    turbulence: measured between the manoeuvres) but not beyond :data:`TRIM_MOTION_SHARE` of the excursion.

    Parameters
    ----------
    excursion : float
        Largest deviation of the excitation from trim.
    noise_std : float
        Noise standard deviation at trim (the sensor's, from the ends of the stretch).
    trim_std : float
        Standard deviation of the trim motion between manoeuvres (0 when unknown).
    """
    motion = min(4.0 * max(trim_std, 0.0), TRIM_MOTION_SHARE * excursion) if trim_std > 0 else 0.0
    return max(4.0 * max(noise_std, 0.0), 0.1 * excursion, motion)


#: An excited stretch shorter than this [s] ...
MIN_ACTIVE_S = 0.1
#: ... or whose excursion from trim is no more than this many noise standard deviations is a noise spike.
SPIKE_FACTOR = 8.0
#: Trim levels are the medians of this much of a stretch's start and end [s]: the detector dates an excitation
#: up to half its energy window late, so a longer head could reach into the manoeuvre when the data begin
#: shortly before it (a 1 s trim before a 3-2-1-1).
TRIM_LEVEL_S = 0.5


def _levels(u: np.ndarray, dt: float, pre_n: int, post_n: int) -> tuple[float, float]:
    n = max(1, int(round(TRIM_LEVEL_S / dt)))
    head = u[: max(1, min(pre_n, n, u.size // 4))]
    tail = u[u.size - max(1, min(post_n, n, u.size // 4)):]
    return float(np.median(head)), float(np.median(tail))


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Starts and ends (exclusive) of the runs of True in ``mask``."""
    d = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


def _half_periods(dev: np.ndarray, tol: float) -> np.ndarray:
    """Sample indices where ``dev`` crosses from beyond ``+tol`` to beyond ``-tol`` or back (hysteresis)."""
    state = np.where(dev > tol, 1, np.where(dev < -tol, -1, 0))
    nz = np.flatnonzero(state)
    if nz.size < 2:
        return nz[:0]
    s = state[nz]
    return nz[1:][s[1:] != s[:-1]]


def _rank_trend(values: np.ndarray) -> float:
    """Spearman correlation of ``values`` with their order (+1: increasing)."""
    if values.size < 3:
        return 0.0
    ranks = np.argsort(np.argsort(values, kind="stable"), kind="stable").astype(float)
    order = np.arange(values.size, dtype=float)
    if np.std(ranks) == 0:
        return 0.0
    return float(np.corrcoef(order, ranks)[0, 1])


def _restarts(dev: np.ndarray, tol: float, lo: int, hi: int) -> list[int]:
    """Indices in ``[lo, hi)`` where a monotonic sweep starts over (see the module docstring)."""
    flips = _half_periods(dev[lo:hi], tol)
    if flips.size < _TREND_HALF_PERIODS + 2:
        return []
    half = np.diff(flips).astype(float)
    values = half.tolist()
    out: list[int] = []
    first = 0                                            # half-periods since the last cut
    for j in range(_TREND_HALF_PERIODS, half.size):
        if j - max(first, j - _TREND_WINDOW) < _TREND_HALF_PERIODS:
            continue
        recent = sorted(values[j - 3:j])[1]              # median of the last three
        longer, shorter = values[j] >= _RESTART_RATIO * recent, values[j] * _RESTART_RATIO <= recent
        if not (longer or shorter):                      # the cheap test first: most half-periods go on
            continue
        # a new sweep stays at its start frequency for several half-periods; crossings lost to noise give one
        # long (or short) half-period among the others
        # fewer at the end of a group (a doublet after a sweep)
        after = values[j + 1:j + 1 + _RESTART_CONFIRM]
        if not after:
            continue
        lasting = sorted(after)[(len(after) - 1) // 2] if longer else sorted(after)[len(after) // 2]
        if (longer and lasting < _RESTART_RATIO * recent) or (shorter and lasting * _RESTART_RATIO > recent):
            continue
        trend = _rank_trend(half[max(first, j - _TREND_WINDOW):j])
        if (longer and trend <= -0.8) or (shorter and trend >= 0.8):
            out.append(lo + int(flips[j]))
            first = j + 1
    return out


def split_record(u: np.ndarray, dt: float, noise_std: float, pre_n: int, post_n: int,
                 min_quiet_s: float = 1.0, trim_std: float = 0.0, open_end: bool = False) -> list[Piece]:
    """Split a buffered excited stretch into the manoeuvres flown (see the module docstring).

    Parameters
    ----------
    u : ndarray
        Excitation signal on the grid: trim (``pre_n`` samples), the excited stretch, trim (``post_n``).
    dt : float
        Grid step [s].
    noise_std : float
        Standard deviation of the excitation's noise at trim (0 when unknown).
    pre_n, post_n : int
        Samples of trim kept before and after each manoeuvre at most.
    min_quiet_s : float
        Shortest stretch at trim that separates two manoeuvres [s].
    trim_std : float
        Standard deviation of the trim motion between manoeuvres (0 when unknown): it widens the band about
        trim (:func:`trim_tolerance`); noise spikes are judged against ``noise_std`` alone.
    open_end : bool
        ``u`` was cut while a manoeuvre went on (a full record buffer): its last samples are no trim, and the
        trim is the level before alone. Taken from a sweep's middle, the "trim after" lies near one of its
        peaks, and a slow sweep dwells there for more than ``min_quiet_s`` every period: cut into pieces of
        one period each (a 107 s sweep from 0.7 rad/s, flown six times with 6 s of trim between, came out as
        two "multisteps").

    Returns
    -------
    list of Piece
        In time order; empty when nothing in ``u`` leaves trim (excursions shorter than :data:`MIN_ACTIVE_S`
        or within :data:`SPIKE_FACTOR` noise standard deviations are noise spikes).
    """
    u = np.asarray(u, float)
    if u.size < 3:
        return []
    before, after = _levels(u, dt, pre_n, post_n)
    if open_end:
        after = before
    dev = u - before
    excursion = float(np.percentile(np.abs(dev), 99))
    tol = trim_tolerance(excursion, noise_std, trim_std)
    at_trim = (np.abs(u - before) <= tol) | (np.abs(u - after) <= tol)
    active = ~at_trim
    if not active.any():
        return []
    starts, ends = _runs(active)
    min_gap = max(1, int(round(min_quiet_s / dt)))
    # merge active runs separated by less than min_gap of trim
    groups = [[int(starts[0]), int(ends[0])]]
    for a, b in zip(starts[1:], ends[1:]):
        if a - groups[-1][1] < min_gap:
            groups[-1][1] = int(b)
        else:
            groups.append([int(a), int(b)])
    # an excursion no larger than the noise, or shorter than a tenth of a second, is a noise spike, not a
    # manoeuvre
    shortest = max(2, int(round(MIN_ACTIVE_S / dt)))
    groups = [(a, b) for a, b in groups if b - a >= shortest
              and np.max(np.abs(dev[a:b])) > SPIKE_FACTOR * max(noise_std, 0.0)]
    # frequency restarts inside a group
    active_spans = []
    for g, (a, b) in enumerate(groups):
        cuts = [a] + _restarts(dev, tol, a, b) + [b]
        if len(cuts) > 2 and _is_periodic(dev[a:b], dt):
            # a periodic excitation (a Schroeder multisine sweeps every period)
            cuts = [a, b]
        active_spans += [(c0, c1, g) for c0, c1 in zip(cuts[:-1], cuts[1:]) if c1 > c0]
    pieces = []
    for i, (a, b, g) in enumerate(active_spans):
        prev_end = active_spans[i - 1][1] if i else 0
        next_start = active_spans[i + 1][0] if i + 1 < len(active_spans) else u.size
        start = max(a - pre_n, (prev_end + a + 1) // 2 if i else 0)
        end = min(b + post_n, next_start)    # its response settles until the next manoeuvre begins
        pieces.append(Piece(int(start), int(end), int(a), int(b), g))
    return pieces


def trim_noise(u: np.ndarray, dt: float) -> float:
    """Noise of the excitation at trim: the smaller of the standard deviations about a straight line of the
    first and the last :data:`TRIM_LEVEL_S` of a buffered stretch (0 for a stretch too short to tell).

    Parameters
    ----------
    u : ndarray
        The buffered excitation signal (trim at both ends).
    dt : float
        Grid step [s].
    """
    u = np.asarray(u, float)
    n = max(3, int(round(TRIM_LEVEL_S / dt)))
    if u.size < 4 * n:
        return 0.0
    x = np.arange(n, dtype=float)
    out = []
    for part in (u[:n], u[-n:]):
        fit = np.polyval(np.polyfit(x, part, 1), x)
        out.append(float(np.std(part - fit)))
    return min(out)


def _plateaus(dev: np.ndarray, dt: float, tol: float) -> list[float]:
    """Signed levels of the flat stretches (plateaus) of ``dev`` away from trim, in time order."""
    n = max(2, int(round(_MIN_PLATEAU_S / dt)))
    if dev.size < n:
        return []
    win = np.lib.stride_tricks.sliding_window_view(dev, n)
    flat = (win.max(axis=1) - win.min(axis=1) <= max(tol, 0.1 * np.max(np.abs(dev)))) & \
        (np.abs(win.mean(axis=1)) > 2.0 * tol)
    starts, ends = _runs(flat)
    levels = []
    for a, b in zip(starts, ends):
        level = float(np.mean(dev[a:b + n - 1]))
        if levels and np.sign(level) == np.sign(levels[-1]) and abs(level - levels[-1]) <= tol:
            continue
        levels.append(level)
    return levels


def _is_chirp(dev: np.ndarray, tol: float) -> bool:
    half = np.diff(_half_periods(dev, tol)).astype(float)
    if half.size < 12:
        return False
    spread = np.percentile(half, 90) / max(np.percentile(half, 10), 1.0)
    return bool(abs(_rank_trend(half)) >= 0.8 and spread >= 3.0)


def period(dev: np.ndarray, dt: float) -> int:
    """The period of a periodic excitation in samples (0 when it is not periodic).

    The shortest lag of at least 1 s whose normalised autocorrelation is at least 0.8 and within 0.05 of the
    highest (the fundamental, not a multiple of it), with at least about two periods in ``dev`` (lags up to
    60 % of it: the fade-in and fade-out of two periods lie partly within the trim tolerance).

    Parameters
    ----------
    dev : ndarray
        The excitation about trim, on the grid.
    dt : float
        Grid step [s].
    """
    n = dev.size
    lo = int(round(1.0 / dt))
    if n < 2 * lo + 2:
        return 0
    x = dev - dev.mean()
    spec = np.fft.rfft(x, 2 * n)
    acf = np.fft.irfft(spec * np.conj(spec))[:n]
    energy = np.concatenate(([0.0], np.cumsum(x * x)))
    lags = np.arange(lo, int(0.6 * n) + 1)
    with np.errstate(divide="ignore", invalid="ignore"):   # correlation of x[:n-L] with x[L:]
        rho = acf[lags] / np.sqrt(energy[n - lags] * (energy[n] - energy[lags]))
    rho = np.where(np.isfinite(rho), rho, 0.0)
    if not rho.size or rho.max() < 0.8:
        return 0
    good = np.flatnonzero(rho >= max(0.8, rho.max() - 0.05))
    first = good[0]
    run_end = first
    while run_end + 1 < rho.size and rho[run_end + 1] >= rho[run_end]:   # climb to the local peak
        run_end += 1
    return int(lags[run_end])


def _is_periodic(dev: np.ndarray, dt: float) -> bool:
    return period(dev, dt) > 0


def classify(u: np.ndarray, dt: float, piece: Piece, noise_std: float, trim_std: float = 0.0) -> str:
    """The kind of one manoeuvre (see the module docstring).

    Parameters
    ----------
    u : ndarray
        The buffered excitation signal the piece indexes.
    dt : float
        Grid step [s].
    piece : Piece
        The manoeuvre.
    noise_std : float
        Noise standard deviation of the excitation at trim.
    trim_std : float
        Standard deviation of the trim motion between manoeuvres (0 when unknown).

    Returns
    -------
    str
        One of :data:`KINDS`.
    """
    rec = np.asarray(u[piece.start:piece.end], float)
    a0, a1 = piece.active_start - piece.start, piece.active_end - piece.start
    pre = rec[:max(1, a0)]
    post = rec[a1:] if a1 < rec.size else rec[-1:]
    enough = max(2, int(round(0.2 / dt)))            # a margin this long is trim by construction of the split
    # a piece cut by a gap (or the start of the data) has no trim on that side: its level there is unknown
    before = float(np.median(pre)) if pre.size >= enough else None
    after = float(np.median(post)) if post.size >= enough else None
    reference = before if before is not None else after if after is not None else float(np.median(rec[a0:a1]))
    dev = rec[a0:a1] - reference
    if dev.size == 0:
        return "broadband"
    excursion = float(np.max(np.abs(dev)))
    tol = trim_tolerance(excursion, noise_std, trim_std)
    if _is_chirp(_detrended(dev), tol):  # a sweep is a sweep even where the trim moved meanwhile (a long one)
        return "chirp"
    if before is not None and after is not None and abs(after - before) > max(0.3 * excursion, 2.0 * tol):
        return "step"
    if _is_periodic(dev, dt):
        return "multisine"
    levels = _plateaus(dev, dt, tol)
    flat = _flat_share(dev, dt, tol)
    if flat >= 0.6 and levels:
        if len(levels) == 1:
            return "pulse"
        if len(levels) == 2 and np.sign(levels[0]) != np.sign(levels[1]):
            return "doublet"
        return "multistep"
    return "broadband"


def _detrended(dev: np.ndarray) -> np.ndarray:
    """``dev`` less its least-squares straight line: the trim's drift over a long manoeuvre (a pilot's
    corrections, a slow mode) moves the crossings of a fixed level, not those about the drifting one."""
    if dev.size < 3:
        return dev
    x = np.arange(dev.size, dtype=float)
    return dev - np.polyval(np.polyfit(x, dev, 1), x)


def _flat_share(dev: np.ndarray, dt: float, tol: float) -> float:
    """Share of the excursion (samples beyond twice the trim tolerance) that lies on plateaus: most of it for
    square-wave-like inputs, little for sines; a slow trim ramp next to a doublet is not an excursion."""
    n = max(2, int(round(_MIN_PLATEAU_S / dt)))
    away = np.abs(dev) > 2.0 * tol
    if dev.size < n or not away.any():
        return 0.0
    win = np.lib.stride_tricks.sliding_window_view(dev, n)
    spread = max(tol, 0.1 * float(np.max(np.abs(dev))))
    flat = (win.max(axis=1) - win.min(axis=1) <= spread) & (np.abs(win.mean(axis=1)) > 2.0 * tol)
    covered = np.zeros(dev.size, bool)
    idx = np.flatnonzero(flat)
    for k in range(n):
        covered[idx + k] = True
    return float(np.count_nonzero(covered & away) / np.count_nonzero(away))


#: Share of a manoeuvre's samples pinned at its extremes from which it counts as saturated.
SATURATED_SHARE = 0.05


def saturated_share(u: np.ndarray, piece: Piece) -> float:
    """Share of a manoeuvre's excited samples pinned at exactly its largest or smallest value.

    Parameters
    ----------
    u : ndarray
        The buffered excitation signal the piece indexes.
    piece : Piece
        The manoeuvre.

    Returns
    -------
    float
        Samples in runs of three or more equal to the extreme value (either side), over the excited samples; 0
        for a signal that never repeats its extremes (any noisy signal).
    """
    active = np.asarray(u[piece.active_start:piece.active_end], float)
    if active.size < 3:
        return 0.0
    pinned = 0
    hi, lo = float(np.max(active)), float(np.min(active))
    tie = 1e-9 * (hi - lo)                     # interpolation onto the estimator's grid may leave round-off
    for at in (active >= hi - tie, active <= lo + tie):
        if np.count_nonzero(at) < 3:
            continue
        starts, ends = _runs(at)
        lengths = ends - starts
        pinned += int(np.sum(lengths[lengths >= 3]))
    return pinned / active.size
