"""The mistakes every user makes, named as such (issue 23): a sign, units, the body frame, a clock.

The first flight a team validates usually fails for a reason that is not physics: a surface whose positive
direction is the other way round, positions logged in degrees where the config says radians, an IMU in ROS's
body frame (REP 103: x forward, y left, z up) against a model in the aircraft's (x forward, y right, z down),
two topics stamped by different clocks. Each makes the measured response the model's times a *convention
factor*:

=================  =====================================  ====================================================
kind               the data are the model times           what it is
=================  =====================================  ====================================================
``sign``           -1                                     a surface (or a rate) reversed
``units``          1/57.2958, 57.2958 or 10^k (either     surfaces (or rates) in degrees, or in another decade
                   sign)                                  of units than the config says
``body_frame``     -1 on pitch and yaw, +1 on roll        the IMU is FLU (ROS), the model FRD (across
                                                          channels)
``clock_offset``   exp(+j w T), T > 0 (a lead)            the input stamped late (or the output early): a
                                                          lead is never the physics of a causal airframe
=================  =====================================  ====================================================

:func:`candidates` lists them for one channel; the diagnosis
(:func:`gap_validation.core.diagnosis.analyse_channel`) accepts one only where the model times it leaves the
data within their random error, like any candidate, and a channel with one gets no physical
diagnosis. :func:`resolve` looks across the channels (pitch and yaw reversed with roll right is the body
frame) and words the fix: the config change that makes the data the model's (:class:`Convention`, the JSON
``conventions``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from gap_validation.core import wording
from gap_validation.core.results import Convention

__all__ = [
    "Convention",
    "ConventionFit",
    "candidates",
    "fit_clock",
    "clock",
    "resolve",
    "with_stream_changes",
    "KINDS",
    "DEGREES",
]

#: The kinds the JSON ``conventions`` holds.
KINDS = ("sign", "units", "body_frame", "clock_offset")
#: Degrees per radian.
DEGREES = 180.0 / math.pi
#: Decades of units tried (a factor 10^k, k = +-1 .. +-3: centidegrees, milliradians ...).
DECADES = (1, 2, 3)
#: Longest clock offset looked for [s] (stamps of different clocks within half a second).
MAX_OFFSET_S = 0.5


@dataclass(frozen=True)
class ConventionFit:
    """A convention factor for one channel: its kind, factor or lead, and its response multiplier."""

    kind: str
    factor: float = 1.0
    seconds: float = 0.0

    def response(self, w_rad_s: np.ndarray) -> np.ndarray:
        """The factor the data are the model times, at ``w_rad_s``.

        Parameters
        ----------
        w_rad_s : ndarray
            Frequencies [rad/s].
        """
        w = np.asarray(w_rad_s, float)
        return self.factor * np.exp(1j * w * self.seconds)


def candidates() -> list[ConventionFit]:
    """The constant factors to try on a channel: the sign, degrees (either way, either sign) and decades of
    units (either way, either sign). The clock offset is fitted (:meth:`fit_clock`), not listed."""
    out = [ConventionFit("sign", -1.0)]
    for sign in (1.0, -1.0):
        out += [ConventionFit("units", sign / DEGREES), ConventionFit("units", sign * DEGREES)]
        for k in DECADES:
            out += [ConventionFit("units", sign * 10.0 ** -k), ConventionFit("units", sign * 10.0 ** k)]
    return out


def fit_clock(w_rad_s: np.ndarray, ratio: np.ndarray, weight: np.ndarray) -> float:
    """The lead ``T`` whose ``exp(+j w T)`` best matches a measured-over-model ratio (weighted least squares
    on the complex ratio, over a grid of ``T`` in (0, :data:`MAX_OFFSET_S`] refined about its best point); 0
    when none.

    Parameters
    ----------
    w_rad_s : ndarray
        Frequencies [rad/s].
    ratio : ndarray
        Measured response over the model's.
    weight : ndarray
        Weight per frequency (inverse variance).
    """
    w = np.asarray(w_rad_s, float)
    ratio = np.asarray(ratio, complex)
    weight = np.asarray(weight, float)
    if w.size < 3 or not np.any(weight > 0):
        return 0.0
    step = math.pi / (8.0 * float(np.max(w)))                 # an eighth of a turn at the top frequency
    grid = np.arange(step, MAX_OFFSET_S + step, step)
    cost = np.array([np.sum(weight * np.abs(ratio - np.exp(1j * w * t)) ** 2) for t in grid])
    best = int(np.argmin(cost))
    lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, grid.size - 1)]
    fine = np.linspace(lo, hi, 41)
    cost = np.array([np.sum(weight * np.abs(ratio - np.exp(1j * w * t)) ** 2) for t in fine])
    return float(fine[int(np.argmin(cost))])


def _fmt(value: float) -> str:
    return f"{value:.6g}"


def _stream_words(channel: str, stream: str) -> str:
    return f"channels.{channel}.{stream}"


def _single(channel: str, fit: ConventionFit, spec_of: Callable[[str, str], object]) -> Convention:
    """A convention found on one channel alone, worded with the stream it most likely belongs to."""
    if fit.kind == "clock_offset":
        spec = spec_of(channel, "input")
        new = float(getattr(spec, "time_offset_s", 0.0)) - fit.seconds
        where = f"{spec.topic}" if spec is not None else "the input"
        fix = f"add time_offset_s: {_fmt(new)} to {_stream_words(channel, 'input')}"
        return Convention(
            "clock_offset",
            seconds=fit.seconds,
            stream="input",
            fix=fix,
            sentence=wording.clock_sentence(fit.seconds, f"the surface topic ({where})", fix),
            changes=[{"channel": channel, "stream": "input", "key": "time_offset_s", "value": new}],
        )
    if fit.kind == "sign":
        spec = spec_of(channel, "input")
        new = -float(getattr(spec, "scale", 1.0))
        fix = f"add scale: {_fmt(new)} to {_stream_words(channel, 'input')}"
        return Convention(
            "sign",
            factor=-1.0,
            stream="input",
            fix=fix,
            sentence=wording.sign_sentence(fix),
            changes=[{"channel": channel, "stream": "input", "key": "scale", "value": new}],
        )
    # units: data = model x factor; a factor below one is an input read too large (surfaces in degrees), above
    # one an output read too large (rates in deg/s)
    stream = "input" if abs(fit.factor) < 1.0 else "output"
    spec = spec_of(channel, stream)
    correction = fit.factor if stream == "input" else 1.0 / fit.factor
    new = float(getattr(spec, "scale", 1.0)) * correction
    unit = (
        "degrees"
        if math.isclose(abs(fit.factor), 1.0 / DEGREES, rel_tol=1e-6)
        or math.isclose(abs(fit.factor), DEGREES, rel_tol=1e-6)
        else f"units {1.0 / abs(correction):g} times too small"
    )
    fix = f"add scale: {_fmt(new)} to {_stream_words(channel, stream)}"
    return Convention("units", factor=fit.factor, stream=stream, fix=fix,
                      sentence=wording.units_sentence(fit.factor, wording.units_words(stream, unit), fix),
                      changes=[{"channel": channel, "stream": stream, "key": "scale", "value": new}])


def resolve(found: dict[str, ConventionFit], spec_of: Callable[[str, str], object],
            fitting: set[str] | None = None) -> dict[str, list[Convention]]:
    """The conventions of every channel, looked at together, with their fixes.

    Pitch and yaw reversed with roll right (fitting, or not reversed) is the body frame: the IMU is FLU (ROS),
    the model FRD, and ``frame: flu`` on their outputs fixes both. Roll, pitch and yaw all reversed is a
    reversed IMU mounting (or every surface reversed): ``scale`` on the three outputs. Anything else is worded
    per channel.

    Parameters
    ----------
    found : dict
        Channel -> the convention factor its data showed.
    spec_of : callable
        ``spec_of(channel, stream) -> SignalSpec`` (None where the channel has no such stream).
    fitting : set of str, optional
        Channels whose data fit the model as it is (no convention needed).
    """
    fitting = fitting or set()
    signs = {ch for ch, fit in found.items() if fit.kind == "sign"}
    out: dict[str, list[Convention]] = {}
    axes = {ch: getattr(spec_of(ch, "output"), "field", "").rsplit(".", 1)[-1] for ch in found}
    yz = {ch for ch in signs if axes[ch] in ("y", "z")}
    others = {ch for ch in found if ch not in signs} | fitting
    if yz and {"y", "z"} <= {axes[ch] for ch in yz} and any(
            getattr(spec_of(ch, "output"), "field", "").endswith(".x") for ch in others):
        # the frame the config gives those outputs is the wrong one: FRD where the IMU is FLU, or the other
        # way
        said = {getattr(spec_of(ch, "output"), "frame", None) or "frd" for ch in yz}
        frame = "frd" if said == {"flu"} else "flu"
        imu, model = (
            ("FLU (ROS REP 103)", "FRD")
            if frame == "flu"
            else ("FRD", "FRD too (the config's frame: flu is wrong)")
        )
        fix = f"add frame: {frame} to " + " and ".join(_stream_words(ch, "output") for ch in sorted(yz))
        for ch in yz:
            spec = spec_of(ch, "output")
            out[ch] = [
                Convention(
                    "body_frame",
                    factor=-1.0,
                    stream="output",
                    fix=fix,
                    sentence=wording.body_frame_sentence(spec.topic, imu, model, fix),
                    changes=[
                        {"channel": c, "stream": "output", "key": "frame", "value": frame} for c in sorted(yz)
                    ],
                )
            ]
        signs -= yz
    if len(signs) >= 3 and {axes[ch] for ch in signs} >= {"x", "y", "z"}:
        fix = "add scale: -1 to " + " and ".join(_stream_words(ch, "output") for ch in sorted(signs))
        for ch in signs:
            spec = spec_of(ch, "output")
            out[ch] = [
                Convention(
                    "sign",
                    factor=-1.0,
                    stream="output",
                    fix=fix,
                    sentence=wording.reversed_imu_sentence(spec.topic, fix),
                    changes=[
                        {
                            "channel": c,
                            "stream": "output",
                            "key": "scale",
                            "value": -float(getattr(spec_of(c, "output"), "scale", 1.0)),
                        }
                        for c in sorted(signs)
                    ],
                )
            ]
        signs = set()
    _shared(found, out, spec_of)
    for ch, fit in found.items():
        if ch not in out:
            out[ch] = [_single(ch, fit, spec_of)]
    return out


def _shared(found: dict[str, ConventionFit], out: dict[str, list[Convention]],
            spec_of: Callable[[str, str], object]) -> None:
    """Units or a clock offset shown alike by every channel whose stream comes from one topic: the topic is
    the culprit; one sentence and one fix for all of them (the clock's lead averaged over the channels)."""
    groups: dict[tuple, list[str]] = {}
    for ch, fit in found.items():
        if ch in out or fit.kind not in ("units", "clock_offset"):
            continue
        stream = "input" if fit.kind == "clock_offset" or abs(fit.factor) < 1.0 else "output"
        spec = spec_of(ch, stream)
        key = (
            fit.kind,
            stream,
            getattr(spec, "topic", None),
            round(fit.factor, 9) if fit.kind == "units" else 0.0,
        )
        groups.setdefault(key, []).append(ch)
    for (kind, stream, topic, _), members in groups.items():
        if len(members) < 2:
            continue
        members = sorted(members)
        if kind == "clock_offset":
            lead = float(np.mean([found[ch].seconds for ch in members]))
            changes = [
                {
                    "channel": ch,
                    "stream": stream,
                    "key": "time_offset_s",
                    "value": float(getattr(spec_of(ch, stream), "time_offset_s", 0.0)) - lead,
                }
                for ch in members
            ]
            fix = "add " + ", ".join(
                f"time_offset_s: {_fmt(c['value'])} to {_stream_words(c['channel'], stream)}" for c in changes
            )
            sentence = wording.clock_sentence(lead, str(topic), fix, members)
            conv = Convention(
                "clock_offset", seconds=lead, stream=stream, fix=fix, sentence=sentence, changes=changes
            )
        else:
            factor = found[members[0]].factor
            correction = factor if stream == "input" else 1.0 / factor
            changes = [
                {
                    "channel": ch,
                    "stream": stream,
                    "key": "scale",
                    "value": float(getattr(spec_of(ch, stream), "scale", 1.0)) * correction,
                }
                for ch in members
            ]
            fix = "add " + ", ".join(f"scale: {_fmt(c['value'])} to {_stream_words(c['channel'], stream)}"
                                     for c in changes)
            single = _single(members[0], found[members[0]], spec_of)
            what = single.sentence.split(": ", 1)[1].rsplit("; add", 1)[0]
            sentence = wording.units_sentence(factor, what, fix, members, str(topic))
            conv = Convention(
                "units", factor=factor, stream=stream, fix=fix, sentence=sentence, changes=changes
            )
        for ch in members:
            out[ch] = [conv]


def with_stream_changes(raw: dict, conventions: list[Convention]) -> dict:
    """``raw`` (a config mapping, changed in place and returned) with the conventions' changes written into
    the streams they name.

    Parameters
    ----------
    raw : dict
        A config mapping (``channels``).
    conventions : list of Convention
        The conventions to fix.
    """
    for convention in conventions:
        for change in convention.changes:
            stream = raw["channels"][change["channel"]][change["stream"]]
            stream[change["key"]] = change["value"]
    return raw


def clock(seconds: float) -> ConventionFit:
    """The clock-offset factor of a lead of ``seconds``.

    Parameters
    ----------
    seconds : float
        How far the output leads the input [s].
    """
    return ConventionFit("clock_offset", 1.0, float(seconds))
