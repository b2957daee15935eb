"""Impact models: Appendix B closed form, conservation laws, 3D <-> planar, symmetry, friction."""

import numpy as np
import pytest

from gprm.flight.impact import impact_3d, kinetic_energy, planar_impact


def appendix_b(mA, IA, xA, vAx, vAy, wA, mB, IB, xB, vBx, vBy, wB, *, printed_wB=False):
    """Eq. B.1 as printed in the paper (collision frame: x tangent, y normal, contact at the
    origin, x_k the CoM tangential coordinate), with V_N^f = -V_N^i. The printed omega_B^f has
    ``+2 v_Ay`` where the conservation laws give ``-2 v_Ay`` (it is then not Galilean
    invariant); ``printed_wB=True`` returns the printed form."""
    den = mA * xA ** 2 * mB * IB + mA * mB * xB ** 2 * IA + (mA + mB) * IA * IB
    IN = 2 * mA * mB * IA * IB * (-vAy + vBy + xA * wA - xB * wB) / den
    vAy_f = (IA * (-mB * IB * (vAy - 2 * (vBy + xA * wA - xB * wB)) + mA * IB * vAy
                   + mA * mB * xB ** 2 * vAy) + mA * xA ** 2 * mB * IB * vAy) / den
    wA_f = (IB * (mB * wA * IA + mA * xA * mB * (2 * vAy - 2 * vBy - xA * wA + 2 * xB * wB)
                  + mA * wA * IA) + mA * mB * xB ** 2 * wA * IA) / den
    vBy_f = (IA * (mA * IB * (2 * vAy - vBy - 2 * xA * wA + 2 * xB * wB)
                   + mA * mB * xB ** 2 * vBy + mB * IB * vBy) + mA * xA ** 2 * mB * IB * vBy) / den
    sA = 2 if printed_wB else -2
    wB_f = (IA * (mA * wB * IB + mA * mB * xB * (sA * vAy + 2 * vBy + 2 * xA * wA - xB * wB)
                  + mB * wB * IB) + mA * xA ** 2 * mB * wB * IB) / den
    return dict(IN=IN, vAx=vAx, vAy=vAy_f, wA=wA_f, vBx=vBx, vBy=vBy_f, wB=wB_f)


def _random_planar(rng, n):
    return dict(mA=rng.uniform(0.01, 2, n), IA=rng.uniform(1e-6, 1e-3, n),
                xA=rng.uniform(-0.03, 0.03, n), yA=rng.uniform(-0.05, -0.001, n),
                vA=rng.normal(0, 1e-2, (n, 2)), wA=rng.normal(0, 1, n),
                mB=rng.uniform(0.01, 2, n), IB=rng.uniform(1e-6, 1e-3, n),
                xB=rng.uniform(-0.03, 0.03, n), yB=rng.uniform(0.001, 0.05, n),
                vB=rng.normal(0, 1e-2, (n, 2)), wB=rng.normal(0, 1, n))


def _solve(d, e=1.0):
    rhoA = -np.stack([d["xA"], d["yA"]], -1)          # contact minus CoM
    rhoB = -np.stack([d["xB"], d["yB"]], -1)
    n = np.array([0.0, 1.0])
    return planar_impact(d["mA"], d["IA"], rhoA, d["vA"], d["wA"], d["mB"], d["IB"], rhoB,
                         d["vB"], d["wB"], n, e)


def test_planar_matches_appendix_b_closed_form():
    rng = np.random.default_rng(0)
    d = _random_planar(rng, 500)
    r = _solve(d)
    ref = appendix_b(d["mA"], d["IA"], d["xA"], d["vA"][:, 0], d["vA"][:, 1], d["wA"],
                     d["mB"], d["IB"], d["xB"], d["vB"][:, 0], d["vB"][:, 1], d["wB"])
    np.testing.assert_allclose(r.vA[:, 0], ref["vAx"], rtol=1e-12)
    np.testing.assert_allclose(r.vB[:, 0], ref["vBx"], rtol=1e-12)
    for mine, key in ((r.vA[:, 1], "vAy"), (r.wA, "wA"), (r.vB[:, 1], "vBy"), (r.wB, "wB")):
        scale = np.max(np.abs(ref[key]))
        np.testing.assert_allclose(mine, ref[key], rtol=1e-9, atol=1e-12 * scale)
    # impulse on A along +y is I_N (ours: -P n with n = +y)
    np.testing.assert_allclose(-r.P, ref["IN"], rtol=1e-9, atol=1e-15)
    # V_N^f = -V_N^i (the garble of the paper read as restitution 1)
    np.testing.assert_allclose(r.vn_after, -r.vn_before, rtol=1e-9, atol=1e-14)


