"""The test card of :mod:`gap_validation.core.simulation` as public functions, for simulators other than the linear
one (e.g. :mod:`gap_validation.jsbsim`): the manoeuvres and their times, each channel's surface deviation from
trim, the pilot's re-trims, the narrow-band output noise and the sampling of the topics.

Thin wrappers: the code is :mod:`~gap_validation.core.simulation`'s own, so another simulator flies exactly the
card the synthetic flight flies (same segments, same sweeps, same rates, jitter and drops).
"""
from __future__ import annotations

import numpy as np

from gap_validation.core import simulation as _sim
from gap_validation.core.config import ValidationConfig
from gap_validation.core.simulation import FlightOptions, Segment, TopicSeries

__all__ = ["card_segments", "card_units", "channel_deviation", "pilot_trim", "band_noises", "sample_topics"]


def card_segments(config: ValidationConfig, options: FlightOptions) -> tuple[list[Segment], float]:
    """The manoeuvres of the flight in time order and the flight's length [s].

    Parameters
    ----------
    config : ValidationConfig
        The channels flown (config order; a MIMO channel's inputs one after the other) and their grids (sweep bands).
    options : FlightOptions
        The card: excitation, rounds, sweep lengths, gaps, ``duration_s``.
    """
    return _sim._test_card(config, options)


def card_units(config: ValidationConfig) -> list[tuple[str, int | None]]:
    """What the card excites in turn: ``(channel, None)`` per SISO channel, ``(channel, j)`` per MIMO input.

    Parameters
    ----------
    config : ValidationConfig
        The config.
    """
    return _sim._card_units(config)


def channel_deviation(name: str, t_s: np.ndarray, segments: list[Segment], options: FlightOptions,
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
    options : FlightOptions
        Amplitudes and manoeuvre shapes.
    channels : tuple of str
        The config's channels (the orthogonal multisine's share).
    input_index : int, optional
        A MIMO channel's input (None: SISO).
    share : (int, int), optional
        ``(index, count)`` of the orthogonal multisine (default: the channel's place in ``channels``).
    """
    return _sim._channel_input(name, t_s, segments, options, channels, input_index, share)


def pilot_trim(t_s: np.ndarray, segments: list[Segment], duration_s: float, options: FlightOptions,
               rng: np.random.Generator) -> np.ndarray:
    """One surface's trim [rad]: a random constant (``trim_offset_rad``) plus the pilot's slow re-trims in the gaps.

    Parameters
    ----------
    t_s : ndarray
        Times from the flight start [s].
    segments : list of Segment
        The manoeuvres (re-trims happen between them).
    duration_s : float
        Flight length [s].
    options : FlightOptions
        ``trim_offset_rad`` and ``trim_step_rad``.
    rng : numpy.random.Generator
        The flight's random stream.
    """
    return _sim._pilot_trim(t_s, segments, duration_s, options, rng)


def band_noises(config: ValidationConfig, n: int, fs_hz: float, options: FlightOptions, seed: int) -> dict:
    """Channel -> narrow-band output disturbance on a uniform grid (empty unless ``band_noise_rad_s`` is set).

    Parameters
    ----------
    config : ValidationConfig
        The channels.
    n : int
        Samples.
    fs_hz : float
        Rate of the grid [Hz].
    options : FlightOptions
        ``band_noise_*`` options.
    seed : int
        The flight's seed (the band noise has its own stream of it).
    """
    return _sim._band_noises(config, n, fs_hz, options, seed)


def sample_topics(plans: dict, measured: dict, t_s: np.ndarray, duration_s: float, options: FlightOptions,
                  rng: np.random.Generator) -> dict[str, TopicSeries]:
    """Topic -> :class:`TopicSeries`: each topic of ``plans`` sampled at its rate with jitter, drops and latency.

    Parameters
    ----------
    plans : dict
        From :func:`gap_validation.core.simulation.plan_topics`.
    measured : dict
        ``(channel, stream) -> (series on t_s, noise std, lsb)``: the physical quantity (SI units), the white
        sensor noise added at each sample and the quantisation step (0: none).
    t_s : ndarray
        The series' time grid from the flight start [s].
    duration_s : float
        Flight length [s].
    options : FlightOptions
        Rates, jitter, drops, latency, start time.
    rng : numpy.random.Generator
        The flight's random stream.
    """
    return _sim._sample_topics(plans, measured, t_s, duration_s, options, rng)
