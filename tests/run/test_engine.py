"""The stage runner of gprm run / gprm demo: resuming by hashes, blocked and failing stages,
run.json provenance. Uses small stand-in stages (files of text), so it runs in well under a
second."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from dataclasses import dataclass

from gprm.run.engine import Stage, run_stages


@dataclass(frozen=True)
class Opts:
    seed: int = 0
    starts: int = 1


def _writer(out: str, calls: list, text=lambda run, o: "x"):
    def run(run_dir: Path, opts, step):
        calls.append(out)
        step(1, 2)
        step(2, 2)
        (run_dir / out).write_text(text(run_dir, opts))
        return {"wrote": out}
    return run


def _chain(calls):
    return (
        Stage("a", "A", (), ("a.txt",), lambda o: {"seed": o.seed},
              _writer("a.txt", calls, lambda r, o: f"seed {o.seed}")),
        Stage("b", "B", ("a.txt",), ("b.txt",), lambda o: {},
              _writer("b.txt", calls, lambda r, o: (r / "a.txt").read_text().upper())),
        Stage("c", "C", ("b.txt",), ("c.txt",), lambda o: {"starts": o.starts},
              _writer("c.txt", calls, lambda r, o: (r / "b.txt").read_text() + "!")),
    )


def test_rerun_skips_up_to_date_stages_and_reruns_what_changed(tmp_path):
    calls: list = []
    events: list = []
    res = run_stages(tmp_path, Opts(seed=1), stages=_chain(calls), report_html=False,
                   progress=lambda *e: events.append(e))
    assert calls == ["a.txt", "b.txt", "c.txt"]
    assert [r.status for r in res.records] == ["ran"] * 3
    assert ("a", "step", 2, 2) in events
    assert (tmp_path / "c.txt").read_text() == "SEED 1!"
    rec = json.loads((tmp_path / "run.json").read_text())
    assert rec["seed"] == 1 and set(rec["stages"]) == {"a", "b", "c"}
    assert rec["stages"]["b"]["inputs"]["a.txt"] and rec["versions"]["gprm"]

    calls.clear()      # same inputs and settings: nothing reruns
    res = run_stages(tmp_path, Opts(seed=1), stages=_chain(calls), report_html=False)
    assert calls == [] and [r.status for r in res.records] == ["skipped"] * 3

    calls.clear()      # a setting of the last stage changed: only it reruns
    run_stages(tmp_path, Opts(seed=1, starts=7), stages=_chain(calls), report_html=False)
    assert calls == ["c.txt"]

    calls.clear()      # an output edited by hand: that stage reruns; it writes the same
    (tmp_path / "b.txt").write_text("tampered")   # file again, so the next one stays valid
    run_stages(tmp_path, Opts(seed=1, starts=7), stages=_chain(calls), report_html=False)
    assert calls == ["b.txt"] and (tmp_path / "b.txt").read_text() == "SEED 1"

    calls.clear()      # an output deleted: that stage reruns
    (tmp_path / "c.txt").unlink()
    run_stages(tmp_path, Opts(seed=1, starts=7), stages=_chain(calls), report_html=False)
    assert calls == ["c.txt"] and (tmp_path / "c.txt").read_text() == "SEED 1!"

    calls.clear()      # the seed changes the first stage's output: everything reruns
    run_stages(tmp_path, Opts(seed=2, starts=7), stages=_chain(calls), report_html=False)
    assert calls == ["a.txt", "b.txt", "c.txt"]
    assert (tmp_path / "c.txt").read_text() == "SEED 2!"


def test_interrupted_run_resumes_after_the_last_finished_stage(tmp_path):
    calls: list = []
    chain = list(_chain(calls))

    def boom(run_dir, opts, step):
        raise KeyboardInterrupt

    broken = chain[:2] + [Stage("c", "C", ("b.txt",), ("c.txt",), lambda o: {}, boom)]
    with pytest.raises(KeyboardInterrupt):
        run_stages(tmp_path, Opts(), stages=broken, report_html=False)
    assert json.loads((tmp_path / "run.json").read_text())["stages"]["c"]["status"] == \
        "interrupted"
    calls.clear()
    res = run_stages(tmp_path, Opts(), stages=_chain(calls), report_html=False)
    assert calls == ["c.txt"]
    assert [r.status for r in res.records] == ["skipped", "skipped", "ran"]


def test_failing_stage_blocks_the_ones_that_need_it_and_keeps_files_it_did_not_write(
        tmp_path):
    calls: list = []
    chain = list(_chain(calls))

    def missing(run_dir, opts, step):
        from gprm.errors import GprmInputError

        raise GprmInputError("missing variable", source="x.nc", field="time")

    chain[1] = Stage("b", "B", ("a.txt",), ("b.txt",), lambda o: {}, missing)
    (tmp_path / "c.txt").write_text("from an older run")
    res = run_stages(tmp_path, Opts(), stages=chain, report_html=False)
    assert [r.status for r in res.records] == ["ran", "failed", "blocked"]
    assert res.records[1].detail == "x.nc: field 'time': missing variable"   # as the CLI says
    assert "b.txt" in res.records[2].detail
    # c.txt was not written by this call: it stays (issue 22), listed as kept, not this run's
    assert (tmp_path / "c.txt").read_text() == "from an older run"
    rec = json.loads((tmp_path / "run.json").read_text())["stages"]["c"]
    assert rec["status"] == "blocked" and rec["kept"] == ["c.txt"]
    from gprm.report.summary import current_file, earlier_outputs

    assert "c.txt" in earlier_outputs(tmp_path) and current_file(tmp_path, "c.txt") is None


def test_failing_stage_is_recorded_and_the_rest_continues(tmp_path):
    calls: list = []
    chain = list(_chain(calls))

    def bad(run_dir, opts, step):
        from gprm._io import write_text_atomic

        write_text_atomic(run_dir / "b.txt", "half")       # as gprm's stages write
        raise ValueError("no convergence")

    chain[1] = Stage("b", "B", ("a.txt",), ("b.txt",), lambda o: {}, bad)
    chain.append(Stage("d", "D", ("a.txt",), ("d.txt",), lambda o: {},
                       _writer("d.txt", calls)))
    res = run_stages(tmp_path, Opts(), stages=chain, report_html=False)
    assert [r.status for r in res.records] == ["ran", "failed", "blocked", "ran"]
    assert res.records[1].detail == "ValueError: no convergence"
    assert not (tmp_path / "b.txt").exists()          # no half-written output is kept
    rec = json.loads((tmp_path / "run.json").read_text())["stages"]["b"]
    assert rec["status"] == "failed" and "no convergence" in rec["traceback"][-1]
