"""What the commands print on bad input, shared by every stage's ``commands`` module and by
:mod:`gprm.cli`: one line ``gprm: error: ...`` on stderr and exit code 2.

It sits below the stages (it imports only :mod:`gprm.errors` and typer), so a stage's
commands never import the CLI module that registers them.
"""

from __future__ import annotations

import functools
from typing import Mapping

import typer

from gprm.errors import GprmInputError


def one_line(text) -> str:
    """``text`` on one line (runs of whitespace, newlines included, become one space)."""
    return " ".join(str(text).split())


def one_line_errors(fn):
    """Decorator for commands: bad input -> one line on stderr, exit code 2."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except GprmInputError as exc:
            typer.echo(f"gprm: error: {one_line(exc)}", err=True)
            raise typer.Exit(code=2) from None

    return wrapper


def cli_options(cls, flags: Mapping[str, str] | None = None, **values):
    """``cls(**values)`` for a command: an option dataclass validated on construction, whose
    error names the field; here it is named as the command-line flag that set it (``flags``:
    field -> flag where they differ; else ``--`` + the field with ``-`` for ``_``)."""
    try:
        return cls(**values)
    except GprmInputError as exc:
        f = exc.field
        if f is None or f.startswith("-"):
            raise
        flag = (flags or {}).get(f) or "--" + f.replace("_", "-")
        raise GprmInputError(exc.problem, source=exc.source, field=flag) from None
