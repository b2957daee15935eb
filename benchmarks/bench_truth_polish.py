"""Did the study's multi-start find the best minimum? (issue 21; docs/fitting.md, "Probes")

For each cached fit of benchmarks/bench_sources.py, the fit's own objective (its prior
weighed as in the fit, the resonance it marginalised projected off) polished from the truth
(the physical parameters the truth's, the lags the fit's) with the fit's polish, against the
fit's best point: how often the truth's basin holds a lower objective (by more than
``--tol``), by how much, and where it does, an identified parameter's error over its 68 %
half-width at the fit's point and at the truth's minimum.

    .venv/bin/python benchmarks/bench_truth_polish.py --cache DIR --sources probe-wide-generator
        [--campaigns 20] [--seed 5000] [--starts 100] [--names k_Bx,c_Bx,d2]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_sources as bs  # noqa: E402

from gprm.fit.engine import polish_best  # noqa: E402


def from_truth(case, names) -> dict:
    """One cached fit: its objective at its best point and at the minimum polished from the
    truth, and ``names``' errors over their 68 % half-widths (in u) at both points."""
    fit = case.fit
    obj = fit.objective()
    u = fit.uncertainty
    x = np.asarray(fit.x, float)
    xt = x.copy()
    for j, n in enumerate(u.names):
        if n in case.truth and n in bs.sources.PHYSICAL:
            xt[j] = case.truth[n]
    xp, _ = polish_best(obj, xt, fit.options.lm)

    def value(z):
        return float(obj.chi2(obj.to_normalised(z)[None])[0])

    prior = fit.prior
    half = (prior.to_u(u.upper68) - prior.to_u(u.lower68)) / 2
    ut = prior.to_u(np.array([case.truth.get(n, v) for n, v in zip(u.names, x)]))
    z_fit = (prior.to_u(x) - ut) / half
    z_truth = (prior.to_u(xp) - ut) / half
    return {"fit": value(x), "truth": value(xp),
            "z": {n: (float(z_fit[u.names.index(n)]), float(z_truth[u.names.index(n)]))
                  for n in names if n in u.names and u.identified[u.names.index(n)]}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    bs.cached_study_arguments(ap, "probe-wide-generator")
    ap.add_argument("--names", default="k_Bx,c_Bx,d2")
    ap.add_argument("--tol", type=float, default=1e-3,
                    help="a lower objective by more than this counts as a better minimum")
    a = ap.parse_args(argv)
    names = [n for n in a.names.split(",") if n]
    print("| source | campaigns | truth's basin lower | by (median, largest) | "
          "|z| at the fit / at the truth's minimum, where lower (median) |")
    print("|---|---|---|---|---|")
    for src in [s for s in a.sources.split(",") if s]:
        rows = []
        for k in range(a.campaigns):
            path = Path(a.cache) / f"{src}-{a.seed + k}-{a.starts}.pkl"
            if not path.exists():
                print(f"not in the cache, skipped: {path}", file=sys.stderr)
                continue
            rows.append(from_truth(bs.run_case(src, a.seed + k, a.starts, a.cache), names))
        lower = [r for r in rows if r["truth"] < r["fit"] - a.tol]
        d = np.array([r["fit"] - r["truth"] for r in lower])
        zf = [abs(v[0]) for r in lower for v in r["z"].values()]
        zt = [abs(v[1]) for r in lower for v in r["z"].values()]
        by = f"{np.median(d):.2f}, {d.max():.2f}" if d.size else "-"
        zz = f"{np.median(zf):.2f} / {np.median(zt):.2f}" if zf else "-"
        print(f"| {src} | {len(rows)} | {len(lower)} | {by} | {zz} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
