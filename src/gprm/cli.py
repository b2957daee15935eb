"""The ``gprm`` command: argument parsing and printing only; the work is in the library.

Each stage contributes its commands from ``gprm/<stage>/commands.py`` through a
``register(app, synth_app)`` function, imported here statically in pipeline order, so this
file stays small and the import graph is the one a reader sees. The commands import
:func:`gprm.console.one_line_errors` (below the stages), never this module.

What reaches the console is always short:

- bad input (:class:`gprm.errors.GprmInputError`) and bad options (click's usage errors): one
  line ``gprm: error: ...`` on stderr, exit code 2;
- any other exception: one line naming a log file that holds the traceback, exit code 1
  (``gprm --debug CMD ...`` or ``GPRM_DEBUG=1`` prints the traceback instead);
- Ctrl-C: one line, exit code 130; SIGTERM (and SIGHUP) end gprm the same way, as an
  exception, so that temporary files of unfinished writes are removed and ``gprm run``
  records where it stopped: one line, exit code 143 (129).
"""

from __future__ import annotations

import contextlib
import datetime
import inspect
import os
import signal
import sys
import tempfile
import threading
import traceback
from pathlib import Path
from typing import Any, Iterator

import typer

try:                                   # typer >= 0.2x ships its own click; its errors are these
    from typer import _click as click
    from typer._click.exceptions import NoArgsIsHelpError
except ImportError:                    # older typer (the lower bound) uses the click package
    # mypy sees the newer typer: click's classes differ from typer._click's there, not here
    import click  # type: ignore[no-redef]
    from click.exceptions import NoArgsIsHelpError  # type: ignore[assignment]
from typer.core import TyperGroup
try:
    from typer.exceptions import Abort
except ImportError:                    # older typer: click's
    from click.exceptions import Abort  # type: ignore[assignment]  # as above

from gprm.campaign import commands as campaign_commands
from gprm.console import one_line as _one_line, one_line_errors
from gprm.demo import commands as demo_commands
from gprm.design import commands as design_commands
from gprm.errors import GprmInputError
from gprm.fit import commands as fit_commands
from gprm.flight import commands as flight_commands
from gprm.params import commands as params_commands
from gprm.predict import commands as predict_commands
from gprm.report import commands as report_commands
from gprm.run import commands as run_commands
from gprm.simulate import commands as simulate_commands


def _debug_requested(args) -> bool:
    if os.environ.get("GPRM_DEBUG", "") not in ("", "0"):
        return True
    args = list(sys.argv[1:] if args is None else args)
    head = []
    for a in args:              # only the options before the subcommand are gprm's own
        if not a.startswith("-"):
            break
        head.append(a)
    return "--debug" in head


def log_dir() -> Path:
    """Where tracebacks of unexpected errors go: $GPRM_LOG_DIR, else the user's state folder
    (``$XDG_STATE_HOME/gprm/logs``, default ``~/.local/state/gprm/logs``)."""
    if os.environ.get("GPRM_LOG_DIR"):
        return Path(os.environ["GPRM_LOG_DIR"])
    state = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(state) / "gprm" / "logs"


def write_crash_log(exc: BaseException, args) -> Path:
    """Write the traceback of ``exc`` (with the command line) to a new log file; its path."""
    text = ("gprm " + " ".join(str(a) for a in (sys.argv[1:] if args is None else args))
            + "\n\n" + "".join(traceback.format_exception(exc)))
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    name = f"gprm-error-{stamp}-{os.getpid()}.log"
    for folder in (log_dir(), Path(tempfile.gettempdir())):
        try:
            folder.mkdir(parents=True, exist_ok=True)
            path = folder / name
            path.write_text(text, encoding="utf-8")
            return path
        except OSError:
            continue
    raise OSError("no writable folder for the error log")


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised where the program is, as Ctrl-C raises KeyboardInterrupt:
    every clean-up (``finally``, temporary files, the fit's cluster) runs."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


_STOP_SIGNALS = tuple(getattr(signal, n) for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n))


