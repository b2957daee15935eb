"""Execution engine of the multi-start identification: starts are drawn once from the seed
(:mod:`gprm.fit.starts`), split into chunks, and each chunk runs Levenberg-Marquardt in
lock-step (one batched simulation per iteration serves the whole chunk). Chunks are
independent tasks: they run in-process, on local worker processes (a process pool; a local
Dask cluster where a dashboard is asked for) or on an existing Dask cluster (one BLAS thread
each), are checkpointed as they finish, and a rerun with the same inputs resumes from the checkpoints.
Because the starts and the chunking depend only on the seed and the options, results are
identical whatever the number of workers.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import inspect
import json
import os
import re
import sys
import threading
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from gprm._io import atomic_path, write_text_atomic
from gprm.errors import GprmInputError
from gprm.fit.lm import levenberg_marquardt_batch
from gprm.fit.objective import Objective
from gprm.fit.starts import (LMOptions, MultiStartOptions, StartsOutcome, draw_starts,
                             make_stop_rule, resample_invalid)


# ----------------------------------------------------------------------------- one chunk

def _openblas_thread_setters() -> list[tuple[Any, Any]]:
    """(set, get) functions of every OpenBLAS loaded in this process (numpy's, scipy's)."""
    out: list[tuple[Any, Any]] = []
    try:
        with open("/proc/self/maps") as fh:
            paths = {ln.split()[-1] for ln in fh if "openblas" in ln.lower() and "/" in ln}
    except OSError:
        return out
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for prefix in ("scipy_openblas", "openblas"):
            for suffix in ("64_", ""):
                set_n = getattr(lib, f"{prefix}_set_num_threads{suffix}", None)
                get_n = getattr(lib, f"{prefix}_get_num_threads{suffix}", None)
                if set_n is not None and get_n is not None:
                    get_n.restype = ctypes.c_int
                    out.append((set_n, get_n))
                    break
            else:
                continue
            break
    return out


@contextlib.contextmanager
def single_thread_blas():
    """Run the block with one BLAS thread, restoring the previous setting afterwards.

    OpenBLAS splits some products differently with 1 or 2 threads, which changes the last
    bits of the results; LM then amplifies them. Every chunk runs single-threaded -- in this
    process or in a Dask worker -- so a seed gives the same bits for any number of workers
    (parallelism comes from the workers, one chunk each).
    """
    setters = _openblas_thread_setters()
    old = [int(g()) for _, g in setters]
    for s_, _ in setters:
        s_(ctypes.c_int(1))
    try:
        yield
    finally:
        for (s_, _), n in zip(setters, old):
            s_(ctypes.c_int(n))


@dataclass(frozen=True)
class ChunkTask:
    index: int
    start_ids: np.ndarray
    X0n: np.ndarray
    objective: Objective
    options: MultiStartOptions


def run_chunk(task: ChunkTask) -> dict:
    """Run LM in lock-step for one chunk of starts; returns plain arrays (picklable).

    Starts that stay invalid after resampling are not optimised: they keep x = x0,
    chi2 = NaN, 0 iterations and status ``failed: <reason>``.
    """
    with single_thread_blas():
        return _run_chunk(task)


def _run_chunk(task: ChunkTask) -> dict:
    obj, opts = task.objective, task.options
    X0n, counts, reasons = resample_invalid(obj, task.X0n, task.start_ids, opts)
    n = X0n.shape[0]
    bad0 = reasons != ""
    good = np.nonzero(~bad0)[0]
    Xn = X0n.copy()
    chi2_0 = np.full(n, np.nan)
    chi2 = np.full(n, np.nan)
    iters = np.zeros(n, int)
    conv = np.zeros(n, bool)
    status = np.array([f"failed: {r}" for r in reasons], dtype=object)
    if good.size:
        lo, hi = obj.bounds_normalised()
        res = levenberg_marquardt_batch(
            obj, X0n[good], lower=lo, upper=hi,
            residuals=obj.residuals if opts.lm.residual_trials else None,
            prune=make_stop_rule(opts), **opts.lm.for_starts(obj.dof))
        Xn[good] = res.x
        chi2_0[good] = res.chi2_0
        chi2[good] = np.where(np.isfinite(res.chi2), res.chi2, np.nan)
        iters[good] = res.iterations
        conv[good] = res.converged
        status[good] = [str(s) for s in res.status]
    return {
        "index": task.index, "start_ids": task.start_ids,
        "x0": obj.to_physical(X0n), "x": obj.to_physical(Xn),
        "chi2_0": chi2_0, "chi2": chi2, "iterations": iters, "converged": conv,
        "status": status.astype(str), "resampled": counts,
    }


# ----------------------------------------------------------------------------- checkpoints

def _fingerprint(obj: Objective, X0n: np.ndarray, opts: MultiStartOptions) -> str:
    h = hashlib.sha256()
    for arr in (obj.data.time, obj.data.values, obj.data.sigma, X0n, obj.scale):
        h.update(np.ascontiguousarray(arr, dtype=float).tobytes())
    h.update(json.dumps({"names": obj.names, "piezo": obj.piezo, "base": dict(obj.base.values),
                         "zabs": obj.z_bk_absolute, "opts": asdict(opts)},
                        sort_keys=True, default=str).encode())
    return h.hexdigest()


#: file that marks a folder as a gprm checkpoint folder; gprm deletes only marked content
CHECKPOINT_MARKER = ".gprm-checkpoint"
_CHUNK_RE = re.compile(r"chunk_\d{5}\.npz")
_CHUNK_KEYS = ("index", "start_ids", "x0", "x", "chi2_0", "chi2", "iterations", "converged",
               "status", "resampled")


class Checkpoints:
    """A folder of finished chunks (``chunk_NNNNN.npz``) with a fingerprint of the inputs.

    gprm uses a folder only if it is new (created here), empty, or already marked as a gprm
    checkpoint folder (``.gprm-checkpoint``, which records whether gprm created the folder);
    any other folder is refused, so a checkpoint folder such as ``.`` never puts user files
    at risk. :func:`remove_checkpoints` deletes only the files gprm writes here.
    """

    def __init__(self, folder: str | os.PathLike | None, fingerprint: str):
        self.folder = None if folder is None else Path(folder)
        self.fingerprint = fingerprint
        if self.folder is None:
            return
        prepare_checkpoint_folder(self.folder)
        meta = self.folder / "fingerprint.txt"
        if meta.exists():
            if meta.read_text(errors="replace").strip() != fingerprint:
                raise GprmInputError(
                    "checkpoints belong to a run with other inputs or options; remove the "
                    "folder or choose another", source=str(self.folder), field="checkpoint")
        else:
            write_text_atomic(meta, fingerprint + "\n")

    def path(self, index: int) -> Path:
        assert self.folder is not None, "path() of a Checkpoints without a folder"
        return self.folder / f"chunk_{index:05d}.npz"

    def load(self, index: int, start_ids: np.ndarray | None = None) -> dict | None:
        """A finished chunk, or None when absent or unreadable (a damaged chunk file is not
        trusted: the chunk is run again and the file replaced)."""
        if self.folder is None or not self.path(index).exists():
            return None
        try:
            with np.load(self.path(index), allow_pickle=False) as z:
                res = {k: z[k] for k in z.files}
        except Exception:      # truncated, not a zip, pickled objects: run the chunk again
            return None
        if set(res) != set(_CHUNK_KEYS) or int(res["index"]) != index:
            return None
        n = np.atleast_1d(res["start_ids"]).size
        if start_ids is not None and not np.array_equal(np.atleast_1d(res["start_ids"]),
                                                        start_ids):
            return None
        if any(np.atleast_1d(res[k]).shape[0] != n for k in _CHUNK_KEYS if k != "index"):
            return None
        return res

    def save(self, res: dict) -> None:
        if self.folder is None:
            return
        with atomic_path(self.path(int(res["index"]))) as tmp:
            with open(tmp, "wb") as fh:
                np.savez(fh, **res)


def check_checkpoint_folder(folder: str | os.PathLike, field: str = "checkpoint") -> None:
    """Refuse (without touching anything) a folder gprm may not use for checkpoints: a file,
    or an existing folder with files that is not marked as a gprm checkpoint folder."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise GprmInputError("is a file; expected a checkpoint folder", source=str(folder),
                             field=field)
    if folder.is_dir() and not (folder / CHECKPOINT_MARKER).is_file() \
            and any(folder.iterdir()):
        raise GprmInputError("exists and is not a gprm checkpoint folder (no "
                             f"{CHECKPOINT_MARKER}); choose a new or empty folder",
                             source=str(folder), field=field)


