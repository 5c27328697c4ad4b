"""Throughput of the online frequency-response estimator, and its cost against a scipy batch estimate.

Run: ``python benchmarks/bench_estimator.py [--minutes 20] [--repeat 3]``

A synthetic flight (paper pitch model, a 60 s log sweep 0.1-12 Hz every 90 s, output noise) is fed to
:class:`~gap_validation.core.estimator.FrequencyResponseEstimator`

* as raw sensor streams: IMU (output) at 1 kHz and surfaces (input) at 100 Hz, and
* as grid-rate streams: both at the estimator's 100 Hz grid,

and the same response is computed in batch with ``scipy.signal.csd`` / ``welch`` on the grid-rate data of
every detected sweep: each sweep's whole-record cross and auto spectra (one rectangular segment, the record's
own resolution, as the estimator transforms it) summed over the bins within 10 % of each analysis frequency
(the smoothed ETFE: the estimator's band without its local polynomial and transient terms), and the cheapest
batch Welch (one Hann window of 256 samples for every frequency). Ratio = our time / batch time. Times are
the best of ``--repeat`` runs. The estimator's checkpoint state is measured after half and all of the flight
(constant memory). Prints one table.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy import signal

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gap_validation.core.estimator import FrequencyResponseEstimator  # noqa: E402

PITCH_NUM = [-133.7, -990.76]
PITCH_DEN = [1.0, 23.37, 235.93]
GRID_HZ = 100.0


def log_sweep(t, f0_hz, f1_hz, length_s, amplitude):
    rate = np.log(f1_hz / f0_hz) / length_s
    phase = 2 * np.pi * f0_hz * np.expm1(rate * t) / rate
    taper = np.clip(np.minimum(t, length_s - t), 0.0, 1.0)
    return np.where(
        (t >= 0) & (t <= length_s), amplitude * np.sin(phase) * np.sin(0.5 * np.pi * taper) ** 2, 0.0
    )


def make_flight(minutes: float, rate_hz: float, seed: int = 0):
    """Surface and pitch-rate samples at ``rate_hz`` (a sweep every 90 s)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 60.0 * minutes, 1.0 / rate_hz)
    u = -0.02 + log_sweep(np.mod(t, 90.0) - 15.0, 0.1, 12.0, 60.0, 0.05) + rng.normal(0.0, 3e-4, t.size)
    bd, ad, _ = signal.cont2discrete((PITCH_NUM, PITCH_DEN), 1.0 / rate_hz, method="foh")
    y = signal.lfilter(np.ravel(bd), ad, u - u[0]) + rng.normal(0.0, 0.05, t.size)
    return t, u, y


def best_time(func, repeat: int) -> tuple[float, object]:
    best, out = np.inf, None
    for _ in range(repeat):
        start = time.perf_counter()
        out = func()
        best = min(best, time.perf_counter() - start)
    return best, out


def run_estimator(w, t_in, u, t_out, y):
    est = FrequencyResponseEstimator(w)
    est.add_time_histories(t_in, u, t_out, y)
    est.flush()
    return est


def batch_estimate(x, y, spans_k, w_rad_s, band_fraction=0.1):
    """scipy whole-record csd/welch per sweep, summed over each frequency's band and over sweeps (H1)."""
    sxx = np.zeros(w_rad_s.size)
    sxy = np.zeros(w_rad_s.size, complex)
    for a, b in spans_k:
        kw = dict(fs=GRID_HZ, window="boxcar", nperseg=b - a, detrend="constant")
        f, pxy = signal.csd(x[a:b], y[a:b], **kw)
        pxx = signal.welch(x[a:b], **kw)[1]
        signal.welch(y[a:b], **kw)                                     # Gyy, for coherence
        w_bins = 2 * np.pi * f
        lo = np.searchsorted(w_bins, w_rad_s * (1 - band_fraction))
        hi = np.searchsorted(w_bins, w_rad_s * (1 + band_fraction), side="right")
        cxy, cxx = np.concatenate(([0], np.cumsum(pxy))), np.concatenate(([0], np.cumsum(pxx)))
        sxy += cxy[hi] - cxy[lo]
        sxx += cxx[hi] - cxx[lo]
    return sxy / sxx


