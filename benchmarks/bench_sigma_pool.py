"""Why the fit's weights are pooled over neighbouring samples (docs/fitting.md, "Weights
pooled over neighbouring samples"): the campaign's actual error against what its runs say.

For each campaign of a validation source (the fits of bench_sources.py, read from its
``--cache``), at the truth's physical parameters with the lags and offsets fitted to the
data (bench_linearisation.truth_point), and the estimator linearised there:

- ``err/runs``: the estimate's error predicted from the data's actual error, B (mean -
  model(truth)) / sigma, in units of the sd the runs' spread gives through the same B;
- computed twice: with each sample weighted by its own standard error over the runs (stops
  1-41) and with that variance pooled over ``--pool`` samples on each side
  (gprm.fit.objective.pooled_sigma, the default since stop 42).

An rms over the campaigns near 1 says the runs' spread accounts for the error the estimate
makes; well above 1, the weights themselves add error the runs cannot show.

    .venv/bin/python benchmarks/bench_sigma_pool.py --sources white,sim2-white,drive-2 \\
        --campaigns 20 --cache DIR [--fit-pool 3] [--pool 3]

``--fit-pool``: the pool the cached fits were made with (bench_sources.py --sigma-pool); the
weights compared here are recomputed from the runs, whatever the fit used.

``--widths``: instead, where the default uncertainty's width goes on the cached fits: per
source, the rms over the identified physical parameters of the best fit's error in the
sandwich's own sd (before its interval factors: shape and variance checks, Student's t),
split by which statistical part leads (runs or residuals, gprm.fit.sandwich.runs_lead), with
the share of errors within one sd (0.68 for a correct sd), the 68 % half-width over that sd,
and the mean shares of the variance (statistical, estimated gain, prior, ...). Well over
0.68 within one sd says the sandwich's variance itself is too large.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_sources as bs  # noqa: E402
from bench_linearisation import truth_point  # noqa: E402

from gprm.fit.methods import state_of  # noqa: E402
from gprm.fit.objective import SIGMA_POOL, pooled_sigma  # noqa: E402
from gprm.fit.sandwich import _estimator, run_deviations  # noqa: E402

PARAMS = ("k_Bx", "d2", "c_Bx", "d1", "k_Ax", "m3", "m4", "k_lr", "m1")


def campaign(case, pool: int) -> dict:
    """{weights: {parameter: err/runs}} for one fitted campaign."""
    st = state_of(case.fit)
    obj, prior, names = st.obj, st.obj.prior, list(case.fit.names)
    d = obj.data
    xt = truth_point(case)
    obs = obj.model(xt[None], jacobian=True)
    y, dy = obs.y[0], obs.dy[0]                                     # (S, T), (S, T, P)
    R = d.runs.shape[1]
    err = d.runs.mean(axis=1) - y
    sem = d.runs.std(axis=1, ddof=1) / np.sqrt(R)
    out = {}
    for label, k in (("each sample", 0), (f"pooled +-{pool}", pool)):
        sigma = pooled_sigma(sem, k)
        Ju, Hinv = _estimator(xt, (dy / sigma[:, :, None]).reshape(d.n_obs, -1), prior)
        B = Hinv @ Ju.T
        e = B @ (err / sigma).reshape(-1)
        G = run_deviations(d.runs, sigma).transpose(1, 0, 2).reshape(R, -1) @ B.T   # (R, P)
        sd_runs = np.sqrt((G ** 2).sum(axis=0) / (R - 1) / R)
        out[label] = {n: float(e[names.index(n)] / sd_runs[names.index(n)])
                      for n in PARAMS if n in names}
    return out


def widths(case) -> dict:
    """Per identified physical parameter of one fit: error / sandwich sd, which part leads,
    68 % half-width / sd, and the variance shares."""
    from gprm.fit.methods import uncertainty_of
    from gprm.fit.sandwich import Systematics, error_model, propagate, runs_lead

    f = case.fit
    st = state_of(f)
    prior, names = st.obj.prior, list(f.names)
    x = np.asarray(f.x, float)
    unc = uncertainty_of(f, "sandwich")
    xt = np.array([case.truth.get(n, v) for n, v in zip(names, x)])
    u, ut = prior.to_u(x), prior.to_u(xt)
    parts = propagate(st.obj, x, st.J, prior,
                      error_model(st.obj, x, st.J, st.r, prior, Systematics()))
    sd = np.sqrt(np.diag(parts.total))
    lead = runs_lead(parts)
    lo, hi = (prior.to_u(v[None])[0] for v in unc.interval(0.68))
    share = unc.details["sources"]
    out = []
    for i, n in enumerate(names):
        if n not in case.truth or not unc.identified[i]:
            continue
        z = (ut[i] - u[i]) / sd[i]
        half = (hi[i] - u[i]) if z > 0 else (u[i] - lo[i])
        out.append({"z": float(z), "runs_lead": bool(lead[i]), "half": float(half / sd[i]),
                    "share": {k: float(v[i]) for k, v in share.items()}})
    return out


def widths_table(srcs, a) -> None:
    print("| source | rms z (within 1) | runs lead: n, rms z (within 1) | residuals lead: n, "
          "rms z (within 1) | "
          "68 % half-width / sd, median | variance shares (mean) |")
    print("|---|---|---|---|---|---|")
    for src in srcs:
        rows = [r for k in range(a.campaigns)
                for r in widths(bs.run_case(src, a.seed + k, a.starts, a.cache, a.fit_pool))]
        z = np.array([r["z"] for r in rows])
        lead = np.array([r["runs_lead"] for r in rows])
        mean_share = {k: np.mean([r["share"][k] for r in rows]) for k in rows[0]["share"]}
        sh = ", ".join(f"{k} {v:.3f}" for k, v in mean_share.items() if v > 0)

        def rms(v):
            """rms and the share within one sd (0.68 for a correct sd, robust to the few
            large errors that intervals' own factors cover)"""
            return (f"{np.sqrt(np.mean(v ** 2)):.2f} ({np.mean(np.abs(v) < 1):.2f})"
                    if v.size else "-")
        print(f"| {src} | {rms(z)} | {lead.sum()}, {rms(z[lead])} | {(~lead).sum()}, "
              f"{rms(z[~lead])} | {np.median([r['half'] for r in rows]):.3f} | {sh} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    bs.cached_study_arguments(ap, "white,sim2-white,drive-2")
    ap.add_argument("--fit-pool", type=int, default=SIGMA_POOL)
    ap.add_argument("--pool", type=int, default=SIGMA_POOL)
    ap.add_argument("--widths", action="store_true")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    if a.widths:
        widths_table([s for s in a.sources.split(",") if s], a)
        print(f"\n{a.campaigns} campaigns per source; {time.perf_counter() - t0:.0f} s")
        return 0
    print("| source | weights | " + " | ".join(PARAMS) + " |")
    print("|---|---|" + "---|" * len(PARAMS))
    for src in [s for s in a.sources.split(",") if s]:
        rows = [campaign(bs.run_case(src, a.seed + k, a.starts, a.cache, a.fit_pool), a.pool)
                for k in range(a.campaigns)]
        for label in rows[0]:
            cells = []
            for n in PARAMS:
                v = [r[label][n] for r in rows if n in r[label]]
                cells.append(f"{np.sqrt(np.mean(np.square(v))):.2f}" if v else "-")
            print(f"| {src} | {label} | " + " | ".join(cells) + " |")
    print(f"\nrms over {a.campaigns} campaigns of err/runs; {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
