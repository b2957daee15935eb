"""Nonlinear reference simulation: the full Lagrange equations of the model definition with
every nonlinear term kept (products such as eta*z_lr'' included, exact rotations), integrated
by ``solve_ivp`` (Radau) from the nonlinear static equilibrium at V(0).

Used to quantify what the linear model (paper Eq. 2) drops, and as the richer "truth" of
synthetic campaigns. One parameter set at a time; slow by design (seconds).
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import fsolve

from gprm.errors import GprmInputError
from gprm.model.linear import generated
from gprm.params import ParameterSet
from gprm.simulate.core import (COORDS, OUTPUTS, RATES, ROW_LAGS, SimulationResult,
                                record_times)
from gprm.simulate.inputs import VoltageTrace, default_voltage


def _voltage_fn(p: dict, trace: VoltageTrace | None):
    if trace is None:
        return lambda t: float(default_voltage(np.array([t - p["t0"]]), p)), p["t_c"] + p["t0"]
    return lambda t: float(trace(t - p["t0"])), float(trace.time[0] + p["t0"])


def equilibrium(p: dict, piezo: int, V: float) -> np.ndarray:
    """Nonlinear static equilibrium (9 coordinates) at voltage V."""
    g = generated(piezo)
    n = len(g.COORDINATES)
    Q = np.asarray(g.INPUT)
    zero = np.zeros(n)

    def resid(x):
        _, f = g.nonlinear(x, zero, p)
        return f - Q * V

    # scaled start: the linear solution
    M, C, K = g.linear_matrices({k: np.asarray(v) for k, v in p.items()})
    x0 = np.linalg.solve(K, Q * V)
    x, info, ier, msg = fsolve(resid, x0, full_output=True, xtol=1e-13)
    if ier != 1:
        raise GprmInputError(f"nonlinear equilibrium not found: {msg}", field="parameters")
    return x


def _point_outputs(x: np.ndarray, p: dict) -> dict:
    """Measured points with exact kinematics: the axis point at distance d from A is at
    x_A + d sin(eta), y_A - d cos(eta) sin(theta) (R = R_x(theta) R_y(eta))."""
    z_lr, z_A, x_A, y_A, eta, theta = x[:6]
    return {
        "x_base": x_A + p["d_x_base"] * np.sin(eta),
        "x_head": x_A + p["d_x_head"] * np.sin(eta),
        "y_base": y_A - p["d_y_base"] * np.cos(eta) * np.sin(theta),
        "y_head": y_A - p["d_y_head"] * np.cos(eta) * np.sin(theta),
    }


def simulate_nonlinear(params: ParameterSet, *, piezo: int = 2, time=None,
                       t_end: float = 1.2e-3, rate: float = 200e3,
                       voltage: VoltageTrace | None = None, rtol: float = 1e-9,
                       z_bk_absolute: bool = False) -> SimulationResult:
    """Simulate the full nonlinear equations; outputs as changes from the initial equilibrium.

    Returns a :class:`SimulationResult` with B = 1 (same layout as ``simulate``).
    """

    p = dict(params.values)
    g = generated(piezo)
    times = record_times(t_end, rate) if time is None else np.asarray(time, float)
    Vfn, ts = _voltage_fn(p, voltage)
    V_init = Vfn(min(times.min(), ts) - 1.0)
    x_eq = equilibrium(p, piezo, V_init)
    Q = np.asarray(g.INPUT)
    R = p["R"]

    def rhs(t, s):
        x = s[:9]
        xd = np.zeros(9)
        xd[:8] = s[9:]
        M, f = g.nonlinear(x, xd, p)
        V = Vfn(t)
        # q row: f_q = dU/dq + R q' ; solve for q'
        fq0 = f[8] - R * xd[8]
        qd = (V - fq0) / R
        xd[8] = qd
        M, f = g.nonlinear(x, xd, p)
        acc = np.linalg.solve(M[:8, :8], Q[:8] * V - f[:8])
        return np.concatenate([xd[:8], [qd], acc])

    # each measured point's extra lag: t1 for z_bk, the alignment offsets (ROW_LAGS)
    lag = {k: sum(p[n] for n in ROW_LAGS.get(k, ())) for k in OUTPUTS}
    eval_t = np.unique(np.concatenate([times] + [times - d for d in set(lag.values())]))
    s0 = np.concatenate([x_eq, np.zeros(8)])
    later = eval_t[eval_t > ts]
    states = {tt: s0 for tt in eval_t[eval_t <= ts]}
    if later.size:
        sol = solve_ivp(rhs, (ts, later.max()), s0, method="Radau", t_eval=later, rtol=rtol,
                        atol=np.concatenate([np.full(8, 1e-16), [1e-14], np.full(8, 1e-12)]))
        if not sol.success:
            raise GprmInputError(f"nonlinear integration failed: {sol.message}",
                                 field="parameters")
        states.update({tt: sv for tt, sv in zip(sol.t, sol.y.T)})
    S = np.array([states[tt] for tt in times])                    # (T, 17)
    dev = S - s0
    coords = {c: dev[:, i][None] for i, c in enumerate(COORDS)}
    # rates: s[9:] are mechanical rates; q' from the ODE is not stored (not needed)
    rates = {r: S[:, 9 + i][None] for i, r in enumerate(RATES)}
    pts0 = _point_outputs(s0, p)
    outputs = {}
    for k in pts0:
        S_k = np.array([states[tt] for tt in times - lag[k]])
        outputs[k] = (_point_outputs(S_k.T, p)[k] - pts0[k])[None]
    S_lag = np.array([states[tt] for tt in times - lag["z_bk"]])
    zb = S_lag[:, 1] - s0[1]
    if z_bk_absolute:
        zb = zb + S_lag[:, 0] - s0[0]
    outputs["z_bk"] = zb[None]
    volts = np.array([Vfn(tt) for tt in times])[None]
    return SimulationResult(time=times, coords=coords, rates=rates,
                            outputs={k: outputs[k] for k in OUTPUTS}, voltage=volts,
                            piezo=piezo, ok=np.array([True]), reason=np.array([""], object))
