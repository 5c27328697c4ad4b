"""Excitation waveforms and coloured noise, ROS-free (arrays only): what the synthetic flight
(:mod:`gap_validation.core.simulation`) flies and what disturbs it.

Sweeps are exponential (log) chirps, ``w(t) = w0 (w1/w0)^(t/T)``, so every octave receives the same time
(:func:`log_sweep`); multisines are Schroeder-phased (:func:`multisine`); multisteps (3-2-1-1, doublets) have
raised-cosine steps (:func:`multistep`). The noises are white noise through a Butterworth filter, scaled to
an RMS: a low-pass for gusts and turbulence (:func:`lowpass_noise`), a band-pass for a narrow-band output
disturbance such as a vibration (:func:`band_noise`). Every noise draws from the generator it is given, so
the caller decides the streams and their order.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["log_sweep", "doublet", "multisine", "multistep", "band_noise", "lowpass_noise"]

#: Order of the band-pass filter of the band noise (Butterworth; the band-pass doubles it).
_BAND_NOISE_ORDER = 4


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


def lowpass_noise(n: int, fs_hz: float, bandwidth_rad_s: float, rms: float, rng: np.random.Generator,
                  order: int = 2) -> np.ndarray:
    """Coloured disturbance: white noise through a Butterworth low-pass, scaled to ``rms``.

    The flight's gusts (order 2) and the closed loop's turbulence (order 1) are this noise.

    Parameters
    ----------
    n : int
        Samples.
    fs_hz : float
        Sample rate [Hz].
    bandwidth_rad_s : float
        Corner frequency of the low-pass [rad/s].
    rms : float
        RMS of the result (over its n samples).
    rng : numpy.random.Generator
        Source of the white noise (n samples plus 5 s of filter start-up are drawn even when ``rms`` is 0).
    order : int
        Order of the Butterworth low-pass.
    """
    white = rng.standard_normal(n + int(5 * fs_hz))
    if rms == 0.0:
        return np.zeros(n)
    from scipy import signal  # here: scipy.signal is slow to import

    b, a = signal.butter(order, bandwidth_rad_s / (2 * math.pi), fs=fs_hz)
    coloured = signal.lfilter(b, a, white)[-n:]
    return coloured * (rms / max(float(np.std(coloured)), 1e-300))
