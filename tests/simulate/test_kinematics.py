"""Kinematics: Eq. 8 against its transcription and against independent rotations; velocities
against finite differences; the tip edge and assembly CoM; kinetic energy against the
model's own mass matrix M(x)."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gprm.errors import GprmInputError
from gprm.model.linear import generated
from gprm.params import paper
from gprm.simulate.kinematics import (MECH, PlungerMotion, actuation_axis, body_motion,
                                      kinetic_energy, named_points, point_motion, rotation)


@pytest.fixture(scope="module")
def fm():
    """Table 3 carried as a fitted model carries its best fit (``.params``): the kinematics
    take either (simulate does not import the fit stage)."""
    return SimpleNamespace(params=paper())


def synthetic_motion(fm, t, big=0.3):
    """A made-up motion with large angles and analytic rates (not a simulation)."""
    pb = {k: np.atleast_1d(np.asarray(v, float)) for k, v in
          {n: fm.params[n] for n in fm.params.values}.items()}
    w = 2 * np.pi * np.array([1.1, 1.7, 2.3, 2.9, 3.7, 4.3, 5.1, 6.7]) * 1e3
    amp = np.array([3e-6, 2e-6, 5e-6, 4e-6, big, -0.8 * big, 7e-6, 9e-6])
    ph = np.linspace(0.1, 1.5, 8)
    coords = {c: (amp[i] * np.sin(w[i] * t + ph[i]))[None] for i, c in enumerate(MECH)}
    rates = {c + "_dot": (amp[i] * w[i] * np.cos(w[i] * t + ph[i]))[None]
             for i, c in enumerate(MECH)}
    R = rotation(coords["theta"], coords["eta"])
    th, ed, td = coords["theta"], rates["eta_dot"], rates["theta_dot"]
    omega = np.stack([td, ed * np.cos(th), ed * np.sin(th)], 1)
    mu_eq = {"mu3": np.array([1.5e-5]), "mu4": np.array([1.6e-5])}
    return PlungerMotion(time=t, params=pb, piezo=2, coords=coords, rates=rates, mu_eq=mu_eq,
                         R=R, omega=omega, ok=np.array([True]))


def eq8(v2, g2, h2, eta, theta, x_A, y_A, z_A, z_lr):
    """The paper's Eq. 8, transcribed."""
    xG = v2 * np.cos(eta) + h2 * np.sin(eta) + x_A
    yG = (g2 * np.cos(theta) - h2 * np.cos(eta) * np.sin(theta)
          + v2 * np.sin(eta) * np.sin(theta) + y_A)
    zG = (h2 * np.cos(theta) * np.cos(eta) - v2 * np.cos(theta) * np.sin(eta)
          + g2 * np.sin(theta) + z_A + z_lr)
    return np.stack([xG, yG, zG])


def test_eq8_large_angles(fm):
    t = np.linspace(0, 1e-3, 400)
    m = synthetic_motion(fm, t)
    pos, _ = point_motion(m, named_points(fm)["com"])
    c = m.coords
    ref = eq8(fm.params["v2"], fm.params["g2"], fm.params["h2"], c["eta"][0], c["theta"][0],
              c["x_A"][0], c["y_A"][0], c["z_A"][0], c["z_lr"][0])
    assert np.max(np.abs(pos[0] - ref)) < 1e-15
    assert np.max(np.abs(c["eta"])) > 0.29  # the test exercises large rotations


def test_points_against_scipy_rotations(fm):
    t = np.linspace(0, 1e-3, 50)
    m = synthetic_motion(fm, t)
    pts = named_points(fm)
    p = fm.params
    c = m.coords
    for name, r in (("M_xz", [p["v2"] + p["dist_x"], p["g2"], p["h2"] + p["dist_z"]]),
                    ("M_yz", [p["v2"], p["g2"] + p["dist_y"], p["h2"] + p["dist_z"]])):
        pos, _ = point_motion(m, pts[name])
        for k in (0, 17, 49):
            rot = (Rotation.from_rotvec([c["theta"][0, k], 0, 0])
                   * Rotation.from_rotvec([0, c["eta"][0, k], 0]))
            A = np.array([c["x_A"][0, k], c["y_A"][0, k], c["z_lr"][0, k] + c["z_A"][0, k]])
            np.testing.assert_allclose(pos[0, :, k], A + rot.apply(r), atol=1e-15)


