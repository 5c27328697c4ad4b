"""How a synthetic flight is flown and measured: :class:`FlightOptions` (the test card, rates, noise levels,
the closed loop, the mistakes a log can carry), checked in one place, and :func:`with_options` to change them.
ROS-free; :mod:`gap_validation.core.simulation` flies them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from gap_validation.core.errors import ConfigError
from gap_validation.core.numbers import (
    FINITE as FINITE_NUMBER,
)
from gap_validation.core.numbers import (
    NON_NEGATIVE,
    POSITIVE,
    Interval,
    check_number,
)

__all__ = ["FlightOptions", "EXCITATIONS", "with_options"]

#: Manoeuvres ``FlightOptions.excitation`` can fly.
EXCITATIONS = ("chirp", "multisine", "multisine-orthogonal", "3211", "doublet")


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
    # closed loop and coupled surfaces (issue 13; flown by :mod:`gap_validation.core.loop_flight`)
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
        self._check_loop_options()
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

    def _check_loop_options(self) -> None:
        """ConfigError naming the first closed-loop / coupling option out of range (issue 13)."""
        if self.closed_loop_gain_margin_db is not None:
            check_number(self.closed_loop_gain_margin_db, "simulation option closed_loop_gain_margin_db",
                         Interval(0.5, 60.0), expected="a gain margin from 0.5 to 60 dB")
        if self.loop_delay_s is not None:
            check_number(self.loop_delay_s, "simulation option loop_delay_s", POSITIVE,
                         expected="a number > 0")
        check_number(self.turbulence_rms_rad_s, "simulation option turbulence_rms_rad_s", NON_NEGATIVE,
                     expected="a number >= 0")
        check_number(self.turbulence_bandwidth_rad_s, "simulation option turbulence_bandwidth_rad_s",
                     POSITIVE, expected="a number > 0")
        if self.coupling and self.closed_loop_gain_margin_db is not None:
            raise ConfigError(
                "simulation options coupling and closed_loop_gain_margin_db: not available together "
                "yet (fly them as separate flights)"
            )


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
