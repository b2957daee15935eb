"""TM velocity vs impact time: independent checks against hand-built impulse balances and
symmetry of mirrored mechanisms."""

import numpy as np
import pytest

from gprm.flight.predicted import ImpactGeometry, tm_velocity_vs_time
from gprm.params import batch, paper
from gprm.simulate.kinematics import body_motion, named_points, point_motion

T = np.linspace(1.0e-3, 1.1e-3, 201)


def test_against_effective_mass_impulse():
    """With the TM at rest and restitution e, the normal impulse is
    P = (1 + e) m_eff u_n with 1/m_eff = 1/M + (rho_A x n)^2/J2 + 1/m + (rho_B x n)^2/I and
    u_n the approach speed of the plunger contact point (its exact velocity from the
    kinematics); the TM then moves along n with P/m and spins with rho_B x P n / I."""
    ps = paper()
    pb = batch([ps])
    m = body_motion(pb, T)
    e = 0.7
    out = tm_velocity_vs_time(m, ImpactGeometry(restitution=e, impact_model="planar"))
    pts = named_points(pb)
    a = ps["indent_angle"]
    M = ps["m2"] + ps["m3"] + ps["m4"]
    mt, s = ps["m_tm"], ps["s_tm"]
    It = mt * s ** 2 / 6
    H = s / 2 - 3e-3
    G, _ = point_motion(m, pts["assembly_com"])
    for plane, key, n, lat in (("xz", "M_xz", np.array([np.sin(a), 0, np.cos(a)]), 0),
                               ("yz", "M_yz", np.array([0, np.sin(a), np.cos(a)]), 1)):
        P, vP = point_motion(m, pts[key])
        P, vP, Gp = P[0], vP[0], G[0]
        un = n @ vP                                   # plunger point speed along n (T,)
        C = np.array([ps["v2"], ps["g2"], ps["h2"] + ps["dist_z"] + H])
        rhoA = P - Gp[:, :]
        rhoB = P - C[:, None]
        k = 1 if plane == "xz" else 0                 # rotation axis of the plane
        cA = np.cross(rhoA.T, n)[:, k]
        cB = np.cross(rhoB.T, n)[:, k]
        inv = 1 / M + cA ** 2 / ps["J2"] + 1 / mt + cB ** 2 / It
        Pimp = (1 + e) * un / inv
        ok = un > 0
        assert ok.sum() > 20
        np.testing.assert_array_equal(out[f"approaching_{plane}"][0], ok)
        axes = ("vx", "vz_xz", "wy") if plane == "xz" else ("vy", "vz_yz", "wx")
        v_lat = Pimp / mt * n[lat]
        v_z = Pimp / mt * n[2]
        w = Pimp * cB / It
        np.testing.assert_allclose(out[axes[0]][0][ok], v_lat[ok], rtol=1e-9)
        np.testing.assert_allclose(out[axes[1]][0][ok], v_z[ok], rtol=1e-9)
        np.testing.assert_allclose(out[axes[2]][0][ok], w[ok], rtol=1e-9)
        assert np.all(np.isnan(out[axes[0]][0][~ok]))


def _symmetric_set():
    """No eccentricity (v2 = g2 = gamma = rho = 0) and equal contact offsets: the retraction
    excites no lateral motion, so the two planes see the same axial motion."""
    ps = paper()
    return ps.with_values(v2=0.0, g2=0.0, gamma=0.0, rho=0.0, dist_y=ps["dist_x"])


def test_3d_against_effective_mass_impulse():
    """One-contact 3D model, frictionless: the corner M = G + (dist_x, dist_y, dist_z) strikes
    the face with normal n ∝ (tan a, tan a, 1); P = (1 + e) m_eff u_n with
    1/m_eff = 1/M + |rho_A x n|²/J2 + 1/m + |rho_B x n|²/I (isotropic inertias), the TM moves
    with P n / m and spins with rho_B x P n / I. Both v_z axes are the one v_z."""
    ps = paper()
    pb = batch([ps])
    m = body_motion(pb, T)
    e = 0.8
    out = tm_velocity_vs_time(m, ImpactGeometry(restitution=e, friction=0.0))
    pts = named_points(pb)
    a = ps["indent_angle"]
    M = ps["m2"] + ps["m3"] + ps["m4"]
    mt, s = ps["m_tm"], ps["s_tm"]
    It = mt * s ** 2 / 6
    H = s / 2 - 3e-3
    n = np.array([np.tan(a), np.tan(a), 1.0])
    n /= np.linalg.norm(n)
    corner = pts["com"].r[0] + np.array([ps["dist_x"], ps["dist_y"], ps["dist_z"]])
    P, vP = point_motion(m, corner)
    G, _ = point_motion(m, pts["assembly_com"])
    P, vP, G = P[0], vP[0], G[0]
    C = np.array([ps["v2"], ps["g2"], ps["h2"] + ps["dist_z"] + H])
    un = n @ vP
    cA = np.cross((P - G).T, n)
    cB = np.cross((P - C[:, None]).T, n)
    inv = 1 / M + np.sum(cA ** 2, 1) / ps["J2"] + 1 / mt + np.sum(cB ** 2, 1) / It
    Pimp = (1 + e) * un / inv
    ok = un > 0
    assert ok.sum() > 20
    np.testing.assert_array_equal(out["approaching_xz"][0], ok)
    for k, ax in ((0, "vx"), (1, "vy"), (2, "vz_xz"), (2, "vz_yz")):
        np.testing.assert_allclose(out[ax][0][ok], (Pimp / mt * n[k])[ok], rtol=1e-9)
    for k, ax in ((0, "wx"), (1, "wy"), (2, "wz")):
        np.testing.assert_allclose(out[ax][0][ok], (Pimp * cB[:, k] / It)[ok], rtol=1e-9,
                                   atol=1e-15)
    assert np.all(np.isnan(out["vx"][0][~ok]))


