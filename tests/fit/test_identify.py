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
from gprm.fit.covariance import covariance
from gprm.fit.engine import run_multistart
from gprm.fit.files import load_fit
from gprm.fit.identify import identify
from gprm.fit.lm import levenberg_marquardt_batch
from gprm.fit.objective import Objective, fit_data_from_means
from gprm.fit.starts import LMOptions, MultiStartOptions
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
    # the factory's sem is the noise's own sd, not an estimate from runs: weighed as given
    # (pooling is for estimated weights, gprm.fit.objective.pooled_sigma), so the chi-square
    # statistics below are exact
    data = fit_data_from_means(ds, source="synthetic", sigma_pool=0)
    return truth, ds, data


def test_objective_jacobian_matches_finite_differences(case):
    truth, ds, data = case
    obj = Objective.create(data, paper())
    xn = obj.to_normalised(truth.vector(obj.names))
    r, J = obj(xn[None])
    # Richardson-extrapolated central differences (error O(h^4)) with h = 2e-3 of the
    # normalised (O(1)) parameters: large enough that the round-off of the eigen-solution
    # (~1e-12 relative in y, amplified by 1/h) stays negligible even for the weakest column
    def central(k, h):
        e = np.zeros_like(xn)
        e[k] = h
        return (obj.residuals((xn + e)[None]) - obj.residuals((xn - e)[None]))[0] / (2 * h)

    for k in range(len(obj.names)):
        fd = (4 * central(k, 1e-3) - central(k, 2e-3)) / 3
        assert np.max(np.abs(fd - J[0, :, k])) <= 1e-5 * np.max(np.abs(J[0, :, k])), \
            obj.names[k]


@pytest.fixture(scope="module")
def best(case):
    truth, ds, data = case
    return identify(data, paper(), MultiStartOptions(n_starts=8, seed=3, chunk_size=8),
                    band_samples=0, uncertainty="laplace-prior")


def test_reduced_chi2_near_one_and_truth_recovered(case, best):
    truth, ds, data = case
    res = best
    dof = res.dof
    # chi2/dof of a correct model follows chi2(dof)/dof: mean 1, sd sqrt(2/dof)
    assert abs(res.reduced_chi2 - 1) < 4 * np.sqrt(2 / dof)
    # the best fit is at least as good as the truth itself
    obj = Objective.create(data, paper())
    chi_truth = float(obj.chi2(obj.to_normalised(truth.vector(obj.names))[None])[0])
    assert res.chi2 <= chi_truth + 1e-6
    # in the coordinates of the posterior (ln x for positive parameters) the truth lies
    # within 4.5 posterior standard deviations of the best fit for every parameter
    u, prior = res.uncertainty, res.prior
    sd_u = u.contraction * prior.sd
    z = (prior.to_u(res.x) - prior.to_u(truth.vector(res.names))) / sd_u
    assert np.all(np.isfinite(z))
    assert np.max(np.abs(z)) < 4.5, dict(zip(res.names, np.round(z, 2)))
    # and a parameter reported with a small error is narrow: one the data determine, or one
    # whose narrow interval is mostly the prior's (it leans on the prior, docs/fitting.md)
    small = res.stderr < 0.1 * np.abs(res.x)
    assert np.all((u.identified | u.leans_on_prior)[small])
    assert not np.any(u.identified & u.leans_on_prior)
    # the model describes these data: no resonance marginalised, the strongest candidate of
    # the search recorded with its ratio under the threshold (gprm.fit.resonance)
    assert res.resonance is None and "resonance" not in res.polish
    search = res.polish["resonance_search"]
    assert search["found"] is False and search["strongest"]["ratio"] < search["threshold"]


