"""The fit's local worker processes (gprm.fit.engine.local_pool, worker_pool): forked only
where nothing else runs in the process, the same results as in process, and a stop that
leaves no chunk running on."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gprm.fit.engine import run_multistart, worker_pool
from gprm.fit.starts import LMOptions, MultiStartOptions

sys.path.insert(0, str(Path(__file__).parent))
from means_factory import make_means  # noqa: E402

OPTS = MultiStartOptions(n_starts=6, seed=5, chunk_size=2, lm=LMOptions(max_iter=4))


@pytest.fixture(scope="module")
def obj():
    from gprm.fit.objective import Objective, fit_data_from_means
    from gprm.params import paper

    return Objective.create(fit_data_from_means(make_means(paper(), seed=1)), paper())


_PROBE = """
import threading
from gprm.fit.engine import pool_context
print(pool_context().get_start_method())
stop = threading.Event()
t = threading.Thread(target=stop.wait)
t.start()
print(pool_context().get_start_method())
stop.set(); t.join()
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork is chosen on Linux only")
def test_workers_are_forked_only_where_no_other_thread_runs():
    """A fresh interpreter with its main thread alone forks its workers; once another
    thread runs (a progress display, a Dask client) it uses a fork server instead, where no
    lock another thread holds can be copied into a worker."""
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True,
                         timeout=120, check=True).stdout.split()
    assert out == ["fork", "forkserver"], out


def test_a_pool_gives_the_in_process_result_and_is_left_open(obj):
    """Chunks on the caller's pool, on a pool of run_multistart's own and in process agree
    bit for bit; the caller's pool stays usable after the fit."""
    ref = run_multistart(obj, OPTS)
    own = run_multistart(obj, OPTS, workers=2)
    with worker_pool(2) as pool:
        given = run_multistart(obj, OPTS, executor=pool)
        assert pool.submit(int, "7").result() == 7
    for f in ("x0", "x", "chi2", "iterations", "status"):
        np.testing.assert_array_equal(getattr(ref, f), getattr(own, f))
        np.testing.assert_array_equal(getattr(ref, f), getattr(given, f))


def test_no_pool_where_the_fit_runs_elsewhere():
    """In process, on a scheduler, or on the Dask cluster a dashboard needs: no pool."""
    for kw in ({"n_workers": 0}, {"n_workers": 2, "scheduler": "tcp://127.0.0.1:1"},
               {"n_workers": 2, "dashboard": "127.0.0.1:0"}):
        with worker_pool(**kw) as pool:
            assert pool is None, kw


def test_a_stop_cancels_the_chunks_not_begun(obj, tmp_path):
    """stop_after (as ^C would) stops the fit after one chunk: the chunks not begun are
    cancelled, the finished one is checkpointed, and a rerun resumes to the full result."""
    ref = run_multistart(obj, OPTS)
    ck = tmp_path / "ck"
    with worker_pool(1) as pool:
        with pytest.raises(KeyboardInterrupt):
            run_multistart(obj, OPTS, executor=pool, checkpoint_dir=ck, stop_after=1)
    assert len(list(ck.glob("chunk_*.npz"))) == 1
    again = run_multistart(obj, OPTS, workers=2, checkpoint_dir=ck)
    np.testing.assert_array_equal(ref.x, again.x)


def test_gprm_run_hands_its_pool_to_the_fit_stage(monkeypatch, tmp_path):
    """`gprm run`/`demo` start the fit's workers before their progress display and pass them
    through the chain to run_fit (the fit stage is the only user)."""
    from gprm.run import stages
    from gprm.run.options import RunOptions

    seen = {}

    def fake_run_fit(*args, **kw):
        seen.update(kw)
        raise RuntimeError("stop here")

    monkeypatch.setattr(stages, "run_fit", fake_run_fit)
    marker = object()
    fit = {s.name: s for s in stages.chain(RunOptions(), executor=marker)}["fit"]
    with pytest.raises(RuntimeError, match="stop here"):
        fit.run(tmp_path, RunOptions(), lambda *a, **k: None)
    assert seen["executor"] is marker
    fit = {s.name: s for s in stages.chain(RunOptions())}["fit"]
    with pytest.raises(RuntimeError, match="stop here"):
        fit.run(tmp_path, RunOptions(), lambda *a, **k: None)
    assert seen["executor"] is None


_KILLED = """
import os, sys
from concurrent.futures.process import BrokenProcessPool
import numpy as np
sys.path.insert(0, sys.argv[1])
from means_factory import make_means
import gprm.fit.engine as engine
from gprm.fit.objective import Objective, fit_data_from_means
from gprm.fit.starts import LMOptions, MultiStartOptions
from gprm.params import paper

obj = Objective.create(fit_data_from_means(make_means(paper(), seed=1)), paper())
opts = MultiStartOptions(n_starts=6, seed=5, chunk_size=2, lm=LMOptions(max_iter=4))
ref = engine.run_multistart(obj, opts)
real = engine.run_chunk

def dying(task):
    if task.index == 2:
        os._exit(3)                       # the worker dies (the OOM killer, a kill -9)
    return real(task)

engine.run_chunk = dying
try:
    engine.run_multistart(obj, opts, workers=2, checkpoint_dir=sys.argv[2])
    print("no error")
except BrokenProcessPool:
    print("broken")
engine.run_chunk = real
again = engine.run_multistart(obj, opts, workers=2, checkpoint_dir=sys.argv[2])
print("same" if np.array_equal(ref.x, again.x) else "different")
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the check forks (Linux)")
def test_a_worker_that_dies_ends_the_fit_with_an_error_and_a_rerun_resumes(tmp_path):
    """A worker process killed mid-fit breaks the pool: the fit ends with an error (the
    CLI prints it as one line), the chunks finished before are kept, and a rerun with the
    same checkpoint folder completes to the uninterrupted result."""
    here = str(Path(__file__).parent)
    out = subprocess.run([sys.executable, "-c", _KILLED, here, str(tmp_path / "ck")],
                         capture_output=True, text=True, timeout=300)
    assert out.stdout.split() == ["broken", "same"], (out.stdout, out.stderr[-2000:])
