"""CLI: ``gprm run``: the whole chain on the user's campaign (and, optionally, real
telemetry), resumable, ending in report.html; the progress display and closing tables it
shares with ``gprm demo``."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Optional

import typer

from gprm.console import ProgressLines, cli_options, one_line_errors
from gprm.fit.report_text import weights_label
from gprm.options import Int

if TYPE_CHECKING:
    from rich.progress import TaskID


def register(app: typer.Typer, synth_app: typer.Typer) -> None:
    @app.command("run")
    @one_line_errors
    def run_cmd(
        campaign: Path = typer.Argument(..., help="campaign: NetCDF file or CSV folder with "
                                        "manifest.csv"),
        out: Path = typer.Option(..., "--out", help="run directory (created; a rerun resumes "
                                 "what is up to date)"),
        telemetry: Optional[Path] = typer.Option(None, "--telemetry", help="in-flight "
                                                 "telemetry file, NetCDF or CSV (default: "
                                                 "synthetic releases drawn from the fit)"),
        quick: bool = typer.Option(False, "--quick", help="50 starts, fewer band samples"),
        seed: int = typer.Option(0, "--seed", parser=Int(min=0), help="seed of the starts, the sampled bands "
                                 "and synthetic telemetry"),
        starts: Optional[int] = typer.Option(None, "--starts", parser=Int(min=1), help="random starts of the fit "
                                             "(default 1000, or 50 with --quick)"),
        workers: Optional[int] = typer.Option(None, "--workers", parser=Int(min=0), help="local worker "
                                              "processes for the fit (default: one per core, "
                                              "at most one per chunk of 250 starts, 0 where "
                                              "that is fewer than 2, as with --quick: in "
                                              "this process; the result does not depend on "
                                              "it)"),
        releases: int = typer.Option(11, "--releases", parser=Int(2, 10_000), help="synthetic releases (without "
                                     "--telemetry)"),
    ):
        """The whole chain on a campaign, resumable, ending in report.html.

        campaign -> preprocess -> fit -> predict, what-ifs -> telemetry -> impact -> report
        """
        from gprm.run.options import RunOptions

        opts = make_options(RunOptions, quick=quick, seed=seed, starts=starts, workers=workers,
                            campaign=campaign, telemetry=telemetry, releases=releases)
        run_and_print(out, opts, demo=False)


def make_options(cls, *, quick, seed, starts, workers, **kw):
    """RunOptions from command-line values; a bad value is named as its flag. The default
    ``workers`` is the fit's (:func:`gprm.fit.engine.default_workers`) for the starts the
    run will make."""
    opts = cli_options(cls.make, quick=quick, seed=seed, starts=starts, workers=workers or 0,
                       **kw)
    if workers is None:
        from dataclasses import replace

        from gprm.fit.engine import default_workers

        opts = replace(opts, workers=default_workers(opts.fit.starts, opts.fit.chunk))
    return opts


def run_and_print(out: Path, opts, *, demo: bool) -> None:
    """Run (or, for ``gprm demo``, generate and run) with the progress display, print the
    closing tables, exit 1 if a stage failed."""
    import sys

    from rich.console import Console

    from gprm.run import run_chain, run_demo, stage_titles

    from gprm.run.api import check_run_outputs

    titles = stage_titles(opts)
    name = "gprm demo" if demo else "gprm run"
    if demo:
        from dataclasses import replace

        opts = replace(opts, campaign=None, telemetry=None)
    check_run_outputs(out, opts, field="--out")    # before the progress display starts
    from gprm.fit.engine import worker_pool

    # the fit's workers start (are forked) before the progress display starts its thread
    with worker_pool(opts.workers) as pool, _Progress(Console(stderr=True), titles) as prog:
        res = (run_demo if demo else run_chain)(out, opts, progress=prog.event,
                                                command="gprm " + " ".join(sys.argv[1:]),
                                                executor=pool)
    print_summary(Console(), res, titles, name)
    failed = [r for r in res.records if r.status == "failed"]
    if failed:
        typer.echo("gprm: error: stage(s) failed: "
                   + "; ".join(f"{r.name}: {r.detail}" for r in failed)
                   + f" (details in {out / 'run.json'})", err=True)
        raise typer.Exit(code=1)


class _Progress:
    """One line per stage: spinner while it runs, a bar where the stage reports steps; the
    fit's line counts starts with the best chi-square of the starts so far and the time
    remaining, as ``gprm fit`` shows them (the same progress callback of the library).

    Without a terminal (a log file, a pipe) the stages are plain lines instead
    (:class:`gprm.console.ProgressLines`: start, every tenth of the starts, at least every
    ``every`` seconds while a stage runs, and its outcome). The rich display starts with the
    first stage, so an error before any stage prints only its own line."""

    def __init__(self, console, titles: dict[str, str], *, every: float = 10.0):
        self.console = console
        self.titles = titles
        self.bar = None
        self.lines = None if console.is_terminal else ProgressLines(console.file, every=every)
        self.tasks: dict[str, TaskID] = {}     # stage -> its line

    def _bar(self):
        if self.bar is None:
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, SpinnerColumn,
                                       TextColumn, TimeElapsedColumn, TimeRemainingColumn)

            self.bar = Progress(SpinnerColumn(finished_text="•"),
                                TextColumn("{task.description}"), BarColumn(),
                                MofNCompleteColumn(), TextColumn("{task.fields[info]}"),
                                TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(),
                                console=self.console)
            self.bar.__enter__()
        return self.bar

    def __enter__(self):
        if self.lines is not None:
            self.lines.__enter__()
        return self

    def __exit__(self, *exc):
        if self.lines is not None:
            self.lines.__exit__(*exc)
        if self.bar is not None:
            return self.bar.__exit__(*exc)
        return None

    def event(self, stage: str, kind: str, done=None, total=None, best_chi2=None):
        if self.lines is not None:
            self._line(stage, kind, done, total, best_chi2)
            return
        from gprm.fit.report_text import AFTER_STARTS, starts_info

        bar = self._bar()
        title = self.titles.get(stage, stage)
        if kind == "start":
            self.tasks[stage] = bar.add_task(f"[bold]{title}", total=None, info="")
        elif kind == "step" and stage in self.tasks:
            info = "" if best_chi2 is None else starts_info(best_chi2)
            if info and total and done >= total:
                info += AFTER_STARTS
            bar.update(self.tasks[stage], completed=done, total=total, info=info)
        elif kind == "done" and stage in self.tasks:
            # a stage that counted steps (the fit's starts) keeps its count (1000/1000
            # starts); the elapsed time is the stage's, not that of its last step: a change
            # of total restarts rich's finish clock
            n = next((t.total for t in bar.tasks if t.id == self.tasks[stage]), None) or 1
            info = next((t.fields.get("info", "") for t in bar.tasks
                         if t.id == self.tasks[stage]), "").replace(AFTER_STARTS, "")
            bar.update(self.tasks[stage], total=n + 1)
            bar.update(self.tasks[stage], description=f"[green]✓ {title}", total=n,
                       completed=n, info=info)
        else:
            label = {"skip": "[dim]↷ {} (up to date)", "unavailable": "[yellow]– {} (not "
                     "available)", "blocked": "[yellow]– {} (needs an earlier stage)",
                     "fail": "[red]✗ {} (failed)",
                     "interrupted": "[yellow]✗ {} (interrupted)"}.get(kind)
            if label is None:
                return
            if stage in self.tasks:      # finished (full bar, no spinner), with its outcome
                bar.update(self.tasks[stage], description=label.format(title), total=1,
                           completed=1)
            else:
                self.tasks[stage] = bar.add_task(label.format(title), total=1, info="")
                bar.update(self.tasks[stage], completed=1)

    def _line(self, stage: str, kind: str, done, total, best_chi2) -> None:
        """The event as plain lines (no terminal)."""
        from gprm.fit.report_text import AFTER_STARTS, BEST_START

        lines = self.lines
        assert lines is not None
        title = self.titles.get(stage, stage)
        if kind == "start":
            lines.start(stage, title)
        elif kind == "step":
            if best_chi2 is None:
                lines.update(stage, done, total)
            else:
                best = f"{best_chi2:.6g}" if math.isfinite(best_chi2) else "-"
                after = AFTER_STARTS if total and done >= total else ""
                lines.update(stage, done, total, "starts", f"{BEST_START} {best}{after}")
        elif kind == "done":
            lines.finish(stage, f"{title}: done in {lines.elapsed(stage):.1f} s")
        else:
            outcome = {"skip": "skipped (up to date)", "unavailable": "not available",
                       "blocked": "blocked (needs an earlier stage)",
                       "fail": "failed", "interrupted": "interrupted"}.get(kind)
            if outcome is not None:
                lines.finish(stage, f"{title}: {outcome}")


def _f(v, fmt="{:.4g}"):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "—"
    return fmt.format(v)


def print_summary(console, res, titles: dict[str, str], name: str = "gprm run") -> None:
    """The closing tables: stages with timings, then the results."""
    from rich.table import Table

    t = Table(title=f"{name} → {res.run_dir}", title_justify="left")
    t.add_column("stage")
    t.add_column("status")
    t.add_column("time [s]", justify="right")
    for r in res.records:
        colour = {"ran": "green", "skipped": "dim", "failed": "red"}.get(r.status, "yellow")
        t.add_row(titles.get(r.name, r.name), f"[{colour}]{r.status}[/]"
                  + (f" [dim]({r.detail})[/]" if r.detail and r.status != "skipped" else ""),
                  _f(r.seconds, "{:.1f}") if r.status == "ran" else "—")
    t.add_row("[bold]total", "", f"{res.total_seconds:.1f}")
    console.print(t)

    from gprm.run.stages import NO_UNCERTAINTY

    s = res.summary
    k = Table(title="Results", title_justify="left", show_header=False)
    k.add_column("quantity")
    k.add_column("value")
    if "fit" in s:
        f = s["fit"]
        k.add_row("best χ² (polished fit)", f"{_f(f['chi2'])} for {f['dof']} degrees of freedom")
        k.add_row("reduced χ²", f"{_f(f['reduced_chi2'])} (weights: "
                  f"{weights_label(f.get('sigma'), f.get('sigma_pool'), '±')})")
        k.add_row("starts at the best (Δχ² ≤ 1)", f"{f.get('n_at_best')} of {f.get('starts')}"
                  f" ({f.get('converged')} converged)")
    if "fit" in s and any(NO_UNCERTAINTY in n for r in res.records
                          for n in (r.info or {}).get("notes", [])):
        k.add_row("[yellow]uncertainty", f"{NO_UNCERTAINTY} (see the notes in run.json)")
    tr = s.get("truth_recovery")
    if tr is not None and not (tr["n"] or tr.get("n_interval") or tr.get("undetermined")):
        mrel = tr.get("mass_max_relative_error")
        k.add_row("truth recovery", "no standard errors (the fit has no covariance)" + (
            "" if mrel is None else f"; masses m1–m4 within {100 * mrel:.1f} % of the truth"))
    elif tr is not None:
        from gprm.report.summary import truth_recovery_text   # xarray: only for a summary

        k.add_row("truth recovery", truth_recovery_text(tr))
    if "whatif" in s and s["whatif"]:
        for name, ratios in s["whatif"].items():
            if isinstance(ratios, dict):
                txt = ", ".join(f"{a} {_f(v, '{:.3g}')}" for a, v in ratios.items())
            else:
                txt = _f(ratios, "{:.3g}")
            paper = (s.get("whatif_paper") or {}).get(name)
            if paper:
                txt += " (paper: " + ", ".join(f"{a} {v:g}" for a, v in paper.items()) + ")"
            k.add_row(f"overshoot Piezo 2 / {name}", txt)
    if "tukey" in s:
        tk = s["tukey"]
        k.add_row(f"Tukey test (α = {tk.get('alpha')})", f"{tk['verdict']}; "
                  f"{s.get('releases', '?')} releases")
    if "joint" in s:
        jt = s["joint"]
        k.add_row(f"joint impact time (α = {jt.get('alpha')})",
                  ("[red]" if jt["rejected"] else "") + jt["verdict"])
    if "scenario" in s:
        k.add_row("impact scenario (joint)", s["scenario"])
    notes: dict[str, list[str]] = {}
    for r in res.records:
        for note in (r.info or {}).get("notes", []):
            notes.setdefault(note, []).append(r.name)
    if notes:            # the first in full, the rest counted (all are in run.json)
        first, where = next(iter(notes.items()))
        stages = sorted({w for ws in notes.values() for w in ws})
        more = f" (+{len(notes) - 1} more in run.json)" if len(notes) > 1 else ""
        k.add_row(f"[yellow]notes ({', '.join(stages)})", first + more)
    if not s:
        k.add_row("no results", "no stage produced output (see the stage table)")
    console.print(k)
    console.print(f"report: {Path(res.run_dir) / 'report.html'}")
