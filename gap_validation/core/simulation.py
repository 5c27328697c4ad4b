"""Synthetic flights: time histories of a sweep flight, ROS-free (arrays only;
:mod:`gap_validation.bag.writer` writes them as a rosbag2).

The "true aircraft" of each channel is the config's model (with its effects) with *hidden* effects in series
(:meth:`LinearModel.with_effects`), so a replay of the flight measures the truth and the validation sees how
far the config's model is from it. The flight flies the test card (:mod:`gap_validation.core.testcard`)
with gusts entering at the output as low-pass filtered (coloured) noise, optionally a narrow-band output
disturbance (band-pass filtered noise, e.g. a vibration or a poorly flown band; both noises from
:mod:`gap_validation.core.signals`), gyro and surface sensor noise and quantisation, optionally in a closed
loop (:mod:`gap_validation.core.loop_flight`), and publishes its topics as
:mod:`gap_validation.core.logged_topics` samples them. How it is flown is :class:`FlightOptions`
(:mod:`gap_validation.core.flight_options`).

This module assembles the flight (:func:`simulate_flight`, :class:`SimulatedFlight`) and is the face users
import from: the names of the modules above are imported here too.

Everything is seeded (``numpy.random.default_rng(seed)``) and drawn in a fixed order: the same seed gives the
same flight. The band noise draws from its own stream of the same seed, so switching it on changes nothing
else in the flight (and with it off a flight is exactly what it was before the option existed).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gap_validation.core.config import AIRSPEED_STREAM, ChannelConfig, ValidationConfig
from gap_validation.core.effects import validate_effect
from gap_validation.core.errors import ConfigError
from gap_validation.core.flight_options import EXCITATIONS, FlightOptions, with_options
from gap_validation.core.logged_topics import TopicSeries, plan_topics, sample_topics, with_logged_excitation
from gap_validation.core.loop_flight import WASHOUT_RAD_S, damper_gain, loop_responses
from gap_validation.core.signals import band_noise, doublet, log_sweep, lowpass_noise, multisine, multistep
from gap_validation.core.testcard import (
    SWEEP_SEGMENTS,
    Segment,
    card_segments,
    card_units,
    channel_deviation,
    pilot_trim,
)

__all__ = [
    "FlightOptions", "Segment", "TopicSeries", "SimulatedFlight", "band_noise", "truth_models", "plan_topics",
    "simulate_flight", "log_sweep", "doublet", "with_options", "with_logged_excitation", "EXCITATIONS",
    "multisine", "multistep", "card_segments", "card_units", "channel_deviation", "pilot_trim", "band_noises",
    "sample_topics", "damper_gain", "WASHOUT_RAD_S", "SWEEP_SEGMENTS"
]

#: Spawn key of the band-noise random stream (independent of the main stream of the same seed).
_BAND_NOISE_STREAM = 1


@dataclass
class SimulatedFlight:
    """A synthetic flight.

    Attributes
    ----------
    topics : dict
        Topic -> :class:`TopicSeries` (what a bag of the flight contains).
    segments : list of Segment
        The manoeuvres, in time order.
    truth : dict
        Channel -> the true :class:`LinearModel` (config model + hidden effects).
    hidden : dict
        Channel -> the hidden effects (validated mappings).
    t_s : ndarray
        Internal uniform simulation grid, relative to the start [s].
    inputs, outputs : dict
        Channel -> surface deflection deviation [rad] and noise-free, gust-free response [rad/s] on ``t_s``.
    duration_s, start_time_s : float
        Flight length [s] and absolute start time [s].
    seed : int
        Seed of the random generator.
    options : FlightOptions
    loop_gains : dict
        Closed-loop flights: channel -> the rate damper's gain K (``u = r - K y``, in the loop with
        ``loop_delay_s``); empty in open loop.
    """

    topics: dict[str, TopicSeries]
    segments: list[Segment]
    truth: dict
    hidden: dict[str, list[dict]]
    t_s: np.ndarray
    inputs: dict[str, np.ndarray]
    outputs: dict[str, np.ndarray]
    duration_s: float
    start_time_s: float
    seed: int
    options: FlightOptions
    loop_gains: dict = field(default_factory=dict)

    def histories(self, channel: ChannelConfig) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """``{stream: (t_s, values)}`` of a channel's input and output streams as recorded (SI units), for
        :meth:`~gap_validation.core.validator.OnlineValidator.add_histories`.

        Parameters
        ----------
        channel : ChannelConfig
            The channel (SISO ``input``/``output`` or MIMO ``inputs[j]``/``outputs[i]``).
        """
        out = {}
        for stream in channel.input_streams + channel.output_streams:
            spec = channel.signal(stream)
            series = self.topics[spec.topic]
            out[stream] = (series.stamp_s + spec.time_offset_s, spec.value(series.values[spec.field]))
        return out

    @property
    def message_count(self) -> int:
        """Messages in all topics."""
        return sum(len(s) for s in self.topics.values())

    def sweeps(self, channel: str) -> list[Segment]:
        """The identification manoeuvres of ``channel`` (sweeps, multisines, multisteps; with ``excitation`` =
        ``doublet``, its doublets).

        Parameters
        ----------
        channel : str
            A channel of the flight's config.
        """
        kinds = SWEEP_SEGMENTS + (("doublet",) if self.options.excitation == "doublet" else ())
        return [s for s in self.segments if s.channel == channel and s.kind in kinds]


def truth_models(config: ValidationConfig, hidden: dict[str, list[dict]] | None = None) -> dict:
    """Channel -> the true model: the config's model (with its effects) and the hidden effects in series.

    Parameters
    ----------
    config : ValidationConfig
        The config (models with their effects).
    hidden : dict, optional
        Channel -> effects in series with its model.
    """
    hidden = hidden or {}
    unknown = sorted(set(hidden) - set(config.channels))
    if unknown:
        raise ConfigError(f"hidden effect for unknown channel {unknown[0]!r} "
                          f"(channels: {', '.join(config.channels)})")
    return {name: ch.model.with_effects(list(hidden.get(name, []))) if hidden.get(name) else ch.model
            for name, ch in config.channels.items()}


def _gust(n: int, fs_hz: float, opt: FlightOptions, rng: np.random.Generator) -> np.ndarray:
    """Coloured disturbance: white noise through a 2nd-order Butterworth low-pass, scaled to the gust RMS."""
    return lowpass_noise(n, fs_hz, opt.gust_bandwidth_rad_s, opt.gust_rms_rad_s * opt.noise, rng, order=2)


def band_noises(config: ValidationConfig, n: int, fs_hz: float, opt: FlightOptions, seed: int) -> dict:
    """Channel -> narrow-band output disturbance on a uniform grid (empty unless ``band_noise_rad_s`` is set).

    Parameters
    ----------
    config : ValidationConfig
        The channels.
    n : int
        Samples.
    fs_hz : float
        Rate of the grid [Hz].
    opt : FlightOptions
        ``band_noise_*`` options.
    seed : int
        The flight's seed (the band noise has its own stream of it).
    """
    out: dict[str, np.ndarray] = {}
    if opt.band_noise_rad_s is None:
        return out
    chosen = tuple(config.channels) if opt.band_noise_channels is None else opt.band_noise_channels
    unknown = [c for c in chosen if c not in config.channels]
    if unknown:
        raise ConfigError(f"simulation option band_noise_channels: no channel {unknown[0]!r} in the config "
                          f"(channels: {', '.join(config.channels)})")
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(_BAND_NOISE_STREAM,)))
    for name in config.channels:          # config order, every channel drawn: choosing channels changes none
        noise = band_noise(n, fs_hz, opt.band_noise_rad_s, opt.band_noise_rms_rad_s, rng)
        if name in chosen:
            out[name] = noise
    return out


# --------------------------------------------------------------------------------------------- flight
def simulate_flight(config: ValidationConfig, hidden: dict[str, list[dict]] | None = None,
                    options: FlightOptions | None = None, seed: int = 0) -> SimulatedFlight:
    """Simulate a sweep flight of the aircraft whose truth is the config's models plus hidden effects.

    Parameters
    ----------
    config : ValidationConfig
        Channels (models, frequency grids) and the topics and fields to publish.
    hidden : dict, optional
        Channel -> effects added in series to the config's model to make the truth (see
        :func:`gap_validation.cli.arguments.parse_hidden`).
    options : FlightOptions, optional
        Test card, rates and noise levels.
    seed : int
        Seed: the same seed gives the same flight.

    Returns
    -------
    SimulatedFlight
    """
    opt = (options or FlightOptions()).check()
    hidden = {k: [validate_effect(e, where=f"hidden.{k}") for e in v] for k, v in (hidden or {}).items()}
    truth = truth_models(config, hidden)
    plans = plan_topics(config)
    rng = np.random.default_rng(seed)
    segments, duration_s = card_segments(config, opt)
    rates = [opt.imu_rate_hz if p.role == "imu" else opt.surface_rate_hz for p in plans.values()]
    fs_hz = max(opt.sim_rate_hz, 4.0 * max(rates))
    t_s = np.arange(0.0, duration_s + 2.0 / fs_hz, 1.0 / fs_hz)

    inputs, trim = {}, {}
    units = card_units(config)
    for name, ch in config.channels.items():
        if ch.is_mimo:
            inputs[name], trim[name] = _mimo_inputs(name, ch, t_s, segments, duration_s, opt, units, rng)
            continue
        inputs[name] = channel_deviation(name, t_s, segments, opt, tuple(config.channels),
                                      share=(units.index((name, None)), len(units)))
        trim[name] = pilot_trim(t_s, segments, duration_s, opt, rng)
    gusts = {name: (np.stack([_gust(t_s.size, fs_hz, opt, rng) for _ in ch.outputs]) if ch.is_mimo else
                    _gust(t_s.size, fs_hz, opt, rng)) for name, ch in config.channels.items()}
    bands = band_noises(config, t_s.size, fs_hz, opt, seed)
    loop = loop_responses(config, truth, inputs, gusts, bands, t_s, fs_hz, opt, seed)
    references = dict(inputs)
    if loop is not None:
        inputs, outputs = loop.surfaces, loop.outputs
    else:
        outputs = {name: (_mimo_outputs(truth[name], t_s, inputs[name]) if ch.is_mimo else
                          np.asarray(truth[name].simulate(t_s, inputs[name]), dtype=float).ravel())
                   for name, ch in config.channels.items()}
    measured = {}
    for name, ch in config.channels.items():
        if ch.is_mimo:
            measured.update(_mimo_measured(name, ch, inputs[name] + trim[name], outputs[name] + gusts[name]
                                           + bands.get(name, 0.0), opt))
        else:
            measured[(name, "input")] = (inputs[name] + trim[name], opt.surface_noise_rad * opt.noise,
                                         opt.surface_lsb_rad)
            disturbed = outputs[name] + gusts[name]
            if name in bands:
                disturbed = disturbed + bands[name]
            measured[(name, "output")] = (disturbed, opt.gyro_noise_rad_s * opt.noise, opt.gyro_lsb_rad_s)
            if loop is not None:
                measured[(name, "output")] = loop.measured_output(name, disturbed, opt)
        if ch.trigger is not None:
            active = np.zeros_like(t_s)
            kinds = SWEEP_SEGMENTS + (("doublet",) if opt.excitation == "doublet" else ())
            for seg in segments:
                if seg.channel == name and seg.kind in kinds:
                    active[(t_s >= seg.start_s) & (t_s <= seg.end_s)] = 1.0
            measured[(name, "trigger")] = (active, 0.0, 0.0)

    if opt.log_excitation_topic:
        plans = plan_topics(with_logged_excitation(config, opt.log_excitation_topic))
    _extra_measured(plans, config, references, measured)
    topics = sample_topics(plans, measured, t_s, duration_s, opt, rng)
    return SimulatedFlight(topics=topics, segments=segments, truth=truth, hidden=hidden, t_s=t_s,
                           inputs=inputs, outputs=outputs, duration_s=duration_s,
                           start_time_s=opt.start_time_s, seed=seed, options=opt,
                           loop_gains={} if loop is None else dict(loop.gains))


# --------------------------------------------------------------------------------------------- MIMO channels
def _mimo_inputs(name: str, channel, t_s: np.ndarray, segments: list[Segment], duration_s: float,
                 opt: FlightOptions, units: list, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A MIMO channel's surface deviations (m, n) [rad], each input flown in its own manoeuvres, and the
    pilot's trim of each surface (m, n) [rad]."""
    m = len(channel.inputs)
    u = np.stack([channel_deviation(name, t_s, segments, opt, (), j, (units.index((name, j)), len(units)))
                  for j in range(m)])
    trim = np.stack([pilot_trim(t_s, segments, duration_s, opt, rng) for _ in range(m)])
    return u, trim


