"""Trend statistics (campaign.trends) and the fleet findings in words (campaign.findings): least squares
pinned against scipy's linregress, false alarms at the family-wise rate, drifts found, sentences."""
import re
from datetime import datetime, timedelta

import numpy as np
import pytest
from scipy import stats

from gap_validation.campaign.findings import (
    Finding,
    Series,
    find_trends,
    fleet_series,
    format_value,
    quantity_label,
)
from gap_validation.campaign.manifest import Flight
from gap_validation.campaign.results import VALIDATED, FlightOutcome
from gap_validation.core.trends import MIN_FLIGHTS, holm_significant, linear_trend


def test_ordinary_least_squares_matches_linregress():
    rng = np.random.default_rng(1)
    days = np.sort(rng.uniform(0, 60, 9))
    values = 0.02 + 0.001 * days + rng.normal(0, 0.003, days.size)
    trend, ref = linear_trend(days, values), stats.linregress(days, values)
    assert trend.slope_per_day == pytest.approx(ref.slope, rel=1e-12)
    assert trend.intercept == pytest.approx(ref.intercept, rel=1e-12)
    assert trend.slope_error_per_day == pytest.approx(ref.stderr, rel=1e-10)
    assert trend.p_value == pytest.approx(ref.pvalue, rel=1e-8)
    assert trend.start_value == pytest.approx(ref.intercept + ref.slope * days[0])
    assert trend.slope_per_week == pytest.approx(7 * ref.slope)


def test_equal_weights_are_ordinary_least_squares_and_weights_follow_sigma():
    days, values = [0, 7, 14, 21, 28], [1.0, 1.3, 1.1, 1.6, 1.5]
    plain = linear_trend(days, values)
    same = linear_trend(days, values, sigma=[0.2] * 5)
    assert same.slope_per_day == pytest.approx(plain.slope_per_day) and same.p_value == pytest.approx(
        plain.p_value
    )
    # a flight known to be noisy barely pulls the line
    pulled = linear_trend(days + [35], values + [5.0], sigma=[0.1] * 5 + [100.0])
    assert pulled.slope_per_day == pytest.approx(plain.slope_per_day, rel=1e-3)


def test_too_few_flights_or_one_date_give_no_trend():
    assert linear_trend([0, 7, 14], [1, 2, 3]) is None
    assert linear_trend([5, 5, 5, 5], [1, 2, 3, 4]) is None
    assert linear_trend([0, 7, 14, 21, float("nan")], [1, 2, 3, float("nan"), 5]) is None   # 3 usable
    assert MIN_FLIGHTS == 4


def test_exact_lines_flat_and_sloped():
    assert linear_trend([0, 1, 2, 3], [2, 2, 2, 2]).p_value == 1.0
    assert linear_trend([0, 1, 2, 3], [0, 1, 2, 3]).p_value == 0.0


def test_holm_step_down():
    assert holm_significant([0.001, 0.04, 0.03, 0.5], alpha=0.05) == [True, False, False, False]
    assert holm_significant([0.001, 0.02, 0.016, 0.5], alpha=0.05) == [True, True, True, False]
    assert holm_significant([], alpha=0.05) == []


def test_stable_fleets_raise_a_false_alarm_at_most_at_the_family_rate():
    """800 campaigns of 12 stable series (6 flights each, noise only): any trend called real in about 1 %."""
    rng = np.random.default_rng(7)
    days = np.arange(6) * 7.0
    alarms = 0
    for _ in range(800):
        p = [linear_trend(days, rng.normal(0.3, 0.02, 6)).p_value for _ in range(12)]
        alarms += any(holm_significant(p))
    assert alarms / 800 <= 0.02             # 1 % +- 0.35 % (binomial); seeded


def test_a_drift_of_four_sigma_per_week_is_found_and_the_slope_interval_covers_it():
    """500 seeded airframes, 6 weekly flights, drift 4 flight-to-flight sigma per week, 12 trends tested: the
    drift is called real in >= 97 % (t about 17 against Holm's 8.6 at 4 dof; the miss is a scatter estimate
    twice too large, chi2(4) > 15: 0.5 %), and the 99 % interval of the slope covers the truth in about 99
    %."""
    rng = np.random.default_rng(11)
    days = np.arange(6) * 7.0
    found = covered = 0
    t99 = stats.t.ppf(0.995, 4)
    for _ in range(500):
        trend = linear_trend(days, 20 + 4.0 * days / 7 + rng.normal(0, 1, 6))
        found += holm_significant([trend.p_value] + [1.0] * 11)[0]
        covered += abs(trend.slope_per_week - 4.0) <= t99 * 7 * trend.slope_error_per_day
    assert found / 500 >= 0.97 and 0.97 <= covered / 500


