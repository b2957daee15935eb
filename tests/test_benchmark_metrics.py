"""The coverage benchmark's own statistics (benchmarks/bench_coverage.py): the randomised PIT
it scores the kinetic-energy histogram with is calibrated where a bin's occupancy has an atom
at zero, and the closed percentile band over the bins the truth occupies is not (here it
under-covers; with rarer empty bins it over-covers)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.stats import binom

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_coverage import pit_cover  # noqa: E402


def _binomial_range(p: float, n: int) -> tuple[float, float]:
    """The central 99.99 % range of a binomial proportion (the test fails by chance 1e-4)."""
    lo, hi = binom.interval(0.9999, n, p)
    return lo / n, hi / n


def test_pit_coverage_is_nominal_with_and_without_atoms_and_the_band_is_not():
    rng = np.random.default_rng(5)
    n_sets, k, b = 300, 40, 400
    hits = {"pit95": 0, "pit68": 0, "band68": 0}
    n_pit = n_band = 0
    for _ in range(n_sets):
        mu = rng.uniform(-1.5, 1.0, k)                   # bins empty with probability 16-93 %
        draws = np.maximum(0.0, mu + rng.standard_normal((b, k)))
        truth = np.maximum(0.0, mu + rng.standard_normal(k))   # same distribution as draws
        r = pit_cover(draws, truth, rng)
        hits["pit95"] += r["in95"]
        hits["pit68"] += r["in68"]
        n_pit += k
        used = truth > 0                                  # the bins the truth occupies
        q16, q84 = np.percentile(draws, [16, 84], axis=0)
        hits["band68"] += int(np.sum(used & (q16 <= truth) & (truth <= q84)))
        n_band += int(used.sum())
    # with finitely many draws the PIT is nominal up to O(1/b); the range allows for it
    lo, hi = _binomial_range(0.95, n_pit)
    assert lo - 0.005 <= hits["pit95"] / n_pit <= hi + 0.005
    lo, hi = _binomial_range(0.68, n_pit)
    assert lo - 0.005 <= hits["pit68"] / n_pit <= hi + 0.005
    # scoring the closed band over the bins the truth occupies is off nominal at the atom
    lo, hi = _binomial_range(0.68, n_band)
    assert not lo <= hits["band68"] / n_band <= hi