def state_bytes(est) -> int:
    return sum(
        np.asarray(v).nbytes for v in est.state_dict().values() if isinstance(v, (np.ndarray, int, float))
    )


def batch_single_window(x, y, spans_k, w_rad_s, n_win=256):
    """The cheapest batch: one Welch window for every frequency (interpolated to the grid)."""
    kw = dict(fs=GRID_HZ, window="hann", nperseg=n_win, noverlap=n_win // 2, detrend="constant")
    sxy = sxx = 0.0
    for a, b in spans_k:
        f, pxy = signal.csd(x[a:b], y[a:b], **kw)
        sxy = sxy + pxy
        sxx = sxx + signal.welch(x[a:b], **kw)[1]
        signal.welch(y[a:b], **kw)
    h = sxy / sxx
    f_w = w_rad_s / (2 * np.pi)
    return np.interp(f_w, f, h.real) + 1j * np.interp(f_w, f, h.imag)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=20.0, help="simulated flight length [min]")
    parser.add_argument("--repeat", type=int, default=3, help="runs per measurement (best is kept)")
    args = parser.parse_args(argv)

    t_out, _, y_fast = make_flight(args.minutes, 1000.0)
    t_grid, u_grid, y_grid = make_flight(args.minutes, GRID_HZ)
    u_in = u_grid                                   # surfaces at 100 Hz
    y_out = np.interp(t_out, t_grid, y_grid) + np.random.default_rng(1).normal(0.0, 0.05, t_out.size)
    del y_fast

    rows = []
    for n_freq in (40, 100):
        w = np.logspace(0.0, np.log10(60.0), n_freq)
        t_raw, est_raw = best_time(lambda: run_estimator(w, t_grid, u_in, t_out, y_out), args.repeat)
        t_ours, est = best_time(lambda: run_estimator(w, t_grid, u_grid, t_grid, y_grid), args.repeat)
        spans = [(int(round(s.start_s * GRID_HZ)), int(round(s.end_s * GRID_HZ))) for s in est.sweeps]
        t_batch, h_batch = best_time(lambda: batch_estimate(u_grid, y_grid, spans, w), args.repeat)
        t_single, _ = best_time(lambda: batch_single_window(u_grid, y_grid, spans, w), args.repeat)
        h_ours = est.averaged().response
        agree = float(np.nanmedian(np.abs(h_ours - h_batch) / np.abs(h_batch)))
        half = t_grid <= t_grid[-1] / 2
        mem = (state_bytes(run_estimator(w, t_grid[half], u_grid[half], t_grid[half], y_grid[half])),
               state_bytes(est))
        rows.append((n_freq, (t_grid.size + t_out.size) / t_raw, t_out.size / t_raw, t_grid.size / t_ours,
                     t_ours / t_batch, t_ours / t_single, est.n_sweeps, agree, mem))

    print(f"flight: {args.minutes:g} min, {rows[0][6]} sweeps; best of {args.repeat}; "
          f"grid {GRID_HZ:g} Hz; ratio = our time / scipy batch time on the same grid data")
    header = ("freqs", "raw samples/s (1 kHz+100 Hz)", "IMU samples/s", "grid pairs/s",
              "ratio vs csd (whole records)", "ratio vs csd (one window)", "median |dH|/|H| vs batch",
              "state kB (half, whole flight)")
    print(" | ".join(header))
    for n_freq, raw, imu, grid, ratio, ratio1, _, agree, mem in rows:
        print(f"{n_freq:5d} | {raw:28.3g} | {imu:13.3g} | {grid:12.3g} | {ratio:28.2f} | {ratio1:25.2f} | "
              f"{agree:24.2e} | {mem[0] / 1e3:.0f}, {mem[1] / 1e3:.0f}")


if __name__ == "__main__":
    main()
