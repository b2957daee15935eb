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

``--convergence``: instead, whether the projection's iteration budget matters: the first
proposal round of each campaign projected with the default budget
(:data:`gprm.fit.draws.PROJECT_ITER` iterations, relative tolerance ``PROJECT_FTOL``), with a
long one (:data:`LONG_ITER`, :data:`LONG_FTOL`) and with a short one (:data:`SHORT_ITER`),
the draws each keeps, and the prediction bands they give (overshoots of the standard
scenarios and the velocity curves, 3000 resamples of the kept draws): the median and 90th
percentile over bands of |ln(width / the long budget's width)| at 68 % and 95 %, beside the
same statistic for a bootstrap resample of the long budget's own draws (their Monte Carlo
noise), and the range over parameters of the kept draws' sd in u over the long budget's.

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
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_sources as bs  # noqa: E402

import gprm.fit.sandwich as sandwich  # noqa: E402
from gprm.fit.methods import uncertainty_of  # noqa: E402
from gprm.fit.sandwich import Systematics  # noqa: E402

DEFAULT_SOURCES = "white,jitter-2,drive-2,generator,sim2-white,sim2"
#: --convergence: the long and the short projection budgets compared with the default
LONG_ITER, LONG_FTOL = 60, 1e-3
SHORT_ITER = 8
#: the budgets' keyword arguments of gprm.fit.draws.project
BUDGETS = {"default": {}, "short": {"max_iter": SHORT_ITER},
           "long": {"max_iter": LONG_ITER, "ftol": LONG_FTOL}}
PCT = (25, 50, 75, 90, 99)


def projection_call(case, systematics=None):
    """(uncertainty, the arguments of its :func:`gprm.fit.draws.project_draws` call as a
    dict, the ProjectedDraws it returned, seconds): the case's default uncertainty with the
    projection watched."""
    seen = {}
    real = sandwich.project_draws

    def spy(obj, x, propose, n, lm, **kw):
        out = real(obj, x, propose, n, lm, **kw)
        seen.update(obj=obj, x=x, propose=propose, n=n, lm=lm, kw=kw, out=out)
        return out

    sandwich.project_draws = spy
    try:
        t = time.perf_counter()
        u = uncertainty_of(case.fit, "sandwich", systematics=systematics)
        secs = time.perf_counter() - t
    finally:
        sandwich.project_draws = real
    return u, seen, seen.get("out"), secs


def misfits_of(case):
    """(ProjectedDraws, seconds with, seconds without) of the case's default uncertainty."""
    _, _, p, with_s = projection_call(case)
    t = time.perf_counter()
    uncertainty_of(case.fit, "sandwich", systematics=Systematics(project_draws=False))
    return p, with_s, time.perf_counter() - t


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


def _bands(fit, cov, X, n: int = 3000, seed: int = 5) -> np.ndarray:
    """(5, K) the 2.5, 16, 50, 84, 97.5 % points of the overshoots (standard scenarios, every
    point-axis) and the velocity curves (six axes, 21 times from the fit's t_c) of ``n``
    resamples of the parameter sets ``X``."""
    from bench_coverage import curve_times, overshoots

    from gprm.fit.files import FittedModel
    from gprm.flight.predicted import tm_velocity_vs_time
    from gprm.flight.telemetry import AXES
    from gprm.predict.scenarios import apply_scenario, standard_scenarios
    from gprm.predict.trajectories import default_times
    from gprm.simulate.kinematics import body_motion

    fm = FittedModel(fit.params, cov, piezo=2, draws=X, uncertainty="sandwich")
    cols = []
    for sc in standard_scenarios():
        os_, ok = overshoots(apply_scenario(fm, sc).sample(n, seed), sc, default_times())
        cols.append(np.percentile(os_[ok], [2.5, 16, 50, 84, 97.5], axis=0))
    m = body_motion(fm.sample(n, seed), curve_times(fit.params), piezo=2)
    v = tm_velocity_vs_time(m)
    with warnings.catch_warnings():         # an axis whose curve does not exist at a time
        warnings.simplefilter("ignore", RuntimeWarning)
        cols += [np.nanpercentile(v[a][m.ok], [2.5, 16, 50, 84, 97.5], axis=0) for a in AXES]
    return np.concatenate(cols, axis=1)


