"""The test card of :mod:`gap_validation.core.testcard` flown in JSBSim's nonlinear 6-DOF model
(``gap-validate simulate --jsbsim AIRCRAFT --speed-kt V --altitude-ft H``).

The aircraft is trimmed as :mod:`gap_validation.jsbsim.linearize` does (true airspeed, straight and level) and
flown at JSBSim's own rate (``fdm.get_delta_t()``, 120 Hz by default) through the same card as the synthetic
flight (:mod:`gap_validation.core.testcard`'s card: sweeps per axis then a doublet, rounds, gaps, pilot
re-trims, topic rates, jitter, drops, surface and gyro noise and quantisation). What differs:

- **Surfaces**: each channel's input field names a surface, the joint (``position[aileron]``) or a Float64
  topic's last name (``/elevator``): ``aileron`` (``(left - right) / 2``), ``elevator`` or ``rudder`` [rad]
  (:data:`~gap_validation.jsbsim.linearize.SURFACES`). The logged surface is the trim deflection plus the
  card's deviation, the pilot's corrections and re-trims; the airframe sees the trim plus the card's deviation
  and the pilot's corrections **through the hidden effects** (``--hidden``, applied step by step by
  :class:`HiddenEffects` exactly as :meth:`LinearModel.simulate` applies them: ``rate_limit`` and ``backlash``
  first, the delay interpolated, the linear factors). A hidden effect of a channel acts on its surface, so
  every channel flying that surface sees it (the roll channel's aileron is the lateral channel's aileron).
- The surface positions are **set directly** (the FCS's actuators, with their lags, rate limits and free play,
  are bypassed: :meth:`Trimmed.hold_surfaces`), the ailerons in the ratio the FCS moves them at trim. This is
  the input the linearisation's converted B matrix describes; the c172x's elevator actuator alone (60 rad/s
  lag, 0.05 rad of hysteresis) would otherwise swallow a 2 deg sweep.
- JSBSim holds a surface for a whole step: the airframe gets the card at the middle of each step, so the
  staircase has no mean delay against the smooth logged surface (without it the measured phase lags by half a
  step, ``w dt / 2``: 7 deg at 30 rad/s).
- **Airspeed** logged where a channel has an ``airspeed`` stream (the configs of :func:`config_mapping` have
  one on ``/airspeed``): JSBSim's true airspeed [m/s] with :data:`AIRSPEED_NOISE_M_S` of noise.
- **Rates** logged: the body rates p, q, r of JSBSim (``velocities/p-rad_sec`` ...) with the gyro noise and
  quantisation of :class:`FlightOptions`. No synthetic gusts (``gust_rms_rad_s``): the only disturbances are
  JSBSim's own turbulence (``--turbulence``, seeded through ``atmosphere/randomseed``) and the band noise.
- **Pilot re-trims** (:func:`~gap_validation.core.testcard.pilot_trim`, without its random constant: the
  trim is JSBSim's) appear in the logged surface only, as in the synthetic flight: they stand for the trim
  changes that keep the aircraft at its condition, so the airframe does not see them. A **pilot**
  (:class:`Pilot`) holds the flight condition the model was linearised at: he flies wings level and the
  trimmed pitch attitude (the altitude through it) back when they have wandered, on every axis no manoeuvre is
  sweeping, recovers a swept axis only when the aircraft departs, and holds the airspeed on the throttle
  throughout (the nonlinear aircraft is not held at trim by anything else: without him a c172x at 60 kt
  spirals into the ground within minutes of the card, and in light turbulence a c172x at 100 kt flies its
  sweeps 25-31 % above the trim's dynamic pressure).
- Amplitudes: 2 deg sweeps and doublets by default (:data:`SWEEP_AMPLITUDE_RAD`). Small enough that the
  aircraft stays near trim and its response near the linearisation (c172x, 100 kt: within about 0.5 dB and 4
  deg from 1 to 30 rad/s, noise-free), large enough that the gyro and surface noise of :class:`FlightOptions`
  (sized for the 3.4 deg sweeps of a small UAV) leave the coherence high down to the grid's 1 rad/s; at 1 deg
  the lowest grid frequencies of the yaw and roll channels become data-limited.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from gap_validation.core.config import AIRSPEED_STREAM, FrequencyGrid, ValidationConfig, parse_config
from gap_validation.core.effects import is_nonlinear, validate_effect
from gap_validation.core.errors import ConfigError
from gap_validation.core.fields import FieldPath
from gap_validation.core.flight_options import FlightOptions, with_options
from gap_validation.core.logged_topics import plan_topics, sample_topics
from gap_validation.core.models import LinearModel
from gap_validation.core.simulation import SimulatedFlight, band_noises, truth_models
from gap_validation.core.testcard import (
    SWEEP_SEGMENTS,
    card_segments,
    card_units,
    channel_deviation,
    pilot_trim,
)
from gap_validation.jsbsim.linearize import (
    DEFAULT_GRID,
    KT_TO_M_S,
    POSITIONS,
    RATES,
    SURFACES,
    Linearization,
    Trimmed,
    TrimPoint,
    config_mapping,
    drift_warnings,
    linearize,
    quiet_jsbsim,
)

__all__ = [
    "Turbulence",
    "TURBULENCE_LEVELS",
    "parse_turbulence",
    "jsbsim_options",
    "JSBSimFlight",
    "simulate_jsbsim_flight",
    "fly",
    "Flown",
    "HiddenEffects",
    "Pilot",
    "pilot_for",
    "channel_surfaces",
    "SWEEP_AMPLITUDE_RAD",
    "PILOT_BANDWIDTH_RAD_S",
]

#: Default sweep and doublet amplitude [rad] (2 deg; module docstring).
SWEEP_AMPLITUDE_RAD = math.radians(2.0)
#: ``atmosphere/turb-type`` of JSBSim's Dryden models (FGWinds::tType: 3 ttMilspec, 4 ttTustin).
TURBULENCE_TYPES = {"milspec": 3, "tustin": 4}
#: MIL-F-8785C reference intensities of JSBSim's FGWinds: name -> (severity, wind at 20 ft [kt]).
TURBULENCE_LEVELS = {"light": (3, 15.0), "moderate": (4, 30.0), "severe": (6, 45.0)}
#: Noise of the logged airspeed [m/s] (a pitot-static sensor's, about 0.3 kt).
AIRSPEED_NOISE_M_S = 0.15
#: IMU fields of the body rates.
_RATE_FIELDS = {
    ("angular_velocity", "x"): "p",
    ("angular_velocity", "y"): "q",
    ("angular_velocity", "z"): "r",
}
#: Spawn key of the turbulence seed (a stream of the flight's seed of its own).
_TURBULENCE_STREAM = 11
#: Envelope a flight must stay in (else the amplitudes or the turbulence are too large for a linear
#: validation).
_MAX_BANK_DEG, _MAX_PITCH_DEG, _MIN_HEIGHT_FT = 75.0, 45.0, 50.0
_KT_TO_FPS = 1.6878098571011957


@dataclass(frozen=True)
class Turbulence:
    """JSBSim's Dryden turbulence (FGWinds, MIL-F-8785C).

    Attributes
    ----------
    model : str
        ``milspec`` or ``tustin`` (two discretisations of the Dryden spectra).
    severity : int
        Probability-of-exceedence index, 1 to 7 (``atmosphere/turbulence/milspec/severity``; 3 light, 4
        moderate, 6 severe). Above 2000 ft it alone sets the intensity.
    wind_kt : float
        Wind speed at 20 ft [kt] (``windspeed_at_20ft_AGL-fps``): the intensity below 1000 ft.
    """

    model: str = "milspec"
    severity: int = 3
    wind_kt: float = 15.0

    def describe(self) -> str:
        """One line: model, severity, wind."""
        level = next((k for k, v in TURBULENCE_LEVELS.items() if v == (self.severity, self.wind_kt)), None)
        return (f"JSBSim {self.model} (Dryden) turbulence, severity {self.severity}"
                + (f" ({level})" if level else "") + f", {self.wind_kt:g} kt wind at 20 ft")


def parse_turbulence(text: str | None) -> Turbulence | None:
    """Parse ``--turbulence`` of a JSBSim flight: ``light``, ``moderate``, ``severe``, or
    ``SEVERITY[:WIND_KT]``, each optionally followed by ``:milspec`` (default) or ``:tustin``; ``0``/``none``:
    off.

    Parameters
    ----------
    text : str or None
        The argument (None: off).

    Raises
    ------
    ConfigError
        One line naming the bad part.
    """
    if text is None:
        return None
    usage = ("expected light, moderate, severe or SEVERITY[:WIND_KT] (severity 1-7, wind at 20 ft in kt), "
             "optionally :milspec or :tustin, e.g. moderate:tustin or 3:15")
    parts = [p.strip().lower() for p in str(text).split(":")]
    if parts and parts[0] in ("0", "none", "off", "0.0") and len(parts) == 1:
        return None
    model = "milspec"
    if parts[-1] in TURBULENCE_TYPES:
        model = parts.pop()
    if not parts or not parts[0]:
        raise ConfigError(f"--turbulence {text!r}: {usage}")
    if parts[0] in TURBULENCE_LEVELS:
        if len(parts) != 1:
            raise ConfigError(f"--turbulence {text!r}: {usage}")
        severity, wind = TURBULENCE_LEVELS[parts[0]]
        return Turbulence(model, severity, wind)
    if len(parts) > 2:
        raise ConfigError(f"--turbulence {text!r}: {usage}")
    try:
        severity = int(parts[0])
    except ValueError:
        raise ConfigError(f"--turbulence {text!r}: bad part {parts[0]!r}: {usage}") from None
    if not 0 <= severity <= 7:
        raise ConfigError(f"--turbulence {text!r}: severity {severity} out of range (0 to 7)")
    wind = dict((s, w) for s, w in TURBULENCE_LEVELS.values()).get(severity, 15.0 * severity / 3.0)
    if len(parts) == 2:
        try:
            wind = float(parts[1])
        except ValueError:
            wind = float("nan")
        if not (math.isfinite(wind) and 0.0 <= wind <= 200.0):
            raise ConfigError(f"--turbulence {text!r}: bad wind {parts[1]!r} (0 to 200 kt)")
    return None if severity == 0 else Turbulence(model, severity, wind)


def jsbsim_options(options: FlightOptions | None = None, **changes) -> FlightOptions:
    """:class:`FlightOptions` for a JSBSim flight: 1 deg sweeps and doublets (:data:`SWEEP_AMPLITUDE_RAD`)
    unless ``changes`` say otherwise; every other default as the synthetic flight's.

    Parameters
    ----------
    options : FlightOptions, optional
        Options to start from (default: ``FlightOptions()`` with the JSBSim amplitudes).
    **changes
        Option name -> value (None values ignored).
    """
    base = options or FlightOptions(
        sweep_amplitude_rad=SWEEP_AMPLITUDE_RAD, doublet_amplitude_rad=SWEEP_AMPLITUDE_RAD
    )
    return with_options(base, **changes)


# ------------------------------------------------------------------------------------------------ the config
def _surface_of(spec, where: str) -> str:
    path = FieldPath.parse(spec.field)
    name = path.key if path.key is not None else spec.topic.rstrip("/").rsplit("/", 1)[-1]
    if name not in SURFACES:
        raise ConfigError(
            f"{where}: {spec.topic} {spec.field!r} is no JSBSim surface (the joint, or a Float64 "
            f"topic's last name, must be one of {', '.join(SURFACES)})"
        )
    return name


def _rate_of(spec, where: str) -> str:
    rate = _RATE_FIELDS.get(FieldPath.parse(spec.field).attributes)
    if rate is None:
        raise ConfigError(f"{where}: {spec.topic} {spec.field!r} is no body rate (expected an Imu "
                          "angular_velocity.x, .y or .z: p, q, r)")
    return rate


def channel_surfaces(config: ValidationConfig) -> dict[str, tuple[tuple[str, ...], tuple[str, ...]]]:
    """Channel -> (its input surfaces, its output rates), in stream order (one each for a SISO channel).

    Parameters
    ----------
    config : ValidationConfig
        The config whose channels a JSBSim flight flies.

    Raises
    ------
    ConfigError
        An input that is not a JSBSim surface or an output that is not a body rate.
    """
    out = {}
    for name, ch in config.channels.items():
        ins = tuple(_surface_of(ch.signal(s), f"channel {name} {s}") for s in ch.input_streams)
        outs = tuple(_rate_of(ch.signal(s), f"channel {name} {s}") for s in ch.output_streams)
        for stream, spec in ch.extra_streams():
            if stream not in ("excitation", AIRSPEED_STREAM):
                _surface_of(spec, f"channel {name} {stream}")
        out[name] = (ins, outs)
    return out


def _surface_effects(config: ValidationConfig, hidden: dict, surfaces: dict) -> dict[str, list[dict]]:
    """Surface -> the hidden effects acting on it (those of every channel that flies it, in the order
    given)."""
    truth_models(config, hidden)          # the core's checks: known channels, no effects on a MIMO model yet
    out: dict[str, list[dict]] = {s: [] for s in SURFACES}
    for name, effects in hidden.items():
        for surface in surfaces[name][0]:
            out[surface] += [validate_effect(e, where=f"hidden.{name}") for e in effects]
    return out


# ------------------------------------------------------------------------------------------------ flying
class HiddenEffects:
    """The hidden effects of one surface, applied step by step (the pilot closes a loop through them).

    Exactly what :meth:`LinearModel.simulate` does with a linearly interpolated input: the amplitude-dependent
    effects first (``rate_limit``, ``backlash``, in their order, from the first sample), then the delay
    (interpolated, zero before the start), then the rational part discretised with a first-order hold.

    Parameters
    ----------
    effects : list of dict
        Validated effects (may be empty: the identity).
    dt_s : float
        Step [s].
    """

    def __init__(self, effects: list[dict], dt_s: float) -> None:
        from scipy import signal

        self.effects = list(effects)
        self.dt_s = dt_s
        self._nonlinear = [e for e in effects if is_nonlinear(e)]
        model = LinearModel.from_tf([1.0], [1.0], effects=[e for e in effects if not is_nonlinear(e)])
        self._delay = model.delay_s / dt_s
        a, b, c, d = model.state_space()
        self._x = np.zeros(a.shape[0])
        if a.shape[0]:
            self._ad, self._bd, self._cd, self._dd, _ = signal.cont2discrete((a, b, c, d), dt_s, method="foh")
            self._bd, self._cd, self._dd = self._bd[:, 0], self._cd[0], float(self._dd[0, 0])
        else:
            self._ad = None
            self._dd = float(d[0, 0])
        self._held: list[float | None] = [None] * len(self._nonlinear)
        self._history: list[float] = []
        self.identity = not effects

    def __call__(self, u: float) -> float:
        """The airframe's surface deviation for the command ``u`` of the next step (both [rad])."""
        if self.identity:
            return u
        for i, effect in enumerate(self._nonlinear):
            prev = self._held[i]
            if prev is None:
                prev = u
            elif effect["type"] == "rate_limit":
                step = effect["rad_s"] * self.dt_s
                prev = prev + min(max(u - prev, -step), step)
            else:
                half = 0.5 * effect["width_rad"]
                prev = min(max(prev, u - half), u + half)
            self._held[i] = u = prev
        if self._delay > 0.0:
            self._history.append(u)
            k = len(self._history) - 1
            where = k - self._delay
            i0 = math.floor(where)
            if i0 < 0:
                u = 0.0
            else:
                frac = where - i0
                u = self._history[i0] * (1.0 - frac) + self._history[min(i0 + 1, k)] * frac
            keep = int(self._delay) + 3
            if len(self._history) > 4 * keep:
                del self._history[:-keep]
        if self._ad is None:
            return self._dd * u
        y = float(self._cd @ self._x) + self._dd * u
        self._x = self._ad @ self._x + self._bd * u
        return y


