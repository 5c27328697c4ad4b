"""Exact SISO nu-gap of 10-state pairs: time per pair against the implementation before issue 27, same run.

Run: ``python benchmarks/bench_nugap.py [--pairs 200] [--states 10] [--repeat 3] [--seed 0]
[--reference e4f6fdf]``

Random models P1 of ``--states`` poles (lightly damped pairs and real poles from 0.1 to 50 rad/s, about one in
ten pairs or real poles unstable, now and then an integrator) and 0 to ``states - 1`` zeros, and P2 with every
coefficient of P1 perturbed by ``--perturbation`` (a model against a close one, as in a validation; some
pairs fail the winding-number condition). Each pair is timed with
:func:`gap_validation.core.metrics.nugap` (winding condition, grid over the feature frequencies, refinement of
the sup) and with the reference, the module ``gap_validation/core/metrics.py`` of the git revision
``--reference`` (default: main before the speed-up of issue 27), loaded from git under another name and run
in the same process, alternately. Each time is the best of ``--repeat`` runs; wall and CPU time are printed
with the load average (the machine is shared).

Equality, checked on every pair and on the fixed corner cases of ``test/test_metrics.py`` (the paper's pair,
gains from 1e-6 to 1e8, poles on the axis, integrators, delays): nu-gap and epsilon within 1e-9 (relative,
1e-15 absolute) of the reference's, and the same winding-number verdicts (satisfied, where it fails, reason,
method); the peak frequencies are compared too (they are resolved to about 1e-7: the sup is flat there). A
dense grid (2000 frequencies, ``LinearModel.freqresp``) gives an independent lower bound of the sup. The exit
status is 1 when any check fails.
"""
from __future__ import annotations

import argparse
import importlib.util
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gap_validation.core import metrics  # noqa: E402
from gap_validation.core.models import LinearModel  # noqa: E402

W0 = 27.7200457464113
CORNER_CASES = [  # (num1, den1, delay1, num2, den2, delay2): test/test_metrics.py's pinned pairs
    ([18.75, 225.0], [1.0, 9.0, 225.0], 0.0, [18.75, 225.0], [1.0, 7.22, 246.5], 0.0),
    ([100.0], [2.0, 1.0], 0.0, [100.0], [2.0, -1.0], 0.0),
    ([100.0], [2.0, 1.0], 0.0, [100.0], [1.0, 2.0, 1.0], 0.0),
    ([1e-6], [1.0, 0.0], 0.0, [2e-6], [1.0, 0.0], 0.0),
    ([1e8], [1.0, 1.0], 0.0, [1.1e8], [1.0, 1.0], 0.0),
    ([-50.9], [1.0, 0.0], 0.0, [-56.07], [1.0, -0.002125], 0.0),
    (np.polymul([-3.111686845952856], [1.0, 0.14255673341511005]),
     np.polymul([1.0, 0.0, W0**2], [1.0, 0.9590014583306136]), 0.0,
     np.polymul([-2.898949107865159], [1.0, 0.14711222759321194]),
     np.polymul([1.0, 0.0, W0**2], [1.0, 0.9844060387689597]), 0.0),
    ([1.0], [1.0, 0.0, 1.0], 0.0, [1.0], [1.0, 0.2, 1.0], 0.0),
    ([1.0], [1.0, 1.0, 0.0], 0.0, [1.2], [1.0, 1.3, 0.0], 0.0),
    ([1.0], [1.0, -1.0], 0.0, [1.0], [1.0, -1.1], 0.0),
    ([1.0], [1.0, 1.0], 0.0, [-1.0], [1.0, 1.0], 0.0),
    ([1.0], [1.0, 1.0], 0.0, np.polymul([1.0], [1.0, -3.0]), np.polymul([1.0, 1.0], [1.0, -3.0]), 0.0),
    ([1.0], [1.0, 1.0], 0.1, [1.0], [1.0, 1.0], 0.0),
    ([1.0], [1.0, -1.0], 0.2, [1.0], [1.0, -1.0], 0.0),
    ([1.0], [1.0, 2.0], 0.05, [1.0], [1.0, -2.0], 0.0),
    ([18.75, 225.0], [1.0, 9.0, 225.0], 0.05, [18.75, 225.0], [1.0, 7.22, 246.5], 0.0),
    ([1.0], [1.0, 0.0], 0.0, [1.0], [1.0, 0.0], 0.5),
    ([0.5, 1.0], [1.0, 1.0], 0.2, [1.0], [1.0, 1.0], 0.0),
    ([2.0], [1.0, 1.0], 1.0, [1.0], [1.0, 1.0], 0.0),
    ([2.0, 0.0], [1.0, 1.0], 0.0, [1.0, 0.0], [1.0, 3.0], 0.0),
]


