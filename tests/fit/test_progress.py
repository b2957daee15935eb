"""One progress callback of the fit for ``gprm fit``, ``gprm run`` and ``gprm demo``: starts
done, starts requested and the best chi-square so far, shown with the time remaining."""

from __future__ import annotations

import io
import re
import time

import pytest
from rich.console import Console

from gprm.console import ProgressLines
from gprm.fit.report_text import polish_note, starts_info, starts_progress
from gprm.run.engine import Stage, run_stages


class _Opts:
    seed = 0


def _fit_like_stage(best_values):
    """A stage that reports like the fit does: (done, total, best_chi2=...)."""
    def run(run_dir, opts, step):
        for k, best in enumerate(best_values, 1):
            step(2 * k, 2 * len(best_values), best_chi2=best)
        (run_dir / "out.txt").write_text("x")
        return {}
    return Stage("fit", "fit", (), ("out.txt",), lambda o: {}, run)


def test_the_run_forwards_starts_and_best_chi2_to_a_callback_that_takes_it(tmp_path):
    events = []

    def progress(stage, event, done, total, best_chi2=None):
        events.append((stage, event, done, total, best_chi2))

    run_stages(tmp_path, _Opts(), [_fit_like_stage([50.0, 20.0, 12.5])], progress=progress,
               report_html=False)
    steps = [e for e in events if e[1] == "step"]
    assert steps == [("fit", "step", 2, 6, 50.0), ("fit", "step", 4, 6, 20.0),
                     ("fit", "step", 6, 6, 12.5)]


def test_a_callback_of_four_arguments_still_gets_its_steps(tmp_path):
    events = []
    run_stages(tmp_path, _Opts(), [_fit_like_stage([7.0])],
               progress=lambda stage, event, done, total: events.append((stage, event, done,
                                                                         total)),
               report_html=False)
    assert ("fit", "step", 2, 2) in events


def _render(bar) -> str:
    out = io.StringIO()
    Console(file=out, width=200, color_system=None).print(bar.get_renderable())
    return out.getvalue()


def _terminal(out=None) -> Console:
    return Console(file=out or io.StringIO(), force_terminal=True, width=200)


def test_run_and_fit_displays_show_starts_best_chi2_and_time_remaining():
    """On a terminal ``gprm run``/``gprm demo`` show the fit's line as ``gprm fit`` does:
    starts done of requested, the best chi-square of the starts so far (labelled as before
    the polish), and the time remaining."""
    from gprm.run.commands import _Progress

    prog = _Progress(_terminal(), {"fit": "fit (multi-start LM)"})
    with prog:
        prog.event("fit", "start")
        prog.event("fit", "step", 250, 1000, best_chi2=1234.5678)
        line = _render(prog.bar)
        assert "250/1000" in line and starts_info(1234.5678) in line and "eta" in line
        assert "best start chi2 (before polish) 1234.57" in line
        prog.event("fit", "step", 1000, 1000, best_chi2=1200.0)
        assert "polishing the best start" in _render(prog.bar)
        prog.event("fit", "done")
        text = _render(prog.bar)
        assert "1000/1000" in text and "best start chi2 (before polish) 1200" in text
        assert "polishing" not in text

    fit = starts_progress(_terminal(), 1000)
    callback = fit.__enter__()
    try:
        callback(250, 1000, best_chi2=1234.5678)
        text = _render(fit.bar)
    finally:
        fit.__exit__(None, None, None)
    assert "250/1000" in text and starts_info(1234.5678) in text and "eta" in text
    assert callback.best == 1234.5678


def test_best_chi2_text_before_the_first_chunk():
    assert starts_info(float("nan")) == "starts  best start chi2 (before polish) -"
    assert starts_info(3.5) == "starts  best start chi2 (before polish) 3.5"


def test_the_note_after_the_starts_names_both_chi_squares():
    """Issue 22: the progress said 265.088, the report 257.5; the line after the starts says
    which is which."""
    text = polish_note(1000, 265.088, 257.5, 83.0)
    assert "best start chi2 265.088 before the polish" in text
    assert "chi2 257.5 after it (the data's alone: the report's)" in text
    assert "1000 starts" in text


