"""Where the clean sources' width goes, and what narrowing it would cost elsewhere
(docs/fitting.md, "Where the clean sources' width goes (stop 43)").

On the cached fits of bench_sources.py (``--cache``, made with the default weights), per
source and campaign, the default uncertainty's parts per identified physical parameter, and
the coverage the intervals would have had under other rules for two of its parts:

- the estimated gain error (``Systematics.estimate_gain``: a method-of-moments variance
  clipped at 0, so positive on average where there is none) kept only where it stands out
  from its own noise, z > 1.645 (one-sided 5 %; gprm.fit.sandwich.GainMoments);
- the statistical part's excess of the residuals' kernel estimate over the runs' (V_runs +
  [V_res - V_runs]_+, positive on average where both estimate the same matrix) kept only
  for the parameters whose V_res/V_runs exceeds the F(nu_res, nu_runs) quantile q (the two
  parts' Satterthwaite degrees of freedom, gprm.fit.sandwich.residual_dof/satterthwaite);
- the excess dropped altogether;
- the excess taken beyond the synchronisation's part of the timing (V_runs + [V_res - V_runs
  - S]_+, S that part's covariance; stop 45).

The other rules are scored by a proxy: each reported interval's sides scaled by
sqrt(V_rule / V_default) of its parameter, every interval factor (Student's t, shape and
variance checks, alternative minima) held at the default's. The default's own row is the
bench_sources.py table exactly.

``--curves``: instead, per campaign, whether t0's 68 % interval holds the truth's lag and
the share of the velocity curves' points (bench_coverage.curve_cover) inside their 68 %
band: on the clean sources the curves' misses are t0's. With it, linearised at the best
fit (the sandwich's covariance in u before the intervals' factors): t0's share of the curves'
variance, the truth's |z| for t0 and for the curves (median over the points), and the
correlation of the two over the campaigns (stop 45: the curves' common factor is t0). And
in the draws themselves: the curves' 68 % half-width with every parameter but t0 held at the
best fit over the whole band's (median over the points, then over the campaigns; 1: the
band is t0's alone, as the linearisation says it nearly is), and the truth's offset from
the best fit's curves over the part of it t0's own error makes (G_t0 (u_t0 - u^_t0),
linearised; median over the points, then over the campaigns: below 1, the other parameters'
errors cancel part of t0's along the curves), with ``--draws-stretch`` to
score the draws stretched otherwise (stop 57; docs/fitting.md, "The draws stretched
otherwise (stop 57)").

``--t0``: instead, the lag t0's error (in the fit's aligned axis) over its sd under each
part of the sandwich's covariance alone and combined, and under stop 44's default (no drive
shift, the excess on the lags), as an rms z over the campaigns (1: calibrated), with the
parts' shares of the default's variance (stop 45: on the clean sources the curves' common
factor is t0, ``--curves``), the drive term's and the estimated gain's shares alone and the
rms z without the drive term (stop 56: drive-2's ingredients apart).

``--widths``: instead, where the 68 % intervals' width comes from (stop 58): per source, over
the identified physical parameters pooled and each apart, and t0, the truth's error over
the default's sd (the sandwich's covariance with the excess test applied, before the
intervals' factors) and over the Gauss-Newton noise covariance s^2 H^-1 (the white noise's
alone: on a source whose model is exact and whose noise is white the mean still carries
each run's baseline line, which it lacks; ``--noise-mc``, stop 59), as an rms z; the
median of sd over the Gauss-Newton sd, of the 68 % half-width over z_68 sd (the intervals'
factors: Student's t, shape, variance, profile) and of the Student factor alone; and the
share of the truths inside the 68 % interval, inside +-sd and inside +-the Gauss-Newton sd;
and with the gain errors' variance estimate taken as it comes, unclipped
(gprm.fit.sandwich.gain_moments: unbiased, negative by chance where there is no gain error;
the default clips it at 0, which is positive on average there), the cases whose variance is
then not positive and the share of the others inside +-sd; the mean shares of the
default's variance that the residuals' excess over the runs, the gain and the timing parts
make (means: each is zero in most campaigns), and the median of the runs' part's sd over the
Gauss-Newton sd (docs/fitting.md, "Sixty
campaigns on white and drive-1 (stop 58)").

``--noise-mc K``: instead, what the mean's error does through the estimator at fixed truths
(stop 59; docs/fitting.md, "What the runs carry that white noise does not ... (stop 59)"):
for each of the first ``--campaigns`` cached fits of a source of gprm's generator, K more
campaigns made from its truth with fresh noise (seeds 90000 + 1000 k + j), preprocessed as
the fits' were (the runs moved the rest of their shift through the model at the cached
fit's point, as the fit moves them, gprm.fit.subsample); per identified parameter of the
cached fit's linearised estimator B = H^-1 J^T (held fixed): the sd over the K of B e, e
the weighted error of each mean signal against its noise-free truth (``truth_mean``); the
mean over the K of the runs' part, alone, with the synchronisation's hidden time shift
(``sync_timing_sd``) and with the drive's too (``drive_shift_sd`` on each campaign's runs):
the default's statistical-runs and timing terms (its stated timing error is 0); all over
the white-noise part sqrt(B B^T) that the Gauss-Newton covariance holds; and beside them,
without a Monte Carlo, the white noise plus step 0's straight line (each run's baseline fit
extrapolated into the window, gprm.campaign.preprocess.detrended_noise_factor with the
noise runs' sd) over the white noise alone. ``--mc-source SRC``: the fresh campaigns from
another source at the cached fits' truths (drive-1's fits with drive-v0-2's campaigns, say).
``--put-back`` (stop 60; docs/fitting.md, "The drive's shift put back into each run (stop
60)"): two more columns, the runs' part with each run's drive shift h_r
(gprm.fit.sandwich.drive_shift_weights) put back into its deviation along y', its cross
term with the rest of the run's deviation included and the runs' noise's share of both
subtracted in expectation (+ the synchronisation's part; in brackets the share of campaigns
where the sum is negative and its sd over its mean), without and with a time-warp column
(t - t_x) y' in the regression (a stiffness that varies between runs, to first order); and
a second table: per fresh campaign, B e inside each estimate's 68 % / 95 % normal interval
(the default's runs + sync + drive, the two put-backs, and the warp put-back kept only on
the signals whose runs' variance of h exceeds its noise expectation at the 95 % point of
chi2(R - 1) / (R - 1)).

``--prediction-excess``: instead, the residuals' excess tested along each prediction's own
combination of the parameters (stop 57; docs/fitting.md, "The excess tested along each
prediction (stop 57)"): per campaign, the velocity curves' points and the overshoots (as
bench_coverage scores them, 300 draws) under the draws that keep the whole excess (the
default), the draws whose excess the parameters' own tests thinned
(``Systematics.excess_test_draws``) and, per prediction, the one or the other as the
prediction's own ratio g^T V_res g / g^T V_runs g exceeds the median of F(nu_res(g),
nu_runs(g)) or not, g its gradient in u (least squares over the draws), nu_res(g)
:func:`gprm.fit.sandwich.residual_dof` along g and nu_runs(g) Satterthwaite's over the
signals' runs; with the share of predictions that keep it.

``--ridge``: instead, what the uncertainty's draws do to the y-plane spring pair's
combinations that the data determine (K0 = k_Cy + k_Dy, K1 = k_Cy b1 + k_Dy (b1 + b2),
K2 = k_Cy b1^2 + k_Dy (b1 + b2)^2; docs/fitting.md, "Identifiability"): per source, the
median over campaigns of the draws' median and 16-84 % half-width relative to the best
fit's value, against the linearised sd, the truth's distance from the fit; how far the
draws are from where the linearisation puts them (the median over the draws of
|r(u_d) - r(u^) - J (u_d - u^)|, the weighted data residuals, over the best fit's |r(u^)|:
well above 1, one linearised step cannot put a draw back on the data); and the velocity
curves' 68 % coverage with the draws as drawn, as projected onto the data (the default
since stop 44, gprm.fit.draws; with the median share of proposals kept) and with the
unidentified parameters held at the best fit. (Other combinations of the statistical part, scale-free positive parts:
bench_stat_combination.py.)

    .venv/bin/python benchmarks/bench_combination.py --campaigns 20 --cache DIR [--sources ...]
    .venv/bin/python benchmarks/bench_combination.py --curves --sources white --cache DIR
    .venv/bin/python benchmarks/bench_combination.py --widths --sources white --campaigns 60 --cache DIR
    .venv/bin/python benchmarks/bench_combination.py --noise-mc 200 --sources white --campaigns 3 --cache DIR
    .venv/bin/python benchmarks/bench_combination.py --noise-mc 100 --put-back --sources drive-1 --mc-source drive-param-2 --campaigns 2 --cache DIR
"""