def load_reference(revision: str):
    """The metrics module of a git revision, imported as ``metrics_reference`` (it imports the rest of the
    package from the working tree: only the SISO code of metrics.py differs)."""
    shown = subprocess.run(["git", "-C", str(ROOT), "show", f"{revision}:gap_validation/core/metrics.py"],
                           capture_output=True, text=True)
    if shown.returncode:
        sys.exit(f"bench_nugap: no gap_validation/core/metrics.py at git revision {revision!r} "
                 f"({shown.stderr.strip().splitlines()[-1] if shown.stderr.strip() else 'git failed'})")
    source = shown.stdout
    path = Path(os.environ.get("TMPDIR", "/tmp")) / f"metrics_reference_{os.getpid()}.py"
    path.write_text(source)
    try:
        spec = importlib.util.spec_from_file_location("metrics_reference", path)
        module = importlib.util.module_from_spec(spec)
        sys.modules["metrics_reference"] = module
        spec.loader.exec_module(module)
    finally:
        path.unlink()
    return module


def second_order_roots(rng: np.random.Generator, damping_low: float) -> list[complex]:
    wn, zeta = 10 ** rng.uniform(-1, 1.7), rng.uniform(damping_low, 0.9)
    root = complex(-zeta * wn, wn * math.sqrt(1 - zeta * zeta))
    return [root, root.conjugate()]


def random_pair(rng: np.random.Generator, states: int, size: float) -> tuple[LinearModel, LinearModel]:
    """P1 with ``states`` poles and fewer zeros, P2 with its coefficients perturbed."""
    poles: list[complex] = []
    while len(poles) < states:
        if states - len(poles) >= 2 and rng.random() < 0.6:
            pair = second_order_roots(rng, 0.05)
            poles += [-p.conjugate() for p in pair] if rng.random() < 0.1 else pair   # unstable now and then
        else:
            real = -10 ** rng.uniform(-1, 1.5) * (1.0 if rng.random() < 0.85 else -0.2)
            poles.append(0.0 if rng.random() < 0.05 else real)
    count = int(rng.integers(0, states))
    zeros: list[complex] = []
    while len(zeros) < count:
        if count - len(zeros) >= 2 and rng.random() < 0.5:
            zeros += second_order_roots(rng, 0.05)
        else:
            zeros.append(-10 ** rng.uniform(-1, 1.5) * (1.0 if rng.random() < 0.8 else -1.0))
    den = np.real(np.poly(poles))
    num = np.real(np.poly(zeros)) * 10 ** rng.uniform(-1, 2) * rng.choice([-1.0, 1.0])
    perturbed = [c * (1.0 + size * rng.normal(size=c.shape)) for c in (num, den)]
    return LinearModel.from_tf(num, den), LinearModel.from_tf(*perturbed)


def best_time(fn, m1: LinearModel, m2: LinearModel, repeat: int) -> tuple[float, float, object]:
    """Best wall and CPU time of ``repeat`` calls, and the result."""
    wall, cpu, out = math.inf, math.inf, None
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        out = fn(m1, m2)
        wall = min(wall, time.perf_counter() - start)
        cpu = min(cpu, time.process_time() - start_cpu)
    return wall, cpu, out


def relative(a: float, b: float) -> float:
    """Relative difference (0 for equal values, infinities and nans alike)."""
    if a == b or (math.isnan(a) and math.isnan(b)):
        return 0.0
    return abs(a - b) / max(abs(a), abs(b), 1e-300)


def compare(m1: LinearModel, m2: LinearModel, reference, new: tuple | None = None,
            old: tuple | None = None) -> tuple[float, float, float, bool]:
    """Largest relative difference of the values (nu-gap and epsilon), of the nu-gap's and of epsilon's peak
    frequencies, and whether the winding verdicts agree."""
    new = new if new is not None else metrics.nugap(m1, m2)
    old = old if old is not None else reference.nugap(m1, m2)
    eps_new, eps_old = metrics.epsilon(m1, m2), reference.epsilon(m1, m2)
    # relative difference, or the absolute one scaled so that 1e-15 counts as 1e-9 (values of 1e-16 are noise)
    value = max(
        min(relative(a, b), abs(a - b) * 1e6) for a, b in ((new[0], old[0]), (eps_new[0], eps_old[0]))
    )
    a, b = metrics.winding_condition(m1, m2), reference.winding_condition(m1, m2)
    same = (a.satisfied, a.reason, a.method) == (b.satisfied, b.reason, b.method) and \
        relative(a.frequency_rad_s, b.frequency_rad_s) == 0.0
    return value, relative(new[1], old[1]), relative(eps_new[1], eps_old[1]), same


