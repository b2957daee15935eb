"""CLI: ``gprm fit``."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from gprm.console import one_line_errors
from gprm.options import Int, Number, Race, Window


def register(app: typer.Typer, synth_app: typer.Typer) -> None:
    @app.command("fit")
    @one_line_errors
    def fit_cmd(
        means: Path = typer.Argument(..., help="mean-signals NetCDF (gprm preprocess)"),
        out: Path = typer.Option(..., "--out", help="fit result JSON (sidecar: same name .nc)"),
        starts: int = typer.Option(1000, "--starts", parser=Int(min=1),
                                   help="number of random starts"),
        seed: int = typer.Option(0, "--seed", parser=Int(min=0),
                                 help="random seed of the starts"),
        spread: float = typer.Option(0.2, "--spread", parser=Number(min=0, max=1,
                                     max_open=True), help="starts within ±spread of the "
                                     "paper's initial values (0 <= spread < 1)"),
        sampling: str = typer.Option("uniform", "--sampling", help="uniform or lhs"),
        params: Optional[Path] = typer.Option(None, "--params", help="TOML parameter file "
                                              "(constants, fitted set, bounds)"),
        piezo: int = typer.Option(2, "--piezo", parser=Int(min=1, max=2),
                                  help="driven piezo in the campaign: 1 or 2"),
        window: str = typer.Option("0.97ms,1.2ms", "--window", parser=Window("s"),
                                   help="fit window START,END (units: '0.97ms,1.2ms' or "
                                        "'0.97,1.2 ms'; bare numbers are s)"),
        sigma: str = typer.Option("sem", "--sigma", help="weights: sem (standard error of "
                                  "the mean) or std (the paper's across-run std)"),
        sigma_pool: int = typer.Option(3, "--sigma-pool", parser=Int(min=0),
                                       help="samples on each side over which sigma(t)^2 is "
                                       "averaged before it weighs the residuals (0: sample "
                                       "by sample; a sample's own sem from R runs is too "
                                       "noisy a weight, docs/fitting.md)"),
        workers: Optional[int] = typer.Option(None, "--workers", parser=Int(min=0),
                                              help="local worker processes (default: "
                                              "one per core, at most one per chunk of "
                                              "starts, 0 where that is fewer than 2: "
                                              "in this process, the fastest then; the "
                                              "result does not depend on it)"),
        scheduler: Optional[str] = typer.Option(None, "--scheduler",
                                                help="address of an existing Dask scheduler"),
        dashboard: Optional[str] = typer.Option(None, "--dashboard", help="run the workers on a "
                                                "local Dask cluster and serve its dashboard "
                                                "at this address, e.g. 127.0.0.1:8787 "
                                                "(default: none; the workers are then a "
                                                "plain process pool)"),
        chunk: int = typer.Option(250, "--chunk", parser=Int(min=1),
                                  help="starts per lock-step chunk (part of "
                                  "the result's definition, like the seed; smaller chunks "
                                  "spread over more workers)"),
        max_iter: int = typer.Option(100, "--max-iter", parser=Int(min=1),
                                     help="LM iteration limit per start"),
        stall_window: int = typer.Option(3, "--stall-window", parser=Int(min=0),
                                         help="stop a start once chi2 "
                                         "fell by at most --stall-tol over this many "
                                         "iterations (0: off; docs/fitting.md)"),
        stall_tol: float = typer.Option(0.03, "--stall-tol", parser=Number(min=0),
                                        help="chi2 decrease (absolute, over "
                                             "--stall-window iterations) that counts as "
                                             "stalled"),
        prune_after: int = typer.Option(10, "--prune-after", parser=Int(min=0),
                                        help="stop starts whose chi2 is "
                                        "over --prune-factor x the chunk's best after this "
                                        "many iterations, or that cannot reach it at their "
                                        "recent rate (0: never; docs/fitting.md)"),
        prune_factor: float = typer.Option(100.0, "--prune-factor",
                                           parser=Number(min=1, min_open=True),
                                           help="chi2 ratio to the chunk's best over which "
                                                "--prune-after stops a start (> 1)"),
        race: Optional[str] = typer.Option(None, "--race", parser=Race(),
                                           help="racing within each chunk: ITER:KEEP pairs "
                                           "(after ITER iterations only the KEEP best "
                                           "running starts go on; e.g. 3:25,6:5, about "
                                           "4x less CPU), or 'off' (default: every start "
                                           "runs to its own stop; racing can miss a best "
                                           "start that catches up late, docs/fitting.md)"),
        band_samples: int = typer.Option(200, "--band-samples", parser=Int(min=0),
                                         help="covariance samples "
                                         "for the sampled uncertainty bands"),
        profile: bool = typer.Option(False, "--profile", help="also compute profile "
                                     "likelihoods of every fitted parameter"),
        uncertainty: str = typer.Option("sandwich", "--uncertainty",
                                        help="uncertainty method: sandwich (default: the "
                                        "campaign's own runs and residuals, with the "
                                        "instrument systematics), laplace-prior, mcmc, "
                                        "eq7-corr, eq7 (the paper's) or generator-bootstrap "
                                        "(assumes gprm's synthetic generator's mismatch); "
                                        "docs/fitting.md compares their coverage"),
        boot: int = typer.Option(30, "--boot", parser=Int(min=5),
                                 help="campaigns of the generator bootstrap (>= 5)"),
        gain_sd: Optional[float] = typer.Option(None, "--gain-sd", parser=Number(min=0),
                                                help="gain (calibration) error of each "
                                                "laser channel, 1 sd, as a fraction (default: "
                                                "the parameter file's [systematics] gain, "
                                                "else 0; a gain error the residuals show is "
                                                "included anyway; docs/fitting.md)"),
        timing_sd: Optional[str] = typer.Option(None, "--timing-sd",
                                                help="timing offset of each channel "
                                                "beyond the fitted lags, 1 sd, e.g. '0.1us' "
                                                "(default: the parameter file's, else 0)"),
        prior_width: float = typer.Option(1.25, "--prior-width", parser=Number(min=0),
                                          help="width of the weak "
                                          "prior around the initial values (log units for "
                                          "positive parameters; 0: none, the paper's "
                                          "unregularised fit; docs/fitting.md)"),
        checkpoint: Optional[Path] = typer.Option(None, "--checkpoint", help="checkpoint "
                                                  "folder (default: OUT.ckpt); rerun resumes"),
        z_bk_absolute: bool = typer.Option(False, "--z-bk-absolute",
                                           help="fit z_bk as z_lr + z_A"),
        no_fit_offsets: bool = typer.Option(False, "--no-fit-offsets", help="do not fit the "
                                            "per-signal alignment offsets dt_x_head, "
                                            "dt_y_base, dt_y_head (fitted by default)"),
        no_resonance: bool = typer.Option(False, "--no-resonance", help="do not search the "
                                          "residuals for an unmodelled resonance (by "
                                          "default one that is found is marginalised as a "
                                          "nuisance; docs/fitting.md)"),
    ):
        """Multi-start Levenberg-Marquardt identification (Sec. 3.1)."""
        import os
        import re

        from rich.console import Console

        from gprm.errors import GprmInputError, GprmOutputError
        from gprm.fit.api import FitOptions, run_fit

        from gprm._io import check_outputs
        from gprm.fit.engine import (check_checkpoint_folder, default_workers,
                                     remove_checkpoints, starts_memory)
        from gprm.params import load_params
        from gprm.resources import check_memory
        from gprm.campaign.files import read_means

        if scheduler is not None and not re.fullmatch(
                r"(tcp|tls|inproc|ucx|ws|wss)://\S+|[\w.\-]+:\d+|\[[0-9a-fA-F:]+\]:\d+",
                scheduler):
            raise GprmInputError(f"expected a scheduler address such as tcp://HOST:PORT or "
                                 f"HOST:PORT, got {scheduler!r}", field="--scheduler")
        opts = _options(FitOptions, starts=starts, seed=seed, spread=spread, sampling=sampling,
                        window=window, sigma=sigma, sigma_pool=sigma_pool,
                        fit_offsets=not no_fit_offsets,
                        piezo=piezo, chunk=chunk, max_iter=max_iter,
                        stall_window=stall_window, stall_tol=stall_tol,
                        prune_after=prune_after, prune_factor=prune_factor,
                        **({} if race is None else {"race": race}),
                        band_samples=band_samples, profile=profile,
                        z_bk_absolute=z_bk_absolute, uncertainty=uncertainty,
                        prior_width=prior_width, boot=boot, gain_sd=gain_sd,
                        timing_sd=None if timing_sd is None else _seconds(timing_sd),
                        resonance=not no_resonance)
        ckpt = checkpoint if checkpoint is not None else Path(str(out) + ".ckpt")
        check_outputs({out: "--out", out.with_suffix(".nc"): "--out (its .nc sidecar)"},
                      inputs=[means, params], folders={ckpt: "--checkpoint"},
                      sidecars=[(out.with_suffix(".nc"), out)])
        check_checkpoint_folder(ckpt, field="--checkpoint")
        if out.suffix == ".nc":
            raise GprmInputError("must not end in .nc (that name is the sidecar's)",
                                 source=str(out), field="--out")
        ds = read_means(means)
        base = load_params(params)
        check_memory(starts, starts_memory(1, len(opts.parameters(base).fitted)),
                     field="--starts", what=f"{starts} starts")
        if band_samples:
            from gprm.fit.objective import fit_data_from_means

            # the sampled bands simulate every sample at once: 0.81-0.94 kB per sample and
            # fitted data point (tracemalloc peak of gprm.fit.uncertainty.compute_bands
            # between 100 and 400 samples over 5 x 47 and 5 x 181 points,
            # benchmarks/bench_memory.py; docs/README.md), + 50 MB
            n_points = int(fit_data_from_means(ds, window=opts.window, sigma=opts.sigma,
                                               source=str(means),
                                               sigma_pool=opts.sigma_pool).values.size)
            check_memory(band_samples, 1200.0 * n_points, fixed=50e6, field="--band-samples",
                         what=f"{band_samples} band samples of {n_points} data points",
                         integer=True)
        if workers is None:
            workers = 0 if scheduler else default_workers(starts, chunk)
        if workers < 0:
            raise GprmInputError(f"must be >= 0, got {workers}", field="--workers")
        n_cpu = os.cpu_count() or 1
        if not scheduler and workers > 4 * n_cpu:   # each is a process with its own memory
            raise GprmInputError(f"{workers} local worker processes on {n_cpu} cores; the "
                                 f"largest value accepted is {4 * n_cpu}", field="--workers")
        from gprm.fit.report_text import fit_report, polish_note, starts_progress

        # a refused or failed fit leaves no checkpoint folder of its own behind; one that was
        # there before (a resumed fit) keeps its chunks
        keep = dict(only_if_empty=ckpt.exists())
        err = Console(stderr=True)
        from gprm.fit.engine import worker_pool

        # the workers are started (forked) before the progress display starts its thread
        with worker_pool(workers, scheduler=scheduler, dashboard=dashboard) as pool, \
                starts_progress(err, starts) as progress:
            try:
                with dask_dashboard(dashboard):
                    res = run_fit(ds, opts, params=base, workers=workers,
                                  scheduler=scheduler, checkpoint_dir=ckpt,
                                  progress=progress, source=str(means), executor=pool)
            except GprmOutputError:
                # a write failed (no space, a quota): the chunks done so far stay, resumable
                remove_checkpoints(ckpt, only_if_empty=True)
                raise
            except GprmInputError as exc:
                remove_checkpoints(ckpt, **keep)               # refused: leave nothing behind
                if exc.field in ("checkpoint", "scheduler"):   # name the option as typed
                    raise GprmInputError(exc.problem, source=exc.source,
                                         field="--" + exc.field) from None
                raise
            except Exception:
                remove_checkpoints(ckpt, only_if_empty=True)   # an internal error: resumable
                raise
        # the bar showed the starts' best; the report shows the polished fit's chi-square
        err.print(polish_note(starts, progress.best, res.chi2, res.timings["total"]),
                  highlight=False, markup=False, soft_wrap=True)
        side = res.write(out)
        remove_checkpoints(ckpt)          # only what gprm wrote there, never other files
        from gprm.fit.files import read_fit_document

        # the file just written, read as `gprm show` reads it (the document is built once)
        typer.echo(fit_report(read_fit_document(out)))
        typer.echo(f"wrote {out} and {side} ({res.timings['total']:.1f} s)")

    @app.command("show")
    @one_line_errors
    def show_cmd(
        fit: Path = typer.Argument(..., help="saved fit (fit.json of gprm fit or gprm demo)"),
        min_correl: float = typer.Option(0.9, "--min-correl", parser=Number(0, 1),
                                         help="list parameter correlations with |C| at or "
                                              "above this (0..1)"),
    ):
        """Print the fit report of a saved fit (the text that ends gprm fit)."""
        from gprm.fit.files import read_fit_document
        from gprm.fit.report_text import fit_report

        typer.echo(fit_report(read_fit_document(fit), min_correl=min_correl))


def _seconds(text: str) -> float:
    """A time option ('0.1us', '1e-7', '0.1 us') in s; refused naming --timing-sd."""
    from gprm.params.files import _seconds as seconds

    return seconds(text.strip(), "command line", "--timing-sd")


def dask_dashboard(address):
    """Context: the Dask dashboard address of a local cluster (None: no dashboard)."""
    import dask

    return dask.config.set({"gprm.dashboard-address": address or None})


def _options(cls, **values):
    """``cls(**values)``; an invalid option is named as its command-line flag."""
    from gprm.errors import GprmInputError

    try:
        return cls(**values)
    except GprmInputError as exc:
        flag = None if exc.field is None else "--" + exc.field.replace("_", "-")
        raise GprmInputError(exc.problem, source=exc.source, field=flag) from None
