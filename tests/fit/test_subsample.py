"""The runs' sub-sample remainder, moved through the model (gprm.fit.subsample).

An exact-model campaign (gprm's generator with every imperfection off) with almost no noise
(1e-13 m) but sub-sample trigger offsets (up to 5 samples) is preprocessed: its runs are
moved by whole samples and their sub-sample rest is written beside them. The fit must then
return the truth. Interpolating the runs by a cubic spline (the file's mean, what fits
without the correction see) puts k_lr and k_Ax several 1e-5 off on this campaign (``-s``
prints the errors); the correction leaves them within 2e-5.
"""

from dataclasses import replace

import numpy as np
import pytest

from gprm.campaign.preprocess import PreprocessConfig, preprocess
from gprm.campaign.synth import SynthConfig, synth_campaign
from gprm.fit import subsample
from gprm.fit.api import FitOptions
from gprm.fit.identify import identify
from gprm.fit.objective import SIGMA_POOL, Objective, fit_data_from_means, pooled_sigma
from gprm.fit.starts import MultiStartOptions
from gprm.params import paper

JITTER = dict(nonlinear=False, mode_rel=0.0, trigger_max=5.0, v0_rel=0.0, tau_rel=0.0,
              param_rel=0.0, noise_white=1e-13, noise_coloured=0.0, drift_offset=0.0,
              drift_ramp=0.0, drift_sine=0.0)
CHECKED = ("k_lr", "m1", "m2", "k_Ax", "rho")


@pytest.fixture(scope="module")
def jitter_data():
    camp = synth_campaign(paper(), seed=5, config=replace(SynthConfig(), **JITTER))
    means = preprocess(camp, PreprocessConfig(threshold_factor=1e4)).to_dataset()
    opts = FitOptions()
    return fit_data_from_means(means, window=opts.window, sigma=opts.sigma)


@pytest.fixture(scope="module")
def jitter_fit(jitter_data):
    return _fit(jitter_data)


def _fit(data):
    opts = FitOptions()
    return identify(data, opts.parameters(paper()), MultiStartOptions(n_starts=20, seed=5),
                    band_samples=0, uncertainty="eq7", prior_width=opts.prior_width)


def _errors(fit):
    truth = paper()
    x = dict(zip(fit.names, np.asarray(fit.x)))
    return {n: x[n] / truth[n] - 1 for n in CHECKED}


def test_remainder_is_read_and_within_half_a_sample(jitter_data):
    rem = jitter_data.sync_remainder
    dt = float(np.median(np.diff(jitter_data.time)))
    assert rem is not None and rem.shape == jitter_data.runs.shape[:2]
    assert np.all(np.abs(rem) <= 0.5 * dt + 1e-15)
    assert np.count_nonzero(np.abs(rem) > 0.1 * dt) > rem.size // 2
    assert subsample.applies(jitter_data)


def test_run_corrections_are_the_model_moved_by_each_remainder(jitter_data):
    """The one stacked simulation gives, for every signal and run, y(t - rem) - y(t)
    evaluated one run at a time."""
    opts = FitOptions()
    base = opts.parameters(paper())
    obj = Objective.create(jitter_data, base, tuple(base.fitted))
    x = np.array([base[n] for n in obj.names])
    got = subsample.run_corrections(obj, x, jitter_data.sync_remainder)
    y0 = obj.model(x[None]).y[0]
    for s in (0, 4):
        for r in (1, 7):
            rem = jitter_data.sync_remainder[s, r]
            want = obj.model(x[None], times=jitter_data.time - rem).y[0, s] - y0[s]
            np.testing.assert_allclose(got[s, r], want, rtol=0, atol=1e-12 * np.abs(y0[s]).max())
    assert np.abs(got).max() > 0


