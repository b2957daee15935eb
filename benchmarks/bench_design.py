"""Benchmark and validation of ``gprm design`` (issue 25; docs/design.md).

    .venv/bin/python benchmarks/bench_design.py --timing
        ``gprm design`` with the default candidates on the demo's fit (``gprm demo --quick``)
        and on a fit of a CSV campaign (a generated campaign written as a CSV folder,
        preprocessed and fitted with the CLI): wall time of the command.

    .venv/bin/python benchmarks/bench_design.py --validate --truths 5 --starts 50 [--log F]
        For each truth (benchmarks/bench_coverage.py's draws, seeds 1000...): the base
        campaign (``gprm synth campaign``, every imperfection of the generator, 10 runs),
        preprocessed and fitted with the CLI; ``gprm design`` on that fit with the candidates
        the generator can make (more runs, three times more runs, a longer record fitted over a
        longer window); each candidate's campaign (base + addition, as its design.json's
        ``synth_campaign`` says) simulated with a new seed, preprocessed and fitted with the
        CLI. Compared: achieved / predicted posterior sd (u) of the parameters both identify,
        and the achieved 95 % intervals' coverage of the truth (the 21 physical parameters).
        Control: the base design simulated again with a new seed and fitted, against the
        base fit (the design's prediction for the base design): how closely two fits of the
        same design agree, the floor of any such comparison. ``--from-log F`` prints the
        tables of an earlier (or interrupted) run's JSON lines.

    .venv/bin/python benchmarks/bench_design.py --validate --truths 5 --starts 50 --replicates 3 --keep DIR
        The same with three campaigns of every validated design (the control and each
        candidate; other seeds): besides the single-campaign tables, the geometric mean of
        each parameter's achieved / predicted sd over a design's replicates (the prediction
        against the design's expected width, the campaigns' chance averaged), the ceiling a
        perfect prediction of the expected width would reach against one campaign and
        against the replicates' mean (from the replicates' own spread), and the candidates'
        mean ratio over the control's (the base fit's own chance taken out).

    .venv/bin/python benchmarks/bench_design.py --run-structure DIR
        How the runs of a kept validation's campaigns (``--keep DIR``) differ: each run's
        deviation from the mean regressed on the fitted model's sensitivities to the drive's
        amplitude, the trigger time, the retraction time and one stiffness per plane.

    ``--keep DIR`` (with --validate or --validate-drive): the campaigns, fits and truths are
    written under DIR and kept; a fit already there is used instead of being made again (the
    same seeds make the same campaigns), so running the command again with the same DIR
    re-scores the design's predictions on the same achieved fits, or finishes an
    interrupted validation. Without it they go to a temporary folder.

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
from contextlib import contextmanager
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
    from gprm.campaign.files import load_campaign, write_campaign_dir

    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        gprm("demo", "--quick", "--out", d / "demo")
        t_demo = gprm("design", d / "demo" / "fit.json", "--out", d / "design_demo.json")
        gprm("synth", "campaign", "--seed", 11, "--out", d / "c.nc")
        write_campaign_dir(load_campaign(d / "c.nc"), d / "csv")
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


def _compare(res, pred_sd, pred_ident, fit: dict, truth, base_fit: dict | None = None) -> dict:
    """Achieved (fit.json) against predicted sd in u; the 95 % coverage of the truth over the
    identified physical parameters (fit.json intervals are SI); with ``base_fit``, also the
    achieved sd over the base fit's (``over_base``, the parameters both identify)."""
    from bench_coverage import PHYSICAL

    ratios, cover, n_cov, over = {}, 0, 0, {}
    for i, n in enumerate(res.names):
        e = fit["parameters"][n]
        sd_ach = e["contraction"] * res.prior_sd[i]
        if base_fit is not None:
            b = base_fit["parameters"][n]
            if e.get("identified") and b.get("identified"):
                over[n] = float(e["contraction"] / b["contraction"])
        if e["identified"] and pred_ident[i]:
            ratios[n] = float(sd_ach / pred_sd[i])
        if n in PHYSICAL and e["identified"]:
            lo, hi = e["interval"]["lower"], e["interval"]["upper"]
            cover += int(lo <= truth[n] <= hi)
            n_cov += 1
    return {"ratios": ratios, "cover": cover, "n_cover": n_cov,
            **({"over_base": over} if base_fit is not None else {}),
            "ident_pred": int(np.sum(pred_ident)),
            "ident_ach": sum(bool(fit["parameters"][n]["identified"]) for n in res.names)}



