"""Benchmark of the identification stage (issue 4).

    .venv/bin/python benchmarks/bench_fit.py [--quick] [--nist] [--demo] [--starts N]
                                            [--workers W] [--chunk C] [--no-prune]
                                            [--check-prune] [--full-baseline] [--variants]

Default: the multi-start identification of a synthetic mean-signals set (tests/fit/
means_factory.py: the linear model's five signals plus noise, 47 samples in the
[0.97, 1.2] ms window) with N starts (1000; --quick 100) on W Dask workers (2), against the
baseline a user would otherwise write: scipy ``least_squares`` (default trust-region method,
2-point finite-difference Jacobian, the fit's parameter bounds) around a ``solve_ivp`` Radau
simulation of the same linear model (``gprm.simulate.reference.reference_linear``, rtol
1e-6), one start. The
baseline's time is its measured time per simulation times the number of simulations
``least_squares`` needs from that start (counted on the same problem with gprm's exact
residuals -- the count does not depend on which simulator computes them); ``--full-baseline``
runs it for real instead (about 10 minutes). Ratio = baseline x N / gprm N-start time.
--demo fits the demo's campaign instead (synthetic with model mismatch: nonlinear terms, an
unmodelled mode, coloured noise; the paper's 23 parameters plus the 3 alignment offsets),
exactly as ``gprm demo`` does. Peak memory: maximum resident set size of this process and of
the Dask workers (``resource.getrusage``).

--variants: the comparisons behind the multi-start's defaults, on the demo's fit: stopping
rules (window, pruning) over the 1000 starts, plain Algorithm 1 against geodesic acceleration
and the MINPACK damping, chunk sizes, and one chunk in a Dask worker with Dask's default
environment and with ``local_worker_config`` (about 5 minutes).

--nist: the NIST StRD table (digits of the certified values reached, log relative error,
minimum over the parameters) of ``gprm.fit.levenberg_marquardt`` from both official starts,
analytic and finite-difference Jacobian, next to scipy ``least_squares(method="lm")``
(MINPACK, analytic Jacobian, xtol = ftol = gtol = 1e-15).
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np

from _machine import machine

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "fit"))


# ----------------------------------------------------------------------------- NIST

def nist_table() -> str:
    import nist
    from scipy.optimize import least_squares

    from gprm.fit import levenberg_marquardt

    rows = ["| problem | gprm analytic s1 | s2 | gprm FD s1 | s2 | plain Alg. 1 s1 | s2 "
            "| scipy lm s1 | s2 |", "|---|---|---|---|---|---|---|---|---|"]
    worst = worst_plain = 11.0
    iters = {}
    plain_fails, minpack_fails, fallbacks = [], [], []
    t0 = time.process_time()
    for name in nist.names():
        p = nist.load(name)
        cells = []
        for analytic in (True, False):
            for s in (0, 1):
                with np.errstate(all="ignore"):
                    r = levenberg_marquardt(p.residuals, p.starts[s],
                                            p.jacobian if analytic else None)
                d = nist.digits(r.x, p.certified)
                worst = min(worst, d)
                iters[(name, s, analytic)] = r.iterations
                if r.first_run is not None or r.second_run is not None:   # a fallback ran
                    fallbacks.append(f"{name} s{s + 1} {'analytic' if analytic else 'FD'} "
                                     f"({r.iterations} iterations)")
                cells.append(f"**{d:.1f}**" if d < 4 else f"{d:.1f}")
        for s in (0, 1):           # plain Algorithm 1, as the multi-start fit runs it
            with np.errstate(all="ignore"):
                r = levenberg_marquardt(p.residuals, p.starts[s], p.jacobian,
                                        control="algorithm1", damping="current",
                                        geodesic=False, fallback=False, ftol=1e-12,
                                        gtol=0.0, max_iter=1000, max_nfev=10 ** 9)
            d = nist.digits(r.x, p.certified)
            if d < 4:
                plain_fails.append(f"{name} s{s + 1}")
            else:
                worst_plain = min(worst_plain, d)
            cells.append(f"**{d:.1f}**" if d < 4 else f"{d:.1f}")
        for s in (0, 1):
            with np.errstate(all="ignore"):
                sp = least_squares(p.residuals, p.starts[s], jac=p.jacobian, method="lm",
                                   xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=100000)
            d = nist.digits(sp.x, p.certified)
            if d < 4:
                minpack_fails.append(f"{name} s{s + 1}")
            cells.append(f"**{d:.1f}**" if d < 4 else f"{d:.1f}")
        rows.append(f"| {name} | " + " | ".join(cells) + " |")
    out = "\n".join(rows)
    n = len(nist.names())
    out += ("\n\nDigits = -log10(max relative error over the parameters), capped at 11; bold: "
            "fewer than 4 (the bar). gprm: `levenberg_marquardt` defaults (trust-region "
            "control with MINPACK's scale, initial bound 1 |D x0|, ftol = xtol = gtol = 1e-10, "
            "max_nfev = 1000 (P + 1), central differences for FD; no fallback). Plain "
            "Algorithm 1: `control='algorithm1', damping='current', geodesic=False, "
            "ftol=1e-12, max_iter=1000`, analytic Jacobian, as `levenberg_marquardt_batch` runs the "
            "multi-start fit. The 8 higher-difficulty problems (MGH09, Thurber, BoxBOD, Rat42, "
            "MGH10, Eckerle4, Rat43, Bennett5) are read from tests/fit/nist_strd_extra.")
    out += (f"\n\n{n} problems. Smallest number of digits over the {4 * n} runs with the "
            f"defaults: {worst:.1f}; MGH17 start 1 in {iters[('MGH17', 0, True)]} (analytic) "
            f"and {iters[('MGH17', 0, False)]} (FD) iterations. Runs that needed the fallback: "
            f"{', '.join(fallbacks) or 'none'}. Plain Algorithm 1 below 4 digits: "
            f"{', '.join(plain_fails) or 'none'}; smallest {worst_plain:.1f} over its "
            f"{2 * n - len(plain_fails)} other runs. MINPACK below 4 digits: "
            f"{', '.join(minpack_fails) or 'none'}. CPU for the whole table: "
            f"{time.process_time() - t0:.1f} s.")
    return out


# ----------------------------------------------------------------------------- speed

def baseline(data, base, *, full: bool) -> dict:
    """One start of scipy least_squares around solve_ivp (Radau)."""
    from scipy.optimize import least_squares

    from gprm.fit.objective import Objective
    from gprm.simulate.reference import reference_linear

    obj = Objective.create(data, base)
    names = obj.names
    x0 = base.initial_vector(names)
    w = 1.0 / data.sigma

    def radau_residuals(xn):
        ps = base.with_values(**dict(zip(names, map(float, xn * obj.scale))))
        y = reference_linear(ps, data.time, rtol=1e-6, atol_scale=1e-8)
        return ((data.values - y) * w).ravel()

    x0n = x0 / obj.scale
    bounds = obj.bounds_normalised()         # the same box as gprm's fit
    t = time.perf_counter()
    for _ in range(3):
        radau_residuals(x0n)
    per_eval = (time.perf_counter() - t) / 3
    if full:
        t = time.perf_counter()
        sp = least_squares(radau_residuals, x0n, jac="2-point", bounds=bounds)
        return {"time": time.perf_counter() - t, "nfev_total": None, "per_eval": per_eval,
                "chi2": float(np.sum(sp.fun ** 2)), "measured": True}
    count = {"n": 0}

    def fast(xn):
        count["n"] += 1
        return obj.residuals(xn[None])[0]

    sp = least_squares(fast, x0n, jac="2-point", bounds=bounds)
    n_sim = count["n"]
    # the same start without the bounds, to show why the baseline gets them
    free = least_squares(fast, x0n, jac="2-point")
    lo, hi = bounds
    out = [f"{n} = {v * sc:.3g}" for n, v, a, b, sc in zip(obj.names, free.x, lo, hi, obj.scale)
           if not a < v < b]
    return {"time": per_eval * n_sim, "nfev_total": n_sim, "per_eval": per_eval,
            "chi2": float(np.sum(sp.fun ** 2)), "measured": False,
            "unbounded": f"{float(np.sum(free.fun ** 2)):.1f}"
                         + (f" with {', '.join(out)} outside the bounds" if out else "")}


def _cpu() -> float:
    """CPU seconds of this process plus its finished children (the Dask workers)."""
    a = resource.getrusage(resource.RUSAGE_SELF)
    b = resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def demo_fit_input():
    """The demo's fit: its synthetic campaign (seed 0: nonlinear terms, an unmodelled mode,
    coloured noise, run-to-run variability), preprocessed as the demo does, and the paper's
    fitted set plus the three alignment offsets (26 parameters)."""
    from gprm.campaign.api import PreprocessOptions, run_preprocess
    from gprm.campaign.synth import synth_campaign
    from gprm.fit.api import FitOptions
    from gprm.fit.objective import fit_data_from_means
    from gprm.params import paper

    means = run_preprocess(synth_campaign(seed=0), PreprocessOptions())
    base = FitOptions().parameters(paper())
    return fit_data_from_means(means, source="demo campaign (synthetic, seed 0)"), base


def speed(n_starts: int, workers: int, chunk: int | None, prune: bool, full_baseline: bool,
          check_prune: bool = False, means: str | None = None, demo: bool = False) -> str:
    from means_factory import make_means

    from gprm.fit.identify import identify
    from gprm.fit.objective import fit_data_from_means
    from gprm.fit.starts import MultiStartOptions
    from gprm.params import paper

    p = paper()
    chunk = chunk or MultiStartOptions().chunk_size
    if demo:
        data, p = demo_fit_input()
    elif means:
        from gprm._io import open_netcdf

        data = fit_data_from_means(open_netcdf(means), source=str(means))
    else:
        rng = np.random.default_rng([1, 99])
        truth = p.with_vector(p.vector() * (1 + 0.05 * rng.uniform(-1, 1, len(p.fitted))))
        data = fit_data_from_means(make_means(truth, seed=1), source="synthetic")
    opts = MultiStartOptions(n_starts=n_starts, seed=0, chunk_size=chunk,
                             prune_after=10 if prune else 0)
    if check_prune:
        other = MultiStartOptions(n_starts=n_starts, seed=0, chunk_size=chunk, prune_after=0)
        t = time.perf_counter()
        res0 = identify(data, p, other, workers=workers, band_samples=200)
        t0 = time.perf_counter() - t
    cpu0 = _cpu()
    load0 = os.getloadavg()[0]
    t = time.perf_counter()
    res = identify(data, p, opts, workers=workers, band_samples=200)
    t_fit = time.perf_counter() - t
    cpu_fit = _cpu() - cpu0
    load1 = os.getloadavg()[0]
    rss_self = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    rss_children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    b = baseline(data, p, full=full_baseline)
    ratio = b["time"] * n_starts / t_fit
    st = res.starts
    lines = [
        f"- data: {data.source} ({data.n_obs} observations, sigma = {data.sigma_kind})",
        f"- gprm: {n_starts} starts, {workers} Dask worker(s) (0 = in process), chunks of "
        f"{chunk}, pruning {'on (after 10 iterations: factor 100 and rate rule)' if prune else 'off'}: "
        f"**{t_fit:.1f} s** wall (multi-start {res.timings['multistart']:.1f} s, covariance + "
        f"bands {res.timings['uncertainty']:.1f} s with {res.bands.n_samples} physical "
        f"covariance samples; includes starting the Dask cluster); CPU time of this "
        f"process and the workers {cpu_fit:.1f} s; load average (1 min) before/after "
        f"{load0:.1f}/{load1:.1f} on {os.cpu_count()} cores",
        f"- best chi2 {res.chi2:.4f} (dof {res.dof}), starts within dchi2 <= 1 of the best: "
        f"{st.n_at_best()}, converged {int(st.converged.sum())}, median iterations "
        f"{np.median(st.iterations):.0f}; outcomes "
        + ", ".join(f"{k} {v}" for k, v in zip(*np.unique(st.status, return_counts=True))),
        f"- baseline (scipy least_squares, 2-point Jacobian, bounds, solve_ivp Radau rtol 1e-6): "
        f"{b['per_eval']:.2f} s per simulation" + (
            f", {b['nfev_total']} simulations for one start -> {b['time']:.0f} s per start"
            if not b["measured"] else f", measured {b['time']:.0f} s for one start")
        + f" (final chi2 {b['chi2']:.1f}"
        + (f"; without the bounds {b['unbounded']}" if "unbounded" in b else "") + ")",
        f"- ratio (baseline x {n_starts}) / gprm = **{ratio:.0f}**",
    ]
    if check_prune:
        same = np.array_equal(res0.x, res.x)
        i0, i1 = res0.starts.best_index, res.starts.best_index
        lines.append(
            f"- pruning check: without pruning {t0:.1f} s, best chi2 {res0.chi2:.6f} (start "
            f"{i0}, {res0.starts.n_at_best()} within dchi2 <= 1); with pruning best chi2 "
            f"{res.chi2:.6f} (start {i1}); best fit bit-identical: {same}; largest "
            f"|difference| / stderr of the best-fit parameters "
            f"{np.nanmax(np.abs(res0.x - res.x) / res.stderr):.2g}")
    lines += [
        f"- peak memory (max RSS): this process {rss_self:.0f} MiB, largest child "
        f"(Dask worker) {rss_children:.0f} MiB",
    ]
    return "\n".join(lines)


# ----------------------------------------------------------------------------- variants

def variants(workers: int) -> str:
    """The comparisons behind the defaults of the multi-start (docs/fitting.md), on the demo's
    fit: stopping rules over all 1000 starts, optimizer variants and chunk sizes on the first
    250 starts in this process, and one chunk in a Dask worker with and without
    ``local_worker_config``."""
    from dataclasses import replace

    from gprm.fit.engine import ChunkTask, local_worker_config, run_chunk, run_multistart
    from gprm.fit.starts import LMOptions, MultiStartOptions, draw_starts
    from gprm.fit.objective import Objective

    data, base = demo_fit_input()
    obj = Objective.create(data, base)
    out = []

    def summary(st, wall, cpu):
        c = np.where(np.isfinite(st.chi2), st.chi2, np.inf)
        return (f"{wall:.1f} | {cpu:.1f} | {np.median(st.iterations):.0f} | "
                f"{c.min():.4f} (start {int(np.argmin(c))}) | {st.n_at_best()}")

    out += ["### Stopping rules (1000 starts, %d workers)\n" % workers,
            "| variant | wall s | CPU s | median iterations | best chi2 before the polish "
            "| starts within dchi2 <= 1 |", "|---|---|---|---|---|---|"]
    d = MultiStartOptions()
    for name, o in [
            (f"default: window {d.lm.stall_window} / {d.lm.stall_tol:g}, pruning", d),
            ("window 5 / 0.05, pruning (stops 1-54)",
             replace(d, lm=LMOptions(stall_window=5, stall_tol=0.05))),
            ("window 10 / 0.1, pruning", replace(d, lm=LMOptions(stall_window=10,
                                                                   stall_tol=0.1))),
            ("no window, pruning", replace(d, lm=LMOptions(stall_window=0))),
            ("no window, no pruning (the paper's statistic)",
             replace(d, lm=LMOptions(stall_window=0), prune_after=0))]:
        c0, t0 = _cpu(), time.perf_counter()
        st = run_multistart(obj, o, workers=workers)
        out.append(f"| {name} | {summary(st, time.perf_counter() - t0, _cpu() - c0)} |")

    X = draw_starts(obj.to_normalised(base.initial_vector(obj.names)), d)
    ids = np.arange(250)

    def chunk(o, rows=ids, index=0):
        c0 = time.process_time()
        res = run_chunk(ChunkTask(index, rows, X[rows], obj, o))
        return res, time.process_time() - c0

    out += ["\n### Optimizer variants (the first 250 starts, one chunk, in this process)\n",
            "| variant | CPU s | median iterations | starts within dchi2 <= 1 of the chunk's best |",
            "|---|---|---|---|"]
    for name, lm in [("plain Algorithm 1 (default)", LMOptions()),
                     ("geodesic acceleration", LMOptions(geodesic=True)),
                     ("MINPACK damping (max)", LMOptions(damping="max"))]:
        res, cpu = chunk(replace(d, lm=lm))
        c = res["chi2"][np.isfinite(res["chi2"])]
        out.append(f"| {name} | {cpu:.1f} | {np.median(res['iterations']):.0f} | "
                   f"{int(np.sum(c <= c.min() + 1))} |")

    out += ["\n### Chunk size (the first 250 starts in this process)\n",
            "| chunk | CPU s per 100 starts |", "|---|---|"]
    for size in (25, 50, 100, 250):
        o = replace(d, chunk_size=size)
        cpu = sum(chunk(o, ids[i:i + size], i // size)[1] for i in range(0, 250, size))
        out.append(f"| {size} | {cpu / 2.5:.2f} |")

    import dask
    from distributed import Client, LocalCluster

    def in_worker(warm, task):
        run_chunk(warm)                     # first calls: imports, caches
        t0 = time.process_time()
        run_chunk(task)
        return time.process_time() - t0

    out += ["\n### One chunk of 250 starts: in this process and in a (warmed-up) Dask "
            "worker\n",
            "| where | CPU s |", "|---|---|", f"| this process | {chunk(d)[1]:.1f} |"]
    for name, cfg in [("Dask worker, Dask's default environment", {}),
                      ("Dask worker, local_worker_config (as gprm fit)",
                       local_worker_config())]:
        with dask.config.set(cfg):
            cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                   dashboard_address=":0", silence_logs=40)
        with Client(cluster) as client:
            cpu = client.submit(in_worker, ChunkTask(1, ids[:10], X[:10], obj, d),
                                ChunkTask(0, ids, X[ids], obj, d), pure=False).result()
        cluster.close()
        out.append(f"| {name} | {cpu:.1f} |")
    return "\n".join(out)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="100 starts instead of 1000")
    ap.add_argument("--nist", action="store_true", help="print the NIST StRD table only")
    ap.add_argument("--starts", type=int, default=None)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--chunk", type=int, default=None, help="starts per chunk (default: "
                    "gprm's, 250)")
    ap.add_argument("--no-prune", action="store_true", help="disable early stopping of far "
                    "starts (on by default, as in gprm fit)")
    ap.add_argument("--check-prune", action="store_true", help="also run without pruning "
                    "and compare the best fits")
    ap.add_argument("--full-baseline", action="store_true")
    ap.add_argument("--variants", action="store_true", help="the comparisons behind the "
                    "multi-start defaults on the demo's fit (about 5 minutes)")
    ap.add_argument("--demo", action="store_true", help="fit the demo's campaign (model "
                    "mismatch, 26 parameters) instead of the matched synthetic signals")
    ap.add_argument("--means", default=None, help="mean-signals NetCDF to fit instead of the "
                    "synthetic one (e.g. from gprm synth campaign + gprm preprocess)")
    ap.add_argument("--uncertainty", default=None, help="comma-separated uncertainty methods "
                    "to time with the starts on the demo's campaign, next to the Eq. 7-only "
                    "fit (e.g. laplace-prior,generator-bootstrap)")
    a = ap.parse_args(argv)
    cmd = "benchmarks/bench_fit.py " + " ".join(sys.argv[1:] if argv is None else argv)
    print("## Identification (gprm fit)\n")
    print(machine("scipy"))
    print(f"- command: `.venv/bin/python {cmd.strip()}`\n")
    if a.nist:
        print("### NIST StRD\n")
        print(nist_table())
        return
    if a.variants:
        print("### Variants on the demo's fit\n")
        print(variants(a.workers))
        return
    n = a.starts or (100 if a.quick else 1000)
    if a.uncertainty:
        print("### Starts plus uncertainty\n")
        print(uncertainty_speed(n, a.workers, tuple(a.uncertainty.split(","))))
        return
    print("### Multi-start speed\n")
    print(speed(n, a.workers, a.chunk, not a.no_prune, a.full_baseline, a.check_prune,
                a.means, a.demo))



# ----------------------------------------------------------------------------- uncertainty

def uncertainty_speed(n_starts: int, workers: int, methods: tuple[str, ...]) -> str:
    """1000 starts plus each uncertainty method on the demo's campaign (seed 0, the CLI's
    defaults: alignment offsets fitted, align time 1.01 ms), side by side with the paper's
    Eq. 7-only fit (no prior), in one run (issue 12's speed target: <= 60 s on 2 cores)."""
    from gprm.campaign.preprocess import PreprocessConfig, preprocess
    from gprm.campaign.synth import synth_campaign
    from gprm.fit.identify import identify
    from gprm.fit.objective import fit_data_from_means
    from gprm.fit.starts import MultiStartOptions
    from gprm.params import ALIGNMENT_OFFSETS, paper

    means = preprocess(synth_campaign(seed=0), PreprocessConfig(align_time=1.01e-3)).to_dataset()
    data = fit_data_from_means(means, source="demo campaign (synthetic, seed 0)")
    base = paper()
    base = base.with_fitted(tuple(base.fitted) + tuple(ALIGNMENT_OFFSETS.values()))
    opts = MultiStartOptions(n_starts=n_starts, seed=0)
    lines = ["| fit | uncertainty | wall s | of which multi-start s | uncertainty + bands s | "
             "identified (of 26) |", "|---|---|---|---|---|---|"]
    runs = [("paper (no prior)", "eq7", None)] + [("prior", m, 1.25) for m in methods]
    for label, method, width in runs:
        t = time.perf_counter()
        res = identify(data, base, opts, workers=workers, band_samples=200,
                       uncertainty=method, prior_width=width)
        wall = time.perf_counter() - t
        lines.append(f"| {label} | {method} | **{wall:.1f}** | {res.timings['multistart']:.1f} "
                     f"| {res.timings['uncertainty']:.1f} | {len(res.identified)} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
