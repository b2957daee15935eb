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
from gprm.simulate.core import OUTPUTS, observation_rows
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

    def u_trace(t):
        return float(np.interp(t, kt, ku))

    return u_trace, list(kt)


def reference_linear(params: ParameterSet, times, *, piezo: int = 2,
                     voltage: VoltageTrace | None = None, names=OUTPUTS,
                     rtol: float = 1e-10, atol_scale: float = 1e-12,
                     z_bk_absolute: bool = False, method: str = "Radau") -> np.ndarray:
    """Observables (n_obs, T) by solve_ivp on z' = A z + b u, one parameter set.

    Each row is read from the integrated states at its own time t - lag (t1 for z_bk, the
    alignment offsets for x_head, y_base, y_head), independently of the modal solver.

    The state is exactly zero (rest in static equilibrium at V(0)) until the input starts to
    change; from there the integration restarts at every kink of the input, so the integrator
    never steps across a discontinuity of u'. Tolerances: ``rtol`` and absolute tolerances
    ``atol_scale`` times the scale of each group of components (see below).
    """
    p = batch([params])
    ss = state_space(p, piezo)
    A, b = ss.A[0], ss.b[0]
    u, breaks = _input_change(p, voltage)
    times = np.asarray(times, float)
    H, lags, _ = observation_rows(p, names, z_bk_absolute=z_bk_absolute)
    H = H[0]
    # each row's extra lag (t1 for z_bk, the alignment offsets; the sum of its parameters)
    row_lag = np.array([sum(float(p[n][0]) for n in lg if n in p) for lg in lags])
    eval_t = np.unique(np.concatenate([times] + [times - d for d in np.unique(row_lag)]))
    # absolute tolerances per group of state components (positions and angles, their rates,
    # the charge): atol_scale times the group's largest static response to the largest input
    # change (rates: |A| applied to it). Per group, not per component, because internal piezo
    # forces leave several components with a zero static response.
    umax = max(abs(u(t)) for t in np.linspace(breaks[0], eval_t.max(), 2001)) or 1.0
    zs = np.abs(np.linalg.solve(A, b * umax))
    rates = np.abs(A) @ zs
    atol = np.empty_like(zs)
    atol[:8] = zs[:8].max() * atol_scale
    atol[8:16] = rates[8:16].max() * atol_scale
    atol[16] = zs[16] * atol_scale
    n = A.shape[0]
    states = {}

    def rhs(t, z):
        return A @ z + b * u(t)

    def jac(t, z):
        return A

    start = breaks[0]
    for tt in eval_t[eval_t <= start]:
        states[tt] = np.zeros(n)          # at rest in equilibrium until the input changes
    edges = [start] + [b_ for b_ in breaks[1:] if start < b_ < eval_t.max()] + [eval_t.max()]
    z = np.zeros(n)
    for a, c in zip(edges[:-1], edges[1:]):
        if c <= a:
            continue
        pts = eval_t[(eval_t > a) & (eval_t < c)]
        sol = solve_ivp(rhs, (a, c), z, method=method, t_eval=np.append(pts, c), rtol=rtol,
                        atol=atol, jac=jac)
        if not sol.success:
            raise RuntimeError(sol.message)
        states.update(zip(sol.t, sol.y.T))
        z = sol.y[:, -1]
    y = np.zeros((len(names), times.size))
    for r in range(len(names)):
        y[r] = [H[r] @ states[tt - row_lag[r]] for tt in times]
    return y
