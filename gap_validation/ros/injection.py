"""What the node injects (issue 25): where each channel's surface offset goes, and the samples, without rclpy.

:class:`gap_validation.ros.excitation.Excitation` publishes; this module decides what.

Injection points
----------------
Every SISO channel with an input can be flown (:func:`injection_points`). With ``excitation_type``
``sensor_msgs/msg/JointState`` all channels share ``excitation_topic``: one message per sample, one joint per
surface, named after the joint of the channel's input field (``position[elevator]`` -> ``elevator``; an input
without a joint name: the channel's name), the flying surface's offset and zero for the others. With
``std_msgs/msg/Float64`` each channel has ``<excitation_topic>/<channel>`` (a Float64 carries one number).
Values are surface offsets from trim in rad (the card's unit), for the flight stack to add to its surface
commands.

The node's own publication is each channel's ``excitation`` (closed-loop estimation): :func:`with_injection`
adds ``channels.<channel>.excitation`` on that topic and field to the config the node runs, so the samples
arrive through the node's subscription, the decoding step and the router like any configured stream
(docs/PLAN.md says why). A channel whose config already has an ``excitation`` keeps it (the flight stack logs
what it injected).

Samples
-------
:class:`Player`: a sample grid at ``excitation_rate_hz`` on the node clock, from the first tick on, published
whether a manoeuvre flies or not (zeros between manoeuvres: the estimator's excitation stream stays
continuous, and the flight stack can watch it). Sample ``n`` is stamped ``t0 + n / rate``; a tick publishes
every sample due (a late tick catches up, so the stream holds exactly the card's samples at their times),
unless more than
:data:`MAX_CATCH_UP_S` are due (a stalled node or a jump of ``/clock``): then it starts the grid afresh and a
running manoeuvre is aborted. A manoeuvre flies :func:`~gap_validation.core.plan.manoeuvre_signal` sample by
sample from the next sample of the grid, every sample clipped to the amplitude cap; after it, zeros.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from gap_validation.core.config import SignalSpec, ValidationConfig
from gap_validation.core.errors import ConfigError
from gap_validation.core.fields import FieldPath
from gap_validation.core.plan import PlannedManoeuvre, TestCard, manoeuvre_signal
from gap_validation.ros.parameters import EXCITATION_TYPES, FLOAT64, JOINT_STATE

__all__ = [
    "InjectionPoint",
    "injection_points",
    "with_injection",
    "Player",
    "Flight",
    "Sample",
    "select_manoeuvre",
    "JOINT_STATE",
    "FLOAT64",
    "EXCITATION_TYPES",
    "MAX_CATCH_UP_S",
]

#: Most samples' worth of time a tick publishes at once [s]: the estimator's ``max_gap_s`` (a longer silence
#: breaks its data anyway); beyond, the grid starts afresh and a running manoeuvre is aborted.
MAX_CATCH_UP_S = 0.5


@dataclass(frozen=True)
class InjectionPoint:
    """Where one channel's offset is published.

    Attributes
    ----------
    channel : str
        The channel.
    topic : str
        The topic (absolute).
    joint : str or None
        The JointState joint; None for a Float64 topic of its own.
    spec : SignalSpec
        The ``excitation`` stream reading it back.
    estimated : bool
        Whether the channel estimates against it (False: the config names its own ``excitation``).
    """

    channel: str
    topic: str
    joint: str | None
    spec: SignalSpec
    estimated: bool = True


def injection_points(config: ValidationConfig, topic: str, type_name: str) -> dict[str, InjectionPoint]:
    """Channel -> its injection point, for every SISO channel with an input, in config order.

    Parameters
    ----------
    config : ValidationConfig
        The config (as loaded: without the node's excitation).
    topic : str
        ``excitation_topic``, resolved (absolute).
    type_name : str
        ``excitation_type`` (:data:`EXCITATION_TYPES`).
    """
    if type_name not in EXCITATION_TYPES:
        raise ConfigError(f"parameter excitation_type: expected one of {', '.join(EXCITATION_TYPES)}, "
                          f"got {type_name!r}")
    points: dict[str, InjectionPoint] = {}
    for name, ch in config.channels.items():
        if ch.is_mimo or ch.input is None:
            continue
        if type_name == JOINT_STATE:
            joint = FieldPath.parse(ch.input.field).key or name
            spec = SignalSpec(topic, f"position[{joint}]", 1.0, type=JOINT_STATE)
            points[name] = InjectionPoint(name, topic, joint, spec, ch.excitation is None)
        else:
            where = f"{topic.rstrip('/')}/{name}"
            points[name] = InjectionPoint(name, where, None, SignalSpec(where, "data", 1.0, type=FLOAT64),
                                          ch.excitation is None)
    return points


def with_injection(config: ValidationConfig, points: dict[str, InjectionPoint]) -> ValidationConfig:
    """The config with each injection point as its channel's ``excitation`` (channels with their own keep it).

    Parameters
    ----------
    config : ValidationConfig
        The config as loaded.
    points : dict
        :func:`injection_points`.
    """
    channels = {name: replace(ch, excitation=points[name].spec) if name in points and points[name].estimated
                else ch for name, ch in config.channels.items()}
    return replace(config, channels=channels)


def select_manoeuvre(card: TestCard | None, channel: str, index: int, flown: set[int],
                     points: dict[str, InjectionPoint]) -> PlannedManoeuvre:
    """The manoeuvre ``~/excite`` flies, or a one-line :class:`ConfigError` saying why none.

    Parameters
    ----------
    card : TestCard or None
        The current card.
    channel : str
        ``excite_channel`` ("" = any).
    index : int
        ``excite_index``: the card's manoeuvre of that index; -1: the first in flying order not flown to its
        end yet (of ``channel`` when given).
    flown : set of int
        Indices flown to their end on this card.
    points : dict
        The injection points (the channels the node can fly).
    """
    if card is None:
        raise ConfigError("no card yet: call ~/plan, or set the parameter plan_card to a card file")
    manoeuvres = card.manoeuvres
    if channel and channel not in card.channels:
        raise ConfigError(f"excite_channel {channel!r}: not a channel of the card (channels: "
                          f"{', '.join(card.channels)})")
    if index >= 0:
        chosen = next((m for m in manoeuvres if m.index == index), None)
        if chosen is None:
            raise ConfigError(f"excite_index {index}: no such manoeuvre in the card (indices: "
                              f"{', '.join(str(m.index) for m in manoeuvres) or 'none'})")
        if channel and chosen.channel != channel:
            raise ConfigError(f"excite_index {index} is {chosen.channel}'s manoeuvre, not {channel}'s "
                              f"(set excite_channel to '' or {chosen.channel!r})")
    else:
        mine = [m for m in manoeuvres if not channel or m.channel == channel]
        chosen = next((m for m in mine if m.index not in flown), None)
        if chosen is None:
            whose = f"{channel}'s manoeuvres" if channel else "the card's manoeuvres"
            raise ConfigError(
                f"every one of {whose} has been flown ({len(mine)}); set excite_index to fly one again"
                if mine
                else f"the card has no manoeuvre{' for ' + channel if channel else ''}"
            )
    if chosen.channel not in points:
        raise ConfigError(
            f"manoeuvre {chosen.index}: channel {chosen.channel!r} cannot be flown by the node (not a "
            f"SISO channel with an input in the config)"
        )
    return chosen


@dataclass(frozen=True)
class Sample:
    """One published sample: its stamp [ns, node clock] and the offset [rad] of the flying channel (0:
    none)."""

    stamp_ns: int
    channel: str | None
    value: float


@dataclass
class Flight:
    """A manoeuvre being flown (or flown): its samples and where it stands on the player's grid.

    Attributes
    ----------
    manoeuvre : PlannedManoeuvre
        What flies.
    samples : ndarray
        :func:`~gap_validation.core.plan.manoeuvre_signal` at ``rate_hz`` [rad].
    rate_hz : float
        The player's rate [Hz].
    start_n : int
        Grid index of its first sample.
    start_stamp_ns : int
        Stamp of its first sample [ns].
    sent : int
        Samples published so far.
    state : str
        ``flying``, ``done`` or ``aborted``.
    why : str
        Why it was aborted.
    """

    manoeuvre: PlannedManoeuvre
    samples: np.ndarray
    rate_hz: float
    start_n: int
    start_stamp_ns: int
    sent: int = 0
    state: str = "flying"
    why: str = ""

    @property
    def duration_s(self) -> float:
        """Its length at the player's rate [s] (``samples.size / rate_hz``)."""
        return self.samples.size / self.rate_hz

    def text(self) -> str:
        """``pitch #0 12.3/60.0 s``, ``pitch #0 done (60.0 s)``, ``pitch #0 aborted at 12.3/60.0 s (why)``."""
        m = self.manoeuvre
        at = f"{self.sent / self.rate_hz:.1f}/{self.duration_s:.1f} s"
        if self.state == "flying":
            return f"{m.channel} #{m.index} {at}"
        if self.state == "done":
            return f"{m.channel} #{m.index} done ({self.duration_s:.1f} s)"
        return f"{m.channel} #{m.index} aborted at {at}" + (f" ({self.why})" if self.why else "")


class Player:
    """The sample grid and the manoeuvre on it (see the module docstring).

    Parameters
    ----------
    rate_hz : float
        ``excitation_rate_hz``.

    Attributes
    ----------
    flight : Flight or None
        The manoeuvre flying, or the last one flown (``state`` says which).
    t0_ns : int or None
        Stamp of grid sample 0 (set by the first tick).
    next_n : int
        The next grid sample to publish.
    """

    def __init__(self, rate_hz: float):
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ConfigError(f"parameter excitation_rate_hz: expected a rate > 0 Hz, got {rate_hz!r}")
        self.rate_hz = float(rate_hz)
        self.flight: Flight | None = None
        self.t0_ns: int | None = None
        self.next_n = 0

    @property
    def flying(self) -> Flight | None:
        """The manoeuvre in flight, if any."""
        return self.flight if self.flight is not None and self.flight.state == "flying" else None

    def stamp_ns(self, n: int) -> int:
        """Stamp of grid sample ``n`` [ns] (after the first tick).

        Parameters
        ----------
        n : int
            Grid index.
        """
        return int(self.t0_ns) + int(round(n * 1e9 / self.rate_hz))

    def start(self, manoeuvre: PlannedManoeuvre, now_ns: int) -> Flight:
        """Fly ``manoeuvre`` from the next sample of the grid (the grid starts at ``now_ns`` when it has not
        yet).

        Parameters
        ----------
        manoeuvre : PlannedManoeuvre
            The card's manoeuvre.
        now_ns : int
            Node time [ns].
        """
        if self.t0_ns is None:
            self.t0_ns, self.next_n = int(now_ns), 0
        _, u = manoeuvre_signal(manoeuvre, self.rate_hz)
        self.flight = Flight(manoeuvre, u, self.rate_hz, self.next_n, self.stamp_ns(self.next_n))
        return self.flight

    def abort(self, why: str = "") -> Flight | None:
        """Stop the manoeuvre in flight at once (the next sample is zero); the flight, or None when none
        flies.

        Parameters
        ----------
        why : str
            Why (shown in its status).
        """
        flight = self.flying
        if flight is not None:
            flight.state, flight.why = "aborted", why
        return flight

    def due(self, now_ns: int, cap_rad: float) -> list[Sample]:
        """The samples due at ``now_ns`` (stamp at or before it), each clipped to ``+-cap_rad``; advances the
        grid.

        Parameters
        ----------
        now_ns : int
            Node time [ns].
        cap_rad : float
            ``excitation_max_amplitude_rad``.
        """
        now_ns = int(now_ns)
        if self.t0_ns is None:
            self.t0_ns, self.next_n = now_ns, 0
        # time went back (/clock restarted)
        elif self.next_n > 0 and now_ns < self.stamp_ns(self.next_n - 1):
            self.abort("the node clock went back")
            self.t0_ns, self.next_n = now_ns, 0
        last = int(math.floor((now_ns - self.t0_ns) * self.rate_hz / 1e9 + 1e-9))
        # stalled or /clock jumped ahead
        if last - self.next_n + 1 > MAX_CATCH_UP_S * self.rate_hz:
            self.abort(f"more than {MAX_CATCH_UP_S:g} s of samples were late")
            self.t0_ns, self.next_n, last = now_ns, 0, 0
        out = []
        flight = self.flying
        for n in range(self.next_n, last + 1):
            value, channel = 0.0, None
            if flight is not None and flight.state == "flying":
                k = n - flight.start_n
                if 0 <= k < flight.samples.size:
                    value, channel = (
                        float(np.clip(flight.samples[k], -cap_rad, cap_rad)),
                        flight.manoeuvre.channel,
                    )
                    flight.sent = k + 1
                if flight.sent >= flight.samples.size:
                    flight.state = "done"
            out.append(Sample(self.stamp_ns(n), channel, value))
        self.next_n = max(self.next_n, last + 1)
        return out

    def status(self, channel: str) -> str:
        """``excitation_manoeuvre`` of ``channel``'s status: its flight (flying, done, aborted), else
        ``none``.

        Parameters
        ----------
        channel : str
            The channel.
        """
        flight = self.flight
        if flight is None or flight.manoeuvre.channel != channel:
            return "none"
        return flight.text()
