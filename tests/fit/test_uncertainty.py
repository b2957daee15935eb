"""The uncertainty methods' building blocks against independent references: the time-correlation
factor against statsmodels' autocorrelation, the MCMC sampler against an analytic Gaussian,
the bootstrap correction's centre and spread, and the prior's coordinates."""

from __future__ import annotations

import numpy as np
import pytest

from gprm.fit.prior import default_prior
from gprm.fit.bootstrap import from_bootstrap
from gprm.fit.uncertainty import Uncertainty, mcmc_chain, time_correlation_factor
from gprm.params import paper


def test_time_correlation_factor_matches_statsmodels_acf():
    from statsmodels.tsa.stattools import acf

    rng = np.random.default_rng(0)
    e = rng.standard_normal(4000)
    x = np.convolve(e, np.ones(4) / 2, mode="same")        # MA(3): rho_1..3 = 3/4, 1/2, 1/4
    L = 10
    rho = acf(x, nlags=L, fft=False)
    expect = 1 + 2 * sum((1 - k / (L + 1)) * rho[k] for k in range(1, L + 1))
    got = time_correlation_factor(x, 1, max_lag=L)
    assert got == pytest.approx(expect, rel=2e-3)
    # independent residuals: tau ~ 1; two signals are summed, not concatenated
    assert time_correlation_factor(rng.standard_normal(2000), 2) == pytest.approx(1.0, abs=0.15)


def test_mcmc_chain_samples_a_known_gaussian():
    C = np.array([[1.0, 0.8, 0.0], [0.8, 2.0, -0.3], [0.0, -0.3, 0.5]])
    m = np.array([1.0, -2.0, 0.5])
    Ci = np.linalg.inv(C)

    def lp(U):
        d = U - m
        return -0.5 * np.einsum("ij,jk,ik->i", d, Ci, d)

    ch = mcmc_chain(lp, m + 0.3, C, n_steps=4000, burn=500, seed=3)
    # effective sample size of the stretch move is ~ size / 50 here: 4 MC standard errors
    se = np.sqrt(np.diag(C) / (len(ch) / 50))
    assert np.all(np.abs(ch.mean(axis=0) - m) < 4 * se)
    np.testing.assert_allclose(np.cov(ch.T), C, atol=0.2 * np.max(np.diag(C)))


def test_bootstrap_correction_moves_identified_and_keeps_undetermined():
    p = paper()
    names = ("m2", "k_Cy")
    prior = default_prior(p, names)
    x = np.array([0.0125, 7e6])
    # Laplace: m2 identified (sd_u 0.01), k_Cy not (sd_u ~ the prior's)
    sd_u = np.array([0.01, 1.2])
    D = prior.dx_du(x)
    cov = np.diag((sd_u * D) ** 2)
    lap = Uncertainty("laplace-prior", names, cov, *(np.full(2, np.nan),) * 4,
                      np.array([True, False]), sd_u / prior.sd, None, 10.0, 1.2)
    rng = np.random.default_rng(1)
    # refits biased +2 % in m2 (spread 0.5 %), k_Cy barely moving (prior-dominated)
    refits = np.column_stack([x[0] * np.exp(0.02 + 0.005 * rng.standard_normal(400)),
                              x[1] * np.exp(0.001 * rng.standard_normal(400))])
    for method, width0 in (("bootstrap-runs", 0.005), ("generator-bootstrap", 0.01)):
        u = from_bootstrap(method, x, refits, lap, prior, n_draws=0)
        centre = np.sqrt(u.lower95 * u.upper95)                  # log-symmetric intervals
        assert centre[0] == pytest.approx(x[0] * np.exp(-0.02), rel=1e-3)
        # runs: the refits' spread; parametric: the posterior's
        assert np.log(u.upper95[0] / u.lower95[0]) == pytest.approx(2 * 1.96 * width0,
                                                                     rel=0.1)
        # the undetermined one keeps the posterior's width, not the refits' tiny spread
        assert np.log(u.upper95[1] / u.lower95[1]) == pytest.approx(2 * 1.96 * 1.2, rel=0.01)


