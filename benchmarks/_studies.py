"""Studies over many campaigns as Dask tasks (issue 24, item 5): one task per campaign seed,
on a local cluster of ``workers`` processes or on an existing scheduler (``--scheduler
ADDRESS``: any Dask cluster, e.g. one dask-jobqueue started on SLURM or PBS; recipe in
docs/fitting.md), or in this process when neither is given.

A campaign's result depends only on its seed: every task runs with one BLAS thread
(:func:`gprm.fit.engine.single_thread_blas`, also in this process), and the results are
returned in the order of the seeds, whatever the number of workers or the order they finish.
"""

from __future__ import annotations

import functools
import sys
from pathlib import Path
from typing import Callable


def _run_one(fn: Callable, kwargs: dict, seed: int):
    from gprm.fit.engine import single_thread_blas

    with single_thread_blas():
        return fn(seed, **kwargs)


def map_seeds(fn: Callable, seeds, *, scheduler: str | None = None, workers: int = 0,
              progress: bool = True, labels=None, **kwargs) -> list:
    """``[fn(seed, **kwargs) for seed in seeds]``, as Dask tasks when ``scheduler`` or
    ``workers`` > 0 is given (``fn`` and its arguments must pickle; functions of a script
    travel by value). ``labels``: what the progress lines call each task (default
    ``seed S``)."""
    seeds = [int(s) for s in seeds]
    names = list(labels) if labels is not None else [f"seed {s}" for s in seeds]
    task = functools.partial(_run_one, fn, dict(kwargs))
    if not scheduler and workers <= 0:
        out = []
        for i, s in enumerate(seeds):
            out.append(task(s))
            if progress:
                print(f"campaign {i + 1}/{len(seeds)} ({names[i]}) done", file=sys.stderr,
                      flush=True)
        return out
    import cloudpickle
    from distributed import Client, as_completed

    from gprm.fit.engine import local_cluster

    # the benchmarks' modules (this one, the study's, those it imports) are not importable in
    # the workers (benchmarks/ is not a package): they travel by value
    here = Path(__file__).resolve().parent
    for name, mod in list(sys.modules.items()):
        f = getattr(mod, "__file__", None)
        if name != "__main__" and f and Path(f).resolve().parent == here:
            cloudpickle.register_pickle_by_value(mod)
    mod = sys.modules.get(getattr(fn, "__module__", "") or "")
    if mod is not None and mod.__name__ not in ("__main__",) and not mod.__name__.startswith(
            "gprm"):
        cloudpickle.register_pickle_by_value(mod)
    cluster = None
    if scheduler:
        client = Client(scheduler)
    else:
        cluster = local_cluster(int(workers))
        client = Client(cluster, security=cluster.security)
    try:
        futs = client.map(task, seeds, pure=False)
        index = {f.key: i for i, f in enumerate(futs)}
        out: list = [None] * len(seeds)
        for n, fut in enumerate(as_completed(futs), 1):
            i = index[fut.key]
            out[i] = fut.result()
            if progress:
                print(f"campaign {n}/{len(seeds)} ({names[i]}) done", file=sys.stderr,
                      flush=True)
        return out
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
