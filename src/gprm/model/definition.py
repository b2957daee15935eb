"""Model definitions: kinematics and energies of the GPRM plunger, from which the equations of
motion are derived (``docs/spec.md``; paper Sec. 3, Eq. 1-3, Appendix A).

A :class:`ModelDefinition` is pure data plus a function that builds the Lagrangian pieces with
SymPy. A model variant (another piezo, the linear runner's lateral vibration, ...) is a new
definition; the derivation, code generation, simulator and fitter are shared.

Coordinates (9): ``z_lr`` linear-runner axial displacement; ``z_A`` plunger back (point A) axial
displacement relative to the linear runner; ``x_A, y_A`` lateral displacements of A; ``eta``
rotation about y; ``theta`` rotation about x; ``mu3, mu4`` spacer and tip displacements relative
to the plunger along the actuation axis; ``q`` piezo charge (first order: no inertia).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import sympy as sp

from gprm.model.coordinates import COORDINATES, MECHANICAL  # the names live there (no SymPy)

# Parameters that appear in the equations of motion (all others act through the input, the
# lags or the output maps).
EOM_PARAMETERS: tuple[str, ...] = (
    "v2", "g2", "h2", "gamma", "rho", "k_lr", "k_Az", "k_Ax", "k_Bx", "c_Ax", "c_Bx",
    "k_Cy", "k_Dy", "c_Cy", "c_Dy", "m1", "m2", "m3", "m4", "J2", "d1", "d2", "b1", "b2",
    "h3", "h4", "k3", "k4", "c1", "c3", "T_em", "C_a", "R",
)
OUTPUT_PARAMETERS: tuple[str, ...] = ("d_x_base", "d_x_head", "d_y_base", "d_y_head")


@dataclass(frozen=True)
class Energies:
    """SymPy expressions of the Lagrangian pieces, in terms of coordinate symbols ``x``,
    their rates ``xd`` and parameter symbols ``p``.

    T: kinetic energy; U: potential (springs and piezo electro-mechanical energy);
    D: Rayleigh dissipation (dampers and circuit resistance); input_force: generalised force
    per coordinate multiplying the voltage V (only q: V).
    """

    T: sp.Expr
    U: sp.Expr
    D: sp.Expr
    input_force: dict


@dataclass(frozen=True)
class ModelDefinition:
    name: str
    piezo: int
    description: str
    build: Callable[["Symbols"], Energies]
    first_order: tuple[str, ...] = ("q",)
    coordinates: tuple[str, ...] = COORDINATES


@dataclass(frozen=True)
class Symbols:
    x: dict = field(default_factory=dict)    # coordinate -> Symbol
    xd: dict = field(default_factory=dict)   # coordinate -> Symbol for its rate
    p: dict = field(default_factory=dict)    # parameter -> Symbol


def make_symbols(coordinates=COORDINATES, parameters=EOM_PARAMETERS) -> Symbols:
    x = {c: sp.Symbol(c, real=True) for c in coordinates}
    xd = {c: sp.Symbol(f"{c}_d", real=True) for c in coordinates}
    p = {n: sp.Symbol(n, real=True) for n in parameters}
    return Symbols(x, xd, p)


def rotation(theta, eta) -> sp.Matrix:
    """Plunger attitude R = R_x(theta) R_y(eta) (docs/spec.md; reproduces the paper's Eq. 8)."""
    ct, st, ce, se = sp.cos(theta), sp.sin(theta), sp.cos(eta), sp.sin(eta)
    Rx = sp.Matrix([[1, 0, 0], [0, ct, -st], [0, st, ct]])
    Ry = sp.Matrix([[ce, 0, se], [0, 1, 0], [-se, 0, ce]])
    return Rx * Ry


def actuation_axis(gamma, rho) -> sp.Matrix:
    """Unit vector u of the spacer/tip motion in the plunger frame (docs/spec.md)."""
    return sp.Matrix([sp.sin(gamma), sp.cos(gamma) * sp.sin(rho), sp.cos(gamma) * sp.cos(rho)])


def _velocity(pos: sp.Matrix, s: Symbols, coords) -> sp.Matrix:
    """Time derivative of a position expression by the chain rule over the coordinates."""
    return sum((pos.diff(s.x[c]) * s.xd[c] for c in coords), sp.zeros(*pos.shape))


def _gprm_energies(s: Symbols, piezo: int) -> Energies:
    x, xd, p = s.x, s.xd, s.p
    mech = MECHANICAL
    R = rotation(x["theta"], x["eta"])
    A = sp.Matrix([x["x_A"], x["y_A"], x["z_lr"] + x["z_A"]])
    ez = sp.Matrix([0, 0, 1])
    u = actuation_axis(p["gamma"], p["rho"])

    def body_point(r):
        return A + R * r

    r_cm = sp.Matrix([p["v2"], p["g2"], p["h2"]])
    r3 = p["h3"] * ez + x["mu3"] * u
    r4 = p["h3"] * ez + (p["h4"] + x["mu4"]) * u

    v_cm = _velocity(body_point(r_cm), s, mech)
    v3 = _velocity(body_point(r3), s, mech)
    v4 = _velocity(body_point(r4), s, mech)

    # Angular velocity: skew(omega_space) = R' R^T; body frame omega_b = R^T omega_space.
    Rd = _velocity(R, s, mech)
    W = sp.simplify(Rd * R.T)
    w_space = sp.Matrix([W[2, 1], W[0, 2], W[1, 0]])
    w_body = sp.simplify(R.T * w_space)
    # Axisymmetric plunger: transverse inertia J2 about its CoM; the spin about its own axis is
    # neglected (paper Sec. 3), so the axial inertia does not enter.
    T_rot = sp.Rational(1, 2) * p["J2"] * (w_body[0] ** 2 + w_body[1] ** 2)

    T = (sp.Rational(1, 2) * p["m1"] * xd["z_lr"] ** 2
         + sp.Rational(1, 2) * p["m2"] * (v_cm.T * v_cm)[0]
         + T_rot
         + sp.Rational(1, 2) * p["m3"] * (v3.T * v3)[0]
         + sp.Rational(1, 2) * p["m4"] * (v4.T * v4)[0])

    # Lateral springs/dampers act on the plunger axis point at distance d from A; exact
    # kinematics here (x: x_A + d sin(eta); y: y_A - d cos(eta) sin(theta)), which linearise to
    # docs/spec.md's x_A + d*eta and y_A - d*theta.
    def axis_x(d):
        return body_point(d * ez)[0]

    def axis_y(d):
        return body_point(d * ez)[1]

    dA, dB = p["d1"], p["d1"] + p["d2"]
    bC, bD = p["b1"], p["b1"] + p["b2"]
    xa, xb, yc, yd = axis_x(dA), axis_x(dB), axis_y(bC), axis_y(bD)
    if piezo == 2:
        stroke = x["mu3"]
    elif piezo == 1:
        stroke = x["mu4"] - x["mu3"]
    else:
        raise ValueError("piezo must be 1 or 2")
    U = (sp.Rational(1, 2) * p["k_lr"] * x["z_lr"] ** 2
         + sp.Rational(1, 2) * p["k_Az"] * x["z_A"] ** 2
         + sp.Rational(1, 2) * p["k_Ax"] * xa ** 2 + sp.Rational(1, 2) * p["k_Bx"] * xb ** 2
         + sp.Rational(1, 2) * p["k_Cy"] * yc ** 2 + sp.Rational(1, 2) * p["k_Dy"] * yd ** 2
         + sp.Rational(1, 2) * p["k3"] * x["mu3"] ** 2
         + sp.Rational(1, 2) * p["k3"] * (x["mu4"] - x["mu3"]) ** 2
         + sp.Rational(1, 2) * p["k4"] * x["mu4"] ** 2
         # Piezo (Eq. 1, A.9): electro-mechanical energy (q - T_em*stroke)^2 / (2 C_a).
         + (x["q"] - p["T_em"] * stroke) ** 2 / (2 * p["C_a"]))

    def rate(e):
        return sum(e.diff(s.x[c]) * s.xd[c] for c in mech)

    D = (sp.Rational(1, 2) * p["c_Ax"] * rate(xa) ** 2
         + sp.Rational(1, 2) * p["c_Bx"] * rate(xb) ** 2
         + sp.Rational(1, 2) * p["c_Cy"] * rate(yc) ** 2
         + sp.Rational(1, 2) * p["c_Dy"] * rate(yd) ** 2
         + sp.Rational(1, 2) * p["c1"] * xd["mu3"] ** 2
         + sp.Rational(1, 2) * p["c3"] * (xd["mu4"] - xd["mu3"]) ** 2
         + sp.Rational(1, 2) * p["R"] * xd["q"] ** 2)
    return Energies(T=T, U=U, D=D, input_force={"q": sp.Integer(1)})


GPRM_PIEZO2 = ModelDefinition(
    name="gprm-3d", piezo=2,
    description="3D GPRM plunger, Piezo 2 (redundant, plunger-spacer) driven; Appendix A",
    build=lambda s: _gprm_energies(s, 2))

GPRM_PIEZO1 = ModelDefinition(
    name="gprm-3d", piezo=1,
    description="3D GPRM plunger, Piezo 1 (nominal, spacer-tip) driven",
    build=lambda s: _gprm_energies(s, 1))

DEFINITIONS = {1: GPRM_PIEZO1, 2: GPRM_PIEZO2}
