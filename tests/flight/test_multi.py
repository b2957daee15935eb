"""Multiple impacts: plunger (linear model) and free TM integrated with contact detection."""

import numpy as np
import pytest

from gprm.fit.files import paper_model
from gprm.flight.multi import simulate_contacts


@pytest.fixture(scope="module")
def res():
    return simulate_contacts(paper_model(), 1.010e-3)


def test_second_impacts_found_and_ordered(res):
    ev = res["events"]
    assert res["n_impacts"] == len(ev) >= 2
    times = [e["time"] for e in ev]
    assert times[0] == pytest.approx(1.010e-3)
    assert np.all(np.diff(times) > 0)
    assert all(res["t1"] <= t <= res["t_end"] for t in times)
    for e in ev:
        assert all(p > 0 for p in e["impulses"])


def test_energy_exchange_is_conservative_for_e1(res):
    """Each event moves kinetic energy between mechanism (½ ξ'ᵀ M ξ' of the model's mass
    matrix) and TM without loss for restitution 1 (independent of how the impulses were
    found)."""
    for e in res["events"]:
        scale = abs(e["dE_tm"])
        assert e["dE_tm"] > 0
        assert abs(e["dE_plunger"] + e["dE_tm"]) < 1e-9 * scale


def test_tm_momentum_equals_impulses(res):
    from gprm.params import paper
    ps = paper()
    a = ps["indent_angle"]
    n = {"xz": np.array([np.sin(a), 0, np.cos(a)]), "yz": np.array([0, np.sin(a), np.cos(a)])}
    J = sum(p * n[pl] for e in res["events"] for pl, p in zip(e["planes"], e["impulses"]))
    v = np.array([res["final_tm_velocity"][k] for k in ("vx", "vy", "vz")])
    np.testing.assert_allclose(ps["m_tm"] * v, J, rtol=1e-12)
    # a second impact changes the TM velocity noticeably with respect to the first alone
    v1 = np.array([res["first_tm_velocity"][k] for k in ("vx", "vy", "vz")])
    assert np.linalg.norm(v - v1) > 0.1 * np.linalg.norm(v1)


def test_impulse_free_response_matches_matrix_exponential():
    """The plunger's response to an impulse (eigen-decomposition of the state matrix) equals
    scipy's matrix exponential."""
    from scipy.linalg import expm

    from gprm.flight.multi import _setup, _with_perturbation
    from gprm.model.linear import state_space
    from gprm.simulate.kinematics import body_motion

    m = paper_model()
    pb, geom, (E, lam, V, Vinv), pts = _setup(m, None)
    t = np.linspace(1.0e-3, 1.1e-3, 7)
    base = body_motion(pb, t)
    z0 = np.zeros(17)
    z0[8:16] = np.random.default_rng(0).normal(0, 1e-3, 8)
    pert = _with_perturbation(base, [(1.02e-3, z0)], lam, V, Vinv)
    A = state_space(pb, m.piezo).A[0]
    names = ("z_lr", "z_A", "x_A", "y_A", "eta", "theta", "mu3", "mu4")
    for k, tk in enumerate(t):
        dz = expm(A * (tk - 1.02e-3)) @ z0 if tk >= 1.02e-3 else np.zeros(17)
        for i, n in enumerate(names):
            got = pert.coords[n][0, k] - base.coords[n][0, k]
            assert got == pytest.approx(dz[i], abs=1e-12 * np.abs(dz).max() + 1e-18)
            gotr = pert.rates[f"{n}_dot"][0, k] - base.rates[f"{n}_dot"][0, k]
            assert gotr == pytest.approx(dz[8 + i], abs=1e-9 * np.abs(dz).max() + 1e-18)


def test_no_missed_contact(res):
    """With every detected impulse applied, the plunger points never penetrate the TM faces
    over the whole record (a missed contact would show as a positive gap of the order of the
    plunger motion, micrometres)."""
    assert res["max_penetration"] < 1e-12
