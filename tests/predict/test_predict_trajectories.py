"""Trajectory bands: the exact linear Jacobian against finite differences of whole
simulations, and sampled vs linear spread when the covariance is small."""

from dataclasses import replace

import numpy as np

from gprm.params import batch
from gprm.predict.trajectories import (TRAJECTORY_POINTS, linear_point_jacobians,
                                       predict_trajectories, sampled_points)


def test_linear_jacobian_vs_finite_differences(fm):
    t = np.linspace(0.95e-3, 1.15e-3, 81)
    pts = TRAJECTORY_POINTS
    Jp, Jv = linear_point_jacobians(fm, t, pts, piezo=2)
    names = list(fm.names)
    for n in ("v2", "gamma", "rho", "k_Ax", "m4", "h2" if "h2" in names else "d2", "t0"):
        j = names.index(n)
        # step 1e-3 relative: central-difference truncation ~1e-6, while smaller steps are
        # dominated by rounding (absolute positions ~0.06 m, displacements ~1e-7 m)
        h = 1e-3 * abs(fm.params[n])
        sets = [fm.params.with_values(**{n: fm.params[n] + s * h}) for s in (1, -1)]
        p, v, ok = sampled_points(batch(sets), t, pts, piezo=2)
        fdp = (p[0] - p[1]) / (2 * h)
        fdv = (v[0] - v[1]) / (2 * h)
        for J, fd in ((Jp[j], fdp), (Jv[j], fdv)):
            scale = np.max(np.abs(fd), axis=(-2, -1), keepdims=True) + 1e-300
            assert np.max(np.abs(J - fd) / scale) < 1e-4, n


def test_sampled_matches_linear_for_small_covariance(fm):
    small = replace(fm, covariance=fm.covariance * 1e-6)
    t = np.linspace(0.95e-3, 1.2e-3, 126)
    tr = predict_trajectories(small, t, samples=800, seed=3)
    assert tr.n_ok == 800
    # where the band is not negligible, the two std agree to Monte Carlo precision (~5 %)
    big = tr.pos_std_lin > 0.2 * tr.pos_std_lin.max(axis=-1, keepdims=True)
    ratio = tr.pos_std[big] / tr.pos_std_lin[big]
    assert 0.9 < np.median(ratio) < 1.1
    assert np.quantile(np.abs(ratio - 1), 0.9) < 0.15


def test_band_brackets_best_and_is_reproducible(fm, times):
    a = predict_trajectories(fm, times, samples=100, seed=7, linear=False)
    b = predict_trajectories(fm, times, samples=100, seed=7, linear=False)
    np.testing.assert_array_equal(a.pos_lo, b.pos_lo)
    assert np.all(a.pos_lo <= a.pos_hi)
    assert np.all(a.pos_std >= 0)
    # the best-fit displacement lies inside the 95 % band most of the time
    inside = (a.pos >= a.pos_lo) & (a.pos <= a.pos_hi)
    assert inside.mean() > 0.8
    assert a.samples_pos.shape[0] == 20
    np.testing.assert_allclose(a.static[0], [fm.params["v2"], fm.params["g2"], fm.params["h2"]])


def test_no_covariance_leaves_the_linear_band_empty(fm, times):
    """A fit saved without a covariance still predicts; the linear band is NaN, not an error
    (the command used to guard this itself; the library call now does)."""
    bare = replace(fm, covariance=None)
    tr = predict_trajectories(bare, times, samples=0)
    assert np.all(np.isfinite(tr.pos))
    assert np.all(np.isnan(tr.pos_std_lin)) and np.all(np.isnan(tr.vel_std_lin))
    full = predict_trajectories(fm, times, samples=0)
    np.testing.assert_array_equal(tr.pos, full.pos)
    assert np.all(np.isfinite(full.pos_std_lin))
