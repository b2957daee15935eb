"""The mismatch calibration of the default uncertainty (gprm.fit.calibration, issue 12).

For each campaign (truth within +-10 % of Table 3, every mismatch ingredient on, preprocessing
and fit with the CLI's defaults, as benchmarks/bench_coverage.py makes them), the default
method *without* calibration gives each physical parameter a centre and a standard deviation
in the prior's coordinates u; z = (centre - truth) / sd. The factor of a parameter is the
root mean square of z over the campaigns, floored at 1. Printed: the factors, the table
``MISMATCH_CALIBRATION`` holds, and a cross-validation (factors made on one half of the
campaigns, the identified parameters' coverage measured on the other).

    .venv/bin/python benchmarks/bench_calibration.py [--campaigns 20] [--seeds 1000,2000]
                                                     [--workers W | --scheduler ADDRESS]

(--workers/--scheduler: the campaigns as Dask tasks, benchmarks/_studies.py; the numbers do
not depend on them.)

(``--campaigns`` per seed block; the table in gprm.fit.calibration is the default run.)
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from scipy.stats import norm

sys.path.insert(0, "benchmarks")
from bench_coverage import PHYSICAL, synthetic_fit  # noqa: E402

from gprm.fit.bootstrap import bootstrap_uncertainty  # noqa: E402
from gprm.fit.calibration import MISMATCH_CALIBRATION  # noqa: E402
from gprm.fit.uncertainty import CONTRACTION  # noqa: E402

Z95, Z68 = norm.ppf(0.975), norm.ppf(0.84)


def one_campaign(seed: int, starts: int, n_boot: int) -> dict:
    """z, the uncalibrated sd's ratio to the prior's, and whether identified, per parameter."""
    sf = synthetic_fit(seed, starts)
    truth, fit = sf.truth, sf.fit
    assert fit.prior is not None and fit.uncertainty is not None
    u = bootstrap_uncertainty(fit.objective(), fit.x, fit.uncertainty, fit.prior,
                              "generator-bootstrap", n_boot=n_boot, seed=seed, calibration=None)
    k = [fit.names.index(n) for n in PHYSICAL]
    lo, hi = fit.prior.to_u(u.lower95)[k], fit.prior.to_u(u.upper95)[k]
    tx = fit.x.copy()
    tx[k] = [truth[n] for n in PHYSICAL]
    t = fit.prior.to_u(tx)[k]
    centre, sd = 0.5 * (lo + hi), (hi - lo) / (2 * Z95)
    return {"seed": seed, "z": ((centre - t) / sd).tolist(),
            "contraction": np.asarray(u.contraction)[k].tolist(),
            "identified": np.asarray(fit.uncertainty.identified)[k].tolist()}


def factors(results: list[dict]) -> np.ndarray:
    Z = np.array([r["z"] for r in results])
    return np.sqrt(np.mean(Z * Z, axis=0))


def coverage(results: list[dict], F: np.ndarray) -> tuple[float, float, float]:
    """Identified parameters' 95 and 68 % coverage, identified per campaign, with factors F."""
    F = np.maximum(1.0, F)
    n = c95 = c68 = 0
    for r in results:
        z = np.abs(np.array(r["z"])) / F
        ident = np.array(r["identified"]) & (np.array(r["contraction"]) * F < CONTRACTION)
        n += int(ident.sum())
        c95 += int(np.sum(ident & (z <= Z95)))
        c68 += int(np.sum(ident & (z <= Z68)))
    return c95 / n, c68 / n, n / len(results)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--campaigns", type=int, default=20, help="campaigns per seed block")
    ap.add_argument("--seeds", default="1000,2000", help="first seeds of the blocks")
    ap.add_argument("--starts", type=int, default=200)
    ap.add_argument("--boot", type=int, default=30)
    ap.add_argument("--json", help="write every campaign's z here")
    ap.add_argument("--workers", type=int, default=0,
                    help="campaigns as Dask tasks on a local cluster of this many processes")
    ap.add_argument("--scheduler", default=None,
                    help="campaigns as Dask tasks on the cluster of this scheduler address")
    a = ap.parse_args(argv)
    from _machine import machine
    from _studies import map_seeds

    t0 = time.perf_counter()
    firsts = [int(s) for s in a.seeds.split(",")]
    seeds = [s0 + c for s0 in firsts for c in range(a.campaigns)]
    flat = map_seeds(one_campaign, seeds, scheduler=a.scheduler, workers=a.workers,
                     starts=a.starts, n_boot=a.boot)
    blocks = [flat[i * a.campaigns:(i + 1) * a.campaigns] for i in range(len(firsts))]
    results = [r for b in blocks for r in b]
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(results, fh, indent=1)
    F = factors(results)
    print(f"{len(results)} campaigns, seed blocks {a.seeds} x {a.campaigns}, {a.starts} starts, "
          f"{a.boot} refits ({time.perf_counter() - t0:.0f} s; {machine()})")
    print("| parameter | rms z | factor | in gprm.fit.calibration |\n|---|---|---|---|")
    for n, f in zip(PHYSICAL, F):
        print(f"| {n} | {f:.3f} | {max(1.0, f):.2f} | {MISMATCH_CALIBRATION.get(n, 1.0):.2f} |")
    table = {n: round(float(f), 2) for n, f in zip(PHYSICAL, F) if round(float(f), 2) > 1.0}
    print("MISMATCH_CALIBRATION =", table)
    none = coverage(results, np.ones(len(PHYSICAL)))
    print(f"uncalibrated: identified 95 % {none[0]:.1%}, 68 % {none[1]:.1%}, "
          f"{none[2]:.1f} identified per campaign")
    if len(blocks) == 2:
        for i, j in ((0, 1), (1, 0)):
            cv = coverage(blocks[j], factors(blocks[i]))
            print(f"factors from block {i + 1}, tested on block {j + 1}: identified 95 % "
                  f"{cv[0]:.1%}, 68 % {cv[1]:.1%}, {cv[2]:.1f} identified per campaign")


if __name__ == "__main__":
    main()