def prepare_checkpoint_folder(folder: str | os.PathLike) -> Path:
    """Create or adopt ``folder`` as a checkpoint folder (see :class:`Checkpoints`)."""
    folder = Path(folder)
    marker = folder / CHECKPOINT_MARKER
    check_checkpoint_folder(folder)
    if folder.is_dir():
        if marker.is_file():
            return folder
        created = False
    else:
        try:
            folder.mkdir(parents=True)
        except OSError as exc:
            raise GprmInputError(f"cannot be created ({exc.strerror or exc})",
                                 source=str(folder), field="checkpoint") from None
        created = True
    write_text_atomic(marker, json.dumps({"tool": "gprm", "created_folder": created}) + "\n")
    return folder


def remove_checkpoints(folder: str | os.PathLike | None, *, only_if_empty: bool = False) -> None:
    """Delete what gprm wrote in a marked checkpoint folder, and the folder if gprm created it
    and nothing else is left. An unmarked folder is left alone entirely. With
    ``only_if_empty`` nothing is deleted once a chunk has been saved (a refused or failed run
    leaves no folder of its own behind, an interrupted one keeps its work)."""
    if folder is None:
        return
    folder = Path(folder)
    marker = folder / CHECKPOINT_MARKER
    if not marker.is_file():
        return
    names = [p.name for p in folder.iterdir()]
    if only_if_empty and any(_CHUNK_RE.fullmatch(n) for n in names):
        return
    try:
        created = bool(json.loads(marker.read_text(encoding="utf-8")).get("created_folder"))
    except (OSError, ValueError, AttributeError):
        created = False
    for n in names:
        ours = (n == "fingerprint.txt" or _CHUNK_RE.fullmatch(n)
                or (n.startswith((".chunk_", ".fingerprint.txt.", f"{CHECKPOINT_MARKER}."))
                    and n.endswith(".part")))
        if ours:
            with contextlib.suppress(FileNotFoundError):
                (folder / n).unlink()
    marker.unlink()
    if created:
        with contextlib.suppress(OSError):
            folder.rmdir()            # only if empty: other files stay, with their folder


