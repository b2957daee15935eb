"""CLI: ``gprm params``."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from gprm.console import one_line_errors


def register(app: typer.Typer, synth_app: typer.Typer) -> None:
    @app.command("params")
    @one_line_errors
    def params_cmd(
        set_name: str = typer.Option("paper", "--set", help="built-in parameter set"),
        params: Optional[Path] = typer.Option(None, "--params", help="TOML parameter file"),
        out: Optional[Path] = typer.Option(None, "--out", help="write the resolved set as TOML"),
    ):
        """Print the resolved parameter table with units."""
        from rich.console import Console
        from rich.table import Table

        from gprm.errors import GprmInputError
        from gprm.params import REGISTRY, from_si, load_params, save_params

        if set_name != "paper":
            raise GprmInputError(f"unknown parameter set {set_name!r} (known: paper)",
                                 field="--set")
        from gprm._io import check_outputs

        check_outputs({out: "--out"}, inputs=[params])
        ps = load_params(params)
        table = Table(title=f"Parameters ({ps.source})")
        for col in ("name", "value", "unit", "role", "paper ±", "description"):
            table.add_column(col)
        for name, spec in REGISTRY.items():
            err = "" if spec.paper_stderr is None else f"{from_si(spec.paper_stderr, name):.3g}"
            role = "fitted" if name in ps.fitted else spec.group
            table.add_row(name, f"{from_si(ps.values[name], name):.6g}", spec.unit, role, err,
                          spec.description)
        Console(width=160).print(table)
        if out is not None:
            save_params(ps, out)
