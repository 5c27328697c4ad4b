"""Logging checks of a flight log, each with its fix in words: a stream logged too slowly for the band the
channel asks for, stamps that repeat, go back or leave gaps, values that are not numbers.

The rate check states the limits the estimator applies (:func:`~gap_validation.core.spectra.stream_limit_hz`),
so the warning and the validated band agree: each frequency is estimated from the spectrum within
``band_fraction`` (10 %) of it, and all of that must lie below what the slowest stream resolves -- a quarter
of its rate, or for a slow stream whose channel logs its other streams at least four times faster (they show
what its sampling folds back), up to its Nyquist frequency but at most a tenth of the estimator's grid rate
(PX4's servos at 10 Hz: their Nyquist frequency, 31.4 rad/s; ArduPlane's RCOU at 25 Hz: 62.8 rad/s on the 100
Hz grid). Nothing above that is validated, the per-frequency reason there is ``above_resolution``; and a
frequency onto which a manoeuvre flown past the Nyquist frequency folds back does not count (a slow stream:
where the faster streams show it,
:data:`~gap_validation.core.spectra.MIRROR_MARGIN`; else a manoeuvre whose power reaches
:data:`~gap_validation.core.spectra.ALIAS_BAND` of the stream's Nyquist frequency counts nowhere unless it
stands 20 dB above that power).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gap_validation.core.estimator import ESTIMATOR_DEFAULTS
from gap_validation.core.spectra import (
    ALIAS_BAND,
    MIRROR_MARGIN,
    RESOLVED_FRACTION,
    SLOW_GRID_FRACTION,
    SPECTRA_DEFAULTS,
    stream_limit_hz,
)

__all__ = ["StampCheck", "StampStats", "check_stamps", "rate_limit_rad_s", "rate_warning", "needed_rate_hz",
           "RATE_FIXES"]

#: A spacing longer than this many median sample intervals is a gap.
GAP_INTERVALS = 5.0
#: The spacings' histogram (:class:`StampStats`): each spacing is rounded to this many significant bits (a
#: relative 2**-33 at most), and to 4 fewer each time the histogram would hold more than :data:`SPACING_BINS`
#: values.
SPACING_BITS = 32
SPACING_BINS = 1 << 16
#: Finite stamps :class:`StampStats` gathers before counting them (512 KB).
STAMP_BATCH = 1 << 16

#: Per log format: how to log a topic faster, ``{topic}`` and ``{need_hz}`` filled in.
RATE_FIXES = {
    "ulog": (
        "raise its rate (PX4: SDLOG_PROFILE with the high-rate bit, bit 4 (+16), logs actuator_servos and "
        "vehicle_angular_velocity at full rate; the system-identification bit, bit 3 (+8), raises "
        "vehicle_angular_velocity and actuator_motors but not actuator_servos; or add the line '{topic} 0' "
        "(full rate) to etc/logging/logger_topics.txt on the SD card); it needs at least {need_hz:.3g} Hz"
    ),
    "dataflash": (
        "raise its rate (ArduPilot: ArduPlane writes RCOU at 25 Hz with LOG_BITMASK's RC bit; log the "
        "attitude and rate loops faster instead (LOG_BITMASK ATTITUDE_FAST, ATTITUDE_FULLRATE: RATE "
        "ROut/POut/YOut), or fly the SystemID mode, whose SIDD comes at up to the loop rate with those bits; "
        "and check that LOG_FILE_RATEMAX does not cap {topic}); it needs at least {need_hz:.3g} Hz"
    ),
    "csv": "record {topic} faster (at least {need_hz:.3g} Hz), or resample it no coarser, before exporting "
           "the CSV",
}


_GRID_HZ = float(ESTIMATOR_DEFAULTS["sample_rate_hz"])
_BAND = float(SPECTRA_DEFAULTS["band_fraction"])


def rate_limit_rad_s(rate_hz: float, grid_hz: float = _GRID_HZ, witness_hz: float = math.inf) -> float:
    """Highest frequency a stream sampled at ``rate_hz`` resolves for the estimator [rad/s]: no band of a
    validated frequency reaches above it (:func:`~gap_validation.core.spectra.stream_limit_hz`: its Nyquist
    frequency for a slow stream, else a quarter of its rate); a sweep is validated up to this over ``1 +
    band_fraction``.

    Parameters
    ----------
    rate_hz : float
        The stream's sample rate [Hz].
    grid_hz : float
        The estimator's grid rate (``sample_rate_hz``) [Hz].
    witness_hz : float
        The rate of the channel's streams of the other side (the outputs of an input) [Hz]; inf: fast enough.
    """
    return 2.0 * math.pi * stream_limit_hz(rate_hz, grid_hz, witness_hz)


def needed_rate_hz(top_rad_s: float, grid_hz: float = _GRID_HZ) -> float:
    """Sample rate [Hz] a stream needs for the estimator to validate a sweep up to ``top_rad_s`` (its band
    within ``band_fraction`` of it included), with the channel's other streams logged at least four times
    faster.

    Parameters
    ----------
    top_rad_s : float
        The highest frequency wanted [rad/s].
    grid_hz : float
        The estimator's grid rate [Hz].
    """
    limit_hz = top_rad_s * (1.0 + _BAND) / (2.0 * math.pi)
    return 2.0 * limit_hz if limit_hz <= 0.5 * SLOW_GRID_FRACTION * grid_hz else limit_hz / RESOLVED_FRACTION


def rate_warning(
    fmt: str,
    topic: str,
    rate_hz: float,
    top_rad_s: float,
    feeds: str,
    grid_hz: float = _GRID_HZ,
    witness_hz: float = math.inf,
) -> str | None:
    """The warning for ``topic`` logged at ``rate_hz`` when that cannot carry the band up to ``top_rad_s``,
    with the fix for the log format ``fmt``; None when it can.

    Parameters
    ----------
    fmt : str
        ``ulog``, ``dataflash`` or ``csv``.
    topic : str
        The topic as the log names it.
    rate_hz : float
        Its sample rate [Hz] (median interval).
    top_rad_s : float
        The highest frequency the channels it feeds ask for [rad/s].
    feeds : str
        The streams it feeds, e.g. ``pitch.input``.
    grid_hz : float
        The estimator's grid rate [Hz].
    witness_hz : float
        The rate of the channel's streams of the other side [Hz]; inf (unknown here): assumed fast enough, and
        the warning says what they need.
    """
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        return None
    limit = rate_limit_rad_s(rate_hz, grid_hz, witness_hz)
    top = limit / (1.0 + _BAND)
    if top >= top_rad_s:
        return None
    fix = RATE_FIXES.get(fmt, RATE_FIXES["csv"]).format(
        topic=topic, need_hz=needed_rate_hz(top_rad_s, grid_hz)
    )
    nyquist = math.pi * rate_hz
    quarter = 2.0 * math.pi * RESOLVED_FRACTION * rate_hz
    head = (
        f"{topic} ({feeds}) is logged at {rate_hz:.3g} Hz: frequencies above {top:.3g} rad/s cannot be "
        "validated "
        f"(each is estimated from the spectrum within {100 * _BAND:.0f} % of it, and that must lie below "
    )
    if limit <= quarter * (1.0 + 1e-12):
        return (
            f"{head}{limit:.3g} rad/s, a quarter of its rate: four samples per period, half its Nyquist "
            "frequency "
            f"of {nyquist:.3g} rad/s; the channel asks up to {top_rad_s:.3g} rad/s), and a manoeuvre flown "
            "above "
            f"{ALIAS_BAND[0] * nyquist:.3g} rad/s folds back into what lies below (then none of it counts); "
            f"{fix}"
        )
    grid = 2.0 / SLOW_GRID_FRACTION
    reach = (
        f"its Nyquist frequency, {limit:.3g} rad/s, above which its sampling folds everything back"
        if limit >= nyquist * (1.0 - 1e-12)
        else f"{limit:.3g} rad/s, 1/{grid:.0f} of the estimator's {grid_hz:.3g} Hz grid rate (above it the "
             "images of "
        f"its sampling fold back through the grid's own sampling)"
    )
    return (
        f"{head}{reach}; the channel asks up to {top_rad_s:.3g} rad/s); that needs the channel's other "
        "streams "
        f"logged at {limit / (math.pi * RESOLVED_FRACTION):.3g} Hz or faster: they show what folds back, and "
        "a "
        f"frequency onto which more than {100 * MIRROR_MARGIN**-0.5:.1f} % (in amplitude) folds back, from a "
        f"manoeuvre flown past {nyquist:.3g} rad/s, does not count (with slower ones it is read up to a "
        "quarter of "
        f"its rate: {quarter / (1.0 + _BAND):.3g} rad/s); {fix}"
    )


@dataclass(frozen=True)
class StampCheck:
    """How regular a topic's stamps are.

    Attributes
    ----------
    samples : int
        Stamps looked at.
    rate_hz : float
        One over the median positive spacing [Hz] (NaN with fewer than two distinct stamps).
    duplicates : int
        Stamps equal to the latest before them.
    back : int
        Stamps earlier than the latest before them (what replay drops as not increasing, repeats aside).
    gaps : int
        Spacings longer than :data:`GAP_INTERVALS` median intervals.
    longest_gap_s : float
        The longest spacing [s] (0 without gaps).
    not_finite : int
        Stamps that are not numbers.
    """

    samples: int
    rate_hz: float
    duplicates: int
    back: int
    gaps: int
    longest_gap_s: float
    not_finite: int

    def warning(self, where: str) -> str | None:
        """One line on what is irregular, or None when nothing is.

        Parameters
        ----------
        where : str
            The file and topic, e.g. ``flight.ulg: topic actuator_servos``.
        """
        parts = []
        if self.duplicates:
            parts.append(f"{self.duplicates} repeated stamps")
        if self.back:
            parts.append(f"{self.back} stamps going back")
        if self.not_finite:
            parts.append(f"{self.not_finite} stamps that are not numbers")
        if self.gaps:
            parts.append(f"{self.gaps} gaps longer than {GAP_INTERVALS:g} sample intervals (the longest "
                         f"{self.longest_gap_s:.3g} s)")
        if not parts:
            return None
        dropped = " (repeated and earlier stamps are dropped and counted as bad samples)" if self.duplicates \
            or self.back else ""
        gaps = (
            " (a gap longer than the estimator's max_gap_s ends the manoeuvre in progress)"
            if self.gaps
            else ""
        )
        return f"{where}: irregular stamps: {', '.join(parts)} in {self.samples} samples{dropped}{gaps}"


class StampStats:
    """The stamps of one topic given in pieces (a log replayed block by block), in logged order: what
    :func:`check_stamps` says of all of them together, kept in memory that does not grow with the log.

    Counts (samples, repeated and earlier stamps, non-numbers) and the longest spacing are exact; the median
    spacing (the rate, and the threshold of a gap) comes from a histogram of the spacings, each rounded to
    :data:`SPACING_BITS` significant bits (coarser by 4 bits whenever more than :data:`SPACING_BINS` distinct
    values would be kept), so it agrees with the median of the exact spacings to a relative 2**-33 (a few
    1e-10) on any log whose spacings take fewer values than that. The same pieces in any split give the same
    result.
    """

    def __init__(self) -> None:
        self.samples = 0
        self.not_finite = 0
        self.duplicates = 0
        self.back = 0
        self._last = math.nan              # the last finite stamp (the next spacing starts there)
        self._latest = math.nan            # the latest finite stamp so far
        self._max_step = 0.0
        self._bits = SPACING_BITS
        # the rounded positive spacings (bit patterns), sorted, and how
        self._values = np.zeros(0, np.uint64)
        self._counts = np.zeros(0, np.int64)    # often each came
        # finite stamps not counted yet (at most STAMP_BATCH and a piece)
        self._pending: list[np.ndarray] = []
        self._held = 0

    def add(self, t_s: np.ndarray) -> None:
        """Take the next stamps of the topic (the finite ones are gathered up to :data:`STAMP_BATCH` before
        they are counted, for speed: the result is the same in any split).

        Parameters
        ----------
        t_s : numpy.ndarray
            Stamps [s] following the ones given before, in logged order.
        """
        t = np.asarray(t_s, dtype=float).ravel()
        tf = t[np.isfinite(t)]
        self.samples += int(t.size)
        self.not_finite += int(t.size - tf.size)
        if tf.size:
            self._pending.append(tf)
            self._held += int(tf.size)
            if self._held >= STAMP_BATCH:
                self._take()

    def _take(self) -> None:
        """Count the finite stamps gathered so far."""
        if not self._pending:
            return
        tf = self._pending[0] if len(self._pending) == 1 else np.concatenate(self._pending)
        self._pending, self._held = [], 0
        if math.isnan(self._latest):
            latest = np.maximum.accumulate(tf)[:-1]
            later, step = tf[1:], np.diff(tf)
        else:
            latest = np.maximum.accumulate(np.concatenate([[self._latest], tf]))[:-1]
            later, step = tf, np.diff(np.concatenate([[self._last], tf]))
        self.duplicates += int(np.count_nonzero(later == latest))
        self.back += int(np.count_nonzero(later < latest))
        self._latest = float(tf.max()) if math.isnan(self._latest) else max(self._latest, float(tf.max()))
        self._last = float(tf[-1])
        positive = step[step > 0]
        if positive.size:
            self._max_step = max(self._max_step, float(positive.max()))
            self._count(self._round(positive))

    def _round(self, step: np.ndarray) -> np.ndarray:
        """Positive finite spacings rounded to ``_bits`` significant bits (half up), as their IEEE bit
        patterns (which sort as the values do)."""
        drop = 53 - self._bits                          # of the 53 significant bits of a float64
        raw = np.ascontiguousarray(step, dtype=np.float64).view(np.uint64)
        return (raw + np.uint64(1 << (drop - 1))) & ~np.uint64((1 << drop) - 1)

    def _count(self, rounded: np.ndarray) -> None:
        """Add rounded spacings to the histogram (both sorted: merged without sorting again)."""
        values, counts = np.unique(rounded, return_counts=True)
        if self._values.size:
            at = np.searchsorted(self._values, values)
            known = at < self._values.size
            known[known] = self._values[at[known]] == values[known]
            self._counts[at[known]] += counts[known]
            new = ~known
            values = np.insert(self._values, at[new], values[new]) if new.any() else self._values
            counts = np.insert(self._counts, at[new], counts[new]) if new.any() else self._counts
        while values.size > SPACING_BINS and self._bits > 4:
            self._bits -= 4
            values, where = np.unique(self._round(values.view(np.float64)), return_inverse=True)
            counts = np.bincount(where, weights=counts).astype(np.int64)
        self._values, self._counts = values, counts

    def median_step(self) -> float:
        """The median positive spacing [s] (NaN before two distinct stamps)."""
        self._take()
        n = int(self._counts.sum())
        if not n:
            return math.nan
        cum = np.cumsum(self._counts)
        low, high = np.searchsorted(cum, [(n - 1) // 2 + 1, n // 2 + 1])
        values = self._values.view(np.float64)
        return float((values[low] + values[high]) / 2.0)

    def result(self) -> StampCheck:
        """What the stamps given so far say (:class:`StampCheck`)."""
        median = self.median_step()  # counts what was gathered
        gaps = (
            int(self._counts[self._values.view(np.float64) > GAP_INTERVALS * median].sum())
            if median > 0
            else 0
        )
        return StampCheck(samples=self.samples, rate_hz=1.0 / median if median > 0 else math.nan,
                          duplicates=self.duplicates, back=self.back, gaps=gaps,
                          longest_gap_s=self._max_step if gaps else 0.0, not_finite=self.not_finite)


def check_stamps(t_s: np.ndarray) -> StampCheck:
    """Rate, repeated and earlier stamps, gaps and non-numbers of one topic's stamps (:class:`StampStats` of
    all of them at once).

    Parameters
    ----------
    t_s : numpy.ndarray
        The stamps [s] in logged order.
    """
    stats = StampStats()
    stats.add(t_s)
    return stats.result()
