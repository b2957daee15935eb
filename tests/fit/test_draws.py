"""The posterior draws put back on the data (gprm.fit.draws)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.stats import chi2

from gprm.fit.draws import inflation, project, project_draws
from gprm.fit.prior import Prior


class _Toy:
    """A stand-in objective: data y(t) = f(x0) (noise-free, weights 1) for a model ``f``
    (rows X (B, P) -> (B, T)) with Jacobian ``df`` (B, T, P), plus the prior's rows."""

    def __init__(self, f, df, x0, prior, lower, upper, T=60):
        self.t = np.linspace(0.0, 1.0, T)
        self.f, self.df, self.prior = f, df, prior
        self.scale = np.ones(len(x0))
        self.data = SimpleNamespace(n_obs=T)
        self.values = f(self.t, np.asarray(x0, float)[None])[0]
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)

    def to_normalised(self, X):
        return np.asarray(X, float) / self.scale

    def to_physical(self, Xn):
        return np.asarray(Xn, float) * self.scale

    def bounds_normalised(self):
        return self.lower, self.upper

    def residuals(self, Xn):
        X = np.atleast_2d(Xn)
        return np.concatenate([self.values[None] - self.f(self.t, X), self.prior.residuals(X)], 1)

    def __call__(self, Xn):
        X = np.atleast_2d(Xn)
        J = -self.df(self.t, X)
        Jp = np.zeros((X.shape[0], X.shape[1], X.shape[1]))
        i = np.arange(X.shape[1])
        Jp[:, i, i] = self.prior.jacobian(X)
        return self.residuals(X), np.concatenate([J, Jp], 1)


def _laplace(obj, x):
    """(Ju, Hinv): the weighted data Jacobian in u and the inverse Gauss-Newton Hessian."""
    _, J = obj(obj.to_normalised(x)[None])
    n = obj.data.n_obs
    Ju = J[0, :n] / obj.scale[None] * obj.prior.dx_du(x)[None]
    H = Ju.T @ Ju + np.diag(obj.prior.weight ** 2 / obj.prior.sd ** 2)
    return Ju, np.linalg.inv(H)


def test_a_model_linear_in_the_draws_coordinates_leaves_every_draw_where_it_is():
    A = np.random.default_rng(0).standard_normal((60, 3))
    prior = Prior(("a", "b", "c"), np.zeros(3), np.full(3, 10.0), np.zeros(3, bool), 1.0)
    obj = _Toy(lambda t, X: X @ A.T, lambda t, X: np.broadcast_to(A, (len(X),) + A.shape),
               np.array([0.3, -0.2, 1.0]), prior, [-np.inf] * 3, [np.inf] * 3)
    x = np.array([0.3, -0.2, 1.0])
    U = np.random.default_rng(1).standard_normal((50, 3))
    X, misfit = project(obj, x, U)
    np.testing.assert_allclose(X, x[None] + U, rtol=0, atol=1e-12)
    assert np.all(misfit <= 1e-20)


def _ridge_problem():
    """y = (a + b) g1 + c g2 with a, b > 0 in log coordinates: the data fix a + b, the prior
    alone holds a/b; the ridge a + b = const is straight in x and curved in ln x."""
    g1 = lambda t: np.sin(2 * t) + 0.3                                  # noqa: E731
    g2 = lambda t: t ** 2                                               # noqa: E731

    def f(t, X):
        return (X[:, :1] + X[:, 1:2]) * g1(t)[None] + X[:, 2:3] * g2(t)[None]

    def df(t, X):
        cols = [g1(t), g1(t), g2(t)]
        return np.broadcast_to(np.stack(cols, -1)[None], (len(X), t.size, 3))

    x = np.array([1.0, 1.0, 0.5])
    prior = Prior(("a", "b", "c"), x.copy(), np.array([0.6, 0.6, 5.0]),
                  np.array([True, True, False]), 0.05)
    return _Toy(f, df, x, prior, [0.0, 0.0, -np.inf], [np.inf] * 3), x


