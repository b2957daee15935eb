"""The studies' Dask map (benchmarks/_studies.py, issue 24 item 5): one task per campaign seed,
results in the order of the seeds and the same bits in this process, on 1 and on 2 local
workers (one BLAS thread everywhere)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from _studies import map_seeds  # noqa: E402


def small_study(seed: int, size: int) -> dict:
    """A stand-in for one campaign: seeded draws through BLAS products and a solve (what a
    fit does), slow enough for the tasks to finish out of order."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(size, size))
    x = np.linalg.solve(A @ A.T + size * np.eye(size), rng.normal(size=size))
    return {"seed": seed, "x": x, "norm": float(x @ A @ x)}


def test_results_do_not_depend_on_the_worker_count():
    seeds = [7, 3, 11, 5]
    here = map_seeds(small_study, seeds, size=200, progress=False)
    one = map_seeds(small_study, seeds, workers=1, size=200, progress=False)
    two = map_seeds(small_study, seeds, workers=2, size=200, progress=False)
    assert [r["seed"] for r in here] == seeds
    for a, b, c in zip(here, one, two):
        assert a["seed"] == b["seed"] == c["seed"]
        np.testing.assert_array_equal(a["x"], b["x"])
        np.testing.assert_array_equal(a["x"], c["x"])
        assert a["norm"] == b["norm"] == c["norm"]


def test_progress_lines_name_each_task(capsys):
    """``labels`` name the tasks in the progress lines (bench_sources' tasks are jobs, not
    seeds); without them a task is its seed."""
    map_seeds(small_study, [4, 2], size=5, labels=["white seed 5000", "mode-1 seed 5001"])
    err = capsys.readouterr().err
    assert "campaign 1/2 (white seed 5000) done" in err
    assert "campaign 2/2 (mode-1 seed 5001) done" in err
    map_seeds(small_study, [4], size=5)
    assert "campaign 1/1 (seed 4) done" in capsys.readouterr().err
