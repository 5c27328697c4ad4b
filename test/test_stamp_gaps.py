"""Messages missing from a topic's stamps (gap_validation.ros.stamp_gaps): gaps counted, pauses and jitter not."""
import random

import pytest

from gap_validation.ros.stamp_gaps import StampGaps


def test_stamp_gaps_counts_missing_messages_and_ignores_pauses_and_jitter():
    rng = random.Random(3)
    gaps = StampGaps(max_gap_s=3.0)
    period, kept = 0.001, 0
    missing = 0
    for k in range(5000):
        if k > 100 and rng.random() < 0.2:   # this message is lost
            missing += 1
            continue
        gaps.add(k * period + rng.uniform(-0.2, 0.2) * period)   # jittered stamps
        kept += 1
    assert gaps.dropped == missing
    gaps.add(5000 * period + 10.0)          # a 10 s pause: STALE, not drops
    for k in range(1, 40):
        gaps.add(5000 * period + 10.0 + k * 0.01)   # a new rate after the pause is learnt again
    gaps.add(5000 * period + 10.0 + 39 * 0.01 - 0.005)   # a stamp going backwards is ignored
    assert gaps.dropped == missing and gaps.period_s == pytest.approx(0.01)