def test_draws_along_a_curved_ridge_are_brought_back_to_what_the_data_fix():
    obj, x = _ridge_problem()
    Ju, Hinv = _laplace(obj, x)
    Cu = obj.prior.weight ** 2 * Hinv           # the Laplace covariance in u
    U = np.random.default_rng(2).multivariate_normal(np.zeros(3), Cu, size=300)
    raw = obj.prior.from_u(obj.prior.to_u(x)[None] + U)
    X, misfit = project(obj, x, U)
    # the linearised sd of a + b
    g = np.array([x[0], x[1], 0.0])
    sd_sum = float(np.sqrt(g @ Cu @ g))
    raw_sum, proj_sum = raw[:, 0] + raw[:, 1], X[:, 0] + X[:, 1]
    # as drawn, a + b lies well away from where the data put it (the exp of a Gaussian)
    assert np.std(raw_sum) > 10 * sd_sum and np.mean(raw_sum) - 2 > 10 * sd_sum
    # projected, its spread is the linearisation's and it is centred on the fit
    assert np.std(proj_sum) == pytest.approx(sd_sum, rel=0.2)
    assert abs(np.mean(proj_sum) - 2.0) < 3 * sd_sum / np.sqrt(len(U))
    # the split the data do not see keeps the spread the prior gave it
    r_raw, r_proj = np.log(raw[:, 0] / raw[:, 1]), np.log(X[:, 0] / X[:, 1])
    assert np.std(r_proj) == pytest.approx(np.std(r_raw), rel=0.25)
    # what is left is mostly the prior's rows' share of the move: every draw is kept
    assert np.all(misfit <= chi2.ppf(0.99, 3)), np.max(misfit)


def _sine_problem():
    """y = sin(w t): the linearisation's outputs t cos(w t) dw grow without bound in dw,
    which no frequency reproduces once dw is large."""
    def f(t, X):
        return np.sin(X[:, :1] * t[None])

    def df(t, X):
        return (t[None] * np.cos(X[:, :1] * t[None]))[..., None]

    x = np.array([6.0])
    prior = Prior(("w",), x.copy(), np.array([2.0]), np.array([True]), 0.1)
    return _Toy(f, df, x, prior, [0.0], [np.inf], T=80), x


def test_draws_the_model_cannot_reproduce_are_dropped_and_replaced():
    obj, x = _sine_problem()
    proposed = []

    def propose(k, rnd):
        rng = np.random.default_rng([7, rnd])
        # every third a proposal far out on the linearisation (a frequency 2.7 times the
        # fit's), the others near the fit
        U = 0.01 * rng.standard_normal((k, 1))
        U[::3] = 1.0
        proposed.append(U)
        return U

    out = project_draws(obj, x, propose, 40, max_rounds=4)
    assert out.x.shape == (40, 1)
    assert len(proposed) > 1                              # the first round was topped up
    far = np.concatenate(proposed)[:, 0] > 0.5
    assert far.size == out.misfit.size and far.any()
    assert np.all(out.misfit[far] > out.threshold) and not np.any(out.kept[far])
    assert np.all(out.misfit[out.kept] <= out.threshold)
    assert np.all(np.abs(np.log(out.x[:, 0] / x[0])) < 0.1)
    assert 0.6 < out.acceptance < 0.7
    # the same proposals give the same draws
    again = project_draws(obj, x, propose, 40, max_rounds=4)
    np.testing.assert_array_equal(again.x, out.x)
    np.testing.assert_array_equal(again.misfit, out.misfit)
    assert out.to_json()["kept"] == 40 and out.to_json()["proposed"] == out.misfit.size


def test_the_threshold_scales_with_the_covariances_inflation_over_the_noise():
    rng = np.random.default_rng(3)
    Ju = rng.standard_normal((50, 4))
    Hinv = np.linalg.inv(Ju.T @ Ju)
    assert inflation(Ju, Hinv, 2.0 * Hinv, 2.0) == pytest.approx(1.0)
    assert inflation(Ju, Hinv, 9.0 * Hinv, 1.0) == pytest.approx(9.0)
    obj, x = _sine_problem()
    one = project_draws(obj, x, lambda k, r: np.zeros((k, 1)), 3)
    nine = project_draws(obj, x, lambda k, r: np.zeros((k, 1)), 3, scale=9.0)
    low = project_draws(obj, x, lambda k, r: np.zeros((k, 1)), 3, scale=0.2)
    assert nine.threshold == pytest.approx(9 * one.threshold)
    assert low.threshold == pytest.approx(one.threshold)          # never below the noise's


