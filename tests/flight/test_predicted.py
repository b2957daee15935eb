"""TM velocity vs impact time: independent checks against hand-built impulse balances and
symmetry of mirrored mechanisms."""

import numpy as np
import pytest

from gprm.flight.predicted import ImpactGeometry, tm_velocity_vs_time
from gprm.params import batch, paper
from gprm.predict.kinematics import body_motion, named_points, point_motion

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
    out = tm_velocity_vs_time(m, ImpactGeometry(restitution=e))
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


def test_axisymmetric_mechanism_gives_identical_planes():
    out = tm_velocity_vs_time(body_motion(batch([_symmetric_set()]), T))
    ok = out["approaching_xz"][0]
    assert ok.sum() > 20
    np.testing.assert_array_equal(ok, out["approaching_yz"][0])
    np.testing.assert_allclose(out["vx"][0][ok], out["vy"][0][ok], rtol=1e-9)
    np.testing.assert_allclose(out["vz_xz"][0][ok], out["vz_yz"][0][ok], rtol=1e-9)
    np.testing.assert_allclose(out["wy"][0][ok], -out["wx"][0][ok], rtol=1e-9)


def test_mirror_x_flips_x_plane():
    """x -> -x (v2, gamma, dist_x change sign): vx and wy flip sign, vz and the y-z plane
    stay."""
    ps = paper()
    mir = ps.with_values(v2=-ps["v2"], gamma=-ps["gamma"], dist_x=-ps["dist_x"])
    a = tm_velocity_vs_time(body_motion(batch([ps]), T))
    b = tm_velocity_vs_time(body_motion(batch([mir]), T))
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
