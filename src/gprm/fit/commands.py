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
    ):
        """Multi-start Levenberg-Marquardt identification (Sec. 3.1)."""
        import os
        import shutil

        from rich.console import Console

        from gprm._io import open_netcdf
        from gprm.errors import GprmInputError
        from gprm.fit.multistart import LMOptions, MultiStartOptions
        from gprm.fit.objective import fit_data_from_means
        from gprm.fit.result import identify
        from gprm.params import load_params

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
        from gprm.fit.report_text import starts_progress

        with starts_progress(Console(stderr=True), starts) as progress:
            res = identify(data, base, opts, piezo=piezo, workers=workers,
                           scheduler=scheduler, checkpoint_dir=ckpt, progress=progress,
                           profile=profile, z_bk_absolute=z_bk_absolute,
                           band_samples=band_samples)
        side = res.write(out)
        shutil.rmtree(ckpt, ignore_errors=True)
        from gprm.fit.report_text import fit_report

        typer.echo(fit_report(res.to_json_dict()))
        typer.echo(f"wrote {out} and {side} ({res.timings['total']:.1f} s)")

    @app.command("show")
    @one_line_errors
    def show_cmd(
        fit: Path = typer.Argument(..., help="saved fit (fit.json of gprm fit or gprm demo)"),
        min_correl: float = typer.Option(0.9, "--min-correl", help="list parameter "
                                         "correlations with |C| at or above this"),
    ):
        """Print the fit report of a saved fit (the text that ends gprm fit)."""
        from gprm.errors import GprmInputError
        from gprm.fit.report_text import fit_report, read_fit_json

        if not 0 <= min_correl <= 1:
            raise GprmInputError(f"must be in [0, 1], got {min_correl}", field="--min-correl")
        typer.echo(fit_report(read_fit_json(fit), min_correl=min_correl))
