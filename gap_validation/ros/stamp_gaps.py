"""Messages missing from a topic, inferred from gaps in its ``header.stamp`` (the node's ``samples_dropped``).

DDS does not tell a subscriber when a KEEP_LAST queue overflows or a BEST_EFFORT link loses a sample; the
stamps do. No rclpy: the node feeds every stamp it sees.
"""
from __future__ import annotations

import numpy as np

__all__ = ["StampGaps"]


class StampGaps:
    """Messages missing from one topic, inferred from its ``header.stamp`` continuity.

    The node cannot see losses inside DDS (a KEEP_LAST queue that overflows drops the oldest samples silently,
    a BEST_EFFORT link loses some), so it counts them from the stamps: the nominal period is learnt from the
    first :attr:`LEARN` intervals (their median) and then refined as the mean of every interval below 1.5
    periods (stamps of 1.7e9 s carry float rounding of 0.24 us, which the mean averages out), and an interval
    of ``dt`` with ``1.5 period < dt <= max_gap_s`` counts ``round(dt / period) - 1`` missing messages --
    those among the first intervals too, once the period is learnt, so the count does not depend on when
    losses begin. Longer silences are pauses (STALE), not drops; after one the period is learnt again. A rate
    change in flight would count as drops; stamps going backwards are ignored.
    """

    LEARN = 16
    __slots__ = ("max_gap_s", "period_s", "first_s", "last_s", "dropped", "_intervals", "_sum_s", "_count")

    def __init__(self, max_gap_s: float):
        self.max_gap_s = float(max_gap_s)
        self.first_s: float | None = None   # first stamp seen [s]
        self.last_s: float | None = None
        self.dropped = 0
        self._learn()

    def _learn(self) -> None:
        self.period_s, self._intervals, self._sum_s, self._count = 0.0, [], 0.0, 0

    def add(self, t_s: float) -> None:
        """One message stamped ``t_s`` [s]."""
        last, self.last_s = self.last_s, t_s
        if last is None:
            self.first_s = t_s
            return
        dt = t_s - last
        if dt <= 0.0:
            self.last_s = last if dt < 0.0 else t_s
        elif dt > self.max_gap_s:
            self._learn()
        elif self.period_s <= 0.0:
            self._intervals.append(dt)
            if len(self._intervals) >= self.LEARN:
                self.period_s = float(np.median(self._intervals))
                normal = [d for d in self._intervals if d <= 1.5 * self.period_s]
                self._sum_s, self._count = float(sum(normal)), len(normal)
                self.dropped += sum(int(round(d / self.period_s)) - 1 for d in self._intervals
                                    if d > 1.5 * self.period_s)
        elif dt > 1.5 * self.period_s:
            self.dropped += int(round(dt / self.period_s)) - 1
        else:
            self._sum_s += dt
            self._count += 1
            self.period_s = self._sum_s / self._count
