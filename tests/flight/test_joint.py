"""Rising-branch crossings, the draws' error bars and the joint impact time: checks against
closed forms and a Monte-Carlo calibration on a model whose answer is known."""

import numpy as np
import pytest

from gprm.flight.impact_time import (branch_crossings, draw_weights, impact_time_mc,
                                     rising_branch)
from gprm.flight.joint import joint_impact_time

T = np.linspace(0.0, 1.0, 201)


def test_rising_branch_stops_at_first_peak_and_gap():
    c = np.where(T < 0.1, np.nan, np.sin(np.pi * (T - 0.1) / 0.6))     # peak at 0.4
    c[(T > 0.75) & (T < 0.8)] = np.nan                                   # a gap
    br = rising_branch(c)[0]
    assert T[br][0] == pytest.approx(0.1) and T[br][-1] == pytest.approx(0.4)
    # the same velocity is crossed twice (0.2 rising, 0.6 falling): only the rising one
    ts = branch_crossings(T, c[None], 0.5)
    assert ts[0] == pytest.approx(0.1 + 0.6 / 6, abs=2e-3)
    assert np.isnan(branch_crossings(T, c[None], 1.5)[0])                # above the peak


def test_linear_draws_give_closed_form_spread():
    """Curves c_k(t) = a_k t with a_k ~ N(a0, s_a) (a small spread): the crossing of v is v/a_k,
    so the error bar is close to v s_a / a0² and the estimate is v/a0."""
    rng = np.random.default_rng(0)
    a0, sa, v = 2.0, 0.02, 1.0
    a = a0 + sa * rng.standard_normal(4000)
    r = impact_time_mc(T, a0 * T, np.zeros_like(T), a[:, None] * T[None], v, 0.0)
    assert r.value == pytest.approx(v / a0, rel=1e-9)
    assert r.stderr == pytest.approx(v * sa / a0 ** 2, rel=0.05)
    assert r.method == "nominal crossing" and r.n_cross == 4000


def test_beyond_nominal_peak_uses_draws_and_missing_has_reason():
    rng = np.random.default_rng(1)
    k = 1 + 0.1 * rng.standard_normal(500)
    S = k[:, None] * np.sin(np.pi * T / 2)[None]            # rising everywhere, peak k at t=1
    nom = np.sin(np.pi * T / 2)
    r = impact_time_mc(T, nom, np.zeros_like(T), S, 1.02, 0.0)
    assert r.value is not None and "median" in r.method
    assert 0 < r.n_cross < 500 and r.value > 0.8
    r = impact_time_mc(T, nom, np.zeros_like(T), S, 1.5, 0.0)
    assert r.value is None and "draws reach it" in r.reason


def test_draw_weights_jacobian():
    w = draw_weights(np.array([1.0, 2.0, 4.0, np.nan]))
    np.testing.assert_allclose(w[:3] / w[0], [1.0, 0.5, 0.25])
    assert w[3] == 0 and w.sum() == pytest.approx(1.0)


def test_joint_independent_equal_is_mean_and_gls_formula():
    rng = np.random.default_rng(2)
    D = rng.standard_normal((5000, 3))                       # independent draws
    t = {"a": 1.0, "b": 2.0, "c": 3.0}
    j = joint_impact_time(t, {"a": 1.0, "b": 1.0, "c": 1.0},
                          {k: D[:, i] for i, k in enumerate(t)})
    assert j.value == pytest.approx(2.0, abs=0.05)
    assert j.stderr == pytest.approx(1 / np.sqrt(3), rel=0.05)
    assert j.df == 2 and j.chi2 == pytest.approx(2.0, rel=0.1)   # (1 + 0 + 1) / 1
    # correlated, positive GLS weights: equals (1' S^-1 t) / (1' S^-1 1)
    C = np.array([[1.0, 0.5], [0.5, 2.0]])
    L = np.linalg.cholesky(C)
    D = rng.standard_normal((20000, 2)) @ L.T
    s = np.sqrt(np.diag(C))
    j = joint_impact_time({"a": 0.0, "b": 1.0}, {"a": s[0], "b": s[1]},
                          {"a": D[:, 0], "b": D[:, 1]})
    Si = np.linalg.inv(C)
    ref = (np.ones(2) @ Si @ np.array([0.0, 1.0])) / (np.ones(2) @ Si @ np.ones(2))
    assert j.value == pytest.approx(ref, abs=0.02)
    assert min(j.weights) >= 0


def test_joint_drops_negative_weights():
    """Two nearly collinear estimates of unequal spread: unrestricted GLS would extrapolate
    (weight > 1 on one, < 0 on the other); the restricted estimate stays between them."""
    rng = np.random.default_rng(3)
    z = rng.standard_normal(5000)
    D = np.stack([z, 2 * z + 0.01 * rng.standard_normal(5000)], 1)
    j = joint_impact_time({"a": 0.0, "b": 1.0}, {"a": 1.0, "b": 2.0},
                          {"a": D[:, 0], "b": D[:, 1]})
    assert j.weights == (1.0, 0.0) and j.value == 0.0


def test_joint_interval_calibrated_on_a_known_model():
    """Truth and draws from the same family of curves c(t) = k t (k log-normal, three axes
    with their own scale); the joint 95 % interval covers the true time in ~95 % of cases."""
    rng = np.random.default_rng(4)
    scales = np.array([1.0, 2.0, -0.5])
    n = 300
    inside = 0
    for _ in range(200):
        kt = np.exp(0.1 * rng.standard_normal(3) + 0.05 * rng.standard_normal())
        t_true = rng.uniform(0.2, 0.6)
        v = kt * scales * t_true
        kd = np.exp(0.1 * rng.standard_normal((n, 3)) + 0.05 * rng.standard_normal((n, 1)))
        times, se, dr, sl = {}, {}, {}, {}
        for i, ax in enumerate("abc"):
            r = impact_time_mc(T, scales[i] * T, np.zeros_like(T),
                               (kd[:, i] * scales[i])[:, None] * T[None], v[i], 0.0)
            times[ax], se[ax], dr[ax], sl[ax] = r.value, r.stderr, r.draws, r.draw_slopes
        j = joint_impact_time(times, se, dr, sl)
        inside += j.ci95[0] <= t_true <= j.ci95[1]
    assert 0.9 <= inside / 200 <= 0.99, inside


def test_analysis_reproducible():
    """Same telemetry, model and seed: the same impact document (draw seeds derive from it)."""
    from gprm.fit.files import paper_model
    from gprm.flight import AnalysisOptions, SynthOptions, analyze, synth_telemetry
    from gprm.flight.files import telemetry_from_dataset

    m = paper_model()
    tel = telemetry_from_dataset(synth_telemetry(m, SynthOptions(n_releases=3, seed=9)))
    a = analyze(m, tel, AnalysisOptions(n_samples=40, n_times=201, seed=4)).to_json()
    b = analyze(m, tel, AnalysisOptions(n_samples=40, n_times=201, seed=4)).to_json()
    assert a == b
    c = analyze(m, tel, AnalysisOptions(n_samples=40, n_times=201, seed=5)).to_json()
    assert c["releases"][0]["joint"] != a["releases"][0]["joint"]
