"""Numbers in configs: the one checker every config reader uses.

The config schema (:mod:`gap_validation.core.config`), the effects (:mod:`gap_validation.core.effects`), the
models (:mod:`gap_validation.core.models`), the estimator options (:mod:`gap_validation.core.estimator`,
:mod:`gap_validation.core.sweeps`) and the simulation options (:mod:`gap_validation.core.flight_options`) all
read their numbers with :func:`check_number`. A number is a real number (int or float: booleans are refused,
``true`` is no delay), finite, and inside the :class:`Interval` its key allows. Numeric strings (``"5e-2"``,
which YAML 1.1 loads as a string) are accepted where the reader asks for them (``strings=True``: effects,
models, estimator options); the schema's own keys refuse them. Errors are one line: ``<where>: expected
<what>, got <value>``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Real
from typing import Any

from gap_validation.core.errors import ConfigError

__all__ = ["Interval", "check_number", "significant", "FINITE", "POSITIVE", "NON_NEGATIVE", "NONZERO"]


@dataclass(frozen=True)
class Interval:
    """The values a number may take: between ``low`` and ``high`` (each bound closed or open), or nonzero.

    Attributes
    ----------
    low, high : float
        Bounds (``-inf``, ``inf``: none).
    low_open, high_open : bool
        Whether the bound itself is excluded.
    nonzero : bool
        Zero is excluded.
    """

    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False
    high_open: bool = False
    nonzero: bool = False

    def __contains__(self, value: float) -> bool:
        if self.nonzero and value == 0.0:
            return False
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return above and below

    def _low_text(self) -> str:
        return f"a number {'>' if self.low_open else '>='} {self.low:g}"

    def _high_text(self) -> str:
        return f"a number {'<' if self.high_open else '<='} {self.high:g}"

    def text(self) -> str:
        """What the interval allows, in words: ``a number > 0``, ``a number in [0, 0.5)``, ``a nonzero
        number``."""
        if self.nonzero:
            return "a nonzero number"
        if math.isinf(self.low) and math.isinf(self.high):
            return "a finite number"
        if math.isinf(self.high):
            return self._low_text()
        if math.isinf(self.low):
            return self._high_text()
        return (f"a number in {'(' if self.low_open else '['}{self.low:g}, {self.high:g}"
                f"{')' if self.high_open else ']'}")

    def violated(self, value: float) -> str:
        """The bound ``value`` violates, in words (``a number <= 0.999``); :meth:`text` when it violates none.

        Parameters
        ----------
        value : float
            The number checked.
        """
        if not self.nonzero and not (value > self.low if self.low_open else value >= self.low):
            return self._low_text()
        if not self.nonzero and not (value < self.high if self.high_open else value <= self.high):
            return self._high_text()
        return self.text()


#: Any finite number; numbers > 0; numbers >= 0; numbers other than 0.
FINITE = Interval()
POSITIVE = Interval(0.0, low_open=True)
NON_NEGATIVE = Interval(0.0)
NONZERO = Interval(nonzero=True)


def _as_float(value: Any, strings: bool) -> float | None:
    """``value`` as a float, or None when it is no number (booleans never are; strings only when allowed)."""
    if isinstance(value, bool):
        return None
    if isinstance(value, Real):
        return float(value)
    if strings and isinstance(value, str):
        try:
            return float(value.strip())
        except ValueError:
            return None
    return None


def check_number(value: Any, where: str, allowed: Interval = FINITE, *, strings: bool = False,
                 expected: str | None = None) -> float:
    """A config value as a finite float inside ``allowed``, or a one-line :class:`ConfigError`.

    Parameters
    ----------
    value : object
        The raw config value.
    where : str
        Where the value sits, the message's prefix (``model.effects[1].seconds``, ``cfg.yaml: channels.pitch.
        coherence_threshold``, ``estimator option hold_s``).
    allowed : Interval
        The values the key allows.
    strings : bool
        Accept numeric strings (``"5e-2"``).
    expected : str, optional
        What the message says is expected, whatever the failure. Default: ``a finite number`` for a value that
        is no finite number, else the bound it violates (:meth:`Interval.violated`).

    Returns
    -------
    float

    Raises
    ------
    ConfigError
        ``<where>: expected <expected>, got <value!r>``.
    """
    number = _as_float(value, strings)
    if number is None or not math.isfinite(number):
        raise ConfigError(f"{where}: expected {expected or 'a finite number'}, got {value!r}")
    if number not in allowed:
        raise ConfigError(f"{where}: expected {expected or allowed.violated(number)}, got {value!r}")
    return number


def significant(value: float, digits: int = 4) -> float:
    """``value`` rounded to ``digits`` significant digits (config-friendly numbers for fitted parameters).

    Parameters
    ----------
    value : float
        The number.
    digits : int
        Significant digits kept.
    """
    return float(f"{float(value):.{digits}g}")