def test_corrected_runs_agree_to_the_noise_and_sigma_follows_them(jitter_data, jitter_fit):
    """Moved by the fitted model's own shape, the runs of this nearly noise-free campaign
    agree with each other to far below the spread the sub-sample offsets leave; mean and
    sigma are taken over them (sem and std as the data were weighed, pooled over as many
    neighbouring samples as the file's sigma was)."""
    obj = Objective.create(jitter_data, jitter_fit.params, jitter_fit.names)
    x = np.asarray(jitter_fit.x)
    corr = subsample.run_corrections(obj, x, jitter_data.sync_remainder)
    fixed = subsample.corrected(jitter_data, corr)
    before = jitter_data.runs.std(axis=1, ddof=1).max(axis=1)
    after = fixed.runs.std(axis=1, ddof=1).max(axis=1)
    assert np.all(after < 0.01 * before), (before, after)
    np.testing.assert_allclose(fixed.values, fixed.runs.mean(axis=1))
    R = fixed.runs.shape[1]
    assert jitter_data.sigma_pool == SIGMA_POOL > 0
    np.testing.assert_allclose(fixed.sigma, pooled_sigma(
        fixed.runs.std(axis=1, ddof=1) / np.sqrt(R), SIGMA_POOL))
    as_std = subsample.corrected(replace(jitter_data, sigma_kind="std", sigma_pool=0), corr)
    np.testing.assert_allclose(as_std.sigma, as_std.runs.std(axis=1, ddof=1))
    assert fixed.sync_remainder is None and fixed.interpolation_error is None


def test_fit_with_trigger_offsets_returns_its_truth(jitter_data, jitter_fit):
    """With the remainder moved through the model the fit returns the truth to 2e-5; the
    same data fitted without it (the file's spline-interpolated mean) miss it by several
    times that on k_lr."""
    fit = jitter_fit
    err = _errors(fit)
    for n, e in err.items():
        assert abs(e) < 2e-5, (n, e)
    assert fit.data.sync_remainder is None
    info = fit.polish["subsample"]
    assert set(info) == set(jitter_data.signals)
    assert max(v["max_run_change_m"] for v in info.values()) > 0
    old = _errors(_fit(replace(jitter_data, sync_remainder=None)))
    # the figures docs/fitting.md quotes (pytest -s prints them)
    print("relative errors, runs moved through the model:", {n: f"{e:.2g}" for n, e in err.items()})
    print("relative errors, interpolated mean:", {n: f"{e:.2g}" for n, e in old.items()})
    assert abs(old["k_lr"]) > 3 * abs(err["k_lr"]) and abs(old["k_lr"]) > 4e-5, old


def test_passes_correct_at_each_point_and_leave_the_last_polish_to_the_caller(jitter_data):
    """``correct_and_polish`` corrects at the given point, polishes, corrects again at the
    polished point; with ``final_polish=False`` (identify's use: its own polish with the prior
    weighed follows) the last correction is not polished, and the objective returned holds
    the runs moved by the corrections at the point returned."""
    opts = FitOptions()
    base = opts.parameters(paper())
    obj = Objective.create(jitter_data, base, tuple(base.fitted))
    x0 = np.array([base[n] for n in obj.names])
    x1 = x0 * (1.0 + 1e-3)
    polished = []

    def polish(o, x):
        polished.append(np.array(x))
        return x1

    def make(d):
        return Objective.create(d, base, tuple(base.fitted))

    out, x, corr = subsample.correct_and_polish(obj, make, x0, polish, final_polish=False)
    assert len(polished) == subsample.PASSES - 1 and np.array_equal(polished[0], x0)
    np.testing.assert_array_equal(x, x1)
    want = subsample.run_corrections(obj, x1, jitter_data.sync_remainder)
    np.testing.assert_array_equal(corr, want)
    np.testing.assert_allclose(out.data.runs, jitter_data.runs - want)
    polished.clear()
    subsample.correct_and_polish(obj, make, x0, polish)
    assert len(polished) == subsample.PASSES
