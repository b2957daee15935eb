"""The standalone optimizer on the Moré-Garbow-Hillstrom set (``mgh.py``; issue 24): the problem
definitions checked (Jacobians against central differences, listed minima at their known
points), and every one of the 105 runs (35 problems from x0, 10 x0, 100 x0) either solved or
one of the documented failures, at most 15 of them (>= 90 solved). A test of success, not of
time: ``benchmarks/bench_lm.py`` measures the evaluations against MINPACK and trf."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from gprm.fit import levenberg_marquardt
from gprm.fit.lm import finite_difference_jacobian

sys.path.insert(0, str(Path(__file__).parent))
import mgh  # noqa: E402

PROBLEMS = mgh.problems()
RUNS = [(p.number, f) for p in PROBLEMS for f in mgh.FACTORS]
BUDGET = 10_000     # residual evaluations per run, as in benchmarks/bench_lm.py

# (problem, factor): the runs the default optimizer does not solve, and where it ends. Most
# end at points other solvers reach too (docs/fitting.md, the MGH table): a listed minimum at
# infinity (Bard), stationary points that are not listed minima (Beale 0.452, Box 0.0756,
# Biggs 0.306), a sum of squares that overflows at the start (Jennrich-Sampson 100 x0:
# not finite, nothing done).
KNOWN_FAILURES = {
    (3, 10.0): "Powell badly scaled: crawls to the budget at 1e-8 (MINPACK too)",
    (3, 100.0): "Powell badly scaled: stops at 1e-8 (MINPACK and trf too)",
    (5, 10.0): "Beale: a stationary point at 0.452 (MINPACK and trf too)",
    (5, 100.0): "Beale: a stationary point at 0.452 (MINPACK too)",
    (6, 10.0): "Jennrich-Sampson: 259.6, not the listed 124.36 (MINPACK too)",
    (6, 100.0): "Jennrich-Sampson: the sum of squares overflows at the start (failed; "
                "MINPACK and trf fail too)",
    (8, 10.0): "Bard: the listed minimum 17.43 at infinity (every solver)",
    (8, 100.0): "Bard: the listed minimum 17.43 at infinity (MINPACK too)",
    (11, 100.0): "Gulf: a flat start, zero gradient (every solver)",
    (12, 10.0): "Box 3-D: a stationary point at 0.0756 (MINPACK too)",
    (12, 100.0): "Box 3-D: a stationary point at 0.0756 (MINPACK too)",
    (18, 100.0): "Biggs EXP6: a stationary point at 0.306 (every solver)",
    (19, 10.0): "Osborne 2: the bound collapses on overflowing trials (every solver fails)",
    (19, 100.0): "Osborne 2: the bound collapses on overflowing trials (every solver fails)",
    (35, 100.0): "Chebyquad: crawls to the budget (MINPACK too)",
}


@pytest.mark.parametrize("p", PROBLEMS, ids=[f"{p.number}" for p in PROBLEMS])
def test_jacobian_matches_central_differences(p):
    """The complex-step Jacobian against central differences, at x0 shifted off symmetric
    points (exact to rounding against an O(h^2) estimate)."""
    x = p.x0 + 0.1 * (1 + np.arange(p.n) / p.n)
    Ja = p.jacobian(x)
    Jf = finite_difference_jacobian(p.residuals, x)
    assert Ja.shape == (p.m, p.n)
    assert np.max(np.abs(Ja - Jf)) <= 1e-6 * max(1.0, np.max(np.abs(Ja))), p.name


KNOWN_POINTS = {1: [1, 1], 2: [5, 4], 4: [1e6, 2e-6], 5: [3, 0.5], 7: [1, 0, 0],
                11: [50, 25, 1.5], 12: [1, 10, 1], 13: [0, 0, 0, 0], 14: [1, 1, 1, 1],
                18: [1, 10, 1, 5, 4, 3], 21: np.ones(10), 22: np.zeros(12), 25: np.ones(10),
                27: np.ones(10), 32: -np.ones(5)}


@pytest.mark.parametrize("number", sorted(KNOWN_POINTS))
def test_listed_minimum_at_its_known_point(number):
    """Where the paper gives the minimiser, the residuals there give the listed minimum."""
    p = PROBLEMS[number - 1]
    assert p.number == number
    r = p.residuals(np.asarray(KNOWN_POINTS[number], float))
    assert float(r @ r) == pytest.approx(p.minima[0], abs=1e-20)


def test_the_set_is_the_papers():
    assert [p.number for p in PROBLEMS] == list(range(1, 36))
    assert len(RUNS) == 105
    for p in PROBLEMS:
        assert p.f(p.x0).shape == (p.m,) and p.m >= p.n
    # every other run is checked solved and every listed one failing (below), so this is
    # the count of solved runs: >= 90 of 105 (89 where a processor-dependent run fails)
    assert len(KNOWN_FAILURES) <= 15
    assert not set(PROCESSOR_DEPENDENT) & set(KNOWN_FAILURES)


# runs at the budget's edge, whose evaluation count depends on the processor's floating-point
# kernels, measured on both: within the budget on one, just over it on the other. Such a run
# must still reach a listed minimum; it may end on the budget instead of converging.
PROCESSOR_DEPENDENT = {
    (35, 10.0): "Chebyquad from 10 x0: converged in under 10,000 residual evaluations on the "
                "Intel Xeon machine of stop 34 (and CI), needs 10,405 on an AMD EPYC (stop "
                "35); the slow crawl is issue 24's",
}


@pytest.mark.parametrize("number,factor", RUNS, ids=[f"{n}-x{f:g}" for n, f in RUNS])
def test_mgh_run_is_solved(number, factor):
    """The default optimizer (exact Jacobian) reaches a listed minimum; a documented failure
    still fails (so the list, and the count of solved runs it implies, stays exact: a run
    that starts to be solved, or to fail, changes this test's outcome)."""
    p = PROBLEMS[number - 1]
    with np.errstate(all="ignore"):
        res = levenberg_marquardt(p.residuals, p.start(factor), p.jacobian, max_nfev=BUDGET)
    if (number, factor) in KNOWN_FAILURES:
        assert not (p.solved(res.chi2) and res.success), \
            f"now solved; remove it from KNOWN_FAILURES ({KNOWN_FAILURES[(number, factor)]})"
        return
    assert p.solved(res.chi2), (res.chi2, p.minima, res.status, res.nfev)
    if (number, factor) in PROCESSOR_DEPENDENT:
        assert res.success or (res.status == "max_nfev" and res.nfev == BUDGET), \
            (res.status, res.nfev, PROCESSOR_DEPENDENT[(number, factor)])
    else:
        assert res.success, res.message
    assert res.chi2 == pytest.approx(float(np.sum(res.fun ** 2)), rel=1e-12, abs=1e-300)