def test_prior_coordinates_round_trip_and_interval():
    p = paper()
    names = ("m2", "gamma", "dt_y_base")
    prior = default_prior(p.with_fitted(p.fitted + ("dt_y_base",)), names)
    assert prior.log.tolist() == [True, False, False]
    x = np.array([[0.012, -0.007, 2e-6]])
    np.testing.assert_allclose(prior.from_u(prior.to_u(x)), x, rtol=1e-14)
    lo, hi = prior.interval(0.95)
    assert lo[0] > 0 and lo[0] < prior.centre[0] < hi[0]
    assert hi[1] - prior.centre[1] == pytest.approx(1.959964 * 1.25 * 0.02, rel=1e-6)


def test_parametric_bootstrap_widens_only_the_lags_by_the_refits_spread():
    """The alignment's timing jitter reaches the refits, not the likelihood: on the lags the
    refits' spread widens the posterior (never narrows it); elsewhere the posterior stands."""
    p = paper()
    names = ("t0", "m2", "dt_x_head")
    prior = default_prior(p, names)
    x = np.array([4e-6, 0.0125, 0.3e-6])
    D = prior.dx_du(x)
    sd_u = np.array([0.01, 0.01, 0.02])
    cov = np.diag((sd_u * D) ** 2)
    lap = Uncertainty("laplace-prior", names, cov, *(np.full(3, np.nan),) * 4,
                      np.array([True, True, True]), sd_u / prior.sd, None, 10.0, 1.2)
    rng = np.random.default_rng(2)
    u_hat = prior.to_u(x)
    # refits: t0 and m2 spread 3x the posterior's, dt_x_head half of it; no bias
    z = rng.standard_normal((4000, 3))
    z = (z - z.mean(0)) / z.std(0, ddof=1)
    refits = prior.from_u(u_hat + z * sd_u * np.array([3.0, 3.0, 0.5]))
    u = from_bootstrap("generator-bootstrap", x, refits, lap, prior, n_draws=0)
    half = 0.5 * (prior.to_u(u.upper95) - prior.to_u(u.lower95)) / 1.959964
    assert half[0] == pytest.approx(3.0 * sd_u[0], rel=1e-6)      # lag: the refits' spread
    assert half[1] == pytest.approx(sd_u[1], rel=1e-6)            # not a lag: posterior's
    assert half[2] == pytest.approx(sd_u[2], rel=1e-6)            # never narrower


def test_mismatch_calibration_widens_named_parameters_and_can_undo_identified():
    """The calibration multiplies a parameter's standard deviation by its factor (never by a
    factor below 1), and a parameter whose widened interval reaches CONTRACTION of the prior's
    is reported as not determined; without calibration the posterior stands."""
    from gprm.fit.calibration import MISMATCH_CALIBRATION
    from gprm.fit.uncertainty import CONTRACTION

    p = paper()
    names = ("k_Bx", "d2", "m2")
    prior = default_prior(p, names)
    x = np.array([2.2e5, 0.04, 0.0125])
    D = prior.dx_du(x)
    # k_Bx identified just below the threshold, d2 well below it, m2 not in the table
    sd_u = prior.sd * np.array([0.9 * CONTRACTION, 0.02, 0.01])
    cov = np.diag((sd_u * D) ** 2)
    lap = Uncertainty("laplace-prior", names, cov, *(np.full(3, np.nan),) * 4,
                      np.array([True, True, True]), sd_u / prior.sd, None, 10.0, 1.2)
    refits = prior.from_u(prior.to_u(x) + 0.1 * sd_u * np.random.default_rng(3)
                          .standard_normal((200, 3)))
    table = {"k_Bx": 2.0, "d2": 3.0, "m2": 0.5}
    u = from_bootstrap("generator-bootstrap", x, refits, lap, prior, n_draws=0,
                       calibration=table)
    plain = from_bootstrap("generator-bootstrap", x, refits, lap, prior, n_draws=0,
                           calibration=None)
    width = prior.to_u(u.upper95) - prior.to_u(u.lower95)
    width0 = prior.to_u(plain.upper95) - prior.to_u(plain.lower95)
    np.testing.assert_allclose(width / width0, [2.0, 3.0, 1.0], rtol=1e-9)
    np.testing.assert_allclose(width0, 2 * 1.959964 * sd_u, rtol=1e-6)
    assert u.identified.tolist() == [False, True, True]
    assert plain.identified.tolist() == [True, True, True]
    assert dict(u.calibration) == {"k_Bx": 2.0, "d2": 3.0} and plain.calibration == ()
    # the package's table names physical parameters only (Table 3's, not the lags), each
    # with a factor above 1
    from gprm.params import FITTED_DEFAULT, LAG_PARAMETERS

    physical = set(FITTED_DEFAULT) - set(LAG_PARAMETERS)
    assert MISMATCH_CALIBRATION and all(n in physical and f > 1.0
                                        for n, f in MISMATCH_CALIBRATION.items())