class _Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_progress_lines_without_a_terminal():
    """Issue 22: without a terminal the fit printed nothing until the end. Plain lines: one
    when a task starts, one per tenth of its count, one at least every ``every`` seconds
    while it runs, with the time taken and the time remaining; ASCII only."""
    out, clock = io.StringIO(), _Clock()
    lines = ProgressLines(out, every=10.0, clock=clock)
    lines.start("fit", "fit")
    lines.update("fit", 0, 1000, "starts", "best -")
    for done in range(50, 1001, 50):              # twenty updates: one line per tenth
        clock.t += 2.0
        lines.update("fit", done, 1000, "starts", f"best {done}")
    text = out.getvalue().splitlines()
    assert text[0] == "fit: started"
    assert text[1].startswith("fit: 0/1000 starts (0 %), best -; 0:00:00 elapsed")
    tenths = [t for t in text if "starts (" in t][1:]
    assert [t.split(" starts")[0] for t in tenths] == [f"fit: {k}/1000" for k in
                                                       range(100, 1001, 100)]
    assert "fit: 500/1000 starts (50 %), best 500; 0:00:20 elapsed, eta 0:00:20" in text
    assert "eta" not in text[-1]                 # all done: nothing left to estimate
    assert all(t.isascii() for t in text)
    # a long step without news: a line after `every` seconds, not before
    n = len(out.getvalue().splitlines())
    clock.t += 9.0
    lines.beat()
    assert len(out.getvalue().splitlines()) == n
    clock.t += 1.0
    lines.beat()
    assert out.getvalue().splitlines()[-1].startswith("fit: 1000/1000 starts (100 %)")
    lines.finish("fit", "fit: done")
    clock.t += 60.0
    lines.beat()
    assert out.getvalue().splitlines()[-1] == "fit: done"


def test_progress_lines_keep_coming_while_nothing_is_reported():
    """The heartbeat is a thread: a fit whose first chunk takes minutes still prints."""
    out = io.StringIO()
    with ProgressLines(out, every=0.05) as lines:
        lines.start("fit", "fit")
        lines.update("fit", 0, 1000, "starts")
        deadline = time.monotonic() + 5.0
        while out.getvalue().count("elapsed") < 3 and time.monotonic() < deadline:
            time.sleep(0.02)
    assert out.getvalue().count("elapsed") >= 3, out.getvalue()


def test_fit_progress_without_a_terminal_is_lines():
    out = io.StringIO()
    fit = starts_progress(Console(file=out), 1000, every=1e9)
    assert fit.bar is None
    with fit as callback:
        callback(0, 1000)
        callback(250, 1000, best_chi2=265.088)
        callback(1000, 1000, best_chi2=265.0)
    text = out.getvalue()
    assert "fit: 250/1000 starts (25 %), best start chi2 (before polish) 265.088;" in text
    assert "1000/1000 starts (100 %), best start chi2 (before polish) 265; polishing" in text
    assert "\x1b" not in text and "…" not in text          # no terminal codes, nothing cut


def test_run_progress_without_a_terminal_is_lines():
    """``gprm run`` without a terminal cut its bars to '0:00… eta 0:00:…'; now each stage is
    lines: started, the fit's tenths, its outcome."""
    from gprm.run.commands import _Progress

    out = io.StringIO()
    titles = {"campaign": "campaign (import)", "fit": "fit (multi-start LM)",
              "telemetry": "telemetry"}
    with _Progress(Console(file=out, width=80), titles, every=1e9) as prog:
        prog.event("campaign", "start")
        prog.event("campaign", "done")
        prog.event("fit", "start")
        prog.event("fit", "step", 0, 1000, best_chi2=float("nan"))
        prog.event("fit", "step", 500, 1000, best_chi2=300.0)
        prog.event("fit", "done")
        prog.event("telemetry", "skip")
    text = out.getvalue().splitlines()
    assert prog.bar is None
    assert text[0] == "campaign (import): started"
    assert re.fullmatch(r"campaign \(import\): done in \d+\.\d s", text[1]), text[1]
    assert any(t.startswith("fit (multi-start LM): 500/1000 starts (50 %), best start chi2 "
                            "(before polish) 300;") for t in text)
    assert text[-1] == "telemetry: skipped (up to date)"
    assert all(t.isascii() and "…" not in t for t in text)


@pytest.mark.parametrize("terminal", [True, False], ids=["terminal", "no terminal"])
def test_an_error_before_any_stage_prints_nothing_of_the_display(terminal):
    """``gprm run nosuchdir`` printed an empty line before its error: the display starts with
    the first stage."""
    from gprm.run.commands import _Progress

    out = io.StringIO()
    console = _terminal(out) if terminal else Console(file=out)
    with pytest.raises(RuntimeError):
        with _Progress(console, {}):
            raise RuntimeError("the campaign does not exist")
    assert out.getvalue() == ""