def test_coverage_over_several_campaigns():
    """Over several noise realisations the Eq. 7 intervals cover the truth at the nominal
    rate: |best - truth| <= 1 stderr for about 68 % of the parameters, <= 2 stderr for about
    95 %. The local minimum next to the truth is found by LM started at the truth (the
    multi-start search is tested elsewhere). Only parameters the data determine are counted
    (stderr below half their value): six y-plane parameters have stderr 10-300 times their
    value in these synthetic campaigns, where a linearised interval means nothing."""
    z_all = []
    for seed in range(6):
        truth = truth_set(10 + seed)
        data = fit_data_from_means(make_means(truth, seed=100 + seed), sigma_pool=0)
        obj = Objective.create(data, paper())
        lo, hi = obj.bounds_normalised()
        xt = obj.to_normalised(truth.vector(obj.names))
        res = levenberg_marquardt_batch(obj, xt[None], residuals=obj.residuals, lower=lo,
                                        upper=hi, max_iter=60, ftol=1e-10, ftol_abs=1e-4)
        r, Jn = obj(res.x)
        C = covariance(Jn[0] / obj.scale, r[0], obj.dof)
        se = np.sqrt(np.diag(C))
        x = obj.to_physical(res.x[0])
        good = se < 0.5 * np.abs(truth.vector(obj.names))
        assert good.sum() >= 15
        z_all.append(np.abs(x - truth.vector(obj.names))[good] / se[good])
    z = np.concatenate(z_all)
    f1, f2 = np.mean(z <= 1), np.mean(z <= 2)
    sd1 = np.sqrt(0.683 * 0.317 / z.size)
    sd2 = np.sqrt(0.954 * 0.046 / z.size)
    assert abs(f1 - 0.683) < 3 * sd1, (f1, f2, z.size)
    assert abs(f2 - 0.954) < 3 * sd2 + 0.01, (f1, f2, z.size)


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
    opts = MultiStartOptions(n_starts=6, seed=5, chunk_size=2, lm=LMOptions(max_iter=12))
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
def test_same_result_in_process_on_a_dask_worker_and_on_two_local_workers(case):
    truth, ds, data = case
    obj = Objective.create(data, paper())
    opts = MultiStartOptions(n_starts=4, seed=7, chunk_size=1, lm=LMOptions(max_iter=8))
    from distributed import LocalCluster

    inproc = run_multistart(obj, opts, workers=0)
    # one worker on an existing Dask cluster (the --scheduler path), two local worker
    # processes (the default pool)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      dashboard_address=":0", silence_logs=40) as cluster:
        one = run_multistart(obj, opts, scheduler=cluster.scheduler_address)
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


# fitted parameters the synthetic campaigns determine (stderr < value; see the coverage test)
WELL_DETERMINED = ("v2", "g2", "gamma", "rho", "k_lr", "k_Ax", "k_Bx", "c_Ax", "c_Bx", "m1",
                   "m2", "m3", "m4", "d1", "d2", "t0", "t1")


def test_fit_files_follow_the_contract(case, tmp_path):
    truth, ds, data = case
    # the y-plane parameters are held at their true values, so that the covariance is
    # well-defined and the sampled band can be compared with the linear one
    base = truth.with_fitted(WELL_DETERMINED)
    res = identify(data, base, MultiStartOptions(n_starts=6, seed=2, chunk_size=6),
                   band_samples=60, uncertainty="laplace-prior")
    out = tmp_path / "fit.json"
    res.write(out)
    d = json.loads(out.read_text())
    for key in ("model", "piezo", "version", "seed", "window", "parameters", "chi2", "dof",
                "reduced_chi2", "correlation", "starts"):
        assert key in d
    assert d["model"] == "gprm-3d"
    # the weights as the fit used them (this case's exact-sigma data: as given)
    assert d["sigma"] == "sem" and d["sigma_pool"] == data.sigma_pool == 0
    assert set(d["starts"]) >= {"requested", "converged", "best_index"}
    v2 = d["parameters"]["v2"]
    assert v2["unit"] == "m" and v2["fitted"] and v2["stderr"] > 0
    assert d["parameters"]["h3"]["fitted"] is False
    assert d["parameters"]["k_Cy"]["fitted"] is False
    # the JSON reads back through the loader later stages use
    fm = load_fit(out)
    assert fm.names == res.names
    np.testing.assert_allclose(fm.params.vector(fm.names), res.x, rtol=1e-12)
    np.testing.assert_allclose(fm.covariance, res.covariance, rtol=1e-9,
                               atol=1e-12 * np.max(np.abs(res.covariance)))
    assert d["band_samples"] > 30
    # a profile with a grid point that could not be evaluated still writes valid JSON
    import dataclasses

    from gprm.fit.uncertainty import Profile

    prof = Profile("m2", np.array([1.0, 2.0, 3.0]), np.array([5.0, np.nan, 4.0]), np.nan, 2.5)
    dataclasses.replace(res, profiles=(prof,)).write(tmp_path / "p.json")
    pj = json.loads((tmp_path / "p.json").read_text())["profiles"][0]
    assert pj["chi2"] == [5.0, None, 4.0] and pj["lower"] is None
    assert pj["identifiable"] is False
    side = xr.open_dataset(out.with_suffix(".nc"))
    assert side.sizes["start"] == 6 and side.sizes["param"] == len(WELL_DETERMINED)
    assert {"x0", "x", "chi2", "iterations", "status", "model_best", "band_linear_std"} <= set(
        side.variables)
    # bands: linear propagation and sampling agree roughly where the signal is large
    lin, smp = side["band_linear_std"].values, side["band_sample_std"].values
    big = lin > 0.2 * lin.max()
    assert np.median(smp[big] / lin[big]) == pytest.approx(1.0, rel=0.35)
    side.close()