def _log_width_ratio(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """|ln(width_A / width_B)| of the 68 % and the 95 % bands, where both are positive."""
    w68 = (A[3] - A[1], B[3] - B[1])
    w95 = (A[4] - A[0], B[4] - B[0])
    ok = (w68[0] > 0) & (w68[1] > 0) & (w95[0] > 0) & (w95[1] > 0)
    return np.abs(np.log(w68[0][ok] / w68[1][ok])), np.abs(np.log(w95[0][ok] / w95[1][ok]))


def convergence_table(a) -> None:
    import gprm.fit.draws as gdraws

    print("| source | kept: default / short / long (sum) | same keep decision as the long "
          "budget: default, short | kept draws' sd in u / the long budget's, range over "
          "parameters: default | short | prediction bands' \\|ln width ratio\\| to the long "
          "budget, median / 90 %, 68 % and 95 %: default | short | a resample of the long "
          "budget's own draws |")
    print("|---|---|---|---|---|---|---|---|")
    for src in [s for s in a.sources.split(",") if s]:
        kept = {"default": 0, "short": 0, "long": 0}
        agree = {"default": [], "short": []}
        sdr = {"default": [], "short": []}
        lw = {"default": ([], []), "short": ([], []), "resample": ([], [])}
        for k in range(a.campaigns):
            case = bs.run_case(src, a.seed + k, a.starts, a.cache)
            u, seen, _, _ = projection_call(case)
            obj, x, lm = seen["obj"], seen["x"], seen["lm"]
            thr = gdraws.acceptance_threshold(np.asarray(x).size, seen["kw"].get("scale", 1.0))
            U = np.asarray(seen["propose"](int(seen["n"]), 0), float)
            X, ok = {}, {}
            for key, kw in BUDGETS.items():
                Xk, mk = gdraws.project(obj, x, U, lm, **kw)
                X[key], ok[key] = Xk[mk <= thr], mk <= thr
                kept[key] += int(ok[key].sum())
            to_u = obj.prior.to_u
            sd_long = np.std(to_u(X["long"]), axis=0)
            rng = np.random.default_rng([a.seed + k, 46])
            X["resample"] = X["long"][rng.integers(0, len(X["long"]), len(X["long"]))]
            B = {key: _bands(case.fit, u.covariance, X[key]) for key in X}
            for key in ("default", "short"):
                agree[key].append(float(np.mean(ok[key] == ok["long"])))
                with np.errstate(all="ignore"):
                    sdr[key].append(np.std(to_u(X[key]), axis=0) / sd_long)
            for key in ("default", "short", "resample"):
                r68, r95 = _log_width_ratio(B[key], B["long"])
                lw[key][0].append(r68)
                lw[key][1].append(r95)

        def q(key, lw=lw):
            r68, r95 = (np.concatenate(v) for v in lw[key])
            return (f"{np.median(r68):.3f} / {np.percentile(r68, 90):.3f}, "
                    f"{np.median(r95):.3f} / {np.percentile(r95, 90):.3f}")

        def rng_(key, sdr=sdr):
            v = np.concatenate(sdr[key])
            v = v[np.isfinite(v)]
            return f"{v.min():.2f}-{v.max():.2f}"
        print(f"| {src} | {kept['default']} / {kept['short']} / {kept['long']} | "
              f"{np.mean(agree['default']):.3f}, {np.mean(agree['short']):.3f} | "
              f"{rng_('default')} | {rng_('short')} | {q('default')} | {q('short')} | "
              f"{q('resample')} |", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    bs.cached_study_arguments(ap, DEFAULT_SOURCES)
    ap.set_defaults(campaigns=10)
    ap.add_argument("--curves", action="store_true")
    ap.add_argument("--convergence", action="store_true",
                    help="whether the projection's iteration budget moves the predictions")
    a = ap.parse_args(argv)
    from _machine import machine
    print(machine())
    print(f"command: `.venv/bin/python benchmarks/bench_draws.py --cache DIR --sources "
          f"{a.sources} --campaigns {a.campaigns}" + (" --curves" if a.curves else "")
          + (" --convergence" if a.convergence else "") + "`\n")
    if a.convergence:
        t0 = time.perf_counter()
        convergence_table(a)
        print(f"\n({time.perf_counter() - t0:.0f} s; cache {a.cache})")
        return 0
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
