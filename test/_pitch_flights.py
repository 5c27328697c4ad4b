"""The pitch-rate flights the estimator and alignment tests measure (test helper, not a test module).

The known system is the paper's pitch-rate model (DESIGN.md example: -133.7 s - 990.76 over
s^2 + 23.37 s + 235.93) with a 20 ms delay, simulated with scipy.signal on a 1 kHz grid.
"""
import numpy as np
from scipy import signal

from gap_validation.core.estimator import FrequencyResponseEstimator

PITCH_NUM = [-133.7, -990.76]
PITCH_DEN = [1.0, 23.37, 235.93]
DELAY_S = 0.02
FINE_HZ = 1000.0
W_RAD_S = np.logspace(0.0, np.log10(60.0), 40)        # the config's default grid (1-60 rad/s, 40 points)
SWEEPS = ((20.0, 70.0), (128.0, 60.0), (240.0, 80.0))  # (start_s, length_s)


def log_sweep(t_s, f0_hz, f1_hz, length_s, amplitude, taper_s=1.0):
    t = np.asarray(t_s, dtype=float)
    rate = np.log(f1_hz / f0_hz) / length_s
    phase = 2.0 * np.pi * f0_hz * np.expm1(rate * t) / rate
    taper = np.clip(np.minimum(t, length_s - t) / taper_s, 0.0, 1.0)
    return np.where((t >= 0) & (t <= length_s),
                    amplitude * np.sin(phase) * (0.5 - 0.5 * np.cos(np.pi * taper)), 0.0)


def doublet(t_s, start_s, half_s, amplitude):
    t = np.asarray(t_s, dtype=float)
    return (amplitude * ((t >= start_s) & (t < start_s + half_s))
            - amplitude * ((t >= start_s + half_s) & (t < start_s + 2 * half_s)))


def true_response(w_rad_s):
    return signal.freqs(PITCH_NUM, PITCH_DEN, w_rad_s)[1] * np.exp(-1j * w_rad_s * DELAY_S)


def simulate(u, fine_hz=FINE_HZ):
    """Pitch rate for elevator ``u`` sampled at ``fine_hz``, starting in trim."""
    bd, ad, _ = signal.cont2discrete((PITCH_NUM, PITCH_DEN), 1.0 / fine_hz, method="foh")
    dc = PITCH_NUM[-1] / PITCH_DEN[-1]
    y = signal.lfilter(np.ravel(bd), ad, u - u[0]) + dc * u[0]
    lag = int(round(DELAY_S * fine_hz))
    return np.concatenate((np.full(lag, y[0]), y[:-lag]))


def flight(duration_s=330.0, sweeps=SWEEPS, gust_std=0.0, gust_band_rad_s=(20.0, 30.0), seed=0):
    """Noise-free 1 kHz flight: log sweeps 0.1-12 Hz; between them doublets, a trim step and a trim ramp.

    Returns t [s], elevator u [rad], pitch rate y [rad/s] (including an optional band-limited gust).
    """
    t = np.arange(0.0, duration_s, 1.0 / FINE_HZ)
    u = np.full(t.size, -0.02)
    for start, length in sweeps:
        u += log_sweep(t - start, 0.1, 12.0, length, 0.05)
    u += doublet(t, 98.0, 1.0, 0.05) + 0.01 * (t >= 110.0) + doublet(t, 200.0, 1.5, 0.04)
    u += np.clip((t - 212.0) / 12.0, 0.0, 1.0) * -0.015
    y = simulate(u) + 0.01                                      # + gyro bias
    if gust_std:
        rng = np.random.default_rng(seed + 1000)
        sos = signal.butter(4, np.array(gust_band_rad_s) / (2 * np.pi), btype="bandpass", fs=FINE_HZ,
                            output="sos")
        gust = signal.sosfilt(sos, rng.normal(size=t.size))
        y = y + gust_std * gust / gust.std()
    return t, u, y


def measure(t, u, y, rate_in_hz, rate_out_hz, seed, noise_in=3e-4, noise_out=0.1, jitter_s=0.0, drop=0.0):
    """Sample the 1 kHz flight as two sensor streams (noise, timestamp jitter, dropped samples)."""
    rng = np.random.default_rng(seed)

    def times(rate):
        ts = np.arange(t[0], t[-1], 1.0 / rate)
        if jitter_s:
            ts = ts + rng.uniform(-jitter_s, jitter_s, ts.size)
        ts = ts[(ts >= t[0]) & (ts <= t[-1])]
        if drop:
            ts = ts[rng.random(ts.size) >= drop]
        return ts

    ti, to = times(rate_in_hz), times(rate_out_hz)
    ui = np.interp(ti, t, u) + rng.normal(0.0, noise_in, ti.size)
    yo = np.interp(to, t, y) + rng.normal(0.0, noise_out, to.size)
    return ti, ui, to, yo


def estimate(ti, ui, to, yo, **options):
    est = FrequencyResponseEstimator(W_RAD_S, **options)
    est.add_time_histories(ti, ui, to, yo)
    est.flush()
    return est


def fraction_within(est_h, ref_h, sigma, k=3.0, dof=np.inf):
    """Fraction of frequencies where |H - H_ref| / |H_ref| is within k noise scales ``sigma``; with ``dof``
    degrees of freedom of the noise estimate, k of the F law (a Rayleigh-equivalent k, as the diagnosis
    uses)."""
    r = np.abs(est_h - ref_h) / np.abs(ref_h) / np.asarray(sigma, float)
    d = np.maximum(np.asarray(dof, float), 0.5)
    k_f = np.where(np.isfinite(d), np.sqrt(2.0 * d * np.log1p(r ** 2 / (2.0 * d))), r)
    return float(np.mean(k_f <= k))


def _nbytes(state):
    return sum(np.asarray(v).nbytes for v in state.values())


def _chunks(streams, step_s=7.0):
    ti, ui, to, yo = streams
    edges = np.arange(0.0, max(ti[-1], to[-1]) + step_s, step_s)
    ia, ib = np.searchsorted(ti, edges), np.searchsorted(to, edges)
    return [(ti[a0:a1], ui[a0:a1], to[b0:b1], yo[b0:b1])
            for a0, a1, b0, b1 in zip(ia[:-1], ia[1:], ib[:-1], ib[1:])]


def _feed(est, chunks):
    for ti, ui, to, yo in chunks:
        est.add_input(ti, ui)
        est.add_output(to, yo)
