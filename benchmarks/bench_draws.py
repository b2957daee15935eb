"""The draws' projection onto the data (gprm.fit.draws), per source: how far the proposals
end from their targets, how many are kept, and what it costs.

On the cached fits of bench_sources.py (``--cache``), per source, over ``--campaigns``
campaigns: the default uncertainty's proposals' misfits to their targets after projection
(in the fit's variance scale; percentiles over all proposals of all campaigns, and the same
over the threshold, and the share that ends within a factor 10 of it: the proposals whose
fate the threshold's level decides), the share kept, the covariance's inflation over the noise that scales
the threshold, the proposals needed for the 400 draws, and the uncertainty's wall time with
and without the projection (this process, one thread of work).

    .venv/bin/python benchmarks/bench_draws.py --cache DIR [--sources white,sim2] [--campaigns 10]
    .venv/bin/python benchmarks/bench_draws.py --curves --cache DIR [--sources ...] [--campaigns 8]

``--curves``: instead, the velocity curves' coverage (bench_coverage.curve_cover, 200
samples) with the default's draws and with the same draws projected from the unstretched
Gaussian N(u^, Cu) (sandwich.stretch_draws replaced by the identity: a development check,
not an option of the method), and how the six axes of one campaign move together: the
median over campaigns of the truth's offset from the band's median in 68 % half-widths, and
of its spread (max - min) over the axes within a campaign.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_sources as bs  # noqa: E402

import gprm.fit.sandwich as sandwich  # noqa: E402
from gprm.fit.methods import uncertainty_of  # noqa: E402
from gprm.fit.sandwich import Systematics  # noqa: E402

DEFAULT_SOURCES = "white,jitter-2,drive-2,generator,sim2-white,sim2"
PCT = (25, 50, 75, 90, 99)


def misfits_of(case):
    """(ProjectedDraws, seconds with, seconds without) of the case's default uncertainty."""
    seen = {}
    real = sandwich.project_draws

    def spy(*a, **k):
        out = real(*a, **k)
        seen["p"] = out
        return out

    sandwich.project_draws = spy
    try:
        t = time.perf_counter()
        uncertainty_of(case.fit, "sandwich")
        with_s = time.perf_counter() - t
    finally:
        sandwich.project_draws = real
    t = time.perf_counter()
    uncertainty_of(case.fit, "sandwich", systematics=Systematics(project_draws=False))
    return seen["p"], with_s, time.perf_counter() - t


def curves_table(a) -> None:
    from bench_coverage import curve_cover

    from gprm.fit.files import FittedModel

    real = sandwich.stretch_draws
    print("| source | curves 95 / 68 %: stretched (default) | unstretched | truth's offset / "
          "68 % half-width, median | its spread over the six axes in a campaign, median |")
    print("|---|---|---|---|---|")
    for src in [s for s in a.sources.split(",") if s]:
        cov = {"stretched": [0, 0, 0], "unstretched": [0, 0, 0]}
        offs, spreads = [], []
        for k in range(a.campaigns):
            case = bs.run_case(src, a.seed + k, a.starts, a.cache)
            truth = bs.truth_in_fit_time(case)[1]
            for key in cov:
                sandwich.stretch_draws = real if key == "stretched" else \
                    (lambda Z, sd, f68, f95, z: Z)
                try:
                    u = uncertainty_of(case.fit, "sandwich")
                finally:
                    sandwich.stretch_draws = real
                fm = FittedModel(case.fit.params, u.covariance, piezo=2, draws=u.draws,
                                 uncertainty=u.method)
                c = curve_cover(fm, truth, 200, case.seed)
                cov[key] = [cov[key][0] + c["in95"], cov[key][1] + c["in68"],
                            cov[key][2] + c["n"]]
                if key == "stretched" and c["axis_offset"]:
                    v = np.array(list(c["axis_offset"].values()))
                    offs.append(float(np.median(v)))
                    spreads.append(float(v.max() - v.min()))

        def pc(key, cov=cov):
            i95, i68, n = cov[key]
            return f"{100 * i95 / max(n, 1):.1f} / {100 * i68 / max(n, 1):.1f}"
        print(f"| {src} | {pc('stretched')} | {pc('unstretched')} | {np.median(offs):.2f} | "
              f"{np.median(spreads):.3f} |", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    bs.cached_study_arguments(ap, DEFAULT_SOURCES)
    ap.set_defaults(campaigns=10)
    ap.add_argument("--curves", action="store_true")
    a = ap.parse_args(argv)
    from _machine import machine
    print(machine())
    print(f"command: `.venv/bin/python benchmarks/bench_draws.py --cache DIR --sources "
          f"{a.sources} --campaigns {a.campaigns}" + (" --curves" if a.curves else "") + "`\n")
    if a.curves:
        t0 = time.perf_counter()
        curves_table(a)
        print(f"\n({time.perf_counter() - t0:.0f} s; cache {a.cache})")
        return 0
    print("| source | misfit, variance scales: " + ", ".join(f"{p} %" for p in PCT)
          + " | misfit / threshold: 50 %, 75 %, 90 % | share within 0.1-10 x the threshold | "
          "share kept | inflation (median) | "
          "proposals (median) | uncertainty s: projected / as drawn (median) |")
    print("|---|---|---|---|---|---|---|---|")
    t0 = time.perf_counter()
    for src in [s for s in a.sources.split(",") if s]:
        mis, rel, acc, infl, prop, tw, to = [], [], [], [], [], [], []
        for k in range(a.campaigns):
            case = bs.run_case(src, a.seed + k, a.starts, a.cache)
            p, with_s, without_s = misfits_of(case)
            mis.append(p.misfit)
            rel.append(p.misfit / p.threshold)
            acc.append(p.acceptance)
            infl.append(p.scale)
            prop.append(p.n_proposed)
            tw.append(with_s)
            to.append(without_s)
        m, r = np.concatenate(mis), np.concatenate(rel)
        fin = np.isfinite(m)
        q = np.percentile(m[fin], PCT)
        qr = np.percentile(r[fin], (50, 75, 90))
        print(f"| {src} | " + ", ".join(f"{v:.3g}" for v in q) + " | "
              + ", ".join(f"{v:.3g}" for v in qr)
              + f" | {np.mean((r > 0.1) & (r < 10)):.2f}"
              + f" | {np.mean(acc):.2f} | {np.median(infl):.3g} | {np.median(prop):.0f} | "
              f"{np.median(tw):.2f} / {np.median(to):.2f} |", flush=True)
    print(f"\n({time.perf_counter() - t0:.0f} s; cache {a.cache})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
