"""Reference integrators for checks (never used by the fitter).

* :func:`reference_linear` integrates the same linear state-space equations with a general
  stiff integrator (``scipy.integrate.solve_ivp``, Radau) at tight tolerances.
* :func:`gprm.simulate.nonlinear.simulate_nonlinear` keeps every nonlinear term.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from gprm.model.linear import state_space
from gprm.params import ParameterSet, batch
from gprm.simulate.core import COORDS, OUTPUTS, observation_rows
from gprm.simulate.inputs import VoltageTrace


def _input_change(p: dict, trace: VoltageTrace | None):
    """u(t) = V(t - t0) - V(0) as a function of record time, and its break points."""
    t0 = float(p["t0"][0])
    if trace is None:
        V0, tc, tau = float(p["V0"][0]), float(p["t_c"][0]), float(p["tau_v"][0])
        ts = tc + t0

        def u(t):
            return 0.0 if t <= ts else V0 * (np.exp(-(t - ts) / tau) - 1.0)

        return u, [ts]
    kt, ku = trace.knots(t0)

    def u(t):
        return float(np.interp(t, kt, ku))

    return u, list(kt)


def reference_linear(params: ParameterSet, times, *, piezo: int = 2,
                     voltage: VoltageTrace | None = None, names=OUTPUTS,
                     rtol: float = 1e-11, atol_scale: float = 1e-13,
                     z_bk_absolute: bool = False, method: str = "Radau") -> np.ndarray:
    """Observables (n_obs, T) by solve_ivp on z' = A z + b u. Integration restarts at every
    kink of the input, so the integrator never steps across a discontinuity of u'."""
    p = batch([params])
    ss = state_space(p, piezo)
    A, b = ss.A[0], ss.b[0]
    u, breaks = _input_change(p, voltage)
    times = np.asarray(times, float)
    H, lagged, _ = observation_rows(p, names, z_bk_absolute=z_bk_absolute)
    H = H[0]
    t1 = float(p["t1"][0])
    eval_t = np.unique(np.concatenate([times, times - t1]))
    # state scale for absolute tolerances: static response to the full input step
    zs = np.abs(np.linalg.solve(A, b * float(p["V0"][0])))
    atol = np.maximum(zs * atol_scale * 1e3, 1e-30)
    # also velocities: rough scale |A| * z
    atol = np.maximum(atol, np.abs(A) @ zs * atol_scale)
    out = {}
    z = np.zeros(A.shape[0])
    t_prev = min(eval_t.min(), 0.0)
    segments = sorted(set(b_ for b_ in breaks if eval_t.min() < b_ < eval_t.max()))
    edges = [t_prev] + segments + [eval_t.max()]

    def rhs(t, z):
        return A @ z + b * u(t)

    def jac(t, z):
        return A

    for a, c in zip(edges[:-1], edges[1:]):
        mask = (eval_t >= a) & (eval_t <= c)
        if c <= a:
            continue
        sol = solve_ivp(rhs, (a, c), z, method=method, t_eval=eval_t[mask], rtol=rtol,
                        atol=atol, jac=jac, dense_output=False)
        if not sol.success:
            raise RuntimeError(sol.message)
        for tt, zz in zip(sol.t, sol.y.T):
            out[tt] = zz
        sol_end = solve_ivp(rhs, (a, c), z, method=method, rtol=rtol, atol=atol, jac=jac)
        z = sol_end.y[:, -1]
    Z = lambda tt: out[tt] if tt in out else np.zeros(A.shape[0])
    y = np.zeros((len(names), times.size))
    for k, tt in enumerate(times):
        y[~lagged, k] = H[~lagged] @ Z(tt)
        if lagged.any():
            y[lagged, k] = H[lagged] @ Z(tt - t1)
    return y