def test_profile_likelihood_brackets_the_best_fit(case, best):
    """For a well-determined parameter the profile's 68 % and 95 % intervals (D <= 1, 3.84
    on the posterior's scale) agree with the Laplace posterior's, the profile's minimum is at
    the best fit, and a parameter the data do not determine is not bounded by its profile
    on at least one side (its interval comes from the prior alone)."""
    truth, ds, data = case
    from gprm.fit.prior import default_prior
    from gprm.fit.uncertainty import profile_likelihood

    u = best.uncertainty
    prior = default_prior(paper(), best.names).with_weight(np.sqrt(u.s2))
    obj = Objective.create(data, paper(), prior=prior)
    k = obj.names.index("m2")
    sd_u = u.contraction * prior.sd
    prof = profile_likelihood(obj, best.x, "m2", s2=u.s2, sd_u=sd_u[k])
    assert prof.identifiable
    assert np.all(np.diff(prof.grid) > 0) and np.nanmin(prof.chi2) == 0.0
    assert prof.grid[np.nanargmin(prof.chi2)] == pytest.approx(best.x[k], rel=1e-6)
    for lo, hi, plo, phi in ((u.lower68[k], u.upper68[k], prof.lower, prof.upper),
                             (u.lower95[k], u.upper95[k], prof.lower95, prof.upper95)):
        assert (phi - plo) / (hi - lo) == pytest.approx(1.0, rel=0.3)
    # the least determined parameter: its profile (bounded by the prior, which is part of
    # the posterior) is as wide as the posterior says, far wider than an identified one's
    j = int(np.argmax(u.contraction))
    assert not u.identified[j]
    pj = profile_likelihood(obj, best.x, obj.names[j], s2=u.s2, sd_u=sd_u[j])
    width_u = np.log(pj.upper95 / pj.lower95) if prior.log[j] else pj.upper95 - pj.lower95
    assert width_u > 2 * 1.96 * 0.3 * prior.sd[j]


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
    small = fit_data_from_means(ds, window=(1.0e-3, 1.015e-3))   # 4 times x 5 signals < 23
    with pytest.raises(GprmInputError, match="too few observations"):
        Objective.create(small, paper())
    obj = Objective.create(data, paper())
    with pytest.raises(GprmInputError, match="at least 1"):
        run_multistart(obj, MultiStartOptions(n_starts=0))


