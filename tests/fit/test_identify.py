"""Identification on synthetic mean signals with known truth: objective, multi-start,
covariance, coverage, reduced chi-square, scipy cross-check, resume and workers, bad input."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from scipy.optimize import least_squares

from gprm.errors import GprmInputError
from gprm.fit.multistart import LMOptions, MultiStartOptions, run_multistart
from gprm.fit.objective import Objective, fit_data_from_means
from gprm.fit.result import identify
from gprm.params import paper

sys.path.insert(0, str(Path(__file__).parent))
from means_factory import make_means  # noqa: E402


def truth_set(seed: int):
    """A truth drawn around the paper set: fitted parameters within +-5 %."""
    p = paper()
    rng = np.random.default_rng([seed, 99])
    x = p.vector() * (1 + 0.05 * rng.uniform(-1, 1, len(p.fitted)))
    return p.with_vector(x)


@pytest.fixture(scope="module")
def case():
    truth = truth_set(1)
    ds = make_means(truth, seed=1)
    data = fit_data_from_means(ds, source="synthetic")
    return truth, ds, data


def test_objective_jacobian_matches_finite_differences(case):
    truth, ds, data = case
    obj = Objective.create(data, paper())
    xn = obj.to_normalised(truth.vector(obj.names))
    r, J = obj(xn[None])
    h = 1e-6
    for k in (0, 5, 13, 21, 22):
        e = np.zeros_like(xn)
        e[k] = h
        fd = (obj.residuals((xn + e)[None]) - obj.residuals((xn - e)[None]))[0] / (2 * h)
        assert np.max(np.abs(fd - J[0, :, k])) <= 1e-5 * np.max(np.abs(J[0, :, k]))


def test_reduced_chi2_near_one_and_truth_recovered(case):
    truth, ds, data = case
    res = identify(data, paper(), MultiStartOptions(n_starts=24, seed=3, chunk_size=24),
                   band_samples=50)
    dof = res.dof
    # chi2/dof of a correct model follows chi2(dof)/dof: mean 1, sd sqrt(2/dof)
    assert abs(res.reduced_chi2 - 1) < 4 * np.sqrt(2 / dof)
    # the best fit is at least as good as the truth itself
    obj = Objective.create(data, paper())
    chi_truth = float(obj.chi2(obj.to_normalised(truth.vector(obj.names))[None])[0])
    assert res.chi2 <= chi_truth + 1e-6
    z = (res.x - truth.vector(res.names)) / res.stderr
    assert np.all(np.isfinite(z))
    assert np.max(np.abs(z)) < 4.5, dict(zip(res.names, np.round(z, 2)))


def test_coverage_over_several_campaigns():
    """Over several noise realisations, |best - truth| <= 1 stderr for about 68 % of
    the parameters (and <= 2 stderr for about 95 %)."""
    hits1 = hits2 = total = 0
    for seed in range(6):
        truth = truth_set(10 + seed)
        data = fit_data_from_means(make_means(truth, seed=100 + seed))
        res = identify(data, paper(), MultiStartOptions(n_starts=16, seed=seed, chunk_size=16),
                       band_samples=0)
        z = np.abs(res.x - truth.vector(res.names)) / res.stderr
        hits1 += int(np.sum(z <= 1))
        hits2 += int(np.sum(z <= 2))
        total += z.size
    f1, f2 = hits1 / total, hits2 / total
    sd1 = np.sqrt(0.68 * 0.32 / total)
    assert abs(f1 - 0.683) < 4 * sd1, (f1, f2)
    assert f2 > 0.85, (f1, f2)


def test_matches_scipy_least_squares_from_same_start(case):
    truth, ds, data = case
    obj = Objective.create(data, paper())
    x0 = obj.to_normalised(paper().initial_vector(obj.names))
    ours = run_multistart(obj, MultiStartOptions(n_starts=1, spread=0.0, chunk_size=1,
                                                 lm=LMOptions(max_iter=300)))
    sp = least_squares(lambda x: obj.residuals(x[None])[0], x0,
                       jac=lambda x: obj(x[None])[1][0], method="lm", xtol=1e-12,
                       ftol=1e-12, gtol=1e-12, max_nfev=3000)
    chi_sp = float(np.sum(sp.fun ** 2))
    assert ours.chi2[0] <= chi_sp * (1 + 1e-6) + 1e-6, (ours.chi2[0], chi_sp)


def test_resume_after_interruption_is_identical(case, tmp_path):
    truth, ds, data = case
    obj = Objective.create(data, paper())
    opts = MultiStartOptions(n_starts=12, seed=5, chunk_size=4, lm=LMOptions(max_iter=30))
    full = run_multistart(obj, opts)
    ck = tmp_path / "ckpt"
    with pytest.raises(KeyboardInterrupt):
        run_multistart(obj, opts, checkpoint_dir=ck, stop_after=1)
    assert len(list(ck.glob("chunk_*.npz"))) == 1
    resumed = run_multistart(obj, opts, checkpoint_dir=ck)
    for f in ("x0", "x", "chi2", "iterations", "converged", "status"):
        np.testing.assert_array_equal(getattr(full, f), getattr(resumed, f))


def test_checkpoint_from_other_inputs_is_refused(case, tmp_path):
    truth, ds, data = case
    obj = Objective.create(data, paper())
    opts = MultiStartOptions(n_starts=4, seed=5, chunk_size=4, lm=LMOptions(max_iter=5))
    run_multistart(obj, opts, checkpoint_dir=tmp_path / "c")
    other = MultiStartOptions(n_starts=4, seed=6, chunk_size=4, lm=LMOptions(max_iter=5))
    with pytest.raises(GprmInputError, match="checkpoint"):
        run_multistart(obj, other, checkpoint_dir=tmp_path / "c")


@pytest.mark.slow
def test_same_result_for_one_and_two_dask_workers(case):
    truth, ds, data = case
    obj = Objective.create(data, paper())
    opts = MultiStartOptions(n_starts=8, seed=7, chunk_size=2, lm=LMOptions(max_iter=20))
    inproc = run_multistart(obj, opts, workers=0)
    one = run_multistart(obj, opts, workers=1)
    two = run_multistart(obj, opts, workers=2)
    for f in ("x", "chi2", "iterations", "status"):
        np.testing.assert_array_equal(getattr(one, f), getattr(two, f))
        np.testing.assert_array_equal(getattr(inproc, f), getattr(two, f))


def test_unstable_starts_are_resampled_or_reported(case):
    truth, ds, data = case
    # A huge spread makes many starts non-physical (negative masses/stiffnesses).
    obj = Objective.create(data, paper())
    out = run_multistart(obj, MultiStartOptions(n_starts=20, seed=1, spread=3.0, chunk_size=20,
                                                lm=LMOptions(max_iter=3)))
    assert out.resampled.sum() > 0
    failed = np.char.startswith(out.status.astype(str), "failed")
    assert np.all(np.isfinite(out.chi2[~failed]))
    for s in out.status[failed]:
        assert len(s) > len("failed: ")


def test_fit_files_follow_the_contract(case, tmp_path):
    truth, ds, data = case
    res = identify(data, paper(), MultiStartOptions(n_starts=6, seed=2, chunk_size=6),
                   band_samples=30)
    out = tmp_path / "fit.json"
    res.write(out)
    d = json.loads(out.read_text())
    for key in ("model", "piezo", "version", "seed", "window", "parameters", "chi2", "dof",
                "reduced_chi2", "correlation", "starts"):
        assert key in d
    assert d["model"] == "gprm-3d"
    assert set(d["starts"]) >= {"requested", "converged", "best_index"}
    v2 = d["parameters"]["v2"]
    assert v2["unit"] == "m" and v2["fitted"] and v2["stderr"] > 0
    assert d["parameters"]["h3"]["fitted"] is False
    side = xr.open_dataset(out.with_suffix(".nc"))
    assert side.sizes["start"] == 6 and side.sizes["param"] == 23
    assert {"x0", "x", "chi2", "iterations", "status", "model_best", "band_linear_std"} <= set(
        side.variables)
    # bands: linear propagation and sampling agree roughly where the signal is large
    lin, smp = side["band_linear_std"].values, side["band_sample_std"].values
    big = lin > 0.2 * lin.max()
    assert np.median(smp[big] / lin[big]) == pytest.approx(1.0, rel=0.35)
    side.close()


def test_profile_likelihood_brackets_the_best_fit(case):
    truth, ds, data = case
    res = identify(data, paper(), MultiStartOptions(n_starts=8, seed=2, chunk_size=8),
                   band_samples=0)
    from gprm.fit.result import profile_likelihood

    obj = Objective.create(data, paper())
    k = res.names.index("m2")
    prof = profile_likelihood(obj, res.x, res.stderr, "m2", n_points=9)
    assert prof.identifiable
    # the profile interval agrees with the linearised +-1 stderr within a factor ~1.5
    half = 0.5 * (prof.upper - prof.lower)
    assert 0.6 < half / res.stderr[k] < 1.6
    assert np.argmin(prof.chi2) == 4


@pytest.mark.parametrize("mutate, field", [
    (lambda ds: ds.drop_vars("sem"), "sem"),
    (lambda ds: ds.assign(sem=ds["sem"] * 0), "sem"),
    (lambda ds: ds.assign(sem=-ds["sem"]), "sem"),
    (lambda ds: ds.isel(time=slice(0, 150)), "window"),
])
def test_bad_mean_signals(case, mutate, field):
    truth, ds, data = case
    with pytest.raises(GprmInputError) as e:
        fit_data_from_means(mutate(ds), source="means.nc")
    assert e.value.field == field


def test_too_few_observations_and_zero_starts(case):
    truth, ds, data = case
    small = fit_data_from_means(ds, window=(1.0e-3, 1.02e-3))
    with pytest.raises(GprmInputError, match="too few observations"):
        Objective.create(small, paper())
    obj = Objective.create(data, paper())
    with pytest.raises(GprmInputError, match="at least 1"):
        run_multistart(obj, MultiStartOptions(n_starts=0))