@dataclass(frozen=True)
class Pilot:
    """The pilot: wings level on the ailerons, the trimmed pitch attitude (and altitude) on the elevator, the
    airspeed on the throttle.

    As test pilots fly a card: hands off the swept control during a manoeuvre (the stick held where it was on
    that axis) unless the aircraft departs (bank beyond ``recover_bank_rad``, or pitch attitude
    ``recover_pitch_rad`` from trim); the other axis, and both in the gaps between manoeuvres, are flown back
    once they have wandered (``wander_*``: bank, pitch attitude, or altitude ``wander_altitude_ft`` from
    trim), until back within ``level_*``. The pitch attitude flown to is the trim's plus ``k_altitude`` per
    foot below the trimmed altitude (at most ``altitude_pitch_rad``): the altitude is flown back at the
    pilot's pace. The throttle holds the true airspeed all the time (``k_speed``, integral time
    ``speed_ti_s``): the flight condition the model was linearised at is the one flown, as a test pilot keeps
    it (measured, c172x at 100 kt in light turbulence, a 6-minute card: without the off-axis, altitude and
    speed holds the aircraft sinks 2300 ft and flies its roll and yaw sweeps 11-14 kt fast, dynamic pressure
    +25-31 %, and the response follows).

    Why: nothing else holds the nonlinear aircraft at its trim. Without a pilot a c172x at 60 kt spirals into
    the ground 4 minutes into the default card, and light turbulence does the same to a c172x at 100 kt. An
    attitude hold flown all the time reacts to the sweeps' own low-frequency motion and puts pilot inputs into
    the validated band and into the estimator's records (measured, noise-free c172x at 100 kt: pitch epsilon
    0.054 -> 0.13), and so does a recovery at 30 deg of bank or 10 deg of pitch, which 2 deg sweeps reach at
    their start (0.5 rad/s). The swept axis alone is hands off: the other is held as a test pilot holds it (a
    roll sweep flown with the pitch attitude let go pumps the phugoid and dives the aircraft).

    ``aileron = -k_phi phi``, ``elevator = -k_theta (theta - theta_ref)``, each through a first-order lag of
    ``lag_s`` (the pilot's hand) and limited to ``limit_rad``. The gains give the attitude loops a crossover
    of ``bandwidth_rad_s`` from the aircraft's short-term rate response to the surface (:func:`pilot_for`).
    The corrections are logged with the surface and reach the airframe through the hidden effects like the
    card.

    Attributes
    ----------
    k_phi, k_theta : float
        Gains [rad of surface per rad of attitude].
    theta_trim_rad : float
        Pitch attitude at trim [rad].
    bandwidth_rad_s : float
        Crossover the gains were sized for [rad/s].
    lag_s : float
        Time constant of the pilot's hand [s].
    limit_rad : float
        Largest correction [rad].
    recover_bank_rad, recover_pitch_rad : float
        Departure from the trimmed attitude that makes the pilot take over in a manoeuvre [rad].
    wander_bank_rad, wander_pitch_rad : float
        Departure that makes him fly an axis back when he is not sweeping it [rad].
    level_bank_rad, level_pitch_rad : float
        Where he lets go again [rad].
    k_altitude : float
        Pitch attitude added per foot below the trimmed altitude [rad/ft] (0: no altitude hold).
    altitude_pitch_rad : float
        Largest pitch attitude added for the altitude [rad].
    wander_altitude_ft, level_altitude_ft : float
        Altitude error that makes him fly the pitch axis back, and where he lets go [ft].
    k_speed : float
        Throttle per unit of relative airspeed error (``(V_trim - V) / V_trim``) (0: throttle held at trim).
    speed_ti_s : float
        Integral time of the airspeed hold [s].
    """

    k_phi: float
    k_theta: float
    theta_trim_rad: float
    bandwidth_rad_s: float
    lag_s: float = 1.0
    limit_rad: float = 0.1
    recover_bank_rad: float = math.radians(45.0)
    recover_pitch_rad: float = math.radians(20.0)
    wander_bank_rad: float = math.radians(5.0)
    wander_pitch_rad: float = math.radians(3.0)
    level_bank_rad: float = math.radians(2.0)
    level_pitch_rad: float = math.radians(1.0)
    k_altitude: float = 0.0
    altitude_pitch_rad: float = math.radians(3.0)
    wander_altitude_ft: float = 100.0
    level_altitude_ft: float = 30.0
    k_speed: float = 0.0
    speed_ti_s: float = 30.0


