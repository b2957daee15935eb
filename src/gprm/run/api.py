"""``run_chain`` and ``run_demo``: the library entry points of ``gprm run`` and ``gprm demo``
(see the package docstring)."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

from gprm.errors import GprmInputError
from gprm.run.engine import RunResult, run_stages
from gprm.run.options import RunOptions
from gprm.run.stages import chain

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
              command: str | None = None, report_html: bool = True) -> RunResult:
    """Run the chain of ``opts`` into ``out`` (created if needed), resuming what is up to
    date (see :mod:`gprm.run.engine`). A campaign or telemetry path that does not exist is a
    :class:`GprmInputError` before anything runs; a stage that fails on its input is recorded
    in ``run.json`` (status ``failed``, with the message) and blocks the stages after it."""
    if not isinstance(opts, RunOptions):
        raise GprmInputError(f"expected RunOptions, got {type(opts).__name__}", field="opts")
    _check_sources(opts)
    return run_stages(out, opts, chain(opts), progress=progress, command=command,
                      report_html=report_html)


def run_demo(out: str | os.PathLike, opts: RunOptions = RunOptions(), **kw) -> RunResult:
    """``gprm demo``: :func:`run_chain` on a campaign generated with ``opts.seed`` (and
    synthetic telemetry)."""
    return run_chain(out, replace(opts, campaign=None, telemetry=None), **kw)