def test_3d_friction_changes_the_impulse_direction_not_momentum_balance():
    """With Coulomb friction the impulse leaves the normal (v no longer along n); the TM still
    takes one impulse J at the contact: m v = J and I w = rho_B x J, i.e. I w = rho_B x m v."""
    ps = paper()
    pb = batch([ps])
    m = body_motion(pb, T)
    f0 = tm_velocity_vs_time(m, ImpactGeometry(friction=0.0))
    f1 = tm_velocity_vs_time(m, ImpactGeometry(friction=0.3))
    ok = f0["approaching_xz"][0] & f1["approaching_xz"][0]
    assert ok.sum() > 20
    r0 = f0["vz_xz"][0][ok] / f0["vx"][0][ok]
    r1 = f1["vz_xz"][0][ok] / f1["vx"][0][ok]
    a = ps["indent_angle"]
    np.testing.assert_allclose(r0, 1 / np.tan(a), rtol=1e-9)     # frictionless: along n
    assert np.max(np.abs(r1 - r0)) > 0.05                          # friction: it is not
    pts = named_points(pb)
    corner = pts["com"].r[0] + np.array([ps["dist_x"], ps["dist_y"], ps["dist_z"]])
    P, _ = point_motion(m, corner)
    C = np.array([ps["v2"], ps["g2"], ps["h2"] + ps["dist_z"] + ps["s_tm"] / 2 - 3e-3])
    rho = (P[0] - C[:, None]).T[ok]
    v = np.stack([f1["vx"][0], f1["vy"][0], f1["vz_xz"][0]], 1)[ok]
    w = np.stack([f1["wx"][0], f1["wy"][0], f1["wz"][0]], 1)[ok]
    It = ps["m_tm"] * ps["s_tm"] ** 2 / 6
    np.testing.assert_allclose(It * w, np.cross(rho, ps["m_tm"] * v), rtol=1e-9, atol=1e-18)


@pytest.mark.parametrize("model", ["3d", "planar"])
def test_axisymmetric_mechanism_gives_identical_planes(model):
    out = tm_velocity_vs_time(body_motion(batch([_symmetric_set()]), T),
                              ImpactGeometry(impact_model=model))
    ok = out["approaching_xz"][0]
    assert ok.sum() > 20
    np.testing.assert_array_equal(ok, out["approaching_yz"][0])
    np.testing.assert_allclose(out["vx"][0][ok], out["vy"][0][ok], rtol=1e-9)
    np.testing.assert_allclose(out["vz_xz"][0][ok], out["vz_yz"][0][ok], rtol=1e-9)
    np.testing.assert_allclose(out["wy"][0][ok], -out["wx"][0][ok], rtol=1e-9)


@pytest.mark.parametrize("model", ["3d", "planar"])
def test_mirror_x_flips_x_plane(model):
    """x -> -x (v2, gamma, dist_x change sign): vx and wy flip sign, vz and the y-z plane
    stay."""
    ps = paper()
    mir = ps.with_values(v2=-ps["v2"], gamma=-ps["gamma"], dist_x=-ps["dist_x"])
    g = ImpactGeometry(impact_model=model)
    a = tm_velocity_vs_time(body_motion(batch([ps]), T), g)
    b = tm_velocity_vs_time(body_motion(batch([mir]), T), g)
    for k in ("approaching_xz", "approaching_yz"):
        np.testing.assert_array_equal(a[k], b[k])
    ok = a["approaching_xz"][0]
    np.testing.assert_allclose(b["vx"][0][ok], -a["vx"][0][ok], rtol=1e-7)
    np.testing.assert_allclose(b["wy"][0][ok], -a["wy"][0][ok], rtol=1e-7)
    np.testing.assert_allclose(b["vz_xz"][0][ok], a["vz_xz"][0][ok], rtol=1e-7)
    oy = a["approaching_yz"][0]
    for k in ("vy", "vz_yz", "wx"):
        np.testing.assert_allclose(b[k][0][oy], a[k][0][oy], rtol=1e-7)


def test_velocity_curves_bands():
    from gprm.fit.files import paper_model
    from gprm.flight.predicted import velocity_curves

    c = velocity_curves(paper_model(), n_times=101, n_samples=40, seed=3)
    for a in ("vx", "wx"):
        fin = np.isfinite(c.nominal[a]) & np.isfinite(c.sigma[a])
        assert fin.sum() > 5
        assert np.all(c.sigma[a][fin] > 0)
        np.testing.assert_allclose(c.sigma[a][fin] ** 2, c.sigma_fit[a][fin] ** 2
                                   + c.sigma_geometry[a][fin] ** 2, rtol=1e-12)
        inside = (c.lo[a][fin] <= c.nominal[a][fin]) & (c.nominal[a][fin] <= c.hi[a][fin])
        assert inside.mean() > 0.8
    # same seed -> same result
    c2 = velocity_curves(paper_model(), n_times=101, n_samples=40, seed=3)
    np.testing.assert_array_equal(c.sigma["vx"], c2.sigma["vx"])


def test_bad_geometry_option():
    from gprm.errors import GprmInputError
    m = body_motion(batch([paper()]), T[:5])
    with pytest.raises(GprmInputError):
        tm_velocity_vs_time(m, ImpactGeometry(plunger_velocity="nonsense"))
    with pytest.raises(GprmInputError, match="3d"):
        tm_velocity_vs_time(m, ImpactGeometry(impact_model="2d"))
    with pytest.raises(GprmInputError):
        tm_velocity_vs_time(m, ImpactGeometry(friction=-0.1))
