"""How cleanly the fit's resonance search tells an unmodelled resonance from noise and other
mismatch (docs/fitting.md, "An unmodelled resonance as a nuisance"): per source of
benchmarks/sources.py, the search's detection ratio (the strongest resonance's chi-square
drop over what the campaign's own noise would give) at each stored fit, and how many fits
marginalised one.

    .venv/bin/python benchmarks/bench_resonance.py --cache DIR [--sources white,mode-1,...]
        [--campaigns 20] [--starts 100]

DIR: a ``bench_sources.py --cache`` folder (its fits are not refitted; a missing campaign is
made and fitted as bench_sources does). The search runs on the fit's data residuals without
any projection, at the fit's best point; for a fit that marginalised a resonance that point
is the marginalised one, where the resonance is all in the residuals (a larger ratio than
at detection, which fit.json's ``polish.resonance.ratio`` records).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import sources  # noqa: E402
from bench_sources import run_case  # noqa: E402

from gprm.fit.identify import _data_jacobian  # noqa: E402
from gprm.fit.resonance import DETECT_RATIO, search  # noqa: E402


def one(source: str, seed: int, starts: int, cache: str) -> dict:
    case = run_case(source, seed, starts, cache)
    fit = case.fit
    obj = fit.objective().with_projection(None)
    x = np.asarray(fit.x, float)
    r, J = _data_jacobian(obj, x)
    found = search(obj, x, r, J, obj.prior)
    used = getattr(fit, "resonance", None)
    return {"source": source, "seed": seed,
            "ratio": float(found.ratio) if found is not None else 0.0,
            "frequency": float(found.frequency) if found is not None else np.nan,
            "marginalised": used is not None,
            "detected_ratio": float(used.ratio) if used is not None else np.nan}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", required=True)
    ap.add_argument("--sources", default=",".join(sources.SOURCES))
    ap.add_argument("--campaigns", type=int, default=20)
    ap.add_argument("--seed", type=int, default=5000)
    ap.add_argument("--starts", type=int, default=100)
    a = ap.parse_args()
    print(f"detection ratio threshold {DETECT_RATIO:g}\n")
    print("| source | campaigns | marginalised | ratio at the fit: min / median / max | "
          "at detection: min / median | frequency (kHz), median |")
    print("|---|---|---|---|---|---|")
    for src in a.sources.split(","):
        rows = [one(src, a.seed + i, a.starts, a.cache) for i in range(a.campaigns)]
        ratio = np.array([r["ratio"] for r in rows])
        det = np.array([r["detected_ratio"] for r in rows if r["marginalised"]])
        n = sum(r["marginalised"] for r in rows)
        f = np.nanmedian([r["frequency"] for r in rows]) / 1e3
        dtxt = f"{det.min():.3g} / {np.median(det):.3g}" if det.size else "-"
        print(f"| {src} | {len(rows)} | {n} | {ratio.min():.3g} / {np.median(ratio):.3g} / "
              f"{ratio.max():.3g} | {dtxt} | {f:.1f} |")


if __name__ == "__main__":
    main()
