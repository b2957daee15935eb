"""How the sandwich combines the runs' and the residuals' covariance, and what other choices do.

The default's statistical part is ``V_runs + [V_res - V_runs]_+`` (gprm.fit.sandwich), the
positive part taken in the prior's coordinates u. That choice depends on the prior's scale:
where a poorly determined direction's two estimates differ by their own sampling noise, the
positive part of the difference reaches parameters with small variance in u (the lags above
all). Two scale-free alternatives are scored here on the cached fits of bench_sources.py:

``diagonal``  the positive part taken with each parameter scaled by its own sd (invariant to
              the parameters' units and the prior's widths);
``whitened``  the positive part taken in the coordinates that whiten (V_runs + V_res) / 2
              (invariant to any linear reparametrisation).

For each, the Gaussian z-score of every identified physical parameter and of t0 (in the fit's
time axis, bench_sources.truth_in_fit_time) against the truth, with the rest of the sandwich
(gain, timing, interpolation, prior) unchanged and without the intervals' shape, variance
and Student factors: a comparison of the combinations, not the default's coverage (for that,
bench_sources.py).

    .venv/bin/python benchmarks/bench_stat_combination.py --sources white,sim2 --campaigns 20 \\
        --cache DIR
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

import bench_sources as bs  # noqa: E402

from gprm.fit.methods import state_of  # noqa: E402
from gprm.fit.sandwich import _psd_part, error_model, propagate  # noqa: E402

LAGS = ("t0", "t1", "dt_x_head", "dt_y_base", "dt_y_head")


def whitened_max(A: np.ndarray, C: np.ndarray) -> np.ndarray:
    """A + [C - A]_+ in the coordinates that whiten (A + C) / 2."""
    M = 0.5 * (A + C)
    w, V = np.linalg.eigh(0.5 * (M + M.T))
    keep = w > w.max() * 1e-14
    up, down = V[:, keep] * np.sqrt(w[keep]), V[:, keep] / np.sqrt(w[keep])
    a, c = down.T @ A @ down, down.T @ C @ down
    return up @ (a + _psd_part(c - a)) @ up.T


def diagonal_max(A: np.ndarray, C: np.ndarray) -> np.ndarray:
    """A + [C - A]_+ with each parameter scaled by the sd of (A + C) / 2."""
    d = np.sqrt(np.diag(0.5 * (A + C)))
    D = np.outer(d, d)
    a, c = A / D, C / D
    return (a + _psd_part(c - a)) * D


def z_scores(case) -> dict:
    """{combination: {"phys": [z of each identified physical parameter], "t0": z}}."""
    st = state_of(case.fit)
    x = np.asarray(st.x, float)
    err = error_model(st.obj, x, st.J, st.r, st.prior)
    P = propagate(st.obj, x, st.J, st.prior, err)
    names = list(st.names)
    truth_t = bs.truth_in_fit_time(case)[1]
    tu = st.prior.to_u(np.array([truth_t[n] for n in names]))
    u = st.prior.to_u(x)
    rest = P.total - P.statistical
    ident = np.asarray(case.fit.uncertainty.identified)
    out = {}
    for key, S in (("default (u)", P.statistical),
                   ("diagonal", diagonal_max(P.runs, P.residuals)),
                   ("whitened", whitened_max(P.runs, P.residuals))):
        z = (u - tu) / np.sqrt(np.clip(np.diag(S + rest), 1e-300, None))
        out[key] = {"phys": [float(z[i]) for i, n in enumerate(names)
                             if n not in LAGS and ident[i] and n in case.truth],
                    "t0": float(z[names.index("t0")])}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    bs.cached_study_arguments(ap)
    a = ap.parse_args(argv)
    print("| source | combination | identified physical: \\|z\\| < 1.96 | \\|z\\| < 1 | "
          "t0: \\|z\\| < 1.96 | \\|z\\| < 1 |")
    print("|---|---|---|---|---|---|")
    for src in [s for s in a.sources.split(",") if s]:
        acc: dict = {}
        for i in range(a.campaigns):
            case = bs.run_case(src, a.seed + i, a.starts, a.cache)
            for key, v in z_scores(case).items():
                acc.setdefault(key, {"phys": [], "t0": []})
                acc[key]["phys"] += v["phys"]
                acc[key]["t0"].append(v["t0"])
        for key, v in acc.items():
            zp, zt = np.abs(v["phys"]), np.abs(v["t0"])
            print(f"| {src} | {key} | {100 * np.mean(zp < 1.96):.1f} | "
                  f"{100 * np.mean(zp < 1):.1f} | {100 * np.mean(zt < 1.96):.0f} | "
                  f"{100 * np.mean(zt < 1):.0f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
