"""Fleet findings: per aircraft and channel, epsilon and each diagnosed parameter over date, and the trends
that are real against the flights' random error, in words ("UAV-3 pitch: delay grows 6.1 ms per week, from 20
to 45 ms"; "UAV-3 pitch: epsilon grows 29 % per week, from 0.41 to 1.5").

Quantities: ``epsilon`` of every validated flight, and every parameter of the flight's *top* diagnosis
candidate, named ``<effect type>.<parameter>`` (``time_delay.seconds``); a flight whose top candidate lacks
the parameter (or has no diagnosis) is left out of that series. Statistics: :mod:`gap_validation.core.trends`
(least squares over date, slope against the residual scatter, Holm over every trend of the campaign), on
``log(epsilon)`` for epsilon.
No matplotlib, no Dask.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import datetime
from typing import Sequence

from gap_validation.campaign.results import FAILED, FlightOutcome
from gap_validation.core.trends import FAMILY_ALPHA, MIN_FLIGHTS, Trend, holm_significant, linear_trend

__all__ = ["Series", "Finding", "fleet_series", "find_trends", "fits_log", "quantity_label", "format_value",
           "EPSILON"]

EPSILON = "epsilon"

#: Words and display units of the effects' parameters: ``<type>.<parameter>`` -> (label, unit, scale).
_LABELS = {
    EPSILON: ("epsilon", "", 1.0),
    "time_delay.seconds": ("delay", "ms", 1e3),
    "first_order_lag.bandwidth_rad_s": ("lag bandwidth", "rad/s", 1.0),
    "second_order_lag.natural_frequency_rad_s": ("actuator natural frequency", "rad/s", 1.0),
    "second_order_lag.damping": ("actuator damping", "", 1.0),
    "gain.factor": ("gain factor", "", 1.0),
    "structural_mode.frequency_rad_s": ("structural mode frequency", "rad/s", 1.0),
    "structural_mode.damping": ("structural mode damping", "", 1.0),
    "structural_mode.zero_frequency_rad_s": ("structural mode zero frequency", "rad/s", 1.0),
    "structural_mode.zero_damping": ("structural mode zero damping", "", 1.0),
    "rate_limit.rad_s": ("rate limit", "rad/s", 1.0),
    "backlash.width_rad": ("backlash width", "mrad", 1e3),
    "zero_order_hold.rate_hz": ("hold rate", "Hz", 1.0),
}


def quantity_label(quantity: str) -> tuple[str, str, float]:
    """(words, display unit, scale from SI to the display unit) of a quantity name."""
    if quantity in _LABELS:
        return _LABELS[quantity]
    kind, _, parameter = quantity.partition(".")
    for suffix, unit, scale in (("_rad_s", "rad/s", 1.0), ("seconds", "ms", 1e3), ("_s", "ms", 1e3),
                                ("_rad", "mrad", 1e3)):
        if parameter.endswith(suffix):
            words = parameter[: -len(suffix)].rstrip("_")
            return f"{kind.replace('_', ' ')} {words.replace('_', ' ')}".strip(), unit, scale
    return f"{kind.replace('_', ' ')} {parameter.replace('_', ' ')}".strip(), "", 1.0


def format_value(value: float) -> str:
    """A value for a sentence: two significant figures, whole numbers from 10 up (``21``, ``6.1``,
    ``0.45``)."""
    if not math.isfinite(value):
        return str(value)
    if abs(value) >= 10:
        return f"{value:.0f}"
    return f"{value:.2g}" if abs(value) < 1 else f"{value:.1f}"


@dataclass
class Series:
    """One quantity of one aircraft's channel over the campaign's flights (date order)."""

    aircraft: str
    channel: str
    quantity: str
    dates: list[datetime] = field(default_factory=list)
    values: list[float] = field(default_factory=list)
    flights: list[str] = field(default_factory=list)

    def days(self, origin: datetime) -> list[float]:
        return [(d - origin).total_seconds() / 86400.0 for d in self.dates]


@dataclass
class Finding:
    """A series, its trend (None with fewer than :data:`MIN_FLIGHTS` flights) and whether the trend is real.

    Epsilon's trend is fitted to ``log(epsilon)`` (:func:`fits_log`): epsilon is a ratio, its changes are
    relative (a delay growing steadily makes it grow ever faster, ``tan(w T/2)`` for a pure delay at the worst
    frequency w) and its random error grows with it. Its rate is then a percentage per week. Parameters are
    fitted as they are.
    """

    series: Series
    trend: Trend | None
    significant: bool = False

    @property
    def label(self) -> tuple[str, str, float]:
        return quantity_label(self.series.quantity)

    @property
    def log(self) -> bool:
        return fits_log(self.series.quantity)

    def fitted(self, day: float) -> float:
        """The trend line at ``day`` in display units (on the log scale for epsilon)."""
        t = self.trend
        line = t.intercept + t.slope_per_day * day
        return math.exp(line) if self.log else line * self.label[2]

    def rate_per_week(self) -> tuple[float, float, str]:
        """(rate, standard error, unit) per week in display units: ``%`` for epsilon."""
        t = self.trend
        if self.log:  # exp(b) - 1, its error by the delta method
            return (
                100 * math.expm1(t.slope_per_week),
                100 * math.exp(t.slope_per_week) * 7 * t.slope_error_per_day,
                "%",
            )
        _, unit, scale = self.label
        return t.slope_per_week * scale, 7 * t.slope_error_per_day * scale, unit

    def sentence(self) -> str:
        """The trend in words: ``UAV-3 pitch: delay grows 6.1 ms per week, from 20 to 45 ms (6 flights,
        ...)``."""
        s, t = self.series, self.trend
        words, unit, _ = self.label
        head = f"{s.aircraft} {s.channel}: {words}"
        if t is None:
            return f"{head}: {len(s.values)} flights, too few for a trend (at least {MIN_FLIGHTS})"
        rate, error, rate_unit = self.rate_per_week()
        stats = f"{t.n} flights, {s.dates[0]:%Y-%m-%d} to {s.dates[-1]:%Y-%m-%d}, p = {t.p_value:.1g}"
        if not self.significant:
            return (
                f"{head}: no real trend "
                f"({_with_unit(f'{format_value(rate)} +- {format_value(error)}', rate_unit)} "
                f"per week, {stats})"
            )
        verb = "grows" if rate > 0 else "falls"
        span = f"{format_value(self.fitted(t.first_day))} to {format_value(self.fitted(t.last_day))}"
        return (f"{head} {verb} {_with_unit(format_value(abs(rate)), rate_unit)} per week, from "
                f"{_with_unit(span, unit)} ({stats})")

    def to_json_dict(self) -> dict:
        s = self.series
        out = {
            "aircraft": s.aircraft,
            "channel": s.channel,
            "quantity": s.quantity,
            "flights": len(s.values),
            "significant": self.significant,
            "sentence": self.sentence(),
            "fitted_to": "log" if self.log else "value",
            "trend": self.trend.to_json_dict() if self.trend is not None else None,
        }
        if self.trend is not None:
            rate, error, unit = self.rate_per_week()
            out.update(rate_per_week=rate, rate_error_per_week=error, rate_unit=unit,
                       start=self.fitted(self.trend.first_day), end=self.fitted(self.trend.last_day))
        return out


def _with_unit(text: str, unit: str) -> str:
    return f"{text} {unit}" if unit else text


def fits_log(quantity: str) -> bool:
    """Whether a quantity's trend is fitted to its logarithm (epsilon: see :class:`Finding`)."""
    return quantity == EPSILON


