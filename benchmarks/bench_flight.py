"""Benchmark of the flight stage:
`.venv/bin/python benchmarks/bench_flight.py [--quick] [--campaigns N] [--releases R]
[--seed0 S] [--no-planar] [--no-timings] [--variants]`.

Prints a markdown section (machine, versions, command, timings) and the recovery study of
issue 14: N synthetic telemetry campaigns (R releases each, seeds S .. S+N-1; truth drawn
within the model's uncertainty from the one-contact 3D impact, as `gprm synth telemetry paper
--truth-model 3d --seed s` does: the issue-14 truth, no longer the default since issue 23),
each analysed as `gprm impact paper TEL.nc --scenario-draws 0` does (the
curves and draws depend on the model and the analysis seed only, so they are computed once and
reused): impact times found / total, fraction of the found ones within 2 sigma of the truth,
the joint estimate's 95 % interval coverage, the joint chi-square's and Tukey's rejection
rates at alpha = 0.01, and the same for the paper's planar analysis on the same data (its
systematic error against a 3D truth)."""

from __future__ import annotations

import argparse

import numpy as np

from _machine import best_time as timed, machine


#: the per-campaign counts of an impact-time analysis (:func:`add_analysis`)
COUNTS = ("impact_times", "found", "within_2sigma", "joint_releases", "joint_truth_in_ci95")


def new_totals() -> dict:
    """Zeroed totals for :func:`add_analysis`."""
    return {"campaigns": 0, **{k: 0 for k in COUNTS}, "chi2_rejects": 0, "chi2_tests": 0,
            "tukey_rejecting_campaigns": 0}


def add_analysis(tot: dict, doc: dict) -> None:
    """Add one analysed synthetic campaign (``AnalysisResult.to_json()``) to ``tot``: its truth
    summary's counts, the joint chi-square tests (rejected at 0.01) and whether Tukey
    rejected."""
    sm = doc["truth"]["summary"]
    for k in COUNTS:
        tot[k] += sm[k]
    tot["campaigns"] += 1
    for r in doc["releases"]:
        p = r["joint"].get("p")
        if p is not None:
            tot["chi2_tests"] += 1
            tot["chi2_rejects"] += p < 0.01
    tot["tukey_rejecting_campaigns"] += not doc["tukey"].get("all_compatible", True)


def recovery(fm, n_campaigns: int, releases: int, seed0: int, model: str,
             models=None) -> dict:
    """Totals over campaigns of :func:`gprm.flight.analysis.truth_summary` and the tests
    (``models``: one model per campaign instead of ``fm`` for all)."""
    from gprm.flight import AnalysisOptions, SynthOptions, analyze, synth_telemetry
    from gprm.flight.files import telemetry_from_dataset

    tot = {**new_totals(), "missing_reasons": {}}
    zs = []
    curves = None
    for i, s in enumerate(range(seed0, seed0 + n_campaigns)):
        m = fm if models is None else models[i]
        ds = synth_telemetry(m, SynthOptions(n_releases=releases, seed=s, truth_model="3d"))
        tel = telemetry_from_dataset(ds, source=f"seed {s}")
        if models is not None:
            curves = None
        res = analyze(m, tel, AnalysisOptions(impact_model=model), curves=curves)
        doc, curves = res.to_json(), res.curves
        add_analysis(tot, doc)
        for r in doc["releases"]:
            zs += [z for z in r["error_sigma"].values() if z is not None]
        for m in doc["missing"]:
            key = m["reason"].split(":")[0]
            tot["missing_reasons"][key] = tot["missing_reasons"].get(key, 0) + 1
    zs = np.abs(np.array(zs))
    tot["median_abs_z"] = float(np.median(zs)) if zs.size else float("nan")
    return tot


class BestFitOnly:
    """A model without usable uncertainty as issue 12's contract gives it for a fit without
    covariance: ``has_uncertainty`` False, ``sample`` the best fit repeated."""

    def __init__(self, fm, params=None):
        self.params = params if params is not None else fm.params
        self.piezo, self.source, self.has_uncertainty = fm.piezo, "best fit only", False

    def sample(self, n, seed=0):
        from gprm.params import batch
        return {k: np.repeat(v, n) for k, v in batch([self.params]).items()}


# chain-check's truths: the paper's values of these parameters times 1 + U(-0.1, 0.1)
PERTURBED = ("v2", "g2", "gamma", "rho", "k_lr", "k_Ax", "k_Bx", "c_Ax", "c_Bx", "k_Cy",
             "k_Dy", "c_Cy", "c_Dy", "m1", "m2", "m3", "m4", "d1", "d2", "b1", "b2")


def perturbed_models(fm, n: int, seed0: int):
    """``n`` models with the paper's covariance about parameters perturbed by +-10 %."""
    from dataclasses import replace

    out = []
    for i in range(n):
        rng = np.random.default_rng(seed0 + i)
        ps = fm.params.with_values(**{k: fm.params[k] * (1 + rng.uniform(-0.1, 0.1))
                                      for k in PERTURBED})
        out.append(replace(fm, params=ps, source=f"perturbed {seed0 + i}"))
    return out


