"""The time shift the synchronisation hides from the runs' spread (docs/fitting.md, "The time
shift the synchronisation hides"): for a few fixed truths of the ``white`` source (the exact
model, white noise), many campaigns that differ only in their noise, each preprocessed and
its runs moved through the model as the fit moves them; the estimator linearised once at
the truth (the cached fit of bench_sources.py, its lags and offsets fitted at the truth).

Per parameter, in units of the sd white noise averaged over the runs would give:

- ``actual``: the spread over the campaigns of B (mean - truth) / sigma, the estimate's
  error that the data's noise makes (the truth on the data's aligned axis, ``truth_mean``);
- ``runs``: the root-mean of the variance the runs' spread predicts for it (the default's
  runs part);
- ``runs + sync``: that plus the timing term of ``sync_timing_sd`` for every signal.

    .venv/bin/python benchmarks/bench_sync_timing.py --seeds 5003,5007,5019 --noise 150 \\
        --cache DIR
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_sources as bs  # noqa: E402
import sources  # noqa: E402
from bench_linearisation import truth_point  # noqa: E402

from gprm.campaign.preprocess import PreprocessConfig, preprocess  # noqa: E402
from gprm.campaign.synth import SynthConfig, synth_campaign  # noqa: E402
from gprm.fit import subsample  # noqa: E402
from gprm.fit.methods import state_of  # noqa: E402
from gprm.fit.objective import fit_data_from_means  # noqa: E402
from gprm.fit.sandwich import _estimator, run_deviations, time_derivative  # noqa: E402

PARAMS = ("m3", "m4", "k_lr", "m1", "k_Bx", "d2", "c_Bx", "t0", "t1", "dt_x_head",
          "dt_y_base", "dt_y_head")


def one_truth(seed: int, n_noise: int, cache: str, starts: int) -> dict:
    case = bs.run_case("white", seed, starts, cache)
    st = state_of(case.fit)
    obj, prior, names = st.obj, st.obj.prior, list(case.fit.names)
    d = obj.data
    xt = truth_point(case)
    obs = obj.model(xt[None], jacobian=True)
    sigma = d.sigma
    J = (obs.dy[0] / sigma[:, :, None]).reshape(d.n_obs, -1)
    Ju, Hinv = _estimator(xt, J, prior)
    B = Hinv @ Ju.T                                                     # (P, N)
    S = len(d.signals)
    Bs = B.reshape(B.shape[0], S, -1)
    ydot = time_derivative(obj, xt, J, obs.y[0])
    bt = np.stack([Bs[:, s, :] @ (ydot[s] / sigma[s]) for s in range(S)])   # (S, P)
    cfg = replace(SynthConfig(), **sources._OFF)
    R = cfg.n_runs
    theory = np.sqrt(np.sum(B ** 2 * ((cfg.noise_white / np.sqrt(R)) / sigma).reshape(-1)
                            [None, :] ** 2, axis=1))
    truth = sources.draw_truth(seed)
    err, runs_var, sync_var = [], [], []
    for k in range(n_noise):
        ms = preprocess(synth_campaign(truth, seed=100000 + k, config=cfg), PreprocessConfig())
        fd = fit_data_from_means(ms.to_dataset(), window=d.window, sigma=d.sigma_kind,
                                 sigma_pool=d.sigma_pool)
        fc = subsample.corrected(fd, subsample.run_corrections(obj, xt, fd.sync_remainder))
        si = [list(ms.signals).index(s) for s in d.signals]
        tsel = np.isin(np.round(ms.time, 12), np.round(fd.time, 12))
        err.append(B @ ((fc.values - ms.truth_mean[si][:, tsel]) / sigma).reshape(-1))
        G = run_deviations(fc.runs, sigma).transpose(1, 0, 2).reshape(R, -1) @ B.T
        runs_var.append((G ** 2).sum(axis=0) / (R - 1) / R)
        sync_var.append(np.sum((fd.sync_timing_sd[:, None] * bt) ** 2, axis=0))
    idx = [names.index(p) for p in PARAMS]
    err, runs_var, sync_var = (np.asarray(v)[:, idx] for v in (err, runs_var, sync_var))
    th = theory[idx]
    return {"actual": err.std(axis=0) / th, "runs": np.sqrt(runs_var.mean(axis=0)) / th,
            "runs + sync": np.sqrt(runs_var.mean(axis=0) + sync_var.mean(axis=0)) / th,
            "sync_ns": 1e9 * fd.sync_timing_sd}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="5003,5007,5019")
    ap.add_argument("--noise", type=int, default=150)
    ap.add_argument("--starts", type=int, default=100)
    ap.add_argument("--cache", required=True)
    a = ap.parse_args(argv)
    t = time.perf_counter()
    print("| truth (seed) | sync_timing_sd per signal (ns) | sd | " + " | ".join(PARAMS) + " |")
    print("|---|---|---|" + "---|" * len(PARAMS))
    for seed in (int(s) for s in a.seeds.split(",") if s):
        res = one_truth(seed, a.noise, a.cache, a.starts)
        for k in ("actual", "runs", "runs + sync"):
            sync = ", ".join(f"{v:.1f}" for v in res["sync_ns"]) if k == "actual" else ""
            print(f"| {seed if k == 'actual' else ''} | {sync} | {k} | "
                  + " | ".join(f"{v:.2f}" for v in res[k]) + " |", flush=True)
    print(f"\n({a.noise} campaigns per truth, {time.perf_counter() - t:.0f} s; cache {a.cache})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