#: Default crossover of the pilot's attitude hold [rad/s] (:class:`Pilot`).
PILOT_BANDWIDTH_RAD_S = 0.2
#: Crossovers of his altitude and airspeed holds, each a quarter and a half of the attitude's [rad/s] (outer
#: loops slower than the loop they act through).
ALTITUDE_BANDWIDTH_SHARE, SPEED_BANDWIDTH_SHARE = 0.25, 0.5


def pilot_for(
    aircraft: str,
    speed_kt: float,
    altitude_ft: float,
    bandwidth_rad_s: float = PILOT_BANDWIDTH_RAD_S,
    split: np.ndarray | None = None,
) -> Pilot | None:
    """A :class:`Pilot` sized on the aircraft: the roll and pitch rate 1.5 s after a 0.5 deg aileron and
    elevator step (flown on trimmed twins) give ``d phi/dt`` and ``d theta/dt`` per rad of surface; the gains
    are the bandwidth over them. None when ``bandwidth_rad_s`` is 0 (hands off).

    Parameters
    ----------
    aircraft : str
        JSBSim aircraft name.
    speed_kt, altitude_ft : float
        The trim (true airspeed [kt], altitude [ft]).
    bandwidth_rad_s : float
        Crossover of the attitude loops [rad/s] (0: no pilot).
    split : ndarray, optional
        :meth:`Trimmed.surface_split`'s split (measured when not given).
    """
    if not bandwidth_rad_s:
        return None
    step = math.radians(0.5)
    rates = []
    for surface, rate in (("aileron", 0), ("elevator", 1)):
        twin = Trimmed(aircraft, speed_kt, altitude_ft)
        if split is None:
            split = twin.surface_split()[1]
            twin = Trimmed(aircraft, speed_kt, altitude_ft)
        n = int(round(1.5 / twin.point.dt_s))
        deviation = np.zeros((n, len(SURFACES)))
        deviation[:, SURFACES.index(surface)] = step
        flown = fly(twin, deviation, split, check_envelope=False)
        rates.append(flown.rates[-1, rate] / step)
    k_phi, k_theta = (bandwidth_rad_s / r if abs(r) > 1e-6 else 0.0 for r in rates)
    twin = Trimmed(aircraft, speed_kt, altitude_ft)
    point = twin.point
    v0 = speed_kt * _KT_TO_FPS
    # the airspeed's relative rate of change 3 s after a throttle step of 0.1, surfaces at trim (1/s per unit)
    step_th, seconds = 0.1, 3.0
    throttle = [min(1.0, t + step_th) for t in point.throttle]
    flown = fly(
        twin,
        np.zeros((int(round(seconds / point.dt_s)), len(SURFACES))),
        split,
        check_envelope=False,
        throttle=throttle,
    )
    accel = (flown.airspeed_kt[-1] * _KT_TO_FPS - v0) / seconds / v0 / step_th
    k_speed = SPEED_BANDWIDTH_SHARE * bandwidth_rad_s / accel if accel > 1e-6 else 0.0
    return Pilot(k_phi=k_phi, k_theta=k_theta, theta_trim_rad=math.radians(point.theta_deg),
                 bandwidth_rad_s=bandwidth_rad_s, k_altitude=ALTITUDE_BANDWIDTH_SHARE * bandwidth_rad_s / v0,
                 k_speed=k_speed)


