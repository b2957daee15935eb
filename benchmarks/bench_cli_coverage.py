"""The identification's promise checked through the command line, as a user runs it (issue 12,
"Done when"): for each campaign a truth drawn within +-10 % of Table 3's physical parameters
(written to a TOML file, as the project's CLI chain check does), then

    gprm synth campaign --truth truth.toml --seed S --out campaign.nc
    gprm preprocess campaign.nc --out means.nc
    gprm fit means.nc --seed S --out fit.json          (every default: 1000 starts, sandwich)

and from fit.json: how many of the 21 physical parameters are identified, how many of their
95 % / 68 % intervals contain the truth, and (through the library, on the fit `gprm predict`
reads) how many of the moving point-axes' overshoots in the three scenarios of Sec. 4.2 lie in
the 95 % / 68 % bands (benchmarks/bench_coverage.py's definition).

    .venv/bin/python benchmarks/bench_cli_coverage.py [--campaigns 10] [--seed 5000] [--keep DIR]
        [--workers W | --scheduler ADDRESS]

With ``--workers``/``--scheduler`` the campaigns run as Dask tasks (benchmarks/_studies.py),
each fit then in its task's process (``gprm fit --workers 0``: the fit's result does not depend
on its workers, docs/fitting.md); on a remote cluster ``--keep`` must be a folder every worker
can write.
"""

from __future__ import annotations

import argparse
import json
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import xarray as xr

sys.path.insert(0, "benchmarks")
from bench_coverage import PHYSICAL, prediction_cover  # noqa: E402

from gprm.fit.files import load_fit  # noqa: E402
from gprm.params import load_params, paper  # noqa: E402
from gprm.predict.trajectories import default_times  # noqa: E402


def gprm(folder: Path, *args: str) -> None:
    exe = Path(sys.executable).with_name("gprm")
    r = subprocess.run([str(exe), *args], cwd=folder, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"gprm {' '.join(args)} failed in {folder}:\n{r.stdout}{r.stderr}")


def one_campaign(seed: int, root: str, samples: int, fit_args: tuple[str, ...] = ()) -> dict:
    """The chain on campaign ``seed`` in ``root``/seed<seed>; its scores (a Dask task of
    _studies.map_seeds: the result depends only on the seed)."""
    folder = Path(root) / f"seed{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    rnd = random.Random(seed)
    p = paper()
    (folder / "truth.toml").write_text("[parameters]\n" + "".join(
        f"{n} = {p[n] * (1 + rnd.uniform(-0.1, 0.1))!r}\n" for n in PHYSICAL))
    t = time.perf_counter()
    gprm(folder, "synth", "campaign", "--truth", "truth.toml", "--seed", str(seed), "--out",
         "campaign.nc")
    gprm(folder, "preprocess", "campaign.nc", "--out", "means.nc")
    gprm(folder, "fit", "means.nc", "--seed", str(seed), *fit_args, "--out", "fit.json")
    fit_s = time.perf_counter() - t
    truth = load_params(folder / "truth.toml")
    doc = json.loads((folder / "fit.json").read_text())
    rows = {}
    for n in PHYSICAL:
        e = doc["parameters"][n]
        tv = truth[n]
        rows[n] = {"identified": bool(e["identified"]),
                   "in95": bool(e["interval"]["lower"] <= tv <= e["interval"]["upper"]),
                   "in68": bool(e["interval68"]["lower"] <= tv <= e["interval68"]["upper"])}
    fm = load_fit(folder / "fit.json")
    # the truth's lag in the fit's time axis (preprocessing's truth_shift of x_base): the
    # overshoots are maxima over a fixed window, which the lag moves
    with xr.open_dataset(folder / "means.nc") as means:
        shift = float(means["truth_shift"].sel(signal="x_base"))
    pred = prediction_cover(fm, truth.with_values(t0=truth["t0"] + shift), default_times(),
                            samples, seed)
    return {"seed": seed, "fit_s": round(fit_s, 1), "params": rows, "pred": pred}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--campaigns", type=int, default=10)
    ap.add_argument("--seed", type=int, default=5000)
    ap.add_argument("--samples", type=int, default=200, help="parameter sets per prediction")
    ap.add_argument("--keep", help="keep every campaign's files under this folder")
    ap.add_argument("--json", help="write every campaign's numbers here")
    ap.add_argument("--workers", type=int, default=0,
                    help="campaigns as Dask tasks on a local cluster of this many processes")
    ap.add_argument("--scheduler", default=None,
                    help="campaigns as Dask tasks on the cluster of this scheduler address")
    a = ap.parse_args(argv)
    from _machine import machine
    from _studies import map_seeds

    t0 = time.perf_counter()
    tasks = bool(a.scheduler) or a.workers > 0
    with tempfile.TemporaryDirectory() as tmp:
        root = str(Path(a.keep).resolve()) if a.keep else tmp
        out = map_seeds(one_campaign, range(a.seed, a.seed + a.campaigns),
                        scheduler=a.scheduler, workers=a.workers, root=root,
                        samples=a.samples, fit_args=("--workers", "0") if tasks else ())
    for r in out:
        ident = [n for n, v in r["params"].items() if v["identified"]]
        miss = [n for n in ident if not r["params"][n]["in95"]]
        print(f"seed {r['seed']}: {len(ident)} identified, missed {miss or 'none'}, overshoots "
              f"{r['pred']['in95']}/{r['pred']['n']} in 95 % bands ({r['fit_s']} s to fit)",
              file=sys.stderr, flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1))
    n_id = [sum(v["identified"] for v in r["params"].values()) for r in out]
    i95 = sum(v["in95"] for r in out for v in r["params"].values() if v["identified"])
    i68 = sum(v["in68"] for r in out for v in r["params"].values() if v["identified"])
    p95 = sum(r["pred"]["in95"] for r in out)
    p68 = sum(r["pred"]["in68"] for r in out)
    pn = sum(r["pred"]["n"] for r in out)
    ni = sum(n_id)
    where = (f"scheduler {a.scheduler}" if a.scheduler else
             f"{a.workers} Dask workers" if a.workers > 0 else "in process")
    print(f"{a.campaigns} campaigns through the CLI, seeds {a.seed}..{a.seed + a.campaigns - 1} "
          f"({time.perf_counter() - t0:.0f} s, {where}; {machine()})")
    print("| identified / campaign (min) | identified 95 % | identified 68 % | overshoots 95 % "
          "| overshoots 68 % |\n|---|---|---|---|---|")
    print(f"| {np.mean(n_id):.1f} ({min(n_id)}) | {i95 / ni:.1%} ({i95}/{ni}) | "
          f"{i68 / ni:.1%} ({i68}/{ni}) | {p95 / pn:.1%} ({p95}/{pn}) | "
          f"{p68 / pn:.1%} ({p68}/{pn}) |")


if __name__ == "__main__":
    main()
