"""Where the fit's linearisation is taken matters (issue 21): the diagnosis behind the
default uncertainty's variance check (gprm.fit.sandwich.variance_factors), reproducible.

For each campaign of a validation source (benchmarks/sources.py, the fits of
bench_sources.py, read from its ``--cache`` when there), with the truth's lags and offsets
fitted to the data at the truth's physical parameters:

- ``z``: the best fit's error in the sandwich's standard deviations (linearised at the best
  fit, every error source), per parameter;
- ``lin``: the same error predicted by the estimator linearised *at the truth*, applied to
  the data's actual error there (-H^-1 J^T r(truth));
- ``sd(t)/sd(^)``: the runs' spread propagated through the estimator linearised at the truth
  over the same at the best fit;
- ``+-2 sd``: the same ratio at the best fit +-2 sd along the parameter's posterior
  direction, which is what the variance check can see without the truth.

    .venv/bin/python benchmarks/bench_linearisation.py [--source drive-1] [--campaigns 6]
        [--params k_Bx,d2,c_Bx,m1] [--starts 100] [--cache DIR] [--t0]

``--t0``: instead, per campaign, the fitted lag t0's error against the truth's lag in the
fit's time base, the reference signal's crossing offset (gprm.fit.sandwich.crossing_offsets)
and t0's 95 % interval, relative to the truth.

Where ``lin`` matches ``z`` the estimate's error is linear in the data's error, just not at
the best fit; where ``sd(t)/sd(^)`` is far from 1 the spread at the best fit understates the
spread where the truth is, and ``+-2 sd`` shows whether a check along the posterior
direction finds it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_sources  # noqa: E402

from gprm.fit.methods import state_of  # noqa: E402
from gprm.fit.methods import uncertainty_of  # noqa: E402
from gprm.fit.sandwich import Systematics, error_model, propagate  # noqa: E402


def truth_point(case) -> np.ndarray:
    """The fit's parameter vector at the truth, its lags and offsets fitted to the data."""
    f = case.fit
    obj = f.objective()
    names = list(f.names)
    n = obj.data.n_obs
    x = np.array(f.x, float)
    nuis = [k for k, nm in enumerate(names) if nm not in case.truth]
    for k, nm in enumerate(names):
        if nm in case.truth:
            x[k] = case.truth[nm]

    def res(z):
        xx = x.copy()
        xx[nuis] = z
        return obj(obj.to_normalised(xx)[None])[0][0, :n]

    x[nuis] = least_squares(res, x[nuis], x_scale=np.full(len(nuis), 1e-7)).x
    return x


def runs_sd(obj, x, prior, err) -> np.ndarray:
    """(P,) the runs' spread propagated through the estimator linearised at x (u units)."""
    n = obj.data.n_obs
    _, Jn = obj(obj.to_normalised(x)[None])
    return np.sqrt(np.diag(propagate(obj, x, Jn[0, :n] / obj.scale, prior, err).runs))


def diagnose(case, params) -> list[str]:
    f = case.fit
    obj = f.objective()
    prior = obj.prior
    names = list(f.names)
    n = obj.data.n_obs
    xh = np.asarray(f.x, float)
    xt = truth_point(case)
    st = state_of(f)
    err = error_model(obj, xh, st.J, st.r, prior, Systematics())
    Cu = propagate(obj, xh, st.J, prior, err).total
    sd = np.sqrt(np.diag(Cu))
    uh, ut = prior.to_u(xh), prior.to_u(xt)
    rt, Jn = obj(obj.to_normalised(xt)[None])
    Ju = Jn[0, :n] / obj.scale * prior.dx_du(xt)[None, :]
    H = Ju.T @ Ju + np.diag(float(prior.weight) ** 2 / prior.sd ** 2)
    lin = -np.linalg.solve(H, Ju.T @ rt[0, :n])
    s_h, s_t = runs_sd(obj, xh, prior, err), runs_sd(obj, xt, prior, err)
    out = []
    for nm in params:
        k = names.index(nm)
        v = Cu[:, k] / sd[k]
        side = [runs_sd(obj, prior.from_u(uh + a * v), prior, err)[k] / s_h[k]
                for a in (-2, 2)]
        out.append(f"| {case.source} | {case.seed} | {nm} | {(uh - ut)[k] / sd[k]:+.2f} | "
                   f"{lin[k] / sd[k]:+.2f} | {s_t[k] / s_h[k]:.2f} | "
                   f"{side[0]:.2f} / {side[1]:.2f} |")
    return out


def t0_row(case) -> str:
    """The fitted t0's error against the truth's lag in the fit's time base, next to the
    reference signal's crossing offset and the 95 % interval the default now gives t0."""
    u = uncertainty_of(case.fit, "sandwich")
    _, truth_t = bench_sources.truth_in_fit_time(case)
    k = list(case.fit.names).index("t0")
    off = u.details["systematics"]["x_base"]["crossing_offset_s"]
    t = truth_t["t0"]
    return (f"| {case.source} | {case.seed} | {1e6 * (case.fit.x[k] - t):+.2f} | "
            f"{1e6 * off:+.2f} | [{1e6 * (u.lower95[k] - t):+.2f}, {1e6 * (u.upper95[k] - t):+.2f}] |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", default="drive-1")
    ap.add_argument("--campaigns", type=int, default=6)
    ap.add_argument("--seed", type=int, default=5000)
    ap.add_argument("--params", default="k_Bx,d2,c_Bx,m1")
    ap.add_argument("--starts", type=int, default=100)
    ap.add_argument("--cache")
    ap.add_argument("--t0", action="store_true",
                    help="instead: t0's error, x_base's crossing offset and t0's 95 % interval")
    a = ap.parse_args(argv)
    if a.t0:
        print("| source | seed | t0 fit - truth (us) | x_base crossing offset (us) | "
              "t0 95 % interval - truth (us) |")
        print("|---|---|---|---|---|")
        for i in range(a.campaigns):
            print(t0_row(bench_sources.run_case(a.source, a.seed + i, a.starts, a.cache)),
                  flush=True)
        return 0
    params = [p for p in a.params.split(",") if p]
    print("| source | seed | parameter | z (best fit - truth) / sd | lin (at truth) / sd | "
          "sd(t)/sd(^) | +-2 sd: sd/sd(^) |")
    print("|---|---|---|---|---|---|---|")
    for i in range(a.campaigns):
        case = bench_sources.run_case(a.source, a.seed + i, a.starts, a.cache)
        for line in diagnose(case, params):
            print(line, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