@dataclass
class Flown:
    """What :func:`fly` returns.

    Attributes
    ----------
    rates : ndarray
        n x 3: p, q, r after each step [rad/s].
    pilot : ndarray
        n x 3: the pilot's corrections per surface (aileron, elevator, rudder) [rad] (zeros without a pilot).
    airframe : ndarray
        n x 3: the surface deviations the airframe got (through the hidden effects) [rad].
    airspeed_kt, altitude_ft : ndarray
        n: true airspeed [kt] and altitude above sea level [ft] after each step (the flight condition flown).
    """

    rates: np.ndarray
    pilot: np.ndarray
    airframe: np.ndarray
    airspeed_kt: np.ndarray = field(default_factory=lambda: np.empty(0))
    altitude_ft: np.ndarray = field(default_factory=lambda: np.empty(0))


def fly(trimmed: Trimmed, deviations: np.ndarray, split: np.ndarray, *, effects: dict | None = None,
        pilot: Pilot | None = None, pilot_flies: np.ndarray | None = None, check_envelope: bool = True,
        throttle: list[float] | None = None) -> Flown:
    """Fly the trimmed aircraft with its surfaces set step by step; the body rates after each step.

    Step k sets the surfaces to trim + ``H(deviations[k] + pilot_k)`` (``H``: the surface's hidden effects),
    held for the step (the FCS bypassed: :meth:`Trimmed.hold_surfaces`), runs JSBSim once and reads p, q, r.
    JSBSim's step first integrates the state (with the accelerations of the step before), then evaluates the
    forces with the new surfaces: so ``rates[k]`` is the state at ``t_k``, when the surface of step k starts
    to act, and that surface holds until ``t_k + dt`` (a zero-order hold; fly a smooth signal at the steps'
    middles, ``t_k + dt / 2``, and it has no mean delay).

    Parameters
    ----------
    trimmed : Trimmed
        A trimmed aircraft (flown on: call once per :class:`Trimmed`).
    deviations : ndarray
        n x 3: the commanded deviations from trim of aileron, elevator, rudder per step [rad].
    split : ndarray
        :meth:`Trimmed.surface_split`'s split (how the FGFCS positions move per rad of each surface).
    effects : dict, optional
        Surface -> :class:`HiddenEffects` (default: none).
    pilot : Pilot, optional
        The pilot (default: none, hands off throughout).
    pilot_flies : ndarray, optional
        n x 2 booleans (or n, for both): where the pilot flies the roll (ailerons) and the pitch (elevator)
        axis back once it has wandered, i.e. where no manoeuvre sweeps that axis (default: all steps);
        elsewhere he holds that stick still unless the aircraft departs (:class:`Pilot`).
    throttle : list of float, optional
        Throttle commands held throughout, one per engine (default: the trim's, or the pilot's airspeed hold).
    check_envelope : bool
        Stop with a ConfigError when the aircraft banks beyond 75 deg, pitches beyond 45 deg or descends below
        50 ft (the card is too strong for a linear validation).
    """
    fdm = trimmed.fdm
    trimmed.hold_surfaces()
    nodes, write = trimmed.position_nodes()
    manager = fdm.get_property_manager()
    p_node, q_node, r_node = trimmed.rate_nodes()
    phi_node, theta_node, height_node, vt_node, h_node = (
        manager.get_node(p) for p in ("attitude/phi-rad", "attitude/theta-rad", "position/h-agl-ft",
                                      "velocities/vt-fps", "position/h-sl-ft"))
    deviations = np.asarray(deviations, float)
    n = deviations.shape[0]
    rates, corrections, airframe = np.empty((n, 3)), np.zeros((n, 3)), np.empty((n, 3))
    airspeed, altitude = np.empty(n), np.empty(n)
    filters = [(effects or {}).get(s) or HiddenEffects([], trimmed.point.dt_s) for s in SURFACES]
    base = np.array([trimmed.point.positions_rad[p] for p in POSITIONS])
    split = np.asarray(split, float)
    split_rows = [list(map(float, row)) for row in split]
    base_list = base.tolist()
    every = max(1, int(round(0.5 / trimmed.point.dt_s)))
    dt = trimmed.point.dt_s
    alpha = 0.0 if pilot is None else min(1.0, dt / pilot.lag_s)
    flies = np.ones((n, 2), bool) if pilot_flies is None else np.asarray(pilot_flies, bool)
    if flies.ndim == 1:
        flies = np.repeat(flies[:, None], 2, axis=1)
    held = [0.0, 0.0, 0.0]
    wandered, departed = [False, False], False
    throttle_nodes = [
        manager.get_node(f"fcs/throttle-cmd-norm[{i}]") for i in range(len(trimmed.point.throttle))
    ]
    throttle_trim = list(trimmed.point.throttle)
    if throttle is not None:
        for node, value in zip(throttle_nodes, throttle):
            node.set_double_value(float(value))
    v_trim = trimmed.point.speed_kt * _KT_TO_FPS
    h_trim = trimmed.point.altitude_ft
    speed_hold = pilot is not None and pilot.k_speed > 0 and throttle is None
    integral = 0.0
    previous = [None] * len(nodes)
    run = fdm.run
    with quiet_jsbsim():
        for k in range(n):
            if pilot is not None:
                phi, theta = phi_node.get_double_value(), theta_node.get_double_value()
                below = h_trim - h_node.get_double_value()
                theta_ref = pilot.theta_trim_rad + min(
                    max(pilot.k_altitude * below, -pilot.altitude_pitch_rad), pilot.altitude_pitch_rad
                )
                bank, pitch = abs(phi), abs(theta - theta_ref)
                off = (bank > pilot.wander_bank_rad,
                       pitch > pilot.wander_pitch_rad or abs(below) > pilot.wander_altitude_ft)
                level = (bank < pilot.level_bank_rad,
                         pitch < pilot.level_pitch_rad and abs(below) < pilot.level_altitude_ft)
                for j in (0, 1):
                    if not flies[k, j]:
                        wandered[j] = False              # a manoeuvre sweeps this axis: hands off it
                    elif off[j]:
                        wandered[j] = True
                    elif level[j]:
                        wandered[j] = False
                if (
                    bank > pilot.recover_bank_rad
                    or abs(theta - pilot.theta_trim_rad) > pilot.recover_pitch_rad
                ):
                    departed = True
                elif level[0] and pitch < pilot.level_pitch_rad:
                    departed = False
                targets = (-pilot.k_phi * phi, -pilot.k_theta * (theta - theta_ref))
                for j in (0, 1):
                    if wandered[j] or departed:
                        value = held[j] + alpha * (targets[j] - held[j])
                        held[j] = min(max(value, -pilot.limit_rad), pilot.limit_rad)
                corrections[k] = held
                if speed_hold:
                    error = (v_trim - vt_node.get_double_value()) / v_trim
                    integral += error * dt
                    push = pilot.k_speed * (error + integral / pilot.speed_ti_s)
                    for node, trim in zip(throttle_nodes, throttle_trim):
                        node.set_double_value(min(max(trim + push, 0.0), 1.0))
            command = deviations[k] + corrections[k]
            surface = [filters[j](float(command[j])) for j in range(3)]
            airframe[k] = surface
            row = list(base_list)
            for j in range(3):
                if surface[j]:
                    sj, rj = surface[j], split_rows[j]
                    for i in range(4):
                        row[i] += rj[i] * sj
            for i, value in enumerate(row):
                if value != previous[i]:           # held positions stay: write only what moves
                    node = nodes[i]
                    node.set_attribute(write, True)
                    node.set_double_value(value)
                    node.set_attribute(write, False)
                    previous[i] = value
            run()
            rates[k, 0] = p_node.get_double_value()
            rates[k, 1] = q_node.get_double_value()
            rates[k, 2] = r_node.get_double_value()
            airspeed[k] = vt_node.get_double_value()
            altitude[k] = h_node.get_double_value()
            if check_envelope and k % every == 0:
                phi_deg = math.degrees(phi_node.get_double_value())
                theta_deg = math.degrees(theta_node.get_double_value())
                height = height_node.get_double_value()
                if not (abs(phi_deg) <= _MAX_BANK_DEG and abs(theta_deg) <= _MAX_PITCH_DEG
                        and height >= _MIN_HEIGHT_FT):
                    raise ConfigError(
                        f"JSBSim {trimmed.aircraft}: the aircraft left the envelope of a linear validation "
                        "at "
                        f"{k * dt:.1f} s (bank {phi_deg:.0f} deg, pitch {theta_deg:.0f} deg, height "
                        f"{height:.0f} ft): fly smaller amplitudes (--amplitude-deg), fewer rounds "
                        "(--sweeps), less "
                        "turbulence, or trim higher"
                    )
    if not np.all(np.isfinite(rates)):
        raise ConfigError(f"JSBSim {trimmed.aircraft}: the simulation diverged (non-finite rates)")
    return Flown(rates=rates, pilot=corrections, airframe=airframe, airspeed_kt=airspeed / _KT_TO_FPS,
                 altitude_ft=altitude)


