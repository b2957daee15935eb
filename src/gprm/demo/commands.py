"""CLI: ``gprm demo``: ``gprm run`` on a generated campaign (same stages, same code)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from gprm.console import one_line_errors
from gprm.options import Int


def register(app: typer.Typer, synth_app: typer.Typer) -> None:
    @app.command("demo")
    @one_line_errors
    def demo_cmd(
        out: Path = typer.Option(Path("demo-run"), "--out", help="run directory (created; a "
                                 "rerun resumes what is up to date)"),
        quick: bool = typer.Option(False, "--quick", help="a small run: 50 starts, fewer "
                                   "band samples (about 15 s on 2 cores)"),
        seed: int = typer.Option(0, "--seed", parser=Int(min=0), help="seed of the synthetic data and the starts"),
        starts: Optional[int] = typer.Option(None, "--starts", parser=Int(min=1), help="random starts of the fit "
                                             "(default 1000, or 50 with --quick)"),
        workers: Optional[int] = typer.Option(None, "--workers", parser=Int(min=0), help="local Dask worker "
                                              "processes for the fit (default: one per core, "
                                              "at most one per chunk of 250 starts, 0 where "
                                              "that is fewer than 2, as with --quick: in "
                                              "this process; the result does not depend on "
                                              "it)"),
    ):
        """The whole chain on generated data, resumable, ending in report.html.

        campaign -> preprocess -> fit -> predict, what-ifs -> telemetry -> impact -> report
        """
        from gprm.run.commands import make_options, run_and_print
        from gprm.run.options import RunOptions

        opts = make_options(RunOptions, quick=quick, seed=seed, starts=starts, workers=workers)
        run_and_print(out, opts, demo=True)
