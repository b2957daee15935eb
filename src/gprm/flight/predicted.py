"""Test-mass velocity as a function of the impact time (Section 4, Fig. 11b).

For every time t of a window, the plunger assembly's state at t (from the model's trajectory,
``gprm.simulate.kinematics``) strikes the test mass (TM), initially at rest, at the middle point
of the contact line (M_xz or M_yz) on an indent face; the planar impact of Appendix B
(:func:`gprm.flight.impact.planar_impact`) gives the TM velocity after the impact. The x–z plane
gives v_x, v_z, ω_y, the y–z plane v_y, v_z, ω_x: the six axes ``vx, vz_xz, wy, vy, vz_yz, wx``.
Since issue 14 the default is the one-contact 3D impact instead (:class:`ImpactGeometry`
``impact_model``; docs/flight.md §2), whose six axes are the TM's own components (both v_z
axes the one v_z).

Bodies (docs/spec.md):

* plunger side (A): the assembly plunger + spacer + tip, mass M = m2 + m3 + m4, CoM the
  assembly CoM (``named_points(...)["assembly_com"]``) with its velocity, angular velocity
  the plunger's ω, inertia J2 about the CoM (default; ``plunger_inertia="assembly"`` adds the
  spacer and tip point masses' parallel-axis terms about the assembly CoM);
* TM side (B): cube of mass ``m_tm`` and side ``s_tm``, inertia m s²/6, at rest, CoM at the
  plunger CoM's lateral position at rest and ``tm_com_height`` above the contact points
  (an assumption: the indent's depth is not given by the paper);
* contact point: M_xz (M_yz) plus a settable offset, at its position at t; contact normal (the
  impulse direction on the TM) fixed with the TM: n = (sgn(dist_x) sin α, 0, cos α) in the
  x–z plane and (0, sgn(dist_y) sin α, cos α) in the y–z plane, α = ``indent_angle``.

An impact can happen at t only if the contact point approaches the face (relative normal
velocity < 0); elsewhere the curves are NaN (``approaching`` False).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from gprm.errors import GprmInputError
from gprm.flight.impact import _perp, impact_3d, planar_impact
from gprm.flight.scenario import (COMPARED, Frame, ScenarioPrior,
                                  default_window, plunger_frame, scenario_velocity)
from gprm.flight.telemetry import AXES
from gprm.params import batch
from gprm.simulate.kinematics import body_motion, named_points, point_motion, static_position

IMPACT_MODELS = ("3d", "planar") + COMPARED
"""The impact models of the curves: the corner contact, the paper's planes, and the
rim-contact scenarios of :mod:`gprm.flight.scenario`."""

PLANES = ("xz", "yz")
PLANE_AXES = {"xz": ("vx", "vz_xz", "wy"), "yz": ("vy", "vz_yz", "wx")}


@dataclass(frozen=True)
class ImpactGeometry:
    """Impact geometry and model options (SI). ``None`` values come from the parameters
    (``indent_angle`` registry value, ``tm_com_height`` = s_tm/2 − ``indent_depth``).

    ``impact_model``: ``"3d"`` (default) one contact of the plunger tip corner on the indent
    face, one impulse, restitution and Coulomb friction ``friction`` (nominal 0.1, an
    assumption; :func:`_tm_velocity_3d`); ``"planar"`` the paper's two independent planar
    impacts (Appendix B) at M_xz and M_yz (frictionless). ``contact_offset_3d`` moves the 3D
    contact point, ``contact_offset_xz``/``_yz`` the planar ones. ``"xz"``, ``"yz"``, ``"two"``:
    the rim-contact scenarios of :mod:`gprm.flight.scenario` (issue 23) at ``contact_height``
    and ``azimuth``, with ``friction`` and ``restitution`` (:func:`scenario_geometry` gives
    their nominal values, the middle of :class:`~gprm.flight.scenario.ScenarioPrior`)."""

    indent_angle: float | None = None
    indent_depth: float = 3.0e-3
    tm_com_height: float | None = None
    contact_offset_xz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    contact_offset_yz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    restitution: float = 1.0
    plunger_inertia: str = "J2"
    plunger_velocity: str = "plunger"
    impact_model: str = "3d"
    friction: float = 0.1
    contact_offset_3d: tuple[float, float, float] = (0.0, 0.0, 0.0)
    contact_height: float = 0.0
    azimuth: float = 0.0

    def resolved(self, pb) -> "ImpactGeometry":
        ang = float(np.asarray(pb["indent_angle"]).ravel()[0]) if self.indent_angle is None \
            else self.indent_angle
        h = (float(np.asarray(pb["s_tm"]).ravel()[0]) / 2 - self.indent_depth
             if self.tm_com_height is None else self.tm_com_height)
        return replace(self, indent_angle=ang, tm_com_height=h)


@dataclass(frozen=True)
class GeometryUncertainty:
    """Standard deviations of the impact geometry (defaults: our assumptions, docs/flight.md):
    indent angle 2°, each contact-point offset component 0.5 mm, TM CoM height 0.5 mm,
    restitution 0 (fixed at its value), friction coefficient 0.05 about the nominal 0.1 of
    :class:`ImpactGeometry` (clipped at 0; 3D model only)."""

    indent_angle: float = np.deg2rad(2.0)
    contact_offset: float = 0.5e-3
    tm_com_height: float = 0.5e-3
    restitution: float = 0.0
    friction: float = 0.05


def tm_velocity_vs_time(motion, geometry: ImpactGeometry | list | None = None) -> dict:
    """Post-impact TM velocities if the impact happened at each time of ``motion``.

    ``motion`` is a :class:`gprm.simulate.kinematics.PlungerMotion` (B parameter sets, T times).
    ``geometry`` is one :class:`ImpactGeometry` or a list of B of them (one per set). Returns
    ``{axis: (B, T)}`` for the six axes (NaN where no impact is possible), plus
    ``approaching_xz``, ``approaching_yz`` (B, T) booleans and ``impulse_xz``, ``impulse_yz``
    (B, T) normal impulses, N·s.
    """

    pb = motion.params
    B, T = motion.size, motion.time.size
    geoms = geometry if isinstance(geometry, (list, tuple)) else [geometry or ImpactGeometry()] * B
    if len(geoms) != B:
        raise GprmInputError(f"{len(geoms)} geometries for {B} parameter sets", field="geometry")
    kinds = {g.impact_model for g in geoms}
    if len(kinds) != 1 or not kinds <= set(IMPACT_MODELS):
        raise GprmInputError(f"must be one of {', '.join(IMPACT_MODELS)} for all sets",
                             field="impact_model")
    if kinds == {"3d"}:
        return _tm_velocity_3d(motion, geoms)
    if kinds <= set(COMPARED):
        return _tm_velocity_scenario(motion, geoms)
    geoms = [g.resolved({k: v[i:i + 1] for k, v in pb.items()}) for i, g in enumerate(geoms)]
    alpha = np.array([g.indent_angle for g in geoms])
    H = np.array([g.tm_com_height for g in geoms])
    e = np.array([g.restitution for g in geoms])
    off = {"xz": np.array([g.contact_offset_xz for g in geoms]),
           "yz": np.array([g.contact_offset_yz for g in geoms])}
    pts = named_points(pb)
    asm = pts["assembly_com"]
    G, vG = point_motion(motion, asm)                       # (B, 3, T)
    w = motion.omega                                         # (B, 3, T)
    modes = {g.plunger_velocity for g in geoms}
    if len(modes) != 1 or not modes <= {"plunger", "assembly"}:
        raise GprmInputError("must be one of 'plunger', 'assembly' for all sets",
                             field="plunger_velocity")
    vel_mode = modes.pop()
    m2, m3, m4 = pb["m2"], pb["m3"], pb["m4"]
    Mp = m2 + m3 + m4
    J = np.broadcast_to(pb["J2"], (B,)).astype(float).copy()
    if any(g.plunger_inertia not in ("J2", "assembly") for g in geoms):
        raise GprmInputError("must be 'J2' or 'assembly'", field="plunger_inertia")
    m_tm, s_tm = pb["m_tm"], pb["s_tm"]
    I_tm = m_tm * s_tm ** 2 / 6.0
    # TM CoM at rest: plunger CoM lateral position, tm_com_height above the contact points
    com0 = pts["com"].r                                      # (B, 3) body frame = ground at rest
    # assembly inertia option: parallel-axis terms of spacer and tip (point masses); the
    # static positions do not depend on the plane
    use = np.array([g.plunger_inertia == "assembly" for g in geoms])
    if use.any():
        gA = static_position(motion, asm)
        masses_at = tuple((m, static_position(motion, pts[n]))
                          for m, n in ((m2, "com"), (m3, "spacer"), (m4, "tip_edge")))
    out = {}
    for plane in PLANES:
        key = "M_xz" if plane == "xz" else "M_yz"
        bp = pts[key]
        r_c = bp.r + off[plane]                              # body coordinates of contact
        P, vP = point_motion(motion, r_c)                    # (B, 3, T)
        C_tm = np.stack([com0[:, 0], com0[:, 1], bp.r[:, 2] + H], -1)   # (B, 3)
        Jp = J.copy()
        if use.any():
            ax = 0 if plane == "xz" else 1                  # lateral axis of the plane
            par = sum(m * ((p - gA)[:, ax] ** 2 + (p - gA)[:, 2] ** 2) for m, p in masses_at)
            Jp = np.where(use, J + par, J)
        if plane == "xz":
            idx, wk, sgn = (2, 0), 1, np.sign(np.broadcast_to(pb["dist_x"], (B,)))
        else:
            idx, wk, sgn = (1, 2), 0, np.sign(np.broadcast_to(pb["dist_y"], (B,)))
        sgn = np.where(sgn == 0, 1.0, sgn)
        if plane == "xz":   # (a, b) = (z, x)
            n2 = np.stack([np.cos(alpha), sgn * np.sin(alpha)], -1)
        else:               # (a, b) = (y, z)
            n2 = np.stack([sgn * np.sin(alpha), np.cos(alpha)], -1)
        sel = list(idx)
        rhoA = np.moveaxis((P - G)[:, sel, :], 1, -1)        # (B, T, 2)
        wA = w[:, wk, :]
        if vel_mode == "plunger":
            # rigid field of the plunger body: the contact point keeps its exact velocity
            vA = np.moveaxis(vP[:, sel, :], 1, -1) - _perp(wA, rhoA)
        else:
            vA = np.moveaxis(vG[:, sel, :], 1, -1)
        rhoB = np.moveaxis(P[:, sel, :] - C_tm[:, sel, None], 1, -1)
        zero2 = np.zeros((B, T, 2))
        res = planar_impact(Mp[:, None], Jp[:, None], rhoA, vA, wA,
                            m_tm[:, None], I_tm[:, None], rhoB, zero2, np.zeros((B, T)),
                            n2[:, None, :], e[:, None])
        ok = (res.vn_before < 0) & motion.ok[:, None]
        vB = np.where(ok[..., None], res.vB, np.nan)
        wB = np.where(ok, res.wB, np.nan)
        comp = dict(zip(("a", "b"), (vB[..., 0], vB[..., 1])))
        if plane == "xz":
            out["vx"], out["vz_xz"], out["wy"] = comp["b"], comp["a"], wB
        else:
            out["vy"], out["vz_yz"], out["wx"] = comp["a"], comp["b"], wB
        out[f"approaching_{plane}"] = ok
        out[f"impulse_{plane}"] = np.where(ok, res.P, np.nan)
    return out


def _tm_velocity_3d(motion, geoms) -> dict:
    """The one-contact 3D impact (:class:`ImpactGeometry` ``impact_model="3d"``).

    Contact point: the plunger tip corner M = C_p + (dist_x, dist_y, dist_z) +
    ``contact_offset_3d``, C_p the plunger CoM (its projections on the x–z and y–z planes are
    M_xz and M_yz). Normal (impulse direction on the TM), fixed with the TM: n ∝ (sgn(dist_x) tan α, sgn(dist_y) tan α, 1), the face whose
    traces in the two planes are the planar indent lines. Plunger: m2 + m3 + m4 with the
    isotropic inertia J2·1 about the assembly CoM (``plunger_inertia="assembly"`` adds the spacer
    and tip point masses' parallel-axis tensor), velocity field of the plunger body. TM: the cube
    at rest. :func:`gprm.flight.impact.impact_3d` with restitution e and Coulomb friction μ.

    With one impulse J at ρ from the TM's CoM, v = J/m and ω = ρ × J / I (the cube's inertia is
    isotropic), so the in-plane quantities of each plane are the 3D components: both planes' v_z
    axes carry the one v_z, ω_y (x–z) and ω_x (y–z) are the 3D components (docs/flight.md §2).
    """

    pb = motion.params
    B, T = motion.size, motion.time.size
    geoms = [g.resolved({k: v[i:i + 1] for k, v in pb.items()}) for i, g in enumerate(geoms)]
    if any(g.plunger_inertia not in ("J2", "assembly") for g in geoms):
        raise GprmInputError("must be 'J2' or 'assembly'", field="plunger_inertia")
    if any(g.plunger_velocity not in ("plunger", "assembly") for g in geoms):
        raise GprmInputError("must be one of 'plunger', 'assembly' for all sets",
                             field="plunger_velocity")
    alpha = np.array([g.indent_angle for g in geoms])
    H = np.array([g.tm_com_height for g in geoms])
    e = np.array([g.restitution for g in geoms])
    mu = np.array([g.friction for g in geoms])
    if np.any(mu < 0) or np.any((e < 0) | (e > 1)):
        raise GprmInputError("friction must be >= 0 and restitution in [0, 1]",
                             field="friction")
    off = np.array([g.contact_offset_3d for g in geoms])
    pts = named_points(pb)
    asm = pts["assembly_com"]
    G, vG = point_motion(motion, asm)                       # (B, 3, T)
    w = np.moveaxis(motion.omega, 1, -1)                     # (B, T, 3)
    Mp = pb["m2"] + pb["m3"] + pb["m4"]
    eye = np.eye(3)
    IA = np.broadcast_to(pb["J2"], (B,)).astype(float)[:, None, None] * eye   # (B, 3, 3)
    use = np.array([g.plunger_inertia == "assembly" for g in geoms])
    if use.any():
        gA = static_position(motion, asm)
        for m, nm in ((pb["m2"], "com"), (pb["m3"], "spacer"), (pb["m4"], "tip_edge")):
            d = static_position(motion, pts[nm]) - gA       # (B, 3)
            par = m[:, None, None] * (np.sum(d * d, -1)[:, None, None] * eye
                                      - d[:, :, None] * d[:, None, :])
            IA = np.where(use[:, None, None], IA + par, IA)
    m_tm, s_tm = pb["m_tm"], pb["s_tm"]
    I_tm = (m_tm * s_tm ** 2 / 6.0)[:, None, None] * eye
    com0 = pts["com"].r
    dist = np.stack([np.broadcast_to(pb[k], (B,)) for k in ("dist_x", "dist_y", "dist_z")], -1)
    r_c = com0 + dist + off                                  # body coordinates of the corner
    P, vP = point_motion(motion, r_c)                        # (B, 3, T)
    C_tm = np.stack([com0[:, 0], com0[:, 1], pts["M_xz"].r[:, 2] + H], -1)
    sx = np.sign(dist[:, 0])
    sy = np.sign(dist[:, 1])
    sx, sy = np.where(sx == 0, 1.0, sx), np.where(sy == 0, 1.0, sy)
    n = np.stack([sx * np.tan(alpha), sy * np.tan(alpha), np.ones(B)], -1)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    rhoA = np.moveaxis(P - G, 1, -1)                         # (B, T, 3)
    if geoms[0].plunger_velocity == "plunger":
        vA = np.moveaxis(vP, 1, -1) - np.cross(w, rhoA)
    else:
        vA = np.moveaxis(vG, 1, -1)
    rhoB = np.moveaxis(P, 1, -1) - C_tm[:, None, :]
    zero3 = np.zeros((B, T, 3))
    res = impact_3d(Mp[:, None], IA[:, None], rhoA, vA, w, m_tm[:, None], I_tm[:, None],
                    rhoB, zero3, zero3, n[:, None, :], e[:, None], mu[:, None])
    assert res.mode is not None  # impact_3d always says how each impact resolved
    un = np.sum(res.u_before * n[:, None, :], axis=-1)
    ok = (un < 0) & (res.Jn > 0) & motion.ok[:, None]
    vB = np.where(ok[..., None], res.vB, np.nan)
    wB = np.where(ok[..., None], res.wB, np.nan)
    out = {"vx": vB[..., 0], "vy": vB[..., 1], "vz_xz": vB[..., 2], "vz_yz": vB[..., 2].copy(),
           "wx": wB[..., 0], "wy": wB[..., 1], "wz": wB[..., 2],
           "approaching_xz": ok, "approaching_yz": ok.copy(),
           "impulse_xz": np.where(ok, res.Jn, np.nan), "impulse_yz": np.where(ok, res.Jn, np.nan),
           "mode": np.where(ok, res.mode, -1)}
    return out


def scenario_geometry(kind: str, prior: ScenarioPrior | None = None) -> ImpactGeometry:
    """The nominal geometry of scenario impact model ``kind`` (``xz``, ``yz``, ``two``): the
    middle of each unknown's prior (contact height 0, azimuth 0, friction and restitution the
    middles of their ranges). Any other impact model: its default geometry."""
    if kind not in COMPARED:
        return ImpactGeometry(impact_model=kind)
    pr = prior or ScenarioPrior()
    return ImpactGeometry(impact_model=kind, friction=float(np.mean(pr.friction)),
                          restitution=float(np.mean(pr.restitution)))


def _tm_velocity_scenario(motion, geoms) -> dict:
    """The rim-contact scenarios (:class:`ImpactGeometry` ``impact_model`` ``xz``, ``yz``,
    ``two``): :func:`gprm.flight.scenario.scenario_velocity` at every time of the motion
    (the impact as if it happened there; no gap rule), per parameter set with its geometry."""
    pb = motion.params
    B, T = motion.size, motion.time.size
    kind = geoms[0].impact_model
    frame = plunger_frame(motion)
    keys = ("vx", "vy", "vz", "wx", "wy", "wz")
    out = {k: np.full((B, T), np.nan) for k in keys}
    ok = np.zeros((B, T), bool)
    prior = ScenarioPrior()
    for b, g in enumerate(geoms):
        sub = Frame(frame.time, frame.A[b:b + 1], frame.Ad[b:b + 1], frame.R[b:b + 1],
                    frame.omega[b:b + 1], frame.G[b:b + 1], frame.ok[b:b + 1])
        p = {"f": np.full(T, 0.5), "s": np.full(T, g.contact_height),
             "phi": np.full(T, g.azimuth), "mu": np.full(T, g.friction),
             "e": np.full(T, g.restitution)}
        r = scenario_velocity(kind, sub, {k: np.atleast_1d(v)[b:b + 1] for k, v in pb.items()},
                              p, prior, times=motion.time[None, :])
        for k in keys:
            out[k][b] = r[k][0]
        ok[b] = r["ok"][0]
    res = {"vx": out["vx"], "vy": out["vy"], "vz_xz": out["vz"], "vz_yz": out["vz"].copy(),
           "wx": out["wx"], "wy": out["wy"], "wz": out["wz"],
           "approaching_xz": ok, "approaching_yz": ok.copy(),
           "impulse_xz": np.full((B, T), np.nan), "impulse_yz": np.full((B, T), np.nan)}
    return res


def sample_geometries(geometry: ImpactGeometry, unc: GeometryUncertainty, n: int, seed: int,
                      pb) -> list[ImpactGeometry]:
    """``n`` geometries drawn from independent normals about ``geometry`` (resolved with ``pb``).
    The indent angle is kept in (0, 90°), the restitution in [0, 1] and the friction
    coefficient >= 0 by clipping."""
    g0 = geometry.resolved(pb)
    assert g0.indent_angle is not None and g0.tm_com_height is not None  # resolved
    rng = np.random.default_rng(seed)
    if g0.impact_model in COMPARED:     # the scenario's own prior (issue 23)
        d = ScenarioPrior().draw(n, rng)
        return [replace(g0, contact_height=float(d["s"][i]), azimuth=float(d["phi"][i]),
                        friction=float(d["mu"][i]), restitution=float(d["e"][i]))
                for i in range(n)]
    out = []
    for _ in range(n):
        a = float(np.clip(g0.indent_angle + unc.indent_angle * rng.standard_normal(),
                          1e-3, np.pi / 2 - 1e-3))
        oxz = tuple(np.asarray(g0.contact_offset_xz) + unc.contact_offset * rng.standard_normal(3))
        oyz = tuple(np.asarray(g0.contact_offset_yz) + unc.contact_offset * rng.standard_normal(3))
        h = g0.tm_com_height + unc.tm_com_height * rng.standard_normal()
        e = float(np.clip(g0.restitution + unc.restitution * rng.standard_normal(), 0.0, 1.0))
        o3 = tuple(np.asarray(g0.contact_offset_3d) + unc.contact_offset * rng.standard_normal(3))
        mu = float(max(g0.friction + unc.friction * rng.standard_normal(), 0.0))
        out.append(replace(g0, indent_angle=a, contact_offset_xz=oxz, contact_offset_yz=oyz,
                           tm_com_height=h, restitution=e, contact_offset_3d=o3, friction=mu))
    return out


@dataclass(frozen=True)
class VelocityCurves:
    """Predicted TM velocity vs impact time with its bands (Fig. 11b).

    ``time`` (T,) s from the start of the retraction record; ``nominal[axis]`` (T,) from the
    best-fit parameters and nominal geometry; ``sigma_fit``, ``sigma_geometry`` (T,) standard
    deviations over the parameter samples (fit covariance) and the geometry samples;
    ``sigma`` their quadrature sum; ``lo``, ``hi`` the 2.5 and 97.5 % points of the joint
    samples (both sources drawn together), ``samples`` those joint draws themselves (axis ->
    (n_samples, T)), from which the impact times' spread and covariance are taken.
    NaN where no impact is possible.
    """

    time: np.ndarray
    nominal: dict
    sigma_fit: dict
    sigma_geometry: dict
    sigma: dict
    lo: dict
    hi: dict
    approaching: dict            # plane -> (T,) nominal
    plausible: np.ndarray        # (T,) fraction of joint samples approaching in both planes
    n_samples: int
    seed: int
    meta: dict = field(default_factory=dict)
    samples: dict | None = None  # axis -> (n_samples, T) joint draws (impact-time spread)


def _nanstd(a):
    with np.errstate(invalid="ignore"), _quiet():
        return np.nanstd(a, axis=0, ddof=1)


class _quiet:
    def __enter__(self):
        import warnings
        self._w = warnings.catch_warnings()
        self._w.__enter__()
        warnings.simplefilter("ignore", RuntimeWarning)

    def __exit__(self, *a):
        return self._w.__exit__(*a)


def _repeat_motion(motion, n: int):
    """A one-set motion as ``n`` identical sets (the best fit under ``n`` geometry draws),
    without simulating it again."""
    def rep(d):
        return {k: np.repeat(v, n, axis=0) for k, v in d.items()}

    return replace(motion, params=rep(motion.params), coords=rep(motion.coords),
                   rates=rep(motion.rates), mu_eq=rep(motion.mu_eq),
                   R=np.repeat(motion.R, n, axis=0), omega=np.repeat(motion.omega, n, axis=0),
                   ok=np.repeat(motion.ok, n))


def velocity_curves(model, *, window=None, n_times: int = 401, n_samples: int = 200,
                    seed: int = 0, geometry: ImpactGeometry | None = None,
                    uncertainty: GeometryUncertainty | None = None, voltage=None
                    ) -> VelocityCurves:
    """Nominal curves and uncertainty bands for a :class:`~gprm.fit.files.FittedModel`.

    Three batches are simulated: the best fit (nominal), ``n_samples`` draws from the fit
    covariance (``FittedModel.sample``) with nominal geometry, ``n_samples`` nominal-parameter
    runs with geometry draws (:class:`GeometryUncertainty`), and ``n_samples`` joint draws
    (for the percentile band and the plausibility fraction).
    """

    geometry = geometry or ImpactGeometry()
    uncertainty = uncertainty or GeometryUncertainty()
    pb0 = batch([model.params])
    if window is None:
        window = default_window(pb0)
    t = np.linspace(float(window[0]), float(window[1]), int(n_times))
    nom_m = body_motion(pb0, t, piezo=model.piezo, voltage=voltage)
    nom = tm_velocity_vs_time(nom_m, geometry)
    pf = model.sample(n_samples, seed=seed)
    fit_c = tm_velocity_vs_time(body_motion(pf, t, piezo=model.piezo, voltage=voltage),
                                geometry)
    geos = sample_geometries(geometry, uncertainty, n_samples, seed + 1, pb0)
    geo_c = tm_velocity_vs_time(_repeat_motion(nom_m, n_samples), geos)
    pj = model.sample(n_samples, seed=seed + 2)
    geos_j = sample_geometries(geometry, uncertainty, n_samples, seed + 3, pb0)
    joint = tm_velocity_vs_time(body_motion(pj, t, piezo=model.piezo, voltage=voltage), geos_j)
    sf = {a: _nanstd(fit_c[a]) for a in AXES}
    sg = {a: _nanstd(geo_c[a]) for a in AXES}
    with _quiet():
        lo = {a: np.nanpercentile(joint[a], 2.5, axis=0) for a in AXES}
        hi = {a: np.nanpercentile(joint[a], 97.5, axis=0) for a in AXES}
    plaus = np.mean(joint["approaching_xz"] & joint["approaching_yz"], axis=0)
    return VelocityCurves(
        time=t, nominal={a: nom[a][0] for a in AXES}, sigma_fit=sf, sigma_geometry=sg,
        sigma={a: np.sqrt(sf[a] ** 2 + sg[a] ** 2) for a in AXES}, lo=lo, hi=hi,
        approaching={p: nom[f"approaching_{p}"][0] for p in PLANES}, plausible=plaus,
        n_samples=int(n_samples), seed=int(seed),
        meta={"geometry": geometry.resolved(pb0), "uncertainty": uncertainty,
              "piezo": model.piezo, "source": model.source,
              "impact_model": geometry.impact_model,
              "has_uncertainty": bool(getattr(model, "has_uncertainty", True))},
        samples={a: joint[a] for a in AXES})
