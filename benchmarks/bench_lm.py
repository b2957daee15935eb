"""Benchmark of the standalone Levenberg-Marquardt (issue 24, item 1): the 105 Moré-Garbow-
Hillstrom runs (35 problems from x0, 10 x0, 100 x0; ``tests/fit/mgh.py``) and the 54 NIST StRD
runs (27 problems x 2 official starts; ``tests/fit/nist.py``), exact Jacobians, for

- ``gprm``: ``gprm.fit.levenberg_marquardt`` with its defaults;
- ``gprm-previous``: the previous defaults (``--previous``; Algorithm 1 with MINPACK scaling,
  geodesic acceleration, ftol 1e-12, 1000 iterations and the trust-region fallback run: the
  same function called with :data:`PREVIOUS`; it shares this version's evaluation of the
  Jacobian without re-evaluating the residuals, so it counts fewer residual evaluations than
  the previous code did -- the docstring's ``git archive`` line measures that);
- ``--mechanisms``: the previous options taken apart (:data:`VARIANTS`);
- ``minpack``: scipy ``least_squares(method="lm")`` (MINPACK's lmder);
- ``trf``: scipy ``least_squares(method="trf")``;

all with ``max_nfev`` = 10,000 and the solvers' default tolerances (1e-8 for SciPy; gprm's own
defaults). A MGH run is *solved* when its final sum of squares is within 1e-4 relative
(+1e-10 absolute) of a minimum the paper lists (``mgh.Problem.solved``); a NIST run when the
certified parameters are reached to 4 digits. Evaluations are counted on the runs that all
solvers shown solve.

    PYTHONPATH=src .venv/bin/python benchmarks/bench_lm.py [--previous] [--runs] [--mechanisms]

The code of an earlier commit runs the same comparison (its own defaults and budget):

    mkdir -p /tmp/old && git archive b4d0f0d src | tar -x -C /tmp/old && \
        PYTHONPATH=/tmp/old/src .venv/bin/python benchmarks/bench_lm.py
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from _machine import machine

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "fit"))

MAX_NFEV = 10_000
#: the previous standalone defaults (ed5f611): Algorithm 1, MINPACK scaling, geodesic
#: acceleration, ftol 1e-12, 1000 iterations, then the trust-region run from x0
PREVIOUS = dict(control="algorithm1", geodesic=True, fallback=True, ftol=1e-12, xtol=1e-15,
                gtol=0.0, max_nfev=10 ** 9, max_iter=1000)
#: --mechanisms: the previous options taken apart one mechanism at a time, up to the default
VARIANTS = {
    "gprm": {},
    "gprm-previous": PREVIOUS,
    "previous, no fallback": dict(PREVIOUS, fallback=False),
    "previous, no fallback, no geodesic": dict(PREVIOUS, fallback=False, geodesic=False),
    "trust region, bound 100 |D x0|, no gtol": dict(step_bound=100.0, gtol=0.0),
    "trust region, bound 1 |D x0|, no gtol": dict(gtol=0.0),
}


def solve(method: str, res, x0, jac):
    """(final sum of squares, x, nfev, njev, status text) of one run."""
    from scipy.optimize import least_squares

    from gprm.fit import levenberg_marquardt

    with np.errstate(all="ignore"):
        if method in ("minpack", "trf"):
            try:
                s = least_squares(res, x0, jac, method="lm" if method == "minpack" else "trf",
                                  max_nfev=MAX_NFEV)
            except Exception as exc:                     # noqa: BLE001 -- recorded as failed
                return np.inf, x0, 0, 0, f"error: {exc}"
            return float(2 * s.cost), s.x, int(s.nfev), int(s.njev or 0), str(s.status)
        import inspect

        # an earlier commit's code (the git archive line of the docstring) has no max_nfev:
        # its own budget applies
        kw = ({"max_nfev": MAX_NFEV}
              if "max_nfev" in inspect.signature(levenberg_marquardt).parameters else {})
        kw.update(VARIANTS[method])
        r = levenberg_marquardt(res, x0, jac, **kw)
        return float(r.chi2), r.x, int(r.nfev), int(r.njev), r.status


def mgh_table(methods) -> tuple[str, dict]:
    import mgh

    out = {m: [] for m in methods}
    for p, factor, x0 in mgh.runs():
        for m in methods:
            t0 = time.perf_counter()
            F, x, nfev, njev, st = solve(m, p.residuals, x0, p.jacobian)
            out[m].append(dict(problem=p.number, name=p.name, factor=factor, F=F,
                               solved=p.solved(F), nfev=nfev, njev=njev, status=st,
                               time=time.perf_counter() - t0))
    return summary(out, 105), out


def nist_table(methods) -> tuple[str, dict]:
    import nist

    out = {m: [] for m in methods}
    for name in nist.names():
        p = nist.load(name)
        for s in (0, 1):
            for m in methods:
                t0 = time.perf_counter()
                F, x, nfev, njev, st = solve(m, p.residuals, p.starts[s], p.jacobian)
                ok = bool(np.all(np.isfinite(x))) and nist.digits(x, p.certified) >= 4.0
                out[m].append(dict(problem=name, factor=s + 1, F=F, solved=ok, nfev=nfev,
                                   njev=njev, status=st, time=time.perf_counter() - t0))
    return summary(out, 54), out


def summary(out: dict, n: int) -> str:
    methods = list(out)
    common = np.all([[r["solved"] for r in out[m]] for m in methods], axis=0)
    lines = [f"| solver | solved (of {n}) | nfev on the {int(common.sum())} commonly solved "
             "| njev there | nfev + njev there | time, s (all runs) |", "|---|---:|---:|---:|---:|---:|"]
    for m in methods:
        rows = out[m]
        nfev = sum(r["nfev"] for r, c in zip(rows, common) if c)
        njev = sum(r["njev"] for r, c in zip(rows, common) if c)
        lines.append(f"| {m} | {sum(r['solved'] for r in rows)} | {nfev:,} | {njev:,} | "
                     f"{nfev + njev:,} | {sum(r['time'] for r in rows):.1f} |")
    return "\n".join(lines)


def run_lines(out: dict) -> str:
    methods = list(out)
    lines = ["| run | " + " | ".join(f"{m} F / nfev / njev" for m in methods) + " |",
             "|---|" + "---|" * len(methods)]
    for i, r0 in enumerate(out[methods[0]]):
        cells = []
        for m in methods:
            r = out[m][i]
            mark = "" if r["solved"] else " **x**"
            cells.append(f"{r['F']:.4g} / {r['nfev']} / {r['njev']}{mark}")
        lines.append(f"| {r0['problem']} x{r0['factor']:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--previous", action="store_true",
                    help="add the previous optimizer (as at ed5f611) as a column")
    ap.add_argument("--runs", action="store_true", help="print every run")
    ap.add_argument("--mechanisms", action="store_true",
                    help="the previous options taken apart, one mechanism at a time (MGH only)")
    args = ap.parse_args(argv)
    methods = ["gprm"] + (["gprm-previous"] if args.previous else []) + ["minpack", "trf"]
    print(machine())
    print(f"command: {' '.join(sys.argv)}\n")
    if args.mechanisms:
        t, _ = mgh_table(list(VARIANTS)[1:] + ["gprm", "minpack"])
        print("## Moré-Garbow-Hillstrom, 105 runs: mechanisms\n")
        print(t)
        return
    for title, table in (("Moré-Garbow-Hillstrom, 105 runs", mgh_table),
                         ("NIST StRD, 54 runs", nist_table)):
        t, out = table(methods)
        print(f"## {title}\n")
        print(t)
        if args.runs:
            print()
            print(run_lines(out))
        print()


if __name__ == "__main__":
    main()