def test_prior_share_is_the_variance_the_prior_centre_moves_the_posterior_mean_by():
    """prior_share_of against an independent Monte Carlo: in a linear-Gaussian model the
    posterior mean is C (A^T y + Pr m); moving the prior's centre m over N(truth, Pr^-1) moves
    it by C Pr C, moving the data's noise by C A^T A C: their sum is C, and the prior's share
    of each diagonal is the share of the posterior-mean spread the prior alone causes."""
    from gprm.fit.uncertainty import prior_share_of

    rng = np.random.default_rng(3)
    A = rng.standard_normal((12, 3)) * np.array([3.0, 0.3, 0.05])   # well, weakly, hardly seen
    sd = np.array([1.0, 2.0, 0.5])
    Pr = np.diag(1 / sd ** 2)
    C = np.linalg.inv(A.T @ A + Pr)
    truth = np.array([0.3, -1.0, 0.2])
    n = 200_000
    M = truth + rng.standard_normal((n, 3)) * sd                   # prior centres
    means = (M @ Pr + (A @ truth) @ A) @ C                          # data without noise
    share_mc = np.var(means, 0) / np.diag(C)
    np.testing.assert_allclose(prior_share_of(C, sd), share_mc, rtol=0.02)
    assert prior_share_of(C, sd)[0] < 0.2 < 0.8 < prior_share_of(C, sd)[2]


def test_a_narrow_interval_tied_to_an_unseen_parameter_leans_on_the_prior():
    """b1's case (docs/fitting.md, "Parameters that lean on the prior"): the data fix
    u0 - 0.05 u1 very precisely and do not see u1, so u0's posterior is 20 times narrower
    than its prior and yet almost all of it is u1's prior; u2, seen directly, is identified."""
    from gprm.fit.prior import Prior
    from gprm.fit.uncertainty import determined, estimate

    names = ("m2", "m3", "m4")
    prior = Prior(names, np.array([0.012, 0.004, 0.0005]), np.full(3, 1.25),
                  np.ones(3, bool))
    x = prior.centre.copy()
    D = prior.dx_du(x)
    Ju = np.zeros((40, 3))
    Ju[:20, 0], Ju[:20, 1] = 300.0, -15.0            # u0 - 0.05 u1, precise
    Ju[20:, 2] = 300.0                                # u2 alone
    J = Ju / D[None, :]
    r = np.random.default_rng(0).standard_normal(40)
    u = estimate("laplace-prior", x, J, r, 37, 2, prior, names, n_draws=0)
    # u0 and u2 narrow, u1 (unseen) the prior's
    assert u.contraction[0] < 0.1 and u.contraction[2] < 0.01 and u.contraction[1] > 0.95
    assert u.leans_on_prior.tolist() == [True, False, False]
    assert u.identified.tolist() == [False, False, True]
    # the rule itself, on its edges
    ident, leans = determined(np.array([0.1, 0.1, 0.5, 0.1]), np.array([0.49, 0.5, 0.9, 0.0]))
    assert ident.tolist() == [True, False, False, True]
    assert leans.tolist() == [False, True, False, False]
    ident, leans = determined(np.array([0.1, 0.5]), None)
    assert ident.tolist() == [True, False] and not leans.any()