def _set_turbulence(trimmed: Trimmed, turbulence: Turbulence | None, seed: int) -> int | None:
    if turbulence is None:
        return None
    fdm = trimmed.fdm
    turb_seed = int(
        np.random.SeedSequence(seed, spawn_key=(_TURBULENCE_STREAM,)).generate_state(1)[0] % 2**31
    )
    with quiet_jsbsim():
        fdm["atmosphere/randomseed"] = turb_seed
        fdm["atmosphere/turb-type"] = TURBULENCE_TYPES[turbulence.model]
        fdm["atmosphere/turbulence/milspec/windspeed_at_20ft_AGL-fps"] = turbulence.wind_kt * _KT_TO_FPS
        fdm["atmosphere/turbulence/milspec/severity"] = turbulence.severity
    return turb_seed


@dataclass
class JSBSimFlight:
    """A test card flown in JSBSim.

    Attributes
    ----------
    flight : SimulatedFlight
        What :func:`gap_validation.bag.writer.write_flight` writes (``truth``: the config's models with the
        hidden effects, the linear approximation of the truth; ``inputs``: the logged surface deviations from
        trim, ``outputs``: JSBSim's rates less their trim values).
    config : ValidationConfig
        The config flown (the linearisation's when none was given).
    point : TrimPoint
        The trim flown about.
    linearization : Linearization or None
        The linearisation at the flown condition when no config was given.
    surfaces : dict
        Channel -> (input surfaces, output rates).
    surface_effects : dict
        Surface -> hidden effects acting on it.
    turbulence : Turbulence or None
    turbulence_seed : int or None
        ``atmosphere/randomseed`` given to JSBSim.
    steps : int
        JSBSim steps flown.
    jsbsim_s, jsbsim_cpu_s : float
        Wall and CPU time of the steps [s] (JSBSim and the per-step Python around it).
    flown : Flown
        What :func:`fly` returned (rates, the pilot's corrections, the airframe's surfaces per step).
    pilot : Pilot or None
        The attitude hold flown (None: hands off).
    warnings : list of str
        One-line warnings (a trim the nonlinear model does not hold).
    """

    flight: SimulatedFlight
    config: ValidationConfig
    point: TrimPoint
    linearization: Linearization | None
    surfaces: dict
    surface_effects: dict
    turbulence: Turbulence | None
    turbulence_seed: int | None
    steps: int
    jsbsim_s: float
    jsbsim_cpu_s: float
    flown: "Flown | None" = field(repr=False, default=None)
    pilot: "Pilot | None" = None
    warnings: list = field(default_factory=list)


