"""The lags' recovery on gprm's generator, with and without the unmodelled resonance
marginalised (a diagnosis, issue 21): t0, t1 and the alignment offsets dt_x_head, dt_y_base,
dt_y_head are not scored by bench_sources.py (their truth is the generator's lag plus the
alignment's offset), so this scores them as the demo's summary does
(`gprm.report.summary.truth_recovery` on `truth_for_fit`), next to the x-plane B support.

    .venv/bin/python benchmarks/bench_lags.py [--seeds 0-9] [--starts 30] [--source NAME]

For each seed: `synth_campaign(seed)` (the demo's campaign for seed 0; ``--source``: a
gprm-generator source of benchmarks/sources.py instead, e.g. ``mode-1``, its truth drawn
within +-10 % of Table 3), `preprocess`, `run_fit` with ``--starts`` starts, once
with the resonance search (the default) and once without (``FitOptions(resonance=False)``);
prints z = (fit - truth) / sd per parameter and, per variant, the mean and rms z and how many
truths lie outside the 95 % interval.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gprm.campaign.files import write_means
from gprm.campaign.preprocess import preprocess
from gprm.campaign.synth import synth_campaign
from gprm.fit.api import FitOptions, run_fit
from gprm.fit.files import write_fit
from gprm.report.summary import truth_for_fit, truth_from_means, truth_recovery

sys.path.insert(0, str(Path(__file__).resolve().parent))

NAMES = ("t0", "t1", "dt_x_head", "dt_y_base", "dt_y_head", "k_Bx", "c_Bx", "d2")


def seeds_of(text: str) -> list[int]:
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(s) for s in text.split(",")]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="0-9")
    ap.add_argument("--starts", type=int, default=30)
    ap.add_argument("--source", default=None,
                    help="a gprm-generator source of benchmarks/sources.py (not sim2)")
    a = ap.parse_args()
    print(f"- command: `.venv/bin/python benchmarks/bench_lags.py {' '.join(sys.argv[1:])}`")
    z: dict[bool, dict[str, list[float]]] = {True: {}, False: {}}
    out: dict[bool, dict[str, int]] = {True: {}, False: {}}
    t = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for s in seeds_of(a.seeds):
            d = Path(tmp) / str(s)
            d.mkdir()
            if a.source:
                import sources

                camp, _ = sources.make(a.source, s)
            else:
                camp = synth_campaign(seed=s)
            write_means(preprocess(camp), d / "means.nc")
            for res_on in (True, False):
                res = run_fit(str(d / "means.nc"), FitOptions(starts=a.starts, resonance=res_on),
                              workers=0)
                write_fit(res, d / "fit.json")
                fit = json.loads((d / "fit.json").read_text())
                truth = truth_for_fit(truth_from_means(d), fit)
                tr = truth_recovery(fit, truth)
                row = []
                for n in NAMES:
                    if n in tr["z"]:
                        z[res_on].setdefault(n, []).append(tr["z"][n])
                        iv = fit["parameters"][n]["interval"]
                        miss = not (iv["lower"] <= truth[n] <= iv["upper"])
                        out[res_on][n] = out[res_on].get(n, 0) + miss
                        row.append(f"{n} {tr['z'][n]:+.2f}{'*' if miss else ''}")
                print(f"seed {s}, resonance {'on ' if res_on else 'off'}"
                      f" ({'found' if res.resonance is not None else 'none'}): "
                      + ", ".join(row), flush=True)
    print(f"\n{time.perf_counter() - t:.0f} s; * = truth outside the 95 % interval\n")
    print("| parameter | resonance | campaigns identified | mean z | rms z | outside 95 % |\n"
          "|---|---|---|---|---|---|")
    for n in NAMES:
        for res_on in (True, False):
            v = np.array(z[res_on].get(n, []))
            if v.size:
                print(f"| {n} | {'marginalised' if res_on else 'off'} | {v.size} | "
                      f"{v.mean():+.2f} | {np.sqrt(np.mean(v ** 2)):.2f} | "
                      f"{out[res_on].get(n, 0)} |")


if __name__ == "__main__":
    main()
