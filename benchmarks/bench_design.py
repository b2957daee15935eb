"""Benchmark and validation of ``gprm design`` (issue 25; docs/design.md).

    .venv/bin/python benchmarks/bench_design.py --timing
        ``gprm design`` with the default candidates on the demo's fit (``gprm demo --quick``)
        and on a fit of a CSV campaign (a generated campaign written as a CSV folder,
        preprocessed and fitted with the CLI): wall time of the command.

    .venv/bin/python benchmarks/bench_design.py --validate --truths 5 --starts 50
        For each truth (benchmarks/bench_coverage.py's draws, seeds 1000...): the base
        campaign (``gprm synth campaign``, every imperfection of the generator, 10 runs),
        preprocessed and fitted with the CLI; ``gprm design`` on that fit with the candidates
        the generator can make (more runs, three times more runs, a longer record fitted over a
        longer window); each candidate's campaign (base + addition, as its design.json's
        ``synth_campaign`` says) simulated with a new seed, preprocessed and fitted with the
        CLI. Compared: achieved / predicted posterior sd (u) of the parameters both identify,
        and the achieved 95 % intervals' coverage of the truth (the 21 physical parameters).

Prints markdown (machine, command, tables).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _machine import machine

GPRM = [sys.executable, "-m", "gprm.cli"]

VALIDATION_CANDIDATES = """include_defaults = false
[cost]
max_additions = 1
[[candidate]]
name = "more-runs"
note = "the five positions, 10 more runs"
[[candidate]]
name = "more-runs-x3"
runs = 30
note = "the five positions, 30 more runs"
[[candidate]]
name = "long-window"
record = "2 ms"
window = ["0.97 ms", "1.6 ms"]
note = "10 more runs recorded to 2 ms, all fitted to 1.6 ms"
"""


def gprm(*args, cwd=None) -> float:
    t = time.perf_counter()
    r = subprocess.run([*GPRM, *map(str, args)], capture_output=True, text=True, cwd=cwd)
    if r.returncode != 0:
        raise RuntimeError(f"gprm {' '.join(map(str, args))}: {r.stderr or r.stdout}")
    return time.perf_counter() - t


def timing(starts: int) -> None:
    from gprm.campaign.files import read_campaign, write_campaign_dir

    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        gprm("demo", "--quick", "--out", d / "demo")
        t_demo = gprm("design", d / "demo" / "fit.json", "--out", d / "design_demo.json")
        gprm("synth", "campaign", "--seed", 11, "--out", d / "c.nc")
        write_campaign_dir(read_campaign(d / "c.nc"), d / "csv")
        gprm("preprocess", d / "csv", "--out", d / "means.nc")
        gprm("fit", d / "means.nc", "--starts", starts, "--out", d / "fit.json")
        t_csv = gprm("design", d / "fit.json", "--out", d / "design_csv.json")
        doc = json.loads((d / "design_csv.json").read_text())
        t_paper = gprm("design", "paper", "--out", d / "design_paper.json")
    print("| fit | candidates | wall s (command) | of which design s |")
    print("|---|---|---|---|")
    print(f"| demo (`gprm demo --quick`) | default ({len(doc['candidates'])}) | {t_demo:.1f} | |")
    print(f"| CSV campaign (seed 11, {starts} starts) | default ({len(doc['candidates'])}) | "
          f"{t_csv:.1f} | {doc['timings_s']['total']:.1f} |")
    print(f"| paper | default | {t_paper:.1f} | |")


def validate(n_truths: int, starts: int, seed0: int) -> None:
    sys.path.insert(0, os.path.dirname(__file__))
    from bench_coverage import PHYSICAL, draw_truth

    from dataclasses import replace

    from gprm.design.config import read_design_config
    from gprm.design.core import run_design
    from gprm.params.files import save_params

    rows = []
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        (d / "cands.toml").write_text(VALIDATION_CANDIDATES)
        for k in range(n_truths):
            seed = seed0 + k
            truth = draw_truth(seed)
            tdir = d / f"t{seed}"
            tdir.mkdir()
            save_params(truth, tdir / "truth.toml")
            gprm("synth", "campaign", "--truth", tdir / "truth.toml", "--seed", seed,
                 "--out", tdir / "base.nc")
            gprm("preprocess", tdir / "base.nc", "--out", tdir / "base_means.nc")
            gprm("fit", tdir / "base_means.nc", "--starts", starts, "--seed", seed,
                 "--out", tdir / "base_fit.json")
            gprm("design", tdir / "base_fit.json", "--candidates", d / "cands.toml",
                 "--out", tdir / "design.json")
            design = json.loads((tdir / "design.json").read_text())
            base_fit = json.loads((tdir / "base_fit.json").read_text())
            for rank, name in enumerate(design["ranking"], 1):
                # the prediction for exactly that campaign: a design of this one addition
                cfg = read_design_config(d / "cands.toml")
                cfg = replace(cfg, candidates=tuple(c for c in cfg.candidates
                                                    if c.name == name))
                res = run_design(tdir / "base_fit.json", cfg)
                syn = res.synth
                assert syn["simulated"] == [name], syn
                pred = syn["predicted"]
                camp = tdir / f"{name}.nc"
                gprm("synth", "campaign", "--truth", tdir / "truth.toml", "--seed",
                     seed + 5000, "--runs", syn["runs"], "--noise-runs", syn["noise_runs"],
                     "--t-end", f"{syn['t_end'] * 1e3:g}ms", "--out", camp)
                gprm("preprocess", camp, "--out", tdir / f"{name}_means.nc")
                w = syn["window"]
                gprm("fit", tdir / f"{name}_means.nc", "--starts", starts, "--seed", seed,
                     "--window", f"{w[0] * 1e3:g}ms,{w[1] * 1e3:g}ms",
                     "--out", tdir / f"{name}_fit.json")
                fit = json.loads((tdir / f"{name}_fit.json").read_text())
                ratios, cover, n_cov = {}, 0, 0
                for i, n in enumerate(res.names):
                    e = fit["parameters"][n]
                    sd_ach = e["contraction"] * res.prior_sd[i]
                    if e["identified"] and pred["identified"][i]:
                        ratios[n] = sd_ach / pred["sd_u"][i]
                    if n in PHYSICAL and e["identified"]:
                        lo, hi = e["interval"]["lower"], e["interval"]["upper"]
                        tv = truth[n]                     # fit.json intervals are SI
                        cover += int(lo <= tv <= hi)
                        n_cov += 1
                r = np.array(list(ratios.values()))
                base_ident = sum(bool(base_fit["parameters"][n]["identified"])
                                 for n in res.names)
                rows.append({"seed": seed, "rank": rank, "name": name,
                             "runs": syn["runs"], "window": w,
                             "n_compared": len(r), "median_ratio": float(np.median(r)),
                             "within25": int(np.sum(np.abs(r - 1) <= 0.25)),
                             "ratios": ratios, "cover": cover, "n_cover": n_cov,
                             "ident_base": base_ident,
                             "ident_pred": int(np.sum(pred["identified"])),
                             "ident_ach": sum(bool(fit["parameters"][n]["identified"])
                                              for n in res.names)})
                print(json.dumps({k: v for k, v in rows[-1].items() if k != "ratios"}),
                      file=sys.stderr, flush=True)
    wall = time.perf_counter() - t_all
    print(f"\n{n_truths} truths, {starts} starts per fit, {wall:.0f} s\n")
    print("| truth seed | rank | candidate | runs | window ms | identified: base fit / "
          "predicted / achieved | params compared | achieved / predicted sd, median | "
          "within +-25 % | identified physical: 95 % coverage |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['seed']} | {r['rank']} | {r['name']} | {r['runs']} | "
              f"{r['window'][0] * 1e3:g}-{r['window'][1] * 1e3:g} | {r['ident_base']} / "
              f"{r['ident_pred']} / {r['ident_ach']} | {r['n_compared']} | "
              f"{r['median_ratio']:.2f} | {r['within25']}/{r['n_compared']} | "
              f"{r['cover']}/{r['n_cover']} |")
    allr = np.concatenate([list(r["ratios"].values()) for r in rows])
    cov = sum(r["cover"] for r in rows) / max(sum(r["n_cover"] for r in rows), 1)
    print(f"\nAll: {len(allr)} parameter comparisons, median achieved/predicted "
          f"{np.median(allr):.2f}, within +-25 %: {np.mean(np.abs(allr - 1) <= 0.25):.0%}; "
          f"coverage of the identified physical parameters' 95 % intervals {cov:.1%}")
    per = {}
    for r in rows:
        for n, v in r["ratios"].items():
            per.setdefault(n, []).append(v)
    print("\n| parameter | comparisons | achieved / predicted sd: median (min .. max) |")
    print("|---|---|---|")
    for n, v in per.items():
        print(f"| {n} | {len(v)} | {np.median(v):.2f} ({min(v):.2f} .. {max(v):.2f}) |")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--timing", action="store_true")
    ap.add_argument("--validate", action="store_true")
    ap.add_argument("--truths", type=int, default=1)
    ap.add_argument("--starts", type=int, default=50)
    ap.add_argument("--seed", type=int, default=1000)
    a = ap.parse_args(argv)
    print(machine("numpy", "scipy"))
    print(f"\ncommand: `.venv/bin/python benchmarks/bench_design.py {' '.join(sys.argv[1:])}`\n")
    if a.timing:
        timing(a.starts)
    if a.validate:
        validate(a.truths, a.starts, a.seed)


if __name__ == "__main__":
    main()