@contextlib.contextmanager
def stop_signals_raise() -> Iterator[dict[str, Any]]:
    """While the command runs, SIGTERM and SIGHUP raise :class:`Terminated` (a second one
    ends the process at once, the system's default; one the caller ignores stays ignored). Yields a dict whose ``signum`` says
    which signal arrived (None: none). Only the main thread can take signals; elsewhere
    nothing changes."""
    got: dict[str, Any] = {"signum": None, "armed": True}
    if threading.current_thread() is not threading.main_thread():
        yield got
        return

    def on_signal(signum, frame):
        got["signum"] = signum
        for s in old:
            signal.signal(s, signal.SIG_DFL)
        if got["armed"]:            # not once the command has finished: only the exit code
            raise Terminated(signum)

    # a signal the caller ignores stays ignored (`nohup gprm run ...` survives a hangup)
    old = {s: signal.signal(s, on_signal) for s in _STOP_SIGNALS
           if signal.getsignal(s) is not signal.SIG_IGN}
    try:
        yield got
    finally:
        for s, h in old.items():
            signal.signal(s, h)


class _GprmGroup(TyperGroup):
    """The root group: every error leaves as one line with a meaningful exit code."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True,
             **extra):
        with stop_signals_raise() as got:
            try:
                code = self._main(args, prog_name, complete_var, **extra)
            except KeyboardInterrupt:   # arrived while an error was being reported
                code = 130
            finally:
                got["armed"] = False
            if got["signum"] is not None:
                name = signal.Signals(got["signum"]).name
                click.echo(f"gprm: stopped by {name}; unfinished outputs were not written",
                           err=True)
                code = 128 + got["signum"]
            elif code == 130:       # Ctrl-C (typer returns its exit code silently)
                click.echo("gprm: interrupted; unfinished outputs were not written", err=True)
        if standalone_mode:
            sys.exit(code)
        return code

    def _main(self, args, prog_name, complete_var, **extra) -> int:
        code = 0
        try:
            rv = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
            code = rv if isinstance(rv, int) else 0
        except GprmInputError as exc:
            click.echo(f"gprm: error: {_one_line(exc)}", err=True)
            code = 2
        except NoArgsIsHelpError as exc:          # `gprm`, `gprm synth`: the help
            click.echo(exc.ctx.get_help() if exc.ctx is not None else exc.format_message())
            code = exc.exit_code
        except click.ClickException as exc:       # usage errors: bad option or argument
            msg = _one_line(exc.format_message()).replace(": Value error, ", ": ")
            click.echo(f"gprm: error: {msg}", err=True)
            code = exc.exit_code
        except Abort:
            code = 130
        except Exception as exc:                   # a bug or an environment problem
            if _debug_requested(args):
                traceback.print_exception(exc, file=sys.stderr)
                code = 1
            else:
                try:
                    where = f"traceback in {write_crash_log(exc, args)}"
                except OSError:
                    where = "no log written; rerun with gprm --debug for the traceback"
                click.echo(f"gprm: internal error ({type(exc).__name__}: "
                           f"{_one_line(exc)[:200]}); {where}", err=True)
                code = 1
        return code


app = typer.Typer(cls=_GprmGroup, add_completion=False, no_args_is_help=True,
                  rich_markup_mode=None, pretty_exceptions_enable=False,
                  help="gprm: GPRM ground-test identification and flight analysis.")
synth_app = typer.Typer(add_completion=False, no_args_is_help=True, rich_markup_mode=None,
                        help="Synthetic data with known truth (campaigns, telemetry).")
app.add_typer(synth_app, name="synth")


@app.callback()
def _root(debug: bool = typer.Option(False, "--debug", help="print the traceback of an "
                                     "unexpected error instead of writing it to a log file")):
    """gprm: GPRM ground-test identification and flight analysis."""


#: the stages' commands, registered in pipeline order (the order of ``gprm --help``)
STAGE_COMMANDS = (params_commands, simulate_commands, campaign_commands, fit_commands,
                  predict_commands, flight_commands, design_commands, report_commands, run_commands,
                  demo_commands)
for _mod in STAGE_COMMANDS:
    _mod.register(app, synth_app)


def _whole_summaries(typer_app: typer.Typer) -> None:
    """The summary of each command in ``--help`` is the first paragraph of its docstring,
    whole. Left to click it ends at the first period ("(Sec.") and is cut to fit one line
    ("and write..."); given as ``short_help`` it is wrapped onto the next lines instead."""
    for info in typer_app.registered_commands:
        doc = getattr(info.callback, "__doc__", None)
        if info.short_help is None and doc:
            info.short_help = " ".join(inspect.cleandoc(doc).split("\n\n")[0].split())


_whole_summaries(app)
_whole_summaries(synth_app)

__all__ = ["app", "main", "one_line_errors", "synth_app"]


def main() -> None:  # console-script entry point
    app(prog_name="gprm")


if __name__ == "__main__":  # pragma: no cover
    main()
