"""Trajectories of the plunger CoM (Eq. 8), the contact middle points M_xz and M_yz and the tip
edge (Sec. 4, Fig. 10), with uncertainty bands from the fit covariance.

Two bands, both around the best-fit trajectory:

- sampled: ``FittedModel.sample`` parameter sets (truncated normal), each simulated; the band is
  the 2.5 % / 97.5 % quantiles and the standard deviation across the sets;
- linear: J C J^T, with J the exact derivative of the point's displacement with respect to the
  fitted parameters (simulated coordinate sensitivities combined with the point kinematics by a
  complex step, which is exact to rounding).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from gprm.errors import GprmInputError
from gprm.fit.files import FittedModel
from gprm.params import batch
from gprm.simulate.kinematics import (MECH, RATES, _point_kinematics, body_motion,
                                      check_times, linear_statics, named_points, point_motion)

TRAJECTORY_POINTS: tuple[str, ...] = ("com", "M_xz", "M_yz", "tip_edge")
AXES: tuple[str, ...] = ("x", "y", "z")


def default_times(t_start: float = 0.95e-3, t_end: float = 1.2e-3,
                  rate: float = 1e6) -> np.ndarray:
    """Prediction times: t_start..t_end at ``rate`` (default 1 us steps)."""

    for v, f in ((t_start, "t_start"), (t_end, "t_end"), (rate, "rate")):
        if not np.isfinite(v):
            raise GprmInputError(f"must be finite, got {v}", field=f)
    if t_start < 0:
        raise GprmInputError(f"starts at {t_start:g} s, before the simulation start (0 s)",
                             field="t_start")
    if not t_end > t_start:
        raise GprmInputError(f"t_end {t_end:g} s must be after t_start {t_start:g} s",
                             field="t_end")
    if not rate > 0:
        raise GprmInputError(f"must be positive, got {rate:g}", field="rate")
    n = int(np.floor((t_end - t_start) * rate + 1e-9)) + 1
    return t_start + np.arange(n) / rate


@dataclass(frozen=True)
class Trajectories:
    """Point trajectories; arrays are (point, axis, time) unless said.

    pos/vel: best-fit displacement from the initial equilibrium position (m) and velocity
    (m/s); static: initial position (point, axis) in the frame with origin at A at rest;
    *_lo/*_hi: 2.5/97.5 % sampled quantiles; *_std: sampled std; *_std_lin: linear std;
    samples_pos: a few sampled displacements (sample, point, axis, time) for plotting;
    n_ok: sampled sets simulated (unsimulable ones dropped).
    """

    time: np.ndarray
    points: tuple[str, ...]
    piezo: int
    pos: np.ndarray
    vel: np.ndarray
    static: np.ndarray
    pos_lo: np.ndarray
    pos_hi: np.ndarray
    pos_std: np.ndarray
    vel_lo: np.ndarray
    vel_hi: np.ndarray
    vel_std: np.ndarray
    pos_std_lin: np.ndarray
    vel_std_lin: np.ndarray
    samples_pos: np.ndarray
    n_samples: int
    n_ok: int


def sampled_points(pb_samples: dict, times, points: Sequence[str], *, piezo: int,
                   voltage=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Displacements and velocities (B, point, 3, T) of ``points`` for a batch; and ok (B,)."""
    m = body_motion(pb_samples, times, piezo=piezo, voltage=voltage)
    pts = named_points(m.params)
    pos, vel = [], []
    for p in points:
        a, b = point_motion(m, pts[p], relative=True)
        pos.append(a)
        vel.append(b)
    return np.stack(pos, 1), np.stack(vel, 1), m.ok


def linear_point_jacobians(fm: FittedModel, times, points: Sequence[str], *, piezo: int,
                           voltage=None) -> tuple[np.ndarray, np.ndarray]:
    """Exact Jacobians (P, point, 3, T) of displacement and velocity w.r.t. ``fm.names``.

    The simulated coordinates carry their exact parameter sensitivities; the closed-form
    point kinematics (which also depend on the parameters directly: v2, g2, gamma, rho, the
    masses) is differentiated by a complex step, exact to rounding."""
    names = fm.names
    P = len(names)
    m = body_motion(fm, times, piezo=piezo, voltage=voltage, sensitivities=names)
    assert m.sens is not None  # asked for above
    h = 1e-20
    pb = {k: np.full(P, v[0], dtype=complex) for k, v in m.params.items()}
    for j, n in enumerate(names):
        pb[n][j] += 1j * h
    coords = {c: m.coords[c][0][None, :] + 1j * h * m.sens[c][0].T for c in MECH}
    rates = {r: m.rates[r][0][None, :] + 1j * h * m.sens[r][0].T for r in RATES}
    mu_eq = _statics_complex_step(m.params, names, piezo, h)
    pts = named_points(pb)
    Jp, Jv = [], []
    for p in points:
        a, b = _point_kinematics(pts[p], coords, rates, mu_eq, True)
        Jp.append(a.imag / h)
        Jv.append(b.imag / h)
    return np.stack(Jp, 1), np.stack(Jv, 1)


def _statics_complex_step(pb0: dict, names, piezo: int, h: float) -> dict:
    """mu_eq (P,) with imaginary part h * d mu_eq / d p_j. The generated matrices are real-only,
    so the derivative of this static solve is a central difference (relative step 1e-6;
    mu_eq depends on k3, k4, T_em, C_a, V0 only, none fitted by default)."""
    P = len(names)
    plus = {k: np.repeat(v[:1], P) for k, v in pb0.items()}
    minus = {k: v.copy() for k, v in plus.items()}
    steps = np.zeros(P)
    for j, n in enumerate(names):
        steps[j] = 1e-6 * max(abs(pb0[n][0]), 1e-12)
        plus[n][j] += steps[j]
        minus[n][j] -= steps[j]
    base = linear_statics({k: v[:1] for k, v in pb0.items()}, piezo)
    sp, sm = linear_statics(plus, piezo), linear_statics(minus, piezo)
    return {k: base[k][0] + 1j * h * (sp[k] - sm[k]) / (2 * steps) for k in base}


def _lin_std(J: np.ndarray, cov: np.ndarray) -> np.ndarray:
    return np.sqrt(np.maximum(np.einsum("p...,pq,q...->...", J, cov, J), 0.0))


def predict_trajectories(fm: FittedModel, times, *, piezo: int = 2, voltage=None,
                         points: Sequence[str] = TRAJECTORY_POINTS, samples: int = 200,
                         seed: int = 0, keep_samples: int = 20,
                         linear: bool = True) -> Trajectories:
    """Best-fit trajectories of ``points`` with sampled (and linear) uncertainty bands."""

    t = check_times(times)
    points = tuple(points)
    pb0 = batch([fm.params])
    best_p, best_v, _ = sampled_points(pb0, t, points, piezo=piezo, voltage=voltage)
    # initial position: the static equilibrium, no simulation needed
    mu0 = linear_statics(pb0, piezo)
    pts0 = named_points(pb0)
    static = np.stack([pts0[p].body_coordinates(mu0["mu3"], mu0["mu4"])[0] for p in points])
    shape = best_p[0].shape
    nan = np.full(shape, np.nan)
    lo = hi = sd = vlo = vhi = vsd = nan
    keep = np.zeros((0,) + shape)
    n_ok = 0
    if samples > 0:
        sp, sv, ok = sampled_points(fm.sample(samples, seed), t, points, piezo=piezo,
                                    voltage=voltage)
        sp, sv = sp[ok], sv[ok]
        n_ok = int(ok.sum())
        if n_ok:
            lo, hi = np.quantile(sp, [0.025, 0.975], axis=0)
            vlo, vhi = np.quantile(sv, [0.025, 0.975], axis=0)
            sd = sp.std(axis=0, ddof=1) if n_ok > 1 else nan
            vsd = sv.std(axis=0, ddof=1) if n_ok > 1 else nan
            keep = sp[:keep_samples]
    lin_p = lin_v = nan
    if linear and len(fm.names) and fm.covariance is not None:
        Jp, Jv = linear_point_jacobians(fm, t, points, piezo=piezo, voltage=voltage)
        lin_p, lin_v = _lin_std(Jp, fm.covariance), _lin_std(Jv, fm.covariance)
    return Trajectories(time=t, points=points, piezo=piezo, pos=best_p[0], vel=best_v[0],
                        static=static, pos_lo=lo, pos_hi=hi, pos_std=sd, vel_lo=vlo,
                        vel_hi=vhi, vel_std=vsd, pos_std_lin=lin_p, vel_std_lin=lin_v,
                        samples_pos=keep, n_samples=int(samples), n_ok=n_ok)
