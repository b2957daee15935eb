"""Benchmark of the simulation engine (issue 2): simulations per second for one parameter set
and for the fitter's shape (1000 sets x 23 sensitivities x 5 outputs x 47 window times), and
the speed-up over the solve_ivp reference of the same linear equations.

    .venv/bin/python benchmarks/bench_simulate.py [--quick]

Prints a markdown section. Timings are the best of several repetitions (wall clock, and CPU
time of this process, which is less disturbed by other jobs on a shared machine).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from _machine import machine

from gprm.params import FITTED_DEFAULT, batch, batch_from_vectors, paper
from gprm.simulate import observe, simulate
from gprm.simulate.core import OUTPUTS
from gprm.simulate.reference import reference_linear

WINDOW = np.arange(0.97e-3, 1.2e-3 + 1e-12, 5e-6)    # the fit window at 200 kHz: 47 times


def _best(fn, reps):
    wall, cpu = [], []
    for _ in range(reps):
        t, c = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return min(wall), min(cpu)


def _starts(n, seed=0):
    """n sets spread +-20% around the paper's initial values (the fitter's random starts)."""
    ps = paper()
    rng = np.random.default_rng(seed)
    X = ps.initial_vector() * (1 + 0.2 * rng.uniform(-1, 1, (n, len(ps.fitted))))
    return batch_from_vectors(ps, ps.fitted, X)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repetitions and reference runs")
    args = ap.parse_args(argv)
    reps = 2 if args.quick else 5
    n_ref = 1 if args.quick else 3

    ps = paper()
    one = batch([ps])
    pb = _starts(1000)
    rows = []

    # one set: the full record of `gprm simulate` (241 samples, 9 coordinates, 8 rates, 5 points)
    w, c = _best(lambda: simulate(ps), reps * 4)
    rows.append(("one set, `simulate` (241 samples, all 22 signals)", 1, w, c))
    w, c = _best(lambda: observe(one, WINDOW), reps * 4)
    rows.append(("one set, `observe` (fit window, 5 outputs)", 1, w, c))
    w, c = _best(lambda: observe(one, WINDOW, sensitivities=FITTED_DEFAULT), reps * 4)
    rows.append(("one set + 23 sensitivities", 1, w, c))
    observe(pb, WINDOW, sensitivities=FITTED_DEFAULT)            # warm-up
    w, c = _best(lambda: observe(pb, WINDOW), reps)
    rows.append(("1000 sets, `observe` (chi2 of trial steps)", 1000, w, c))
    w, c = _best(lambda: observe(pb, WINDOW, sensitivities=FITTED_DEFAULT), reps)
    rows.append(("**1000 sets + 23 sensitivities (one LM iteration)**", 1000, w, c))
    batch_sens_wall = w

    # reference: solve_ivp (Radau, rtol 1e-10, the reference_linear default) on a few sets
    ref_sets = [ps] + [ps.with_vector(ps.initial_vector() * f) for f in (0.9, 1.1)][:n_ref - 1]
    ref_times = []
    for s in ref_sets:
        t0 = time.perf_counter()
        reference_linear(s, WINDOW, names=OUTPUTS)
        ref_times.append(time.perf_counter() - t0)
    t_ref = float(np.mean(ref_times))
    t_ref_bdf = None
    if not args.quick:
        t0 = time.perf_counter()
        reference_linear(ps, WINDOW, names=OUTPUTS, method="BDF")
        t_ref_bdf = time.perf_counter() - t0

    cmd = "OMP_NUM_THREADS=%s .venv/bin/python benchmarks/bench_simulate.py%s" % (
        os.environ.get("OMP_NUM_THREADS", "<unset>"), " --quick" if args.quick else "")
    print("## Simulation engine (`gprm.simulate`)\n")
    print(f"Command: `{cmd}`\n")
    print(machine("scipy") + "\n")
    print("| case | sets | wall s (best) | CPU s (best) | simulations/s (wall) |")
    print("|---|---|---|---|---|")
    for label, n, w, c in rows:
        print(f"| {label} | {n} | {w:.4f} | {c:.4f} | {n / w:,.0f} |")
    print()
    print(f"Reference `reference_linear` (solve_ivp Radau, rtol 1e-10, 5 outputs, fit window), "
          f"mean of {len(ref_times)} set(s): {t_ref:.2f} s per set"
          + (f"; BDF rtol 1e-10: {t_ref_bdf:.2f} s per set" if t_ref_bdf else "") + ".\n")
    one_plain = rows[1][2]
    print(f"- speed-up, one set without sensitivities: {t_ref / one_plain:,.0f}x")
    per_set = batch_sens_wall / 1000
    # a reference Jacobian needs at least 1 + 23 integrations (forward differences) per set
    print(f"- speed-up, fitter shape (1000 sets with 23 sensitivities; reference = 24 "
          f"integrations per set, extrapolated: {24 * 1000 * t_ref / 3600:.1f} h): "
          f"{24 * t_ref / per_set:,.0f}x")
    print(f"- speed-up, 1000 sets without sensitivities (reference extrapolated "
          f"{1000 * t_ref / 60:.0f} min): {1000 * t_ref / rows[3][2]:,.0f}x")


if __name__ == "__main__":
    sys.exit(main())