def _outcome(aircraft: str, day: int, epsilon: float, delay_s: float | None) -> FlightOutcome:
    date = datetime(2025, 3, 3) + timedelta(days=day)
    flight = Flight(f"{aircraft} {date:%Y-%m-%d}", (), None, aircraft, date)
    diagnosis = None if delay_s is None else {"effect": "time_delay", "parameters": {"seconds": delay_s},
                                              "effects": [{"type": "time_delay", "seconds": delay_s}]}
    return FlightOutcome(
        flight, status=VALIDATED, channels={"pitch": {"epsilon": epsilon, "diagnosis": diagnosis}}
    )


def test_fleet_findings_name_the_drifting_airframe_in_words():
    rng = np.random.default_rng(3)
    flights = []
    for k, aircraft in enumerate(["UAV-1", "UAV-2", "UAV-3"]):
        for week in range(6):
            delay = 0.021 + (0.0054 * week if aircraft == "UAV-3" else 0.0) + rng.normal(0, 0.0005)
            flights.append(_outcome(aircraft, 7 * week + k, 0.4 + 10 * (delay - 0.02), delay))
    flights.append(_outcome("UAV-1", 50, 0.4, None))           # no diagnosis: not in the delay series
    findings = find_trends(fleet_series(flights))
    assert [(f.series.aircraft, f.series.quantity) for f in findings] == [
        (a, q) for a in ("UAV-1", "UAV-2", "UAV-3") for q in ("epsilon", "time_delay.seconds")]
    real = [f for f in findings if f.significant]
    assert [(f.series.aircraft, f.series.quantity) for f in real] == [("UAV-3", "epsilon"),
                                                                       ("UAV-3", "time_delay.seconds")]
    text = real[1].sentence()
    assert text.startswith("UAV-3 pitch: delay grows 5.")
    assert "ms per week, from 21 to 48 ms (6 flights, 2025-03-05 to 2025-04-09, p = " in text
    assert re.fullmatch(
        r"UAV-3 pitch: epsilon grows 1\d % per week, from 0\.4\d? to 0\.[67]\d? \(6 flights, .*\)",
        real[0].sentence(),
    ), real[0].sentence()
    assert re.fullmatch(
        r"UAV-1 pitch: epsilon: no real trend \(-?[\d.e-]+ \+- [\d.e-]+ % per week, 7 flights, .*\)",
        findings[0].sentence(),
    ), findings[0].sentence()
    assert len(findings[1].series.values) == 6 and len(findings[0].series.values) == 7


def test_epsilon_trends_are_relative():
    """Epsilon is fitted on a log scale: growing by a fifth each week is "20 % per week", whatever its
    size."""
    flights = [
        _outcome("UAV-7", 7 * week, 0.3 * 1.2**week * (1 + 0.01 * (-1) ** week), None) for week in range(6)
    ]
    finding = find_trends(fleet_series(flights))[0]
    assert finding.significant and finding.log
    rate, error, unit = finding.rate_per_week()
    assert unit == "%" and rate == pytest.approx(20, abs=0.5) and error < 1
    assert re.match(
        r"UAV-7 pitch: epsilon grows 20 % per week, from 0\.3 to 0\.7[45] \(6 flights", finding.sentence()
    )
    data = finding.to_json_dict()
    assert data["fitted_to"] == "log" and data["start"] == pytest.approx(0.3, rel=0.02)


def test_words_and_units():
    assert quantity_label("time_delay.seconds") == ("delay", "ms", 1e3)
    assert quantity_label("first_order_lag.bandwidth_rad_s") == ("lag bandwidth", "rad/s", 1.0)
    assert quantity_label("new_effect.corner_rad_s") == ("new effect corner", "rad/s", 1.0)
    assert quantity_label("new_effect.ratio") == ("new effect ratio", "", 1.0)
    assert [format_value(v) for v in (9.04, 21.4, 0.4512, 6.06, -0.003)] == [
        "9.0",
        "21",
        "0.45",
        "6.1",
        "-0.003",
    ]
    few = Finding(
        Series("UAV-9", "roll", "epsilon", [datetime(2025, 1, 1)] * 2, [0.1, 0.2], ["a", "b"]), None
    )
    assert few.sentence() == "UAV-9 roll: epsilon: 2 flights, too few for a trend (at least 4)"
