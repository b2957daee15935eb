"""CLI: ``gprm report``."""

from __future__ import annotations

from pathlib import Path

import typer

from gprm.console import one_line_errors


def register(app: typer.Typer, synth_app: typer.Typer) -> None:
    @app.command("report")
    @one_line_errors
    def report_cmd(
        run_dir: Path = typer.Argument(..., help="run directory (as written by gprm demo)"),
        out: Path = typer.Option(..., "--out", help="the self-contained HTML report"),
    ):
        """One self-contained HTML report (figures inline, no network) of a run directory."""
        from gprm._io import check_outputs
        from gprm.errors import GprmInputError
        from gprm.report.build import write_report

        if not run_dir.is_dir():
            raise GprmInputError("is not a folder (expected a run directory)",
                                 source=str(run_dir))
        from gprm._io import files_read_from

        check_outputs({out: "--out"},
                      inputs=files_read_from(run_dir, suffixes={".nc", ".json", ".toml"}))

        path = write_report(run_dir, out)
        typer.echo(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB)")