from __future__ import annotations

import argparse
from dataclasses import replace
import sys
import time
from pathlib import Path

import numpy as np
from scipy.special import ndtri
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_sources as bs  # noqa: E402

from gprm.fit.methods import state_of, uncertainty_of  # noqa: E402
from gprm.fit.sandwich import (DRAWS_STRETCH, Systematics, _estimator,  # noqa: E402
                               _linearised, _psd_part, error_model, gain_moments,
                               propagate, residual_dof, satterthwaite)

GAIN_Z = 1.645
QUANTILES = (0.5, 0.9)


def default_sandwich(case) -> dict:
    """What the rules', widths' and noise tables start from, for one fitted campaign: the
    fit's state, its default uncertainty, the default's error model and parts at the best fit,
    the estimator's linearisation there (Ju, Hinv, its influence Bs per signal and time, the
    model signals y and their time derivative dy), the residuals' degrees of freedom and the
    gain estimate's moments."""
    f = case.fit
    st = state_of(f)
    prior = st.obj.prior
    x = np.asarray(f.x, float)
    err = error_model(st.obj, x, st.J, st.r, prior, Systematics())
    Ju, Hinv, Bs, y, dy = _linearised(st.obj, x, st.J, prior)
    d = st.obj.data
    return {"st": st, "prior": prior, "names": list(f.names), "x": x,
            "unc": uncertainty_of(f, "sandwich"), "err": err,
            "parts": propagate(st.obj, x, st.J, prior, err, y), "Ju": Ju, "Hinv": Hinv,
            "Bs": Bs, "y": y, "dy": dy,
            "nu_res": residual_dof(Ju, Hinv, err.R, err.max_lag, err.p_eff,
                                   whitenings=err.whitenings,
                                   projection=getattr(st.obj, "projection", None)),
            "gain": gain_moments(Ju, Hinv, err.R, y, d.sigma, d.runs, max_lag=err.max_lag)}


def campaign(case) -> dict:
    """The default's parts per identified physical parameter of one fitted campaign."""
    c = default_sandwich(case)
    st, prior, names, x = c["st"], c["prior"], c["names"], c["x"]
    unc, parts, nu_res = c["unc"], c["parts"], c["nu_res"]
    # the synchronisation's part of the timing (the sandwich with it off, subtracted) and
    # the statistical part with the excess taken beyond it
    sync = parts.timing - propagate(st.obj, x, st.J, prior, error_model(
        st.obj, x, st.J, st.r, prior, Systematics(sync_timing=False))).timing
    beyond = parts.total - parts.statistical + parts.runs + _psd_part(
        parts.residuals - parts.runs - sync)
    nu_runs = satterthwaite(parts.runs_by_signal, parts.n_runs)
    xt = np.array([case.truth.get(n, v) for n, v in zip(names, x)])
    u, ut = prior.to_u(x), prior.to_u(xt)
    lv = {L: [prior.to_u(b[None])[0] for b in unc.interval(L)] for L in (0.68, 0.95)}
    rows = []
    for i, n in enumerate(names):
        if n not in case.truth or not unc.identified[i]:
            continue
        rows.append({"e": ut[i] - u[i], "runs": parts.runs[i, i], "res": parts.residuals[i, i],
                     "excess": parts.statistical[i, i] - parts.runs[i, i],
                     "gain": parts.gain[i, i], "total": parts.total[i, i],
                     "beyond_sync": beyond[i, i],
                     "nu_res": nu_res[i], "nu_runs": nu_runs[i],
                     "sides": {L: (u[i] - lv[L][0][i], lv[L][1][i] - u[i]) for L in lv}})
    return {"gain_z": c["gain"].z, "rows": rows}


def coverage(camps: list[dict], gain_z: float | None = None, q: float | None = None,
             no_excess: bool = False, beyond_sync: bool = False) -> tuple[float, float]:
    """(95 %, 68 %) coverage of the identified parameters under a rule (module docstring)."""
    from scipy.stats import f as fdist

    n = 0
    inside = {0.95: 0, 0.68: 0}
    for c in camps:
        drop_gain = gain_z is not None and c["gain_z"] <= gain_z
        for r in c["rows"]:
            v = r["total"] - (r["gain"] if drop_gain else 0.0)
            if beyond_sync:
                v = r["beyond_sync"]
            elif no_excess:
                v -= r["excess"]
            elif q is not None:
                crit = fdist.ppf(q, r["nu_res"], r["nu_runs"]) if np.isfinite(r["nu_res"]) \
                    else 1.0
                if r["res"] / max(r["runs"], 1e-300) <= crit:
                    v -= r["excess"]
            k = np.sqrt(max(v, 1e-300) / r["total"])
            n += 1
            for L in inside:
                lo, hi = r["sides"][L]
                inside[L] += int(-lo * k <= r["e"] <= hi * k)
    return 100 * inside[0.95] / max(n, 1), 100 * inside[0.68] / max(n, 1)


