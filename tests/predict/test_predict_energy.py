"""Kinetic-energy check (Fig. 8): histogram properties, the five-point energy against the
coordinates it stands for, error propagation, and model vs measured on a synthetic campaign."""

import numpy as np
import pytest

from gprm.errors import GprmInputError
from gprm.predict.energy import (FIVE, derivative_std, differentiate, energy_check,
                                 histogram, point_energy, read_means, window_weights)
from gprm.simulate.kinematics import body_motion

from predict_means_synth import synthetic_means


@pytest.fixture(scope="module")
def truth(fm):
    """The model itself (best fit) plays the hardware; noise is added to its signals."""
    return fm.params


@pytest.fixture(scope="module")
def means_file(tmp_path_factory, truth):
    p = tmp_path_factory.mktemp("means") / "means.nc"
    synthetic_means(truth, seed=5).to_netcdf(p)
    return p


def test_histogram_properties(fm, means_file):
    ec = energy_check(fm, means=read_means(means_file), samples=60, seed=1, noise_draws=50)
    span = ec.window[1] - ec.window[0]
    for E in (ec.model_total, ec.model_point, ec.measured_point):
        assert np.all(E >= 0)
    sel = ec.weights > 0
    assert ec.edges[0] == 0 and ec.edges[-1] >= max(ec.model_point[sel].max(),
                                                    ec.measured_point[sel].max())
    assert ec.edges_total[-1] >= ec.model_total[sel].max()
    for h in (ec.hist_model_total, ec.hist_model_point, ec.hist_measured):
        assert np.all(h >= 0)
        assert abs(h.sum() - span) < 1e-12 * span
    assert np.isclose(ec.weights.sum(), span, rtol=0, atol=1e-15)
    # the all-bodies energy exceeds what the five points see (spacer/tip axial motion hidden)
    assert ec.model_total[sel].max() > ec.model_point[sel].max()


def test_histogram_totals_any_window():
    t = np.linspace(0, 1, 101)
    w = window_weights(t, (0.2, 0.75))
    assert np.isclose(w.sum(), 0.55)
    E = np.abs(np.sin(7 * t))[None].repeat(3, 0)
    h = histogram(E, w, np.linspace(0, 1, 6))
    np.testing.assert_allclose(h.sum(axis=-1), 0.55)


def test_point_energy_equals_coordinate_form(fm):
    """E_5 from the five points' rates equals the same energy written with the coordinates."""
    t = np.linspace(0.95e-3, 1.2e-3, 126)
    m = body_motion(fm, t)
    p = {k: v[0] for k, v in m.params.items()}
    r = {k: v[0] for k, v in m.rates.items()}
    pts = {"x_base": r["x_A_dot"] + p["d_x_base"] * r["eta_dot"],
           "x_head": r["x_A_dot"] + p["d_x_head"] * r["eta_dot"],
           "y_base": r["y_A_dot"] - p["d_y_base"] * r["theta_dot"],
           "y_head": r["y_A_dot"] - p["d_y_head"] * r["theta_dot"],
           "z_bk": r["z_A_dot"]}
    E = point_energy(pts, p)
    ref = 0.5 * p["J2"] * (r["eta_dot"] ** 2 + r["theta_dot"] ** 2)
    for mass, s in (("m2", p["h2"]), ("m3", p["h3"]), ("m4", p["h3"] + p["h4"])):
        ref = ref + 0.5 * p[mass] * ((r["x_A_dot"] + s * r["eta_dot"]) ** 2
                                     + (r["y_A_dot"] - s * r["theta_dot"]) ** 2
                                     + r["z_A_dot"] ** 2)
    np.testing.assert_allclose(E, ref, rtol=1e-12, atol=1e-30)


def test_derivative_std_monte_carlo():
    rng = np.random.default_rng(0)
    t = np.cumsum(np.r_[0, rng.uniform(0.5, 1.5, 30)])
    s = rng.uniform(0.5, 2.0, t.size)
    draws = differentiate(s * rng.standard_normal((20000, t.size)), t)
    np.testing.assert_allclose(draws.std(axis=0), derivative_std(s, t), rtol=0.04)


def agreement(ec):
    diff = np.abs(ec.hist_model_point - ec.hist_measured)
    err = np.sqrt(ec.hist_model_point_err ** 2 + ec.hist_measured_err ** 2)
    return diff <= 2 * err + 1e-15


def test_model_and_measured_agree_on_synthetic_campaign(fm, means_file):
    ec = energy_check(fm, means=read_means(means_file), samples=150, seed=2, noise_draws=100)
    ok = agreement(ec)
    assert ok.all(), (ec.hist_model_point, ec.hist_measured, ec.hist_model_point_err)


def test_disagreement_detected(fm, truth, tmp_path):
    """Negative control: signals 1.5 times too large (energy x 2.25) do not agree."""
    p = tmp_path / "big.nc"
    synthetic_means(truth, seed=5, scale=1.5).to_netcdf(p)
    ec = energy_check(fm, means=read_means(p), samples=150, seed=2, noise_draws=100)
    assert not agreement(ec).all()


def test_measured_energy_std_linear_vs_draws(fm, means_file):
    """The linear per-time std of the measured E_5 matches the noise-draw spread."""
    t, mean, sem = read_means(means_file)
    ec = energy_check(fm, means=(t, mean, sem), samples=0, noise_draws=10)
    rng = np.random.default_rng(9)
    p = {k: float(fm.params[k]) for k in fm.params.values}
    draws = point_energy({n: differentiate(mean[n] + sem[n] * rng.standard_normal(
        (4000, t.size)), t) for n in FIVE}, p)
    sel = ec.measured_point > 0.05 * ec.measured_point.max()
    np.testing.assert_allclose(draws.std(axis=0)[sel], ec.measured_point_std[sel], rtol=0.1)


def test_bad_means(fm, tmp_path, truth):
    p = tmp_path / "short.nc"
    synthetic_means(truth, t_end=1.1e-3).to_netcdf(p)
    with pytest.raises(GprmInputError, match="not inside the record"):
        energy_check(fm, means=read_means(p), samples=0)
    ds = synthetic_means(truth)
    ds["sem"][:] = 0.0
    ds.to_netcdf(tmp_path / "zero.nc")
    with pytest.raises(GprmInputError, match="sem"):
        read_means(tmp_path / "zero.nc")


def test_record_starting_before_zero(fm, truth, tmp_path):
    """A mean-signals record that starts before t = 0 (alignment shift): the model is at rest
    there, and the histograms equal those of the same record cut at t >= 0."""
    ds = synthetic_means(truth, seed=5)
    ds_neg = ds.assign_coords(time=ds["time"] - 0.1e-3)
    ds_neg.to_netcdf(tmp_path / "neg.nc")
    t, mean, sem = read_means(tmp_path / "neg.nc")
    assert t[0] < 0
    a = energy_check(fm, means=(t, mean, sem), samples=0, noise_draws=5,
                     window=(0.87e-3, 1.1e-3))
    keep = t >= 0
    b = energy_check(fm, means=(t[keep], {k: v[keep] for k, v in mean.items()},
                                {k: v[keep] for k, v in sem.items()}), samples=0,
                     noise_draws=5, window=(0.87e-3, 1.1e-3))
    np.testing.assert_allclose(a.hist_model_point, b.hist_model_point)
    np.testing.assert_allclose(a.model_total[keep], b.model_total)
    assert np.all(a.model_total[~keep] == 0)
