"""Synthetic campaigns: layout, truth, ingredients."""


import numpy as np
import pytest

from gprm.campaign.data import MODEL_POSITIONS, POSITIONS, validate_campaign
from gprm.campaign.synth import TRUTH_OVERSAMPLE, SynthConfig, _mode, synth_campaign
from gprm.params import FITTED_DEFAULT, REGISTRY, paper
from gprm.campaign.files import read_truth


def test_layout(full_campaign):
    ds = full_campaign
    assert ds["displacement"].dims == ("position", "run", "time")
    assert ds["noise"].dims == ("position", "noise_run", "time")
    assert ds["voltage"].dims == ("vrun", "vtime")
    assert ds.sizes["run"] == 10 and ds.sizes["noise_run"] == 5 and ds.sizes["vrun"] == 10
    assert ds.sizes["time"] == 301 and ds["time"].values[-1] == pytest.approx(1.5e-3)
    assert [str(p) for p in ds["position"].values] == list(POSITIONS)
    for v, u in (("displacement", "m"), ("noise", "m"), ("voltage", "V"), ("time", "s")):
        assert ds[v].attrs["units"] == u
    assert ds.attrs["sample_rate"] == 200e3 and ds.attrs["seed"] == 7
    validate_campaign(ds)


def test_truth_drawn_around_paper(full_campaign):
    truth = read_truth(full_campaign)
    base = paper()
    assert set(truth) == set(REGISTRY)
    for n in REGISTRY:
        ratio = truth[n] / base[n] if base[n] != 0 else 1.0
        if n in FITTED_DEFAULT:
            assert 0.95 - 1e-12 <= ratio <= 1.05 + 1e-12, n
        else:
            assert truth[n] == base[n], n
    assert any(abs(truth[n] / base[n] - 1) > 0.01 for n in FITTED_DEFAULT)


def test_given_truth_is_stored():
    ps = paper().with_values(m2=0.0131, k_Ax=1.0e8)
    ds = synth_campaign(ps, seed=1, config=SynthConfig(n_runs=2, n_noise=1, nonlinear=False))
    truth = read_truth(ds)
    assert truth == dict(ps.values)


def test_trigger_offsets(full_campaign):
    off = full_campaign["trigger_offset"].values * 200e3
    assert np.all(np.abs(off) <= 5.0) and np.ptp(off) > 6.0
    assert np.all(np.abs(off - np.round(off)) > 1e-6)      # sub-sample, not integers


def test_voltage_traces(full_campaign):
    v = full_campaign["voltage"].values
    t = full_campaign["vtime"].values
    assert v.shape == (10, 1501)
    np.testing.assert_allclose(v[:, t < 0.9e-3].mean(axis=1), 120, rtol=0.08)
    assert np.all(np.abs(v[:, t > 1.3e-3].mean(axis=1)) < 0.5)
    assert np.ptp(v[:, t < 0.9e-3].mean(axis=1)) > 0.5          # drop amplitude varies


def test_richer_than_the_fitted_model(full_campaign):
    """The noise-free truth = linear model + nonlinear correction + unmodelled mode: the
    nonlinear part is present but far below the noise (the model's linearisation is good),
    the higher mode is 1.5 % of each peak."""
    from gprm.params import ParameterSet
    from gprm.simulate import simulate

    truth = ParameterSet(read_truth(full_campaign))
    tt = full_campaign["truth_time"].values
    assert tt[1] - tt[0] == pytest.approx(5e-6 / TRUTH_OVERSAMPLE)
    lin = simulate(truth, time=tt).outputs
    cfg = SynthConfig()
    for p in MODEL_POSITIONS:
        clean = full_campaign["truth_displacement"].sel(position=p).values
        peak = np.max(np.abs(clean))
        rest = clean - lin[p][0]
        lag = truth["t1"] if p == "z_bk" else 0.0
        mode = rest - _mode(tt, np.array([truth["t_c"] + truth["t0"] + lag]),
                            np.array([cfg.mode_rel * peak]), cfg, truth["tau_v"])[0]
        # what remains is the nonlinear correction
        assert 1e-13 < np.max(np.abs(mode)) < 5e-10, p
        assert np.max(np.abs(rest)) == pytest.approx(cfg.mode_rel * peak, rel=0.5)
