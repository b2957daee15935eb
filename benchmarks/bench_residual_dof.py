"""The residual kernel (HAC) estimate of the default uncertainty on the studies' fits
(issue 21; docs/fitting.md, "Student's t for the residuals' kernel estimate"): how often it
is the larger statistical part, its degrees of freedom there, and its expectation under
independent errors against the variance it estimates.

    .venv/bin/python benchmarks/bench_residual_dof.py [--sources white,generator,sim2]
        [--campaigns 20] [--starts 100] [--cache DIR] [--hac-lag default,auto,5,0]

For each campaign of each source (the fits of benchmarks/bench_sources.py, read from
``--cache`` where present), over the parameters the cached fit reported as identified:

- ``residuals lead``: the share where the residuals' estimate is the larger of the two
  statistical parts (the runs' and the residuals'), where Student's t takes its degrees of
  freedom (:func:`gprm.fit.sandwich.residual_dof`);
- ``nu``: the median of those degrees of freedom where the residuals lead (the runs' part
  has 9-45 with 10 runs);
- ``mean / target``: the median, over the identified parameters, of the estimate's
  expectation under a Gaussian working model of independent errors of each signal's
  residual mean square over the variance it estimates under that model
  (:func:`gprm.fit.sandwich.residual_moments`): how far the estimate falls short where the
  campaign's error is white. It is not applied as a correction: on the white sources the
  residuals' estimate equals the runs' (``res / runs``, the median ratio of the two parts)
  although under white errors it would fall short by that factor, so the residuals carry
  correlated structure that the working model lacks.

``--hac-lag``: one row per source and lag window of the residuals' kernel estimate
(``Systematics.hac_lag``: ``default`` a quarter of the window's samples, ``auto`` Andrews'
plug-in, or a number of samples; docs/fitting.md, "The residuals' lag window (stop 47)"),
with the median window used and the median nu over every identified parameter (``nu, all``),
not only where the residuals lead.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_sources as bs  # noqa: E402

from gprm.fit import sandwich as sw  # noqa: E402
from gprm.fit.methods import state_of  # noqa: E402


def campaign(case, hac_lag=None) -> dict:
    """One fit's residual estimate at its best fit, over its identified parameters, with the
    lag window ``hac_lag`` (Systematics.hac_lag)."""
    state = state_of(case.fit)
    syst = sw.Systematics(hac_lag=hac_lag)
    x = np.asarray(state.x, float)
    err = sw.error_model(state.obj, x, state.J, state.r, state.prior, syst)
    parts = sw.propagate(state.obj, x, state.J, state.prior, err)
    Ju, Hinv = sw._estimator(x, state.J, state.prior)
    E, V, target = sw.residual_moments(Ju, Hinv, err.R, err.max_lag, err.p_eff,
                                       whitenings=err.whitenings,
                                       projection=getattr(state.obj, "projection", None))
    nu = np.where(V > 0, 2 * E ** 2 / np.maximum(V, 1e-300), np.inf)
    ident = np.asarray(case.fit.uncertainty.identified, bool)
    vres = np.diag(parts.residuals)
    vruns = np.diag(parts.runs) if parts.runs is not None else np.zeros_like(vres)
    lead = ident & ~sw.runs_lead(parts)
    return {"n": int(ident.sum()), "lead": int(lead.sum()), "nu": nu[lead].tolist(),
            "nu_all": nu[ident].tolist(), "lag": int(err.max_lag),
            "ratio": (E / target)[ident].tolist(),
            "res_runs": (vres / np.clip(vruns, 1e-300, None))[ident].tolist()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sources", default="white,generator,sim2")
    ap.add_argument("--campaigns", type=int, default=20)
    ap.add_argument("--seed", type=int, default=5000)
    ap.add_argument("--starts", type=int, default=100)
    ap.add_argument("--cache")
    ap.add_argument("--hac-lag", default="default",
                    help="comma-separated lag windows: default, auto or a number of samples")
    a = ap.parse_args(argv)
    try:
        lags = [bs.hac_lag_arg(v) for v in a.hac_lag.split(",") if v]
    except argparse.ArgumentTypeError as exc:
        ap.error(f"--hac-lag {exc}")
    print("| source | lag window (median) | identified parameters | residuals lead | "
          "median nu there (10-90 %) | median nu, all (10-90 %) "
          "| median mean / target (10-90 %) | median res / runs |")
    print("|---|---|---|---|---|---|---|---|")
    for src, lag in [(s, g) for s in a.sources.split(",") if s for g in lags]:
        rows = [campaign(bs.run_case(src, a.seed + k, a.starts, a.cache), lag)
                for k in range(a.campaigns)]
        n = sum(r["n"] for r in rows)
        lead = sum(r["lead"] for r in rows)
        nu = np.array([v for r in rows for v in r["nu"]])
        nu_all = np.array([v for r in rows for v in r["nu_all"]])
        window = np.median([r["lag"] for r in rows])
        ratio = np.array([v for r in rows for v in r["ratio"]])
        rr = np.array([v for r in rows for v in r["res_runs"]])

        def q(v):
            if not v.size:
                return "-"
            a10, a50, a90 = np.percentile(v, [10, 50, 90])
            return f"{a50:.2f} ({a10:.2f}-{a90:.2f})"

        label = "default" if lag is None else lag
        print(f"| {src} | {label} ({window:g}) | {n} | {lead} ({100 * lead / max(n, 1):.0f} %) "
              f"| {q(nu)} | {q(nu_all)} | {q(ratio)} | {np.median(rr):.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