def test_profiles_in_the_fit_result(case, tmp_path):
    truth, ds, data = case
    base = truth.with_fitted(("k_lr", "m2", "t1"))
    res = identify(data, base, MultiStartOptions(n_starts=2, seed=1, chunk_size=2),
                   band_samples=0, profile=True, uncertainty="laplace-prior")
    assert [p.name for p in res.profiles] == list(res.names)
    for p, x, se in zip(res.profiles, res.x, res.stderr):
        assert p.identifiable
        assert p.lower < x < p.upper
        # with 3 well-determined parameters the profile and Eq. 7 agree closely
        assert 0.8 < 0.5 * (p.upper - p.lower) / (se / np.sqrt(res.reduced_chi2)) < 1.25
    res.write(tmp_path / "f.json")
    d = json.loads((tmp_path / "f.json").read_text())
    assert [p["name"] for p in d["profiles"]] == list(res.names)


def test_sem_and_std_weights_give_the_same_fit_and_covariance(case):
    """std = sqrt(10) sem in the factory: chi-square scales by 1/10, the best fit and the
    Eq. 7 covariance (which rescales by the residual variance) do not change."""
    truth, ds, data = case
    out = {}
    for kind in ("sem", "std"):
        d = fit_data_from_means(ds, sigma=kind)
        obj = Objective.create(d, paper())
        lo, hi = obj.bounds_normalised()
        xt = obj.to_normalised(truth.vector(obj.names))
        res = levenberg_marquardt_batch(obj, xt[None], residuals=obj.residuals, lower=lo,
                                        upper=hi, max_iter=15, ftol=0.0)
        r, Jn = obj(res.x)
        out[kind] = (res.chi2[0], obj.to_physical(res.x[0]),
                     covariance(Jn[0] / obj.scale, r[0], obj.dof))
    assert out["std"][0] == pytest.approx(out["sem"][0] / 10, rel=1e-6)
    se = np.sqrt(np.diag(out["sem"][2]))
    assert np.max(np.abs(out["std"][1] - out["sem"][1]) / se) < 1e-3
    np.testing.assert_allclose(np.sqrt(np.diag(out["std"][2])), se, rtol=1e-3)


def test_profile_of_a_predicted_quantity_matches_the_parameter_profile(case, best):
    """A predicted quantity that is a parameter itself (g(x) = m2): its profile, computed
    through the soft constraint, brackets the same 68 % and 95 % intervals as the parameter's
    own profile; and a real prediction (the plunger CoM's x overshoot) gets a profile with its
    minimum at the best fit."""
    from gprm.fit.prior import default_prior
    from gprm.fit.uncertainty import profile_likelihood, profile_prediction

    truth, ds, data = case
    u = best.uncertainty
    prior = default_prior(paper(), best.names).with_weight(np.sqrt(u.s2))
    obj = Objective.create(data, paper(), prior=prior)
    k = obj.names.index("m2")
    sd_u = u.contraction * prior.sd
    par = profile_likelihood(obj, best.x, "m2", s2=u.s2, sd_u=sd_u[k])
    pred = profile_prediction(obj, best.x, lambda X: X[:, k], "m2 as a prediction", s2=u.s2,
                              sd=best.x[k] * sd_u[k])
    assert pred.identifiable and par.identifiable
    for a, b in ((pred.lower, par.lower), (pred.upper, par.upper),
                 (pred.lower95, par.lower95), (pred.upper95, par.upper95)):
        assert a == pytest.approx(b, rel=0.02 * (par.upper95 - par.lower95) / best.x[k])

    from gprm.params import batch_from_vectors
    from gprm.predict.trajectories import default_times, sampled_points

    t = default_times(rate=2e5)

    def overshoot_x(X):
        pos, _, _ = sampled_points(batch_from_vectors(paper(), obj.names, X), t, ("com",),
                                   piezo=2)
        return np.max(np.abs(pos[:, 0, 0]), axis=-1)

    prof = profile_prediction(obj, best.x, overshoot_x, "com x overshoot", s2=u.s2)
    assert np.nanmin(prof.chi2) == 0.0
    assert prof.grid[np.nanargmin(prof.chi2)] == pytest.approx(overshoot_x(best.x[None])[0],
                                                              rel=1e-6)
    assert prof.lower95 < overshoot_x(best.x[None])[0] < prof.upper95
