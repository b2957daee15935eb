"""Benchmark of the prediction stage: `.venv/bin/python benchmarks/bench_predict.py [--quick]`.

Prints a markdown section (machine, versions, command, timings)."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time


from _machine import best_time, machine


def timed(fn, repeat):
    return best_time(fn, repeat)[0]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    from gprm.fit.files import paper_model
    from gprm.predict.core import predict
    from gprm.predict.energy import energy_check
    from gprm.simulate.kinematics import body_motion, named_points, point_motion
    from gprm.predict.risk import impact_risk
    from gprm.predict.trajectories import default_times, predict_trajectories
    from gprm.predict.whatif import whatif

    fm = paper_model()
    t = default_times()  # 0.95..1.2 ms at 1 MHz: 251 times
    n = 200 if a.quick else 1000
    rep = 1 if a.quick else 3
    pb = fm.sample(n, 0)
    pts = named_points(pb)

    def kin():
        m = body_motion(pb, t)
        for p in ("com", "M_xz", "M_yz", "tip_edge"):
            point_motion(m, pts[p], relative=True)

    rows = [
        (f"body_motion + 4 points, {n} sets x {t.size} times", timed(kin, rep)),
        (f"predict_trajectories, {n // 5} samples + linear band", timed(
            lambda: predict_trajectories(fm, t, samples=n // 5), rep)),
        (f"energy_check (model only), {n // 5} samples", timed(
            lambda: energy_check(fm, samples=n // 5), rep)),
        ("whatif, 3 standard scenarios, 100 samples", timed(
            lambda: whatif(fm, samples=100), rep)),
        (f"impact_risk, {n // 2} samples", timed(
            lambda: impact_risk(fm, 2e-6, 0.5e-6, times=t, samples=n // 2), rep)),
        ("predict() all products, 200 samples", timed(
            lambda: predict(fm, times=t, samples=200, gap=2e-6, gap_std=0.5e-6), rep)),
    ]
    with tempfile.TemporaryDirectory() as d:
        cmd = [os.path.join(os.path.dirname(sys.executable), "gprm"), "predict", "paper",
               "--out", os.path.join(d, "p.nc"), "--samples", "200", "--gap", "2um",
               "--whatif", os.path.join(d, "w.json")]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True)
        rows.append(("`gprm predict paper --samples 200 --gap 2um --whatif` (process)",
                     time.perf_counter() - t0))
    print("## predict\n")
    print(machine())
    print(f"- command: `.venv/bin/python benchmarks/bench_predict.py"
          f"{' --quick' if a.quick else ''}` (best of {rep})\n")
    print("| task | seconds |\n|---|---|")
    for name, s in rows:
        print(f"| {name} | {s:.2f} |")


if __name__ == "__main__":
    main()
