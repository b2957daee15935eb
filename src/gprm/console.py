"""What the commands print, shared by every stage's ``commands`` module and by
:mod:`gprm.cli`: on bad input one line ``gprm: error: ...`` on stderr and exit code 2; and
progress as plain lines where stderr is not a terminal (:class:`ProgressLines`).

It sits below the stages (it imports only :mod:`gprm.errors` and typer), so a stage's
commands never import the CLI module that registers them.
"""

from __future__ import annotations

import functools
import sys
import threading
import time
from typing import Callable, Mapping, TextIO

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


def clock_text(seconds: float) -> str:
    """``H:MM:SS`` of a duration (``-:--:--`` when unknown)."""
    if not (seconds >= 0 and seconds < float("inf")):
        return "-:--:--"
    s = int(round(seconds))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


class ProgressLines:
    """Progress for a stream that is not a terminal (a log file, a pipe, CI): plain ASCII
    lines, no cursor movement, no bars cut to the width of an unknown screen.

    A task (a stage, the fit's starts) gets a line when it starts, one each time its count
    passes another tenth of its total, one when it ends, and, while it runs, one at least
    every ``every`` seconds from a background thread, so that a long step without news
    still shows that it is alive and how long it has taken. Use it as a context manager (the
    thread runs inside the ``with``)::

        with ProgressLines() as lines:
            lines.start("fit", "fit")
            lines.update("fit", 250, 1000, "starts")
            lines.finish("fit", "fit: done in 83.1 s")
    """

    def __init__(self, file: TextIO | None = None, *, every: float = 10.0,
                 clock: Callable[[], float] = time.monotonic):
        self.file = file
        self.every = float(every)
        self.clock = clock
        self._lock = threading.Lock()
        self._tasks: dict[str, dict] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ output
    def line(self, text: str) -> None:
        """Print one line now."""
        out = self.file if self.file is not None else sys.stderr
        with self._lock:
            print(text, file=out, flush=True)

    def status(self, name: str) -> str:
        """The task's line: count, share, what the caller says about it, time taken and
        (with a count) time remaining."""
        return self._status(self._tasks[name])

    def _status(self, t: dict) -> str:
        elapsed = self.clock() - t["t0"]
        done, total = t["done"], t["total"]
        parts = [f"{t['label']}:"]
        if total:
            parts.append(f"{done}/{total}" + (f" {t['unit']}" if t["unit"] else "")
                         + f" ({100 * done / total:.0f} %)")
        else:
            parts.append("running")
        text = " ".join(parts) + (f", {t['info']}" if t["info"] else "")
        text += f"; {clock_text(elapsed)} elapsed"
        if total and done < total:
            counted = done - t["done0"]
            rate = counted / (self.clock() - t["t_first"]) if counted > 0 else 0.0
            eta = (total - done) / rate if rate > 0 else float("nan")
            text += f", eta {clock_text(eta)}"
        return text

    # ------------------------------------------------------------------ tasks
    def start(self, name: str, label: str | None = None) -> None:
        now = self.clock()
        self._tasks[name] = {"label": label or name, "done": 0, "total": None, "unit": "",
                             "info": "", "t0": now, "t_first": now, "done0": 0,
                             "tenth": -1, "last": now}
        self.line(f"{label or name}: started")

    def update(self, name: str, done: int, total: int | None, unit: str = "",
               info: str = "") -> None:
        """A new count (``done`` of ``total`` ``unit``) and what to say beside it."""
        if name not in self._tasks:
            self.start(name)
        t = self._tasks[name]
        if t["total"] is None and total:           # the first count: the rate starts here
            t["t_first"], t["done0"] = self.clock(), int(done)
        t.update(done=int(done), total=None if total is None else int(total), unit=unit,
                 info=info)
        tenth = int(10 * done // total) if total else 0
        if tenth > t["tenth"]:
            t["tenth"] = tenth
            t["last"] = self.clock()
            self.line(self.status(name))

    def finish(self, name: str, text: str) -> None:
        """The task's last line, ``text``; it is no longer followed."""
        self._tasks.pop(name, None)
        self.line(text)

    def elapsed(self, name: str) -> float:
        t = self._tasks.get(name)
        return float("nan") if t is None else self.clock() - t["t0"]

    def beat(self) -> None:
        """A line for each task that has had none for ``every`` seconds (the heartbeat
        thread calls this; tests may too)."""
        now = self.clock()
        for t in list(self._tasks.values()):
            if now - t["last"] >= self.every:
                t["last"] = now
                self.line(self._status(t))

    def _run(self) -> None:
        while not self._stop.wait(min(1.0, self.every / 4)):
            self.beat()

    def __enter__(self) -> "ProgressLines":
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="gprm-progress", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self._thread = None
