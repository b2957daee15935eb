"""The parameter registry: every parameter of the paper's Tables 2 and 3 and the documented
assumed values of ``docs/spec.md``, with unit, role, default, paper initial value, paper
uncertainty and bounds.

Values are stored in SI (radians for angles). Units are shown and accepted only at the edges
(see :mod:`gprm.params.files`).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

import math

INF = math.inf


@dataclass(frozen=True)
class ParamSpec:
    """Description of one parameter.

    Attributes
    ----------
    name: the paper's notation (``k_Ax`` for k_{A,x}).
    unit: the unit the paper quotes and the tool shows (a pint unit string).
    description: what the parameter is.
    group: ``fitted`` (Table 3), ``constant`` (Table 2), ``geometry`` (values the paper does
        not give; docs/spec.md's assumed values), ``alignment`` (per-signal time offsets of
        the aligned mean signals; default 0, not fitted by default), ``input`` (voltage
        profile) or ``flight`` (test mass and impact geometry).
    default: the ``paper`` value, SI.
    initial: the paper's initial value (centre of the random starts), SI, fitted ones only.
    paper_stderr: the Table 3 uncertainty, SI, fitted ones only.
    nominal: the CAD nominal value (Table 3 "Nominal value"), where given.
    lower, upper: physical bounds, SI. Non-physical values outside them are input errors.
    """

    name: str
    unit: str
    description: str
    group: str
    default: float
    initial: float | None = None
    paper_stderr: float | None = None
    nominal: float | None = None
    lower: float = -INF
    upper: float = INF

    @property
    def fitted_by_default(self) -> bool:
        return self.group == "fitted"


def _s(name, unit, scale, desc, group, default, initial=None, stderr=None, nominal=None,
       lower=-INF, upper=INF):
    """Build a spec from values quoted in ``unit`` (``scale`` converts them to SI)."""
    def f(v):
        return None if v is None else v * scale

    lo = lower if lower in (-INF, 0.0) else lower * scale
    hi = upper if upper == INF else upper * scale
    return ParamSpec(name, unit, desc, group, default * scale, f(initial), f(stderr), f(nominal),
                     lo, hi)


# Table 3 (best fit = default, initial value, uncertainty), Table 2 constants,
# the assumed geometry of docs/spec.md. Bounds: physical sign constraints only (masses, stiffnesses,
# dampings, distances and electrical constants are non-negative; angles within ±0.5 rad).
# The lags t0, t1 and the alignment offsets are signed offsets in the aligned time base of the
# mean signals (preprocessing puts each signal's own 2-sigma crossing at 1 ms), so they may be
# negative: t0, t1 within ±1 ms, the alignment offsets within ±50 us.
_SPECS = (
    # --- fitted (Table 3) ---
    _s("v2", "mm", 1e-3, "plunger CoM x coordinate in the plunger frame", "fitted",
       2.7, 2.8, 0.2),
    _s("g2", "mm", 1e-3, "plunger CoM y coordinate in the plunger frame", "fitted",
       -0.4, -0.4, 0.1),
    _s("gamma", "mrad", 1e-3, "spacer/tip axis misalignment in the x-z plane", "fitted",
       -7.0, 5.0, 2.0, lower=-500.0, upper=500.0),
    _s("rho", "mrad", 1e-3, "spacer/tip axis misalignment in the y-z plane", "fitted",
       37.0, 37.0, 3.0, lower=-500.0, upper=500.0),
    _s("k_lr", "N/m", 1.0, "linear-runner axial spring to ground (k_{I,r} in Table 3)", "fitted",
       164e4, 166e4, 1e4, lower=0.0),
    _s("k_Ax", "N/m", 1.0, "lateral x spring at d1 from A", "fitted", 1104e5, 1123e5, 7e5,
       lower=0.0),
    _s("k_Bx", "N/m", 1.0, "lateral x spring at d1+d2 from A", "fitted", 223e3, 232e3, 2e3,
       lower=0.0),
    _s("c_Ax", "N*s/m", 1.0, "lateral x damper at d1 from A", "fitted", 1.07, 0.099, 0.01,
       lower=0.0),
    _s("c_Bx", "N*s/m", 1.0, "lateral x damper at d1+d2 from A", "fitted", 21.6, 23.0, 0.7,
       lower=0.0),
    _s("k_Cy", "N/m", 1.0, "lateral y spring at b1 from A", "fitted", 7e6, 6e6, 1e6, lower=0.0),
    _s("k_Dy", "N/m", 1.0, "lateral y spring at b1+b2 from A", "fitted", 50e5, 54e5, 6e5,
       lower=0.0),
    _s("c_Cy", "N*s/m", 1.0, "lateral y damper at b1 from A", "fitted", 1.50, 1.57, 0.02,
       lower=0.0),
    _s("c_Dy", "N*s/m", 1.0, "lateral y damper at b1+b2 from A", "fitted", 1.61, 1.72, 0.01,
       lower=0.0),
    _s("m1", "g", 1e-3, "linear-runner mass", "fitted", 0.4, 0.4, 0.1, lower=0.0),
    _s("m2", "g", 1e-3, "plunger mass", "fitted", 12.4, 12.7, 0.9, nominal=12.3, lower=0.0),
    _s("m3", "g", 1e-3, "spacer mass", "fitted", 1.7, 1.9, 0.3, nominal=1.5, lower=0.0),
    _s("m4", "g", 1e-3, "tip mass", "fitted", 0.5, 0.3, 0.3, nominal=0.39, lower=0.0),
    _s("d1", "mm", 1e-3, "distance of k_Ax, c_Ax from A", "fitted", 2.0, 2.0, 2.0, lower=0.0),
    _s("d2", "mm", 1e-3, "distance of k_Bx, c_Bx from k_Ax, c_Ax", "fitted", 40.0, 45.0, 3.0,
       lower=0.0),
    _s("b1", "mm", 1e-3, "distance of k_Cy, c_Cy from A", "fitted", 42.0, 39.0, 4.0, lower=0.0),
    _s("b2", "mm", 1e-3, "distance of k_Dy, c_Dy from k_Cy, c_Cy", "fitted", 4.0, 4.0, 6.0,
       lower=0.0),
    _s("t0", "s", 1.0, "lag of the response behind the command (in the aligned time base of "
       "the mean signals; may be negative)", "fitted", 4e-6, 5e-6, 3e-6,
       lower=-1e-3, upper=1e-3),
    _s("t1", "s", 1.0, "lag of the plunger back behind the tip: extra lag of z_bk on top of t0 "
       "(in the aligned time base of the mean signals; may be negative)", "fitted",
       5e-6, 4e-6, 3e-6, lower=-1e-3, upper=1e-3),
    # --- per-signal alignment offsets (not in the paper; docs/model.md) ---
    _s("dt_x_head", "us", 1e-6, "alignment offset of x_head: extra lag behind x_base (the "
       "reference) in the aligned time base", "alignment", 0.0, lower=-50.0, upper=50.0),
    _s("dt_y_base", "us", 1e-6, "alignment offset of y_base: extra lag behind x_base (the "
       "reference) in the aligned time base", "alignment", 0.0, lower=-50.0, upper=50.0),
    _s("dt_y_head", "us", 1e-6, "alignment offset of y_head: extra lag behind x_base (the "
       "reference) in the aligned time base", "alignment", 0.0, lower=-50.0, upper=50.0),
    # --- constants (Table 2) ---
    _s("h3", "m", 1.0, "distance of the spacer from A", "constant", 0.0421, lower=0.0),
    _s("h4", "m", 1.0, "distance of the tip from the spacer", "constant", 0.0192, lower=0.0),
    _s("J2", "kg*m^2", 1.0, "plunger transverse inertia about its CoM", "constant", 2.7e-6,
       lower=0.0),
    _s("k_Az", "N/m", 1.0, "axial spring between plunger and linear runner", "constant", 2.1e6,
       lower=0.0),
    _s("k3", "N/m", 1.0, "spring plunger-spacer and spacer-tip", "constant", 2.0e7, lower=0.0),
    _s("k4", "N/m", 1.0, "spring tip-plunger", "constant", 9.8e4, lower=0.0),
    _s("c1", "N*s/m", 1.0, "damper plunger-spacer", "constant", 1.3, lower=0.0),
    _s("c3", "N*s/m", 1.0, "damper spacer-tip", "constant", 1.4, lower=0.0),
    _s("T_em", "C/m", 1.0, "piezo electro-mechanical coupling", "constant", 2.6, lower=0.0),
    _s("C_a", "F", 1.0, "piezo capacitance", "constant", 5.0e-7, lower=0.0),
    _s("R", "ohm", 1.0, "drive circuit resistance", "constant", 19.06, lower=0.0),
    # --- geometry the paper does not give (docs/spec.md, assumed values) ---
    _s("h2", "mm", 1e-3, "plunger CoM along the axis from A (assumed)", "geometry", 30.0),
    _s("d_x_base", "mm", 1e-3, "x_base laser point distance from A (assumed)", "geometry", 25.0),
    _s("d_x_head", "mm", 1e-3, "x_head laser point distance from A (assumed)", "geometry", 58.0),
    _s("d_y_base", "mm", 1e-3, "y_base laser point distance from A (assumed)", "geometry", 25.0),
    _s("d_y_head", "mm", 1e-3, "y_head laser point distance from A (assumed)", "geometry", 58.0),
    _s("dist_x", "mm", 1e-3, "M_xz x offset from the plunger CoM (assumed)", "geometry", 4.0),
    _s("dist_y", "mm", 1e-3, "M_yz y offset from the plunger CoM (assumed)", "geometry", 4.0),
    _s("dist_z", "mm", 1e-3, "M_xz, M_yz z offset from the plunger CoM (assumed)", "geometry",
       29.0),
    # --- default voltage profile (docs/spec.md) ---
    _s("V0", "V", 1.0, "piezo voltage before the retraction", "input", 120.0),
    _s("t_c", "ms", 1e-3, "time the retraction command starts", "input", 1.0, lower=0.0),
    _s("tau_v", "us", 1e-6, "time constant of the voltage drop", "input", 10.0, lower=0.0),
    # --- test mass and impact geometry (Section 4, docs/spec.md) ---
    _s("m_tm", "kg", 1.0, "test-mass mass", "flight", 1.928, lower=0.0),
    _s("s_tm", "mm", 1e-3, "test-mass cube side", "flight", 46.0, lower=0.0),
    _s("indent_angle", "deg", math.pi / 180, "indent face normal angle to the z axis (assumed)",
       "flight", 45.0, lower=0.0, upper=90.0),
)

REGISTRY: MappingProxyType = MappingProxyType({s.name: s for s in _SPECS})
"""All parameters by name, in the paper's order."""

