"""The one number checker of configs (gap_validation.core.numbers): finite, in range, booleans refused."""
import math

import pytest

from gap_validation.core.errors import ConfigError
from gap_validation.core.numbers import (
    FINITE,
    NON_NEGATIVE,
    NONZERO,
    POSITIVE,
    Interval,
    check_number,
    significant,
)


@pytest.mark.parametrize("interval, text", [
    (FINITE, "a finite number"), (POSITIVE, "a number > 0"), (NON_NEGATIVE, "a number >= 0"),
    (NONZERO, "a nonzero number"), (Interval(0.0, 0.5, high_open=True), "a number in [0, 0.5)"),
    (Interval(high=0.999), "a number <= 0.999"),
])
def test_interval_words(interval, text):
    assert interval.text() == text


def test_the_violated_bound_is_named():
    band = Interval(0.0, 0.999)
    assert band.violated(-1.0) == "a number >= 0" and band.violated(2.0) == "a number <= 0.999"
    assert 0.5 in band and 1.0 not in band and 0.0 not in POSITIVE and 0.0 in NON_NEGATIVE


def test_numbers_and_numeric_strings():
    assert check_number(3, "x") == 3.0 and isinstance(check_number(3, "x"), float)
    assert check_number(" 5e-2 ", "x", strings=True) == 0.05
    with pytest.raises(ConfigError, match=r"^x: expected a finite number, got '5e-2'$"):
        check_number("5e-2", "x")                         # the schema's own keys refuse strings


@pytest.mark.parametrize("value", [True, False, None, [1.0], math.nan, math.inf, "abc"])
def test_not_a_finite_number(value):
    with pytest.raises(ConfigError) as err:
        check_number(value, "cfg.yaml: channels.pitch.scale", strings=True)
    assert str(err.value) == f"cfg.yaml: channels.pitch.scale: expected a finite number, got {value!r}"


def test_out_of_range_names_the_key_and_the_bound():
    with pytest.raises(ConfigError, match=r"^a.b: expected a number > 0, got -1$"):
        check_number(-1, "a.b", POSITIVE)
    with pytest.raises(ConfigError, match=r"^a.b: expected a positive finite number, got 0$"):
        check_number(0, "a.b", POSITIVE, expected="a positive finite number")


def test_significant_digits():
    assert significant(0.0449999, 4) == 0.045 and significant(37.7123, 3) == 37.7