def rules_table(srcs, a) -> None:
    rules = [("default", {}), (f"gain only where z > {GAIN_Z}", {"gain_z": GAIN_Z})]
    rules += [(f"excess only where V_res/V_runs > F_{q:g}", {"q": q}) for q in QUANTILES]
    rules += [(f"both (F_{QUANTILES[-1]:g})", {"gain_z": GAIN_Z, "q": QUANTILES[-1]}),
              ("no excess", {"no_excess": True}),
              ("excess beyond the synchronisation's part", {"beyond_sync": True})]
    print("| source | gain z: median, share > 1.645 | "
          + " | ".join(f"{name}: 95 / 68 %" for name, _ in rules) + " |")
    print("|---|---|" + "---|" * len(rules))
    inside = [0] * len(rules)
    for src in srcs:
        camps = [campaign(bs.run_case(src, a.seed + k, a.starts, a.cache))
                 for k in range(a.campaigns)]
        z = np.array([c["gain_z"] for c in camps])
        cells = []
        for j, (_, kw) in enumerate(rules):
            c95, c68 = coverage(camps, **kw)
            inside[j] += int(90 <= c95 <= 98 and 60 <= c68 <= 76)
            cells.append(f"{c95:.1f} / {c68:.1f}")
        print(f"| {src} | {np.median(z):+.2f}, {np.mean(z > GAIN_Z):.2f} | "
              + " | ".join(cells) + " |", flush=True)
    print("| sources inside 90-98 / 60-76 % | | " + " | ".join(map(str, inside)) + " |")


