"""Benchmark of command start-up (issue 15 item 7): wall-clock time of ``gprm --help`` and of
``gprm <command> --help`` for every command, each in a fresh interpreter, as a user types it.

    .venv/bin/python benchmarks/bench_startup.py [--quick] [--repeat N] [--gprm PATH]

Reported per command: best and median of N runs (5; --quick 2) in seconds. ``--help`` parses
the command line and prints, which is all a command does before its own work starts; the
target is under 1 s. Also listed: which heavy libraries a bare ``import gprm.cli`` loads (none
expected; tests/io/test_startup.py checks it).
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

from _machine import machine

COMMANDS = ["", "params", "simulate", "preprocess", "fit", "show", "predict", "impact",
            "report", "demo", "synth campaign", "synth telemetry"]
HEAVY = ["numpy", "scipy", "xarray", "pint", "sympy", "matplotlib", "dask", "distributed",
         "netCDF4", "pandas"]


def gprm_exe(given: str | None) -> list[str]:
    if given:
        return [given]
    here = Path(sys.executable).with_name("gprm")
    if here.exists():
        return [str(here)]
    found = shutil.which("gprm")
    return [found] if found else [sys.executable, "-m", "gprm.cli"]


def time_once(cmd: list[str]) -> float | None:
    t0 = time.perf_counter()
    r = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    dt = time.perf_counter() - t0
    if r.returncode != 0 and "No such command" in r.stderr:
        return None                       # an older gprm without this command
    if r.returncode != 0:
        sys.exit(f"bench_startup: {' '.join(cmd)} failed: {r.stderr.strip()[-300:]}")
    return dt


def heavy_loaded() -> list[str]:
    code = ("import sys, gprm.cli; print(' '.join(m for m in %r if m in sys.modules))"
            % (HEAVY,))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=dict(os.environ), check=True).stdout.split()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--repeat", type=int, default=None)
    ap.add_argument("--gprm", default=None, help="the gprm executable (default: next to "
                    "this Python, else on PATH)")
    a = ap.parse_args()
    n = a.repeat or (2 if a.quick else 5)
    exe = gprm_exe(a.gprm)
    print("## Start-up (bench_startup.py)\n")
    print(machine("typer", "click"))
    print(f"- executable: `{' '.join(exe)}`, {n} runs each\n")
    print("| command | best, s | median, s |")
    print("|---|---:|---:|")
    worst = 0.0
    for c in COMMANDS:
        cmd = exe + (c.split() if c else []) + ["--help"]
        ts = [time_once(cmd) for _ in range(n)]
        if None in ts:
            print(f"| `gprm {c} --help` | n/a | n/a |")
            continue
        worst = max(worst, statistics.median(ts))
        print(f"| `gprm {c + ' ' if c else ''}--help` | {min(ts):.3f} | "
              f"{statistics.median(ts):.3f} |")
    loaded = heavy_loaded()
    print(f"\n- slowest median: {worst:.3f} s (target < 1 s: "
          f"{'met' if worst < 1 else 'NOT met'})")
    print(f"- heavy libraries loaded by `import gprm.cli`: {', '.join(loaded) or 'none'}")


if __name__ == "__main__":
    main()