def _top_parameters(summary: dict) -> dict[str, float]:
    """``<type>.<parameter>`` -> value of the top candidate's effects (scalars only; the first of a type)."""
    out: dict[str, float] = {}
    top = summary.get("diagnosis") or {}
    for effect in top.get("effects") or []:
        kind = effect.get("type")
        for key, value in effect.items():
            if key == "type" or isinstance(value, bool) or not isinstance(value, (int, float)):
                continue
            out.setdefault(f"{kind}.{key}", float(value))
    return out


def fleet_series(outcomes: Sequence[FlightOutcome]) -> list[Series]:
    """Every (aircraft, channel, quantity) series of the validated flights: aircraft and channels in the order
    of the flights given (the manifest's), each series' flights in date order."""
    table: dict[tuple[str, str, str], Series] = {}
    done = [o for o in outcomes if o.status != FAILED and o.channels]
    for outcome in done:                   # series in manifest order of aircraft and channels ...
        for channel, summary in outcome.channels.items():
            for quantity in (EPSILON, *_top_parameters(summary)):
                key = (outcome.flight.aircraft, channel, quantity)
                table.setdefault(key, Series(*key))
    for outcome in sorted(done, key=lambda o: o.flight.date):        # ... values in date order
        f = outcome.flight
        for channel, summary in outcome.channels.items():
            values = {EPSILON: summary.get("epsilon"), **_top_parameters(summary)}
            for quantity, value in values.items():
                if value is None or not math.isfinite(value):
                    continue
                series = table[(f.aircraft, channel, quantity)]
                series.dates.append(f.date)
                series.values.append(float(value))
                series.flights.append(f.name)
    return [s for s in table.values() if s.values]


def find_trends(series: Sequence[Series], alpha: float = FAMILY_ALPHA) -> list[Finding]:
    """A :class:`Finding` per series: its trend, and whether it is real (Holm over all trends, ``alpha``).

    Order: aircraft and channel as in ``series``, epsilon first within each, then the parameters by name.

    Parameters
    ----------
    series : sequence of Series
        The quantities over date.
    alpha : float
        Family-wise false-alarm rate (Holm).
    """
    if not series:
        return []
    origin = min(d for s in series for d in s.dates)
    findings = []
    for s in series:
        values = [math.log(v) if v > 0 else math.nan for v in s.values] if fits_log(s.quantity) else s.values
        findings.append(Finding(s, linear_trend(s.days(origin), values)))
    tested = [f for f in findings if f.trend is not None]
    for finding, real in zip(tested, holm_significant([f.trend.p_value for f in tested], alpha)):
        finding.significant = real
    order = {}
    for f in findings:
        order.setdefault((f.series.aircraft, f.series.channel), len(order))
    return sorted(findings, key=lambda f: (order[(f.series.aircraft, f.series.channel)],
                                           f.series.quantity != EPSILON, f.series.quantity))