def dense_sup(m1: LinearModel, m2: LinearModel, w: np.ndarray) -> float:
    with np.errstate(all="ignore"):
        return float(np.nanmax(metrics.chordal_distance(m1.freqresp(w), m2.freqresp(w))))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=200)
    parser.add_argument("--states", type=int, default=10)
    parser.add_argument("--perturbation", type=float, default=0.05)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--reference", default="e4f6fdf", help="git revision of the reference metrics.py")
    args = parser.parse_args()
    reference = load_reference(args.reference)
    rng = np.random.default_rng(args.seed)
    pairs = [random_pair(rng, args.states, args.perturbation) for _ in range(args.pairs)]
    for module in (metrics, reference):   # warm up (imports, caches)
        module.nugap(*pairs[0])
        module.epsilon(*pairs[0])
    times = np.zeros((args.pairs, 4))   # wall new, wall reference, cpu new, cpu reference
    differences, verdicts, held, below = [], 0, 0, []
    grid = np.geomspace(1e-4, 1e5, 2000)
    for k, (m1, m2) in enumerate(pairs):
        wall, cpu, new = best_time(metrics.nugap, m1, m2, args.repeat)
        wall_ref, cpu_ref, old = best_time(reference.nugap, m1, m2, args.repeat)
        times[k] = wall, wall_ref, cpu, cpu_ref
        *difference, same = compare(m1, m2, reference, new, old)
        differences.append(difference)
        verdicts += not same
        if metrics.winding_condition(m1, m2).satisfied:
            held += 1
            below.append(new[0] - dense_sup(m1, m2, grid))
    corner = [compare(LinearModel.from_tf(n1, d1, t1), LinearModel.from_tf(n2, d2, t2), reference)
              for n1, d1, t1, n2, d2, t2 in CORNER_CASES]

    def line(label: str, column: int) -> str:
        t = 1e3 * times[:, column]
        return (f"{label} median {np.median(t):6.2f} ms, p90 {np.percentile(t, 90):6.2f} ms, "
                f"worst {t.max():6.2f} ms")

    print(f"exact SISO nu-gap, {args.states} states, {args.pairs} random pairs (perturbation "
          f"{args.perturbation:g}, seed {args.seed}), best of {args.repeat}; load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print("  wall time:  " + line("nugap", 0) + " (goal: median below 2 ms)")
    print("              " + line("reference " + args.reference, 1))
    print("  CPU time:   " + line("nugap", 2))
    print("              " + line("reference " + args.reference, 3))
    ratio = np.median(times[:, 0]) / np.median(times[:, 1])
    print(f"  ratio nugap / reference: medians {ratio:.3f} (wall), "
          f"{np.median(times[:, 2]) / np.median(times[:, 3]):.3f} (CPU); "
          f"per pair median {np.median(times[:, 0] / times[:, 1]):.3f}, p90 "
          f"{np.percentile(times[:, 0] / times[:, 1], 90):.3f}")
    value_max, where_max, eps_where_max = np.max(differences, axis=0)
    corner_value, corner_where, corner_eps_where = np.max([c[:3] for c in corner], axis=0)
    corner_verdicts = sum(not c[3] for c in corner)
    print(f"  equality with the reference, random pairs: nu-gap and epsilon max relative difference "
          f"{value_max:.1e} (limit 1e-9); peak frequencies of the nu-gap {where_max:.1e} (limit 1e-6), of "
          f"epsilon {eps_where_max:.1e}; winding verdicts differing: {verdicts}")
    print(f"  equality, {len(CORNER_CASES)} corner cases of the tests: values {corner_value:.1e}, peak "
          f"frequencies {corner_where:.1e} (epsilon {corner_eps_where:.1e}); winding verdicts differing: "
          f"{corner_verdicts}")
    print(f"  winding condition held for {held} of {args.pairs} pairs; exact - dense grid (2000 points) sup: "
          f"min {min(below):+.1e} (never below beyond round-off)")
    ok = value_max <= 1e-9 and corner_value <= 1e-9 and not verdicts and not corner_verdicts and \
        min(below) >= -1e-12 and max(where_max, corner_where) <= 1e-6
    print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
