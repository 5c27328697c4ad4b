"""The test card of a synthetic flight, ROS-free: the manoeuvres in time order (:func:`card_segments`), the
surface deflections they command (:func:`channel_deviation`) and the pilot's trims (:func:`pilot_trim`).
Other simulators (:mod:`gap_validation.jsbsim.flight`) fly the same card.

The card follows the paper's test card (Section V): frequency sweeps per axis (roll, pitch, yaw in turn,
several rounds), a doublet after each sweep, pilot re-trims between manoeuvres (a MIMO channel's inputs are
flown one after the other). Instead of sweeps it can fly multisines (one channel at a time, or every channel
at once on interleaved harmonics), 3-2-1-1 multisteps or doublets alone
(:data:`~gap_validation.core.flight_options.EXCITATIONS`); the waveforms are those of
:mod:`gap_validation.core.signals`.

By default a sweep lasts 120 s and runs from half the channel's lowest grid frequency to 1.3 times its
highest: the estimator's analysis windows are anchored at the sweep start and last up to 20 s, so the grid's
lowest frequencies need the sweep to pass them well inside the first windows (a sweep that starts *at* the
lowest grid frequency biases the estimate there, most visibly near the lightly damped yaw zeros of the Ultra
Stick).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from gap_validation.core.config import ValidationConfig
from gap_validation.core.flight_options import FlightOptions
from gap_validation.core.signals import log_sweep, multisine, multistep

__all__ = ["Segment", "SWEEP_SEGMENTS", "card_units", "card_segments", "channel_deviation", "pilot_trim"]

#: Segment kinds that are identification manoeuvres (sweeps); ``doublet`` segments after them are checks.
SWEEP_SEGMENTS = ("sweep", "multisine", "multisine-orthogonal", "3211")


@dataclass(frozen=True)
class Segment:
    """One manoeuvre of the test card; times from the flight start [s].

    ``kind`` is ``sweep`` (log chirp), ``multisine``, ``multisine-orthogonal`` (one segment per channel, same
    times), ``3211`` or ``doublet``. On a MIMO channel each input is flown in turn: ``input_index`` says
    which.
    """

    channel: str
    kind: str
    start_s: float
    end_s: float
    band_rad_s: tuple[float, float] | None = None
    input_index: int | None = None         # a MIMO channel's input this manoeuvre excites (None: SISO)


def card_units(config: ValidationConfig) -> list[tuple[str, int | None]]:
    """What the card excites in turn: ``(channel, None)`` per SISO channel, ``(channel, j)`` per MIMO input.

    Parameters
    ----------
    config : ValidationConfig
        The config.
    """
    return [(name, j) for name, ch in config.channels.items()
            for j in (range(len(ch.inputs)) if ch.is_mimo else (None,))]


def card_segments(config: ValidationConfig, opt: FlightOptions) -> tuple[list[Segment], float]:
    """The manoeuvres of the flight in time order and the flight's length [s].

    Parameters
    ----------
    config : ValidationConfig
        The channels flown (config order; a MIMO channel's inputs one after the other) and their grids (sweep
        bands).
    opt : FlightOptions
        The card: excitation, rounds, sweep lengths, gaps, ``duration_s``.
    """
    segments: list[Segment] = []
    units = card_units(config)
    t = opt.quiet_s if opt.trim_s is None else opt.trim_s
    doublet_s = 2 * opt.doublet_half_period_s
    for _ in range(opt.sweeps_per_channel):
        bands = {
            name: (
                ch.frequencies.min_rad_s * opt.band_low_factor,
                ch.frequencies.max_rad_s * opt.band_high_factor,
            )
            for name, ch in config.channels.items()
        }
        if opt.excitation == "multisine-orthogonal":
            length = opt.multisine_period_s * opt.multisine_periods
            segments += [
                Segment(name, "multisine-orthogonal", t, t + length, bands[name], j) for name, j in units
            ]
            t += length + opt.quiet_s
            continue
        for name, j in units:
            if opt.excitation == "doublet":
                segments.append(Segment(name, "doublet", t, t + doublet_s, None, j))
                t += doublet_s + opt.quiet_s
                continue
            kind, length = {"chirp": ("sweep", opt.sweep_duration_s),
                            "multisine": ("multisine", opt.multisine_period_s * opt.multisine_periods),
                            "3211": ("3211", 7.0 * opt.multistep_unit_s)}[opt.excitation]
            segments.append(Segment(name, kind, t, t + length, bands[name], j))
            t += length + opt.quiet_s
            if opt.excitation in ("chirp", "multisine"):
                segments.append(Segment(name, "doublet", t, t + doublet_s, None, j))
                t += doublet_s + opt.quiet_s
    if opt.duration_s is not None:
        segments = [seg for seg in segments if seg.start_s < opt.duration_s]
        return segments, float(opt.duration_s)
    return segments, t + opt.quiet_s


def channel_deviation(name: str, t_s: np.ndarray, segments: list[Segment], opt: FlightOptions,
                   channels: tuple[str, ...] = (), input_index: int | None = None,
                   share: tuple[int, int] | None = None) -> np.ndarray:
    """The surface deflection deviation from trim the card commands on one channel (or one MIMO input) [rad].

    Parameters
    ----------
    name : str
        The channel.
    t_s : ndarray
        Times from the flight start [s].
    segments : list of Segment
        From :func:`card_segments`.
    opt : FlightOptions
        Amplitudes and manoeuvre shapes.
    channels : tuple of str
        The config's channels (the orthogonal multisine's share).
    input_index : int, optional
        A MIMO channel's input (None: SISO).
    share : (int, int), optional
        ``(index, count)`` of the orthogonal multisine (default: the channel's place in ``channels``).
    """
    u = np.zeros_like(t_s)
    card, rounds = opt, 0
    for seg in segments:
        if seg.channel != name or seg.input_index != input_index:
            continue
        opt = card
        if seg.kind in SWEEP_SEGMENTS:
            opt, rounds = _round_options(card, rounds), rounds + 1
        tau, length = t_s - seg.start_s, seg.end_s - seg.start_s
        if seg.kind == "sweep":
            w0, w1 = seg.band_rad_s
            u += opt.sweep_amplitude_rad * log_sweep(tau, length, w0, w1, dwell_cycles=opt.dwell_cycles)
        elif seg.kind in ("multisine", "multisine-orthogonal"):
            share = (share or (channels.index(name), len(channels))) if seg.kind == "multisine-orthogonal" \
                else (0, 1)
            u += opt.sweep_amplitude_rad * multisine(tau, opt.multisine_period_s, opt.multisine_periods,
                                                     *seg.band_rad_s, share=share)
        elif seg.kind == "3211":
            u += opt.doublet_amplitude_rad * multistep(
                tau, opt.multistep_unit_s, (3, 2, 1, 1), opt.step_rise_s
            )
        else:
            u += opt.doublet_amplitude_rad * multistep(
                tau, opt.doublet_half_period_s, (1, 1), opt.step_rise_s
            )
    return u


def _round_options(opt: FlightOptions, round_index: int) -> FlightOptions:
    """The options of round ``round_index`` of the test card: its sweep and multistep amplitudes scaled by
    ``sweep_amplitude_scales`` (unchanged when it is None)."""
    scales = opt.sweep_amplitude_scales
    if not scales:
        return opt
    scale = float(scales[round_index % len(scales)])
    return replace(opt, sweep_amplitude_rad=opt.sweep_amplitude_rad * scale,
                   doublet_amplitude_rad=opt.doublet_amplitude_rad * scale)


def pilot_trim(t_s: np.ndarray, segments: list[Segment], duration_s: float, opt: FlightOptions,
                rng: np.random.Generator) -> np.ndarray:
    """One surface's trim [rad]: a random constant (``trim_offset_rad``) plus the pilot's slow re-trims in the
    gaps.

    In about half of the quiet gaps between manoeuvres the pilot ramps the trim (over 1-3 s) by
    ``trim_step_rad`` up or down (a bounded random walk). A re-trim moves the equilibrium the linear model is
    taken about, so it appears in the surface measurement but not in the model's input (an airframe-only
    model with a spiral mode would otherwise drift for minutes after every trim change).

    Parameters
    ----------
    t_s : ndarray
        Times from the flight start [s].
    segments : list of Segment
        The manoeuvres (re-trims happen between them).
    duration_s : float
        Flight length [s].
    opt : FlightOptions
        ``trim_offset_rad`` and ``trim_step_rad``.
    rng : numpy.random.Generator
        The flight's random stream.
    """
    out = np.full_like(t_s, float(rng.uniform(-1.0, 1.0)) * opt.trim_offset_rad)
    edges = [0.0] + [x for seg in segments for x in (seg.start_s, seg.end_s)] + [duration_s]
    level = 0.0
    for start, end in zip(edges[0::2], edges[1::2]):
        ramp = float(rng.uniform(1.0, 3.0))
        go = rng.random() < 0.5
        target = float(np.clip(level + rng.choice([-1.0, 1.0]) * opt.trim_step_rad,
                               -3 * opt.trim_step_rad, 3 * opt.trim_step_rad))
        if not go or end - start < ramp + 2.0:
            continue
        t0 = start + 1.0
        out += (target - level) * np.clip((t_s - t0) / ramp, 0.0, 1.0)
        level = target
    return out
