"""Benchmark of the flight stage: `.venv/bin/python benchmarks/bench_flight.py [--quick]`.

Prints a markdown section (machine, versions, command, timings)."""

from __future__ import annotations

import argparse

import numpy as np

from _machine import best_time as timed, machine


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    from gprm.fit.files import paper_model
    from gprm.flight import (AnalysisOptions, SynthOptions, analyze, impact_3d, planar_impact,
                             simulate_contacts, synth_telemetry, tukey_range_test,
                             velocity_curves)
    from gprm.flight.telemetry import AXES, telemetry_from_dataset

    fm = paper_model()
    rep = 1 if a.quick else 3
    ns = 50 if a.quick else 200
    rng = np.random.default_rng(0)
    N = 100_000
    rows = []

    def planar():
        return planar_impact(rng.uniform(0.01, 1, N), 1e-4, rng.normal(0, .02, (N, 2)),
                             rng.normal(0, 1e-2, (N, 2)), 0.0, 1.9, 7e-4,
                             rng.normal(0, .02, (N, 2)), 0.0, 0.0, np.array([0.0, 1.0]))
    t, _ = timed(planar, rep)
    rows.append((f"planar impact, {N} configurations (7x7 solves)", t))

    def d3():
        return impact_3d(rng.uniform(0.01, 1, N), np.eye(3) * 1e-4, rng.normal(0, .02, (N, 3)),
                         rng.normal(0, 1e-2, (N, 3)), 0.0, 1.9, np.eye(3) * 7e-4,
                         rng.normal(0, .02, (N, 3)), 0.0, 0.0, np.array([0, 0, 1.0]), mu=0.3)
    t, _ = timed(d3, rep)
    rows.append((f"3D impact with Coulomb friction, {N} configurations", t))

    t, curves = timed(lambda: velocity_curves(fm, n_samples=ns, n_times=401), rep)
    rows.append((f"velocity curves + bands: 401 times, 3 x {ns} draws + nominal", t))

    t, ds = timed(lambda: synth_telemetry(fm, SynthOptions(n_releases=11, seed=0)), rep)
    rows.append(("synthetic telemetry, 11 releases", t))
    tel = telemetry_from_dataset(ds)
    t, (doc, _) = timed(lambda: analyze(fm, tel, AnalysisOptions(), curves=curves), rep)
    rows.append(("release velocities + impact times + Tukey (curves given)", t))
    groups = {a: 1e-3 + 1e-6 * rng.standard_normal(11) for a in AXES}
    t, _ = timed(lambda: tukey_range_test(groups), rep)
    rows.append(("Tukey test alone, k=6, n=11 (15 studentized-range p-values)", t))
    t, mres = timed(lambda: simulate_contacts(fm, 1.0150e-3), 1)
    rows.append((f"multiple impacts from t1=1.015 ms ({mres['n_impacts']} contacts)", t))

    print("## Flight analysis (`gprm.flight`)\n")
    print(machine("scipy"))
    print(f"- command: `.venv/bin/python benchmarks/bench_flight.py{' --quick' if a.quick else ''}`"
          f" (best of {rep})\n")
    print("| step | time (s) |\n|---|---|")
    for name, t in rows:
        print(f"| {name} | {t:.3f} |")
    n_ok = sum(1 for r in doc["releases"] for v in r["impact_time"].values()
               if v["value"] is not None)
    print(f"\n{n_ok} of 66 impact times found on the synthetic set; Tukey: "
          f"{'all compatible' if doc['tukey'].get('all_compatible') else 'some pairs rejected'}.")


if __name__ == "__main__":
    main()
