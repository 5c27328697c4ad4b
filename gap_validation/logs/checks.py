"""Logging checks of a flight log, each with its fix in words: a stream logged too slowly for the band the
channel asks for, stamps that repeat, go back or leave gaps, values that are not numbers.

The rate check states the limits the estimator applies (:func:`~gap_validation.core.spectra.stream_limit_hz`), so
the warning and the validated band agree: each frequency is estimated from the spectrum within ``band_fraction``
(10 %) of it, and all of that must lie below what the slowest stream resolves -- a quarter of its rate, or for a
slow stream whose channel logs its other streams at least four times faster (they show what its sampling folds
back), up to its Nyquist frequency but at most a tenth of the estimator's grid rate (PX4's servos at 10 Hz: their
Nyquist frequency, 31.4 rad/s; ArduPlane's RCOU at 25 Hz: 62.8 rad/s on the 100 Hz grid). Nothing above that is
validated, the per-frequency reason there is ``above_resolution``; and a frequency onto which a manoeuvre flown past
the Nyquist frequency folds back does not count (a slow stream: where the faster streams show it,
:data:`~gap_validation.core.spectra.MIRROR_MARGIN`; else a manoeuvre whose power reaches
:data:`~gap_validation.core.spectra.ALIAS_BAND` of the stream's Nyquist frequency counts nowhere unless it stands
20 dB above that power).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gap_validation.core.estimator import ESTIMATOR_DEFAULTS
from gap_validation.core.spectra import (ALIAS_BAND, MIRROR_MARGIN, RESOLVED_FRACTION, SLOW_GRID_FRACTION,
                                         SPECTRA_DEFAULTS, stream_limit_hz)

__all__ = ["StampCheck", "check_stamps", "rate_limit_rad_s", "rate_warning", "needed_rate_hz", "RATE_FIXES"]

#: A spacing longer than this many median sample intervals is a gap.
GAP_INTERVALS = 5.0

#: Per log format: how to log a topic faster, ``{topic}`` and ``{need_hz}`` filled in.
RATE_FIXES = {
    "ulog": ("raise its rate (PX4: SDLOG_PROFILE with the high-rate bit, bit 4 (+16), logs actuator_servos and "
             "vehicle_angular_velocity at full rate; the system-identification bit, bit 3 (+8), raises "
             "vehicle_angular_velocity and actuator_motors but not actuator_servos; or add the line '{topic} 0' "
             "(full rate) to etc/logging/logger_topics.txt on the SD card); it needs at least {need_hz:.3g} Hz"),
    "dataflash": ("raise its rate (ArduPilot: ArduPlane writes RCOU at 25 Hz with LOG_BITMASK's RC bit; log the "
                  "attitude and rate loops faster instead (LOG_BITMASK ATTITUDE_FAST, ATTITUDE_FULLRATE: RATE "
                  "ROut/POut/YOut), or fly the SystemID mode, whose SIDD comes at up to the loop rate with those bits; "
                  "and check that LOG_FILE_RATEMAX does not cap {topic}); it needs at least {need_hz:.3g} Hz"),
    "csv": "record {topic} faster (at least {need_hz:.3g} Hz), or resample it no coarser, before exporting the CSV",
}


_GRID_HZ = float(ESTIMATOR_DEFAULTS["sample_rate_hz"])
_BAND = float(SPECTRA_DEFAULTS["band_fraction"])


def rate_limit_rad_s(rate_hz: float, grid_hz: float = _GRID_HZ, witness_hz: float = math.inf) -> float:
    """Highest frequency a stream sampled at ``rate_hz`` resolves for the estimator [rad/s]: no band of a validated
    frequency reaches above it (:func:`~gap_validation.core.spectra.stream_limit_hz`: its Nyquist frequency for a slow
    stream, else a quarter of its rate); a sweep is validated up to this over ``1 + band_fraction``.

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
    """Sample rate [Hz] a stream needs for the estimator to validate a sweep up to ``top_rad_s`` (its band within
    ``band_fraction`` of it included), with the channel's other streams logged at least four times faster.

    Parameters
    ----------
    top_rad_s : float
        The highest frequency wanted [rad/s].
    grid_hz : float
        The estimator's grid rate [Hz].
    """
    limit_hz = top_rad_s * (1.0 + _BAND) / (2.0 * math.pi)
    return 2.0 * limit_hz if limit_hz <= 0.5 * SLOW_GRID_FRACTION * grid_hz else limit_hz / RESOLVED_FRACTION


