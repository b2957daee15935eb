"""Benchmark of campaign preprocessing (issue 3), and of generating the synthetic campaign.

    .venv/bin/python benchmarks/bench_preprocess.py [--quick] [--repeat N]

Preprocessing (``gprm.campaign.preprocess.preprocess``, library call, file reading excluded)
of a full campaign: 10 positions x (10 actuated + 5 noise) runs x 301 samples (0..1.5 ms at
200 kHz), the default of ``gprm synth campaign`` (seed 0). Reported: the best and the median
of N repetitions (5; --quick 2), and that divided by the 10 positions. Also timed once:
loading the campaign NetCDF (validation included), importing it from the CSV directory layout,
and generating the campaign (with and without the nonlinear correction).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _machine import machine


def timed(fn, n):
    out, ts = None, []
    for _ in range(n):
        t0 = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t0)
    return out, np.array(ts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--repeat", type=int, default=None)
    args = ap.parse_args()
    n = args.repeat or (2 if args.quick else 5)

    from gprm.campaign.files import write_campaign_dir
    from gprm.campaign.files import load_campaign, write_campaign
    from gprm.campaign.preprocess import preprocess
    from gprm.campaign.synth import SynthConfig, synth_campaign

    ds, t_gen = timed(lambda: synth_campaign(seed=0), 1)
    _, t_gen_lin = timed(lambda: synth_campaign(seed=0, config=SynthConfig(nonlinear=False)), 1)
    P, R, Nn, T = (ds.sizes["position"], ds.sizes["run"], ds.sizes["noise_run"],
                   ds.sizes["time"])
    with tempfile.TemporaryDirectory() as tmp:
        f = Path(tmp) / "c.nc"
        write_campaign(ds, f)
        write_campaign_dir(ds, Path(tmp) / "csv")
        camp, t_load = timed(lambda: load_campaign(f), 1)
        _, t_csv = timed(lambda: load_campaign(Path(tmp) / "csv"), 1)
    preprocess(camp)  # warm-up (imports, caches)
    ms, t_pre = timed(lambda: preprocess(camp), n)

    cmd = "python benchmarks/bench_preprocess.py" + (" --quick" if args.quick else "") + (
        f" --repeat {args.repeat}" if args.repeat else "")
    print("## Campaign preprocessing (issue 3)\n")
    print(f"Command: `.venv/bin/{cmd}`\n")
    print(machine("scipy", "xarray"))
    print(f"- campaign: {P} positions x ({R} actuated + {Nn} noise) runs x {T} samples "
          f"(0..{ds['time'].values[-1] * 1e3:.1f} ms at {ds.attrs['sample_rate'] / 1e3:g} kHz), "
          "synthetic, seed 0\n")
    print("| step | time | per position |")
    print("|---|---|---|")
    print(f"| preprocess (sync, mean/std, align, Table 1, truth comparison), best of {n} | "
          f"{t_pre.min() * 1e3:.0f} ms | {t_pre.min() / P * 1e3:.1f} ms |")
    print(f"| preprocess, median of {n} | {np.median(t_pre) * 1e3:.0f} ms | "
          f"{np.median(t_pre) / P * 1e3:.1f} ms |")
    print(f"| load + validate campaign NetCDF | {t_load[0] * 1e3:.0f} ms | |")
    print(f"| import CSV directory ({P * (R + Nn) + ds.sizes['vrun']} files) | "
          f"{t_csv[0] * 1e3:.0f} ms | |")
    print(f"| generate the campaign (`gprm synth campaign` default, nonlinear correction "
          f"included) | {t_gen[0]:.2f} s | |")
    print(f"| generate without the nonlinear correction | {t_gen_lin[0]:.2f} s | |")
    print(f"\nTarget: well under 1 s per position; measured {t_pre.min() / P * 1e3:.0f} ms "
          "per position.")


if __name__ == "__main__":
    sys.exit(main())