def test_the_plungers_y_plane_spring_sum_stays_where_the_data_put_it():
    """On the GPRM model (synthetic campaign at the paper set, the default prior): Gaussian
    draws in the prior's log coordinates move k_Cy + k_Dy, which the data fix, by far more
    than its linearised sd; projected, it keeps that sd, and the split k_Cy / k_Dy, which
    the data do not see to first order, keeps most of the prior's spread."""
    from means_factory import make_means

    from gprm.fit.objective import Objective, fit_data_from_means
    from gprm.fit.prior import default_prior
    from gprm.params import paper

    p = paper()
    data = fit_data_from_means(make_means(p, seed=5), source="synthetic", sigma_pool=0)
    names = tuple(p.fitted)
    obj = Objective.create(data, p, names, prior=default_prior(p, names).with_weight(1.0))
    x = p.vector(obj.names)
    Ju, Hinv = _laplace(obj, x)
    U = np.random.default_rng(4).multivariate_normal(np.zeros(x.size), Hinv, size=120)
    raw = obj.prior.from_u(obj.prior.to_u(x)[None] + U)
    X, misfit = project(obj, x, U)
    ic, idd = obj.names.index("k_Cy"), obj.names.index("k_Dy")
    g = np.zeros(x.size)
    g[[ic, idd]] = x[[ic, idd]]                      # d(k_Cy + k_Dy)/du
    sd_sum = float(np.sqrt(g @ Hinv @ g))
    K0 = x[ic] + x[idd]
    raw_sum, proj_sum = raw[:, ic] + raw[:, idd], X[:, ic] + X[:, idd]
    assert np.std(raw_sum) > 100 * sd_sum                 # 740 x with this seed
    kept = misfit <= chi2.ppf(0.99, x.size)
    assert kept.mean() > 0.5                              # 71 %
    assert 0.7 * sd_sum < np.std(proj_sum[kept]) < 1.4 * sd_sum   # 1.04 x
    assert abs(np.median(proj_sum[kept]) - K0) < 0.5 * sd_sum
    split_raw = np.log(raw[:, ic] / raw[:, idd])
    split_proj = np.log(X[kept, ic] / X[kept, idd])
    # the data narrow the split at second order (0.56 x): the spread is not lost
    assert np.std(split_proj) > 0.4 * np.std(split_raw)


def test_the_threshold_is_scipy_stats_chi_square_quantile():
    """chdtri (scipy.special, what the fit imports) against scipy.stats' chi2.ppf."""
    obj, x = _sine_problem()
    out = project_draws(obj, x, lambda k, r: np.zeros((k, 1)), 2, level=0.99)
    assert out.threshold == pytest.approx(chi2.ppf(0.99, 1), rel=1e-12)


def test_a_proposal_that_is_not_a_finite_point_is_dropped_not_projected():
    obj, x = _ridge_problem()
    U = np.zeros((4, 3))
    U[1, 0] = np.nan
    U[2, 1] = 1e6                         # absurdly far: exp(u) overflows
    X, misfit = project(obj, x, U)
    assert np.isinf(misfit[1]) and np.all(np.isnan(X[1]))
    assert misfit[2] > 1e6                # projected from its linear image, and ruled out
    assert np.all(np.isfinite(misfit[[0, 3]])) and np.allclose(X[[0, 3]], x[None])


def test_when_the_projection_fails_the_draws_are_kept_as_drawn_and_the_file_says_why(
        monkeypatch):
    """The intervals never depend on the projection: if it raises, the default uncertainty
    keeps the Gaussian's draws, its intervals are the same, and fit.json's details say why
    (which gprm show prints)."""
    from means_factory import make_means

    import gprm.fit.sandwich as sandwich
    from gprm.fit.methods import FitState, compute
    from gprm.fit.objective import Objective, fit_data_from_means
    from gprm.fit.prior import default_prior
    from gprm.fit.report_text import draws_label
    from gprm.params import paper

    p = paper()
    data = fit_data_from_means(make_means(p, seed=6), source="synthetic")
    names = tuple(p.fitted)
    obj = Objective.create(data, p, names, prior=default_prior(p, names).with_weight(1.0))
    x = p.vector(obj.names)
    r, J = obj(obj.to_normalised(x)[None])
    n = data.n_obs
    state = FitState(obj, x, J[0, :n] / obj.scale, r[0, :n], obj.prior, seed=1, n_draws=30)
    good = compute("sandwich", state)
    assert good.details["draws"]["kept"] == good.draws.shape[0] > 0

    def boom(*a, **k):
        raise np.linalg.LinAlgError("Eigenvalues did not converge")

    monkeypatch.setattr(sandwich, "project_draws", boom)
    bad = compute("sandwich", state)
    assert bad.draws.shape == (30, x.size) and np.all(np.isfinite(bad.draws))
    for side in ("lower95", "upper95", "lower68", "upper68"):
        np.testing.assert_array_equal(getattr(bad, side), getattr(good, side))
    reason = bad.details["draws"]["not_projected"]
    assert reason == "LinAlgError: Eigenvalues did not converge"
    assert "not put back on the data (LinAlgError" in draws_label(bad.details)
