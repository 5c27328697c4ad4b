"""Logging checks of a flight log, each with its fix in words: a stream logged too slowly for the band the
channel asks for, stamps that repeat, go back or leave gaps, values that are not numbers.

The rate check states the limits the estimator applies (:data:`~gap_validation.core.estimator.RESOLVED_FRACTION`
of the slowest stream's rate: a frequency counts only where every stream of the channel has at least four samples
per period, half the Nyquist frequency; above it the interpolation onto the estimator's grid cannot be corrected
and its images fold back), so the warning and the validated band agree: nothing above that limit is validated,
and the per-frequency reason there is ``above_resolution``; and a manoeuvre whose power reaches
:data:`~gap_validation.core.spectra.ALIAS_BAND` of the stream's Nyquist frequency may have folded back (aliased)
below it, so nothing it excites counts unless it stands 20 dB above that power.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gap_validation.core.estimator import RESOLVED_FRACTION
from gap_validation.core.spectra import ALIAS_BAND

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


def rate_limit_rad_s(rate_hz: float) -> float:
    """Highest frequency a stream sampled at ``rate_hz`` lets the estimator validate [rad/s]
    (``2 pi RESOLVED_FRACTION rate``).

    Parameters
    ----------
    rate_hz : float
        The stream's sample rate [Hz].
    """
    return 2.0 * math.pi * RESOLVED_FRACTION * rate_hz


def needed_rate_hz(top_rad_s: float) -> float:
    """Sample rate [Hz] a stream needs for the estimator to validate up to ``top_rad_s``.

    Parameters
    ----------
    top_rad_s : float
        The highest frequency wanted [rad/s].
    """
    return top_rad_s / (2.0 * math.pi * RESOLVED_FRACTION)


def rate_warning(fmt: str, topic: str, rate_hz: float, top_rad_s: float, feeds: str) -> str | None:
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
    """
    limit = rate_limit_rad_s(rate_hz)
    if not (math.isfinite(rate_hz) and rate_hz > 0) or limit >= top_rad_s:
        return None
    fix = RATE_FIXES.get(fmt, RATE_FIXES["csv"]).format(topic=topic, need_hz=needed_rate_hz(top_rad_s))
    return (f"{topic} ({feeds}) is logged at {rate_hz:.3g} Hz: frequencies above {limit:.3g} rad/s cannot be "
            f"validated (the estimate needs four samples per period, half the Nyquist frequency of "
            f"{math.pi * rate_hz:.3g} rad/s; the channel asks up to {top_rad_s:.3g} rad/s), and a manoeuvre flown "
            f"above {ALIAS_BAND[0] * math.pi * rate_hz:.3g} rad/s folds back into what lies below (then none of it "
            f"counts); {fix}")


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