def curves_gradient(case, parts, prior, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(G (n, P), d (n,)): the velocity curves' points of bench_coverage.curve_cover (six
    axes, 21 times from the truth's t_c, the fit's aligned axis) differentiated in the prior's
    coordinates u at the best fit (central differences, steps of 0.05 of each coordinate's
    sd in ``parts.total``), and the truth's curves minus the best fit's; points where either
    is undefined dropped."""
    from gprm.flight.predicted import tm_velocity_vs_time
    from gprm.flight.telemetry import AXES
    from gprm.params import batch
    from gprm.params.core import batch_from_vectors
    from gprm.simulate.kinematics import body_motion

    from bench_coverage import curve_times

    truth = bs.truth_in_fit_time(case)[1]
    names = list(case.fit.names)
    t = curve_times(truth)
    u0 = prior.to_u(x)

    def curves(pb):
        v = tm_velocity_vs_time(body_motion(pb, t, piezo=2))
        return np.concatenate([v[ax] for ax in AXES], axis=1)

    P = x.size
    h = 0.05 * np.maximum(np.sqrt(np.clip(np.diag(parts.total), 0.0, None)), 1e-12)
    U = np.concatenate([np.zeros((1, P)), np.diag(h), -np.diag(h)])
    C = curves(batch_from_vectors(case.fit.params, names, prior.from_u(u0[None] + U)))
    G = ((C[1:P + 1] - C[P + 1:]) / (2 * h)[:, None]).T
    d = curves(batch([truth]))[0] - C[0]
    ok = np.isfinite(d) & np.all(np.isfinite(G), axis=1)
    return G[ok], d[ok]


def t0_band_ratio(case, draws: np.ndarray, i: int) -> float:
    """The velocity curves' 68 % half-width (bench_coverage.curve_cover's points) from
    ``draws`` with every parameter but the ``i``-th (t0) held at the best fit, over the
    half-width from the draws as they are: median over the points where both exist."""
    from bench_coverage import curve_times

    from gprm.flight.predicted import tm_velocity_vs_time
    from gprm.flight.telemetry import AXES
    from gprm.params.core import batch_from_vectors
    from gprm.simulate.kinematics import body_motion

    names = list(case.fit.names)
    x = np.asarray(case.fit.x, float)
    t = curve_times(bs.truth_in_fit_time(case)[1])
    held = np.repeat(x[None], len(draws), 0)
    held[:, i] = draws[:, i]
    half = []
    for D in (draws, held):
        m = body_motion(batch_from_vectors(case.fit.params, names, D), t, piezo=2)
        v = tm_velocity_vs_time(m)
        V = np.concatenate([v[ax] for ax in AXES], axis=1)[m.ok]
        ok = np.mean(np.isfinite(V), axis=0) > 0.5
        q = np.full((2, V.shape[1]), np.nan)
        q[:, ok] = np.nanpercentile(V[:, ok], [16, 84], axis=0)
        half.append(0.5 * (q[1] - q[0]))
    with np.errstate(divide="ignore", invalid="ignore"):
        r = half[1] / half[0]
    return float(np.nanmedian(r[np.isfinite(r)])) if np.isfinite(r).any() else float("nan")


def curves_table(srcs, a) -> None:
    from bench_coverage import curve_cover

    from gprm.fit.files import FittedModel

    syst = Systematics(draws_stretch=a.draws_stretch)
    print(f"(draws stretched: {a.draws_stretch})")
    print("| source | campaigns | t0 outside its 68 % | curves' points inside 68 %: "
          "those campaigns | the others | all | linearised: t0's share of the curves' "
          "variance, median | \\|z\\| of t0, of the curves: medians | their correlation "
          "over the campaigns | draws: t0's band over the curves' band, median (range) | "
          "the truth's offset from the curves over t0's error's part, median (range) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for src in srcs:
        out_in = out_n = in_in = in_n = 0
        n_out = 0
        share, z_t0, z_cv, band, offset = [], [], [], [], []
        for k in range(a.campaigns):
            case = bs.run_case(src, a.seed + k, a.starts, a.cache)
            unc = uncertainty_of(case.fit, "sandwich", systematics=syst)
            names = list(case.fit.names)
            i = names.index("t0")
            lo, hi = unc.interval(0.68)
            t_true = bs.truth_in_fit_time(case)[1]["t0"]
            fm = FittedModel(case.fit.params, unc.covariance, piezo=2, draws=unc.draws,
                             uncertainty=unc.method)
            c = curve_cover(fm, bs.truth_in_fit_time(case)[1], 200, case.seed)
            band.append(t0_band_ratio(case, np.asarray(unc.draws, float), i))
            if lo[i] <= t_true <= hi[i]:
                in_in, in_n = in_in + c["in68"], in_n + c["n"]
            else:
                n_out += 1
                out_in, out_n = out_in + c["in68"], out_n + c["n"]
            # the linearised picture: how much of the curves' variance (the sandwich's
            # covariance in u, before the intervals' factors) is t0's own, and whether the
            # truth's offset from the curves follows t0's
            st = state_of(case.fit)
            x = np.asarray(st.x, float)
            prior = st.obj.prior
            parts = propagate(st.obj, x, st.J, prior,
                              error_model(st.obj, x, st.J, st.r, prior, Systematics()))
            G, d = curves_gradient(case, parts, prior, x)
            if d.size:
                v = np.einsum("ij,jk,ik->i", G, parts.total, G)
                share.append(float(np.median(G[:, i] ** 2 * parts.total[i, i] / v)))
                z_cv.append(float(np.median(np.abs(d) / np.sqrt(v))))
                u_true = prior.to_u(np.array([bs.truth_in_fit_time(case)[1][n]
                                              for n in names]))[i]
                z_t0.append(abs(u_true - prior.to_u(x)[i]) / np.sqrt(parts.total[i, i]))
                # the truth's offset from the fit's curves over t0's error's own part of it
                # (linearised): below 1, the other parameters' errors cancel part of t0's
                part = np.abs(G[:, i] * (u_true - prior.to_u(x)[i]))
                keep = part > 0
                if keep.any():
                    offset.append(float(np.median(np.abs(d[keep]) / part[keep])))

        def pct(p, q):
            """share inside, with the points counted"""
            return f"{100 * p / q:.1f} ({q})" if q else "-"
        corr = float(np.corrcoef(z_t0, z_cv)[0, 1]) if len(z_cv) > 2 else float("nan")
        print(f"| {src} | {a.campaigns} | {n_out} | {pct(out_in, out_n)} | {pct(in_in, in_n)} | "
              f"{pct(out_in + in_in, out_n + in_n)} | {np.median(share):.2f} | "
              f"{np.median(z_t0):.2f}, {np.median(z_cv):.2f} | {corr:.2f} | "
              f"{np.nanmedian(band):.2f} ({np.nanmin(band):.2f}-{np.nanmax(band):.2f}) | "
              f"{np.median(offset):.2f} ({np.min(offset):.2f}-{np.max(offset):.2f}) |",
              flush=True)


def t0_table(srcs, a) -> None:
    """``--t0``: t0's error against its sd under the sandwich's parts (module docstring)."""
    print("| source | t0's rms z with: the default | stop 44's default (no drive shift, the "
          "excess on the lags) | runs' part only | residuals' only | runs + timing, stop 44 "
          "| the noise's Gauss-Newton covariance | the excess beyond the synchronisation's "
          "part, stop 44 | the drive's shift on x_base, median ns | shares of the default: "
          "statistical, timing (of which the synchronisation's and the drive's) | shares "
          "of the default: the drive's term alone, the gain's | t0's rms z without the "
          "drive's term |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    old = Systematics(drive_timing=False, excess_on_lags=True)
    for src in srcs:
        rows = []
        for k in range(a.campaigns):
            case = bs.run_case(src, a.seed + k, a.starts, a.cache)
            st = state_of(case.fit)
            x, prior = np.asarray(st.x, float), st.obj.prior
            err = error_model(st.obj, x, st.J, st.r, prior, Systematics())
            P = propagate(st.obj, x, st.J, prior, err)
            e44 = error_model(st.obj, x, st.J, st.r, prior, old)
            P44 = propagate(st.obj, x, st.J, prior, e44)
            no_sync = propagate(st.obj, x, st.J, prior, error_model(
                st.obj, x, st.J, st.r, prior, replace(old, sync_timing=False)))
            no_drive = propagate(st.obj, x, st.J, prior, error_model(
                st.obj, x, st.J, st.r, prior, Systematics(sync_timing=False,
                                                          drive_timing=False)))
            only_drive_off = propagate(st.obj, x, st.J, prior, error_model(
                st.obj, x, st.J, st.r, prior, Systematics(drive_timing=False)))
            names = list(case.fit.names)
            i = names.index("t0")
            truth = bs.truth_in_fit_time(case)[1]
            e = prior.to_u(x)[i] - prior.to_u(np.array([truth[n] for n in names]))[i]
            _, Hinv = _estimator(x, st.J, prior)
            s2 = float(st.r @ st.r) / max(st.obj.dof, 1)
            sync = P44.timing - no_sync.timing
            beyond = P44.total - P44.statistical + P44.runs + _psd_part(
                P44.residuals - P44.runs - sync)
            k0 = list(st.obj.data.signals).index("x_base")
            drive = 0.0 if err.drive_timing_sd is None else float(err.drive_timing_sd[k0])
            rows.append([e ** 2, P.total[i, i], P44.total[i, i], P.runs[i, i],
                         P.residuals[i, i], P44.runs[i, i] + P44.timing[i, i],
                         s2 * Hinv[i, i], beyond[i, i], drive * 1e9,
                         P.statistical[i, i] / P.total[i, i], P.timing[i, i] / P.total[i, i],
                         (P.timing[i, i] - no_drive.timing[i, i]) / P.total[i, i],
                         (P.timing[i, i] - only_drive_off.timing[i, i]) / P.total[i, i],
                         P.gain[i, i] / P.total[i, i],
                         P.total[i, i] - (P.timing[i, i] - only_drive_off.timing[i, i])])
        R = np.array(rows)

        def rms(j, R=R):
            return f"{np.sqrt(np.mean(R[:, 0] / R[:, j])):.2f}"
        print(f"| {src} | " + " | ".join(rms(j) for j in range(1, 8))
              + f" | {np.median(R[:, 8]):.1f} | {np.median(R[:, 9]):.2f}, "
              f"{np.median(R[:, 10]):.2f} ({np.median(R[:, 11]):.2f}) | "
              f"{np.median(R[:, 12]):.2f}, {np.median(R[:, 13]):.2f} | "
              f"{np.sqrt(np.mean(R[:, 0] / R[:, 14])):.2f} |", flush=True)


def draws_gradients(U: np.ndarray, V: np.ndarray) -> np.ndarray:
    """(Q, P): each prediction's gradient in u, least squares of its values V (n, Q) over the
    draws' coordinates U (n, P) with an intercept."""
    A = np.concatenate([np.ones((U.shape[0], 1)), U - U.mean(0)], 1)
    coef = np.linalg.lstsq(A, V - V.mean(0), rcond=None)[0]
    return coef[1:].T


