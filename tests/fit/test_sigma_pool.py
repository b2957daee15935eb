"""The fit's weights pooled over neighbouring samples (gprm.fit.objective.pooled_sigma).

The claim behind the default: weighting each sample by its own standard error of the mean,
estimated from R runs (R - 1 degrees of freedom each), makes a weighted least-squares
estimator noisier than the runs' covariance (taken with the same weights) says, and the runs
cannot show it: their weighted spread is 1 at every sample by construction. The same
weights pooled over 2 K + 1 neighbouring samples remove most of that excess. Checked here by
Monte Carlo on a linear problem of the fit's size (47 samples, 10 runs), against the
sandwich the fit itself uses for the runs' part.
"""

from __future__ import annotations

import numpy as np
import pytest

from gprm.errors import GprmInputError
from gprm.fit.api import FitOptions
from gprm.fit.objective import SIGMA_POOL, fit_data_from_means, pooled_sigma

from means_factory import make_means
from gprm.params import paper


def _naive(sigma, k):
    """The pooled sigma by an explicit loop (the definition, independent of the cumsum)."""
    out = np.empty_like(sigma)
    T = sigma.shape[-1]
    for t in range(T):
        lo, hi = max(0, t - k), min(T, t + k + 1)
        out[..., t] = np.sqrt(np.mean(sigma[..., lo:hi] ** 2, axis=-1))
    return out


def test_pooled_sigma_is_the_rms_over_the_neighbours_and_leaves_a_constant_alone():
    rng = np.random.default_rng(1)
    s = rng.uniform(0.5, 2.0, (5, 47))
    for k in (1, 3, 10, 60):
        np.testing.assert_allclose(pooled_sigma(s, k), _naive(s, k), rtol=1e-12)
    np.testing.assert_array_equal(pooled_sigma(s, 0), s)
    np.testing.assert_allclose(pooled_sigma(np.full((2, 30), 3e-10), 3), 3e-10, rtol=1e-12)
    # a window wider than the record: every sample gets the whole record's rms
    np.testing.assert_allclose(pooled_sigma(s, 100),
                               np.sqrt(np.mean(s ** 2, axis=-1, keepdims=True))
                               * np.ones_like(s), rtol=1e-12)
    with pytest.raises(ValueError, match="half_width"):
        pooled_sigma(s, -1)


def _weighted_study(pool: int, *, R=10, T=47, P=4, reps=4000, seed=7):
    """(empirical variance of the estimates, mean of the runs' covariance estimate), per
    parameter, for weighted least squares of the mean of R white-noise runs (sd varying
    smoothly in time, as a drive variation's spread does), weighted by the per-sample sem
    pooled over ``pool`` samples on each side."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, T)
    A = np.stack([np.sin(2 * np.pi * (j + 1) * t + j) for j in range(P)], axis=1)   # (T, P)
    sd = 1.0 + 0.5 * np.sin(2 * np.pi * t) ** 2
    runs = sd[None, None, :] * rng.standard_normal((reps, R, T))        # truth: beta = 0
    mean = runs.mean(axis=1)
    sem = runs.std(axis=1, ddof=1) / np.sqrt(R)
    w = 1.0 / pooled_sigma(sem, pool)                                    # (reps, T)
    Aw = w[:, :, None] * A[None]                                         # (reps, T, P)
    H = np.einsum("rtp,rtq->rpq", Aw, Aw)
    M = np.linalg.solve(H, np.transpose(Aw, (0, 2, 1)))                  # (reps, P, T)
    est = np.einsum("rpt,rt->rp", M, w * mean)
    dev = (runs - mean[:, None, :]) * w[:, None, :]                     # (reps, R, T)
    proj = np.einsum("rpt,rkt->rkp", M, dev)                             # (reps, R, P)
    runs_var = (proj ** 2).sum(axis=1) / (R - 1) / R
    return est.var(axis=0), runs_var.mean(axis=0)


def test_per_sample_weights_hide_variance_from_the_runs_and_pooled_ones_do_not():
    v_each, e_each = _weighted_study(0)
    v_pool, e_pool = _weighted_study(SIGMA_POOL)
    ratio_each, ratio_pool = v_each / e_each, v_pool / e_pool
    # per-sample weights: each weighted error alone has variance (R - 1) / (R - 3) = 1.29,
    # and the estimator's excess over the runs' estimate is larger still (1.6 here): every
    # parameter far above what 4000 replicates could show by chance (se of a ratio ~ 0.03)
    assert np.all(ratio_each > 1.3), ratio_each
    # pooled over 7 samples (about 63 dof per weight, 63 / 61 = 1.03, and sd(t) varies
    # within the window): the runs' covariance is the estimator's to within a few per cent
    # plus sampling; the bound is a fifth of the per-sample excess
    assert np.all(np.abs(ratio_pool - 1.0) < 0.12), ratio_pool
    # and the pooled estimator is the more precise one
    assert np.all(v_pool < v_each), (v_pool, v_each)


def test_fit_data_pools_the_file_sigma_and_records_it():
    ds = make_means(paper(), seed=3)
    raw = fit_data_from_means(ds, sigma_pool=0)
    got = fit_data_from_means(ds)
    assert got.sigma_pool == SIGMA_POOL and raw.sigma_pool == 0
    np.testing.assert_allclose(got.sigma, _naive(raw.sigma, SIGMA_POOL), rtol=1e-12)
    np.testing.assert_array_equal(got.values, raw.values)
    for bad in (-1, 1.5, True, "3"):
        with pytest.raises(GprmInputError) as exc:
            fit_data_from_means(ds, sigma_pool=bad)
        assert exc.value.field == "sigma_pool"
    with pytest.raises(GprmInputError) as exc:
        FitOptions(sigma_pool=-2)
    assert exc.value.field == "sigma_pool"


def test_the_command_line_default_is_the_librarys():
    """`gprm fit --sigma-pool` states its default as a literal (the command module stays
    import-light); it must be SIGMA_POOL and FitOptions'."""
    import typer.main

    from gprm.cli import app

    fit = typer.main.get_command(app).commands["fit"]
    default = next(p.default for p in fit.params if p.name == "sigma_pool")
    assert default == SIGMA_POOL == FitOptions().sigma_pool
