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
        uncertainty: str = typer.Option("parametric-bootstrap", "--uncertainty",
                                        help="uncertainty method: parametric-bootstrap "
                                        "(default), laplace-prior "
                                        "(posterior of the prior-regularised fit), mcmc, "
                                        "eq7-corr (Eq. 7 with the residuals' time "
                                        "correlation) or eq7 (the paper's); docs/fitting.md "
                                        "compares their coverage"),
        boot: int = typer.Option(30, "--boot", help="campaigns of the parametric bootstrap"),
        prior_width: float = typer.Option(1.25, "--prior-width", help="width of the weak "
                                          "prior around the initial values (log units for "
                                          "positive parameters; 0: none, the paper's "
                                          "unregularised fit; docs/fitting.md)"),
        checkpoint: Optional[Path] = typer.Option(None, "--checkpoint", help="checkpoint "
                                                  "folder (default: OUT.ckpt); rerun resumes"),
        z_bk_absolute: bool = typer.Option(False, "--z-bk-absolute",
                                           help="fit z_bk as z_lr + z_A"),
    ):
        """Multi-start Levenberg-Marquardt identification (Sec. 3.1)."""
        import os
        import shutil

        import numpy as np

        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        from gprm._io import open_netcdf
        from gprm.errors import GprmInputError
        from gprm.fit.multistart import LMOptions, MultiStartOptions
        from gprm.fit.objective import fit_data_from_means
        from gprm.fit.result import identify
        from gprm.params import load_params

        from gprm.fit.uncertainty import METHODS

        if uncertainty not in METHODS:
            raise GprmInputError(f"must be one of {', '.join(METHODS)}, got {uncertainty!r}",
                                 field="--uncertainty")
        if not (prior_width >= 0 and np.isfinite(prior_width)):
            raise GprmInputError(f"must be >= 0, got {prior_width}", field="--prior-width")
        if prior_width == 0 and uncertainty not in ("eq7", "eq7-corr"):
            raise GprmInputError("--prior-width 0 (no prior) needs --uncertainty eq7 or "
                                 "eq7-corr", field="--prior-width")
        if boot < 5:
            raise GprmInputError(f"must be at least 5, got {boot}", field="--boot")
        if sigma not in ("sem", "std"):
            raise GprmInputError(f"must be sem or std, got {sigma!r}", field="--sigma")
        if starts < 1:
            raise GprmInputError(f"must be at least 1, got {starts}", field="--starts")
        ds = open_netcdf(means, what="mean-signals file")
        data = fit_data_from_means(ds, window=window, sigma=sigma, source=str(means))
        base = load_params(params)
        opts = MultiStartOptions(n_starts=starts, seed=seed, spread=spread, sampling=sampling,
                                 chunk_size=chunk,
                                 lm=LMOptions(max_iter=max_iter, stall_window=stall_window,
                                              stall_tol=stall_tol),
                                 prune_after=prune_after, prune_factor=prune_factor)
        if chunk < 1:
            raise GprmInputError(f"must be at least 1, got {chunk}", field="--chunk")
        if stall_window < 0:
            raise GprmInputError(f"must be >= 0, got {stall_window}", field="--stall-window")
        if not stall_tol >= 0:
            raise GprmInputError(f"must be >= 0, got {stall_tol}", field="--stall-tol")
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

            res = identify(data, base, opts, piezo=piezo, workers=workers,
                           scheduler=scheduler, checkpoint_dir=ckpt, progress=progress,
                           profile=profile, z_bk_absolute=z_bk_absolute,
                           band_samples=band_samples, uncertainty=uncertainty,
                           prior_width=prior_width or None, n_boot=boot)
        side = res.write(out)
        shutil.rmtree(ckpt, ignore_errors=True)
        typer.echo(res.summary())
        typer.echo(f"wrote {out} and {side} ({res.timings['total']:.1f} s)")
