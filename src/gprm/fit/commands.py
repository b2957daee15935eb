"""CLI: ``gprm fit``."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer


def register(app: typer.Typer, synth_app: typer.Typer) -> None:
    from gprm.cli import one_line_errors

    @app.command("fit")
    @one_line_errors
    def fit_cmd(
        means: Path = typer.Argument(..., help="mean-signals NetCDF (gprm preprocess)"),
        out: Path = typer.Option(..., "--out", help="fit result JSON (sidecar: same name .nc)"),
        starts: int = typer.Option(1000, "--starts", help="number of random starts"),
        seed: int = typer.Option(0, "--seed", help="random seed of the starts"),
        spread: float = typer.Option(0.2, "--spread", help="starts within ±spread of the "
                                     "paper's initial values"),
        sampling: str = typer.Option("uniform", "--sampling", help="uniform or lhs"),
        params: Optional[Path] = typer.Option(None, "--params", help="TOML parameter file "
                                              "(constants, fitted set, bounds)"),
        piezo: int = typer.Option(2, "--piezo", help="driven piezo in the campaign"),
        window: tuple[float, float] = typer.Option((0.97e-3, 1.2e-3), "--window",
                                                   help="fit window start end, s"),
        sigma: str = typer.Option("sem", "--sigma", help="weights: sem (standard error of "
                                  "the mean) or std (the paper's across-run std)"),
        workers: Optional[int] = typer.Option(None, "--workers", help="local Dask worker "
                                              "processes (default: one per core; 0: run in "
                                              "this process; the result does not depend "
                                              "on it)"),
        scheduler: Optional[str] = typer.Option(None, "--scheduler",
                                                help="address of an existing Dask scheduler"),
        chunk: int = typer.Option(250, "--chunk", help="starts per lock-step chunk (part of "
                                  "the result's definition, like the seed; smaller chunks "
                                  "spread over more workers)"),
        max_iter: int = typer.Option(100, "--max-iter", help="LM iteration limit per start"),
        stall_window: int = typer.Option(5, "--stall-window", help="stop a start once chi2 "
                                         "fell by at most --stall-tol over this many "
                                         "iterations (0: off; docs/fitting.md)"),
        stall_tol: float = typer.Option(0.05, "--stall-tol"),
        prune_after: int = typer.Option(10, "--prune-after", help="stop starts whose chi2 is "
                                        "over --prune-factor x the chunk's best after this "
                                        "many iterations, or that cannot reach it at their "
                                        "recent rate (0: never; docs/fitting.md)"),
        prune_factor: float = typer.Option(100.0, "--prune-factor"),
        band_samples: int = typer.Option(200, "--band-samples", help="covariance samples "
                                         "for the sampled uncertainty bands"),
        profile: bool = typer.Option(False, "--profile", help="also compute profile "
                                     "likelihoods of every fitted parameter"),
        checkpoint: Optional[Path] = typer.Option(None, "--checkpoint", help="checkpoint "
                                                  "folder (default: OUT.ckpt); rerun resumes"),
        z_bk_absolute: bool = typer.Option(False, "--z-bk-absolute",
                                           help="fit z_bk as z_lr + z_A"),
        no_fit_offsets: bool = typer.Option(False, "--no-fit-offsets", help="do not fit the "
                                            "per-signal alignment offsets dt_x_head, "
                                            "dt_y_base, dt_y_head (fitted by default)"),
    ):
        """Multi-start Levenberg-Marquardt identification (Sec. 3.1)."""
        import os
        import shutil

        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        from gprm.errors import GprmInputError
        from gprm.fit.api import FitOptions, run_fit

        opts = _options(FitOptions, starts=starts, seed=seed, spread=spread, sampling=sampling,
                        window=window, sigma=sigma, fit_offsets=not no_fit_offsets,
                        piezo=piezo, chunk=chunk, max_iter=max_iter,
                        stall_window=stall_window, stall_tol=stall_tol,
                        prune_after=prune_after, prune_factor=prune_factor,
                        band_samples=band_samples, profile=profile,
                        z_bk_absolute=z_bk_absolute)
        if workers is None:
            workers = 0 if scheduler else max(1, os.cpu_count() or 1)
        if workers < 0:
            raise GprmInputError(f"must be >= 0, got {workers}", field="--workers")
        ckpt = checkpoint if checkpoint is not None else Path(str(out) + ".ckpt")
        console = Console(stderr=True)
        with Progress(TextColumn("fit"), BarColumn(), TextColumn("{task.completed}/"
                      "{task.total} chunks"), TimeElapsedColumn(), console=console,
                      transient=True) as bar:
            task = bar.add_task("fit", total=None)

            def progress(done, total):
                bar.update(task, completed=done, total=total)

            res = run_fit(means, opts, params=params, workers=workers, scheduler=scheduler,
                          checkpoint_dir=ckpt, progress=progress)
        side = res.write(out)
        shutil.rmtree(ckpt, ignore_errors=True)
        typer.echo(res.summary())
        typer.echo(f"wrote {out} and {side} ({res.timings['total']:.1f} s)")


def _options(cls, **values):
    """``cls(**values)``; an invalid option is named as its command-line flag."""
    from gprm.errors import GprmInputError

    try:
        return cls(**values)
    except GprmInputError as exc:
        flag = None if exc.field is None else "--" + exc.field.replace("_", "-")
        raise GprmInputError(exc.problem, source=exc.source, field=flag) from None
