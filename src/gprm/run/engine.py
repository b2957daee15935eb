"""The stage runner of ``gprm run`` / ``gprm demo``: runs a chain of stages into one run
directory, resuming what is up to date, and records ``run.json``.

Resuming: after each stage ``run.json`` records the SHA-256 of the stage's input files, its
settings and the SHA-256 of the files it wrote. A rerun into the same directory skips a stage
when its outputs still exist with those hashes and its inputs and settings are unchanged, so an
interrupted run continues where it stopped (the fit also checkpoints its chunks of starts in
``fit.json.ckpt/``). Any change upstream reruns everything downstream of it, because the
downstream stage's input hash changes.

A stage that fails is recorded (with the last lines of its traceback); the stages that need
its output are "blocked", and the report says "not run" for them. This module knows nothing of
the particular stages (:mod:`gprm.run.stages`); it sits above the report, which it calls last.

Nothing the tool did not write is deleted: a stage that fails removes only the files it wrote
in this call (a multi-file stage that stopped half-way); files of the stage's names that were
there before (an earlier run's, or the user's) are left as they were and listed as ``kept``
in its record, and the report and the summary leave them out (they are not this run's). The
temporary files of writes that a killed gprm left in the folder are removed.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy
import scipy
import xarray

from gprm import __version__
from gprm._io import read_json, remove_stale_temps, write_json_atomic, written_here
from gprm.fit.engine import takes_keyword
from gprm.errors import GprmInputError
from gprm.report.build import write_report
from gprm.report.summary import summarise

RUN_JSON = "run.json"
FORMAT_VERSION = 1

Progress = Callable[[str, str, "int | None", "int | None"], None]


@dataclass(frozen=True)
class Stage:
    """One step of the chain: reads ``inputs`` from the run directory, writes ``outputs``.

    ``settings(opts)`` is what of the options changes the outputs (part of the hash);
    ``run(run_dir, opts, step)`` does the work and returns a small dict of facts (``notes``:
    a list of sentences the report shows)."""

    name: str
    title: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    settings: Callable[[Any], dict]
    run: Callable[[Path, Any, Callable[[int, int], None]], dict]


@dataclass
class StageRecord:
    name: str
    status: str                 # ran | skipped (up to date) | blocked | failed
    seconds: float = 0.0
    detail: str = ""
    info: dict = field(default_factory=dict)


@dataclass
class RunResult:
    run_dir: Path
    records: list[StageRecord]
    summary: dict
    total_seconds: float


# ----------------------------------------------------------------------------- hashing

def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def input_key(run: Path, stage: Stage, opts) -> str:
    """Hash of everything a stage's output depends on: its input files, its settings, the
    gprm version."""

    h = hashlib.sha256()
    h.update(json.dumps({"stage": stage.name, "settings": stage.settings(opts),
                         "version": __version__}, sort_keys=True).encode())
    for name in stage.inputs:
        h.update(name.encode())
        h.update(sha256_file(run / name).encode())
    return h.hexdigest()


def _file_key(path: Path) -> tuple | None:
    """What changes when a file is written (atomically: a new inode) or edited."""
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


def last_result(previous: dict, name: str) -> dict | None:
    """The record of the last call in which stage ``name`` produced its outputs: its own
    record, or, where it then failed or was blocked and its earlier outputs were kept, the
    record of those (``earlier``)."""
    rec = (previous.get("stages") or {}).get(name)
    if not isinstance(rec, dict):
        return None
    if rec.get("status") in ("ran", "skipped"):
        return rec
    earlier = rec.get("earlier")
    return earlier if isinstance(earlier, dict) else None


def up_to_date(run: Path, stage: Stage, key: str, previous: dict) -> bool:
    rec = last_result(previous, stage.name)
    if not rec or rec.get("input_key") != key:
        return False
    outs = rec.get("outputs", {})
    for name in stage.outputs:
        p = run / name
        if not p.exists() or outs.get(name) != sha256_file(p):
            return False
    return True


# ----------------------------------------------------------------------------- running

def _versions() -> dict:
    return {"gprm": __version__, "python": platform.python_version(), "numpy": numpy.__version__,
            "scipy": scipy.__version__, "xarray": xarray.__version__,
            "platform": platform.platform()}


def _options_json(opts) -> dict:
    return asdict(opts) if hasattr(opts, "__dataclass_fields__") else dict(vars(opts))


def _events(progress: Progress | None) -> Callable[..., None]:
    """The progress callback as a function that takes the fit's ``best_chi2`` keyword, which
    a callback of (stage, event, done, total) alone is not given."""
    if progress is None:
        return lambda *a, **k: None
    if takes_keyword(progress, "best_chi2"):
        return progress
    return lambda stage, event, done=None, total=None, **_: progress(stage, event, done, total)


def run_stages(out: str | os.PathLike, opts, stages, *, progress: Progress | None = None,
               command: str | None = None, report_html: bool = True) -> RunResult:
    """Run ``stages`` into ``out`` (created if needed), resuming what is up to date.

    ``progress(stage, event, done, total)`` is called with event ``start``, ``step`` (with
    done/total, e.g. the fit's starts), ``done``, ``skip``, ``blocked``, ``fail`` or
    ``interrupted`` (a signal or Ctrl-C stopped the stage: a rerun resumes it); a
    callback that takes a ``best_chi2`` keyword also gets the fit's smallest chi-square so far
    with its steps (the fit's progress callback, :func:`gprm.fit.run_fit`). Returns the
    stage records and the summary (also written to ``run.json``).
    """
    run = Path(out)
    try:
        run.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise GprmInputError(f"cannot be created ({exc.strerror or exc})", source=str(run),
                             field="out") from None
    # temporary files of writes a killed gprm left here (their names say which process
    # made them); nothing else, not even files named like an old version's temporaries
    remove_stale_temps(run)
    prev_path = run / RUN_JSON
    previous: dict = {}
    if prev_path.exists():
        try:
            rec = read_json(prev_path, what="run record")
        except Exception:   # a damaged record only costs a full rerun
            rec = None
        previous = rec if isinstance(rec, dict) else {}
    report = _events(progress)
    seed = getattr(opts, "seed", None)
    state: dict[str, Any] = {           # the run record (run.json)
        "format_version": FORMAT_VERSION,
        "command": command or " ".join(sys.argv),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "options": _options_json(opts),
        "seed": seed,
        "versions": _versions(),
        "stages": {},
        "timings_s": {},
    }
    records: list[StageRecord] = []
    not_this_run: set[str] = set()      # outputs of stages that did not run: never inputs

    def not_done(stage: Stage, rec: StageRecord, event: str, before: dict | None = None,
                 **entry) -> None:
        """Record a stage that produced no outputs (blocked, failed). Of its output names,
        the files it wrote in this call (``before``: their state before it ran) are removed;
        any other file of those names is left as it was and listed as ``kept``: not this
        run's result, so the summary and the report leave it out."""
        report(stage.name, event, None, None)
        records.append(rec)
        not_this_run.update(stage.outputs)
        before = before if before is not None else {n: _file_key(run / n)
                                                    for n in stage.outputs}
        kept = []
        for name in stage.outputs:
            now = _file_key(run / name)
            if now is None:
                continue
            # written by this stage, in this call (and still the file it wrote: not one
            # someone put at that name meanwhile)
            if now != before.get(name) and written_here(run / name):
                try:
                    (run / name).unlink(missing_ok=True)
                    continue
                except OSError:                     # cannot be removed: not used either
                    pass
            kept.append(name)
        state["stages"][stage.name] = {"status": rec.status, "detail": rec.detail, **entry}
        if kept:
            state["stages"][stage.name]["kept"] = kept
            earlier = last_result(previous, stage.name)
            if earlier is not None:     # a later call may still find them up to date
                state["stages"][stage.name]["earlier"] = earlier
        _write_state(run, state)

    t_all = time.perf_counter()
    for stage in stages:
        missing = [n for n in stage.inputs if n in not_this_run or not (run / n).exists()]
        if missing:
            not_done(stage, StageRecord(stage.name, "blocked",
                                        detail="needs " + ", ".join(missing)), "blocked")
            continue
        key = input_key(run, stage, opts)
        if up_to_date(run, stage, key, previous):
            old = last_result(previous, stage.name) or {}
            rec = StageRecord(stage.name, "skipped", seconds=0.0,
                              detail="up to date (inputs and settings unchanged)",
                              info=old.get("info", {}))
            report(stage.name, "skip", None, None)
            records.append(rec)
            state["stages"][stage.name] = old | {"status": "skipped",
                                                  "detail": rec.detail}
            state["timings_s"][stage.name] = old.get("seconds", 0.0)
            _write_state(run, state)
            continue
        report(stage.name, "start", None, None)
        t0 = time.perf_counter()
        before = {n: _file_key(run / n) for n in stage.outputs}
        try:
            info = stage.run(run, opts, lambda d, t, _n=stage.name, **kw:
                             report(_n, "step", d, t, **kw))
        except Exception as exc:
            # a failing stage does not stop the chain: it is recorded (with the traceback's
            # last lines), the stages needing its output are blocked, the report says why
            import traceback

            detail = str(exc) if _is_input_error(exc) else f"{type(exc).__name__}: {exc}"
            tb = traceback.format_exc().strip().splitlines()[-12:]
            not_done(stage, StageRecord(stage.name, "failed", seconds=time.perf_counter() - t0,
                                        detail=detail), "fail", before, traceback=tb)
            continue
        except BaseException:          # interrupted: record it and stop; a rerun resumes
            not_done(stage, StageRecord(stage.name, "interrupted",
                                        seconds=time.perf_counter() - t0,
                                        detail="interrupted"), "interrupted", before)
            raise
        dt = time.perf_counter() - t0
        rec = StageRecord(stage.name, "ran", seconds=dt, info=info or {})
        report(stage.name, "done", None, None)
        records.append(rec)
        state["stages"][stage.name] = {
            "status": "ran", "seconds": round(dt, 3), "input_key": key,
            "inputs": {n: sha256_file(run / n) for n in stage.inputs},
            "outputs": {n: sha256_file(run / n) for n in stage.outputs if (run / n).exists()},
            "settings": stage.settings(opts), "info": rec.info}
        state["timings_s"][stage.name] = round(dt, 3)
        _write_state(run, state)
    summary = summarise(run)
    state["summary"] = summary
    state["timings_s"]["stages (this invocation)"] = round(time.perf_counter() - t_all, 3)
    _write_state(run, state)
    if report_html:
        report("report", "start", None, None)
        t0 = time.perf_counter()
        write_report(run, run / "report.html")
        dt = time.perf_counter() - t0
        report("report", "done", None, None)
        records.append(StageRecord("report", "ran", seconds=dt))
        state["stages"]["report"] = {"status": "ran", "seconds": round(dt, 3)}
        state["timings_s"]["report"] = round(dt, 3)
    total = time.perf_counter() - t_all
    state["timings_s"]["total (this invocation)"] = round(total, 3)
    state["finished"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    _write_state(run, state)
    return RunResult(run, records, summary, total)


def _is_input_error(exc: Exception) -> bool:

    return isinstance(exc, GprmInputError)


def _json_safe(obj):
    """NaN and infinities (e.g. a missing z-score) as null, so run.json stays strict JSON."""
    if isinstance(obj, float):
        return obj if obj == obj and abs(obj) != float("inf") else None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


def _write_state(run: Path, state: dict) -> None:
    write_json_atomic(run / RUN_JSON, _json_safe(state))
