"""Benchmark of the fit's speed targets (issue 24, item 2): a 10-start fit <= 1.5 s and 1000
starts <= 5 s wall on 2 cores, on the demo's campaign, with the same or better best chi2 and
the same identified set on 20 campaigns.

    .venv/bin/python benchmarks/bench_fit_speed.py [--repeat 5] [--big-repeat 1] [--no-big]
                                                   [--no-cli] [--profile]
    .venv/bin/python benchmarks/bench_fit_speed.py --campaigns 20 --starts 200 --json OUT
    .venv/bin/python benchmarks/bench_fit_speed.py --compare BEFORE.json AFTER.json
    .venv/bin/python benchmarks/bench_fit_speed.py --race 3:25,6:5 ...   (any of the above)
    .venv/bin/python benchmarks/bench_fit_speed.py --ranks 0 1 2 --starts 1000
    .venv/bin/python benchmarks/bench_fit_speed.py --cluster-cost 3
    .venv/bin/python benchmarks/bench_fit_speed.py --chunk-phases [--race 3:25,6:5|off] [--repeat N] [--profile]

Default: the demo's campaign (``gprm synth campaign --seed 0``, preprocessed with the
defaults, written to a temporary folder), then

- ``identify`` with 10 starts in this process (every default: prior, sandwich uncertainty,
  adequacy, 200 band samples): median and range of ``--repeat`` runs after one warm-up, with
  the fit's own ``timings_s``, and the same runs less their uncertainty's time (the
  identification alone: the issue counts the default uncertainty in the fit issue's 30 s);
- the command a user types, ``gprm fit means.nc --starts 10 --out f.json``, in a fresh
  interpreter: median and range of ``--repeat`` runs (imports included);
- ``identify`` with 1000 starts on the CLI's default workers (one per core, at most one per
  chunk: two on the 2-core machine; the Dask cluster's start included) and in this process,
  ``--big-repeat`` runs each.

The load average (1 minute) is printed before and after each measurement: the machine is
shared, so a number is comparable only at a similar load; the 1000-start rows also give the
CPU seconds of the process and its (finished) Dask workers, which the load does not change
much. ``--race ITER:KEEP,...|off`` runs every fit with that racing schedule
(``gprm fit --race``; default: the library's, off). ``--profile`` adds the 25 functions
with the most own time in one 10-start fit and the 40 of gprm's with the most cumulative time
(cProfile; where the fit's phases spend it: the draws' projection, the polishes, the
resonance search, the adequacy).

``--campaigns K``: the fits of campaigns seeds 0..K-1 (``synth_campaign(seed=k)``, the
defaults otherwise) with ``--starts`` starts in this process, one JSON line each (best chi2,
the identified set, the timings), written to ``--json``; ``--compare`` sets two such files
side by side (run the first with the code before a change, the second after it).

``--ranks K ...``: the racing diagnosis (docs/fitting.md, "Racing"): the fits of these
campaigns without racing, and per chunk the rank of its eventual best start among the running
starts after 3 .. 40 iterations. ``--cluster-cost N``: the local Dask cluster's fixed cost
(start, first task on each of the 2 workers, close), N times. ``--chunk-phases``: the CPU
per phase of one chunk of 250 demo starts (validity check, initial Jacobians, iterations by
the number of starts running), with ``--race`` (default there 3:25,6:5); then the chunk's
CPU over ``--repeat`` - 1 more runs without the phases' timers, and with ``--profile`` its 20
functions with the most own time (cProfile).
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import pstats
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _machine import machine


def load() -> float:
    return os.getloadavg()[0]


def means_file(folder: Path, seed: int = 0) -> Path:
    from gprm.campaign.preprocess import PreprocessConfig, preprocess
    from gprm.campaign.synth import synth_campaign

    path = folder / f"means_{seed}.nc"
    preprocess(synth_campaign(seed=seed), PreprocessConfig()).to_dataset().to_netcdf(path)
    return path


RACE: tuple | None = None   # --race (gprm.fit.starts.make_race_rule); None: the library's


def fit(path: Path, starts: int, workers: int = 0):
    from gprm.fit.api import FitOptions, run_fit

    extra = {"race": RACE} if RACE is not None else {}
    return run_fit(str(path), FitOptions(starts=starts, **extra), workers=workers)


def spread(values: list[float]) -> str:
    return (f"median {statistics.median(values):.2f} s (range {min(values):.2f}-"
            f"{max(values):.2f}, {len(values)} runs)")


def cpu_seconds() -> float:
    """CPU of this process and of its finished children (the Dask workers once the cluster
    closed, a command's interpreter): load-independent, unlike the wall time."""
    import resource

    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + ch.ru_utime + ch.ru_stime


CPUS: list[float] = []      # CPU seconds of the runs of the last timed() call


def timed(fn, repeat: int):
    walls, loads, out = [], [load()], None
    CPUS.clear()
    for _ in range(repeat):
        t, c = time.perf_counter(), cpu_seconds()
        out = fn()
        walls.append(time.perf_counter() - t)
        CPUS.append(cpu_seconds() - c)
    loads.append(load())
    return walls, loads, out


def gprm_exe() -> list[str]:
    here = Path(sys.executable).with_name("gprm")
    return [str(here)] if here.exists() else [sys.executable, "-m", "gprm.cli"]


def speed(args) -> None:
    from gprm.fit.engine import default_workers

    print(machine("scipy"))
    print(f"- command: `.venv/bin/python benchmarks/bench_fit_speed.py {' '.join(sys.argv[1:])}`"
          "\n")
    with tempfile.TemporaryDirectory() as tmp:
        path = means_file(Path(tmp))
        fit(path, 10)                                             # warm-up
        results: list = []                                        # every timed run's result

        def fit10():
            results.append(fit(path, 10))
            return results[-1]

        walls, loads, res = timed(fit10, args.repeat)
        print(f"10-start fit, identify in this process: {spread(walls)}; load {loads[0]:.2f}"
              f"/{loads[1]:.2f}; best chi2 {res.chi2:.4f}; identified {len(res.identified)}; "
              f"timings_s of the last {res.timings}")
        # the issue counts the default uncertainty in the fit issue's own 30 s budget: the
        # identification alone (multi-start, polishes, adequacy) is each run's wall time less
        # its uncertainty's
        alone = [w - float(r.timings.get("uncertainty", 0.0)) for w, r in zip(walls, results)]
        print(f"10-start fit without the default uncertainty (each run's wall less its "
              f"timings_s['uncertainty']): {spread(alone)}")
        if args.profile:
            pr = cProfile.Profile()
            pr.enable()
            fit(path, 10)
            pr.disable()
            for order, what, n, only in (("tottime", "own time", 25, ()),
                                         ("cumtime", "cumulative time, gprm's functions", 40,
                                          ("gprm/",))):
                s = io.StringIO()
                pstats.Stats(pr, stream=s).sort_stats(order).print_stats(*only, n)
                print(f"\nprofile ({what}) of one 10-start fit:\n```\n" +
                      "\n".join(ln for ln in s.getvalue().splitlines() if ln.strip())[-6000:]
                      + "\n```")
        if not args.no_cli:
            out = Path(tmp) / "f.json"

            def cli():
                for p in (out, out.with_suffix(".nc")):
                    p.unlink(missing_ok=True)
                subprocess.run(gprm_exe() + ["fit", str(path), "--starts", "10", "--out",
                                             str(out)], check=True, capture_output=True)
            walls, loads, _ = timed(cli, args.repeat)
            print(f"`gprm fit means.nc --starts 10 --out f.json`: {spread(walls)}; load "
                  f"{loads[0]:.2f}/{loads[1]:.2f}; the fit's timings_s "
                  f"{json.loads(out.read_text())['timings_s']}")
        if not args.no_big:
            w = default_workers(1000, 250)
            for workers in (w, 0):
                walls, loads, res = timed(lambda w=workers: fit(path, 1000, w),
                                            args.big_repeat)
                print(f"1000-start fit, identify, {workers} workers, race {RACE}: "
                      f"{spread(walls)}; CPU {', '.join(f'{c:.2f}' for c in CPUS)} s (this "
                      f"process and its workers); load {loads[0]:.2f}/{loads[1]:.2f}; best "
                      f"chi2 {res.chi2:.4f}; identified {len(res.identified)}; timings_s "
                      f"{res.timings}")


def campaigns(args) -> None:
    print(machine("scipy"), file=sys.stderr)
    with tempfile.TemporaryDirectory() as tmp, open(args.json, "w") as fh:
        for k in range(args.campaigns):
            path = means_file(Path(tmp), k)
            t, c = time.perf_counter(), time.process_time()
            res = fit(path, args.starts)
            st = res.starts
            row = {"seed": k, "starts": args.starts, "race": [list(p) for p in RACE or ()],
                   "chi2": res.chi2, "identified": list(res.identified),
                   "wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c,
                   "timings_s": res.timings, "load": load(),
                   "best_start_chi2": float(st.chi2[st.best_index]),
                   "best_index": st.best_index, "n_at_best": st.n_at_best(),
                   "start_iterations": int(st.iterations.sum())}
            fh.write(json.dumps(row) + "\n")
            fh.flush()
            print(f"seed {k}: chi2 {res.chi2:.6f}, {len(res.identified)} identified, "
                  f"{row['wall_s']:.2f} s", file=sys.stderr, flush=True)


RANK_AT = (3, 6, 10, 15, 20, 25, 30, 40)


def ranks(args) -> None:
    """Why racing by chi-square rank loses the best start on some campaigns: the fits of
    campaigns ``--ranks`` with ``--starts`` starts and no racing, every chunk's chi-square
    recorded before each iteration (through the LM's prune hook), then per chunk the rank
    (0 = the smallest) of the start that ends best in it among the chunk's running starts
    after 3 .. 40 iterations, how far its final chi2 is from the fit's best start, and how
    many of the chunk's starts end within dchi2 <= 1 of it (many: any of them will do)."""
    import numpy as np

    import gprm.fit.engine as engine

    global RACE
    RACE = ()
    make = engine.make_stop_rule
    paths: list[list] = []

    def recording(opts):                      # the driver's rule, plus a record of chi2
        rule, rec = make(opts), []
        paths.append(rec)

        def wrapped(chi2, active):
            rec.append((np.array(chi2, float), np.array(active, bool)))
            return rule(chi2, active) if rule is not None else np.zeros(len(chi2), bool)
        return wrapped

    engine.make_stop_rule = recording
    print(machine("scipy"))
    print(f"- command: `.venv/bin/python benchmarks/bench_fit_speed.py {' '.join(sys.argv[1:])}`"
          "\n")
    print("| campaign | chunk | final chi2 - fit's best start | chunk's starts within "
          "dchi2 <= 1 of it | "
          + " | ".join(f"rank after {r}" for r in RANK_AT) + " |\n"
          + "|---" * (4 + len(RANK_AT)) + "|")
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for k in args.ranks:
                paths.clear()
                res = fit(means_file(Path(tmp), k), args.starts)
                final = res.starts.chi2
                best = np.nanmin(final)
                size = res.options.chunk_size
                for c, rec in enumerate(paths):
                    f = final[c * size:(c + 1) * size]
                    b = int(np.nanargmin(f))
                    cells = []
                    for r in RANK_AT:
                        if r >= len(rec):
                            cells.append("-")
                            continue
                        chi2, active = rec[r]
                        if not active[b]:
                            cells.append("stopped")
                            continue
                        cells.append(str(int(np.sum(active & (chi2 < chi2[b])))))
                    near = int(np.sum(f <= f[b] + 1.0))
                    print(f"| {k} | {c} | {f[b] - best:.3g} | {near} | " + " | ".join(cells)
                          + " |", flush=True)
    finally:
        engine.make_stop_rule = make


def chunk_phases(args) -> None:
    """Where the CPU of one chunk of 250 starts of the demo's campaign goes (in process, after
    one warm-up run of the chunk): the starts' validity check, the Jacobians at the starting
    points (LM's initialisation), and the lock-step iterations by the number of starts
    running, with the racing schedule ``--race`` (default here: 3:25,6:5)."""
    import numpy as np

    import gprm.fit.engine as engine
    import gprm.fit.lm as lm
    from gprm.campaign.files import read_means
    from gprm.fit.api import FitOptions
    from gprm.fit.objective import Objective, fit_data_from_means
    from gprm.fit.prior import default_prior
    from gprm.fit.starts import draw_starts
    from gprm.params import load_params

    race = ((3, 25), (6, 5)) if RACE is None else RACE
    print(machine("scipy"))
    print(f"- command: `.venv/bin/python benchmarks/bench_fit_speed.py {' '.join(sys.argv[1:])}`"
          f"; race {race}\n")
    with tempfile.TemporaryDirectory() as tmp:
        o = FitOptions(starts=250, race=race)
        data = fit_data_from_means(read_means(means_file(Path(tmp))), window=o.window,
                                   sigma=o.sigma, source="demo")
    base = o.parameters(load_params(None))
    names = tuple(base.fitted)
    obj = Objective.create(data, base, names, piezo=o.piezo,
                           prior=default_prior(base, names, o.prior_width))
    ms = o.multistart()
    X0n = draw_starts(obj.to_normalised(base.initial_vector(names)), ms)
    task = engine.ChunkTask(0, np.arange(250), X0n, obj, ms)
    log: list = []

    def timed_call(label, f):
        def g(*a, **k):
            n = label(*a) if callable(label) else label
            c = time.process_time()
            out = f(*a, **k)
            log.append((n, time.process_time() - c))
            return out
        return g

    saved = (lm.lm_step, lm.lm_init, engine.resample_invalid)
    lm.lm_step = timed_call(lambda state, *a: int(state.active.sum()), lm.lm_step)
    lm.lm_init = timed_call("initial Jacobians", lm.lm_init)
    engine.resample_invalid = timed_call("validity check", engine.resample_invalid)
    try:
        engine.run_chunk(task)
        log.clear()
        c = time.process_time()
        engine.run_chunk(task)
        total = time.process_time() - c
    finally:
        lm.lm_step, lm.lm_init, engine.resample_invalid = saved
    groups: dict = {}
    for n, t in log:
        key = n if isinstance(n, str) else f"iterations with {n} starts running"
        groups.setdefault(key, [0, 0.0])
        groups[key][0] += 1
        groups[key][1] += t
    print("| phase | calls | CPU s |\n|---|---:|---:|")
    for key, (k, t) in groups.items():
        print(f"| {key} | {k} | {t:.3f} |")
    print(f"| **the chunk** | | **{total:.3f}** |\n\nload {load():.2f}")
    # the chunk again without the phases' timers, --repeat times, and with --profile under
    # cProfile: where its CPU goes by function
    plain = []
    for _ in range(max(0, args.repeat - 1)):
        c = time.process_time()
        engine.run_chunk(task)
        plain.append(time.process_time() - c)
    if plain:
        print(f"\nthe chunk's CPU without the phase timers, {len(plain)} more runs: "
              f"median {statistics.median(plain):.3f} s (range {min(plain):.3f}-"
              f"{max(plain):.3f})\n")
    if args.profile:
        pr = cProfile.Profile()
        pr.enable()
        engine.run_chunk(task)
        pr.disable()
        out = io.StringIO()
        pstats.Stats(pr, stream=out).sort_stats("tottime").print_stats(20)
        print("profile (own time) of the chunk:\n```\n" + "\n".join(
            ln for ln in out.getvalue().splitlines() if ln.strip()) + "\n```\n")


def _warm_worker() -> int:
    import gprm.fit.engine  # noqa: F401  (what a chunk imports in a worker)
    import gprm.fit.objective  # noqa: F401

    return os.getpid()


def cluster_cost(repeat: int) -> None:
    """The fixed cost of the fit's local Dask cluster (``gprm.fit.engine.local_cluster`` with
    the CLI's default 2 workers, TLS, HTTP stopped): start, the first task on each worker (its
    imports of the fit), close; wall and CPU of this process and of the workers."""
    from distributed import Client

    from gprm.fit.engine import _stop_http_server, local_cluster

    print(machine("scipy"))
    print(f"- command: `.venv/bin/python benchmarks/bench_fit_speed.py {' '.join(sys.argv[1:])}`"
          "\n")
    for _ in range(repeat):
        l0, t, c = load(), time.perf_counter(), cpu_seconds()
        cluster = local_cluster(2)
        client = Client(cluster, security=cluster.security)
        client.run(_stop_http_server)
        up = time.perf_counter() - t
        client.gather([client.submit(_warm_worker, pure=False, key=f"warm-{i}")
                       for i in range(2)])
        first = time.perf_counter() - t
        client.close()
        cluster.close()
        print(f"local cluster, 2 workers: up {up:.2f} s, first task on each {first:.2f} s, "
              f"closed {time.perf_counter() - t:.2f} s wall; CPU {cpu_seconds() - c:.2f} s "
              f"(this process and the workers); load {l0:.2f}/{load():.2f}", flush=True)


def _cpu(row: dict) -> str:
    return f"{row['cpu_s']:.2f}" if "cpu_s" in row else "-"


def compare(before: str, after: str) -> None:
    rows = [[json.loads(ln) for ln in Path(f).read_text().splitlines() if ln.strip()]
            for f in (before, after)]
    print("| seed | best chi2 before | after | after - before | identified before | after "
          "| same set | fit wall s before | after | CPU s before | after |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|")
    after_by_seed = {r["seed"]: r for r in rows[1]}
    pairs = [(a, after_by_seed[a["seed"]]) for a in rows[0] if a["seed"] in after_by_seed]
    worse = differ = 0
    for a, b in pairs:
        d = b["chi2"] - a["chi2"]
        same = set(a["identified"]) == set(b["identified"])
        worse += d > 1e-6 * abs(a["chi2"])
        differ += not same
        print(f"| {a['seed']} | {a['chi2']:.6f} | {b['chi2']:.6f} | {d:+.2e} | "
              f"{len(a['identified'])} | {len(b['identified'])} | {'yes' if same else 'NO'} | "
              f"{a['wall_s']:.2f} | {b['wall_s']:.2f} | {_cpu(a)} | {_cpu(b)} |")
    print(f"\n{len(pairs)} campaigns (those in both files): best chi2 worse (by more than 1e-6 relative) on {worse}, "
          f"identified set different on {differ}")


def polishes(args) -> None:
    """Each polish of one 10-start fit of the demo's campaign (captured as identify calls
    them) run again three ways: Algorithm 1's damping update, the trust region, the trust
    region settled; iterations, status and the chi-square reached (docs/fitting.md, "Speed",
    stop 38)."""
    import numpy as np

    import gprm.fit.identify as identify_module
    from gprm.fit.engine import polish_best

    print(machine("scipy"))
    calls = []
    real = identify_module.polish_best

    def capture(obj, x, lm, **kw):
        calls.append((obj, np.array(x, float), lm, kw))
        return real(obj, x, lm, **kw)

    with tempfile.TemporaryDirectory() as tmp:
        path = means_file(Path(tmp))
        identify_module.polish_best = capture
        try:
            fit(path, 10)
        finally:
            identify_module.polish_best = real
    print("| polish | ftol | Algorithm 1 | trust region | trust region, settled |\n"
          "|---|---|---|---|---|")
    for i, (obj, x, lm, kw) in enumerate(calls):
        ftol = kw.get("ftol", 1e-12)
        cells = []
        for extra in ({"trust_region": False}, {}, {"settle": True}):
            _, info = polish_best(obj, x, lm, ftol=ftol, **extra)
            cells.append(f"{info['iterations']} ({info['status']}), {info['chi2_after']:.6f}")
        print(f"| {i + 1} | {ftol:g} | " + " | ".join(cells) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--big-repeat", type=int, default=1)
    ap.add_argument("--no-big", action="store_true")
    ap.add_argument("--no-cli", action="store_true")
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--polishes", action="store_true",
                    help="each polish of a 10-start fit three ways (stop 38's comparison)")
    ap.add_argument("--campaigns", type=int, default=0)
    ap.add_argument("--starts", type=int, default=200)
    ap.add_argument("--json", default="fit_speed_campaigns.jsonl")
    ap.add_argument("--compare", nargs=2, metavar=("BEFORE", "AFTER"))
    ap.add_argument("--chunk-phases", action="store_true",
                    help="CPU per phase of one chunk of 250 demo starts (with --race)")
    ap.add_argument("--cluster-cost", type=int, default=0, metavar="N",
                    help="N starts and stops of the fit's local cluster (its fixed cost)")
    ap.add_argument("--ranks", type=int, nargs="+", metavar="SEED",
                    help="the racing diagnosis on these campaigns (with --starts; no racing)")
    ap.add_argument("--race", default=None, help="racing schedule of the fits, as gprm fit "
                    "--race (ITER:KEEP,... or off); default: the library's")
    args = ap.parse_args()
    global RACE
    if args.race is not None:
        from gprm.options import Race

        RACE = Race()(args.race)
    else:
        RACE = None
    if args.polishes:
        polishes(args)
    elif args.chunk_phases:
        chunk_phases(args)
    elif args.cluster_cost:
        cluster_cost(args.cluster_cost)
    elif args.ranks:
        ranks(args)
    elif args.compare:
        compare(*args.compare)
    elif args.campaigns:
        campaigns(args)
    else:
        speed(args)


if __name__ == "__main__":
    main()