def test_tip_and_assembly_points(fm):
    t = np.linspace(0, 1e-3, 60)
    m = synthetic_motion(fm, t)
    p = fm.params
    pts = named_points(fm)
    u = np.array([np.sin(p["gamma"]), np.cos(p["gamma"]) * np.sin(p["rho"]),
                  np.cos(p["gamma"]) * np.cos(p["rho"])])
    mu4 = m.coords["mu4"][0] + m.mu_eq["mu4"][0]
    tip, _ = point_motion(m, pts["tip_edge"])
    fixed, _ = point_motion(m, np.array([0, 0, p["h3"]]) + p["h4"] * u)
    Ru = np.einsum("tij,j->it", m.R[0], u)
    np.testing.assert_allclose(tip[0] - fixed[0], mu4 * Ru, atol=1e-18)
    # assembly CoM = mass-weighted mean of plunger CoM, spacer and tip
    com, _ = point_motion(m, pts["com"])
    sp, _ = point_motion(m, pts["spacer"])
    asm, vasm = point_motion(m, pts["assembly_com"])
    mm = np.array([p["m2"], p["m3"], p["m4"]])
    np.testing.assert_allclose(asm, (mm[0] * com + mm[1] * sp + mm[2] * tip) / mm.sum(),
                               atol=1e-15)
    # raw body coordinates with which="tip" equal the named tip point
    tip2, _ = point_motion(m, np.array([0, 0, p["h3"]]) + p["h4"] * u, which="tip")
    np.testing.assert_allclose(tip2, tip, atol=1e-18)


@pytest.mark.parametrize("name", ["com", "M_xz", "M_yz", "tip_edge", "assembly_com"])
def test_velocity_vs_finite_difference_large_angles(fm, name):
    t = np.linspace(0, 1e-3, 2001)
    h = 1e-9
    m0, mp, mm = (synthetic_motion(fm, t + s) for s in (0.0, h, -h))
    pt = named_points(fm)[name]
    _, v = point_motion(m0, pt)
    fd = (point_motion(mp, pt)[0] - point_motion(mm, pt)[0]) / (2 * h)
    assert np.max(np.abs(fd - v)) < 1e-6 * np.max(np.abs(v))


def test_velocity_vs_finite_difference_simulated(fm):
    t = np.linspace(0.99e-3, 1.1e-3, 111)
    h = 2e-9
    pts = named_points(fm)
    m0 = body_motion(fm, t)
    mp, mm = body_motion(fm, t + h), body_motion(fm, t - h)
    for name in ("com", "M_xz", "M_yz", "tip_edge"):
        _, v = point_motion(m0, pts[name])
        fd = (point_motion(mp, pts[name])[0] - point_motion(mm, pts[name])[0]) / (2 * h)
        scale = np.max(np.abs(v), axis=-1, keepdims=True)
        assert np.max(np.abs(fd - v) / scale) < 1e-4, name


def test_relative_starts_at_zero_and_omega(fm):
    t = np.linspace(1e-6, 1.2e-3, 241)
    m = body_motion(fm, t)
    for name, pt in named_points(fm).items():
        d, _ = point_motion(m, pt, relative=True)
        assert np.max(np.abs(d[..., 0])) < 1e-15, name  # at rest before t_c
    # omega from R' R^T (finite differences of the attitude)
    h = 1e-9
    Rp, Rm = body_motion(fm, t + h).R, body_motion(fm, t - h).R
    W = np.einsum("btij,btkj->btik", (Rp - Rm) / (2 * h), m.R)
    w = np.stack([W[..., 2, 1], W[..., 0, 2], W[..., 1, 0]], 1)
    assert np.max(np.abs(w - m.omega)) < 1e-4 * np.max(np.abs(m.omega))


def test_kinetic_energy_matches_mass_matrix(fm):
    """T = 1/2 x'^T M(x) x' with the generated nonlinear mass matrix (SymPy path)."""
    t = np.linspace(0, 1e-3, 30)
    m = synthetic_motion(fm, t)
    ke = kinetic_energy(m)["total"][0]
    g = generated(2)
    p = {k: float(v[0]) for k, v in m.params.items()}
    for k in (0, 11, 29):
        x = np.array([m.coords[c][0, k] for c in MECH] + [0.0])
        x[6] += m.mu_eq["mu3"][0]
        x[7] += m.mu_eq["mu4"][0]
        xd = np.array([m.rates[c + "_dot"][0, k] for c in MECH] + [0.0])
        M, _ = g.nonlinear(x, xd, p)
        M = np.asarray(M, float)[:8, :8]
        ref = 0.5 * xd[:8] @ M @ xd[:8]
        assert abs(ke[k] - ref) < 1e-10 * abs(ref)
    assert np.all(ke >= 0)


def test_actuation_axis_unit(fm):
    u = actuation_axis({"gamma": np.array([0.1, -0.3]), "rho": np.array([0.2, 0.05])})
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), 1.0)


def test_bad_times(fm):
    with pytest.raises(GprmInputError, match="before the simulation start"):
        body_motion(fm, [-1e-6, 0.0])
    with pytest.raises(GprmInputError, match="increase"):
        body_motion(fm, [1e-3, 0.5e-3])
    with pytest.raises(GprmInputError, match="piezo"):
        body_motion(fm, [0.0, 1e-3], piezo=3)
