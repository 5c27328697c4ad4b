"""The closed loop of a synthetic flight (issue 13), ROS-free: a rate damper closing the loop around each
channel with the manoeuvre injected inside it (the injected signal logged as the excitation), turbulence,
interconnected surfaces (``coupling``) and the response of one channel's rate to another channel's surface
(``cross_responses``). Kept apart from the open-loop flight of :mod:`gap_validation.core.simulation`: without
these options (:class:`~gap_validation.core.flight_options.FlightOptions`, which checks them) a flight is
exactly what it was.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from gap_validation.core.config import ValidationConfig
from gap_validation.core.effects import EFFECTS
from gap_validation.core.errors import ConfigError
from gap_validation.core.flight_options import FlightOptions
from gap_validation.core.signals import lowpass_noise

if TYPE_CHECKING:  # pragma: no cover
    from gap_validation.core.models import LinearModel

__all__ = ["WASHOUT_RAD_S", "damper_gain", "LoopResponses", "loop_responses"]

#: Spawn keys of the closed loop's random streams (gyro noise fed back, turbulence).
_LOOP_NOISE_STREAM, _TURBULENCE_STREAM = 2, 3


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
class LoopResponses:
    """A closed-loop (or coupled) flight: the surfaces, the responses and the gyro noise fed back.

    Attributes
    ----------
    surfaces : dict
        Channel -> surface deflection deviation [rad] on the simulation grid (the manoeuvre, the damper's
        feedback and the coupled surfaces).
    outputs : dict
        Channel -> the rate's response to the surfaces [rad/s] (cross responses included).
    gains : dict
        Channel -> the rate damper's gain K (closed loop only).
    gyro_noise : dict
        Channel -> the gyro noise the damper read and fed back [rad/s] (closed loop only).
    """

    surfaces: dict
    outputs: dict
    gains: dict
    gyro_noise: dict

    def measured_output(self, name: str, disturbed: np.ndarray, opt: FlightOptions) -> tuple:
        """``(series, noise std, lsb)`` of the logged rate: the rate the damper read (gyro noise included: the
        same noise drives the surface), no further noise at sampling.

        Parameters
        ----------
        name : str
            The channel.
        disturbed : ndarray
            Its rate with gusts, turbulence and band noise on the simulation grid [rad/s].
        opt : FlightOptions
            Gyro noise and resolution (an open-loop channel's noise is drawn at sampling).
        """
        noise = self.gyro_noise.get(name)
        if noise is None:                                  # open loop: sensor noise drawn at sampling
            return disturbed, opt.gyro_noise_rad_s * opt.noise, opt.gyro_lsb_rad_s
        return disturbed + noise, 0.0, opt.gyro_lsb_rad_s


def _turbulence(n: int, fs_hz: float, opt: FlightOptions, rng: np.random.Generator) -> np.ndarray:
    """Turbulence at the rate: white noise through a first-order low-pass at ``turbulence_bandwidth_rad_s``,
    scaled to ``turbulence_rms_rad_s``."""
    return lowpass_noise(n, fs_hz, opt.turbulence_bandwidth_rad_s, opt.turbulence_rms_rad_s, rng, order=1)


def _cross_model(gain: float, wn: float, damping: float):
    from gap_validation.core.models import LinearModel

    return LinearModel.from_tf([gain * wn * wn], [1.0, 2.0 * damping * wn, wn * wn])


def loop_responses(config: ValidationConfig, truth: dict, references: dict, gusts: dict, bands: dict,
                   t_s: np.ndarray, fs_hz: float, opt: FlightOptions, seed: int) -> LoopResponses | None:
    """Surfaces and responses of a closed-loop, turbulent or coupled flight; None for an open-loop flight
    without them (the flight is then exactly the one of the options before issue 13).

    Closed loop: per channel ``u = z^-Nc (r - K (y + d + n))`` with ``r`` the manoeuvre (injected inside the
    loop), ``d`` gusts, turbulence and band noise at the rate, ``n`` the gyro noise, ``K`` the rate damper of
    :func:`damper_gain` and ``Nc`` the loop delay (default one surface sample); ``y = P u`` with P the truth
    discretised on the simulation grid (zero-order hold, delay in whole samples). Solved exactly with linear
    filters. The turbulence is added to ``gusts`` (in place) so the logged rate holds it.

    Parameters
    ----------
    config : ValidationConfig
        The channels (SISO only).
    truth : dict
        Channel -> the true model.
    references : dict
        Channel -> the manoeuvre the card commands [rad] on ``t_s`` (injected inside the loop).
    gusts : dict
        Channel -> gusts at the rate [rad/s]; the turbulence is added to it in place.
    bands : dict
        Channel -> band noise at the rate [rad/s] (channels without it absent).
    t_s : ndarray
        The simulation grid [s].
    fs_hz : float
        Its rate [Hz].
    opt : FlightOptions
        The closed-loop, turbulence, coupling and cross-response options.
    seed : int
        The flight's seed (the loop's gyro noise and the turbulence have their own streams of it).

    Raises
    ------
    ConfigError
        A MIMO channel, an effect simulated on the surface samples in a closed loop, or a damper that does not
        stabilise the discretised loop.
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
    return LoopResponses(surfaces, outputs, gains, noise)
