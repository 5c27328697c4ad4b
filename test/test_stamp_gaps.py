"""Messages missing from a topic's stamps (gap_validation.ros.stamp_gaps): gaps counted, pauses and jitter
not."""
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


def test_losses_while_the_period_is_learnt_are_counted_once_it_is():
    """The count does not depend on when losses begin (the flood test counted off by the first few)."""
    for first_loss in range(0, 20):
        gaps = StampGaps(max_gap_s=3.0)
        stamps = [k * 0.001 for k in range(200) if k not in (first_loss + 1, first_loss + 2, first_loss + 10)]
        for t in stamps:
            gaps.add(1.7e9 + t)
        assert gaps.dropped == 3, first_loss
