"""The shortcuts the fit takes for speed (issue 24, item 2) give the numbers of the direct
forms: the lock-step leave-one-signal-out polishes against one objective and one polish per
signal, a batch of different problems in one LM run against each problem alone (and SciPy),
gprm's periodogram against scipy.signal's, and identify's single BLAS thread."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.signal import periodogram as scipy_periodogram

from gprm.fit.adequacy import (LOSO_FTOL, LeftOut, leave_one_signal_out,
                               leave_one_signal_out_each, periodogram)
from gprm.fit.engine import single_thread_blas
from gprm.fit.lm import levenberg_marquardt_batch
from gprm.fit.objective import Objective
from gprm.params import paper

sys.path.insert(0, str(Path(__file__).parent))
from means_factory import perturbed_problem  # noqa: E402


@pytest.mark.parametrize("n", [47, 48, 2, 3])
def test_periodogram_matches_scipy(n):
    x = np.random.default_rng(n).standard_normal(n) + 3.0
    f, p = periodogram(x, 2e5)
    fs_, ps_ = scipy_periodogram(x, fs=2e5, detrend="constant")
    np.testing.assert_allclose(f, fs_, rtol=1e-14)
    np.testing.assert_allclose(p, ps_, rtol=1e-12, atol=1e-15 * ps_.max())


def _exp_residuals(t, Y):
    """Residuals and Jacobian of y = a exp(-b t) + c against the data rows ``Y[rows]``."""
    def fun(X, rows):
        a, b, c = X[:, :1], X[:, 1:2], X[:, 2:3]
        e = np.exp(-b * t[None])
        r = a * e + c - Y[rows]
        J = np.stack([e, -a * t[None] * e, np.ones_like(e)], axis=2)
        return r, J

    return fun


@pytest.mark.parametrize("geodesic", [False, True])
def test_indexed_batch_is_each_problem_alone_and_matches_scipy(geodesic):
    """Each row of an ``indexed`` batch sees its own data (also in the geodesic
    acceleration's extra residual call)."""
    t = np.linspace(0, 4, 30)
    rng = np.random.default_rng(0)
    truths = np.array([[2.0, 1.3, 0.1], [1.0, 0.4, -0.3], [3.0, 2.5, 0.0], [0.5, 0.9, 1.0]])
    Y = (truths[:, :1] * np.exp(-truths[:, 1:2] * t) + truths[:, 2:3]
         + 0.01 * rng.standard_normal((4, t.size)))
    fun = _exp_residuals(t, Y)
    X0 = np.array([[1.0, 1.0, 0.0]] * 4)
    both = levenberg_marquardt_batch(fun, X0, residuals=lambda X, rows: fun(X, rows)[0],
                                     indexed=True, max_iter=200, ftol=1e-14,
                                     geodesic=geodesic)
    for k in range(4):
        def fk(X, rows, k=k):
            return fun(X, np.full(len(X), k))

        one = levenberg_marquardt_batch(fk, X0[k:k + 1], indexed=True, max_iter=200,
                                        ftol=1e-14, geodesic=geodesic,
                                        residuals=lambda X, rows, k=k: fk(X, rows, k)[0])
        np.testing.assert_allclose(both.x[k], one.x[0], rtol=1e-9)
        ref = least_squares(lambda x, k=k: fun(x[None], np.array([k]))[0][0], X0[k],
                            jac=lambda x, k=k: fun(x[None], np.array([k]))[1][0], method="lm",
                            xtol=1e-15, ftol=1e-15, gtol=1e-15)
        np.testing.assert_allclose(both.x[k], ref.x, rtol=1e-7)
        assert abs(both.chi2[k] - 2 * ref.cost) <= 1e-10 * both.chi2[k]


@pytest.fixture(scope="module")
def fitted():
    """An objective with the prior on synthetic signals, and a point a few per cent off the
    truth (so that every leave-one-out polish moves)."""
    return perturbed_problem(5)


def test_left_out_objective_is_the_objective_without_the_signal(fitted):
    obj, x = fitted
    S, T = obj.data.values.shape
    fun = LeftOut(obj, np.arange(S))
    xn = obj.to_normalised(x)
    r, J = fun(np.repeat(xn[None], S, axis=0), np.arange(S))
    for s in range(S):
        keep = [i for i in range(S) if i != s]
        sub = Objective(obj.data.__class__(obj.data.time, obj.data.values[keep],
                                           obj.data.sigma[keep],
                                           tuple(obj.data.signals[i] for i in keep)),
                        obj.base, obj.names, obj.scale, obj.piezo, obj.z_bk_absolute,
                        obj.prior)
        rs, Js = sub(xn[None])
        rows = np.ones(r.shape[1], bool)
        rows[s * T:(s + 1) * T] = False
        np.testing.assert_allclose(r[s, rows], rs[0], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(J[s, rows], Js[0], rtol=1e-10, atol=1e-10 * np.abs(Js).max())
        assert not r[s, ~rows].any() and not J[s, ~rows].any()
        # the residuals-only path (and a subset of the batch's rows) agrees
        rr = fun.residuals(xn[None], np.array([s]))
        np.testing.assert_array_equal(rr[0], r[s])


def test_batched_leave_one_signal_out_matches_one_polish_per_signal(fitted):
    obj, x = fitted
    with single_thread_blas():
        each = leave_one_signal_out_each(obj, x)
        batched = leave_one_signal_out(obj, x)
    assert np.all(np.isfinite(each)) and np.all(each > 0)
    # the polishes stop at a relative chi-square change of LOSO_FTOL: the ratios agree far
    # inside the digits the report prints (3)
    np.testing.assert_allclose(batched, each, rtol=1e-6)
    assert LOSO_FTOL <= 1e-10
    # and the polishes moved: at the unpolished point every ratio would be exactly 1
    assert np.all(np.abs(each - 1) > 1e-3), each


def test_the_fit_does_not_import_the_heavy_modules_it_does_not_use():
    """scipy.signal (about a second of import), scipy.stats (0.6 s; the fit's normal
    quantiles and chi-square tail come from scipy.special) and SymPy (0.4 s; the simulator
    names the coordinates from gprm.model.coordinates): the fit's path (the library's
    identify and the CLI's fit command) does without them."""
    import subprocess

    heavy = ("scipy.signal", "scipy.stats", "sympy")
    code = ("import sys, gprm.fit.api, gprm.fit.identify, gprm.fit.commands\n"
            f"print([m for m in {heavy!r} if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]"


def test_adequacy_chi_square_p_value_is_scipy_stats(fitted):
    """The verdict's chi-square tail from scipy.special (chdtrc, degrees of freedom first)
    is scipy.stats' chi2.sf of the same statistic, and moves the right way with chi2."""
    from scipy.stats import chi2 as chi2_dist

    from gprm.fit.adequacy import assess

    obj, x = fitted
    r = obj.residuals(obj.to_normalised(x)[None])[0, :obj.data.n_obs]
    dof = r.size - 20.0
    r = r * np.sqrt(dof / float(r @ r))          # chi2 = dof: a p-value near one half
    a = assess(obj, x, r, 20.0, loso=False)
    assert 0.3 < a.p_value < 0.7
    assert a.p_value == pytest.approx(float(chi2_dist.sf(a.chi2, a.dof)), rel=1e-12)
    b = assess(obj, x, 1.1 * r, 20.0, loso=False)
    assert b.p_value < a.p_value


def test_identify_runs_on_one_blas_thread(fitted, monkeypatch):
    """identify's whole body (multi-start, polish, uncertainty, adequacy) runs with one BLAS
    thread, and the previous setting is back afterwards."""
    from gprm.fit import identify as identify_module
    from gprm.fit.engine import _openblas_thread_setters

    setters = _openblas_thread_setters()
    if not setters:
        pytest.skip("no OpenBLAS thread control in this numpy build")
    seen = []

    class Stop(Exception):
        pass

    def record(*args, **kwargs):
        seen.append([int(g()) for _, g in setters])
        raise Stop

    import ctypes

    old = [int(g()) for _, g in setters]
    for s_, _ in setters:              # two threads outside, so that one inside is seen
        s_(ctypes.c_int(2))
    monkeypatch.setattr(identify_module, "run_multistart", record)
    obj, _ = fitted
    try:
        with pytest.raises(Stop):
            identify_module.identify(obj.data, paper())
        after = [int(g()) for _, g in setters]
    finally:
        for (s_, _), n in zip(setters, old):
            s_(ctypes.c_int(n))
    assert seen == [[1] * len(setters)]
    assert after == [2] * len(setters)
