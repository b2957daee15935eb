"""Which parameters lean on the prior (issue 21; docs/fitting.md, "Parameters that lean on the
prior (stop 48)"): per physical parameter, over the cached fits of benchmarks/bench_sources.py,
how often its interval is narrow (sd in u below gprm.fit.uncertainty.CONTRACTION of the
prior's), how often it is narrow and at least PRIOR_SHARE of its variance the prior's (it
leans on the prior, not identified), the prior's share among the narrow ones (percentiles
and largest), and how often the leaning ones' 95 % and 68 % intervals hold the truth.

    .venv/bin/python benchmarks/bench_prior_share.py --cache DIR [--sources white,sim2]
        [--campaigns 20] [--seed 5000] [--starts 100]

Read from each cached fit's own uncertainty (the default method's contraction, its variance
shares ``details["sources"]["prior"]`` and its intervals), so it takes a minute: the rule of
stop 48 changes which parameters count, not these numbers.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_sources as bs  # noqa: E402

from gprm.fit.uncertainty import CONTRACTION, PRIOR_SHARE  # noqa: E402


def shares(case) -> list[dict]:
    """One cached fit: per physical parameter with a truth, its contraction, prior share and
    whether its 95 % / 68 % intervals hold the truth."""
    u = case.fit.uncertainty
    share = np.asarray(u.details["sources"]["prior"], float)
    out = []
    for k, n in enumerate(u.names):
        if n not in case.truth:
            continue
        v = case.truth[n]
        out.append({"name": n, "contraction": float(u.contraction[k]), "share": float(share[k]),
                    "in95": bool(u.lower95[k] <= v <= u.upper95[k]),
                    "in68": bool(u.lower68[k] <= v <= u.upper68[k])})
    return out


def table(rows: list[dict]) -> str:
    by = defaultdict(list)
    for r in rows:
        by[r["name"]].append(r)
    out = ["| parameter | narrow (campaigns) | leaning on the prior | prior share of the narrow: "
           "10 / 50 / 90 %, largest | leaning: truth in 95 %, 68 % |", "|---|---|---|---|---|"]
    for name, rr in by.items():
        narrow = [r for r in rr if r["contraction"] < CONTRACTION]
        if not narrow:
            continue
        lean = [r for r in narrow if r["share"] >= PRIOR_SHARE]
        s = np.array([r["share"] for r in narrow])
        q = np.percentile(s, [10, 50, 90])
        cover = (f"{sum(r['in95'] for r in lean)} / {len(lean)}, "
                 f"{sum(r['in68'] for r in lean)} / {len(lean)}" if lean else "-")
        out.append(f"| {name} | {len(narrow)} | {len(lean)} | {q[0]:.2f} / {q[1]:.2f} / "
                   f"{q[2]:.2f}, {s.max():.2f} | {cover} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    bs.cached_study_arguments(ap)
    a = ap.parse_args(argv)
    rows = []
    for src in [s for s in a.sources.split(",") if s]:
        for k in range(a.campaigns):
            path = Path(a.cache) / f"{src}-{a.seed + k}-{a.starts}.pkl"
            if not path.exists():
                # this study only reads: a fit the cache lacks is not made here
                print(f"not in the cache, skipped: {path}", file=sys.stderr)
                continue
            rows += shares(bs.run_case(src, a.seed + k, a.starts, a.cache))
    print(f"{len(rows)} parameter fits; narrow: sd below {CONTRACTION} of the prior's; "
          f"leaning: narrow and the prior's share at least {PRIOR_SHARE}")
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