def _truth_folders(root: Path, seed0: int, n: int):
    """(seed, truth, folder) for the validation's truths seed0 .. seed0 + n - 1: each truth
    drawn as bench_coverage draws them and written to folder/truth.toml."""
    from bench_coverage import draw_truth

    from gprm.params.files import save_params

    for seed in range(seed0, seed0 + n):
        truth = draw_truth(seed)
        tdir = root / f"t{seed}"
        tdir.mkdir(exist_ok=True)
        if not (tdir / "truth.toml").exists():
            save_params(truth, tdir / "truth.toml")
        yield seed, truth, tdir


@contextmanager
def _workdir(keep: Path | None):
    """The validation's folder: ``keep`` (created if absent, kept) or a temporary one."""
    if keep is not None:
        keep.mkdir(parents=True, exist_ok=True)
        yield keep
        return
    with tempfile.TemporaryDirectory() as d:
        yield Path(d)

#: the seed step between replicate campaigns of one design (replicate j of a design whose
#: first campaign has seed s has seed s + REPLICATE_STEP * j)
REPLICATE_STEP = 100


def validate(n_truths: int, starts: int, seed0: int, log: Path,
             keep: Path | None = None, replicates: int = 1) -> list[dict]:
    """Runs the validation (see the module docstring); one JSON line per campaign to
    ``log`` as it goes. ``replicates``: campaigns of each design (the control and every
    ranked candidate), the same design with other seeds; row field ``replicate`` j = 0 ..
    replicates - 1 (the first is the single-campaign validation of earlier stops)."""
    sys.path.insert(0, os.path.dirname(__file__))
    from dataclasses import replace


    from gprm.design.config import read_design_config
    from gprm.design.core import run_design

    rows = []
    with _workdir(keep) as d, open(log, "a") as fh:
        (d / "cands.toml").write_text(VALIDATION_CANDIDATES)
        cfg_all = read_design_config(d / "cands.toml")

        def campaign(tdir, name, seed, runs, noise_runs, t_end, window):
            if (tdir / f"{name}_fit.json").exists():          # kept from an earlier run
                return json.loads((tdir / f"{name}_fit.json").read_text())
            camp = tdir / f"{name}.nc"
            gprm("synth", "campaign", "--truth", tdir / "truth.toml", "--seed", seed,
                 "--runs", runs, "--noise-runs", noise_runs, "--t-end", f"{t_end * 1e3:g}ms",
                 "--out", camp)
            gprm("preprocess", camp, "--out", tdir / f"{name}_means.nc")
            gprm("fit", tdir / f"{name}_means.nc", "--starts", starts, "--seed", seed,
                 "--window", f"{window[0] * 1e3:g}ms,{window[1] * 1e3:g}ms",
                 "--out", tdir / f"{name}_fit.json")
            return json.loads((tdir / f"{name}_fit.json").read_text())

        def emit(row):
            rows.append(row)
            fh.write(json.dumps(row) + "\n")
            fh.flush()

        for seed, truth, tdir in _truth_folders(d, seed0, n_truths):
            base_fit = campaign(tdir, "base", seed, 10, 5, 1.5e-3, (0.97e-3, 1.2e-3))
            gprm("design", tdir / "base_fit.json", "--candidates", d / "cands.toml",
                 "--out", tdir / "design.json")
            design = json.loads((tdir / "design.json").read_text())
            res0 = run_design(tdir / "base_fit.json", replace(cfg_all, candidates=()))
            # control: the same design again (a new seed); its prediction is the base fit
            for j in range(replicates):
                rep = campaign(tdir, "replicate" + (f"_r{j}" if j else ""),
                               seed + 7000 + REPLICATE_STEP * j, 10, 5, 1.5e-3,
                               (0.97e-3, 1.2e-3))
                emit({"seed": seed, "rank": 0, "name": "base again (control)", "runs": 10,
                      "window": [0.97e-3, 1.2e-3], "replicate": j,
                      **_compare(res0, res0.base.sd_u, res0.base.identified, rep, truth,
                                 base_fit)})
            for rank, name in enumerate(design["ranking"], 1):
                # the prediction for exactly that campaign: a design of this one addition
                cfg = replace(cfg_all, candidates=tuple(c for c in cfg_all.candidates
                                                        if c.name == name))
                res = run_design(tdir / "base_fit.json", cfg)
                syn = res.synth
                assert syn["simulated"] == [name], syn
                pred = syn["predicted"]
                for j in range(replicates):
                    fit = campaign(tdir, name + (f"_r{j}" if j else ""),
                                   seed + 5000 + REPLICATE_STEP * j, syn["runs"],
                                   syn["noise_runs"], syn["t_end"], syn["window"])
                    emit({"seed": seed, "rank": rank, "name": name, "runs": syn["runs"],
                          "window": list(syn["window"]), "replicate": j,
                          **_compare(res, pred["sd_u"], pred["identified"], fit, truth,
                                     base_fit)})
    return rows