def print_recovery(rows, cmd) -> None:
    print("\n### Recovery of synthetic truths (issue 14)\n")
    print(f"- command: `{cmd}`\n")
    print("| analysis | campaigns x releases | impact times found | within 2 sigma of truth "
          "| joint 95 % interval contains truth | joint chi2 rejects (alpha 0.01) "
          "| campaigns where Tukey rejects | median abs(error)/sigma |")
    print("|---|---|---|---|---|---|---|---|")
    for name, t, R in rows:
        f = t["found"] / max(t["impact_times"], 1)
        w = t["within_2sigma"] / max(t["found"], 1)
        j = t["joint_truth_in_ci95"] / max(t["joint_releases"], 1)
        c = t["chi2_rejects"] / max(t["chi2_tests"], 1)
        print(f"| {name} | {t['campaigns']} x {R} | {t['found']}/{t['impact_times']} "
              f"({f:.1%}) | {t['within_2sigma']}/{t['found']} ({w:.1%}) | "
              f"{t['joint_truth_in_ci95']}/{t['joint_releases']} ({j:.1%}) | "
              f"{t['chi2_rejects']}/{t['chi2_tests']} ({c:.1%}) | "
              f"{t['tukey_rejecting_campaigns']}/{t['campaigns']} | {t['median_abs_z']:.2f} |")
    for name, t, _ in rows:
        if t["missing_reasons"]:
            print(f"\n{name}: reasons of the missing times: "
                  + "; ".join(f"{k} ({v})" for k, v in t["missing_reasons"].items()))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--campaigns", type=int, default=100)
    ap.add_argument("--releases", type=int, default=11)
    ap.add_argument("--seed0", type=int, default=1000)
    ap.add_argument("--no-planar", action="store_true")
    ap.add_argument("--no-timings", action="store_true")
    ap.add_argument("--variants", action="store_true",
                    help="also: best fit only (no covariance), and 10 models perturbed by "
                         "+-10 %% (chain-check's truths), 3D analysis")
    a = ap.parse_args()
    from gprm.fit.files import paper_model
    from gprm.flight import (AnalysisOptions, SynthOptions, analyze, impact_3d, planar_impact,
                             simulate_contacts, synth_telemetry, tukey_range_test,
                             velocity_curves)
    from gprm.flight.files import telemetry_from_dataset
    from gprm.flight.telemetry import AXES

    fm = paper_model()
    import sys
    cmd = ".venv/bin/python benchmarks/bench_flight.py " + " ".join(sys.argv[1:])
    if a.no_timings:
        print("## Flight analysis (`gprm.flight`)\n")
        print(machine("scipy"))
        _recovery_section(fm, a, cmd.strip())
        return
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

    t, ds = timed(lambda: synth_telemetry(fm, SynthOptions(n_releases=11, seed=0,
                                                           truth_model="3d")), rep)
    rows.append(("synthetic telemetry, 11 releases", t))
    tel = telemetry_from_dataset(ds)
    t, res = timed(lambda: analyze(fm, tel, AnalysisOptions(), curves=curves), rep)
    doc = res.to_json()
    rows.append(("release velocities + impact times + Tukey (curves given)", t))
    groups = {a: 1e-3 + 1e-6 * rng.standard_normal(11) for a in AXES}
    t, _ = timed(lambda: tukey_range_test(groups), rep)
    rows.append(("Tukey test alone, k=6, n=11 (15 studentized-range p-values)", t))
    t, mres = timed(lambda: simulate_contacts(fm, 1.0150e-3), 1)
    rows.append((f"multiple impacts from t1=1.015 ms ({mres['n_impacts']} contacts)", t))

    print("## Flight analysis (`gprm.flight`)\n")
    print(machine("scipy"))
    print(f"- command: `{cmd.strip()}` (timings: best of {rep})\n")
    print("| step | time (s) |\n|---|---|")
    for name, t in rows:
        print(f"| {name} | {t:.3f} |")
    n_ok = sum(1 for r in doc["releases"] for v in r["impact_time"].values()
               if v["value"] is not None)
    print(f"\n{n_ok} of 66 impact times found on the synthetic set; Tukey: "
          f"{'all compatible' if doc['tukey'].get('all_compatible') else 'some pairs rejected'}.")
    _recovery_section(fm, a, cmd.strip())


def _recovery_section(fm, a, cmd) -> None:
    import time

    t0 = time.process_time()
    n = 5 if a.quick else a.campaigns
    rows = [("3D one-contact (default)", recovery(fm, n, a.releases, a.seed0, "3d"),
             a.releases)]
    if not a.no_planar:
        rows.append(("planar, two planes (paper)", recovery(fm, n, a.releases, a.seed0,
                                                            "planar"), a.releases))
    if a.variants:
        k = 10 if not a.quick else 2
        rows.append(("3D, best fit only (no covariance)",
                     recovery(BestFitOnly(fm), k, a.releases, a.seed0, "3d"), a.releases))
        rows.append(("3D, paper covariance about +-10 % perturbed parameters",
                     recovery(fm, k, a.releases, a.seed0, "3d",
                              models=perturbed_models(fm, k, a.seed0)), a.releases))
    print_recovery(rows, cmd)
    print(f"\n(recovery study: {time.process_time() - t0:.0f} s CPU)")


if __name__ == "__main__":
    main()
