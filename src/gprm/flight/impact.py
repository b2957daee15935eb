"""Instantaneous rigid-body impact models (Section 4 hypotheses 1-4, Appendix B).

Two models, both written from the conservation laws and solved as linear systems (never typed
in from the paper's closed form):

* :func:`planar_impact` – two planar rigid bodies (two translations and one rotation each),
  frictionless, impulse along the contact normal, Newton restitution ``e``. With ``e = 1`` this
  is the model of Appendix B (Eq. B.1, with its garble ``V_N^f = V_N^i`` read as
  ``V_N^f = -V_N^i``).
* :func:`impact_3d` – two 3D rigid bodies (full inertia tensors), Newton restitution ``e`` and
  optional Coulomb friction ``mu`` (stick or slip, see the function). With ``mu = 0`` and planar
  data it reduces to :func:`planar_impact` in each plane.

Conventions (both models): body A is the striker (the plunger), body B the struck body (the
test mass). ``n`` is the unit contact normal; the impulse on B is ``+J`` and on A ``-J``, with
``J·n = P >= 0`` for approaching bodies. ``rho`` is the contact point relative to the body's
centre of mass. All functions are batched: leading dimensions broadcast.

Planar convention: a plane with coordinates (a, b) and a scalar angular velocity ``w`` about
the axis a × b, so that the velocity of a body point is ``v + w * (-rho_b, rho_a)``. The x–z
plane of the paper is (a, b) = (z, x) with ``w = ω_y`` (η'); the y–z plane is (a, b) = (y, z)
with ``w = ω_x`` (θ').
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


# --------------------------------------------------------------------------------------------
# planar model (Appendix B)
# --------------------------------------------------------------------------------------------
def _cross2(r, v):
    """z component of r × v for 2-vectors (..., 2)."""
    return r[..., 0] * v[..., 1] - r[..., 1] * v[..., 0]


def _perp(w, r):
    """w e_3 × r for a scalar w and 2-vector r: (-w r_b, w r_a)."""
    return np.stack([-w * r[..., 1], w * r[..., 0]], axis=-1)


@dataclass(frozen=True)
class PlanarImpact:
    """Post-impact state of a planar impact (all arrays, batched).

    ``vA, vB`` (..., 2) CoM velocities, ``wA, wB`` (...) angular velocities, ``P`` (...) the
    normal impulse on B (on A it is ``-P n``), ``vn_before, vn_after`` the relative normal
    velocity of B's contact point with respect to A's (negative: approaching).
    """

    vA: np.ndarray
    wA: np.ndarray
    vB: np.ndarray
    wB: np.ndarray
    P: np.ndarray
    vn_before: np.ndarray
    vn_after: np.ndarray


def planar_impact(mA, IA, rhoA, vA, wA, mB, IB, rhoB, vB, wB, n, e=1.0) -> PlanarImpact:
    """Frictionless instantaneous impact of two planar rigid bodies (Appendix B, Eq. B.1).

    Unknowns: vA'(2), wA', vB'(2), wB' and the normal impulse P (7). Equations (hypotheses 1-4
    of Section 4): the tangential impulse is zero (frictionless), so

    * linear momentum of each body:  mA (vA' - vA) = -P n,   mB (vB' - vB) = +P n;
    * angular momentum of each body about its CoM:
      IA (wA' - wA) = rhoA × (-P n),   IB (wB' - wB) = rhoB × (P n);
    * restitution along the normal: n·(u_B' - u_A') = -e n·(u_B - u_A), with u the contact
      point velocity v + w e_3 × rho.

    The 7×7 linear system is assembled and solved for every batch element. ``e = 1`` is
    perfectly elastic (Appendix B), ``e = 0`` plastic. Returns a :class:`PlanarImpact`.
    """
    arrs = [np.asarray(a, float) for a in (mA, IA, rhoA, vA, wA, mB, IB, rhoB, vB, wB, n)]
    mA, IA, rhoA, vA, wA, mB, IB, rhoB, vB, wB, n = arrs
    e = np.asarray(e, float)
    shape = np.broadcast_shapes(mA.shape, IA.shape, rhoA.shape[:-1], vA.shape[:-1], wA.shape,
                                mB.shape, IB.shape, rhoB.shape[:-1], vB.shape[:-1], wB.shape,
                                n.shape[:-1], e.shape)
    b2 = lambda a: np.broadcast_to(a, shape + (2,))  # noqa: E731
    b1 = lambda a: np.broadcast_to(a, shape)  # noqa: E731
    mA, IA, wA, mB, IB, wB, e = map(b1, (mA, IA, wA, mB, IB, wB, e))
    rhoA, vA, rhoB, vB, n = map(b2, (rhoA, vA, rhoB, vB, n))
    # unknown vector y = [vA_a, vA_b, wA, vB_a, vB_b, wB, P]
    M = np.zeros(shape + (7, 7))
    r = np.zeros(shape + (7,))
    for k in range(2):  # momentum of A and B, components a, b
        M[..., k, k] = mA
        M[..., k, 6] = n[..., k]
        r[..., k] = mA * vA[..., k]
        M[..., 3 + k, 3 + k] = mB
        M[..., 3 + k, 6] = -n[..., k]
        r[..., 3 + k] = mB * vB[..., k]
    # angular momentum: IA wA' + (rhoA × n) P = IA wA ;  IB wB' - (rhoB × n) P = IB wB
    M[..., 2, 2] = IA
    M[..., 2, 6] = _cross2(rhoA, n)
    r[..., 2] = IA * wA
    M[..., 5, 5] = IB
    M[..., 5, 6] = -_cross2(rhoB, n)
    r[..., 5] = IB * wB
    # restitution: n·(vB' + wB' e3×rhoB) - n·(vA' + wA' e3×rhoA) = -e vn
    uA = vA + _perp(wA, rhoA)
    uB = vB + _perp(wB, rhoB)
    vn = np.sum(n * (uB - uA), axis=-1)
    perpA = _perp(np.ones(shape), rhoA)
    perpB = _perp(np.ones(shape), rhoB)
    M[..., 6, 0:2] = -n
    M[..., 6, 2] = -np.sum(n * perpA, axis=-1)
    M[..., 6, 3:5] = n
    M[..., 6, 5] = np.sum(n * perpB, axis=-1)
    r[..., 6] = -e * vn
    y = np.linalg.solve(M, r[..., None])[..., 0]
    vA2, wA2, vB2, wB2, P = y[..., 0:2], y[..., 2], y[..., 3:5], y[..., 5], y[..., 6]
    vn2 = np.sum(n * ((vB2 + _perp(wB2, rhoB)) - (vA2 + _perp(wA2, rhoA))), axis=-1)
    return PlanarImpact(vA2, wA2, vB2, wB2, P, vn, vn2)


# --------------------------------------------------------------------------------------------
# 3D model with restitution and Coulomb friction
# --------------------------------------------------------------------------------------------
def _skew(r):
    """Matrix [r]× with [r]× v = r × v, batched (..., 3, 3)."""
    z = np.zeros(r.shape[:-1])
    return np.stack([np.stack([z, -r[..., 2], r[..., 1]], -1),
                     np.stack([r[..., 2], z, -r[..., 0]], -1),
                     np.stack([-r[..., 1], r[..., 0], z], -1)], -2)


@dataclass(frozen=True)
class Impact3D:
    """Post-impact state of a 3D impact (batched).

    ``vA, wA, vB, wB`` (..., 3); ``J`` (..., 3) the impulse on B (on A: -J); ``Jn`` its normal
    part; ``slip`` (...) True where the contact slides (Coulomb cone active), False where it
    sticks; ``u_before, u_after`` (..., 3) the relative velocity of B's contact point with
    respect to A's; ``dE`` (...) the kinetic-energy change (<= 0 for a dissipative impact).
    """

    vA: np.ndarray
    wA: np.ndarray
    vB: np.ndarray
    wB: np.ndarray
    J: np.ndarray
    Jn: np.ndarray
    slip: np.ndarray
    u_before: np.ndarray
    u_after: np.ndarray
    dE: np.ndarray
    mode: np.ndarray | None = None   # 0 frictionless, 1 stick, 2 slip, 3 jam (frictionless)


def kinetic_energy(m, I, v, w):
    """½ m v·v + ½ w·I w, batched (I (..., 3, 3) or planar scalar with w (...))."""
    v = np.asarray(v, float)
    w = np.asarray(w, float)
    I = np.asarray(I, float)
    lin = 0.5 * np.asarray(m) * np.sum(v * v, axis=-1)
    if I.ndim >= 2 and I.shape[-2:] == (3, 3) and w.shape[-1:] == (3,):
        rot = 0.5 * np.einsum("...i,...ij,...j->...", w, I, w)
    else:
        rot = 0.5 * I * w * w
    return lin + rot


def collision_matrix(mA, IA_inv, rhoA, mB, IB_inv, rhoB):
    """K with Δu = K J: change of the relative contact velocity u = u_B - u_A per impulse J on B.

    K = (1/mA + 1/mB) 1 - [rhoA]× IA⁻¹ [rhoA]× - [rhoB]× IB⁻¹ [rhoB]× (symmetric, positive
    definite for bodies of finite mass and positive-definite inertia).
    """
    SA, SB = _skew(rhoA), _skew(rhoB)
    eye = np.eye(3)
    return ((1.0 / mA + 1.0 / mB)[..., None, None] * eye
            - SA @ IA_inv @ SA - SB @ IB_inv @ SB)


def impact_3d(mA, IA, rhoA, vA, wA, mB, IB, rhoB, vB, wB, n, e=1.0, mu=0.0) -> Impact3D:
    """Instantaneous impact of two 3D rigid bodies at one contact point.

    Model (documented in docs/flight.md):

    * impulse J on B (−J on A) at the contact point; each body's momentum changes by ±J and its
      angular momentum about its CoM by rho × (±J), so Δu = K J (:func:`collision_matrix`);
    * Newton restitution on the normal: u_n' = −e u_n (u_n < 0 approaching);
    * ``mu = 0``: frictionless, J = P n, P = −(1 + e) u_n / (n·K n);
    * ``mu > 0`` (Coulomb): first try sticking, J = K⁻¹(−e u_n n − u) (tangential relative
      velocity brought to zero); accept it if |J_t| <= mu J_n. Otherwise the contact slides
      with the friction impulse opposing the initial tangential slip direction t̂ (constant
      direction over the impulse), J = P (n − mu t̂), P = −(1 + e) u_n / (n·K (n − mu t̂)).
      This is the algebraic Newton–Coulomb model; it does not track a slip reversal during
      the impulse (a stick/slip decision is made once), see docs/flight.md. A sticking
      impulse must also push (J_n > 0). Where the sliding branch has no positive effective
      normal mass (n·K(n − mu t̂) <= 0, a "jam" of rigid-body Coulomb friction) the
      frictionless impulse is used and ``mode`` says so (3).

    Inertias ``IA, IB`` are (..., 3, 3) tensors about the CoM in the common frame. Returns an
    :class:`Impact3D`.
    """
    A = [np.asarray(a, float) for a in (mA, IA, rhoA, vA, wA, mB, IB, rhoB, vB, wB, n)]
    mA, IA, rhoA, vA, wA, mB, IB, rhoB, vB, wB, n = A
    e = np.asarray(e, float)
    mu = np.asarray(mu, float)
    shape = np.broadcast_shapes(mA.shape, IA.shape[:-2], rhoA.shape[:-1], vA.shape[:-1],
                                wA.shape[:-1], mB.shape, IB.shape[:-2], rhoB.shape[:-1],
                                vB.shape[:-1], wB.shape[:-1], n.shape[:-1], e.shape, mu.shape)
    v3 = lambda a: np.broadcast_to(a, shape + (3,))  # noqa: E731
    s = lambda a: np.broadcast_to(a, shape)  # noqa: E731
    m33 = lambda a: np.broadcast_to(a, shape + (3, 3))  # noqa: E731
    mA, mB, e, mu = map(s, (mA, mB, e, mu))
    rhoA, vA, wA, rhoB, vB, wB = map(v3, (rhoA, vA, wA, rhoB, vB, wB))
    IA, IB = m33(IA), m33(IB)
    n = v3(n) / np.linalg.norm(v3(n), axis=-1, keepdims=True)
    IA_inv, IB_inv = np.linalg.inv(IA), np.linalg.inv(IB)
    K = collision_matrix(mA, IA_inv, rhoA, mB, IB_inv, rhoB)
    u = (vB + np.cross(wB, rhoB)) - (vA + np.cross(wA, rhoA))
    un = np.sum(u * n, axis=-1)
    Kn = np.einsum("...ij,...j->...i", K, n)
    # frictionless impulse
    J = (-(1.0 + e) * un / np.sum(n * Kn, axis=-1))[..., None] * n
    slip = np.zeros(shape, bool)
    mode = np.zeros(shape, int)
    if np.any(mu > 0):
        target = (-e * un)[..., None] * n
        J_stick = np.linalg.solve(K, (target - u)[..., None])[..., 0]
        Jn_s = np.sum(J_stick * n, axis=-1)
        Jt_s = J_stick - Jn_s[..., None] * n
        stick_ok = ((Jn_s > 0)
                    & (np.linalg.norm(Jt_s, axis=-1) <= mu * Jn_s * (1 + 1e-12)))
        ut = u - un[..., None] * n
        ut_norm = np.linalg.norm(ut, axis=-1)
        safe = np.where(ut_norm > 0, ut_norm, 1.0)
        that = np.where(ut_norm[..., None] > 0, ut / safe[..., None], 0.0)
        d = n - mu[..., None] * that
        Kd = np.einsum("...ij,...j->...i", K, d)
        nKd = np.sum(n * Kd, axis=-1)
        jam = nKd <= 0
        P_slip = -(1.0 + e) * un / np.where(jam, 1.0, nKd)
        J_slip = P_slip[..., None] * d
        use_fric = mu > 0
        slip = use_fric & ~stick_ok & ~jam
        J = np.where((use_fric & stick_ok)[..., None], J_stick, J)
        J = np.where(slip[..., None], J_slip, J)
        mode = np.where(use_fric, np.where(stick_ok, 1, np.where(jam, 3, 2)), 0)
    vA2 = vA - J / mA[..., None]
    vB2 = vB + J / mB[..., None]
    wA2 = wA + np.einsum("...ij,...j->...i", IA_inv, np.cross(rhoA, -J))
    wB2 = wB + np.einsum("...ij,...j->...i", IB_inv, np.cross(rhoB, J))
    u2 = (vB2 + np.cross(wB2, rhoB)) - (vA2 + np.cross(wA2, rhoA))
    E0 = kinetic_energy(mA, IA, vA, wA) + kinetic_energy(mB, IB, vB, wB)
    E1 = kinetic_energy(mA, IA, vA2, wA2) + kinetic_energy(mB, IB, vB2, wB2)
    return Impact3D(vA2, wA2, vB2, wB2, J, np.sum(J * n, axis=-1), slip, u, u2, E1 - E0,
                    mode)
