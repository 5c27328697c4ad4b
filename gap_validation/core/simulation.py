"""Synthetic flights: time histories of a sweep flight, ROS-free (arrays only;
:mod:`gap_validation.bag.writer` writes them as a rosbag2).

The "true aircraft" of each channel is the config's model (with its effects) with *hidden* effects in series
(:meth:`LinearModel.with_effects`), so a replay of the flight measures the truth and the validation sees how
far the config's model is from it. The flight follows the paper's test card (Section V): frequency sweeps per
axis (roll, pitch, yaw in turn, several rounds), a doublet after each sweep, pilot re-trims between
manoeuvres, gusts entering at the output as low-pass filtered (coloured) noise, optionally a narrow-band
output disturbance (band-pass filtered noise, e.g. a vibration or a poorly flown band), gyro and surface
sensor noise and quantisation, and topics published at their own rates with timestamp jitter, dropped messages
and a transport latency (bag time = ``header.stamp`` + latency).

Sweeps are exponential (log) chirps, ``w(t) = w0 (w1/w0)^(t/T)``, so every octave receives the same time.
By default a sweep lasts 120 s and runs from half the channel's lowest grid frequency to 1.3 times its
highest: the estimator's analysis windows are anchored at the sweep start and last up to 20 s, so the grid's
lowest frequencies need the sweep to pass them well inside the first windows (a sweep that starts *at* the
lowest grid frequency biases the estimate there, most visibly near the lightly damped yaw zeros of the Ultra
Stick).

Everything is seeded (``numpy.random.default_rng(seed)``) and drawn in a fixed order: the same seed gives the
same flight. The band noise draws from its own stream of the same seed, so switching it on changes nothing
else in the flight (and with it off a flight is exactly what it was before the option existed).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from gap_validation.core.config import AIRSPEED_STREAM, ChannelConfig, SignalSpec, ValidationConfig
from gap_validation.core.effects import EFFECTS, validate_effect
from gap_validation.core.errors import ConfigError
from gap_validation.core.fields import FieldPath
from gap_validation.core.layouts import JOINT_STATE, LAYOUTS, infer_type
from gap_validation.core.numbers import (
    FINITE as FINITE_NUMBER,
)
from gap_validation.core.numbers import (
    NON_NEGATIVE,
    POSITIVE,
    Interval,
    check_number,
)

if TYPE_CHECKING:  # pragma: no cover
    from gap_validation.core.models import LinearModel

__all__ = [
    "FlightOptions", "Segment", "TopicSeries", "SimulatedFlight", "band_noise", "truth_models", "plan_topics",
    "simulate_flight", "log_sweep", "doublet", "with_options", "with_logged_excitation", "EXCITATIONS",
    "multisine", "multistep", "card_segments", "card_units", "channel_deviation", "pilot_trim", "band_noises",
    "sample_topics", "damper_gain"
]

#: Manoeuvres ``FlightOptions.excitation`` can fly.
EXCITATIONS = ("chirp", "multisine", "multisine-orthogonal", "3211", "doublet")
#: Segment kinds that are identification manoeuvres (sweeps); ``doublet`` segments after them are checks.
SWEEP_SEGMENTS = ("sweep", "multisine", "multisine-orthogonal", "3211")

#: Spawn key of the band-noise random stream (independent of the main stream of the same seed).
_BAND_NOISE_STREAM = 1
#: Order of the band-pass filter of the band noise (Butterworth; the band-pass doubles it).
_BAND_NOISE_ORDER = 4


@dataclass(frozen=True)
class FlightOptions:
    """How the synthetic flight is flown and measured.

    Attributes
    ----------
    sweeps_per_channel : int
        Rounds of the test card; each round excites every channel once (in config order).
    excitation : str
        The manoeuvre flown (:data:`EXCITATIONS`): ``chirp`` (a log sweep, then a doublet), ``multisine`` (a
        Schroeder-phased multisine of ``multisine_periods`` periods, then a doublet), ``multisine-orthogonal``
        (every channel at once, each on its own interleaved harmonics: harmonic k belongs to channel k mod n),
        ``3211`` (a 3-2-1-1 multistep of ``multistep_unit_s`` units) or ``doublet``.
    sweep_duration_s : float
        Length of one log sweep [s].
    imu_rate_hz, surface_rate_hz : float
        Publication rates of topics carrying outputs (IMU) and inputs or triggers (surfaces) [Hz].
    sweep_amplitude_rad, doublet_amplitude_rad : float
        Surface deflection amplitudes [rad].
    doublet_half_period_s : float
        Duration of each half of the doublet [s].
    quiet_s : float
        Quiet time (trim inputs, gusts) between manoeuvres [s].
    band_low_factor, band_high_factor : float
        The sweep covers ``[band_low_factor * min_rad_s, band_high_factor * max_rad_s]`` of the channel's
        grid. Starting an octave below the grid puts the grid's lowest frequencies inside whole analysis
        windows of the estimator (windows are anchored at the sweep start).
    noise : float
        Multiplies every noise and gust level below (0 gives a noise-free flight).
    gyro_noise_rad_s, surface_noise_rad : float
        Standard deviation of white sensor noise on rates [rad/s] and surface positions [rad].
    gust_rms_rad_s, gust_bandwidth_rad_s : float
        RMS and corner frequency of the gust disturbance added at each output: white noise through a
        second-order low-pass (damping 0.7), so coherence falls at low frequency.
    band_noise_rad_s : tuple of float, optional
        ``(low, high)`` [rad/s]: a narrow-band disturbance is added to the measured output (body rate) of the
        channels in ``band_noise_channels``: white noise through a Butterworth band-pass (order 4, -3 dB at
        ``low`` and ``high``), scaled to ``band_noise_rms_rad_s``. Like a gust it is uncorrelated with the
        surface, so the coherence drops in that band only (a band above the output topic's Nyquist frequency
        aliases into it, as it would on a real gyro). None (default): off.
    band_noise_rms_rad_s : float
        RMS of the band noise [rad/s] (not scaled by ``noise``: the band noise is asked for explicitly).
    band_noise_channels : tuple of str, optional
        Channels that get the band noise; None (default): every channel.
    trim_step_rad : float
        Size of the pilot's re-trims (slow ramps in about half of the quiet gaps, random sign) [rad]. Trim
        moves the equilibrium, so it is in the surface measurement but not in the model's input.
    trim_offset_rad : float
        Largest constant trim deflection of a surface (the linearisation point; not fed to the model) [rad].
    dwell_cycles : float
        Periods at the lowest frequency before each sweep starts rising (flight-test practice: start with
        long-period cycles); 0 gives a pure exponential sweep.
    gyro_lsb_rad_s, surface_lsb_rad : float
        Sensor resolution: measured rates and surface positions are rounded to multiples of these (a 16-bit
        gyro at +-250 deg/s resolves about 2^-13 rad/s, a 12-bit surface encoder about 2^-12 rad); 0 keeps
        full precision.
    jitter_s : float
        Standard deviation of the timestamp jitter [s] (clipped to a third of the sample period).
    drop_probability : float
        Probability that a message is lost.
    latency_s, latency_jitter_s : float
        Transport latency from ``header.stamp`` to the bag time: constant plus exponential part [s].
    sim_rate_hz : float
        Rate of the internal simulation grid [Hz] (raised to 4 times the fastest topic).
    start_time_s : float
        Absolute time of the flight start (epoch seconds) for stamps and bag times.
    trim_s : float, optional
        Trim before the first manoeuvre [s] (default ``quiet_s``).
    duration_s : float, optional
        Length of the flight [s]: the test card is cut there (default: as long as the card).
    multisine_period_s : float
        Period of a multisine [s] (its lowest harmonic is ``2 pi / period``).
    multisine_periods : int
        Periods flown per multisine.
    multistep_unit_s : float
        Unit of the 3-2-1-1 [s] (3, 2, 1, 1 units of alternating sign).
    step_rise_s : float
        Transition time of every step of a doublet or multistep (raised cosine; the surface actuator is not
        infinitely fast, and a measured step sampled at tens of hertz would be ambiguous by half a sample)
        [s].
    sweep_amplitude_scales : tuple of float, optional
        Round i of the test card flies its identification manoeuvres (sweeps, multisines, multisteps) at
        ``scales[i % len(scales)]`` times their amplitude, e.g. ``(1.0, 0.4)`` (sweeps at different amplitudes
        reveal an amplitude-dependent, nonlinear response). None (default): every round the same.
    """

    sweeps_per_channel: int = 3
    excitation: str = "chirp"
    sweep_duration_s: float = 120.0
    imu_rate_hz: float = 100.0
    surface_rate_hz: float = 50.0
    sweep_amplitude_rad: float = 0.06
    dwell_cycles: float = 0.0
    doublet_amplitude_rad: float = 0.05
    doublet_half_period_s: float = 0.5
    quiet_s: float = 5.0
    band_low_factor: float = 0.5
    band_high_factor: float = 1.3
    noise: float = 1.0
    gyro_noise_rad_s: float = 0.004
    surface_noise_rad: float = 0.001
    gust_rms_rad_s: float = 0.03
    gust_bandwidth_rad_s: float = 1.5
    band_noise_rad_s: tuple[float, float] | None = None
    band_noise_rms_rad_s: float = 0.0
    band_noise_channels: tuple[str, ...] | None = None
    trim_step_rad: float = 0.004
    trim_offset_rad: float = 0.03
    gyro_lsb_rad_s: float = 2.0 ** -13
    surface_lsb_rad: float = 2.0 ** -12
    jitter_s: float = 0.0005
    drop_probability: float = 0.003
    latency_s: float = 0.002
    latency_jitter_s: float = 0.0005
    sim_rate_hz: float = 400.0
    start_time_s: float = 1_700_000_000.0
    trim_s: float | None = None
    duration_s: float | None = None
    multisine_period_s: float = 20.0
    multisine_periods: int = 3
    multistep_unit_s: float = 0.5
    step_rise_s: float = 0.04
    sweep_amplitude_scales: tuple[float, ...] | None = None
    # closed loop and coupled surfaces (issue 13; see the functions under "closed loop" below)
    closed_loop_gain_margin_db: float | None = None
    loop_delay_s: float | None = None
    turbulence_rms_rad_s: float = 0.0
    turbulence_bandwidth_rad_s: float = 8.0
    log_excitation_topic: str | None = None
    coupling: tuple = ()
    cross_responses: tuple = ()
    # the mistakes every user makes (issue 23): what the logged topics get wrong relative to the config
    # (channel, "input"|"output"): that stream logged with the opposite sign
    flips: tuple = ()
    # every input (surface) logged in degrees where the config says radians
    surfaces_in_degrees: bool = False
    # "flu": IMU rate outputs logged in ROS's body frame (y and z reversed)
    imu_frame: str = "frd"
    stamp_offsets: tuple = ()              # (topic, seconds): that topic stamped late by seconds

    def check(self) -> "FlightOptions":
        """Raise :class:`ConfigError` naming the first option out of range; return self."""
        positive = ("sweep_duration_s", "imu_rate_hz", "surface_rate_hz", "doublet_half_period_s",
                    "gust_bandwidth_rad_s", "sim_rate_hz", "band_low_factor",
                    "band_high_factor")
        for name in positive:
            check_number(getattr(self, name), f"simulation option {name}", POSITIVE, expected="a number > 0")
        for name in ("sweep_amplitude_rad", "doublet_amplitude_rad", "quiet_s", "noise", "gyro_noise_rad_s",
                     "surface_noise_rad", "gust_rms_rad_s", "trim_step_rad", "trim_offset_rad", "jitter_s",
                     "gyro_lsb_rad_s", "surface_lsb_rad",
                     "latency_s", "latency_jitter_s", "band_noise_rms_rad_s"):
            check_number(
                getattr(self, name), f"simulation option {name}", NON_NEGATIVE, expected="a number >= 0"
            )
        if self.excitation not in EXCITATIONS:
            raise ConfigError(f"simulation option excitation: expected one of {', '.join(EXCITATIONS)}, "
                              f"got {self.excitation!r}")
        for name in ("multisine_period_s", "multistep_unit_s"):
            check_number(getattr(self, name), f"simulation option {name}", POSITIVE, expected="a number > 0")
        for name in ("trim_s", "duration_s", "step_rise_s"):
            if getattr(self, name) is not None:
                check_number(getattr(self, name), f"simulation option {name}", NON_NEGATIVE,
                             expected="a number >= 0")
        if not isinstance(self.multisine_periods, int) or self.multisine_periods < 1:
            raise ConfigError(f"simulation option multisine_periods: expected an integer >= 1, "
                              f"got {self.multisine_periods!r}")
        if not isinstance(self.sweeps_per_channel, int) or self.sweeps_per_channel < 1:
            raise ConfigError(f"simulation option sweeps_per_channel: expected an integer >= 1, "
                              f"got {self.sweeps_per_channel!r}")
        if self.band_low_factor >= self.band_high_factor:
            raise ConfigError(f"simulation options band_low_factor {self.band_low_factor!r} must be below "
                              f"band_high_factor {self.band_high_factor!r}")
        check_number(
            self.drop_probability,
            "simulation option drop_probability",
            Interval(0.0, 0.5, high_open=True),
            expected="a number in [0, 0.5)",
        )
        self._check_band_noise()
        self._check_amplitude_scales()
        _check_loop_options(self)
        self._check_mistakes()
        return self

    def _check_mistakes(self) -> None:
        for item in self.flips:
            if not (isinstance(item, tuple) and len(item) == 2 and item[1] in ("input", "output")):
                raise ConfigError(
                    f"simulation option flips: expected (channel, 'input' or 'output') pairs, got {item!r}"
                )
        if self.imu_frame not in ("frd", "flu"):
            raise ConfigError(f"simulation option imu_frame: expected frd or flu, got {self.imu_frame!r}")
        for item in self.stamp_offsets:
            if not (isinstance(item, tuple) and len(item) == 2 and isinstance(item[0], str)):
                raise ConfigError(
                    f"simulation option stamp_offsets: expected (topic, seconds) pairs, got {item!r}"
                )
            check_number(item[1], f"simulation option stamp_offsets {item[0]}", FINITE_NUMBER,
                         expected="a finite number of seconds")

    def _check_amplitude_scales(self) -> None:
        scales = self.sweep_amplitude_scales
        if scales is None:
            return
        try:
            values = [float(x) for x in scales]
        except (TypeError, ValueError):
            values = []
        if not values or not all(math.isfinite(v) and v > 0 for v in values):
            raise ConfigError(f"simulation option sweep_amplitude_scales: expected a tuple of numbers > 0, "
                              f"got {scales!r}")

    def _check_band_noise(self) -> None:
        band = self.band_noise_rad_s
        if band is None:
            return
        try:
            low, high = (float(x) for x in band)
        except (TypeError, ValueError):
            raise ConfigError(f"simulation option band_noise_rad_s: expected (low, high) in rad/s, "
                              f"got {band!r}") from None
        nyquist_rad_s = math.pi * self.sim_rate_hz
        if not (math.isfinite(low) and math.isfinite(high) and 0 < low < high < nyquist_rad_s):
            raise ConfigError(f"simulation option band_noise_rad_s: expected 0 < low < high < "
                              f"{nyquist_rad_s:.0f} rad/s (Nyquist of sim_rate_hz), got {band!r}")
        channels = self.band_noise_channels
        if channels is not None and (
            isinstance(channels, str) or not all(isinstance(c, str) for c in channels)
        ):
            raise ConfigError(f"simulation option band_noise_channels: expected a tuple of channel names, "
                              f"got {channels!r}")


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


@dataclass
class TopicSeries:
    """The messages of one topic: times and the value of every configured field (in message units).

    Attributes
    ----------
    topic, msgtype : str
        Topic name and ROS message type (e.g. ``sensor_msgs/msg/Imu``).
    stamp_s : ndarray
        ``header.stamp`` of each message, absolute [s].
    receive_s : ndarray
        Bag (receive) time of each message, absolute [s], non-decreasing.
    values : dict
        Field path text (as in the config) -> value per message, already divided by the signal's ``scale``.
    joint_names : tuple of str
        JointState ``name`` list (every message carries all of them).
    """

    topic: str
    msgtype: str
    stamp_s: np.ndarray
    receive_s: np.ndarray
    values: dict[str, np.ndarray] = field(default_factory=dict)
    joint_names: tuple[str, ...] = ()

    def __len__(self) -> int:
        return int(self.stamp_s.size)


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


# --------------------------------------------------------------------------------------------- topic layout
@dataclass
class _TopicPlan:
    topic: str
    msgtype: str
    role: str                                    # "imu" or "surface"
    entries: list[tuple[str, str, SignalSpec, FieldPath]]
    joint_names: tuple[str, ...] = ()


def _infer_type(spec: SignalSpec, path: FieldPath, stream: str) -> str | None:
    return spec.type or infer_type(path, stream)


def _check_field(plan_topic: str, msgtype: str, path: FieldPath) -> None:
    allowed = LAYOUTS[msgtype]
    attrs = path.attributes
    ok = attrs in allowed and all(s.kind == "attr" for s in path.steps)
    if msgtype == JOINT_STATE:
        ok = (len(path.steps) == 2 and attrs in allowed
              and path.steps[1].kind in ("key", "index") and (path.index is None or path.index >= 0))
    if not ok:
        raise ConfigError(f"cannot simulate field {path.text!r} on topic {plan_topic} ({msgtype}); "
                          f"supported: {_supported_text(msgtype)}")


def _supported_text(msgtype: str) -> str:
    if msgtype == JOINT_STATE:
        return "position[name], velocity[name], effort[name] or [index]"
    return ", ".join(sorted(".".join(a) for a in LAYOUTS[msgtype]))


def plan_topics(config: ValidationConfig) -> dict[str, _TopicPlan]:
    """Topic -> message type, rate role and the fields to fill, from the config's signals.

    The type is the signal's ``type`` when given, else inferred from the field: ``angular_velocity.*`` and
    friends -> ``sensor_msgs/msg/Imu``, ``position[name]`` -> ``sensor_msgs/msg/JointState``, ``data`` ->
    ``std_msgs/msg/Float64`` (``std_msgs/msg/Bool`` for a trigger).

    Parameters
    ----------
    config : ValidationConfig
        The config whose signals the flight publishes.

    Raises
    ------
    ConfigError
        A topic whose type cannot be inferred or is not supported, or whose signals disagree on the type.
    """
    plans: dict[str, _TopicPlan] = {}
    for topic, entries in config.topics().items():
        parsed = [(ch, stream, spec, FieldPath.parse(spec.field)) for ch, stream, spec in entries]
        types = {t for ch, stream, spec, path in parsed if (t := _infer_type(spec, path, stream)) is not None}
        if not types:
            raise ConfigError(f"cannot infer the message type of topic {topic} from field "
                              f"{parsed[0][3].text!r}; set 'type' ({', '.join(LAYOUTS)})")
        if len(types) > 1:
            raise ConfigError(f"topic {topic}: its signals need different message types "
                              f"({', '.join(sorted(types))})")
        msgtype = types.pop()
        if msgtype not in LAYOUTS:
            raise ConfigError(f"cannot simulate topic {topic} of type {msgtype} "
                              f"(supported: {', '.join(LAYOUTS)})")
        for _, _, _, path in parsed:
            _check_field(topic, msgtype, path)
        role = "imu" if any(stream.startswith("output") for _, stream, _, _ in parsed) else "surface"
        plans[topic] = _TopicPlan(topic, msgtype, role, parsed, _joint_names(parsed) if msgtype == JOINT_STATE
                                  else ())
    return plans


def _joint_names(parsed) -> tuple[str, ...]:
    names: list[str] = []
    for _, _, _, path in parsed:
        if path.key is not None and path.key not in names:
            names.append(path.key)
    needed = max([path.index + 1 for *_, path in parsed if path.index is not None] or [0])
    k = 0
    while len(names) < needed:
        if f"joint{k}" not in names:
            names.append(f"joint{k}")
        k += 1
    return tuple(names)


# --------------------------------------------------------------------------------------------- excitation
def log_sweep(t_s: np.ndarray, duration_s: float, w0_rad_s: float, w1_rad_s: float,
              taper_s: float = 1.0, dwell_cycles: float = 0.0) -> np.ndarray:
    """Exponential sweep on ``0 <= t <= T`` (zero outside) with half-cosine fade-in and fade-out.

    The sweep first dwells ``dwell_cycles`` periods at ``w0`` (``T_d = 2 pi n / w0``; flight-test practice
    starts a sweep with a couple of long-period cycles), then sweeps exponentially:
    ``phi(t) = w0 T_d + w0 T_s / ln(k) (k^((t - T_d)/T_s) - 1)``, ``k = w1/w0``, ``T_s = T - T_d``, so the
    instantaneous frequency is ``w0 k^((t - T_d)/T_s)`` and every octave gets the same time.

    Parameters
    ----------
    t_s : ndarray
        Times from the sweep start [s].
    duration_s : float
        Sweep length T [s].
    w0_rad_s, w1_rad_s : float
        Start and end frequencies [rad/s].
    taper_s : float
        Half-cosine fade-in and fade-out [s] (at most T / 4).
    dwell_cycles : float
        Periods at ``w0`` before the sweep.
    """
    t = np.asarray(t_s, dtype=float)
    inside = (t >= 0.0) & (t <= duration_s)
    ratio = w1_rad_s / w0_rad_s
    tau = np.clip(t, 0.0, duration_s)
    dwell_s = min(2.0 * math.pi * dwell_cycles / w0_rad_s, 0.5 * duration_s)
    sweep_s = duration_s - dwell_s
    rel = np.clip(tau - dwell_s, 0.0, None)
    phase = w0_rad_s * np.minimum(tau, dwell_s) + w0_rad_s * sweep_s / math.log(ratio) * (
        np.power(ratio, rel / sweep_s) - 1.0)
    taper_s = min(taper_s, duration_s / 4.0)
    envelope = np.ones_like(t)
    if taper_s > 0:
        envelope = np.minimum(envelope, 0.5 - 0.5 * np.cos(np.pi * np.clip(tau / taper_s, 0.0, 1.0)))
        envelope = np.minimum(
            envelope, 0.5 - 0.5 * np.cos(np.pi * np.clip((duration_s - tau) / taper_s, 0.0, 1.0))
        )
    return np.where(inside, np.sin(phase) * envelope, 0.0)


def doublet(t_s: np.ndarray, half_period_s: float) -> np.ndarray:
    """Unit doublet: +1 for ``0 <= t < h``, -1 for ``h <= t < 2h``, zero elsewhere.

    Parameters
    ----------
    t_s : ndarray
        Times from the doublet start [s].
    half_period_s : float
        Length h of each half [s].
    """
    t = np.asarray(t_s, dtype=float)
    return np.where((t >= 0) & (t < half_period_s), 1.0, 0.0) - np.where(
        (t >= half_period_s) & (t < 2 * half_period_s), 1.0, 0.0)


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


def _gust(n: int, fs_hz: float, opt: FlightOptions, rng: np.random.Generator) -> np.ndarray:
    """Coloured disturbance: white noise through a 2nd-order Butterworth low-pass, scaled to the gust RMS."""
    rms = opt.gust_rms_rad_s * opt.noise
    white = rng.standard_normal(n + int(5 * fs_hz))
    if rms == 0.0:
        return np.zeros(n)
    from scipy import signal  # here: scipy.signal is slow to import

    b, a = signal.butter(2, opt.gust_bandwidth_rad_s / (2 * math.pi), fs=fs_hz)
    coloured = signal.lfilter(b, a, white)[-n:]
    return coloured * (rms / max(float(np.std(coloured)), 1e-300))


def band_noise(n: int, fs_hz: float, band_rad_s: tuple[float, float], rms: float,
               rng: np.random.Generator) -> np.ndarray:
    """Narrow-band disturbance: white noise through a Butterworth band-pass, scaled to ``rms``.

    Parameters
    ----------
    n : int
        Samples.
    fs_hz : float
        Sample rate [Hz].
    band_rad_s : (float, float)
        -3 dB edges of the band-pass [rad/s] (below the Nyquist frequency ``pi fs``).
    rms : float
        RMS of the result (over its n samples) [rad/s].
    rng : numpy.random.Generator
        Source of the white noise (n samples plus the filter's start-up, at least 5 s, are drawn even when
        ``rms`` is 0).
    """
    low, high = band_rad_s
    settle_s = max(5.0, 20.0 * 2.0 * math.pi / low)     # filter start-up: 20 periods of the lower edge
    white = rng.standard_normal(n + int(settle_s * fs_hz))
    if rms == 0.0:
        return np.zeros(n)
    from scipy import signal

    sos = signal.butter(_BAND_NOISE_ORDER, [low / (2 * math.pi), high / (2 * math.pi)], btype="bandpass",
                        output="sos", fs=fs_hz)
    filtered = signal.sosfilt(sos, white)[-n:]
    return filtered * (rms / max(float(np.std(filtered)), 1e-300))


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


# --------------------------------------------------------------------------------------------- sampling
def _sample_times(duration_s: float, rate_hz: float, opt: FlightOptions, rng: np.random.Generator):
    """Nominal sample instants with jitter and drops, and receive times with latency (both relative) [s]."""
    period = 1.0 / rate_hz
    nominal = np.arange(float(rng.uniform(0.0, period)), duration_s, period)
    jitter = np.clip(rng.standard_normal(nominal.size) * opt.jitter_s, -period / 3, period / 3)
    stamps = nominal + jitter
    keep = rng.random(nominal.size) >= opt.drop_probability
    stamps = stamps[keep]
    latency = opt.latency_s + rng.exponential(opt.latency_jitter_s, stamps.size) if opt.latency_jitter_s > 0 \
        else np.full(stamps.size, opt.latency_s)
    receive = np.maximum.accumulate(stamps + latency)
    return stamps, receive


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
    loop = _loop_flight(config, truth, inputs, gusts, bands, t_s, fs_hz, opt, seed)
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


def sample_topics(plans: dict, measured: dict, t_s: np.ndarray, duration_s: float, opt: FlightOptions,
                   rng: np.random.Generator) -> dict[str, TopicSeries]:
    """Topic -> :class:`TopicSeries`: each topic of ``plans`` sampled at its rate with jitter, drops and
    latency.

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
    opt : FlightOptions
        Rates, jitter, drops, latency, start time.
    rng : numpy.random.Generator
        The flight's random stream.
    """
    topics = {}
    late = dict(opt.stamp_offsets)
    for topic, plan in plans.items():
        rate = opt.imu_rate_hz if plan.role == "imu" else opt.surface_rate_hz
        stamps, receive = _sample_times(duration_s, rate, opt, rng)
        values = {}
        for name, stream, spec, path in plan.entries:
            series, noise_std, lsb = measured[(name, stream)]
            if stream == "trigger":
                sampled = np.interp(stamps, t_s, series) >= 0.5
                values[spec.field] = sampled.astype(float) / spec.scale
                continue
            sampled = np.interp(stamps, t_s, series) + noise_std * rng.standard_normal(stamps.size)
            if lsb > 0:
                sampled = np.round(sampled / lsb) * lsb
            values[spec.field] = _logged(spec, sampled, name, stream, opt)
        # the config's own time offset is what the stamps lack; a stamp offset flown is a mistake on top of it
        shift = late.get(topic, 0.0) - _topic_time_offset(topic, plan.entries)
        topics[topic] = TopicSeries(topic, plan.msgtype, opt.start_time_s + stamps + shift,
                                    opt.start_time_s + receive, values, plan.joint_names)
    return topics


def _logged(spec: SignalSpec, value: np.ndarray, channel: str, stream: str, opt: FlightOptions) -> np.ndarray:
    """What a topic carries for a signal ``value`` (SI, the models' frame): the config's raw units
    (:meth:`SignalSpec.raw`), then the mistakes flown (:class:`FlightOptions`: a reversed stream, surfaces in
    degrees, rates in ROS's body frame)."""
    raw = spec.raw(value)
    if (channel, stream) in opt.flips:
        raw = -raw
    if opt.surfaces_in_degrees and stream == "input":
        raw = raw * (180.0 / math.pi)
    if opt.imu_frame == "flu" and stream == "output" and spec.field.rsplit(".", 1)[-1] in ("y", "z"):
        raw = -raw
    return raw


def _topic_time_offset(topic: str, entries) -> float:
    """The config's ``time_offset_s`` of a topic's streams (one value: the stamps are the topic's)."""
    offsets = {float(spec.time_offset_s) for _, stream, spec, _ in entries if stream != "trigger"}
    if len(offsets) > 1:
        raise ConfigError(
            f"simulate: the streams of {topic} have different time_offset_s ({sorted(offsets)}): a "
            f"simulated topic has one clock"
        )
    return offsets.pop() if offsets else 0.0


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


def multisine(t_s: np.ndarray, period_s: float, periods: int, w0_rad_s: float, w1_rad_s: float,
              share: tuple[int, int] = (0, 1), taper_s: float = 0.5) -> np.ndarray:
    """Schroeder-phased multisine of peak 1 on ``0 <= t < periods * period_s`` (zero outside).

    The harmonics ``k 2 pi / period_s`` within ``[w0, w1]`` of equal amplitude, phases
    ``-pi j (j - 1) / n`` (Schroeder: low peak factor); ``share = (c, n)`` keeps the harmonics with
    ``k mod n == c`` only (orthogonal multisines on n axes flown at once). A half-cosine fade of ``taper_s``
    at both ends.

    Parameters
    ----------
    t_s : ndarray
        Times from the start [s].
    period_s : float
        Period [s].
    periods : int
        Periods flown.
    w0_rad_s, w1_rad_s : float
        Band of the harmonics [rad/s].
    share : (int, int)
        ``(c, n)``: the harmonics ``k mod n == c`` only.
    taper_s : float
        Fade-in and fade-out [s].
    """
    t = np.asarray(t_s, dtype=float)
    length = period_s * periods
    w_f = 2.0 * math.pi / period_s
    k = np.arange(max(1, math.ceil(w0_rad_s / w_f)), max(1, math.floor(w1_rad_s / w_f)) + 1)
    k = k[k % share[1] == share[0]]
    if k.size == 0:
        return np.zeros_like(t)
    j = np.arange(1, k.size + 1)
    phase = -math.pi * j * (j - 1) / k.size
    inside = (t >= 0.0) & (t < length)
    tau = np.where(inside, t, 0.0)
    one_period = np.linspace(0.0, period_s, 4096, endpoint=False)
    peak = float(np.max(np.abs(np.cos(np.outer(one_period, k * w_f) + phase).sum(axis=1))))
    u = np.zeros_like(t)
    for kk, ph in zip(k, phase):
        u[inside] += np.cos(kk * w_f * tau[inside] + ph)
    envelope = np.clip(np.minimum(tau, length - tau) / taper_s, 0.0, 1.0) if taper_s > 0 else 1.0
    envelope = 0.5 - 0.5 * np.cos(np.pi * envelope)
    return np.where(inside, u / peak * envelope, 0.0)


def multistep(t_s: np.ndarray, unit_s: float, pattern: tuple[int, ...] = (3, 2, 1, 1),
              rise_s: float = 0.0) -> np.ndarray:
    """Multistep of unit amplitude: ``pattern[i] * unit_s`` at alternating signs (+1 first), zero outside.

    ``(3, 2, 1, 1)`` is the 3-2-1-1, ``(1, 1)`` a doublet. Each step is a raised-cosine transition of
    ``rise_s`` centred on its nominal time (0: ideal steps).

    Parameters
    ----------
    t_s : ndarray
        Times from the start [s].
    unit_s : float
        Length of one unit [s].
    pattern : tuple of int
        Units per step.
    rise_s : float
        Transition time of each step [s].
    """
    t = np.asarray(t_s, dtype=float)
    edges = np.concatenate(([0.0], np.cumsum(pattern) * unit_s))
    levels = np.array([(-1.0) ** i for i in range(len(pattern))] + [0.0])
    u = np.zeros_like(t)
    previous = 0.0
    for edge, level in zip(edges, levels):
        step = level - previous
        if rise_s > 0:
            x = np.clip((t - edge + 0.5 * rise_s) / rise_s, 0.0, 1.0)
            u += step * (0.5 - 0.5 * np.cos(np.pi * x))
        else:
            u += step * (t >= edge)
        previous = level
    return u


def with_options(options: FlightOptions | None = None, **changes: Any) -> FlightOptions:
    """A copy of ``options`` (default options when None) with ``changes`` (None values are ignored).

    Parameters
    ----------
    options : FlightOptions, optional
        The options to change (default: :class:`FlightOptions()`).
    **changes
        Option name -> value.
    """
    base = options or FlightOptions()
    return replace(base, **{k: v for k, v in changes.items() if v is not None})


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


# --------------------------------------------------------------------------------------------- closed loop
# Issue 13: a rate damper closing the loop around each channel with the manoeuvre injected inside it (the
# injected signal logged as the excitation), turbulence, interconnected surfaces (``coupling``) and the
# response of one channel's rate to another channel's surface (``cross_responses``). Kept apart from the
# open-loop flight above: without these options a flight is exactly what it was.

#: Spawn keys of the closed loop's random streams (gyro noise fed back, turbulence).
_LOOP_NOISE_STREAM, _TURBULENCE_STREAM = 2, 3


def _check_loop_options(opt: FlightOptions) -> None:
    """ConfigError naming the first closed-loop / coupling option out of range."""
    if opt.closed_loop_gain_margin_db is not None:
        check_number(opt.closed_loop_gain_margin_db, "simulation option closed_loop_gain_margin_db",
                     Interval(0.5, 60.0), expected="a gain margin from 0.5 to 60 dB")
    if opt.loop_delay_s is not None:
        check_number(opt.loop_delay_s, "simulation option loop_delay_s", POSITIVE, expected="a number > 0")
    check_number(opt.turbulence_rms_rad_s, "simulation option turbulence_rms_rad_s", NON_NEGATIVE,
                 expected="a number >= 0")
    check_number(opt.turbulence_bandwidth_rad_s, "simulation option turbulence_bandwidth_rad_s", POSITIVE,
                 expected="a number > 0")
    if opt.coupling and opt.closed_loop_gain_margin_db is not None:
        raise ConfigError(
            "simulation options coupling and closed_loop_gain_margin_db: not available together "
            "yet (fly them as separate flights)"
        )


#: Washout of the simulated rate damper [rad/s]: ``C(s) = K s / (s + a)`` (no feedback in steady state, so the
#: damper leaves the slow spiral and trim to the pilot, as real dampers do).
WASHOUT_RAD_S = 0.3


def damper_gain(model: LinearModel, gain_margin_db: float, loop_delay_s: float,
                w_rad_s: np.ndarray | None = None) -> float:
    """Gain K of a rate damper ``u = r - C(s) y``, ``C = K s / (s + a)`` (washout ``a`` =
    :data:`WASHOUT_RAD_S`), with the given gain margin around ``model`` and a loop delay.

    The sign makes the feedback negative in the channel's band (``K Re P(j w) > 0`` at 1 rad/s); ``|K|`` is
    the critical gain (smallest ``1 / |P W|`` where the phase of ``K W(j w) P(j w) exp(-j w T)`` crosses -180
    deg) over ``10^(gain_margin_db / 20)``.

    Parameters
    ----------
    model : LinearModel
        The true aircraft of the channel.
    gain_margin_db : float
        Gain margin of the loop [dB].
    loop_delay_s : float
        Delay of the flight computer and actuator in the loop [s].
    w_rad_s : ndarray, optional
        Search grid [rad/s] (default 0.05 to 2000 rad/s).

    Raises
    ------
    ConfigError
        When the loop has no phase crossover (no finite gain margin).
    """
    w = np.geomspace(0.05, 2000.0, 40000) if w_rad_s is None else np.asarray(w_rad_s, float)
    p = model.freqresp(w) * np.exp(-1j * w * loop_delay_s) * (1j * w) / (1j * w + WASHOUT_RAD_S)
    sign = 1.0 if p[np.argmin(np.abs(w - 1.0))].real >= 0 else -1.0
    loop = sign * p
    crossing = np.flatnonzero((np.sign(loop.imag[:-1]) != np.sign(loop.imag[1:])) & (loop.real[:-1] < 0))
    if crossing.size == 0:
        raise ConfigError("closed loop: the rate damper's loop has no phase crossover, no finite gain margin")
    critical = min(1.0 / abs(loop[i]) for i in crossing)
    return sign * critical * 10.0 ** (-gain_margin_db / 20.0)


def _discrete(model, fs_hz: float) -> tuple[np.ndarray, np.ndarray, int]:
    """The model's rational part discretised with a zero-order hold (numerator, denominator in powers of
    ``z^-1``, the same length) and its pure delay in samples."""
    from scipy import signal

    a, b, c, d = model.state_space()
    if a.shape[0] == 0:
        num, den = np.array([float(d[0, 0])]), np.array([1.0])
    else:
        ad, bd, cd, dd, _ = signal.cont2discrete((a, b, c, d), 1.0 / fs_hz, method="zoh")
        num, den = signal.ss2tf(ad, bd, cd, dd)
        num = np.atleast_2d(num)[0]
    size = max(num.size, den.size)
    num, den = np.pad(num, (size - num.size, 0)), np.pad(den, (size - den.size, 0))
    return num, den, int(round(model.delay_s * fs_hz))


def _shifted(poly: np.ndarray, n: int, size: int) -> np.ndarray:
    out = np.zeros(size)
    out[n:n + poly.size] = poly
    return out


@dataclass
class _Loop:
    """A closed-loop (or coupled) flight: the surfaces, the responses and the gyro noise fed back."""

    surfaces: dict
    outputs: dict
    gains: dict
    gyro_noise: dict

    def measured_output(self, name: str, disturbed: np.ndarray, opt: FlightOptions) -> tuple:
        """The logged rate: the rate the damper read (gyro noise included: the same noise drives the surface),
        no further noise at sampling."""
        noise = self.gyro_noise.get(name)
        if noise is None:                                  # open loop: sensor noise drawn at sampling
            return disturbed, opt.gyro_noise_rad_s * opt.noise, opt.gyro_lsb_rad_s
        return disturbed + noise, 0.0, opt.gyro_lsb_rad_s


def _turbulence(n: int, fs_hz: float, opt: FlightOptions, rng: np.random.Generator) -> np.ndarray:
    """Turbulence at the rate: white noise through a first-order low-pass at ``turbulence_bandwidth_rad_s``,
    scaled to ``turbulence_rms_rad_s``."""
    white = rng.standard_normal(n + int(5 * fs_hz))
    if opt.turbulence_rms_rad_s == 0.0:
        return np.zeros(n)
    from scipy import signal

    b, a = signal.butter(1, opt.turbulence_bandwidth_rad_s / (2 * math.pi), fs=fs_hz)
    coloured = signal.lfilter(b, a, white)[-n:]
    return coloured * (opt.turbulence_rms_rad_s / max(float(np.std(coloured)), 1e-300))


def _cross_model(gain: float, wn: float, damping: float):
    from gap_validation.core.models import LinearModel

    return LinearModel.from_tf([gain * wn * wn], [1.0, 2.0 * damping * wn, wn * wn])


def _loop_flight(config: ValidationConfig, truth: dict, references: dict, gusts: dict, bands: dict,
                 t_s: np.ndarray, fs_hz: float, opt: FlightOptions, seed: int) -> _Loop | None:
    """Surfaces and responses of a closed-loop, turbulent or coupled flight; None for an open-loop flight
    without them (the flight is then exactly the one of the options before issue 13).

    Closed loop: per channel ``u = z^-Nc (r - K (y + d + n))`` with ``r`` the manoeuvre (injected inside the
    loop), ``d`` gusts, turbulence and band noise at the rate, ``n`` the gyro noise, ``K`` the rate damper of
    :func:`damper_gain` and ``Nc`` the loop delay (default one surface sample); ``y = P u`` with P the truth
    discretised on the simulation grid (zero-order hold, delay in whole samples). Solved exactly with linear
    filters. The turbulence is added to ``gusts`` (in place) so the logged rate holds it.
    """
    if opt.closed_loop_gain_margin_db is None and not opt.turbulence_rms_rad_s and not opt.coupling \
            and not opt.cross_responses:
        return None
    mimo = [name for name, ch in config.channels.items() if ch.is_mimo]
    if mimo:
        raise ConfigError(
            f"closed loop, turbulence, coupling and cross responses: not available for the MIMO "
            f"channel {mimo[0]} yet (fly it open loop)"
        )
    from scipy import signal

    n = t_s.size
    turb_rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(_TURBULENCE_STREAM,)))
    for name in config.channels:
        gusts[name] = gusts[name] + _turbulence(n, fs_hz, opt, turb_rng)
    surfaces = {name: np.asarray(r, float).copy() for name, r in references.items()}
    for source, target, gain in opt.coupling:
        surfaces[target] = surfaces[target] + gain * references[source]
    gains, noise = {}, {}
    if opt.closed_loop_gain_margin_db is not None:
        for name in config.channels:
            sampled = [e["type"] for e in truth[name].effects if EFFECTS[e["type"]].time_domain is not None]
            if sampled:
                raise ConfigError(
                    f"closed loop: channel {name}: {sampled[0]} is simulated on the surface samples, "
                    f"which the discretised loop does not have (fly it open loop)"
                )
        noise_rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(_LOOP_NOISE_STREAM,)))
        delay_s = opt.loop_delay_s if opt.loop_delay_s is not None else 1.0 / opt.surface_rate_hz
        n_c = max(1, int(round(delay_s * fs_hz)))
        wash_b, wash_a = signal.bilinear([1.0, 0.0], [1.0, WASHOUT_RAD_S], fs_hz)
        for name in config.channels:
            # the zero-order hold adds half a sample of delay to the discretised loop
            k = damper_gain(truth[name], opt.closed_loop_gain_margin_db, (n_c + 0.5) / fs_hz)
            num, den, n_p = _discrete(truth[name], fs_hz)
            size = den.size + wash_a.size + n_c + n_p
            den_w, num_w = np.convolve(den, wash_a), np.convolve(num, wash_b)
            closed = _shifted(den_w, 0, size) + k * _shifted(num_w, n_c + n_p, size)
            if np.max(np.abs(np.roots(np.trim_zeros(closed, "b")))) >= 1.0:
                raise ConfigError(
                    f"closed loop: channel {name}: the rate damper K = {k:.4g} does not stabilise the "
                    f"simulated loop (gain margin {opt.closed_loop_gain_margin_db:g} dB)"
                )
            noise[name] = opt.gyro_noise_rad_s * opt.noise * noise_rng.standard_normal(n)
            disturbance = gusts[name] + bands.get(name, 0.0) + noise[name]
            fed_back = signal.lfilter(_shifted(k * np.convolve(den, wash_b), n_c, size), closed, disturbance)
            surfaces[name] = signal.lfilter(_shifted(den_w, n_c, size), closed, surfaces[name]) - fed_back
            gains[name] = k
    outputs = {}
    for name in config.channels:
        if name in gains:
            num, den, n_p = _discrete(truth[name], fs_hz)
            outputs[name] = signal.lfilter(_shifted(num, n_p, num.size + n_p), den, surfaces[name])
        else:
            outputs[name] = np.asarray(truth[name].simulate(t_s, surfaces[name]), dtype=float).ravel()
    for out_channel, surface, gain, wn, damping in opt.cross_responses:
        outputs[out_channel] = outputs[out_channel] + np.asarray(
            _cross_model(gain, wn, damping).simulate(t_s, surfaces[surface]), float).ravel()
    return _Loop(surfaces, outputs, gains, noise)


def with_logged_excitation(config: ValidationConfig, topic: str | None) -> ValidationConfig:
    """The config with every channel's injected signal logged on ``topic`` (``--log-excitation``): a channel
    without ``excitation`` gets one there, with its input's field (a JointState joint), else ``data`` on
    ``TOPIC/<channel>``.

    Parameters
    ----------
    config : ValidationConfig
        The config flown.
    topic : str, optional
        The ``--log-excitation`` topic (None: ``config`` as it is).
    """
    if not topic:
        return config
    topic = topic if topic.startswith("/") else "/" + topic
    channels = {}
    for name, ch in config.channels.items():
        if ch.excitation is None and ch.input is not None:
            path = FieldPath.parse(ch.input.field)
            spec = SignalSpec(topic, ch.input.field, ch.input.scale) if path.key is not None or \
                path.index is not None else SignalSpec(f"{topic}/{name}", "data", ch.input.scale)
            ch = replace(ch, excitation=spec)
        channels[name] = ch
    return replace(config, channels=channels)


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
