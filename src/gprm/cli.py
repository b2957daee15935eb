"""The ``gprm`` command: argument parsing and printing only; the work is in the library.

Each stage contributes its commands from ``gprm/<stage>/commands.py`` through a
``register(app, synth_app)`` function, so this file stays small. Every command turns a
:class:`gprm.errors.GprmInputError` into a one-line message on stderr and exit code 2.
"""

from __future__ import annotations

import functools
import importlib
import sys

import typer

from gprm.errors import GprmInputError

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="gprm: GPRM ground-test identification and flight analysis.")
synth_app = typer.Typer(add_completion=False, no_args_is_help=True,
                        help="Synthetic data with known truth (campaigns, telemetry).")
app.add_typer(synth_app, name="synth")


def one_line_errors(fn):
    """Decorator for commands: bad input -> one line on stderr, exit code 2."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except GprmInputError as exc:
            typer.echo(f"gprm: error: {exc}", err=True)
            raise typer.Exit(code=2) from None

    return wrapper


_STAGES = ("params", "simulate", "campaign", "fit", "predict", "flight", "report", "run", "demo")


def _register_all() -> None:
    for stage in _STAGES:
        try:
            mod = importlib.import_module(f"gprm.{stage}.commands")
        except ModuleNotFoundError as exc:
            if exc.name == f"gprm.{stage}.commands" or exc.name == f"gprm.{stage}":
                continue  # stage not present
            raise
        mod.register(app, synth_app)


_register_all()


def main() -> None:  # console-script entry point
    app(prog_name="gprm")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
