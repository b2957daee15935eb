"""Why the x-plane B support (k_Bx, c_Bx, d2) is under-covered when the noise is high
(issue 21; docs/fitting.md, "Probes, and the x-plane support at higher noise").

    .venv/bin/python benchmarks/bench_xplane.py [--sources white,probe-noise-4x]
        [--campaigns 20] [--starts 100] [--cache DIR] [--direct 6] [--names k_Bx,c_Bx,d2,m3]
    .venv/bin/python benchmarks/bench_xplane.py --same-truth 5011 --sources drive-v0-2 \
        --campaigns 8 [--starts 100] [--names ...]

For each campaign of each source (the fits of benchmarks/bench_sources.py, read from
``--cache`` where present) it measures, for k_Bx, c_Bx, d2 and for comparison m3 (or the
parameters ``--names`` lists, e.g. k_lr,m1 with ``--direct 0`` for their offsets):

- ``z``: the truth's distance from the best fit in the default interval's own standard
  deviations (the 68 % half-width on the truth's side), in the prior's coordinates;
- ``sd ratio``: the estimator's linearised sd *at the truth* over that at the best fit (the
  Jacobian at the truth, the physical parameters there and the lags refitted; the weak prior
  and the data weights as in the fit);
- with ``--direct K``: K data sets made directly from the model at the truth plus white
  noise of the campaign's own sigma(t) (no campaign, no preprocessing), each fitted from the
  truth: the rms of the errors in the same sds. If these are as large as the campaign fits'
  errors, the cause is the estimator (its nonlinearity), not the data's preparation.

Prints one table row per source and parameter: rms z, the share of |z| < 1 (nominal 68 %),
the mean z with its standard error over the campaigns (z is truth minus best fit: a mean
away from 0 is a bias common to the campaigns), the median sd ratio, and the direct data's
rms z. The truth's lags come from ``bench_linearisation.truth_point``.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_sources as bs  # noqa: E402
from bench_linearisation import truth_point  # noqa: E402

from gprm.fit import sandwich as sw  # noqa: E402
from gprm.fit.engine import polish_best  # noqa: E402
from gprm.fit.methods import state_of, uncertainty_of  # noqa: E402
from gprm.fit.objective import Objective  # noqa: E402

NAMES = ("k_Bx", "c_Bx", "d2", "m3")


def linear_sd(obj, prior, x: np.ndarray) -> np.ndarray:
    """The estimator's linearised sd in u at ``x`` (H^-1 with the fit's prior weight)."""
    n = obj.data.n_obs
    _, Jn = obj(obj.to_normalised(x)[None])
    J = Jn[0, :n] / obj.scale
    Hinv = sw._linearised(obj, x, J, prior)[1]
    return np.sqrt(np.diag(Hinv))


def campaign(case, direct: int, names_of_interest=NAMES) -> dict:
    st = state_of(case.fit)
    obj, prior, x, names = st.obj, st.prior, np.asarray(st.x, float), list(st.names)
    unc = uncertainty_of(case.fit, "sandwich")
    lo, hi = unc.interval(0.68)
    xt = truth_point(case)
    u, ut = prior.to_u(x), prior.to_u(xt)
    sd_fit, sd_truth = linear_sd(obj, prior, x), linear_sd(obj, prior, xt)
    out = {}
    idx = [names.index(n) for n in names_of_interest]
    for n, i in zip(names_of_interest, idx):
        e = ut[i] - u[i]
        half = (prior.to_u(hi[None])[0][i] - u[i]) if e > 0 else (u[i] - prior.to_u(lo[None])[0][i])
        out[n] = {"z": float(e / half), "ratio": float(sd_truth[i] / sd_fit[i]), "direct": []}
    if direct:
        yt = obj.model(xt[None]).y[0]
        rng = np.random.default_rng([case.seed, 77])
        for _ in range(direct):
            data = replace(obj.data, values=yt + rng.standard_normal(yt.shape) * obj.data.sigma)
            o3 = Objective.create(data, obj.base, obj.names, piezo=obj.piezo,
                                  z_bk_absolute=obj.z_bk_absolute, prior=obj.prior)
            xp, _ = polish_best(o3, xt, case.fit.options.lm)
            up = prior.to_u(xp)
            for n, i in zip(names_of_interest, idx):
                out[n]["direct"].append(float((up[i] - ut[i]) / sd_fit[i]))
    return out


def same_truth(source: str, truth_seed: int, n: int, starts: int, names) -> None:
    """``--same-truth``: ``n`` campaigns of one of gprm's generator's sources, all with the
    truth of seed ``truth_seed`` (``bench_coverage.draw_truth``), made with campaign seeds
    1..n and fitted with the CLI's defaults (``starts`` starts): per campaign each parameter's
    best fit over the truth less 1 and its 68 % interval relative to the best fit; then the
    fits' spread (sd of ln(best fit)) against the median of the stated 68 % half-widths in
    ln, and how many of the campaigns' 68 % intervals hold the truth, with the default and
    without its profile check (``Systematics(profile_check=False)``, stop 48's default).
    The estimator's own spread for one mechanism, which each campaign's interval claims to
    describe."""
    import sources
    from bench_coverage import draw_truth
    from gprm.campaign.preprocess import PreprocessConfig, preprocess
    from gprm.fit.api import FitOptions
    from gprm.fit.identify import identify
    from gprm.fit.methods import uncertainty_of
    from gprm.fit.objective import fit_data_from_means
    from gprm.fit.sandwich import Systematics
    from gprm.fit.starts import MultiStartOptions
    from gprm.params import paper

    truth = draw_truth(truth_seed)
    print(f"{source}, truth of seed {truth_seed}, campaigns 1..{n}, {starts} starts\n")
    print("| campaign | reduced chi2 | " + " | ".join(
        f"{k}: fit / truth - 1 [68 % interval / fit - 1]" for k in names) + " |")
    print("|---|---|" + "---|" * len(names))
    logs: dict[str, list[float]] = {k: [] for k in names}
    halves: dict[str, list[float]] = {k: [] for k in names}
    inside = {k: [0, 0] for k in names}
    for s in range(1, n + 1):
        camp, _ = sources.from_truth(source, s, truth)
        means = preprocess(camp, PreprocessConfig()).to_dataset()
        o = FitOptions()
        fit = identify(fit_data_from_means(means, window=o.window, sigma=o.sigma),
                       o.parameters(paper()), MultiStartOptions(n_starts=starts, seed=s),
                       band_samples=0, uncertainty="sandwich", prior_width=o.prior_width)
        u = fit.uncertainty
        lo, hi = u.interval(0.68)
        lo0, hi0 = uncertainty_of(fit, "sandwich",
                                  systematics=Systematics(profile_check=False)).interval(0.68)
        cells = []
        for k in names:
            j, b = u.names.index(k), fit.x[list(fit.names).index(k)]
            logs[k].append(np.log(b))
            halves[k].append(0.5 * (np.log(hi[j]) - np.log(lo[j])))
            inside[k][0] += int(lo[j] <= truth[k] <= hi[j])
            inside[k][1] += int(lo0[j] <= truth[k] <= hi0[j])
            cells.append(f"{b / truth[k] - 1:+.3f} [{lo[j] / b - 1:+.3f}, {hi[j] / b - 1:+.3f}]")
        print(f"| {s} | {fit.reduced_chi2:.2f} | " + " | ".join(cells) + " |", flush=True)
    print("\n| parameter | sd of ln(best fit) over the campaigns | median stated 68 % "
          "half-width in ln | ratio | 68 % intervals holding the truth | without the profile "
          "check |\n|---|---|---|---|---|---|")
    for k in names:
        sd, h = float(np.std(logs[k], ddof=1)), float(np.median(halves[k]))
        print(f"| {k} | {sd:.3f} | {h:.3f} | {sd / h:.2f} | {inside[k][0]} of {n} | "
              f"{inside[k][1]} of {n} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sources", default="white,probe-noise-4x")
    ap.add_argument("--campaigns", type=int, default=20)
    ap.add_argument("--seed", type=int, default=5000)
    ap.add_argument("--starts", type=int, default=100)
    ap.add_argument("--cache")
    ap.add_argument("--direct", type=int, default=6,
                    help="data sets made directly from the truth per campaign (0: none)")
    ap.add_argument("--names", default=",".join(NAMES),
                    help="fitted parameters to score (comma-separated)")
    ap.add_argument("--same-truth", type=int, default=None, metavar="SEED",
                    help="the first source's campaigns 1..--campaigns all with the truth of "
                    "this seed, fitted afresh (no cache): the estimator's spread for one "
                    "mechanism against the intervals' stated widths")
    a = ap.parse_args(argv)
    names = tuple(n for n in a.names.split(",") if n)
    if a.same_truth is not None:
        same_truth(a.sources.split(",")[0], a.same_truth, a.campaigns, a.starts, names)
        return 0
    print("| source | parameter | rms z | abs z < 1 | mean z (se) | median sd ratio "
          "(truth / fit) | direct data: rms z |")
    print("|---|---|---|---|---|---|---|")
    for src in [s for s in a.sources.split(",") if s]:
        rows = [campaign(bs.run_case(src, a.seed + k, a.starts, a.cache), a.direct, names)
                for k in range(a.campaigns)]
        for n in names:
            z = np.array([r[n]["z"] for r in rows])
            ratio = np.array([r[n]["ratio"] for r in rows])
            d = np.array([v for r in rows for v in r[n]["direct"]])
            dtxt = f"{np.sqrt(np.mean(d ** 2)):.2f}" if d.size else "-"
            print(f"| {src} | {n} | {np.sqrt(np.mean(z ** 2)):.2f} | "
                  f"{np.mean(np.abs(z) < 1):.2f} | "
                  f"{np.mean(z):+.2f} ({np.std(z, ddof=1) / np.sqrt(z.size):.2f}) | "
                  f"{np.median(ratio):.2f} | {dtxt} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