def starts_memory(n_starts: int, n_params: int) -> float:
    """Estimated peak bytes of the per-start arrays of a fit (the start matrix, each chunk's
    results, their concatenation and ordering, the sidecar dataset: 4 copies of 3 vectors of
    ``n_params`` and 6 scalars per start, plus the status strings)."""
    return float(n_starts) * (4 * (3 * n_params + 6) * 8 + 4 * 64)


# ----------------------------------------------------------------------------- driver

def _chunks(n: int, size: int) -> list[np.ndarray]:
    size = max(1, int(size))
    return [np.arange(i, min(i + size, n)) for i in range(0, n, size)]


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity where the system says; else the
    machine's count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def default_workers(n_starts: int, chunk_size: int, cores: int | None = None) -> int:
    """The default number of local worker processes of ``gprm fit``, ``gprm run`` and
    ``gprm demo`` (``--workers``): one per core, at most one per chunk of starts, and none
    (in this process) when that would be fewer than two. A chunk runs on one worker, so with
    one chunk (up to ``chunk_size`` starts: a 200-start fit, ``--quick``) workers cannot work
    in parallel and only add their start-up; on one core neither can two chunks. Measured on
    the 2-core machine (docs/fitting.md, "Scale"): 200 starts run faster in process, 1000
    starts (four chunks) on two workers."""
    cores = usable_cores() if cores is None else max(1, int(cores))
    n_chunks = len(_chunks(int(n_starts), chunk_size))
    n = min(cores, n_chunks)
    return n if n >= 2 else 0