def excess_along(case, G: np.ndarray) -> np.ndarray:
    """(Q,) bool: whether each combination g (rows of G, in u) keeps the residuals' excess:
    g^T V_res g / g^T V_runs g above the median of F(nu_res(g), nu_runs(g)) (all True where
    the campaign has no runs to test against)."""
    from scipy.special import fdtri

    st = state_of(case.fit)
    x, prior = np.asarray(st.x, float), st.obj.prior
    err = error_model(st.obj, x, st.J, st.r, prior, Systematics())
    parts = propagate(st.obj, x, st.J, prior, err)
    if parts.runs is None or err.dev is None or err.dev.shape[1] < 2:
        return np.ones(G.shape[0], bool)
    ratio = (np.einsum("qi,ij,qj->q", G, parts.residuals, G)
             / np.maximum(np.einsum("qi,ij,qj->q", G, parts.runs, G), 1e-300))
    Ju, Hinv, Bs, _, _ = _linearised(st.obj, x, st.J, prior)
    n_r = err.dev.shape[1]
    Bg = np.einsum("qp,pst->qst", G, Bs)
    by_signal = np.stack([np.sum((err.dev[s] @ Bg[:, s, :].T) ** 2, axis=0)
                          for s in range(Bs.shape[1])]) / (n_r * (n_r - 1))
    nu_runs = satterthwaite(by_signal, n_r)
    nu_res = residual_dof(Ju, Hinv, err.R, err.max_lag, err.p_eff, whitenings=err.whitenings,
                          projection=getattr(st.obj, "projection", None), rows=G)
    return ratio > fdtri(nu_res, nu_runs, 0.5)


