"""One progress callback of the fit for ``gprm fit``, ``gprm run`` and ``gprm demo``: starts
done, starts requested and the best chi-square so far, shown with the time remaining."""

from __future__ import annotations

import io

from rich.console import Console

from gprm.fit.report_text import starts_info, starts_progress
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


def test_run_and_fit_displays_show_starts_best_chi2_and_time_remaining():
    """``gprm run``/``gprm demo`` show the fit's line as ``gprm fit`` does: starts done of
    requested, the best chi-square so far, and the time remaining."""
    from gprm.run.commands import _Progress

    prog = _Progress(Console(file=io.StringIO()), {"fit": "fit (multi-start LM)"})
    prog.event("fit", "start")
    prog.event("fit", "step", 250, 1000, best_chi2=1234.5678)
    line = _render(prog.bar)
    assert "250/1000" in line and starts_info(1234.5678) in line and "eta" in line
    assert "best chi2 1234.57" in line
    prog.event("fit", "step", 1000, 1000, best_chi2=1200.0)
    prog.event("fit", "done")
    assert "1000/1000" in _render(prog.bar) and "best chi2 1200" in _render(prog.bar)

    fit = starts_progress(Console(file=io.StringIO()), 1000)
    callback = fit.__enter__()
    try:
        callback(250, 1000, best_chi2=1234.5678)
        text = _render(fit.bar)
    finally:
        fit.__exit__(None, None, None)
    assert "250/1000" in text and starts_info(1234.5678) in text and "eta" in text


def test_best_chi2_text_before_the_first_chunk():
    assert starts_info(float("nan")) == "starts  best chi2 -"
    assert starts_info(3.5) == "starts  best chi2 3.5"
