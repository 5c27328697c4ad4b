"""Exact MIMO nu-gap of 2x2, 10-state models: time per pair, and against a dense-grid reference.

Run: ``python benchmarks/bench_mimo_nugap.py [--pairs 50] [--states 10] [--points 20000] [--repeat 3] [--seed
0]``

Random lateral-directional-like models (lightly damped and real modes from 0.1 to 50 rad/s, some unstable,
an integrator now and then) P1, and P2 with every matrix perturbed by a few percent. For each pair the exact
nu-gap (:func:`gap_validation.core.metrics.nugap`: minimal realizations, normalised coprime factors, the
winding-number condition, H-infinity level sets, peak refined) is timed, and the same quantity is computed
by brute force in the same run: kappa(w) = sigma_max((I + P2 P2*)^-1/2 (P2 - P1) (I + P1* P1)^-1/2) on a
dense logarithmic grid (``--points`` from 1e-6 to 1e4 rad/s) and its largest value. Prints the
median and worst time of the exact computation, the time of the dense grid, their ratio, and how the values
compare (the exact sup is never below the grid's and agrees with it where the grid resolves the peak).
Each time is the best of ``--repeat`` runs (the machine is shared: the CPU time of the process and the load
average are printed too), every run from fresh model objects (no cached minimal realization).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gap_validation.core.metrics import chordal_distance, nugap, winding_condition  # noqa: E402
from gap_validation.core.models import MimoModel  # noqa: E402


def random_model(rng: np.random.Generator, states: int, inputs: int = 2, outputs: int = 2) -> MimoModel:
    """A real model in modal form: second-order blocks (0.1-50 rad/s, damping 0.05-0.9) and real poles."""
    blocks, n = [], 0
    while n < states:
        if states - n >= 2 and rng.random() < 0.6:
            wn, zeta = 10 ** rng.uniform(-1, 1.7), rng.uniform(0.05, 0.9)
            sigma, omega = -zeta * wn, wn * np.sqrt(1 - zeta * zeta)
            blocks.append(np.array([[sigma, omega], [-omega, sigma]]))
            n += 2
        else:
            pole = -10 ** rng.uniform(-1, 1.5) * (1 if rng.random() < 0.85 else -0.2)
            blocks.append(np.array([[0.0 if rng.random() < 0.1 else pole]]))
            n += 1
    a = np.zeros((states, states))
    k = 0
    for block in blocks:
        a[k:k + block.shape[0], k:k + block.shape[0]] = block
        k += block.shape[0]
    b = rng.normal(size=(states, inputs)) * 3.0
    c = rng.normal(size=(outputs, states)) * 3.0
    d = rng.normal(size=(outputs, inputs)) * 0.1 * (rng.random() < 0.3)
    return MimoModel(a, b, c, d)


def perturbed(rng: np.random.Generator, model: MimoModel, size: float) -> MimoModel:
    a, b, c, d = model.state_space()
    scale = lambda m: m * (1.0 + size * rng.normal(size=m.shape))  # noqa: E731
    return MimoModel(scale(a), scale(b), scale(c), scale(d))


def dense_nugap(m1: MimoModel, m2: MimoModel, points: int) -> tuple[float, float]:
    """Largest chordal distance over a dense grid (the winding condition assumed, as on data)."""
    # not w = 0: next to an integrator P(j0) is huge and the formula loses it
    w = np.geomspace(1e-6, 1e4, points)
    with np.errstate(all="ignore"):
        kappa = chordal_distance(m1.freqresp(w), m2.freqresp(w))
    k = int(np.nanargmax(kappa))
    return float(kappa[k]), float(w[k])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=50)
    parser.add_argument("--states", type=int, default=10)
    parser.add_argument("--points", type=int, default=20000)
    parser.add_argument("--perturbation", type=float, default=0.05)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    pairs = []
    while len(pairs) < args.pairs:
        m1 = random_model(rng, args.states)
        m2 = perturbed(rng, m1, args.perturbation)
        pairs.append((m1, m2))
    nugap(*pairs[0])  # warm up (imports, caches of scipy)
    exact_times, dense_times, rows = [], [], []
    cpu_times = []
    for m1, m2 in pairs:
        best, best_cpu = np.inf, np.inf
        for _ in range(args.repeat):
            # no cached minimal realization
            m1, m2 = MimoModel(*m1.state_space()), MimoModel(*m2.state_space())
            start, start_cpu = time.perf_counter(), time.process_time()
            value, w_peak = nugap(m1, m2)
            best = min(best, time.perf_counter() - start)
            best_cpu = min(best_cpu, time.process_time() - start_cpu)
        exact_times.append(best)
        cpu_times.append(best_cpu)
        best = np.inf
        for _ in range(args.repeat):
            start = time.perf_counter()
            grid_value, grid_w = dense_nugap(m1, m2, args.points)
            best = min(best, time.perf_counter() - start)
        dense_times.append(best)
        rows.append((value, w_peak, grid_value, grid_w, winding_condition(m1, m2).satisfied))
    exact_times, dense_times = np.array(exact_times), np.array(dense_times)
    values = np.array(rows, dtype=float)
    held = values[:, 4] == 1.0
    below = values[held, 0] - values[held, 2]
    print(f"exact MIMO nu-gap, 2x2, {args.states} states per model, {args.pairs} random pairs "
          f"(perturbation {args.perturbation:g}, seed {args.seed}):")
    print(
        f"  exact:       median {1e3 * np.median(exact_times):6.2f} ms, worst {1e3 * exact_times.max():6.2f} "
        "ms "
        f"(goal: under 10 ms); CPU time median {1e3 * np.median(cpu_times):.2f} ms, worst "
        f"{1e3 * max(cpu_times):.2f} ms; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    )
    print(f"  dense grid:  median {1e3 * np.median(dense_times):6.2f} ms ({args.points} frequencies, "
          f"kappa from singular value decompositions)")
    print(f"  time ratio exact / dense grid: median {np.median(exact_times / dense_times):.3f}")
    print(f"  winding condition held for {int(held.sum())} of {args.pairs} pairs (nu-gap 1 for the others)")
    if held.any():
        rel = below / np.maximum(values[held, 2], 1e-300)
        print(f"  exact - dense sup where it held: min {below.min():.2e} (never negative beyond round-off), "
              f"median relative {np.median(rel):.2e}, max relative {rel.max():.2e}")
        print(f"  nu-gap values: median {np.median(values[held, 0]):.4f}, range {values[held, 0].min():.4f}-"
              f"{values[held, 0].max():.4f}")


if __name__ == "__main__":
    main()
