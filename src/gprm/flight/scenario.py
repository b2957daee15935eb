"""Impact scenarios: which contact of the plunger head strikes the indent, where, with which
friction and restitution, and when (issue 23; docs/flight.md §10).

A *scenario* is a contact configuration between the plunger head and the test-mass (TM)
indent; its continuous unknowns (:data:`PARAMS`) are drawn from documented distributions
(:class:`ScenarioPrior`); the geometry of each is in :func:`contacts`:

* ``"xz"``: one contact of the indent's rim edge on the round side of the head, on the x–z
  side: horizontal normal (sgn(dist_x) cos φ, sin φ, 0), φ the contact's azimuth;
* ``"yz"``: the same on the y–z side;
* ``"two"`` (the default truth): both rim sides at once, one impulse per contact solved
  jointly (:func:`impact_3d_two`);
* ``"xz-face"``, ``"yz-face"``, ``"two-face"``: the paper's contact lines (Fig. 9) on the
  indent faces, normals at the indent angle α to z (Sec. 4);
* ``"corner"``: the tip corner C_p + (dist_x, dist_y, dist_z) on the face
  n ∝ (sgn dist_x tan α, sgn dist_y tan α, 1) (the issue-14 truth, docs/flight.md §2).

Impact time (the **gap rule**): before the release the head stands a gap g from the contact
surface along its normal; the first contact is the first time the contact point's
displacement along n, d_n(t) = (P(t) − P(t_c))·n, reaches g, with g = f · max d_n (the
largest excursion of that parameter set in the window).

Why the rim contacts give the paper's pattern (measured in docs/flight.md §10): their normal
is horizontal, so the normal impulse moves the TM laterally, while the head slides axially
against the rim and Coulomb friction gives v_z at most μ times the normal impulse's share;
the face contacts' 45° normals make v_z the largest component.

All numerics are batched plain functions over arrays (SI).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gprm.errors import GprmInputError
from gprm.flight.impact import _skew, impact_3d, kinetic_energy
from gprm.simulate.kinematics import (body_motion, motion_omega, named_points, point_motion,
                                     rotation)

SCENARIOS: tuple[str, ...] = ("xz", "yz", "two", "xz-face", "yz-face", "two-face", "corner")
"""The contact scenarios (module docstring). The first three are the rim contacts the scenario
inference compares (:data:`COMPARED`)."""

COMPARED: tuple[str, ...] = ("xz", "yz", "two")
"""The scenarios the posterior compares (issue 23: one contact in x–z, in y–z, two)."""

PARAMS: tuple[str, ...] = ("f", "s", "phi", "mu", "e")
"""The continuous unknowns of a scenario: gap fraction f, contact height s on the head (m, along
z for a rim contact, down the line for a face contact), azimuth φ of the contact on the head
(rad), friction coefficient μ, restitution e."""

OFFSETS: tuple[str, ...] = ("tm_dx", "tm_dy")
"""The TM CoM's lateral offset (m) from the head axis in x and y (:class:`ScenarioPrior`
``tm_offset``): drawn for the truths, marginalised by the inference in a first-order Gaussian
approximation (:func:`offset_covariance`), not among the inferred :data:`PARAMS`."""

COMPONENTS: tuple[str, ...] = ("vx", "vy", "vz", "wx", "wy", "wz")
"""The TM velocity components after the impact (m/s, rad/s)."""


@dataclass(frozen=True)
class ScenarioPrior:
    """The documented distributions of a scenario's unknowns (our assumptions; the paper gives
    none of them), all independent:

    gap fraction f ~ U(``gap``) of the largest excursion of the contact point along the
    contact normal in the window; contact height s ~ U(−``height``, ``height``) (m);
    azimuth φ ~ U(−``azimuth``, ``azimuth``) (rad): where the indent's rim side touches the
    round head, set by the rim's yaw relative to the head (a TM yaw offset in the indent);
    friction μ ~ U(``friction``); restitution e ~ U(``restitution``) (near-elastic: the paper
    finds the flight impacts compatible with energy conservation, Sec. 3). Face scenarios use
    the indent angle ``indent_angle`` (the registry's 45°). The TM CoM lies
    s_tm/2 − ``indent_depth`` above the contact lines' middle points, laterally offset from the
    head axis by δ = (tm_dx, tm_dy), each ~ U(−``tm_offset``, ``tm_offset``) (m; 0: centred,
    and nothing drawn, so the draws of the other unknowns are those without the offset). The
    offset gives the impact a lever arm about z: ω_z = (I_B⁻¹ Σ ρ_i × J_i)_z with
    ρ_i = P_i − C − δ (docs/flight.md §10).
    """

    gap: tuple[float, float] = (0.2, 0.8)
    height: float = 1.0e-3
    azimuth: float = float(np.deg2rad(30.0))
    friction: tuple[float, float] = (0.2, 0.8)
    restitution: tuple[float, float] = (0.7, 1.0)
    indent_angle: float = float(np.deg2rad(45.0))
    indent_depth: float = 3.0e-3
    tm_offset: float = 1.0e-3

    def __post_init__(self):
        for name in ("gap", "friction", "restitution"):
            lo, hi = getattr(self, name)
            if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
                raise GprmInputError(f"expected LO < HI, got {(lo, hi)!r}", field=name)
        if not (0 < self.gap[0] and self.gap[1] < 1):
            raise GprmInputError("gap fractions must lie in (0, 1)", field="gap")
        if self.friction[0] < 0:
            raise GprmInputError("must be >= 0", field="friction")
        if self.restitution[0] < 0 or self.restitution[1] > 1:
            raise GprmInputError("must lie in [0, 1]", field="restitution")
        for name in ("height", "azimuth", "tm_offset"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise GprmInputError(f"must be >= 0, got {v!r}", field=name)

    def bounds(self) -> dict[str, tuple[float, float]]:
        """Support of each of :data:`PARAMS`."""
        return {"f": (self.gap[0], self.gap[1]), "s": (-self.height, self.height),
                "phi": (-self.azimuth, self.azimuth),
                "mu": (self.friction[0], self.friction[1]),
                "e": (self.restitution[0], self.restitution[1])}

    def draw(self, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """``n`` independent draws of :data:`PARAMS` and :data:`OFFSETS` (each (n,)); the
        offsets are drawn after the others, and only when ``tm_offset`` > 0 (else zeros)."""
        out = {k: rng.uniform(lo, hi, n) for k, (lo, hi) in self.bounds().items()}
        for k in OFFSETS:
            out[k] = (rng.uniform(-self.tm_offset, self.tm_offset, n) if self.tm_offset > 0
                      else np.zeros(n))
        return out


# ----------------------------------------------------------------------------- geometry
def contacts(kind: str, pb, p: dict[str, np.ndarray],
             prior: "ScenarioPrior | None" = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """The contact(s) of scenario ``kind``: a list of (r, n), r (K, 3) the contact point in
    plunger body coordinates, n (K, 3) the unit normal (impulse direction on the TM), for the K
    draws ``p`` (:data:`PARAMS`) and the (first) parameter set of ``pb``.

    Rim contacts (``xz``, ``yz``, ``two``): the indent's rim edge on the round side of the
    head, radius dist_x (dist_y) about the plunger axis through its CoM: the x–z contact at
    azimuth φ from the x axis, r = C_p + (dist_x cos φ, dist_x sin φ, dist_z + s), normal
    n = (sgn(dist_x) cos φ, sin φ, 0) (an edge on a surface: the surface's normal, horizontal);
    the y–z contact at r = C_p + (−dist_y sin φ, dist_y cos φ, dist_z + s),
    n = (−sin φ, sgn(dist_y) cos φ, 0) (the square rim's two sides yawed by the same φ).
    Face contacts (``xz-face``, ``yz-face``, ``two-face``): the line's middle point M_xz (M_yz)
    moved s down the face and dist·φ across it, normal (sgn dist_x sin α, 0, cos α)
    ((0, sgn dist_y sin α, cos α)), α = the indent angle. ``corner``: the corner
    C_p + (dist_x, dist_y, dist_z) on the face n ∝ (sgn dist_x tan α, sgn dist_y tan α, 1)
    (docs/flight.md §2), moved s down and dist_x·φ across the face.
    """
    if kind not in SCENARIOS:
        raise GprmInputError(f"must be one of {', '.join(SCENARIOS)}, got {kind!r}",
                             field="scenario")
    prior = prior or ScenarioPrior()
    pts = named_points(pb)
    com0 = pts["com"].r[0]
    dx, dy, dz = (float(np.ravel(pb[k])[0]) for k in ("dist_x", "dist_y", "dist_z"))
    sx, sy = (1.0 if v >= 0 else -1.0 for v in (dx, dy))
    s = np.atleast_1d(np.asarray(p["s"], float))
    ph = np.atleast_1d(np.asarray(p["phi"], float))
    K = s.size
    z, one = np.zeros(K), np.ones(K)
    cp, sp = np.cos(ph), np.sin(ph)
    a = prior.indent_angle
    ca, sa = np.cos(a), np.sin(a)

    def rim(plane):
        if plane == "xz":
            r = com0 + np.stack([abs(dx) * sx * cp, abs(dx) * sp, dz + s], -1)
            n = np.stack([sx * cp, sp, z], -1)
        else:
            r = com0 + np.stack([-abs(dy) * sp, abs(dy) * sy * cp, dz + s], -1)
            n = np.stack([-sp, sy * cp, z], -1)
        return r, n

    def face(plane):
        if plane == "xz":
            m = com0 + np.array([dx, 0.0, dz])
            n = np.stack([sx * sa * one, z, ca * one], -1)
            lhat = np.stack([sx * ca * one, z, -sa * one], -1)
            r = m + s[:, None] * lhat + (abs(dx) * ph)[:, None] * np.array([0.0, 1.0, 0.0])
        else:
            m = com0 + np.array([0.0, dy, dz])
            n = np.stack([z, sy * sa * one, ca * one], -1)
            lhat = np.stack([z, sy * ca * one, -sa * one], -1)
            r = m + s[:, None] * lhat + (abs(dy) * ph)[:, None] * np.array([1.0, 0.0, 0.0])
        return r, n

    if kind in ("xz", "yz"):
        return [rim(kind)]
    if kind == "two":
        return [rim("xz"), rim("yz")]
    if kind in ("xz-face", "yz-face"):
        return [face(kind[:2])]
    if kind == "two-face":
        return [face("xz"), face("yz")]
    ta = np.tan(a)
    n = np.stack([sx * ta * one, sy * ta * one, one], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    lhat = np.cross(np.cross(n, np.array([0.0, 0.0, 1.0])), n)
    lhat /= np.linalg.norm(lhat, axis=-1, keepdims=True)
    what = np.cross(n, lhat)
    r = (com0 + np.array([dx, dy, dz]) + s[:, None] * lhat
         + (abs(dx) * ph)[:, None] * what)
    return [(r, n)]


def tm_centre(pb, prior: ScenarioPrior) -> np.ndarray:
    """TM CoM (3,) at rest, plunger body coordinates, when centred on the head: the plunger
    CoM's lateral position (the head axis of :func:`contacts`), and s_tm/2 − indent_depth
    above the contact lines' middle points (as docs/flight.md §2). A draw's lateral offset
    (:data:`OFFSETS`) is added by :func:`scenario_velocity`."""
    pts = named_points(pb)
    com0 = pts["com"].r[0]
    s_tm = float(np.ravel(pb["s_tm"])[0])
    return np.array([com0[0], com0[1], pts["M_xz"].r[0, 2] + s_tm / 2 - prior.indent_depth])


# ----------------------------------------------------------------------------- kinematics
@dataclass(frozen=True)
class Frame:
    """The plunger body's rigid motion on a time grid: origin A (B, 3, T), its velocity Ad,
    rotation R (B, T, 3, 3), angular velocity ω (B, 3, T); the assembly CoM G and its body
    coordinates are in ``G`` (B, 3, T) (positions) for the impact's lever arm."""

    time: np.ndarray
    A: np.ndarray
    Ad: np.ndarray
    R: np.ndarray
    omega: np.ndarray
    G: np.ndarray
    ok: np.ndarray


def plunger_frame(motion) -> Frame:
    """The plunger body's rigid motion of a :class:`~gprm.simulate.kinematics.PlungerMotion`
    (a body point r moves as A + R r with velocity Ad + ω × R r, the closed form of
    :func:`gprm.simulate.kinematics.point_motion` for the plunger body)."""
    c, d = motion.coords, motion.rates
    A = np.stack([c["x_A"], c["y_A"], c["z_lr"] + c["z_A"]], 1)
    Ad = np.stack([d["x_A_dot"], d["y_A_dot"], d["z_lr_dot"] + d["z_A_dot"]], 1)
    R = rotation(c["theta"], c["eta"])
    G, _ = point_motion(motion, named_points(motion.params)["assembly_com"])
    return Frame(motion.time, A, Ad, R, motion_omega(c, d), G, motion.ok)


def excursion(frame: Frame, r: np.ndarray, n: np.ndarray) -> np.ndarray:
    """d_n (B, K, T): displacement along n (K, 3) of the body points r (K, 3) since the first
    grid time (the head at rest at the retraction command)."""
    dA = frame.A - frame.A[:, :, :1]                               # (B, 3, T)
    dR = frame.R - frame.R[:, :1]                                  # (B, T, 3, 3)
    B, T = dR.shape[:2]
    K = n.shape[0]
    # one product: [n, n_j r_i] (K, 12) times [dA; dR] (12, B T)
    lhs = np.concatenate([n, (n[:, :, None] * r[:, None, :]).reshape(K, 9)], 1)
    rhs = np.concatenate([np.moveaxis(dA, 1, 0).reshape(3, B * T),
                          np.moveaxis(dR.reshape(B, T, 9), 2, 0).reshape(9, B * T)], 0)
    return np.moveaxis((lhs @ rhs).reshape(K, B, T), 0, 1)


def gap_time(frame: Frame, r: np.ndarray, n: np.ndarray, f: np.ndarray):
    """The gap rule: first time (B, K) at which d_n reaches f · max d_n (linear interpolation
    on the grid), and d_max (B, K). NaN where the head never moves towards the face."""
    d = excursion(frame, r, n)
    dmax = d.max(axis=-1)
    g = np.asarray(f)[None, :] * dmax
    above = d >= g[..., None]
    i1 = np.argmax(above, axis=-1)
    i1 = np.maximum(i1, 1)
    d0 = np.take_along_axis(d, (i1 - 1)[..., None], -1)[..., 0]
    d1 = np.take_along_axis(d, i1[..., None], -1)[..., 0]
    t = frame.time
    frac = np.clip((g - d0) / np.where(d1 > d0, d1 - d0, 1.0), 0.0, 1.0)
    tt = t[i1 - 1] + frac * (t[i1] - t[i1 - 1])
    return np.where(dmax > 0, tt, np.nan), dmax


def _interp(arr: np.ndarray, time: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Linear interpolation of arr (B, ..., T) at times t (B, K): (B, K, ...)."""
    T = time.size
    tt = np.nan_to_num(t, nan=time[0])
    i = np.clip(np.searchsorted(time, tt) - 1, 0, T - 2)
    a = np.clip((tt - time[i]) / (time[i + 1] - time[i]), 0.0, 1.0)
    B = arr.shape[0]
    bidx = np.arange(B)[:, None]
    x0 = np.moveaxis(arr, -1, 1)[bidx, i]                          # (B, K, ...)
    x1 = np.moveaxis(arr, -1, 1)[bidx, i + 1]
    ex = (slice(None), slice(None)) + (None,) * (x0.ndim - 2)
    return x0 + a[ex] * (x1 - x0)


def contact_state(frame: Frame, r: np.ndarray, t: np.ndarray):
    """Position and velocity (B, K, 3) of the body points r (K, 3) at times t (B, K), with
    the plunger's angular velocity (B, K, 3) and the assembly CoM (B, K, 3) there."""
    A = _interp(frame.A, frame.time, t)
    Ad = _interp(frame.Ad, frame.time, t)
    R = _interp(np.moveaxis(frame.R, 1, -1), frame.time, t)       # (B, K, 3, 3)
    w = _interp(frame.omega, frame.time, t)
    G = _interp(frame.G, frame.time, t)
    Rr = np.einsum("bkij,kj->bki", R, r)
    return A + Rr, Ad + np.cross(w, Rr), w, G


# ----------------------------------------------------------------------------- impacts
@dataclass(frozen=True)
class TwoContactImpact:
    """Post-impact state of a two-contact impact (batched, shapes as :class:`Impact3D`):
    ``P`` (..., 2) the normal-direction impulse magnitudes, ``J`` (..., 2, 3) the impulses on
    B, ``active`` (..., 2) which contacts push, ``dE`` the kinetic-energy change."""

    vA: np.ndarray
    wA: np.ndarray
    vB: np.ndarray
    wB: np.ndarray
    P: np.ndarray
    J: np.ndarray
    active: np.ndarray
    u_before: np.ndarray
    u_after: np.ndarray
    dE: np.ndarray


def impact_3d_two(mA, IA, rhoA, vA, wA, mB, IB, rhoB, vB, wB, n, e=1.0, mu=0.0
                  ) -> TwoContactImpact:
    """Simultaneous instantaneous impact at two contact points (``rhoA``, ``rhoB``, ``n``:
    (..., 2, 3)), Newton restitution ``e`` and sliding Coulomb friction ``mu`` at each.

    Impulse on B at contact i: J_i = P_i d_i, d_i = n_i − μ t̂_i, t̂_i the initial tangential
    slip direction of B's contact point relative to A's (the sliding branch of
    :func:`gprm.flight.impact.impact_3d`; no stick is tried: with two contacts the grazing
    contacts of the scenarios slide). The relative velocity at contact i changes by
    Σ_j K_ij J_j with K_ij = (1/mA + 1/mB) 1 − [ρA_i]× IA⁻¹ [ρA_j]× − [ρB_i]× IB⁻¹ [ρB_j]×;
    restitution n_i·u_i' = −e n_i·u_i gives a 2×2 linear system for P. A contact whose P comes
    out ≤ 0 (or that does not approach) separates: the other is solved alone
    (:func:`impact_3d`, stick or slip). Returns a :class:`TwoContactImpact`.
    """
    f = lambda x: np.asarray(x, float)  # noqa: E731
    mA, IA, rhoA, vA, wA, mB, IB, rhoB, vB, wB, n = map(
        f, (mA, IA, rhoA, vA, wA, mB, IB, rhoB, vB, wB, n))
    e, mu = f(e), f(mu)
    shape = np.broadcast_shapes(mA.shape, IA.shape[:-2], rhoA.shape[:-2], vA.shape[:-1],
                                wA.shape[:-1], mB.shape, IB.shape[:-2], rhoB.shape[:-2],
                                vB.shape[:-1], wB.shape[:-1], n.shape[:-2], e.shape, mu.shape)
    mA, mB, e, mu = (np.broadcast_to(x, shape) for x in (mA, mB, e, mu))
    IA, IB = (np.broadcast_to(x, shape + (3, 3)) for x in (IA, IB))
    vA, wA, vB, wB = (np.broadcast_to(x, shape + (3,)) for x in (vA, wA, vB, wB))
    rhoA, rhoB = (np.broadcast_to(x, shape + (2, 3)) for x in (rhoA, rhoB))
    n = np.broadcast_to(n, shape + (2, 3))
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    IAi, IBi = np.linalg.inv(IA), np.linalg.inv(IB)
    u = (vB[..., None, :] + np.cross(wB[..., None, :], rhoB)
         - vA[..., None, :] - np.cross(wA[..., None, :], rhoA))     # (..., 2, 3)
    un = np.sum(u * n, -1)                                          # (..., 2)
    ut = u - un[..., None] * n
    utn = np.linalg.norm(ut, axis=-1, keepdims=True)
    that = np.where(utn > 0, ut / np.where(utn > 0, utn, 1.0), 0.0)
    d = n - mu[..., None, None] * that                              # (..., 2, 3)
    SA, SB = _skew(rhoA), _skew(rhoB)                               # (..., 2, 3, 3)
    eye = np.eye(3)
    inv_m = (1.0 / mA + 1.0 / mB)[..., None, None, None, None] * eye
    Kij = (inv_m - SA[..., :, None, :, :] @ IAi[..., None, None, :, :] @ SA[..., None, :, :, :]
           - SB[..., :, None, :, :] @ IBi[..., None, None, :, :] @ SB[..., None, :, :, :])
    Amat = np.einsum("...ik,...ijkl,...jl->...ij", n, Kij, d)       # (..., 2, 2)
    b = -(1.0 + e)[..., None] * un
    det = Amat[..., 0, 0] * Amat[..., 1, 1] - Amat[..., 0, 1] * Amat[..., 1, 0]
    safe = np.where(np.abs(det) > 0, det, 1.0)
    P0 = (Amat[..., 1, 1] * b[..., 0] - Amat[..., 0, 1] * b[..., 1]) / safe
    P1 = (Amat[..., 0, 0] * b[..., 1] - Amat[..., 1, 0] * b[..., 0]) / safe
    P = np.stack([P0, P1], -1)
    both = (P0 > 0) & (P1 > 0) & (un[..., 0] < 0) & (un[..., 1] < 0) & (np.abs(det) > 0)
    J = P[..., None] * d
    active = np.stack([both, both], -1)
    # where not both: the single contact that gives the larger pushing impulse alone
    singles = [impact_3d(mA, IA, rhoA[..., i, :], vA, wA, mB, IB, rhoB[..., i, :], vB, wB,
                         n[..., i, :], e, mu) for i in (0, 1)]
    ok = [(s.Jn > 0) & (un[..., i] < 0) for i, s in enumerate(singles)]
    pick1 = ok[1] & (~ok[0] | (singles[1].Jn > singles[0].Jn))
    pick0 = ok[0] & ~pick1
    Js = np.zeros(shape + (2, 3))
    Js[..., 0, :] = np.where(pick0[..., None], singles[0].J, 0.0)
    Js[..., 1, :] = np.where(pick1[..., None], singles[1].J, 0.0)
    J = np.where(both[..., None, None], J, Js)
    active = np.where(both[..., None], active, np.stack([pick0, pick1], -1))
    P = np.where(both[..., None], P, np.sum(J * n, -1))
    Jt = J.sum(-2)
    vA2 = vA - Jt / mA[..., None]
    vB2 = vB + Jt / mB[..., None]
    wA2 = wA + np.einsum("...ij,...j->...i", IAi, np.cross(rhoA, -J).sum(-2))
    wB2 = wB + np.einsum("...ij,...j->...i", IBi, np.cross(rhoB, J).sum(-2))
    u2 = (vB2[..., None, :] + np.cross(wB2[..., None, :], rhoB)
          - vA2[..., None, :] - np.cross(wA2[..., None, :], rhoA))
    E0 = kinetic_energy(mA, IA, vA, wA) + kinetic_energy(mB, IB, vB, wB)
    E1 = kinetic_energy(mA, IA, vA2, wA2) + kinetic_energy(mB, IB, vB2, wB2)
    return TwoContactImpact(vA2, wA2, vB2, wB2, P, J, active, u, u2, E1 - E0)


def scenario_velocity(kind: str, frame: Frame, pb0, p: dict[str, np.ndarray],
                      prior: ScenarioPrior, *, times=None, per_set: bool = False) -> dict:
    """TM velocity after the scenario's impact for draws ``p`` (K each) on every parameter set
    of ``frame`` (B): ``{component: (B, K)}`` (:data:`COMPONENTS`), ``t`` (B, K) the impact
    time, ``ok`` (B, K) where an impact happens (the contact approaches and the impulse
    pushes).

    ``pb0``: the parameter batch whose first set defines the geometry (the contacts, the TM
    position) and, when ``per_set`` is True, each set's own parameters (``pb0`` then holds
    B sets: masses and geometry per set, with K == B, draw k on set k). ``times`` (B, K):
    impact times to use instead of each set's own gap rule.
    """
    B = frame.A.shape[0]
    if per_set:
        sets = [{k: np.atleast_1d(v)[b:b + 1] for k, v in pb0.items()} for b in range(B)]
        geo = [contacts(kind, sets[b], {k: np.atleast_1d(v)[b:b + 1] for k, v in p.items()},
                        prior)
               for b in range(B)]
        cons = [(np.concatenate([g[i][0] for g in geo]), np.concatenate([g[i][1] for g in geo]))
                for i in range(len(geo[0]))]
        C = np.stack([tm_centre(s, prior) for s in sets])          # (B, 3)
        mass = {k: np.array([float(np.ravel(s[k])[0]) for s in sets])
                for k in ("m2", "m3", "m4", "J2", "m_tm", "s_tm")}
    else:
        cons = contacts(kind, pb0, p, prior)
        C = np.broadcast_to(tm_centre(pb0, prior), (B, 3))
        mass = {k: np.full(B, float(np.ravel(pb0[k])[0]))
                for k in ("m2", "m3", "m4", "J2", "m_tm", "s_tm")}
    r0, n0 = cons[0]
    K = r0.shape[0]
    if times is None:
        t, _ = gap_time(frame, r0, n0, np.asarray(p["f"]))
        if per_set:     # draw k belongs to set k
            t = np.diag(t)[:, None] if B > 1 else t[:, :1]
    else:
        t = np.asarray(times, float)
    if per_set:
        cons = [(r[:, None, :], nn[:, None, :]) for r, nn in cons]
        states = [_state_per_set(frame, r[:, 0], t) for r, _ in cons]
        Kx = 1
    else:
        states = [contact_state(frame, r, t) for r, _ in cons]
        Kx = K
    Mp = (mass["m2"] + mass["m3"] + mass["m4"])[:, None]
    IA = mass["J2"][:, None, None, None] * np.eye(3)
    mt = mass["m_tm"][:, None]
    IB = (mass["m_tm"] * mass["s_tm"] ** 2 / 6.0)[:, None, None, None] * np.eye(3)
    mu = np.broadcast_to(np.asarray(p["mu"], float).reshape(-1)[None, :] if not per_set
                         else np.asarray(p["mu"], float)[:, None], (B, Kx))
    e = np.broadcast_to(np.asarray(p["e"], float).reshape(-1)[None, :] if not per_set
                        else np.asarray(p["e"], float)[:, None], (B, Kx))
    zero = np.zeros((B, Kx, 3))
    # the TM CoM of each draw: centred on the head (C) plus its lateral offset δ
    if all(k in p for k in OFFSETS):
        dx, dy = (np.asarray(p[k], float).reshape(-1) for k in OFFSETS)
        off = np.stack([dx, dy, np.zeros_like(dx)], -1)
        off = off[:, None, :] if per_set else off[None, :, :]        # (B, 1, 3) or (1, K, 3)
    else:
        off = np.zeros((1, 1, 3))
    centre = C[:, None, :] + off
    rhoA, vAs, rhoB, ns = [], [], [], []
    for (_, nn), (P, vP, w, G) in zip(cons, states):
        ra = P - G
        rhoA.append(ra)
        vAs.append(vP - np.cross(w, ra))
        # TM fixed in the ground frame: its CoM at rest (body coordinates at rest = ground)
        rhoB.append(P - centre)
        ns.append(np.broadcast_to(nn if not per_set else nn[:, 0][:, None, :], (B, Kx, 3)))
    w = states[0][2]
    ncon = None
    if len(cons) == 1:
        one = impact_3d(Mp, IA, rhoA[0], vAs[0], w, mt, IB, rhoB[0], zero, zero, ns[0], e, mu)
        un = np.sum(one.u_before * ns[0], -1)
        ok = (un < 0) & (one.Jn > 0)
        vB, wB = one.vB, one.wB
    else:
        # one rigid plunger: the two contact points share its CoM velocity field
        two = impact_3d_two(Mp, IA, np.stack(rhoA, -2), vAs[0], w, mt, IB,
                            np.stack(rhoB, -2), zero, zero, np.stack(ns, -2), e, mu)
        ok = two.active.all(-1)     # the scenario is two contacts: both must push
        vB, wB, ncon = two.vB, two.wB, two.active.sum(-1)
    ok = ok & np.isfinite(t) & frame.ok[:, None]
    out = {c: np.where(ok, vB[..., i], np.nan) for i, c in enumerate(COMPONENTS[:3])}
    out.update({c: np.where(ok, wB[..., i], np.nan) for i, c in enumerate(COMPONENTS[3:])})
    out["t"] = t
    out["ok"] = ok
    if ncon is not None:
        out["contacts"] = ncon
    return out


def offset_covariance(v: np.ndarray, s_tm: float, tm_offset: float) -> np.ndarray:
    """Covariance (..., 6, 6) of the TM's :data:`COMPONENTS` that the lateral offset
    δ = (tm_dx, tm_dy), each ~ U(−tm_offset, tm_offset), adds after an impact that left the
    TM with linear velocity ``v`` (..., 3): to first order in δ the impulses are unchanged
    (the contact's effective mass is the plunger's, the TM being 130 times heavier) and only
    the lever arms move, ρ_i → ρ_i − δ, so Δω = −I_B⁻¹ (δ × Σ J_i) = −(6 / s_tm²) δ × v
    (I_B = m_tm s_tm² / 6, Σ J_i = m_tm v): Δω = G δ with
    G = (6 / s_tm²) [[0, −v_z], [v_z, 0], [−v_y, v_x]], and Cov = G (tm_offset² / 3) Gᵀ in
    the angular block (a uniform's variance; zero elsewhere). Checked against the exact
    impact in tests/flight/test_scenario.py."""
    v = np.asarray(v, float)
    k = 6.0 / s_tm ** 2
    z = np.zeros(v.shape[:-1])
    G = k * np.stack([np.stack([z, -v[..., 2]], -1), np.stack([v[..., 2], z], -1),
                      np.stack([-v[..., 1], v[..., 0]], -1)], -2)   # (..., 3, 2)
    out = np.zeros(v.shape[:-1] + (6, 6))
    out[..., 3:, 3:] = (tm_offset ** 2 / 3.0) * (G @ np.swapaxes(G, -1, -2))
    return out


def _state_per_set(frame: Frame, r: np.ndarray, t: np.ndarray):
    """contact_state with one body point per set: r (B, 3), t (B, 1) -> (B, 1, 3) arrays."""
    outs = [contact_state(Frame(frame.time, frame.A[b:b + 1], frame.Ad[b:b + 1],
                                frame.R[b:b + 1], frame.omega[b:b + 1], frame.G[b:b + 1],
                                frame.ok[b:b + 1]), r[b:b + 1], t[b:b + 1])
            for b in range(r.shape[0])]
    return tuple(np.concatenate([o[i] for o in outs]) for i in range(4))


# ----------------------------------------------------------------------------- truths
def default_window(pb) -> tuple[float, float]:
    """[t_c, t_c + 0.2 ms]: from the retraction command to the end of the paper's record (the
    impact-time window of the analysis, :mod:`gprm.flight.predicted`)."""
    tc = float(np.asarray(pb["t_c"]).ravel()[0])
    return (tc, tc + 0.2e-3)


SCENARIO_GRID_STEP = 1e-7
"""Grid step (s) of the plunger motion the gap rule and the contact state are read on."""


def scenario_grid(pb0, window=None, step: float = SCENARIO_GRID_STEP) -> np.ndarray:
    """The time grid of the scenarios: ``window`` (default [t_c, t_c + 0.2 ms], the window of
    the impact-time analysis) at ``step``; the first time is the head at rest (t_c)."""
    w = default_window(pb0) if window is None else window
    return np.arange(float(w[0]), float(w[1]) + 0.5 * step, step)


@dataclass(frozen=True)
class ScenarioTruth:
    """Synthetic truths of :func:`draw_truths` (R releases): ``scenario`` (R,) names,
    ``params`` {name: (R,)} (:data:`PARAMS` and :data:`OFFSETS`), ``t`` (R,) impact times
    (s), ``velocity`` (R, 6) the TM's :data:`COMPONENTS`, ``contacts`` (R,) how many contacts
    pushed."""

    scenario: tuple[str, ...]
    params: dict
    t: np.ndarray
    velocity: np.ndarray
    contacts: np.ndarray


def draw_truths(model, kinds, seed: int, prior: ScenarioPrior | None = None, *,
                spread: bool = True, window=None, max_rounds: int = 20) -> ScenarioTruth:
    """One truth per entry of ``kinds`` (scenario names): a parameter set drawn from the fit
    (``model.sample``; ``spread=False``: the best fit), the scenario's unknowns drawn from
    ``prior``, the impact time from the gap rule on that set's own motion, and the TM velocity
    after the impact (:func:`scenario_velocity`). A draw without an impact (the contact does
    not approach, or the impulse does not push) is drawn again."""
    from gprm.params import batch

    prior = prior or ScenarioPrior()
    kinds = list(kinds)
    for k in kinds:
        if k not in SCENARIOS:
            raise GprmInputError(f"must be one of {', '.join(SCENARIOS)}, got {k!r}",
                                 field="scenario")
    R = len(kinds)
    rng = np.random.default_rng(seed)
    pb0 = batch([model.params])
    grid = scenario_grid(pb0, window)
    done: dict[int, tuple] = {}
    for rnd in range(max_rounds):
        todo = [i for i in range(R) if i not in done]
        if not todo:
            break
        n = len(todo)
        pb = (model.sample(n, seed=seed * 1000 + rnd) if spread
              else {k: np.repeat(np.atleast_1d(v), n) for k, v in pb0.items()})
        frame = plunger_frame(body_motion(pb, grid, piezo=model.piezo))
        p = prior.draw(n, rng)
        for kind in sorted({kinds[i] for i in todo}):
            idx = [j for j, i in enumerate(todo) if kinds[i] == kind]
            sub = _subset_frame(frame, idx)
            pbs = {k: np.atleast_1d(v)[idx] if np.size(v) == n else v for k, v in pb.items()}
            ps = {k: v[idx] for k, v in p.items()}
            out = scenario_velocity(kind, sub, pbs, ps, prior, per_set=True)
            for jj, j in enumerate(idx):
                if out["ok"][jj, 0]:
                    v = np.array([out[c][jj, 0] for c in COMPONENTS])
                    nc = int(out["contacts"][jj, 0]) if "contacts" in out else 1
                    done[todo[j]] = ({k: float(ps[k][jj]) for k in PARAMS + OFFSETS},
                                     float(out["t"][jj, 0]), v, nc)
    if len(done) < R:
        raise GprmInputError("could not draw impacts for every release (the contact points "
                             "of too few parameter draws approach the indent)",
                             source=str(model.source))
    order = [done[i] for i in range(R)]
    return ScenarioTruth(tuple(kinds),
                         {k: np.array([o[0][k] for o in order]) for k in PARAMS + OFFSETS},
                         np.array([o[1] for o in order]), np.stack([o[2] for o in order]),
                         np.array([o[3] for o in order]))


def _subset_frame(frame: Frame, idx) -> Frame:
    return Frame(frame.time, frame.A[idx], frame.Ad[idx], frame.R[idx], frame.omega[idx],
                 frame.G[idx], frame.ok[idx])