def validate_drive(n_truths: int, starts: int, seed0: int, log: Path,
                   keep: Path | None = None) -> list[dict]:
    """A Piezo 1 campaign of its own (``gprm synth campaign --piezo 1``, fitted with
    ``gprm fit --piezo 1``) against the design's prediction for that block alone, made from
    the fit of the truth's Piezo 2 base campaign (its noise model and per-parameter
    carry-over transferred to the other drive, as the piezo1 candidate assumes)."""
    sys.path.insert(0, os.path.dirname(__file__))

    from gprm.design.config import MODEL_CHANNELS, Block, Channel
    from gprm.design.core import run_design

    rows = []
    block = Block(tuple(Channel(n) for n in MODEL_CHANNELS), drives=(1,), runs=10)
    with _workdir(keep) as d, open(log, "a") as fh:
        for seed, truth, tdir in _truth_folders(d, seed0, n_truths):
            for name, piezo, s in (("base", 2, seed), ("piezo1", 1, seed + 6000)):
                if (tdir / f"{name}_fit.json").exists():      # kept from an earlier run
                    continue
                gprm("synth", "campaign", "--truth", tdir / "truth.toml", "--seed", s,
                     "--piezo", piezo, "--out", tdir / f"{name}.nc")
                gprm("preprocess", tdir / f"{name}.nc", "--out", tdir / f"{name}_means.nc")
                gprm("fit", tdir / f"{name}_means.nc", "--starts", starts, "--seed", seed,
                     "--piezo", piezo, "--out", tdir / f"{name}_fit.json")
            res = run_design(tdir / "base_fit.json", alone=(block,))
            pred = res.alone[0]
            fit = json.loads((tdir / "piezo1_fit.json").read_text())
            row = {"seed": seed, "rank": -1, "name": "piezo1 alone", "runs": 10,
                   "window": [0.97e-3, 1.2e-3],
                   **_compare(res, pred["sd_u"], pred["identified"], fit, truth)}
            rows.append(row)
            fh.write(json.dumps(row) + "\n")
            fh.flush()
            print(json.dumps({k: v for k, v in row.items() if k != "ratios"}),
                  file=sys.stderr, flush=True)
    return rows