def simulate_jsbsim_flight(
    aircraft: str,
    speed_kt: float,
    altitude_ft: float,
    config: ValidationConfig | None = None,
    hidden: dict[str, list[dict]] | None = None,
    options: FlightOptions | None = None,
    seed: int = 0,
    turbulence: Turbulence | None = None,
    grid: FrequencyGrid = DEFAULT_GRID,
    attitude_hold_rad_s: float = PILOT_BANDWIDTH_RAD_S,
) -> JSBSimFlight:
    """Fly the test card in JSBSim (see the module's conventions).

    Parameters
    ----------
    aircraft : str
        JSBSim aircraft name.
    speed_kt : float
        True airspeed [kt].
    altitude_ft : float
        Altitude above sea level [ft].
    config : ValidationConfig, optional
        Channels (surfaces, rates, topics, grids: the card's bands). Default: the linearisation at the flown
        condition (:func:`~gap_validation.jsbsim.linearize.linearize`) with ``grid``.
    hidden : dict, optional
        Channel -> effects between the logged surface and the airframe.
    options : FlightOptions, optional
        The card, rates and noise (default :func:`jsbsim_options`). ``sim_rate_hz``, the gusts and the
        closed-loop options do not apply (JSBSim's rate; its own turbulence).
    seed : int
        The same seed gives the same flight (turbulence included).
    turbulence : Turbulence, optional
        JSBSim's Dryden turbulence (default none).
    grid : FrequencyGrid
        Grid of the config linearised when none is given.
    attitude_hold_rad_s : float
        Crossover of the pilot's attitude hold (:class:`Pilot`; 0: hands off, the aircraft flies the card
        alone).

    Raises
    ------
    ConfigError
        Bad aircraft, condition, trim, channels, options, or a flight that leaves the envelope.
    """
    opt = (options or jsbsim_options()).check()
    _refuse_loop_options(opt)
    lin = None
    if config is None:
        lin = linearize(aircraft, speed_kt, altitude_ft)
        config = parse_config(config_mapping(lin, grid), f"<JSBSim {aircraft} linearised at {speed_kt:g} kt, "
                                                         f"{altitude_ft:g} ft>")
    hidden = {k: [validate_effect(e, where=f"hidden.{k}") for e in v] for k, v in (hidden or {}).items()}
    surfaces = channel_surfaces(config)
    effects = _surface_effects(config, hidden, surfaces)
    trimmed = Trimmed(aircraft, speed_kt, altitude_ft)
    twin = Trimmed(aircraft, speed_kt, altitude_ft)      # measures the FCS gains and the trim's drift
    split = twin.surface_split()[1]
    warnings = drift_warnings(twin.point, twin.drift())
    pilot = pilot_for(aircraft, speed_kt, altitude_ft, attitude_hold_rad_s, split)
    turb_seed = _set_turbulence(trimmed, turbulence, seed)
    point = trimmed.point
    dt = point.dt_s

    rng = np.random.default_rng(seed)
    segments, duration_s = card_segments(config, opt)
    n = int(math.ceil(duration_s / dt)) + 2
    t_s = np.arange(n) * dt
    t_mid = t_s + 0.5 * dt               # JSBSim holds a step's surface: the card at the step's middle

    units = card_units(config)
    names = tuple(config.channels)
    pilot_flies = np.ones((n, 2), bool)                    # axes no manoeuvre sweeps (1 s clear of them)
    for seg in segments:
        ins = surfaces[seg.channel][0]
        moved = ins if seg.input_index is None else (ins[seg.input_index],)
        swept = [j for j, s in enumerate(("aileron", "elevator")) if s in moved]
        during = (t_s >= seg.start_s - 1.0) & (t_s <= seg.end_s + 1.0)
        for j in swept:
            pilot_flies[during, j] = False
    logged = {s: np.zeros(n) for s in SURFACES}            # the card's deviation on t_s (what is logged)
    flown = np.zeros((n, len(SURFACES)))                   # the same on t_mid (what the airframe is given)
    unit_series = {}
    for name, j in units:
        surface = surfaces[name][0][0 if j is None else j]
        col = SURFACES.index(surface)
        share = (units.index((name, j)), len(units))
        chans = names if j is None else ()
        unit_series[(name, j)] = channel_deviation(name, t_s, segments, opt, chans, j, share)
        logged[surface] += unit_series[(name, j)]
        flown[:, col] += channel_deviation(name, t_mid, segments, opt, chans, j, share)
    retrims = {}
    for s in SURFACES:                                     # every surface drawn, in order: reproducible
        trim_series = pilot_trim(t_s, segments, duration_s, opt, rng)
        retrims[s] = trim_series - trim_series[0]          # the constant is JSBSim's trim

    start, cpu = time.perf_counter(), time.process_time()
    done = fly(
        trimmed,
        flown,
        split,
        effects={s: HiddenEffects(effects[s], dt) for s in SURFACES},
        pilot=pilot,
        pilot_flies=pilot_flies,
    )
    jsbsim_s, jsbsim_cpu_s = time.perf_counter() - start, time.process_time() - cpu
    rates = done.rates
    rate_series = {r: rates[:, i] for i, r in enumerate(RATES)}
    for j, s in enumerate(SURFACES):
        logged[s] = logged[s] + done.pilot[:, j]

    surface_noise = (opt.surface_noise_rad * opt.noise, opt.surface_lsb_rad)
    gyro_noise = (opt.gyro_noise_rad_s * opt.noise, opt.gyro_lsb_rad_s)
    bands = band_noises(config, n, 1.0 / dt, opt, seed)
    surface_logged = {s: point.surfaces_rad[s] + retrims[s] + logged[s] for s in SURFACES}   # + the pilot's
    measured, inputs, outputs = {}, {}, {}
    for name, ch in config.channels.items():
        ins, outs = surfaces[name]
        for stream, surface in zip(ch.input_streams, ins):
            measured[(name, stream)] = (surface_logged[surface], *surface_noise)
        for i, (stream, rate) in enumerate(zip(ch.output_streams, outs)):
            band = bands.get(name, 0.0)
            band = band[i] if isinstance(band, np.ndarray) and band.ndim == 2 else band
            measured[(name, stream)] = (rate_series[rate] + band, *gyro_noise)
        for stream, spec in ch.extra_streams():
            if stream == "excitation":
                measured[(name, stream)] = (sum(unit_series[(name, j)] for j in
                                                (range(len(ins)) if ch.is_mimo else (None,))), 0.0, 0.0)
            elif stream == AIRSPEED_STREAM:      # true airspeed [m/s], as a pitot-static system logs it
                measured[(name, stream)] = (done.airspeed_kt * KT_TO_M_S, AIRSPEED_NOISE_M_S, 0.0)
            else:
                measured[(name, stream)] = (surface_logged[_surface_of(spec, name)], *surface_noise)
        if ch.trigger is not None:
            active = np.zeros(n)
            kinds = SWEEP_SEGMENTS + (("doublet",) if opt.excitation == "doublet" else ())
            for seg in segments:
                if seg.channel == name and seg.kind in kinds:
                    active[(t_s >= seg.start_s) & (t_s <= seg.end_s)] = 1.0
            measured[(name, "trigger")] = (active, 0.0, 0.0)
        trims = {r: rates[0, RATES.index(r)] for r in RATES}
        if ch.is_mimo:
            inputs[name] = np.stack([logged[s] for s in ins])
            outputs[name] = np.stack([rate_series[r] - trims[r] for r in outs])
        else:
            inputs[name] = logged[ins[0]]
            outputs[name] = rate_series[outs[0]] - trims[outs[0]]
    topics = sample_topics(plan_topics(config), measured, t_s, duration_s, opt, rng)
    flight = SimulatedFlight(
        topics=topics,
        segments=segments,
        truth=truth_models(config, hidden),
        hidden=hidden,
        t_s=t_s,
        inputs=inputs,
        outputs=outputs,
        duration_s=duration_s,
        start_time_s=opt.start_time_s,
        seed=seed,
        options=opt,
    )
    return JSBSimFlight(flight=flight, config=config, point=point, linearization=lin, surfaces=surfaces,
                        surface_effects={s: e for s, e in effects.items() if e}, turbulence=turbulence,
                        turbulence_seed=turb_seed, steps=n, jsbsim_s=jsbsim_s, jsbsim_cpu_s=jsbsim_cpu_s,
                        flown=done, pilot=pilot, warnings=warnings)


def _refuse_loop_options(opt: FlightOptions) -> None:
    for name, value, flag in (("closed_loop_gain_margin_db", opt.closed_loop_gain_margin_db,
                               "--closed-loop-gain-margin-db"),
                              ("loop_delay_s", opt.loop_delay_s, "--loop-delay-s"),
                              ("log_excitation_topic", opt.log_excitation_topic, "--log-excitation"),
                              ("coupling", opt.coupling, "--coupling"),
                              ("cross_responses", opt.cross_responses, "--cross-response")):
        if value:
            raise ConfigError(
                f"{flag}: not available with --jsbsim (JSBSim flies the card open loop; simulation "
                f"option {name})"
            )
    if opt.turbulence_rms_rad_s:
        raise ConfigError(
            "simulation option turbulence_rms_rad_s: with --jsbsim, --turbulence is JSBSim's own "
            "(light, moderate, severe or SEVERITY[:WIND_KT])"
        )
