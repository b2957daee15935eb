"""``run_chain`` and ``run_demo``: the library entry points of ``gprm run`` and ``gprm demo``
(see the package docstring)."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

from gprm._io import check_outputs, read_json, written_by_gprm
from gprm.campaign.files import campaign_inputs
from gprm.errors import GprmInputError
from gprm.fit.engine import check_checkpoint_folder
from gprm.run.engine import RUN_JSON, RunResult, last_result, run_stages, sha256_file
from gprm.run.options import RunOptions
from gprm.run.stages import FIT_CHECKPOINTS, chain

#: files of a run directory besides the stages' outputs
RUN_FILES = (RUN_JSON, "report.html")


def check_run_outputs(out: str | os.PathLike, opts: RunOptions, field: str = "out") -> None:
    """Refuse, before anything runs, a run directory that cannot be one (a file, a path
    below a file, a place where no file can be created) or whose files would overwrite an
    input (the campaign's files, the telemetry; the run's own ``campaign.nc`` and
    ``telemetry.nc`` may be the inputs they are copies of, when a run is resumed from them),
    and a checkpoint folder ``fit.json.ckpt`` that gprm did not make. ``field`` names the
    option in the message."""
    run = Path(out)
    check_outputs({}, folders={run: field})
    inputs = [*(campaign_inputs(opts.campaign) if opts.campaign is not None else ()),
              *((Path(opts.telemetry),) if opts.telemetry is not None else ())]
    own = {"campaign.nc": opts.campaign, "telemetry.nc": opts.telemetry}
    outs = []
    for name in [*(n for s in chain(opts) for n in s.outputs), *RUN_FILES]:
        src = own.get(name)
        if src is not None and _same_file(Path(src), run / name):
            continue
        outs.append((run / name, field))
    check_checkpoint_folder(run / FIT_CHECKPOINTS, field=field)
    check_outputs(outs, inputs=inputs, own=[*recorded_outputs(run), *imported_copies(run, own)])


def imported_copies(run: Path, sources: dict) -> list[Path]:
    """The run directory's files that are byte for byte the inputs this call imports
    (``sources``: run file name -> the campaign or telemetry file given, None where none):
    a copy gprm took of them earlier, which the import would write again (a record of it may
    be gone: a run stopped before it reached the stage rebuilds run.json without it)."""
    own = []
    for name, src in sources.items():
        path = run / name
        if src is None or not Path(src).is_file() or not path.is_file() \
                or written_by_gprm(path):
            continue
        if path.stat().st_size == Path(src).stat().st_size \
                and sha256_file(path) == sha256_file(Path(src)):
            own.append(path)
    return own


def recorded_outputs(run: Path) -> list[Path]:
    """The files of run directory ``run`` that its run.json records as a stage's outputs
    with the SHA-256 they still have: gprm's own (a campaign or telemetry file taken as it
    is carries no gprm history, :func:`gprm._io.written_by_gprm`), so a rerun may replace
    them. Only the files gprm does not recognise by their content are listed (the others
    need no record); none where there is no readable record."""
    try:
        rec = read_json(run / RUN_JSON, what="run record")
    except Exception:           # no record, or a damaged one: nothing is known to be gprm's
        return []
    stages = rec.get("stages") if isinstance(rec, dict) else None
    own = []
    for name in (stages if isinstance(stages, dict) else {}):
        entry = last_result(rec, name)           # a failed stage's kept files: its earlier record
        outputs = entry.get("outputs") if isinstance(entry, dict) else None
        for file, digest in (outputs or {}).items() if isinstance(outputs, dict) else ():
            path = run / str(file)
            if (path.parent == run and path.is_file() and not written_by_gprm(path)
                    and sha256_file(path) == digest):
                own.append(path)
    return own


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.is_file() and b.is_file() and os.path.samefile(a, b)
    except OSError:
        return False


def _check_sources(opts: RunOptions) -> None:
    if opts.campaign is not None:
        p = Path(opts.campaign)
        if not p.exists():
            raise GprmInputError("campaign does not exist (a NetCDF file or a CSV folder "
                                 "with manifest.csv)", source=str(p))
        if p.is_dir() and not (p / "manifest.csv").is_file():
            raise GprmInputError("a campaign folder needs manifest.csv", source=str(p),
                                 field="manifest.csv")
    if opts.telemetry is not None:
        p = Path(opts.telemetry)
        if not p.exists():
            raise GprmInputError("telemetry file does not exist (a NetCDF or CSV file)",
                                 source=str(p))
        if not p.is_file():
            raise GprmInputError("telemetry must be a file (NetCDF or CSV), not a folder",
                                 source=str(p))


def run_chain(out: str | os.PathLike, opts: RunOptions = RunOptions(), *, progress=None,
              command: str | None = None, report_html: bool = True,
              executor=None) -> RunResult:
    """Run the chain of ``opts`` into ``out`` (created if needed), resuming what is up to
    date (see :mod:`gprm.run.engine`). A campaign or telemetry path that does not exist, or
    an ``out`` that cannot be a run directory (:func:`check_run_outputs`), is a
    :class:`GprmInputError` (field ``out``) before anything runs; a stage that fails on its input is recorded
    in ``run.json`` (status ``failed``, with the message) and blocks the stages after it.
    ``executor``: the fit's local worker processes (:func:`gprm.fit.engine.worker_pool`),
    made by a caller that starts threads before the fit (a progress display) so that they
    are forked first; None: the fit makes its own."""
    if not isinstance(opts, RunOptions):
        raise GprmInputError(f"expected RunOptions, got {type(opts).__name__}", field="opts")
    _check_sources(opts)
    check_run_outputs(out, opts)
    return run_stages(out, opts, chain(opts, executor), progress=progress, command=command,
                      report_html=report_html)


def run_demo(out: str | os.PathLike, opts: RunOptions = RunOptions(), **kw) -> RunResult:
    """``gprm demo``: :func:`run_chain` on a campaign generated with ``opts.seed`` (and
    synthetic telemetry)."""
    return run_chain(out, replace(opts, campaign=None, telemetry=None), **kw)
