#!/usr/bin/env python3
"""The estimate a model would give through the estimator (``spectra.expected_estimate``), against the same
computation written frequency by frequency (the reference, here), on the bundled flight's pooled estimate of
every channel (the estimates that keep their band sums).

The diagnosis calls it once per candidate model and parameter step (every fit evaluation), the node's cheap
results once per channel when the trim changed; ``expected_estimate`` evaluates the model once for every
frequency's nodes and check points together and solves the bands as one stack. Printed: CPU time of each (best
of ``--repeat``), their ratio (goal < 1), and the largest relative difference of the two results.

    python benchmarks/bench_expected.py [--repeat 5]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def reference(sums, w_rad_s, band_fraction, model_response):
    """One frequency at a time: the model at its Chebyshev nodes, a least-squares polynomial, its error on a
    fine grid, the band's solve (the textbook form of ``expected_estimate``)."""
    from gap_validation.core.spectra import EXTRA_ORDER

    w = np.asarray(w_rad_s, float)
    expected, error = np.full(w.size, np.nan + 0j), np.zeros(w.size)
    cols = sums.h_columns()
    degree = sums.order + EXTRA_ORDER
    n_nodes = 3 * (degree + 1)
    cheb = np.cos(np.pi * (np.arange(n_nodes) + 0.5) / n_nodes)
    fine = np.linspace(-1.0, 1.0, 101)
    for i in range(w.size):
        if sums.records[i] == 0:
            continue
        lo, hi = float(sums.r_lo[i]), float(sums.r_hi[i])
        mid, half = 0.5 * (lo + hi), max(0.5 * (hi - lo), 1e-12)
        scale = band_fraction * w[i]
        nodes = mid + half * cheb
        coef = np.linalg.lstsq(np.vander(nodes, degree + 1, increasing=True),
                               np.asarray(model_response(w[i] + scale * nodes), complex), rcond=None)[0]
        if sums.inputs > 1:
            coef = np.concatenate([coef, np.zeros((sums.inputs - 1) * (degree + 1), complex)])
        points = mid + half * fine
        fit = np.vander(points, degree + 1, increasing=True) @ coef[:degree + 1]
        fit_err = np.max(np.abs(fit - model_response(w[i] + scale * points)))
        try:
            theta = np.linalg.solve(sums.zf[i][:, cols], sums.zf[i] @ coef)
        except np.linalg.LinAlgError:
            continue
        expected[i] = theta[0]
        centre = abs(complex(model_response(np.array([w[i]]))[0]))
        error[i] = fit_err / centre if centre > 0 else np.inf
    return expected, error


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    from gap_validation.bag.replay import replay
    from gap_validation.core.config import load_config
    from gap_validation.core.spectra import expected_estimate

    config = load_config(ROOT / "config" / "ultrastick25e.yaml")
    validator = replay([ROOT / "bags" / "ultrastick25e_flight"], config, diagnose=False).validator
    cases = []
    for name, channel in config.channels.items():
        for est in [validator.estimate(name), *validator.sweep_estimates(name)]:
            if est is not None and est.sums is not None:
                model = channel.model
                cases.append((est, lambda w, m=model: m.freqresp(w) * np.exp(-0.03j * np.asarray(w))))

    def run(fn) -> tuple[float, list]:
        best, out = np.inf, []
        for _ in range(args.repeat):
            start = time.process_time()
            out = [fn(e.sums, e.w_rad_s, e.band_fraction, f) for e, f in cases]
            best = min(best, time.process_time() - start)
        return best, out

    ours, got = run(expected_estimate)
    ref, want = run(reference)
    worst = 0.0
    for (a, ea), (b, eb) in zip(got, want):
        ok = np.isfinite(b)
        assert np.array_equal(ok, np.isfinite(a))
        worst = max(worst, float(np.max(np.abs(a[ok] - b[ok]) / np.abs(b[ok]), initial=0.0)),
                    float(np.max(np.abs(ea - eb), initial=0.0)))
    print(
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; {len(cases)} pooled estimates "
        "(the "
        f"bundled flight's channels), the model with a 30 ms delay"
    )
    print(
        f"expected_estimate {ours * 1e3:.1f} ms CPU; frequency by frequency {ref * 1e3:.1f} ms: ratio "
        f"{ours / ref:.3f} (goal < 1); largest difference {worst:.1e} (relative, and of the expansion error)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
