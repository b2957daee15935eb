"""Eq. 7 against the NIST certified standard deviations; its failure messages; bounds; the
standardised covariance sampling and factor; the multi-start draws."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from gprm.fit.covariance import (CovarianceError, covariance, parameters_at_bounds,
                                 sample_normal)
from gprm.fit.starts import MultiStartOptions, draw_starts

sys.path.insert(0, str(Path(__file__).parent))
import nist  # noqa: E402


@pytest.mark.parametrize("name", nist.names())
def test_eq7_reproduces_nist_certified_standard_deviations(name):
    """NIST's certified parameter standard deviations are s^2 (J'J)^-1 at the certified
    values, s^2 = RSS / (n - p): exactly Eq. 7. The residuals are scaled to the certified RSS
    (Lanczos1's certified RSS, 1.4e-25, is below the round-off of evaluating its model)."""
    p = nist.load(name)
    r = p.residuals(p.certified)
    r = r * np.sqrt(p.rss / float(r @ r))
    C = covariance(p.jacobian(p.certified), r, dof=r.size - p.certified.size)
    np.testing.assert_allclose(np.sqrt(np.diag(C)), p.certified_sd, rtol=1e-4)


def test_singular_and_degenerate_cases_say_why():
    rng = np.random.default_rng(0)
    J = rng.standard_normal((20, 3))
    r = rng.standard_normal(20)
    with pytest.raises(CovarianceError, match="no effect.*b"):
        covariance(np.column_stack([J, np.zeros(20)]), r, 16, names=["a", "b2", "c", "b"])
    with pytest.raises(CovarianceError, match="singular J\\^T J.*a"):
        covariance(np.column_stack([J, 2 * J[:, 0]]), r, 16, names=["a", "b", "c", "d"])
    with pytest.raises(CovarianceError, match="degrees of freedom"):
        covariance(J, r, 0)
    with pytest.raises(CovarianceError, match="not finite"):
        Jn = J.copy()
        Jn[3, 1] = np.nan
        covariance(Jn, r, 17)


def test_scaled_inverse_handles_parameters_of_very_different_size():
    """Columns 1e8 and 1e-6 in size: the covariance is the textbook one (statsmodels OLS)."""
    import statsmodels.api as sm

    rng = np.random.default_rng(1)
    X = rng.standard_normal((50, 3)) * np.array([1e8, 1.0, 1e-6])
    y = X @ np.array([1e-8, 2.0, 3e6]) + 0.1 * rng.standard_normal(50)
    ols = sm.OLS(y, X).fit()
    C = covariance(X, ols.resid, 47)
    np.testing.assert_allclose(C, ols.cov_params(), rtol=1e-8)


def test_parameters_at_bounds():
    # normalised (O(1)) coordinates, as the fitter uses them
    x = np.array([1e-9, 0.5, 2.0, 0.49999999999])
    lo = np.array([0.0, 0.0, 0.0, -0.5])
    hi = np.array([np.inf, 1.0, np.inf, 0.5])
    np.testing.assert_array_equal(parameters_at_bounds(x, lo, hi), [True, False, False, True])


def test_sample_normal_keeps_tiny_variances():
    """A covariance spanning 28 orders of magnitude: the small variance survives."""
    s = np.array([1e8, 1e-6, 1.0])
    R = np.array([[1, 0.5, 0.1], [0.5, 1, -0.3], [0.1, -0.3, 1]])
    C = R * np.outer(s, s)
    X = sample_normal(np.zeros(3), C, 20000, np.random.default_rng(2))
    np.testing.assert_allclose(X.std(axis=0) / s, 1, atol=0.03)
    np.testing.assert_allclose(np.corrcoef(X.T), R, atol=0.03)



def test_normal_factor_reproduces_every_variance_where_a_plain_eigen_factor_does_not():
    """The posterior draws' factor (:func:`normal_factor`) on a covariance like the
    sandwich's in the prior's coordinates, O(1) variances beside the lags' ~1e-15 s^2 with
    correlations between them: L L^T gives back each variance and correlation to
    round-off. The plain eigen-factor of the matrix itself (what the draws used until stop
    51) misses the small variances by far more, which is why the factor exists."""
    from gprm.fit.covariance import normal_factor

    rng = np.random.default_rng(4)
    P = 26
    A = rng.standard_normal((P, 3 * P))
    R = np.corrcoef(A)                                    # a well-conditioned correlation
    s = np.where(np.arange(P) >= P - 5, 3e-8, rng.uniform(0.05, 1.0, P))
    C = R * np.outer(s, s)
    L = normal_factor(C)
    back = L @ L.T
    np.testing.assert_allclose(np.diag(back), np.diag(C), rtol=1e-10)
    np.testing.assert_allclose(back / np.outer(s, s), R, atol=1e-10)
    w, V = np.linalg.eigh(C)
    plain = (V * np.sqrt(np.clip(w, 0, None))) @ (V * np.sqrt(np.clip(w, 0, None))).T
    # the small sds more than 2 % off (docs/fitting.md: "several per cent")
    assert np.max(np.abs(np.sqrt(np.diag(plain) / np.diag(C)) - 1)[-5:]) > 0.02


@pytest.mark.parametrize("sampling", ["uniform", "lhs"])
def test_starts_within_spread_and_lhs_stratified(sampling):
    center = np.array([1.0, -2.0, 0.5])
    X = draw_starts(center, MultiStartOptions(n_starts=50, seed=3, spread=0.2,
                                              sampling=sampling))
    u = (X / center - 1) / 0.2
    assert np.all(np.abs(u) <= 1)
    again = draw_starts(center, MultiStartOptions(n_starts=50, seed=3, spread=0.2,
                                                  sampling=sampling))
    np.testing.assert_array_equal(X, again)
    if sampling == "lhs":        # one start in each of the 50 strata of every parameter
        for k in range(3):
            strata = np.floor((u[:, k] + 1) / 2 * 50).astype(int)
            assert sorted(strata) == list(range(50))