FITTED_DEFAULT: tuple[str, ...] = tuple(s.name for s in _SPECS if s.group == "fitted")
"""The 23 parameters of Table 3, fitted by default."""

ALIGNMENT_OFFSETS: dict[str, str] = {"x_head": "dt_x_head", "y_base": "dt_y_base",
                                     "y_head": "dt_y_head"}
"""Measured point -> its alignment offset (x_base is the reference; z_bk has t1)."""

LAG_PARAMETERS: tuple[str, ...] = ("t0", "t1", *ALIGNMENT_OFFSETS.values())
"""The signed lags of the aligned time base: Eq. 3's t0 (x_base) and t1 (z_bk against x_base)
and the per-signal alignment offsets. Preprocessing a campaign moves them all
(gprm.fit.bootstrap.time_base_shift); the parametric bootstrap widens them by the refits'
spread (gprm.fit.uncertainty.from_bootstrap)."""

NO_EXACT_SENSITIVITY: tuple[str, ...] = ("tau_v",)
"""Parameters that move the model's outputs but have no exact sensitivity in the simulator
(the default profile's time constant acts on the input, not on the equations of motion):
gprm.simulate refuses to differentiate them and a parameter file may not fit them."""

# Quantities that must be strictly positive for the model to make sense (an input error if not).
STRICTLY_POSITIVE = frozenset({"m1", "m2", "m3", "m4", "J2", "C_a", "R", "tau_v", "m_tm", "s_tm",
                               "k_lr", "k_Az", "k3", "k4"})