def test_printed_omega_b_is_garbled():
    """The printed omega_B^f changes with a common velocity added to both bodies; ours and the
    corrected form do not (Galilean invariance)."""
    rng = np.random.default_rng(1)
    d = _random_planar(rng, 50)
    args = lambda dv: (d["mA"], d["IA"], d["xA"], d["vA"][:, 0], d["vA"][:, 1] + dv, d["wA"],  # noqa
                       d["mB"], d["IB"], d["xB"], d["vB"][:, 0], d["vB"][:, 1] + dv, d["wB"])
    p0 = appendix_b(*args(0.0), printed_wB=True)["wB"]
    p1 = appendix_b(*args(0.5), printed_wB=True)["wB"]
    c0 = appendix_b(*args(0.0))["wB"]
    c1 = appendix_b(*args(0.5))["wB"]
    assert np.max(np.abs(p1 - p0)) > 1e-3
    np.testing.assert_allclose(c1, c0, rtol=1e-9, atol=1e-12)


def test_planar_conservation_e1():
    rng = np.random.default_rng(2)
    d = _random_planar(rng, 300)
    r = _solve(d, e=1.0)
    p0 = d["mA"][:, None] * d["vA"] + d["mB"][:, None] * d["vB"]
    p1 = d["mA"][:, None] * r.vA + d["mB"][:, None] * r.vB
    np.testing.assert_allclose(p1, p0, rtol=0, atol=1e-13 * np.max(np.abs(p0)))
    E0 = kinetic_energy(d["mA"], d["IA"], d["vA"], d["wA"]) + kinetic_energy(
        d["mB"], d["IB"], d["vB"], d["wB"])
    E1 = kinetic_energy(d["mA"], d["IA"], r.vA, r.wA) + kinetic_energy(d["mB"], d["IB"], r.vB,
                                                                       r.wB)
    np.testing.assert_allclose(E1, E0, rtol=1e-11)

    # angular momentum of each body about the contact point (origin) is conserved
    def L(m, I, c, v, w):
        return I * w + m * (c[:, 0] * v[:, 1] - c[:, 1] * v[:, 0])

    cA = np.stack([d["xA"], d["yA"]], -1)
    cB = np.stack([d["xB"], d["yB"]], -1)
    for m, I, c, v0, w0, v1, w1 in ((d["mA"], d["IA"], cA, d["vA"], d["wA"], r.vA, r.wA),
                                    (d["mB"], d["IB"], cB, d["vB"], d["wB"], r.vB, r.wB)):
        l0, l1 = L(m, I, c, v0, w0), L(m, I, c, v1, w1)
        np.testing.assert_allclose(l1, l0, rtol=1e-9, atol=1e-12 * np.max(np.abs(l0)))


def test_planar_plastic_and_partial_restitution():
    rng = np.random.default_rng(3)
    d = _random_planar(rng, 100)
    for e in (0.0, 0.4):
        r = _solve(d, e=e)
        np.testing.assert_allclose(r.vn_after, -e * r.vn_before, atol=1e-14)


def _embed(d, plane):
    """Planar data -> 3D: plane 'xz' with (a, b) = (z, x), w = w_y; 'yz' with (a, b) = (y, z),
    w = w_x."""
    n = d["mA"].size

    def vec(ab):
        out = np.zeros((n, 3))
        if plane == "xz":
            out[:, 2], out[:, 0] = ab[:, 0], ab[:, 1]
        else:
            out[:, 1], out[:, 2] = ab[:, 0], ab[:, 1]
        return out

    def wvec(w):
        out = np.zeros((n, 3))
        out[:, 1 if plane == "xz" else 0] = w
        return out

    def inertia(I):
        return np.einsum("b,ij->bij", I, np.eye(3))

    return vec, wvec, inertia


