"""Body kinematics of the plunger assembly from a simulation: attitude, angular velocity and the
motion of any point of the plunger, the spacer or the tip (paper Eq. 8, docs/spec.md).

Stable API (other stages rely on these names):

``body_motion(source, times, *, piezo=2, voltage=None, sensitivities=()) -> PlungerMotion``
    ``source`` is a :class:`~gprm.params.ParameterSet`, a batch ``{name: (B,)}`` or a
    :class:`~gprm.fit.files.FittedModel` (its best-fit set). Simulates the exact linear model
    (``gprm.simulate.observe``) at ``times`` and returns a frozen :class:`PlungerMotion`:

    - ``time`` (T,), ``params`` (the batch, ``{name: (B,)}``), ``piezo``, ``ok`` (B,);
    - ``coords`` ``{z_lr, z_A, x_A, y_A, eta, theta, mu3, mu4: (B, T)}`` - changes from the
      initial static equilibrium at V(0) (plunger coordinates are zero there);
    - ``rates`` ``{z_lr_dot, ..., mu4_dot: (B, T)}`` - the simulated (exact) time derivatives;
    - ``mu_eq`` ``{mu3, mu4: (B,)}`` - the equilibrium extensions at V(0) (linear statics);
      ``mu3 + mu_eq["mu3"]`` is the absolute spacer coordinate;
    - ``R`` (B, T, 3, 3) - attitude R = R_x(theta) R_y(eta), exact rotations (docs/spec.md);
    - ``omega`` (B, 3, T) - angular velocity in the ground frame,
      omega = (theta', eta' cos(theta), eta' sin(theta)) (from R' R^T = [omega]x);
    - ``sens`` / ``sens_names`` - optional exact parameter sensitivities of ``coords`` and
      ``rates`` ``{name: (B, T, P)}`` (for linear uncertainty propagation).

``named_points(params) -> dict[str, BodyPoint]``
    The points the paper uses, for a parameter set or batch (B,):
    ``com`` plunger CoM r = (v2, g2, h2) (Eq. 8); ``M_xz`` = CoM + (dist_x, 0, dist_z);
    ``M_yz`` = CoM + (0, dist_y, dist_z) (Sec. 4, Fig. 9); ``tip_edge`` = h3 e_z + (h4 + mu4) u
    (moves with the tip coordinate mu4); ``spacer`` = h3 e_z + mu3 u; ``assembly_com`` the
    centre of mass of plunger + spacer + tip (mass m2 + m3 + m4; the impact model's plunger
    side), which moves with mu3 and mu4.

    A :class:`BodyPoint` is r(t) = r + (a3 mu3(t) + a4 mu4(t)) u in the plunger frame, with
    ``r`` (B, 3), ``a3``, ``a4`` (B,) and ``u`` (B, 3) the actuation axis
    u = (sin g, cos g sin rho, cos g cos rho); mu3, mu4 absolute (equilibrium + change).
    Plunger-fixed points have a3 = a4 = 0; the tip edge a4 = 1; the assembly CoM
    a3 = m3 / M, a4 = m4 / M.

``point_motion(motion, point, *, which="plunger", relative=False) -> (pos, vel)``
    Position and velocity (B, 3, T), ground frame, of a point: A + R r(t), A = (x_A, y_A,
    z_lr + z_A), the origin at point A at the initial equilibrium. ``point`` is a
    :class:`BodyPoint` or body coordinates (3,) / (B, 3); for raw coordinates ``which`` says
    what carries the point: ``"plunger"`` (fixed), ``"spacer"`` (+ mu3 u) or ``"tip"``
    (+ mu4 u). ``relative=True`` subtracts the point's initial equilibrium position (R = I,
    A = 0, mu at equilibrium), i.e. returns the displacement. Velocities come from the
    simulated rates by the chain rule, v = A' + omega x (R r) + R (a3 mu3' + a4 mu4') u - no
    finite differences.

``kinetic_energy(motion) -> dict[str, (B, T)]``
    Kinetic energy of each body (``m1``, ``m2`` translation, ``J2`` rotation, ``m3``, ``m4``)
    and ``total``, as in the model's Lagrangian.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from gprm.errors import GprmInputError
from gprm.model.coordinates import MECHANICAL
from gprm.model.linear import generated
from gprm.model.piezo import check_piezo
from gprm.params import ParameterSet, batch
from gprm.simulate.core import RATES, observe

MECH: tuple[str, ...] = MECHANICAL
"""The eight mechanical coordinates (gprm.model.coordinates)."""

POINTS: tuple[str, ...] = ("com", "M_xz", "M_yz", "tip_edge", "spacer", "assembly_com")


# ----------------------------------------------------------------------------- parameters
def as_batch(source) -> dict[str, np.ndarray]:
    """A parameter batch ``{name: (B,)}`` from a ParameterSet, a FittedModel or a batch."""
    if isinstance(source, ParameterSet):
        return batch([source])
    params = getattr(source, "params", None)
    if isinstance(params, ParameterSet):  # FittedModel
        return batch([params])
    if isinstance(source, Mapping):
        return batch(source)
    raise GprmInputError(f"expected a ParameterSet, FittedModel or batch, got {type(source)}",
                         field="params")


def actuation_axis(pb: Mapping[str, np.ndarray]) -> np.ndarray:
    """u (B, 3) = (sin g, cos g sin rho, cos g cos rho) in the plunger frame (docs/spec.md)."""
    g, r = np.asarray(pb["gamma"]), np.asarray(pb["rho"])
    return np.stack([np.sin(g), np.cos(g) * np.sin(r), np.cos(g) * np.cos(r)], axis=-1)


def rotation(theta, eta) -> np.ndarray:
    """R = R_x(theta) R_y(eta), shape (..., 3, 3) (docs/spec.md; gives Eq. 8)."""
    theta, eta = np.asarray(theta), np.asarray(eta)
    ct, st, ce, se = np.cos(theta), np.sin(theta), np.cos(eta), np.sin(eta)
    z = np.zeros_like(ct * ce)
    return np.stack([
        np.stack([ce + z, z, se + z], -1),
        np.stack([st * se, ct + z, -st * ce], -1),
        np.stack([-ct * se, st + z, ct * ce], -1),
    ], -2)


def angular_velocity(theta, eta_dot, theta_dot) -> np.ndarray:
    """omega (..., 3) ground frame for R = R_x(theta) R_y(eta): (theta', eta' cos, eta' sin)."""
    theta = np.asarray(theta)
    return np.stack([np.asarray(theta_dot) + 0 * theta, eta_dot * np.cos(theta),
                     eta_dot * np.sin(theta)], -1)


def motion_omega(coords: Mapping[str, np.ndarray],
                 rates: Mapping[str, np.ndarray]) -> np.ndarray:
    """omega (B, 3, T) from simulated coordinates and rates ``{name: (B, T)}``."""
    return np.moveaxis(angular_velocity(coords["theta"], rates["eta_dot"],
                                        rates["theta_dot"]), -1, 1)


def linear_statics(pb: Mapping[str, np.ndarray], piezo: int) -> dict[str, np.ndarray]:
    """Equilibrium mu3, mu4 (B,) at V0 (linear model, K x = Q V0)."""

    g = generated(piezo)
    M, C, K = g.linear_matrices({k: np.asarray(v) for k, v in pb.items()})
    K = np.asarray(K, float)
    Q = np.asarray(g.INPUT, float)
    V0 = np.atleast_1d(np.asarray(pb["V0"], float))
    if K.ndim == 2:
        K = K[None]
    B = max(V0.shape[0], K.shape[0])
    K = np.broadcast_to(K, (B,) + K.shape[-2:])
    V0 = np.broadcast_to(V0, (B,))
    x = np.linalg.solve(K, (Q[None, :] * V0[:, None])[..., None])[..., 0]
    idx = {c: i for i, c in enumerate(g.COORDINATES)}
    return {"mu3": x[:, idx["mu3"]], "mu4": x[:, idx["mu4"]]}


# ----------------------------------------------------------------------------- motion
@dataclass(frozen=True)
class PlungerMotion:
    """Simulated rigid-body motion of the plunger with its spacer and tip (see module doc)."""

    time: np.ndarray
    params: dict
    piezo: int
    coords: dict
    rates: dict
    mu_eq: dict
    R: np.ndarray
    omega: np.ndarray
    ok: np.ndarray
    sens: dict | None = None
    sens_names: tuple[str, ...] = ()

    @property
    def size(self) -> int:
        return int(self.ok.shape[0])


def check_times(times, *, t_max: float | None = None, field: str = "times") -> np.ndarray:
    """Times must be finite, >= 0 (the record starts at rest at t = 0), increasing, and within
    ``t_max`` when the input is only known up to there (a measured voltage trace)."""
    t = np.atleast_1d(np.asarray(times, float))
    if t.ndim != 1 or t.size == 0:
        raise GprmInputError("must be a non-empty 1-D array of times", field=field)
    if not np.all(np.isfinite(t)):
        raise GprmInputError("times must be finite", field=field)
    if t[0] < 0:
        raise GprmInputError(f"starts at {t[0]:g} s, before the simulation start (0 s)",
                             field=field)
    if t.size > 1 and np.any(np.diff(t) <= 0):
        raise GprmInputError("times must increase strictly", field=field)
    if t_max is not None and t[-1] > t_max * (1 + 1e-12):
        raise GprmInputError(f"ends at {t[-1]:g} s, after the end of the simulated input "
                             f"({t_max:g} s)", field=field)
    return t


def body_motion(source, times, *, piezo: int = 2, voltage=None,
                sensitivities: Sequence[str] = ()) -> PlungerMotion:
    """Simulate and return the plunger assembly's motion (see module docstring)."""

    check_piezo(piezo)
    pb = as_batch(source)
    t_max = None
    if voltage is not None:
        t_max = float(voltage.time[-1] + np.min(pb["t0"]))
    t = check_times(times, t_max=t_max)
    names = MECH + RATES
    obs = observe(pb, t, names, piezo=piezo, voltage=voltage,
                  sensitivities=tuple(sensitivities))
    k = {n: i for i, n in enumerate(names)}
    coords = {n: obs.y[:, k[n]] for n in MECH}
    rates = {n: obs.y[:, k[n]] for n in RATES}
    sens = None
    if sensitivities:
        assert obs.dy is not None  # observe() hands back dy whenever sensitivities are asked
        sens = {n: obs.dy[:, k[n]] for n in names}
    R = rotation(coords["theta"], coords["eta"])                       # (B, T, 3, 3)
    return PlungerMotion(time=t, params=pb, piezo=piezo, coords=coords, rates=rates,
                         mu_eq=linear_statics(pb, piezo), R=R,
                         omega=motion_omega(coords, rates), ok=obs.ok,
                         sens=sens, sens_names=tuple(sensitivities))


# ----------------------------------------------------------------------------- points
@dataclass(frozen=True)
class BodyPoint:
    """A point of the plunger assembly: r(t) = r + (a3 mu3(t) + a4 mu4(t)) u, plunger frame.

    r, u: (B, 3); a3, a4: (B,); mu3, mu4 absolute (equilibrium at V0 + simulated change).
    """

    name: str
    r: np.ndarray
    a3: np.ndarray
    a4: np.ndarray
    u: np.ndarray

    def body_coordinates(self, mu3, mu4) -> np.ndarray:
        """r(t) for absolute mu3, mu4 of shape (B,) or (B, T): (B, 3) or (B, 3, T)."""
        mu3, mu4 = np.asarray(mu3), np.asarray(mu4)
        s = self.a3.reshape((-1,) + (1,) * (mu3.ndim - 1)) * mu3 \
            + self.a4.reshape((-1,) + (1,) * (mu4.ndim - 1)) * mu4
        if s.ndim == 1:
            return self.r + s[:, None] * self.u
        return self.r[:, :, None] + s[:, None, :] * self.u[:, :, None]


def named_points(params) -> dict[str, BodyPoint]:
    """The paper's points for a parameter set / batch / FittedModel (see module docstring)."""
    pb = params if isinstance(params, Mapping) else as_batch(params)
    pb = {k: np.atleast_1d(np.asarray(v)) for k, v in pb.items()}
    B = np.broadcast(*pb.values()).shape[0]
    one = np.ones(B)
    zero = np.zeros(B)
    u = actuation_axis(pb) * one[:, None]
    com = np.stack([pb["v2"] * one, pb["g2"] * one, pb["h2"] * one], -1)
    ez = np.array([0.0, 0.0, 1.0])
    h3 = pb["h3"] * one
    h4 = pb["h4"] * one
    m2, m3, m4 = pb["m2"] * one, pb["m3"] * one, pb["m4"] * one
    M = m2 + m3 + m4
    asm = (m2[:, None] * com + (m3 + m4)[:, None] * h3[:, None] * ez
           + (m4 * h4)[:, None] * u) / M[:, None]
    dxz = np.stack([pb["dist_x"] * one, zero, pb["dist_z"] * one], -1)
    dyz = np.stack([zero, pb["dist_y"] * one, pb["dist_z"] * one], -1)
    return {
        "com": BodyPoint("com", com, zero, zero, u),
        "M_xz": BodyPoint("M_xz", com + dxz, zero, zero, u),
        "M_yz": BodyPoint("M_yz", com + dyz, zero, zero, u),
        "tip_edge": BodyPoint("tip_edge", h3[:, None] * ez + h4[:, None] * u, zero, one, u),
        "spacer": BodyPoint("spacer", h3[:, None] * ez + zero[:, None], one, zero, u),
        "assembly_com": BodyPoint("assembly_com", asm, m3 / M, m4 / M, u),
    }


def _as_point(motion: PlungerMotion, point, which: str) -> BodyPoint:
    if isinstance(point, BodyPoint):
        return point
    B = motion.size
    r = np.asarray(point, float)
    if r.shape == (3,):
        r = np.broadcast_to(r, (B, 3))
    if r.shape != (B, 3):
        raise GprmInputError(f"body point must have shape (3,) or ({B}, 3), got {r.shape}",
                             field="r_body")
    one, zero = np.ones(B), np.zeros(B)
    a = {"plunger": (zero, zero), "spacer": (one, zero), "tip": (zero, one)}
    if which not in a:
        raise GprmInputError(f"must be plunger, spacer or tip, got {which!r}", field="which")
    return BodyPoint("point", r.astype(float), *a[which], actuation_axis(motion.params) * one[:, None])


def point_motion(motion: PlungerMotion, point, *, which: str = "plunger",
                 relative: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Position and velocity (B, 3, T) of a point (see module docstring)."""
    bp = _as_point(motion, point, which)
    return _point_kinematics(bp, motion.coords, motion.rates, motion.mu_eq, relative)


def _point_kinematics(bp: BodyPoint, coords, rates, mu_eq, relative):
    """The closed-form kinematics; complex-safe (used with complex steps for sensitivities)."""
    c, d = coords, rates
    mu3 = c["mu3"] + mu_eq["mu3"][:, None]
    mu4 = c["mu4"] + mu_eq["mu4"][:, None]
    rb = bp.body_coordinates(mu3, mu4)                                   # (B, 3, T)
    R = rotation(c["theta"], c["eta"])                                   # (B, T, 3, 3)
    Rr = np.einsum("btij,bjt->bit", R, rb)                               # (B, 3, T)
    A = np.stack([c["x_A"], c["y_A"], c["z_lr"] + c["z_A"]], 1)
    pos = A + Rr
    Ad = np.stack([d["x_A_dot"], d["y_A_dot"], d["z_lr_dot"] + d["z_A_dot"]], 1)
    w = motion_omega(c, d)                                               # (B, 3, T)
    s_dot = bp.a3[:, None] * d["mu3_dot"] + bp.a4[:, None] * d["mu4_dot"]    # (B, T)
    Ru = np.einsum("btij,bj->bit", R, bp.u)
    vel = Ad + np.cross(w, Rr, axis=1) + s_dot[:, None, :] * Ru
    if relative:
        pos = pos - bp.body_coordinates(mu_eq["mu3"], mu_eq["mu4"])[:, :, None]
    return pos, vel


def static_position(motion: PlungerMotion, point, *, which: str = "plunger") -> np.ndarray:
    """Initial equilibrium position (B, 3) of a point (R = I, A = 0, mu at equilibrium)."""
    bp = _as_point(motion, point, which)
    return bp.body_coordinates(motion.mu_eq["mu3"], motion.mu_eq["mu4"])


# ----------------------------------------------------------------------------- energy
def kinetic_energy(motion: PlungerMotion) -> dict[str, np.ndarray]:
    """Kinetic energy (B, T) of each body, as in the model's Lagrangian (docs/spec.md):
    m1 z_lr'^2/2; m2 |v_G|^2/2; J2 (w_bx^2 + w_by^2)/2 with w_b = R^T omega (no spin term);
    m3 |v_spacer|^2/2; m4 |v_tip|^2/2 (spacer and tip as point masses)."""
    pb = motion.params
    pts = named_points(pb)
    out = {"m1": 0.5 * pb["m1"][:, None] * motion.rates["z_lr_dot"] ** 2}
    for key, body in (("m2", "com"), ("m3", "spacer"), ("m4", "tip_edge")):
        _, v = point_motion(motion, pts[body])
        out[key] = 0.5 * pb[key][:, None] * np.sum(v ** 2, axis=1)
    wb = np.einsum("btji,bjt->bit", motion.R, motion.omega)
    out["J2"] = 0.5 * pb["J2"][:, None] * (wb[:, 0] ** 2 + wb[:, 1] ** 2)
    out["total"] = out["m1"] + out["m2"] + out["J2"] + out["m3"] + out["m4"]
    return out