def _mimo_outputs(model, t_s: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Outputs (p, n) of a :class:`~gap_validation.core.models.MimoModel` from the full state space for the
    inputs ``u`` (m, n): by superposition, output i is the sum over inputs j of the realization ``(A, B e_j,
    e_i^T C, D_ij)`` simulated exactly (:meth:`LinearModel.simulate`, linear hold)."""
    from gap_validation.core.models import LinearModel

    a, b, c, d = model.state_space()
    p, m = model.shape
    y = np.zeros((p, t_s.size))
    for i in range(p):
        for j in range(m):
            element = LinearModel.from_spec(
                {
                    "state_space": {
                        "A": a.tolist(),
                        "B": b[:, [j]].tolist(),
                        "C": c[[i], :].tolist(),
                        "D": [[float(d[i, j])]],
                    }
                }
            )
            y[i] += np.asarray(element.simulate(t_s, u[j]), float).ravel()
    return y


def _mimo_measured(name: str, channel, u: np.ndarray, y: np.ndarray, opt: FlightOptions) -> dict:
    """``(name, stream) -> (series, noise std, lsb)`` of a MIMO channel's streams ``inputs[j]``,
    ``outputs[i]``."""
    from gap_validation.core.config import mimo_stream

    out = {(name, mimo_stream("inputs", j)): (u[j], opt.surface_noise_rad * opt.noise, opt.surface_lsb_rad)
           for j in range(len(channel.inputs))}
    out.update(
        {
            (name, mimo_stream("outputs", i)): (y[i], opt.gyro_noise_rad_s * opt.noise, opt.gyro_lsb_rad_s)
            for i in range(len(channel.outputs))
        }
    )
    return out


# --------------------------------------------------------------------------------------------- other streams
def _extra_measured(plans: dict, config: ValidationConfig, references: dict, measured: dict) -> None:
    """The series behind the planned topics' ``excitation``, ``other_input<j>`` and ``airspeed`` streams: the
    channel's injected manoeuvre (logged exactly), the other surface's measured deflection (the channel whose
    input is that topic and field; trim alone when no channel flies it), and the channel's trim airspeed (this
    simulator's airframe flies at the model's condition)."""
    by_signal = {(ch.input.topic, ch.input.field): name for name, ch in config.channels.items()
                 if ch.input is not None}
    for plan in plans.values():
        for name, stream, spec, _ in plan.entries:
            if (name, stream) in measured:
                continue
            if stream == "excitation":
                measured[(name, stream)] = (np.asarray(references[name], float), 0.0, 0.0)
            elif stream == AIRSPEED_STREAM:    # this airframe flies at one condition: the model's
                trim = config.channels[name].trim_airspeed_m_s
                measured[(name, stream)] = (
                    np.full(np.shape(next(iter(references.values()))), trim),
                    0.0,
                    0.0,
                )
            elif stream.startswith("other_input"):
                owner = by_signal.get((spec.topic, spec.field))
                if owner is not None:
                    measured[(name, stream)] = measured[(owner, "input")]
                else:
                    zero = np.zeros_like(np.asarray(next(iter(references.values())), float))
                    measured[(name, stream)] = (zero, 0.0, 0.0)