@pytest.mark.parametrize("plane", ["xz", "yz"])
def test_3d_reduces_to_planar(plane):
    rng = np.random.default_rng(4)
    d = _random_planar(rng, 200)
    vec, wvec, inertia = _embed(d, plane)
    rhoA = -np.stack([d["xA"], d["yA"]], -1)
    rhoB = -np.stack([d["xB"], d["yB"]], -1)
    ang = rng.uniform(0, 2 * np.pi, 200)
    n2 = np.stack([np.cos(ang), np.sin(ang)], -1)
    ref = planar_impact(d["mA"], d["IA"], rhoA, d["vA"], d["wA"], d["mB"], d["IB"], rhoB,
                        d["vB"], d["wB"], n2, 1.0)
    # out-of-plane inertia entries must not matter: use different values off the plane axis
    IA = inertia(d["IA"]) * 1.0
    IB = inertia(d["IB"]) * 1.0
    k = 1 if plane == "xz" else 0
    for I3, Ip in ((IA, d["IA"]), (IB, d["IB"])):
        for j in range(3):
            if j != k:
                I3[:, j, j] = 3.7 * Ip
    r = impact_3d(d["mA"], IA, vec(rhoA), vec(d["vA"]), wvec(d["wA"]), d["mB"], IB, vec(rhoB),
                  vec(d["vB"]), wvec(d["wB"]), vec(n2), e=1.0, mu=0.0)
    np.testing.assert_allclose(r.vA, vec(ref.vA), rtol=1e-9, atol=1e-13)
    np.testing.assert_allclose(r.vB, vec(ref.vB), rtol=1e-9, atol=1e-13)
    np.testing.assert_allclose(r.wA, wvec(ref.wA), rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(r.wB, wvec(ref.wB), rtol=1e-9, atol=1e-11)


def _random_3d(rng, n):
    def inertia():
        Q, _ = np.linalg.qr(rng.normal(size=(n, 3, 3)))
        lam = rng.uniform(1e-5, 1e-3, (n, 3))
        return np.einsum("bij,bj,bkj->bik", Q, lam, Q)
    return dict(mA=rng.uniform(0.01, 2, n), IA=inertia(), rhoA=rng.normal(0, 0.02, (n, 3)),
                vA=rng.normal(0, 1e-2, (n, 3)), wA=rng.normal(0, 1, (n, 3)),
                mB=rng.uniform(0.01, 2, n), IB=inertia(), rhoB=rng.normal(0, 0.02, (n, 3)),
                vB=rng.normal(0, 1e-2, (n, 3)), wB=rng.normal(0, 1, (n, 3)),
                n=rng.normal(size=(n, 3)))


def _call3(d, e, mu):
    return impact_3d(d["mA"], d["IA"], d["rhoA"], d["vA"], d["wA"], d["mB"], d["IB"],
                     d["rhoB"], d["vB"], d["wB"], d["n"], e=e, mu=mu)


def test_3d_conservation_e1_frictionless():
    rng = np.random.default_rng(5)
    d = _random_3d(rng, 300)
    r = _call3(d, 1.0, 0.0)
    p0 = d["mA"][:, None] * d["vA"] + d["mB"][:, None] * d["vB"]
    p1 = d["mA"][:, None] * r.vA + d["mB"][:, None] * r.vB
    np.testing.assert_allclose(p1, p0, atol=1e-13 * np.abs(p0).max())
    E0 = kinetic_energy(d["mA"], d["IA"], d["vA"], d["wA"]) + kinetic_energy(
        d["mB"], d["IB"], d["vB"], d["wB"])
    np.testing.assert_allclose(r.dE, 0.0, atol=1e-11 * E0.max())
    # angular momentum about the contact point, total (common point): I w + rho_c x m v, with
    # the CoM at -rho relative to the contact point
    def L(m, I, rho, v, w):
        return np.einsum("bij,bj->bi", I, w) + np.cross(-rho, m[:, None] * v)
    L0 = L(d["mA"], d["IA"], d["rhoA"], d["vA"], d["wA"]) + L(d["mB"], d["IB"], d["rhoB"],
                                                              d["vB"], d["wB"])
    L1 = L(d["mA"], d["IA"], d["rhoA"], r.vA, r.wA) + L(d["mB"], d["IB"], d["rhoB"], r.vB, r.wB)
    np.testing.assert_allclose(L1, L0, atol=1e-12 * np.abs(L0).max())
    nn = d["n"] / np.linalg.norm(d["n"], axis=1, keepdims=True)
    np.testing.assert_allclose(np.sum(r.u_after * nn, 1), -np.sum(r.u_before * nn, 1),
                               atol=1e-13)


def test_3d_friction_stick_and_slip():
    rng = np.random.default_rng(6)
    d = _random_3d(rng, 400)
    nn = d["n"] / np.linalg.norm(d["n"], axis=1, keepdims=True)
    r0 = _call3(d, 0.5, 0.0)
    approaching = np.sum(r0.u_before * nn, 1) < 0
    # very large mu: wherever the sticking impulse pushes (J_n > 0) the contact sticks and
    # the tangential relative velocity after the impact is zero
    rs = _call3(d, 0.5, 1e6)
    ok = approaching & (rs.mode == 1)
    assert ok.sum() > 0.5 * approaching.sum()
    ut = rs.u_after - np.sum(rs.u_after * nn, 1)[:, None] * nn
    np.testing.assert_allclose(ut[ok], 0.0, atol=1e-12)
    assert np.all(rs.Jn[ok] > 0)
    # moderate mu: some slip; slipping impulses lie on the cone, normal restitution holds, and
    # no approaching contact gains energy
    rm = _call3(d, 0.5, 0.2)
    assert rm.slip[approaching].any() and (~rm.slip[approaching]).any()
    Jn = np.sum(rm.J * nn, 1)
    Jt = np.linalg.norm(rm.J - Jn[:, None] * nn, axis=1)
    s = rm.slip & approaching
    np.testing.assert_allclose(Jt[s], 0.2 * Jn[s], rtol=1e-9)
    fr = approaching & (rm.mode != 3)
    assert np.all(Jt[fr] <= 0.2 * Jn[fr] * (1 + 1e-9))
    np.testing.assert_allclose(np.sum(rm.u_after * nn, 1)[approaching],
                               -0.5 * np.sum(rm.u_before * nn, 1)[approaching], atol=1e-13)
    E0 = kinetic_energy(d["mA"], d["IA"], d["vA"], d["wA"]) + kinetic_energy(
        d["mB"], d["IB"], d["vB"], d["wB"])
    assert np.all(rm.dE[approaching] <= 1e-12 * E0[approaching])


def test_symmetric_cases_symmetric():
    """A symmetric striker hitting a symmetric target along the symmetry axis: no sideways
    velocity or spin; mirrored initial states give mirrored results."""
    I = np.eye(3) * 1e-4
    r = impact_3d(0.015, I * 0.03, np.array([0, 0, 0.02]), np.array([0, 0, 0.01]), np.zeros(3),
                  1.928, I * 6.8, np.array([0, 0, -0.02]), np.zeros(3), np.zeros(3),
                  np.array([0, 0, 1.0]))
    np.testing.assert_allclose(r.vB[:2], 0, atol=1e-18)
    np.testing.assert_allclose(r.wB, 0, atol=1e-18)
    # mirror x -> -x
    rng = np.random.default_rng(7)
    d = _random_3d(rng, 50)
    Mx = np.diag([-1.0, 1.0, 1.0])
    ra = _call3(d, 1.0, 0.3)
    dm = dict(d)
    for k in ("rhoA", "vA", "rhoB", "vB", "n"):
        dm[k] = d[k] @ Mx
    for k in ("wA", "wB"):  # angular velocity is a pseudovector: w' = det(M) M w
        dm[k] = -(d[k] @ Mx)
    for k in ("IA", "IB"):
        dm[k] = Mx @ d[k] @ Mx
    rb = _call3(dm, 1.0, 0.3)
    np.testing.assert_allclose(rb.vB, ra.vB @ Mx, atol=1e-14)
    np.testing.assert_allclose(rb.wB, -(ra.wB @ Mx), atol=1e-12)