def tables(rows: list[dict]) -> None:
    print("| truth seed | rank | campaign | runs | window ms | identified: predicted / "
          "achieved | compared | achieved / predicted sd, median | within +-25 % | "
          "identified physical: 95 % coverage |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        v = np.array(list(r["ratios"].values()))
        print(f"| {r['seed']} | {r['rank'] if r['rank'] > 0 else '-'} | {r['name']} | {r['runs']} | "
              f"{r['window'][0] * 1e3:g}-{r['window'][1] * 1e3:g} | {r['ident_pred']} / "
              f"{r['ident_ach']} | {len(v)} | {np.median(v):.2f} | "
              f"{int(np.sum(np.abs(v - 1) <= 0.25))}/{len(v)} | {r['cover']}/{r['n_cover']} |")
    print("\n| campaigns | comparisons | achieved / predicted sd: median (16-84 %) | within "
          "+-25 % | 95 % coverage, identified physical | achieved sd / the base fit's, "
          "median |")
    print("|---|---|---|---|---|---|")
    names = sorted({r["name"] for r in rows if r["rank"] > 0})
    groups = [("control: the base design again", lambda r: r["rank"] == 0),
              ("top three recommendations", lambda r: r["rank"] > 0),
              ("Piezo 1 campaign alone", lambda r: r["rank"] == -1),
              *((n, lambda r, n=n: r["name"] == n) for n in names)]
    for label, sel in groups:
        rs = [r for r in rows if sel(r)]
        if not rs:
            continue
        v = np.concatenate([list(r["ratios"].values()) for r in rs])
        c = sum(r["cover"] for r in rs) / max(sum(r["n_cover"] for r in rs), 1)
        q = np.percentile(v, [16, 84])
        ob = [x for r in rs for x in (r.get("over_base") or {}).values()]
        print(f"| {label} ({len(rs)}) | {len(v)} | {np.median(v):.2f} ({q[0]:.2f}-{q[1]:.2f})"
              f" | {np.mean(np.abs(v - 1) <= 0.25):.0%} | {c:.1%} "
              f"({sum(r['cover'] for r in rs)}/{sum(r['n_cover'] for r in rs)}) | "
              f"{f'{np.median(ob):.2f}' if ob else '-'} |")
    if any(r.get("replicate", 0) > 0 for r in rows):
        replicate_tables(rows, groups)
    per: dict[str, list] = {}
    for r in rows:
        if r["rank"] > 0:
            for n, x in r["ratios"].items():
                per.setdefault(n, []).append(x)
    print("\n| parameter | comparisons | achieved / predicted sd: median (min .. max) |")
    print("|---|---|---|")
    for n, x in per.items():
        print(f"| {n} | {len(x)} | {np.median(x):.2f} ({min(x):.2f} .. {max(x):.2f}) |")


def replicate_means(rows: list[dict]) -> list[dict]:
    """Per design validated with replicates ((truth seed, design name) with 2 or more rows),
    per parameter compared in every replicate: the achieved / predicted sd ratio of each
    replicate; ``gm`` their geometric mean (the prediction against the design's expected
    achieved sd rather than one campaign's), ``var`` the sample variance of their logs (how
    much one campaign's achieved sd varies by chance), ``k`` the replicates."""
    by: dict[tuple, list[dict]] = {}
    for r in rows:
        by.setdefault((r["seed"], r["name"]), []).append(r)
    out = []
    for (seed, name), rs in by.items():
        if len(rs) < 2:
            continue
        common = set.intersection(*(set(r["ratios"]) for r in rs))
        for n in sorted(common):
            ln = np.log([r["ratios"][n] for r in rs])
            out.append({"seed": seed, "name": name, "rank": rs[0]["rank"], "param": n,
                        "gm": float(np.exp(ln.mean())), "var": float(ln.var(ddof=1)),
                        "k": len(rs)})
    return out


def replicate_tables(rows: list[dict], groups) -> None:
    """The replicates' tables (``--replicates``): per group of designs, the geometric mean of
    each parameter's achieved / predicted sd over a design's replicate campaigns, and the
    ceiling: the share within +-25 % (0.75-1.25, as the other tables) that a perfect
    prediction of the expected sd would reach against a single campaign, from the
    replicates' own spread (per parameter a normal in ln with the pooled within-design
    variance, centred on the expected sd; the mean over the comparisons), and against the
    replicates' mean (that variance over k). Last, the candidates' mean ratios divided by
    the control's for the same truth and parameter (the control's replicates against the
    base fit): the prediction as it would be from a base fit whose sd were its design's
    expected one, i.e. the design's own error with the base campaign's chance taken out."""
    from scipy.stats import norm

    def inside(sd: float) -> float:
        """P(0.75 <= exp(Z) <= 1.25) for Z ~ N(0, sd^2): the +-25 % of the other tables."""
        sd = max(sd, 1e-12)
        return float(norm.cdf(np.log(1.25) / sd) - norm.cdf(np.log(0.75) / sd))

    reps = replicate_means(rows)
    if not reps:
        return
    # the control's mean ratio per truth and parameter: the base fit's own chance
    ctrl = {(r["seed"], r["param"]): r["gm"] for r in reps if r["rank"] == 0}
    print("\n| designs, replicated | comparisons | achieved (geometric mean over the "
          "replicates) / predicted sd: median (16-84 %) | within +-25 % | ceiling against "
          "one campaign | ceiling against the replicates' mean | within +-25 % with the base "
          "fit's chance taken out |")
    print("|---|---|---|---|---|---|---|")
    for label, sel in groups:
        rs = [r for r in reps if sel(r)]
        if not rs:
            continue
        gm = np.array([r["gm"] for r in rs])
        pooled: dict[str, list] = {}
        for r in rs:
            pooled.setdefault(r["param"], []).append((r["var"], r["k"]))
        sd1 = {n: np.sqrt(sum(v * (k - 1) for v, k in x) / sum(k - 1 for _, k in x))
               for n, x in pooled.items()}
        one = np.mean([inside(sd1[r["param"]]) for r in rs])
        mean_k = np.mean([inside(sd1[r["param"]] / np.sqrt(r["k"])) for r in rs])
        q = np.percentile(gm, [16, 84])
        designs = len({(r["seed"], r["name"]) for r in rs})
        # the base fit's own chance taken out: each candidate's mean ratio over the
        # control's for that truth and parameter, i.e. the prediction as it would be from
        # a base fit with its expected sd
        adj = np.array([r["gm"] / ctrl[(r["seed"], r["param"])] for r in rs
                        if r["rank"] > 0 and (r["seed"], r["param"]) in ctrl])
        adj_cell = (f"{np.mean(np.abs(adj - 1) <= 0.25):.0%} ({len(adj)}, median "
                    f"{np.median(adj):.2f})" if adj.size else "-")
        print(f"| {label} ({designs} x {rs[0]['k']}) | {len(gm)} | {np.median(gm):.2f} "
              f"({q[0]:.2f}-{q[1]:.2f}) | {np.mean(np.abs(gm - 1) <= 0.25):.0%} | "
              f"{one:.0%} | {mean_k:.0%} | {adj_cell} |")


#: the model's sensitivities the runs' deviations are regressed on (--run-structure), added
#: one at a time: the drive's amplitude, the trigger time, the drive's retraction time, and a
#: stiffness of each plane
RUN_COLUMNS = ("V0", "t0", "tau_v", "k_Ax", "k_lr", "k_Cy")


def run_structure(keep: Path) -> None:
    """How the runs of the validation's kept campaigns differ (``--run-structure DIR``): per
    campaign and model position, each run's deviation from the mean over the fit window,
    regressed (least squares, one coefficient per run) on the fitted model's sensitivities to
    :data:`RUN_COLUMNS`, added one at a time; the share of the runs' spread above the white
    noise each set explains, and what is left in units of the white noise's variance."""
    import xarray as xr

    from gprm.fit.files import load_model
    from gprm.params import batch_from_vectors
    from gprm.simulate import observe

    print("| campaign | position | spread / white noise (variance) | explained by: "
          + " | ".join("+" + c for c in RUN_COLUMNS) + " | left / white noise |")
    print("|---|---|---|" + "---|" * len(RUN_COLUMNS) + "---|")
    for tdir in sorted(p for p in keep.glob("t*") if p.is_dir()):
        for name in ("base", "long-window"):
            fit_path, means_path = tdir / f"{name}_fit.json", tdir / f"{name}_means.nc"
            if not (fit_path.exists() and means_path.exists()):
                continue
            fm = load_model(fit_path)
            doc = json.loads(fit_path.read_text())
            w0, w1 = doc["window"]
            with xr.open_dataset(means_path) as ds:
                t = ds.time.values
                k = (t >= w0 - 1e-12) & (t <= w1 + 1e-12)
                sigs = [str(v) for v in doc["signals"]]
                runs = {sg: ds["runs"].sel(signal=sg).values[:, k] for sg in sigs}
                mean = {sg: ds["mean"].sel(signal=sg).values[k] for sg in sigs}
                white = {sg: float(ds["noise_std"].sel(signal=sg)) for sg in sigs}
            x = fm.params.vector(fm.names)
            # the sensitivities by central differences (relative step 1e-4; 1 ns for t0)
            pb = batch_from_vectors(fm.params, fm.names, np.repeat(x[None], 2 * len(RUN_COLUMNS), 0))
            steps = []
            for j, c in enumerate(RUN_COLUMNS):
                h = 1e-9 if c == "t0" else 1e-4 * abs(float(pb[c][0]))
                pb[c] = np.asarray(pb[c], float).copy()
                pb[c][2 * j] += h
                pb[c][2 * j + 1] -= h
                steps.append(h)
            y = observe(pb, t[k], tuple(sigs), piezo=fm.piezo,
                        z_bk_absolute=fm.z_bk_absolute).y          # (2 C, S, T)
            sens = np.stack([(y[2 * j] - y[2 * j + 1]) / (2 * h)
                             for j, h in enumerate(steps)], -1)     # (S, T, C)
            for i, sg in enumerate(sigs):
                dev = runs[sg] - mean[sg][None]
                n0 = white[sg]
                above = float(np.sum(dev ** 2) - dev.size * n0 ** 2)
                shares, left = [], float("nan")
                for j in range(1, len(RUN_COLUMNS) + 1):
                    A = sens[i, :, :j]
                    coef, *_ = np.linalg.lstsq(A, dev.T, rcond=None)
                    res = dev.T - A @ coef
                    shares.append(1.0 - (float(np.sum(res ** 2)) - res.size * n0 ** 2) / above)
                    left = float(np.mean(res ** 2)) / n0 ** 2
                print(f"| {tdir.name} {name} | {sg} | {np.mean(dev ** 2) / n0 ** 2:.1f} | "
                      + " | ".join(f"{v:.3f}" for v in shares) + f" | {left:.1f} |",
                      flush=True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--timing", action="store_true")
    ap.add_argument("--validate", action="store_true")
    ap.add_argument("--validate-drive", action="store_true",
                    help="a Piezo 1 campaign alone against its prediction")
    ap.add_argument("--truths", type=int, default=1)
    ap.add_argument("--starts", type=int, default=50)
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--log", type=Path, default=Path("design-validation.jsonl"),
                    help="JSON lines, one per campaign, appended as the validation goes")
    ap.add_argument("--from-log", type=Path, default=None,
                    help="only print the tables of a log written earlier")
    ap.add_argument("--run-structure", type=Path, default=None, metavar="DIR",
                    help="how the runs of a kept validation's campaigns differ")
    ap.add_argument("--replicates", type=int, default=1,
                    help="campaigns of each validated design (other seeds): the achieved "
                         "sd's mean over them against the prediction, and the ceiling")
    ap.add_argument("--keep", type=Path, default=None,
                    help="keep the campaigns and fits under this folder; fits found there "
                         "are reused (re-scores the design on the same campaigns)")
    a = ap.parse_args(argv)
    print(machine("scipy"))
    print(f"\ncommand: `.venv/bin/python benchmarks/bench_design.py {' '.join(sys.argv[1:])}`\n")
    if a.timing:
        timing(a.starts)
    if a.run_structure is not None:
        run_structure(a.run_structure)
    if a.from_log is not None:
        tables([json.loads(x) for x in a.from_log.read_text().splitlines() if x.strip()])
    elif a.validate_drive:
        t = time.perf_counter()
        rows = validate_drive(a.truths, a.starts, a.seed, a.log, a.keep)
        print(f"{a.truths} truths, {a.starts} starts per fit, {time.perf_counter() - t:.0f} s\n")
        tables(rows)
    elif a.validate:
        t = time.perf_counter()
        rows = validate(a.truths, a.starts, a.seed, a.log, a.keep, a.replicates)
        print(f"{a.truths} truths, {a.starts} starts per fit, {time.perf_counter() - t:.0f} s\n")
        tables(rows)


if __name__ == "__main__":
    main()