def pool_context():
    """The multiprocessing context of the fit's local worker processes (:func:`local_pool`).

    ``fork`` on Linux where this process runs no thread but its main one: the workers start
    at once, with every module the fit needs already imported, and nothing can hold a lock
    in them that no thread of theirs will release. Where another thread runs (the CLI's
    progress display, a Jupyter kernel's, a Dask client's) forking could leave such a lock
    behind, so ``forkserver``: a fresh server process imports :mod:`gprm.fit.engine` once
    and the workers are forked from it. ``spawn`` where neither exists."""
    import multiprocessing as mp

    methods = mp.get_all_start_methods()
    if sys.platform.startswith("linux") and "fork" in methods \
            and threading.active_count() == 1:
        return mp.get_context("fork")
    if "forkserver" in methods:
        ctx = mp.get_context("forkserver")
        ctx.set_forkserver_preload(["gprm.fit.engine"])
        return ctx
    return mp.get_context("spawn")


def local_pool(n_workers: int):
    """The fit's local worker processes, ``n_workers`` of them (``--workers N``, no dashboard,
    no scheduler): a :class:`concurrent.futures.ProcessPoolExecutor` of
    :func:`pool_context`. No network listener and no scheduler: the chunks and their
    results travel over the processes' own pipes. Replaces the local Dask cluster of stops
    up to 35 as the default, whose start, first imports and close cost about 5 s of a
    1000-start fit on the 2-core machine (BENCHMARKS.md, "Fit speed targets", stop 36); a
    dashboard asked for (``--dashboard``) still starts that cluster (:func:`local_cluster`)."""
    import concurrent.futures as cf

    return cf.ProcessPoolExecutor(max_workers=int(n_workers), mp_context=pool_context(),
                                  initializer=die_with_parent)


