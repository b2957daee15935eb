"""Coverage of the identification's uncertainty methods over synthetic campaigns (issue 12).

For each campaign: a truth drawn within +-10 % of Table 3 (the 21 physical parameters, as
the project's CLI chain check draws them), a synthetic campaign with every mismatch ingredient of
`gprm synth campaign` on, preprocessing and fit with the CLI's defaults, and then for each
method the fraction of 95 % and 68 % intervals that contain the truth:

- parameters: the 21 physical parameters of Table 3 (all, and those the method reports as
  identified);
- predictions: the overshoot (largest |displacement| over 0.95-1.2 ms) of the four points
  (CoM, M_xz, M_yz, tip edge) on three axes in the three scenarios of Sec. 4.2, for the
  point-axes that move (truth overshoot above 1 % of the scenario's largest); the bins of the
  kinetic-energy histogram (Fig. 8), by the randomised PIT (a bin can be empty, an atom the
  percentile band handles badly: ``energy_cover``); the velocity-vs-impact-time curves of
  the six axes (Fig. 11, nominal geometry) at 21 times over t_c .. t_c + 0.2 ms.

Methods: ``eq7`` and ``eq7-corr`` on the paper's unregularised fit; ``laplace-prior``,
``generator-bootstrap``, ``bootstrap-runs`` and ``mcmc`` on the prior-regularised fit
(gprm.fit.uncertainty, gprm.fit.bootstrap).

    .venv/bin/python benchmarks/bench_coverage.py [--campaigns 20] [--starts 200] [--seed 1000] [--boot 30]
                                                  [--workers W | --scheduler ADDRESS]

--workers W runs the campaigns as Dask tasks on a local cluster of W single-threaded
processes, --scheduler ADDRESS on an existing Dask cluster (issue 24; benchmarks/_studies.py,
recipe for an institute cluster in docs/fitting.md); the numbers do not depend on either.

Prints the table docs/fitting.md quotes and, for the default method, each column's Monte
Carlo 95 % interval (campaigns resampled); --json F also writes every campaign's numbers,
and --from-json F [F ...] prints the tables of earlier runs, pooled, without running.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from dataclasses import dataclass

import numpy as np
import xarray as xr

from gprm.campaign.preprocess import PreprocessConfig, preprocess
from gprm.campaign.synth import synth_campaign
from gprm.fit.api import FitOptions
from gprm.fit.bootstrap import bootstrap_uncertainty
from gprm.fit.files import FittedModel
from gprm.fit.identify import identify
from gprm.fit.result import FitResult
from gprm.fit.objective import fit_data_from_means
from gprm.fit.starts import MultiStartOptions
from gprm.fit.uncertainty import from_mcmc
from gprm.params import FITTED_DEFAULT, LAG_PARAMETERS, ParameterSet, batch, paper
from gprm.predict.scenarios import Scenario, apply_scenario, standard_scenarios
from gprm.predict.trajectories import TRAJECTORY_POINTS, default_times, sampled_points
from gprm.predict.whatif import transform_batch

#: the 21 physical parameters of Table 3 (its 23 less the lags t0, t1), in Table 3's order
PHYSICAL = tuple(n for n in FITTED_DEFAULT if n not in LAG_PARAMETERS)


def draw_truth(seed: int, spread: float = 0.1):
    """Table 3 with each of the 21 physical parameters times U(1 - spread, 1 + spread)."""
    rng = np.random.default_rng([seed, 77])
    base = paper()
    return base.with_values(**{n: base[n] * rng.uniform(1.0 - spread, 1.0 + spread)
                               for n in PHYSICAL})


@dataclass(frozen=True)
class SyntheticFit:
    """One campaign of the coverage studies: its truth (and the truth in the fit's time base,
    t0 plus the preprocessing's shift of x_base), the campaign, its mean signals, and the fit
    with the CLI's defaults (preprocessing, fitted set with the alignment offsets, prior) and
    the Laplace posterior, on which the bootstrap methods build."""

    truth: ParameterSet
    truth_t: ParameterSet
    campaign: xr.Dataset
    means: xr.Dataset
    fit: FitResult


def synthetic_fit(seed: int, starts: int) -> SyntheticFit:
    truth = draw_truth(seed)
    camp = synth_campaign(truth, seed=seed)
    means = preprocess(camp, PreprocessConfig()).to_dataset()
    fit = identify(fit_data_from_means(means), fit_parameters(),
                   MultiStartOptions(n_starts=starts, seed=seed), band_samples=0,
                   uncertainty="laplace-prior")
    shift = float(means["truth_shift"].sel(signal="x_base"))
    return SyntheticFit(truth, truth.with_values(t0=truth["t0"] + shift), camp, means, fit)


def fit_parameters() -> ParameterSet:
    """The parameter set the CLI fits by default: Table 3's and the alignment offsets."""
    return FitOptions().parameters(paper())


def overshoots(pb: dict, sc: Scenario, times) -> tuple[np.ndarray, np.ndarray]:
    """(B, point*axis) largest |displacement| and ok (B,)."""
    pos, _, ok = sampled_points(transform_batch(pb, sc), times, TRAJECTORY_POINTS,
                                piezo=sc.piezo)
    return np.max(np.abs(pos), axis=-1).reshape(pos.shape[0], -1), ok


def prediction_cover(fm: FittedModel, truth, times, n: int, seed: int) -> dict:
    """Per standard scenario and moving point-axis, whether the truth's largest |displacement|
    over ``times`` lies inside the draws' 95 % / 68 % percentile bands. ``truth`` must have
    its t0 in the fit's time axis (the window is fixed, so a lag moves the maxima)."""
    res = {"in95": 0, "in68": 0, "n": 0}
    for sc in standard_scenarios():
        t_os, _ = overshoots(batch([truth]), sc, times)
        t_os = t_os[0]
        moving = t_os > 0.01 * t_os.max()
        m = apply_scenario(fm, sc)
        os_, ok = overshoots(m.sample(n, seed), sc, times)
        os_ = os_[ok]
        lo95, hi95 = np.percentile(os_, [2.5, 97.5], axis=0)
        lo68, hi68 = np.percentile(os_, [16, 84], axis=0)
        res["in95"] += int(np.sum(moving & (lo95 <= t_os) & (t_os <= hi95)))
        res["in68"] += int(np.sum(moving & (lo68 <= t_os) & (t_os <= hi68)))
        res["n"] += int(moving.sum())
    return res


def pit_cover(draws: np.ndarray, value: np.ndarray, rng: np.random.Generator,
              levels=(0.95, 0.68)) -> dict:
    """Coverage by the randomised probability integral transform: for each column, the PIT
    F(v-) + U (F(v) - F(v-)) of ``value`` (K,) under the empirical distribution of ``draws``
    (B, K), U uniform; covered at level L where the PIT lies in [(1 - L) / 2, (1 + L) / 2].
    Exact for distributions with atoms (a histogram bin is empty with positive probability),
    where counting a closed band [q_lo, q_hi] is not: it over- or under-covers, depending on
    how often the bin is empty (tests/test_benchmark_metrics.py)."""
    below = np.mean(draws < value[None], axis=0)
    at = np.mean(draws <= value[None], axis=0) - below
    pit = below + rng.uniform(size=value.shape) * at
    return {f"in{round(100 * L)}": int(np.sum((pit >= (1 - L) / 2) & (pit <= (1 + L) / 2)))
            for L in levels}


def energy_cover(fm: FittedModel, truth, n: int, seed: int, n_points: int = 6001) -> dict:
    """Per-bin coverage of the kinetic-energy histogram (time per energy bin of the total
    kinetic energy over the energy window, Fig. 8) of the truth by the draws.

    ``in95``/``in68``/``n``: the randomised PIT (:func:`pit_cover`) over the bins the truth or
    any draw occupies. A bin's occupancy is zero with positive probability (the energy may
    never reach it), and the earlier count (``band95``/``band68``/``band_n``: the truth inside
    the closed percentile band, over the bins the truth occupies) selects bins by the truth's
    own value: for such atoms it is off nominal, most at 68 % (docs/fitting.md)."""
    from gprm.predict.energy import DEFAULT_WINDOW as ENERGY_WINDOW
    from gprm.predict.energy import histogram, window_weights
    from gprm.simulate.kinematics import body_motion, kinetic_energy

    # 0.05 us steps by default: the histogram of the continuous-time energy. Coarser grids
    # alias the fastest modes into lumpy bin occupancies that the bands cover too easily
    # (benchmarks/bench_bootstrap_rules.py --energy-points compares grids)
    t = np.linspace(0.95e-3, 1.25e-3, n_points)
    w = window_weights(t, ENERGY_WINDOW)
    e_t = kinetic_energy(body_motion(batch([truth]), t, piezo=2))["total"]
    m = body_motion(fm.sample(n, seed), t, piezo=2)
    e_d = kinetic_energy(m)["total"][m.ok]
    edges = np.linspace(0.0, 1.05 * max(e_t.max(), np.percentile(e_d.max(axis=1), 50)), 11)
    h_t = histogram(e_t, w, edges)[0]
    h_d = histogram(e_d, w, edges)
    used = h_t > 0
    lo95, hi95 = np.percentile(h_d, [2.5, 97.5], axis=0)
    lo68, hi68 = np.percentile(h_d, [16, 84], axis=0)
    scored = used | np.any(h_d > 0, axis=0)
    pit = pit_cover(h_d[:, scored], h_t[scored], np.random.default_rng([seed, 21]))
    return {**pit, "n": int(scored.sum()),
            "band95": int(np.sum(used & (lo95 <= h_t) & (h_t <= hi95))),
            "band68": int(np.sum(used & (lo68 <= h_t) & (h_t <= hi68))),
            "band_n": int(used.sum())}


def curve_times(truth) -> np.ndarray:
    """The 21 impact times the velocity curves are scored at: t_c .. t_c + 0.2 ms of the
    truth (in the fit's aligned axis)."""
    return truth["t_c"] + np.linspace(0.0, 0.2e-3, 21)


def curve_cover(fm: FittedModel, truth, n: int, seed: int) -> dict:
    """Coverage of the truth's velocity-vs-impact-time curves (the post-impact test-mass
    velocity on the six axes if the impact happened at t, nominal geometry, Fig. 11) by the
    draws' bands, at 21 times over t_c .. t_c + 0.2 ms where the truth's curve exists;
    ``axis_offset``: per axis, the truth's distance from the band's median in 68 % half-widths
    (median over the times)."""
    from gprm.flight.predicted import tm_velocity_vs_time
    from gprm.flight.telemetry import AXES
    from gprm.simulate.kinematics import body_motion

    t = curve_times(truth)
    v_t = tm_velocity_vs_time(body_motion(batch([truth]), t, piezo=2))
    m = body_motion(fm.sample(n, seed), t, piezo=2)
    v_d = tm_velocity_vs_time(m)
    res = {"in95": 0, "in68": 0, "n": 0, "axis_offset": {}}
    for a in AXES:
        vt = v_t[a][0]
        vd = v_d[a][m.ok]
        ok = np.isfinite(vt) & (np.mean(np.isfinite(vd), axis=0) > 0.5)
        if not ok.any():
            continue
        q = np.nanpercentile(vd[:, ok], [2.5, 97.5, 16, 84, 50], axis=0)
        x = vt[ok]
        res["in95"] += int(np.sum((q[0] <= x) & (x <= q[1])))
        res["in68"] += int(np.sum((q[2] <= x) & (x <= q[3])))
        res["n"] += int(ok.sum())
        # the truth's distance from the band's median in 68 % half-widths, median over time
        with np.errstate(divide="ignore", invalid="ignore"):
            res["axis_offset"][a] = float(np.nanmedian(np.abs(x - q[4]) / (0.5 * (q[3] - q[2]))))
    return res


def one_campaign(seed: int, starts: int, samples: int, n_boot: int, methods) -> dict:
    times = default_times()
    out: dict = {"seed": seed, "methods": {}}
    t = time.perf_counter()
    # the truth in the fit's time base (truth_t): preprocessing moved x_base's time by
    # truth_shift, so a fit's lag t0 is the truth's plus that shift (time-resolved
    # predictions compare there)
    sf = synthetic_fit(seed, starts)
    truth, truth_t, camp, prior_fit = sf.truth, sf.truth_t, sf.campaign, sf.fit
    paper_fit = identify(prior_fit.data, fit_parameters(),
                         MultiStartOptions(n_starts=starts, seed=seed), band_samples=0,
                         uncertainty="eq7-corr", prior_width=None)
    out["fit_s"] = round(time.perf_counter() - t, 2)
    cands = [("eq7", paper_fit, paper_fit.eq7), ("eq7-corr", paper_fit, paper_fit.uncertainty),
             ("laplace-prior", prior_fit, prior_fit.uncertainty)]
    # "uncalibrated": the default method with the mismatch calibration off (the same refits)
    for method in ("generator-bootstrap", "bootstrap-runs", "uncalibrated"):
        if method in methods:
            t = time.perf_counter()
            u = bootstrap_uncertainty(prior_fit.objective(), prior_fit.x, prior_fit.uncertainty,
                                      prior_fit.prior, method.replace(
                                          "uncalibrated", "generator-bootstrap"),
                                      n_boot=n_boot, seed=seed, campaign=camp,
                                      **({"calibration": None} if method == "uncalibrated"
                                         else {}))
            out[f"{method}_s"] = round(time.perf_counter() - t, 2)
            cands.append((method, prior_fit, u))
    if "mcmc" in methods:
        t = time.perf_counter()
        u = from_mcmc(prior_fit.objective(), prior_fit.x, prior_fit.uncertainty, prior_fit.prior,
                      seed=seed)
        out["mcmc_s"] = round(time.perf_counter() - t, 2)
        cands.append(("mcmc", prior_fit, u))
    for method, res, u in cands:
        if method not in methods:
            continue
        rows = {}
        for n in PHYSICAL:
            k = res.names.index(n)
            tv = truth[n]
            rows[n] = {"in95": bool(u.lower95[k] <= tv <= u.upper95[k]),
                       "in68": bool(u.lower68[k] <= tv <= u.upper68[k]),
                       "identified": bool(u.identified[k])}
        fm = FittedModel(res.params, u.covariance, piezo=2, draws=u.draws,
                         uncertainty=method)
        none = {"in95": 0, "in68": 0, "n": 0, "undefined": True}
        ok = fm.has_uncertainty
        out["methods"][method] = {
            "params": rows, "message": u.message,
            "pred": prediction_cover(fm, truth_t, times, samples, seed) if ok else none,
            "energy": energy_cover(fm, truth_t, samples, seed) if ok else none,
            "curves": curve_cover(fm, truth_t, samples, seed) if ok else none}
    return out


def table(results: list[dict]) -> str:
    lines = ["| method | params 95 % (all 21) | params 68 % | identified / campaign | "
             "identified 95 % | identified 68 % | overshoots 95 % | overshoots 68 % | "
             "KE histogram 95 % | KE histogram 68 % | velocity curves 95 % | "
             "velocity curves 68 % | undefined |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    cols = ("all 95", "all 68", None, "identified 95", "identified 68", "overshoots 95",
            "overshoots 68", "KE 95", "KE 68", "curves 95", "curves 68")

    def f(a, b):
        return f"{a / b:.1%} ({a}/{b})" if b else "-"
    for m in results[0]["methods"]:
        tot = {k: c.sum(axis=0).astype(int) for k, c in campaign_counts(results, m).items()}
        undef = sum(not r["methods"][m]["message"].startswith("ok") for r in results)
        cells = [f"{tot['identified 95'][1] / len(results):.1f}" if k is None
                 else f(*tot[k]) for k in cols]
        lines.append(f"| {m} | " + " | ".join(cells) + f" | {undef}/{len(results)} |")
    return "\n".join(lines)


def campaign_counts(results: list[dict], method: str) -> dict[str, np.ndarray]:
    """Per campaign (C, 2) hits and trials of each column of the table, for ``method``."""
    cols: dict[str, list] = {k: [] for k in ("identified 95", "identified 68", "all 95",
                                             "all 68", "overshoots 95", "overshoots 68",
                                             "KE 95", "KE 68", "curves 95", "curves 68")}
    for r in results:
        mm = r["methods"][method]
        rows = list(mm["params"].values())
        idn = [row for row in rows if row["identified"]]
        for lvl in ("95", "68"):
            cols[f"identified {lvl}"].append((sum(row[f"in{lvl}"] for row in idn), len(idn)))
            cols[f"all {lvl}"].append((sum(row[f"in{lvl}"] for row in rows), len(rows)))
            for key, name in (("pred", "overshoots"), ("energy", "KE"), ("curves", "curves")):
                q = mm.get(key) or {}
                cols[f"{name} {lvl}"].append((q.get(f"in{lvl}", 0), q.get("n", 0)))
            q = mm.get("energy") or {}      # (0, 0) in files made before the band was kept
            cols.setdefault(f"KE, closed band over the truth's bins {lvl}", []).append(
                (q.get(f"band{lvl}", 0), q.get("band_n", 0)))
    return {k: np.array(v, float) for k, v in cols.items()}


def coverage_intervals(results: list[dict], method: str, n_resamples: int = 4000,
                       seed: int = 0) -> str:
    """The coverage's own Monte Carlo uncertainty: 95 % percentile intervals over the
    campaigns resampled with replacement (a campaign's parameters and bins are correlated,
    so the campaign, not the bin, is the independent unit)."""
    rng = np.random.default_rng(seed)
    counts = campaign_counts(results, method)
    idx = rng.integers(0, len(results), (n_resamples, len(results)))
    lines = [f"Coverage of `{method}` with its Monte Carlo 95 % interval (campaigns "
             f"resampled {n_resamples} times):", "",
             "| column | coverage | 95 % interval |", "|---|---|---|"]
    for k, c in counts.items():
        if c[:, 1].sum() == 0:
            continue
        ratio = c[idx, 0].sum(axis=1) / np.maximum(c[idx, 1].sum(axis=1), 1)
        lo, hi = np.percentile(ratio, [2.5, 97.5])
        lines.append(f"| {k} | {c[:, 0].sum() / c[:, 1].sum():.1%} | {lo:.1%} - {hi:.1%} |")
    return "\n".join(lines)


def tables(results: list[dict]) -> str:
    """The method table and, for the default method, its Monte Carlo intervals."""
    out = table(results)
    if "generator-bootstrap" in results[0]["methods"]:
        out += "\n\n" + coverage_intervals(results, "generator-bootstrap")
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--campaigns", type=int, default=20)
    ap.add_argument("--starts", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--samples", type=int, default=200, help="parameter sets per prediction")
    ap.add_argument("--json", help="write every campaign's numbers here")
    ap.add_argument("--boot", type=int, default=30, help="refits per bootstrap")
    ap.add_argument("--from-json", nargs="+", help="print the tables of earlier --json "
                    "files (pooled) instead of running")
    ap.add_argument("--workers", type=int, default=0,
                    help="campaigns as Dask tasks on a local cluster of this many processes")
    ap.add_argument("--scheduler", default=None,
                    help="campaigns as Dask tasks on the cluster of this scheduler address")
    ap.add_argument("--methods", default="eq7,eq7-corr,laplace-prior,generator-bootstrap,"
                    "bootstrap-runs,mcmc", help="comma-separated methods (also "
                    "'uncalibrated': the default without the mismatch calibration)")
    a = ap.parse_args(argv)
    sys.path.insert(0, "benchmarks")
    from _machine import machine
    from _studies import map_seeds

    if a.from_json:
        results = []
        for f in a.from_json:
            with open(f) as fh:
                results += json.load(fh)
        print(f"{len(results)} campaigns from {', '.join(a.from_json)}")
        print(tables(results))
        return
    t0 = time.perf_counter()
    results = map_seeds(one_campaign, range(a.seed, a.seed + a.campaigns),
                        scheduler=a.scheduler, workers=a.workers, starts=a.starts,
                        samples=a.samples, n_boot=a.boot, methods=a.methods.split(","))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(results, fh, indent=1)
    where = (f"scheduler {a.scheduler}" if a.scheduler else
             f"{a.workers} Dask workers" if a.workers > 0 else "in process")
    print(f"{a.campaigns} campaigns, {a.starts} starts, seeds {a.seed}..{a.seed + a.campaigns - 1}"
          f" ({time.perf_counter() - t0:.0f} s, {where}; {machine()})")
    print(tables(results))


if __name__ == "__main__":
    main()
