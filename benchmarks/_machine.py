"""What every benchmark prints about the machine, and its best-of-n timer (shared by the
``bench_*.py`` scripts, which run from the repository root as ``.venv/bin/python
benchmarks/bench_<stage>.py``)."""

from __future__ import annotations

import importlib
import os
import platform
import time


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine(*packages: str) -> str:
    """Markdown bullet lines: cores, CPU, load average, Python and package versions."""
    try:
        load = f"{os.getloadavg()[0]:.2f}"
    except OSError:
        load = "?"
    versions = ", ".join(f"{p} {importlib.import_module(p).__version__}"
                         for p in dict.fromkeys(("numpy",) + tuple(packages)))
    threads = os.environ.get("OMP_NUM_THREADS", "unset")
    return (f"- machine: {os.cpu_count()} cores (`nproc`), {cpu_model()}; load average at "
            f"start {load}\n- Python {platform.python_version()}, {versions}; "
            f"OMP_NUM_THREADS={threads}")


def best_time(fn, repeat: int):
    """(best wall time over ``repeat`` calls, the last call's result)."""
    best, out = float("inf"), None
    for _ in range(max(1, int(repeat))):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out