def rate_warning(fmt: str, topic: str, rate_hz: float, top_rad_s: float, feeds: str, grid_hz: float = _GRID_HZ,
                 witness_hz: float = math.inf) -> str | None:
    """The warning for ``topic`` logged at ``rate_hz`` when that cannot carry the band up to ``top_rad_s``, with the
    fix for the log format ``fmt``; None when it can.

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
        The rate of the channel's streams of the other side [Hz]; inf (unknown here): assumed fast enough, and the
        warning says what they need.
    """
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        return None
    limit = rate_limit_rad_s(rate_hz, grid_hz, witness_hz)
    top = limit / (1.0 + _BAND)
    if top >= top_rad_s:
        return None
    fix = RATE_FIXES.get(fmt, RATE_FIXES["csv"]).format(topic=topic, need_hz=needed_rate_hz(top_rad_s, grid_hz))
    nyquist = math.pi * rate_hz
    quarter = 2.0 * math.pi * RESOLVED_FRACTION * rate_hz
    head = (f"{topic} ({feeds}) is logged at {rate_hz:.3g} Hz: frequencies above {top:.3g} rad/s cannot be validated "
            f"(each is estimated from the spectrum within {100 * _BAND:.0f} % of it, and that must lie below ")
    if limit <= quarter * (1.0 + 1e-12):
        return (f"{head}{limit:.3g} rad/s, a quarter of its rate: four samples per period, half its Nyquist frequency "
                f"of {nyquist:.3g} rad/s; the channel asks up to {top_rad_s:.3g} rad/s), and a manoeuvre flown above "
                f"{ALIAS_BAND[0] * nyquist:.3g} rad/s folds back into what lies below (then none of it counts); {fix}")
    grid = 2.0 / SLOW_GRID_FRACTION
    reach = (f"its Nyquist frequency, {limit:.3g} rad/s, above which its sampling folds everything back"
             if limit >= nyquist * (1.0 - 1e-12) else
             f"{limit:.3g} rad/s, 1/{grid:.0f} of the estimator's {grid_hz:.3g} Hz grid rate (above it the images of "
             f"its sampling fold back through the grid's own sampling)")
    return (f"{head}{reach}; the channel asks up to {top_rad_s:.3g} rad/s); that needs the channel's other streams "
            f"logged at {limit / (math.pi * RESOLVED_FRACTION):.3g} Hz or faster: they show what folds back, and a "
            f"frequency onto which more than {100 * MIRROR_MARGIN ** -0.5:.1f} % (in amplitude) folds back, from a "
            f"manoeuvre flown past {nyquist:.3g} rad/s, does not count (with slower ones it is read up to a quarter of "
            f"its rate: {quarter / (1.0 + _BAND):.3g} rad/s); {fix}")


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
        gaps = " (a gap longer than the estimator's max_gap_s ends the manoeuvre in progress)" if self.gaps else ""
        return f"{where}: irregular stamps: {', '.join(parts)} in {self.samples} samples{dropped}{gaps}"


def check_stamps(t_s: np.ndarray) -> StampCheck:
    """Rate, repeated and earlier stamps, gaps and non-numbers of one topic's stamps.

    Parameters
    ----------
    t_s : numpy.ndarray
        The stamps [s] in logged order.
    """
    t = np.asarray(t_s, dtype=float)
    finite = np.isfinite(t)
    tf = t[finite]
    step = np.diff(tf)
    positive = step[step > 0]            # the median spacing, the gaps: between stamps as logged
    median = float(np.median(positive)) if positive.size else math.nan
    long = step > GAP_INTERVALS * median if positive.size else np.zeros(step.size, bool)
    latest = np.maximum.accumulate(tf)[:-1]
    return StampCheck(samples=int(t.size), rate_hz=1.0 / median if median > 0 else math.nan,
                      duplicates=int(np.count_nonzero(tf[1:] == latest)), back=int(np.count_nonzero(tf[1:] < latest)),
                      gaps=int(np.count_nonzero(long)), longest_gap_s=float(step[long].max()) if long.any() else 0.0,
                      not_finite=int(t.size - tf.size))