def _band_counts(V: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(in 95 %, in 68 %, n) of the truths x (Q,) in the draws' percentile bands V (n, Q)."""
    q = np.percentile(V, [2.5, 97.5, 16, 84], axis=0)
    return np.array([np.sum((q[0] <= x) & (x <= q[1])), np.sum((q[2] <= x) & (x <= q[3])),
                     x.size], float)


PREDICTION_RULES = ("the whole excess (default)", "tested per parameter",
                    "tested along each prediction")


def prediction_excess(case, n: int = 300) -> dict:
    """One campaign's counts for ``--prediction-excess``: {group: {rule: (in95, in68, n)},
    group + "_keep": share of predictions whose own test keeps the excess}."""
    from bench_coverage import curve_times, overshoots

    from gprm.fit.files import FittedModel
    from gprm.flight.predicted import tm_velocity_vs_time
    from gprm.flight.telemetry import AXES
    from gprm.params import batch
    from gprm.predict.scenarios import apply_scenario, standard_scenarios
    from gprm.predict.trajectories import default_times
    from gprm.simulate.kinematics import body_motion

    fms = []
    for syst in (None, Systematics(excess_test_draws=True)):
        u = uncertainty_of(case.fit, "sandwich", systematics=syst)
        fms.append(FittedModel(case.fit.params, u.covariance, piezo=2, draws=u.draws,
                               uncertainty=u.method))
    prior = state_of(case.fit).obj.prior
    names = list(case.fit.names)

    def to_u(pb):
        return prior.to_u(np.stack([np.asarray(pb[k], float) for k in names], 1))

    def score(V0, V1, U, x):
        keep = excess_along(case, draws_gradients(U, V0))
        return keep, {r: _band_counts(np.where(sel[None], V0, V1), x) for r, sel in zip(
            PREDICTION_RULES, (np.ones_like(keep), np.zeros_like(keep), keep))}

    truth = bs.truth_in_fit_time(case)[1]
    out = {}
    t = curve_times(truth)
    vt = np.concatenate([tm_velocity_vs_time(body_motion(batch([truth]), t, piezo=2))[a][0]
                         for a in AXES])
    vals, oks, Us = [], [], []
    for fm in fms:
        pb = fm.sample(n, case.seed)
        m = body_motion(pb, t, piezo=2)
        vd = tm_velocity_vs_time(m)
        vals.append(np.concatenate([vd[a] for a in AXES], 1))
        oks.append(m.ok)
        Us.append(to_u(pb))
    ok = oks[0] & oks[1]
    cols = np.isfinite(vt) & np.all([np.mean(np.isfinite(v[ok]), 0) > 0.5 for v in vals], 0)
    keep, out["curves"] = score(*(np.nan_to_num(v[ok][:, cols]) for v in vals), Us[0][ok],
                                vt[cols])
    out["curves_keep"] = float(keep.mean())
    out["overshoots"] = {r: np.zeros(3) for r in PREDICTION_RULES}
    kept = []
    for sc in standard_scenarios():
        t_os = overshoots(batch([truth]), sc, default_times())[0][0]
        moving = t_os > 0.01 * t_os.max()
        res = []
        for fm in fms:
            pb = apply_scenario(fm, sc).sample(n, case.seed)
            res.append((*overshoots(pb, sc, default_times()), to_u(pb)))
        ok = res[0][1] & res[1][1]
        keep, c = score(res[0][0][ok][:, moving], res[1][0][ok][:, moving], res[0][2][ok],
                        t_os[moving])
        kept.append(keep)
        for r in PREDICTION_RULES:
            out["overshoots"][r] += c[r]
    out["overshoots_keep"] = float(np.concatenate(kept).mean())
    return out


def prediction_excess_table(srcs, a) -> None:
    """``--prediction-excess``: the predictions' coverage under the three rules for the
    residuals' excess in the draws (module docstring)."""
    print("| source | group | predictions whose own test keeps the excess | "
          + " | ".join(f"{r}: 95 / 68 %" for r in PREDICTION_RULES) + " |")
    print("|---|---|---|" + "---|" * len(PREDICTION_RULES))
    for src in srcs:
        tot: dict = {}
        keep: dict = {}
        for k in range(a.campaigns):
            o = prediction_excess(bs.run_case(src, a.seed + k, a.starts, a.cache))
            for g in ("curves", "overshoots"):
                for r in PREDICTION_RULES:
                    tot.setdefault(g, {}).setdefault(r, np.zeros(3))
                    tot[g][r] += o[g][r]
                keep.setdefault(g, []).append(o[g + "_keep"])
        for g in ("curves", "overshoots"):
            cells = " | ".join(f"{100 * v[0] / v[2]:.1f} / {100 * v[1] / v[2]:.1f}"
                               for v in tot[g].values())
            print(f"| {src} | {g} | {100 * np.mean(keep[g]):.0f} % | {cells} |", flush=True)


def _k(M: np.ndarray, idx: dict) -> np.ndarray:
    """(..., 3): K0, K1, K2 of parameter rows M (SI) with the columns ``idx``."""
    kc, kd, b1, b2 = (M[..., idx[n]] for n in ("k_Cy", "k_Dy", "b1", "b2"))
    return np.stack([kc + kd, kc * b1 + kd * (b1 + b2), kc * b1 ** 2 + kd * (b1 + b2) ** 2],
                    -1)


def ridge_table(srcs, a) -> None:
    from bench_coverage import curve_cover
    from gprm.fit.files import FittedModel

    print("| source | K0, K1, K2: draws' median / fit, as drawn | projected | draws' 16-84 "
          "half-width / fit, as drawn | projected | linearised sd / fit | truth - fit, / fit "
          "| draws' misfit to the linearisation / fit's residual | proposals kept | curves "
          "68 %: as drawn | projected | unidentified held at the fit |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for src in srcs:
        med, half, lin, off, mis, acc = ({"raw": [], "proj": []}, {"raw": [], "proj": []},
                                         [], [], [], [])
        cov = {"raw": [0, 0], "proj": [0, 0], "held": [0, 0]}
        for k in range(a.campaigns):
            case = bs.run_case(src, a.seed + k, a.starts, a.cache)
            uncs = {"raw": uncertainty_of(case.fit, "sandwich",
                                          systematics=Systematics(project_draws=False)),
                    "proj": uncertainty_of(case.fit, "sandwich")}
            unc = uncs["raw"]
            acc.append(uncs["proj"].details["draws"]["acceptance"])
            names = list(case.fit.names)
            x = np.asarray(case.fit.x, float)
            idx = {n: names.index(n) for n in ("k_Cy", "k_Dy", "b1", "b2")}
            K0 = _k(x, idx)
            for key, u in uncs.items():
                Kd = _k(np.asarray(u.draws, float), idx)
                med[key].append(np.median(Kd, 0) / K0)
                half[key].append((np.percentile(Kd, 84, 0) - np.percentile(Kd, 16, 0)) / 2 / K0)
            D = np.asarray(unc.draws, float)
            sel = list(idx.values())
            G = []
            for j in sel:
                xx = x.copy()
                xx[j] *= 1 + 1e-6
                G.append((_k(xx, idx) - K0) / (x[j] * 1e-6))
            G = np.array(G)
            C = np.asarray(unc.covariance)[np.ix_(sel, sel)]
            xt = np.array([case.truth.get(n, v) for n, v in zip(names, x)])
            lin.append(np.sqrt(np.diag(G.T @ C @ G)) / K0)
            off.append(np.abs(_k(xt, idx) - K0) / K0)
            st = state_of(case.fit)
            obj, prior = st.obj, st.obj.prior
            n = obj.data.n_obs
            Ju, _ = _estimator(x, st.J, prior)
            U = prior.to_u(D) - prior.to_u(x)[None]
            rd = obj.residuals(obj.to_normalised(D))[:, :n]
            miss = np.linalg.norm(rd - st.r[None] - U @ Ju.T, axis=1)
            mis.append(float(np.nanmedian(miss)) / float(np.linalg.norm(st.r)))
            truth = bs.truth_in_fit_time(case)[1]
            un = ~np.asarray(unc.identified)
            held = D.copy()
            held[:, un] = x[un]
            for key, dr in (("raw", D), ("proj", uncs["proj"].draws), ("held", held)):
                fm = FittedModel(case.fit.params, unc.covariance, piezo=2, draws=dr,
                                 uncertainty=unc.method)
                c = curve_cover(fm, truth, 200, case.seed)
                cov[key][0] += c["in68"]
                cov[key][1] += c["n"]

        def f3(v):
            return ", ".join(f"{x:.3g}" for x in np.median(np.array(v), 0))

        def pc(key, cov=cov):
            return f"{100 * cov[key][0] / max(cov[key][1], 1):.1f}"
        print(f"| {src} | {f3(med['raw'])} | {f3(med['proj'])} | {f3(half['raw'])} | "
              f"{f3(half['proj'])} | {f3(lin)} | {f3(off)} | {np.median(mis):.3g} | "
              f"{np.median(acc):.2f} | {pc('raw')} | {pc('proj')} | {pc('held')} |", flush=True)


def widths_table(srcs, a) -> None:
    """``--widths``: the 68 % intervals' width taken apart (module docstring)."""
    from gprm.fit.sandwich import (excess_mask, statistical_dof, student_factors,
                                   with_excess_mask)

    z68 = float(ndtri(0.84))
    print("| source | parameter | cases | rms z: sd / Gauss-Newton | sd over Gauss-Newton, "
          "median | 68 % half-width over z sd, median (Student's factor) | inside 68 %: "
          "interval / +-sd / +-Gauss-Newton sd | the gain unclipped: cases whose variance "
          "is not positive, the others inside +-sd | shares of the default's variance, mean: "
          "the residuals' excess, the gain, the timing | the runs' part's sd over "
          "Gauss-Newton's, median |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for src in srcs:
        rows = []
        for k in range(a.campaigns):
            case = bs.run_case(src, a.seed + k, a.starts, a.cache)
            c = default_sandwich(case)
            st, prior, names, x = c["st"], c["prior"], c["names"], c["x"]
            unc, parts, nu_res = c["unc"], c["parts"], c["nu_res"]
            mask = excess_mask(parts, nu_res, Systematics().excess_test)
            if mask is not None:
                parts = with_excess_mask(parts, mask)
            t68 = student_factors(statistical_dof(parts, nu_res), 0.68)
            s2 = float(st.r @ st.r) / max(st.obj.dof, 1)
            Hinv, gv, Bs, d = c["Hinv"], c["gain"].variance, c["Bs"], st.obj.data
            # the gain part for a unit gain error on every signal (propagate's V_gain)
            bg = [Bs[:, s, :] @ (c["y"][s] / d.sigma[s]) for s in range(Bs.shape[1])]
            unit = sum(np.outer(b, b) for b in bg)
            v_u = np.diag(parts.total - parts.gain + gv * unit)
            sd_u = np.sqrt(np.where(v_u > 0, v_u, np.nan))
            truth = bs.truth_in_fit_time(case)[1]
            u, ut = prior.to_u(x), prior.to_u(np.array([truth[n] for n in names]))
            lo, hi = (prior.to_u(b[None])[0] for b in unc.interval(0.68))
            sd = np.sqrt(np.clip(np.diag(parts.total), 1e-300, None))
            gn = np.sqrt(s2 * np.clip(np.diag(Hinv), 1e-300, None))
            for i, n in enumerate(names):
                if n == "t0" or (n in case.truth and unc.identified[i]):
                    e = ut[i] - u[i]
                    half = hi[i] - u[i] if e > 0 else u[i] - lo[i]
                    tot = sd[i] ** 2
                    rows.append((n, e / sd[i], e / gn[i], sd[i] / gn[i], half / (z68 * sd[i]),
                                 t68[i], abs(e) <= half, e / sd_u[i],
                                 (parts.statistical[i, i] - parts.runs[i, i]) / tot,
                                 parts.gain[i, i] / tot, parts.timing[i, i] / tot,
                                 np.sqrt(max(parts.runs[i, i], 0.0)) / gn[i]))

        def line(label, rr, src=src):
            A = np.array([r[1:] for r in rr], float)
            print(f"| {src} | {label} | {len(rr)} | {np.sqrt(np.mean(A[:, 0] ** 2)):.2f} / "
                  f"{np.sqrt(np.mean(A[:, 1] ** 2)):.2f} | {np.median(A[:, 2]):.2f} | "
                  f"{np.median(A[:, 3]):.2f} ({np.median(A[:, 4]):.2f}) | "
                  f"{100 * np.mean(A[:, 5]):.1f} / {100 * np.mean(np.abs(A[:, 0]) <= 1):.1f} / "
                  f"{100 * np.mean(np.abs(A[:, 1]) <= 1):.1f} | "
                  f"{np.sum(~np.isfinite(A[:, 6]))}, "
                  f"{100 * np.mean(np.abs(A[np.isfinite(A[:, 6]), 6]) <= 1):.1f} | "
                  f"{np.mean(A[:, 7]):.2f}, {np.mean(A[:, 8]):.2f}, "
                  f"{np.mean(A[:, 9]):.2f} | {np.median(A[:, 10]):.2f} |", flush=True)
        line("identified physical, pooled", [r for r in rows if r[0] != "t0"])
        for n in sorted({r[0] for r in rows}):
            line(n, [r for r in rows if r[0] == n])


def put_back_parts(obj, Bs: np.ndarray, dy: np.ndarray, W: np.ndarray):
    """((S, P), (S,)): per signal, what putting each run's drive shift h_r = W . (run - mean)
    back into its deviation along y' adds to the runs' part's variances (the cross term with
    the rest of the run's deviation included), less what the runs' noise adds to them in
    expectation (gprm.fit.sandwich's put-back correction); and the runs' variance of h over
    its noise expectation (``--put-back``)."""
    from gprm.campaign.preprocess import detrended_noise_cross
    from gprm.fit.sandwich import (_baseline_times, _put_back_correction, run_deviations,
                                   run_noise_variance)

    d = obj.data
    S, R, T = d.runs.shape
    dev = run_deviations(d.runs, d.sigma)
    dt = float(d.time[1] - d.time[0])
    out, F = np.zeros((S, Bs.shape[0])), np.zeros(S)
    for s in range(S):
        u = dy[s] / d.sigma[s]
        h = (d.runs[s] - d.runs[s].mean(axis=0)) @ W[s]
        Z0 = dev[s] @ Bs[:, s, :].T
        Z = Z0 + h[:, None] * (Bs[:, s, :] @ u)[None, :]
        q = run_noise_variance(d, s, W[s])
        F[s] = np.var(h, ddof=1) / q if q > 0 else np.inf
        acov = (d.noise_acov[s] if d.noise_acov is not None
                else np.array([float(d.noise_std[s]) ** 2]))
        one = np.zeros(S)
        one[s] = q
        U, Cv = np.zeros((S, T)), np.zeros((S, T))
        U[s] = u
        Cv[s] = detrended_noise_cross(W[s], d.time, _baseline_times(d, s), acov, dt) / d.sigma[s]
        out[s] = ((np.sum(Z ** 2, axis=0) - np.sum(Z0 ** 2, axis=0)) / (R * (R - 1))
                  - np.diag(_put_back_correction(Bs, (U, Cv, one), R)))
    return out, F


def noise_mc_table(srcs, a) -> None:
    """``--noise-mc K``: the mean's noise through the estimator at fixed truths (module
    docstring)."""
    import sources

    from gprm.campaign.preprocess import PreprocessConfig, detrended_noise_factor, preprocess
    from gprm.fit.api import FitOptions
    from gprm.fit import subsample
    from gprm.fit.objective import Objective, fit_data_from_means
    from gprm.fit.sandwich import (drive_shift_sd, drive_shift_weights, run_deviations,
                                   runs_covariance)
    from gprm.params import paper

    opts = FitOptions()
    base = opts.parameters(paper())
    pb_head = (" the runs' part with the drive's shift put back, + sync (negative, sd / mean) |"
               " the same with a time-warp column (negative, sd / mean) |" if a.put_back else "")
    print("| source | truth (seed) | parameter | fresh campaigns | sd of B e over the white "
          "part | the runs' part over it, mean | the runs' and the synchronisation's "
          "timing parts over it, mean | and the drive's timing part too | white + step "
          "0's line over white, predicted |" + pb_head)
    print("|---|---|---|---|---|---|---|---|---|" + "---|" * (2 * a.put_back))
    coverage = []
    for src in srcs:
        if src.startswith("sim2") or src == "probe-sim2-2x":
            print(f"| {src} | (sim2 draws its own truth: skipped) ||||||||")
            continue
        for k in range(a.campaigns):
            case = bs.run_case(src, a.seed + k, a.starts, a.cache)
            c = default_sandwich(case)
            st, names, unc, Bs, dy = c["st"], c["names"], c["unc"], c["Bs"], c["dy"]
            d = st.obj.data
            P, S, _ = Bs.shape
            # the synchronisation's hidden time shift through the estimator, per unit sd
            bt = np.stack([Bs[:, s, :] @ (dy[s] / d.sigma[s]) for s in range(S)])  # (S, P)
            white = np.einsum("pst,pst->p", Bs, Bs)
            # step 0's line in the mean: each run's noise (sd noise_std) after its baseline
            # line, averaged over the runs, along the weights B / sigma; against the same
            # noise without the line (|w|^2 alone)
            dt = float(d.time[1] - d.time[0])
            with_line, alone = np.zeros(P), np.zeros(P)
            for s in range(S):
                tb = np.arange(d.baseline[s][0], d.baseline[s][1] + dt / 2, dt)
                v = float(d.noise_std[s]) ** 2 / d.runs.shape[1]
                for i in range(P):
                    w = Bs[i, s] / d.sigma[s]
                    with_line[i] += v * detrended_noise_factor(w, d.time, tb)
                    alone[i] += v * float(w @ w)
            truth = paper().with_values(**case.truth)
            err, runs, sync, drive, put = [], [], [], [], []
            gen = a.mc_source or src
            # the time-warp column (t - t_x) y', t_x each mean's crossing: a run whose
            # stiffness differs is, to first order, the motion on a stretched time axis
            t_x = (np.full(S, PreprocessConfig().align_time) if d.crossing_time is None
                   else np.asarray(d.crossing_time, float))
            warp = ((d.time[None, :] - t_x[:, None]) * dy)[:, :, None]
            for j in range(a.noise_mc):
                camp = sources.from_truth(gen, 90000 + 1000 * k + j, truth)[0]
                ds = preprocess(camp, PreprocessConfig()).to_dataset()
                got = [fit_data_from_means(v, window=opts.window, sigma=opts.sigma,
                                           sigma_pool=d.sigma_pool)
                       for v in (ds, ds.assign(mean=ds["truth_mean"]))]
                if got[0].values.shape != d.values.shape:
                    continue
                obj = Objective.create(got[0], base, names, prior=c["prior"])
                if subsample.applies(got[0]):
                    # the runs moved the rest of their shift through the model, as the fit
                    # moves them (gprm.fit.subsample), at the cached fit's point
                    got[0] = subsample.corrected(got[0], subsample.run_corrections(
                        obj, c["x"], got[0].sync_remainder))
                    obj = Objective.create(got[0], base, names, prior=c["prior"])
                v_sd = drive_shift_sd(obj, c["x"], dy)
                drive.append(np.zeros(P) if v_sd is None else v_sd ** 2 @ bt ** 2)
                if a.put_back:
                    put.append([put_back_parts(obj, Bs, dy, drive_shift_weights(
                        obj, c["x"], dy, extra=ex)) for ex in (None, warp)])
                e = (got[0].values - got[1].values) / got[0].sigma
                err.append(np.einsum("pst,st->p", Bs, e))
                runs.append(np.diag(runs_covariance(Bs, run_deviations(got[0].runs,
                                                                       got[0].sigma))))
                sync.append(np.asarray(got[0].sync_timing_sd, float) ** 2 @ bt ** 2)
            E, V, W, D = np.array(err), np.array(runs), np.array(sync), np.array(drive)
            # (K, 2, P): the runs' part's change with the shift put back, without / with
            # the warp column; the same kept only on the signals whose runs show a shift
            # (their variance of h over its noise expectation above the 95 % point of
            # chi2(R - 1) / (R - 1))
            if a.put_back:
                R_ = d.runs.shape[1]
                crit = chi2.ppf(0.95, R_ - 1) / (R_ - 1)
                U = np.array([[p.sum(axis=0) for p, _ in m] for m in put])
                Ut = np.array([[(p * (F > crit)[:, None]).sum(axis=0) for p, F in m]
                               for m in put])
                # per fresh campaign, each estimate's interval against B e
                est = np.stack([V + W + D, V + W + U[:, 0], V + W + U[:, 1], V + W + Ut[:, 1]],
                               axis=1)                                       # (K, 4, P)
                z = np.abs(E[:, None, :]) / np.sqrt(np.maximum(est, 1e-300))
                coverage.append((gen, a.seed + k, [n for i, n in enumerate(names)
                                                   if unc.identified[i]],
                                 np.mean(z < 1.0, axis=0)[:, unc.identified],
                                 np.mean(z < ndtri(0.975), axis=0)[:, unc.identified]))
            for i, n in enumerate(names):
                if not unc.identified[i]:
                    continue
                pb_cells = ""
                for m in range(2 if a.put_back else 0):
                    tot = V[:, i] + U[:, m, i] + W[:, i]
                    pb_cells += (f" {np.sqrt(max(np.mean(tot), 0.0) / white[i]):.3f} "
                                 f"({np.mean(tot < 0):.2f}, "
                                 f"{np.std(tot) / abs(np.mean(tot)):.2f}) |")
                print(f"| {gen} | {a.seed + k} | {n} | {len(E)} | "
                      f"{np.std(E[:, i]) / np.sqrt(white[i]):.3f} | "
                      f"{np.sqrt(np.mean(V[:, i]) / white[i]):.3f} | "
                      f"{np.sqrt(np.mean(V[:, i] + W[:, i]) / white[i]):.3f} | "
                      f"{np.sqrt(np.mean(V[:, i] + W[:, i] + D[:, i]) / white[i]):.3f} | "
                      f"{np.sqrt(with_line[i] / alone[i]):.3f} |" + pb_cells, flush=True)
    if coverage:
        print("\nThe fresh campaigns' B e inside each estimate's 68 % / 95 % normal interval "
              "(per cent; the runs', synchronisation's and drive's parts only):\n")
        print("| source | truth (seed) | parameter | the default's runs + sync + drive | "
              "the drive's shift put back | with the warp column | the warp put-back where "
              "the runs show it |")
        print("|---|---|---|---|---|---|---|")
        for gen, seed, ns, c68, c95 in coverage:
            for j, n in enumerate(ns):
                print(f"| {gen} | {seed} | {n} | " + " | ".join(
                    f"{100 * c68[m, j]:.0f} / {100 * c95[m, j]:.0f}" for m in range(4)) + " |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    bs.cached_study_arguments(ap)
    ap.add_argument("--curves", action="store_true")
    ap.add_argument("--ridge", action="store_true")
    ap.add_argument("--t0", action="store_true")
    ap.add_argument("--prediction-excess", action="store_true")
    ap.add_argument("--widths", action="store_true")
    ap.add_argument("--noise-mc", type=int, default=0, metavar="K",
                    help="K fresh campaigns per cached truth (module docstring)")
    ap.add_argument("--put-back", action="store_true",
                    help="--noise-mc: also the drive's shift put back into each run (module "
                         "docstring)")
    ap.add_argument("--mc-source", default="", metavar="SRC",
                    help="--noise-mc: the fresh campaigns from this source at the cached "
                         "fits' truths (default: the cached fits' own)")
    ap.add_argument("--draws-stretch", choices=DRAWS_STRETCH,
                    default=Systematics().draws_stretch,
                    help="--curves: the draws stretched this way (Systematics.draws_stretch)")
    a = ap.parse_args(argv)
    srcs = [s for s in a.sources.split(",") if s]
    t = time.perf_counter()
    (ridge_table if a.ridge else curves_table if a.curves else t0_table if a.t0
     else prediction_excess_table if a.prediction_excess else widths_table if a.widths
     else noise_mc_table if a.noise_mc else rules_table)(srcs, a)
    print(f"\n({time.perf_counter() - t:.0f} s; cache {a.cache})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