def die_with_parent() -> None:
    """Run in each local worker as it starts: on Linux, ask the kernel to kill it when its
    parent dies (``prctl(PR_SET_PDEATHSIG, SIGKILL)``), so that a ``gprm fit`` killed with
    SIGKILL leaves no idle workers behind (they hold a copy of the pipe the parent would
    have closed, so they would wait for it for ever); a worker whose parent is already gone
    exits at once. Workers write no files (the parent writes the checkpoints), so nothing
    is lost by killing them. Elsewhere: nothing."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes
    import signal

    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))   # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() == 1:                   # the parent died before the request was made
        os._exit(0)


@contextlib.contextmanager
def worker_pool(n_workers: int, *, scheduler: str | None = None, dashboard: str | None = None):
    """A started :func:`local_pool` of ``n_workers`` for :func:`run_multistart`'s
    ``executor`` (None where the fit runs in process, on ``scheduler``, or on the Dask
    cluster a ``dashboard`` needs), shut down on leaving. Entered before any thread starts
    (``gprm fit`` enters it before its progress display), its workers are forked then."""
    if n_workers <= 0 or scheduler or dashboard:
        yield None
        return
    pool = local_pool(n_workers)
    try:
        pool.submit(int).result()        # the workers start now
        yield pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def local_worker_config() -> dict:
    """Dask settings for the local cluster's workers (a warmed-up chunk of 250 demo starts:
    14.8 s CPU with Dask's defaults, 12.7 s with these, 8.5 s in one process;
    ``benchmarks/bench_fit.py --variants``).

    - Dask starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which also switches off
      glibc's adaptive mmap threshold: every multi-megabyte temporary array of the batched
      solver is then a fresh mmap that page-faults in. The workers here get Dask's other
      settings (one BLAS/OpenMP thread) without it.
    - The statistical profiler, which samples the worker thread every 10 ms, is off.

    Workers of an existing cluster (``--scheduler``) keep their own settings; start them
    without ``MALLOC_TRIM_THRESHOLD_`` for the same speed (docs/fitting.md).
    """
    import dask
    import distributed  # noqa: F401  (registers distributed's configuration defaults)

    env = {k: v for k, v in dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()
           if k != "MALLOC_TRIM_THRESHOLD_"}
    return {"distributed.nanny.pre-spawn-environ": env,
            "distributed.worker.profile.enabled": False}


def local_cluster(n_workers: int, dashboard: str | None = None):
    """The fit's local Dask cluster: ``n_workers`` single-threaded worker processes, the
    scheduler and the workers listening on 127.0.0.1 only (:func:`local_worker_config`).

    Without ``dashboard`` no HTTP server is left listening: distributed starts the
    scheduler's on port 8787 even when told to serve no dashboard (``dashboard_address=None``
    means "the default port", and ``":0"`` means all interfaces), so it is started on a
    random loopback port with no routes and then stopped; the workers' serve no routes
    either (the caller stops them once connected: ``client.run(_stop_http_server)``). With
    ``dashboard`` (``--dashboard 127.0.0.1:8787``) the scheduler serves it there.

    The cluster speaks TLS with temporary credentials (``Security.temporary()``: a key and
    self-signed certificate made for this cluster, held in memory only and required of every
    connection), so another user of the machine who finds the port cannot connect a client
    and run code in the workers (issue 22; docs/fitting.md). Its scheduler address is
    ``tls://``; a client of it needs ``cluster.security`` (``Client(cluster)`` takes it). The
    default ``--workers 0`` starts no cluster.
    """
    import dask
    from distributed import LocalCluster
    from distributed.security import Security

    settings = dict(local_worker_config())
    extra: dict = {}
    if not dashboard:
        settings.update({"distributed.scheduler.http.routes": [],
                         "distributed.worker.http.routes": []})
        extra = {"dashboard_address": "127.0.0.1:0", "scheduler_kwargs": {"dashboard": False}}
    else:
        extra = {"dashboard_address": dashboard}
    with dask.config.set(settings):
        cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                               host="127.0.0.1", protocol="tls://",
                               security=Security.temporary(), silence_logs=40, **extra)
    if not dashboard:
        try:
            cluster.sync(_stop_server_http, cluster.scheduler)
        except Exception:
            cluster.close()
            raise
    return cluster


async def _stop_server_http(server) -> None:
    """Stop the HTTP listener of a scheduler (run on the cluster's event loop)."""
    _stop_http_server(server)


def _stop_http_server(dask_worker=None) -> None:
    """Stop the HTTP listener of a Dask server: ``client.run`` passes each worker as
    ``dask_worker``; the scheduler is passed directly."""
    http = getattr(dask_worker, "http_server", None)
    if http is not None:
        http.stop()


def run_multistart(obj: Objective, opts: MultiStartOptions = MultiStartOptions(), *,
                   workers: int = 0, scheduler: str | None = None,
                   checkpoint_dir: str | os.PathLike | None = None,
                   progress: Callable[..., None] | None = None,
                   stop_after: int | None = None, executor=None) -> StartsOutcome:
    """Run all starts. ``workers=0`` runs in this process; ``workers>0`` runs the chunks on
    that many local worker processes (:func:`local_pool`; a local Dask cluster,
    :func:`local_cluster`, where a dashboard was asked for); ``executor``: such a pool made
    by the caller (``gprm fit`` makes its own before its progress display starts a thread,
    so that the workers can be forked, :func:`pool_context`), used instead of ``workers``
    and left open; ``scheduler`` connects to an
    existing cluster instead, connected as distributed connects any client: with no security
    object from gprm, so a ``tls://`` address takes its credentials from the user's Dask
    configuration (``distributed.comm.tls.*``; docs/fitting.md). ``progress(done, total)`` is called as chunks finish, counting
    starts (finished, requested); a callback that takes a ``best_chi2`` keyword also gets
    the smallest chi-square reached so far (nan before the first chunk).
    ``stop_after`` stops (raising KeyboardInterrupt) after that many new chunks: used to test
    resuming.
    """
    center = obj.to_normalised(obj.base.initial_vector(obj.names))
    X0n = draw_starts(center, opts)
    ck = Checkpoints(checkpoint_dir, _fingerprint(obj, X0n, opts))
    chunks = _chunks(opts.n_starts, opts.chunk_size)
    results: dict[int, dict] = {}
    for i in range(len(chunks)):
        r = ck.load(i, chunks[i])
        if r is not None:
            results[i] = r
    total = len(chunks)
    report = _progress_reporter(progress, chunks, results)
    report()
    pending = [ChunkTask(i, ids, X0n[ids], obj, opts) for i, ids in enumerate(chunks)
               if i not in results]
    new = 0

    def finish(res):
        nonlocal new
        results[int(res["index"])] = res
        ck.save(res)
        new += 1
        report()
        if stop_after is not None and new >= stop_after and len(results) < total:
            raise KeyboardInterrupt("stopped after the requested number of chunks")

    if pending and executor is not None and not scheduler:
        _run_on_pool(executor, pending, finish)
    elif pending and workers > 0 and not scheduler and not _dashboard_asked():
        with worker_pool(workers) as pool:
            _run_on_pool(pool, pending, finish)
    elif pending and (workers > 0 or scheduler):
        import dask
        from distributed import Client, as_completed

        cluster = None
        if scheduler:
            try:
                client = Client(scheduler)
            except (OSError, TimeoutError, ValueError) as exc:
                raise GprmInputError(f"cannot connect to the Dask scheduler {scheduler!r} "
                                     f"({type(exc).__name__}: {exc})",
                                     field="scheduler") from None
        else:                       # a dashboard was asked for (else the pool above)
            cluster = local_cluster(workers, dask.config.get("gprm.dashboard-address", None))
            client = Client(cluster, security=cluster.security)   # its TLS credentials
        try:
            futs = [client.submit(run_chunk, t, pure=False) for t in pending]
            for fut in as_completed(futs):
                finish(fut.result())
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    else:
        for task in pending:
            finish(run_chunk(task))
    parts = [results[i] for i in range(total)]
    cat = {k: np.concatenate([np.atleast_1d(p[k]) for p in parts]) for k in parts[0]
           if k != "index"}
    order = np.argsort(cat["start_ids"], kind="stable")
    return StartsOutcome(
        names=obj.names, x0=cat["x0"][order], x=cat["x"][order], chi2_0=cat["chi2_0"][order],
        chi2=cat["chi2"][order], iterations=cat["iterations"][order],
        converged=cat["converged"][order], status=cat["status"][order].astype(str),
        resampled=cat["resampled"][order])


def _run_on_pool(pool, pending, finish) -> None:
    """The chunks ``pending`` on the process pool ``pool``, ``finish`` called with each
    result as it comes; a stop (an error, ``stop_after``, ^C) cancels the chunks not begun
    and lets the running ones end on their own."""
    import concurrent.futures as cf

    futs = [pool.submit(run_chunk, t) for t in pending]
    try:
        for fut in cf.as_completed(futs):
            finish(fut.result())
    except BaseException:
        for f in futs:
            f.cancel()
        raise


def _dashboard_asked() -> bool:
    """Whether a Dask dashboard was asked for (``gprm.dashboard-address``, set by ``gprm fit
    --dashboard``): only Dask's local cluster serves one. Dask is not imported to find out
    where nothing has imported it (then nothing can have set it)."""
    if "dask" not in sys.modules:
        return False
    import dask

    return bool(dask.config.get("gprm.dashboard-address", None))


def takes_keyword(f: Callable, name: str) -> bool:
    """Whether ``f`` accepts the keyword ``name`` (by name or through ``**kwargs``)."""
    try:
        sig = inspect.signature(f).parameters
    except (TypeError, ValueError):  # pragma: no cover - builtins without a signature
        return False
    return name in sig or any(p.kind is p.VAR_KEYWORD for p in sig.values())


def _progress_reporter(progress, chunks, results):
    """A no-argument function that reports (starts done, starts requested[, best_chi2]):
    the progress callback of the fit (:func:`run_multistart`), the same for ``gprm fit``,
    ``gprm run`` and ``gprm demo``."""
    if progress is None:
        return lambda: None
    with_best = takes_keyword(progress, "best_chi2")
    n_total = int(sum(len(c) for c in chunks))

    def report():
        done = int(sum(len(chunks[i]) for i in results))
        if not with_best:
            progress(done, n_total)
            return
        best = [np.nanmin(r["chi2"]) for r in results.values()
                if np.any(np.isfinite(r["chi2"]))]
        progress(done, n_total, best_chi2=float(min(best)) if best else float("nan"))

    return report


#: The polishes' step control: the trust region of :mod:`gprm.fit.lm` with the initial bound
#: |D x0| (``step_bound`` 1, as the standalone optimizer), not Algorithm 1's lambda / 10, x 10.
#: Measured on the demo's 10-start fit (docs/fitting.md, "Speed"): on the objective with a
#: resonance projected off, Algorithm 1 crept 189-200 iterations (139.13 at the limit against
#: 136.51 in 81 with the trust region), and its final polish ended at lambda_max after 56
#: iterations where the trust region meets ftol in 26 at the same chi-square.
POLISH_STEP_BOUND = 1.0
#: An intermediate polish (``settle=True``: between the runs' sub-sample corrections and the
#: resonance's projections, whose inputs depend on the point smoothly) stops once chi-square
#: fell by at most SETTLE times the variance scale chi2/dof over SETTLE_WINDOW iterations:
#: a thousandth of what one standard deviation of one parameter is worth (Delta chi2 = s2).
#: The final polish is not settled (ftol 1e-12).
SETTLE = 1e-3
SETTLE_WINDOW = 5
SETTLE_ROUNDS = 4


def polish_kwargs(lm: LMOptions, max_iter: int = 200, ftol: float = 1e-12, *,
                  settle_tol: float = 0.0, trust_region: bool = True) -> dict:
    """The options of a polish (:func:`polish_best`): the starts' LM options with the
    iteration limit ``max_iter``, relative tolerance ``ftol``, no absolute part, the trust
    region's step control (:data:`POLISH_STEP_BOUND`; ``trust_region=False``: Algorithm 1's
    damping update, as the starts) and, with ``settle_tol`` > 0, a row stops once chi-square
    fell by at most ``settle_tol`` over :data:`SETTLE_WINDOW` iterations (else no stall
    window)."""
    kw = lm.as_kwargs()
    kw.update(max_iter=max_iter, ftol=ftol, ftol_abs=0.0,
              step_bound=POLISH_STEP_BOUND if trust_region else None,
              stall_window=SETTLE_WINDOW if settle_tol > 0 else 0,
              stall_tol=float(settle_tol))
    return kw


def polish_best(obj: Objective, x: np.ndarray, lm: LMOptions, *, max_iter: int = 200,
                ftol: float = 1e-12, settle: bool = False,
                trust_region: bool = True) -> tuple[np.ndarray, dict]:
    """Continue from the best start with a tight tolerance (relative chi-square change
    1e-12, no absolute part), so that the reported best fit does not depend on the looser
    stopping rule used for the many starts. Chi-square can only decrease. ``settle``: an
    intermediate polish, stopped once chi-square changes by less than :data:`SETTLE` of
    the variance scale over :data:`SETTLE_WINDOW` iterations. ``trust_region``: as
    :func:`polish_kwargs`."""
    lo, hi = obj.bounds_normalised()
    xn = obj.to_normalised(np.asarray(x, float))[None]
    chi2 = float(obj.chi2(xn)[0]) if settle else np.nan
    info: dict = {"iterations": 0}
    moved = False
    for _ in range(SETTLE_ROUNDS if settle else 1):
        # settling: against the variance scale at this round's start; a round that ended
        # below half its start's chi-square settled against too large a scale, and another
        # follows
        tol = SETTLE * chi2 / max(int(obj.dof), 1) if settle else 0.0
        res = levenberg_marquardt_batch(
            obj, xn, lower=lo, upper=hi, residuals=obj.residuals,
            **polish_kwargs(lm, max_iter, ftol, trust_region=trust_region,
                            settle_tol=tol if np.isfinite(tol) and tol > 0 else 0.0))
        c0, chi2 = float(res.chi2_0[0]), float(res.chi2[0])
        info.setdefault("chi2_before", c0)
        info["iterations"] += int(res.iterations[0])
        info["status"] = str(res.status[0])
        if not np.isfinite(chi2) or chi2 > c0:
            info.setdefault("chi2_after", chi2)
            break
        xn, info["chi2_after"], moved = res.x[:1], chi2, True
        if not (settle and info["status"] == "stalled" and chi2 < 0.5 * c0):
            break
    return (obj.to_physical(xn[0]) if moved else x), info
