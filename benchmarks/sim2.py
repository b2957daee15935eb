"""sim2: a second, independent simulator of GPRM ground-test campaigns (validation data).

Written from the model *definition* (docs/model.md sections 1, 2, 5-7; docs/spec.md),
not from gprm's model code: nothing here imports ``gprm.model``, ``gprm.simulate``,
``gprm.campaign`` or ``gprm.fit``. Only ``gprm.params`` is used, to read the nominal values.

Model (derived here)
--------------------
Generalised coordinates ``x = (z_lr, z_A, x_A, y_A, eta, theta, mu3, mu4, q)``. The plunger
attitude is ``R = R_x(theta) R_y(eta)``; a body point ``r`` sits at ``A + R r`` with
``A = (x_A, y_A, z_lr + z_A)``. Four energy functions are written with the exact kinematics:

* kinetic ``T(x, x')``: runner (z only), plunger CoM ``(v2, g2, h2)`` plus its transverse
  rotation ``1/2 J2 (w_x^2 + w_y^2)`` (body-frame angular velocity ``w = vee(R^T R')``, spin
  about the plunger axis neglected), spacer ``h3 e_z + mu3 u`` and tip
  ``h3 e_z + (h4 + mu4) u`` with ``u = (sin g, cos g sin r, cos g cos r)``. Point velocities
  and ``R'`` come from complex-step differentiation of the positions (exact to rounding);
* potential ``U(x)``: runner and axial springs, lateral x springs on the x-component and y
  springs on the y-component of the axis points ``A + R (0, 0, d)``, the spacer/tip chain and
  the piezo energy ``(q - T_em s)^2 / (2 C_a)``, stroke ``s = mu3`` (Piezo 2) or
  ``mu4 - mu3`` (Piezo 1);
* Rayleigh dissipation ``D(x, x')``: lateral dampers at the same axis points, ``c1`` on
  ``mu3'``, ``c3`` on ``mu4' - mu3'``, ``1/2 R q'^2``;
* the input is the generalised force ``V(t - t0)`` on ``q``.

Linearised about rest (paper Eq. 2): ``M0 = d2T/dx'2``, ``C0 = d2D/dx'2`` (both exact
quadratic forms, read off by polarisation) and ``K0 = d2U/dx2`` at 0, obtained from
``U(i h v) = -h^2/2 v^T K0 v + O(h^4)`` (``U(0) = 0`` and ``dU(0) = 0``, so there is no
cancellation) and polarisation. ``M0 x'' + C0 x' + K0 x = e_q V`` is put in first-order form
(16 mechanical states plus the charge, which has no inertia) and integrated with
``scipy.integrate.solve_ivp`` from the start of the voltage drop, as the change from the
static equilibrium at ``V(0)`` (input ``V(t - t0) - V(0)``; the system starts at rest there).
Integrator: LSODA (automatic stiff/non-stiff switching; BDF when stiff) with rtol 1e-9,
absolute tolerances 1e-11 of each state's peak (from a coarse pre-run) and the exact banded
Jacobian; up to CHUNK = 25 retractions are stacked into one block-diagonal system, each in
its own time since its onset, and read at its own sample times through solve_ivp's
``t_eval`` (so a trigger jitter is applied exactly, by moving that run's onset). Measured
against gprm's exact modal solver: <= 2e-8 of each signal's peak (tests/simulate/
test_sim2.py). Radau gives 1e-10 but costs ~10x more (2.5 s for 10 stacked runs vs 0.4 s),
too slow for 100 retractions per campaign.
Outputs (Eq. 3, docs/model.md section 5): ``x_P = x_A + eta d_P``, ``y_P = y_A - theta d_P``,
``z_bk = z_A(t - t1)``; alignment offsets ``dt_*`` are supported (0 in every truth here).

Campaign
--------
Ten laser positions x (10 actuated + 5 noise runs), 0..1.5 ms at 200 kHz, command at 1 ms,
micrometres, plus 10 voltage runs at 1 MHz, in the CSV layout of docs/data-formats.md
section 2, and ``truth.json``. Each actuated run is its own retraction. Imperfections (each
with a strength multiplier, see :class:`Imperfections`) are deliberately different from
gprm's own generator. Runner and flange positions are second-order low-pass copies of the
lateral / axial motion, integrated in the same ODE.

Usage: ``python benchmarks/sim2.py --seed N --out DIR [--preset default|white]
[--strength NAME=X ...]`` or ``make_campaign(out_dir, seed)``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import tempfile
import time as _time
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from gprm.params import FITTED_DEFAULT, paper

GENERATOR = "sim2"

COORDS = ("z_lr", "z_A", "x_A", "y_A", "eta", "theta", "mu3", "mu4", "q")
_C = {n: i for i, n in enumerate(COORDS)}
NMECH = 8                                   # coordinates with inertia (all but q)
MODEL_OUTPUTS = ("x_base", "x_head", "y_base", "y_head", "z_bk")
POSITIONS = ("x_lr", "x_fl", "x_base", "x_head", "z_bk", "z_fl", "y_fl", "y_lr", "y_base",
             "y_head")                      # docs/data-formats.md section 1, in this order
_ROW_LAG = {"z_bk": "t1", "x_head": "dt_x_head", "y_base": "dt_y_base",
            "y_head": "dt_y_head"}         # extra lag of each measured point (docs/model.md 5)

# Campaign layout (docs/data-formats.md section 3 defaults)
RATE = 200e3
T_END = 1.5e-3
N_ACT = 10
N_NOISE = 5
N_VOLT = 10
V_RATE = 1e6

# Runner and flange channels: (source signal, low-pass corner Hz, damping ratio, sign,
# Table-1 numerator, target ratio numerator/this). Ratios near the paper's Table 1
# (3, 17, 3, 21, 26) so that preprocessing's Sec. 2 hypotheses are plausible.
AUX = {
    "x_lr": ("x_base", 20.0e3, 0.4, -1.0, "x_head", 3.3),
    "x_fl": ("x_base", 12.0e3, 0.7, +1.0, "x_head", 16.0),
    "y_lr": ("y_base", 20.0e3, 0.4, -1.0, "y_head", 3.3),
    "y_fl": ("y_base", 12.0e3, 0.7, +1.0, "y_head", 20.0),
    "z_fl": ("z_lr", 10.0e3, 0.6, -1.0, "z_bk", 25.0),
}

# Unmodelled resonance (its own oscillator, excited by the voltage-drop rate)
RES_FREQ = 37e3
RES_ZETA = 0.02

_CS = 1e-30                                 # complex-step size (exact first derivatives)


# ============================================================================ model


def _attitude(eta, theta):
    """R = R_x(theta) R_y(eta) (complex arguments allowed)."""
    ce, se, ct, st = np.cos(eta), np.sin(eta), np.cos(theta), np.sin(theta)
    rx = np.array([[1, 0, 0], [0, ct, -st], [0, st, ct]], dtype=complex)
    ry = np.array([[ce, 0, se], [0, 1, 0], [-se, 0, ce]], dtype=complex)
    return rx @ ry


def _axis(p):
    g, r = p["gamma"], p["rho"]
    return np.array([math.sin(g), math.cos(g) * math.sin(r), math.cos(g) * math.cos(r)])


def _bodies(x, p):
    """World positions of the four masses and the attitude for coordinates x (complex ok)."""
    z_lr, z_A, x_A, y_A, eta, theta, mu3, mu4, _q = x
    R = _attitude(eta, theta)
    A = np.array([x_A, y_A, z_lr + z_A], dtype=complex)
    u = _axis(p)
    ez = np.array([0.0, 0.0, 1.0])
    r_plunger = np.array([p["v2"], p["g2"], p["h2"]])
    r_spacer = p["h3"] * ez + mu3 * u
    r_tip = p["h3"] * ez + (p["h4"] + mu4) * u
    runner = np.array([0.0, 0.0, z_lr], dtype=complex)
    return {"runner": runner, "plunger": A + R @ r_plunger, "spacer": A + R @ r_spacer,
            "tip": A + R @ r_tip}, R


def _axis_point(x, d):
    """World position of the axis point at distance d from A (complex ok)."""
    z_lr, z_A, x_A, y_A, eta, theta = x[:6]
    A = np.array([x_A, y_A, z_lr + z_A], dtype=complex)
    return A + _attitude(eta, theta) @ np.array([0.0, 0.0, d])


def _rate(f, x, xd):
    """d/dt f(x(t)) at x with x' = xd, by complex step (f analytic)."""
    return np.imag(f(np.asarray(x, complex) + 1j * _CS * np.asarray(xd, float))) / _CS


def kinetic(x, xd, p):
    """Kinetic energy T(x, x') with exact rotations."""
    X = np.asarray(x, complex) + 1j * _CS * np.asarray(xd, float)
    pos, R = _bodies(X, p)
    v = {k: np.imag(val) / _CS for k, val in pos.items()}
    Rdot = np.imag(R) / _CS
    W = np.real(R).T @ Rdot                  # skew matrix of the body-frame angular velocity
    wx, wy = W[2, 1], W[0, 2]
    masses = {"runner": p["m1"], "plunger": p["m2"], "spacer": p["m3"], "tip": p["m4"]}
    T = sum(0.5 * m * float(np.dot(v[k], v[k])) for k, m in masses.items())
    return T + 0.5 * p["J2"] * (wx * wx + wy * wy)


def _stroke(x, piezo):
    return x[_C["mu3"]] if piezo == 2 else x[_C["mu4"]] - x[_C["mu3"]]


def _lateral(x, p):
    """Elongations of the four lateral springs/dampers (x springs on the x component, y
    springs on the y component of their axis points)."""
    d1, d2, b1, b2 = p["d1"], p["d2"], p["b1"], p["b2"]
    return (_axis_point(x, d1)[0], _axis_point(x, d1 + d2)[0],
            _axis_point(x, b1)[1], _axis_point(x, b1 + b2)[1])


def potential(x, p, piezo=2):
    """Potential energy U(x), including the piezo electro-mechanical energy."""
    z_lr, z_A, _xa, _ya, _eta, _th, mu3, mu4, q = x
    eAx, eBx, eCy, eDy = _lateral(x, p)
    s = _stroke(x, piezo)
    return 0.5 * (p["k_lr"] * z_lr ** 2 + p["k_Az"] * z_A ** 2
                  + p["k_Ax"] * eAx ** 2 + p["k_Bx"] * eBx ** 2
                  + p["k_Cy"] * eCy ** 2 + p["k_Dy"] * eDy ** 2
                  + p["k3"] * mu3 ** 2 + p["k3"] * (mu4 - mu3) ** 2 + p["k4"] * mu4 ** 2) \
        + (q - p["T_em"] * s) ** 2 / (2.0 * p["C_a"])


def dissipation(x, xd, p):
    """Rayleigh dissipation D(x, x')."""
    rates = _rate(lambda X: np.array(_lateral(X, p)), x, xd)
    mu3d, mu4d, qd = xd[_C["mu3"]], xd[_C["mu4"]], xd[_C["q"]]
    return 0.5 * (p["c_Ax"] * rates[0] ** 2 + p["c_Bx"] * rates[1] ** 2
                  + p["c_Cy"] * rates[2] ** 2 + p["c_Dy"] * rates[3] ** 2
                  + p["c1"] * mu3d ** 2 + p["c3"] * (mu4d - mu3d) ** 2 + p["R"] * qd ** 2)


def _polarise(f, n):
    """The symmetric matrix A of a quadratic form f(v) = 1/2 v^T A v."""
    E = np.eye(n)
    diag = np.array([f(E[i]) for i in range(n)])
    A = np.diag(2.0 * diag)
    for i in range(n):
        for j in range(i + 1, n):
            A[i, j] = A[j, i] = f(E[i] + E[j]) - diag[i] - diag[j]
    return A


# coordinate scales for the imaginary-axis Hessian of U (keeps h * scale small everywhere)
_SCALE = np.array([1e-6, 1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-6, 1e-6, 1e-5])


def linear_matrices(p, piezo=2):
    """M0, C0, K0 (9 x 9, coordinates COORDS) and the input vector F (paper Eq. 2)."""
    if piezo not in (1, 2):
        raise ValueError(f"piezo must be 1 or 2, got {piezo}")
    n = len(COORDS)
    zero = np.zeros(n)
    M = _polarise(lambda v: kinetic(zero, v, p), n)
    C = _polarise(lambda v: dissipation(zero, v, p), n)
    h = 1e-4         # steps h * _SCALE (1e-10 m, 1e-8 rad): O(h^2) truncation ~1e-16 relative
    # U(i h S v) = -(h^2/2) (S v)^T K (S v) + O(h^4): the quadratic form of S K S
    Ks = _polarise(lambda v: -np.real(potential(1j * h * _SCALE * v, p, piezo)) / h ** 2, n)
    K = Ks / np.outer(_SCALE, _SCALE)
    F = np.zeros(n)
    F[_C["q"]] = 1.0
    return M, C, K, F


def state_space(p, piezo=2):
    """z' = A z + b u for z = (x_mech, x_mech', q), u the input voltage (change)."""
    M, C, K, F = linear_matrices(p, piezo)
    m, iq = slice(0, NMECH), NMECH
    tiny = 1e-13
    if np.abs(M[iq]).max() > tiny * np.abs(M).max():
        raise AssertionError("the charge must have no inertia")
    if np.abs(C[m, iq]).max() > tiny * np.abs(C).max():
        raise AssertionError("expected no mechanical-electrical damping coupling")
    cq = C[iq, iq]
    # charge row: cq q' + C[q,m] v + K[q,:] x = u  ->  q' = (u - C[q,m] v - K[q,:] x) / cq
    # mechanical rows: M v' + C[m,m] v + K[m,:] x = F_m u
    Minv = np.linalg.inv(M[m, m])
    ns = 2 * NMECH + 1
    A = np.zeros((ns, ns))
    b = np.zeros(ns)
    A[:NMECH, NMECH:2 * NMECH] = np.eye(NMECH)
    Kx = np.hstack([K[m, m], np.zeros((NMECH, NMECH)), K[m, iq][:, None]])   # on z
    Cv = np.hstack([np.zeros((NMECH, NMECH)), C[m, m], np.zeros((NMECH, 1))])
    A[NMECH:2 * NMECH] = -Minv @ (Kx + Cv)
    b[NMECH:2 * NMECH] = Minv @ F[m]
    A[-1, :NMECH] = -K[iq, m] / cq
    A[-1, NMECH:2 * NMECH] = -C[iq, m] / cq
    A[-1, -1] = -K[iq, iq] / cq
    b[-1] = F[iq] / cq
    return A, b


def _state_row(name):
    """Row over the 17 model states of a coordinate."""
    row = np.zeros(2 * NMECH + 1)
    row[_C[name] if name != "q" else 2 * NMECH] = 1.0
    return row


def output_row(name, p):
    """Eq. 3 as a row over the 17 model states (the lag is applied separately)."""
    r = _state_row
    if name.startswith("x_"):
        return r("x_A") + p[f"d_{name}"] * r("eta")
    if name.startswith("y_"):
        return r("y_A") - p[f"d_{name}"] * r("theta")      # docs/model.md 5: minus sign
    if name == "z_bk":
        return r("z_A")
    return r(name)


@dataclass
class System:
    """One retraction's linear system: model (17 states), resonance oscillator (2) and one
    low-pass channel (2; a runner/flange copy, or unused)."""

    A: np.ndarray
    b_u: np.ndarray          # input u = V(t - t0) - V(0)
    b_du: np.ndarray         # input u'
    rows: dict               # signal name -> row over the state
    lags: dict               # signal name -> extra lag behind t0 (s)


NSTATE = 2 * NMECH + 1 + 2 + 2


def build_system(p, piezo=2, aux=None):
    """The model plus the unmodelled-resonance oscillator and (with ``aux``, a runner/flange
    position) its low-pass channel. Every state starts at 0 (the equilibrium at V(0))."""
    A17, b17 = state_space(p, piezo)
    n17 = A17.shape[0]
    A = np.zeros((NSTATE, NSTATE))
    A[:n17, :n17] = A17
    b_u = np.zeros(NSTATE)
    b_u[:n17] = b17
    b_du = np.zeros(NSTATE)
    pad = np.zeros(NSTATE - n17)
    E = np.eye(NSTATE)
    rows = {name: np.concatenate([output_row(name, p), pad]) for name in MODEL_OUTPUTS}
    for c in COORDS:
        rows[c] = np.concatenate([_state_row(c), pad])
    lags = {name: float(p.get(_ROW_LAG.get(name, ""), 0.0)) for name in rows}
    # resonance: r'' + 2 zeta w r' + w^2 r = -w u' / V0 (kicked by the drop rate)
    w = 2 * math.pi * RES_FREQ
    i = n17
    A[i, i + 1] = 1.0
    A[i + 1, i] = -w * w
    A[i + 1, i + 1] = -2 * RES_ZETA * w
    b_du[i + 1] = -w / p["V0"]
    rows["_res"], rows["_res_rate"] = E[i], E[i + 1] / w
    lags["_res"] = lags["_res_rate"] = 0.0
    # low-pass copy: f'' + 2 zeta wc f' + wc^2 f = wc^2 s(t), s a model signal (no lag)
    j = n17 + 2
    if aux is not None:
        src, fc, zeta = AUX[aux][:3]
        wc = 2 * math.pi * fc
        A[j, j + 1] = 1.0
        A[j + 1, j + 1] = -2 * zeta * wc
        A[j + 1, j] = -wc * wc
        A[j + 1] += wc * wc * rows[src]
        rows[aux] = E[j]
        lags[aux] = 0.0
    return System(A, b_u, b_du, rows, lags)


@dataclass(frozen=True)
class Drive:
    """One retraction: V0 until ``onset``, then V0 exp(-(t - onset)/tau) (onset = command
    time + t0 + trigger jitter, on the record's axis)."""

    V0: float
    tau: float
    onset: float


CHUNK = 25          # retractions integrated together (block-diagonal system)


def _integrate_chunk(systems, drives, rel, rtol, atol):
    """Integrate several independent retractions at once with solve_ivp (LSODA, banded
    Jacobian: the stacked system is block-diagonal), each from rest at its own onset
    (relative time s = 0), input u(s) = V0 (exp(-s/tau) - 1). ``rel[r]``: the relative times
    run r is needed at. Returns, per run, the state at those times (0 before the onset)."""
    R, n = len(systems), NSTATE
    As = np.stack([s.A for s in systems])
    Bu = np.stack([s.b_u for s in systems])
    Bdu = np.stack([s.b_du for s in systems])
    V0 = np.array([d.V0 for d in drives])
    tau = np.array([d.tau for d in drives])
    outs = [np.zeros((n, x.size)) for x in rel]
    pos = [x > 0.0 for x in rel]
    if not any(m.any() for m in pos):
        return outs
    t_eval = np.unique(np.concatenate([x[m] for x, m in zip(rel, pos)]))
    band = np.zeros((2 * n - 1, R * n))         # packed: band[i - j + n - 1, j] = J[i, j]
    ii, jj = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    for r in range(R):
        band[ii - jj + n - 1, r * n + jj] = As[r]

    def fun(s, z):
        e = np.exp(-s / tau)
        Z = np.matmul(As, z.reshape(R, n, 1))[:, :, 0]
        return (Z + Bu * (V0 * (e - 1.0))[:, None] + Bdu * (-V0 / tau * e)[:, None]).ravel()

    sol = solve_ivp(fun, (0.0, float(t_eval[-1])), np.zeros(R * n), method="LSODA",
                    t_eval=t_eval, rtol=rtol, atol=np.asarray(atol).ravel(),
                    jac=lambda s, z: band, lband=n - 1, uband=n - 1)
    if not sol.success:
        raise RuntimeError(f"solve_ivp failed: {sol.message}")
    Y = sol.y.reshape(R, n, -1)
    for r in range(R):
        outs[r][:, pos[r]] = Y[r][:, np.searchsorted(t_eval, rel[r][pos[r]])]
    return outs


def integrate(systems, drives, times, names, *, rtol=1e-9, atol=None):
    """Signals ``names[r]`` of retraction r at record ``times`` (each read at t minus its
    extra lag). ``atol``: (R, NSTATE) absolute tolerances; default from a coarse pre-run
    (1e-11 of each state's peak). Runs are integrated in chunks of CHUNK."""
    times = np.asarray(times, float)
    R = len(systems)
    lagsets = [sorted({systems[r].lags[nm] for nm in names[r]}) for r in range(R)]
    rel = [np.concatenate([times - drives[r].onset - lag for lag in lagsets[r]])
           for r in range(R)]
    if atol is None:
        atol = tolerances(systems, drives, max(float(x.max()) for x in rel))
    states = []
    for c in range(0, R, CHUNK):
        sl = slice(c, min(c + CHUNK, R))
        states += _integrate_chunk(systems[sl], drives[sl], rel[sl], rtol, atol[sl])
    out = []
    for r in range(R):
        d, k = {}, 0
        for lag in lagsets[r]:
            Z = states[r][:, k:k + times.size]
            k += times.size
            for nm in names[r]:
                if systems[r].lags[nm] == lag:
                    d[nm] = systems[r].rows[nm] @ Z
        out.append(d)
    return out


def tolerances(systems, drives, span, rel_tol=1e-11):
    """Per-run, per-state absolute tolerances: ``rel_tol`` x the state's peak in a coarse
    pre-run (states that stay at 0 get the largest peak of that state over the runs)."""
    probe = np.linspace(0.0, span, 301)[1:]
    R = len(systems)
    tiny = np.full((R, NSTATE), 1e-16)
    peaks = []
    for c in range(0, R, CHUNK):
        sl = slice(c, min(c + CHUNK, R))
        z = _integrate_chunk(systems[sl], drives[sl], [probe] * len(systems[sl]), 1e-5,
                             tiny[sl])
        peaks += [np.max(np.abs(x), axis=1) for x in z]
    P = np.array(peaks)
    fill = P.max(axis=0)
    P = np.where(P > 0, P, fill[None, :])
    return rel_tol * np.where(P > 0, P, 1.0)


def simulate_signals(p, times, *, piezo=2, names=MODEL_OUTPUTS, V0=None, tau_v=None,
                     t_c=None, shift=0.0, rtol=1e-9):
    """Noise-free signals of one retraction at record times, as changes from the static
    equilibrium at V(0): V0 until t_c, then V0 exp(-(t - t_c)/tau_v), seen as V(t - t0)
    (``shift`` moves the command: trigger jitter). Each signal is read at t minus its extra
    lag (z_bk: t1; x_head, y_base, y_head: dt_*). ``p``: name -> SI value (every registry
    parameter). ``names`` may include one runner/flange position (x_lr, ...; unscaled
    low-pass copy) and the coordinates."""
    p = dict(p)
    aux = [nm for nm in names if nm in AUX]
    if len(aux) > 1:
        raise ValueError("at most one runner/flange position per call")
    sysm = build_system(p, piezo, aux[0] if aux else None)
    V0 = p["V0"] if V0 is None else V0
    tau = p["tau_v"] if tau_v is None else tau_v
    t_c = p["t_c"] if t_c is None else t_c
    drive = Drive(V0, tau, t_c + shift + p["t0"])
    return integrate([sysm], [drive], times, [tuple(names)], rtol=rtol)[0]



# ============================================================================ campaign


@dataclass(frozen=True)
class Imperfections:
    """Strength multipliers (1 = the default size, 0 = off) of sim2's own imperfections.

    jitter: Gaussian trigger jitter per run, sd 3 us (moves that run's command time).
    drive: per run V0 x (1 + 0.015 N), tau_v x (1 + 0.04 N) (Gaussian).
    gain: calibration gain per laser position, 1 + U(-1 %, +1 %) (all runs of the position).
    resonance: unmodelled 37 kHz resonance, damping ratio 0.02, kicked by the voltage-drop
        rate, 1 % of each position's peak, its own phase per position.
    noise: white + pink (1/f, by spectral shaping) noise: pink std 3e-10 m x strength, white
        std sqrt(max(noise_floor^2 - pink^2, (4e-10 m x strength)^2)), so the total is 5e-10 m
        for strengths up to 1 (at 1: white 4e-10 + pink 3e-10) and grows beyond; per-run
        offsets N(0, 3 nm) and a linear drift N(0, 0.5 nm) over the record (x strength). At 0
        only the white floor remains.
    nonlinear: quadratic distortion of each signal, y + a y^2 / peak, a = 0.5 % x strength
        (default off).
    noise_floor: white-noise std (m) left when ``noise`` is 0 (must be > 0 for a campaign
        preprocessing can read: noise runs would be flat otherwise).
    """

    jitter: float = 1.0
    drive: float = 1.0
    gain: float = 1.0
    resonance: float = 1.0
    noise: float = 1.0
    nonlinear: float = 0.0
    noise_floor: float = 5e-10

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"imperfection {f.name} must be a finite number >= 0, got {v!r}")


PRESETS = {
    "default": Imperfections(),
    "white": Imperfections(jitter=0.0, drive=0.0, gain=0.0, resonance=0.0, noise=0.0,
                           nonlinear=0.0),
}

JITTER_SD = 3e-6
V0_SD, TAU_SD = 0.015, 0.04
GAIN_HALF = 0.01
RES_AMP = 0.01
WHITE_1, PINK_1 = 4e-10, 3e-10
OFFSET_SD, DRIFT_SD = 3e-9, 0.5e-9
NONLIN_A = 0.005
VOLT_NOISE = 0.1
_PINK_LEN = 2048


def draw_truth(rng, spread=0.1, base=None):
    """Every fitted parameter x U(1 - spread, 1 + spread), t0 and t1 kept; others as base."""
    vals = dict((base or paper()).values)
    fac = rng.uniform(1.0 - spread, 1.0 + spread, len(FITTED_DEFAULT))
    for name, f in zip(FITTED_DEFAULT, fac):
        if name not in ("t0", "t1"):
            vals[name] = vals[name] * float(f)
    return vals


def _pink_filter(n):
    f = np.fft.rfftfreq(n)
    H = np.zeros_like(f)
    H[1:] = 1.0 / np.sqrt(f[1:] / f[1])
    full = H[0] ** 2 + 2 * np.sum(H[1:-1] ** 2) + H[-1] ** 2   # n even
    return H / math.sqrt(full / n)          # unit output variance


def _noise(rng, n, imp: Imperfections, pink_h):
    """One record of interferometer noise (m): white + pink, offset, linear drift."""
    s = imp.noise
    pink = PINK_1 * s
    white = math.sqrt(max(imp.noise_floor ** 2 - pink ** 2, (WHITE_1 * s) ** 2))
    w = rng.standard_normal(n)
    g = rng.standard_normal(_PINK_LEN)
    off, drift = rng.standard_normal(2)
    pk = np.fft.irfft(np.fft.rfft(g) * pink_h, _PINK_LEN)[:n]
    ramp = np.linspace(-0.5, 0.5, n)
    return white * w + pink * pk + s * (OFFSET_SD * off + DRIFT_SD * drift * ramp)


def _fmt_csv(path, t, y, header, tfmt="%.12g", yfmt="%.10g"):
    lines = [header] + [f"{tfmt % a},{yfmt % b}" for a, b in zip(t, y)]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def make_campaign(out_dir, seed, imperfections: Imperfections | None = None,
                  truth_spread=0.1, piezo=2, truth_values=None):
    """Write a campaign folder (manifest.csv, CSV runs, truth.json); return the truth dict.

    Deterministic for a seed: one ``numpy.random.default_rng(seed)`` draws everything, in a
    fixed order and whatever the strengths (a strength only scales its draws).
    ``truth_values``: optional full parameter dict to use instead of a random truth.
    """
    imp = imperfections if imperfections is not None else Imperfections()
    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise FileExistsError(f"{out}: exists and is not an empty directory")
    rng = np.random.default_rng(seed)
    p = draw_truth(rng, truth_spread)
    if truth_values is not None:
        p = dict(truth_values)
    V0, tau, t_c = p["V0"], p["tau_v"], p["t_c"]
    times = np.arange(int(round(T_END * RATE)) + 1) / RATE
    vtimes = np.arange(int(round(T_END * V_RATE)) + 1) / V_RATE
    npos = len(POSITIONS)

    # ---- fixed per-position draws
    gains = 1.0 + imp.gain * GAIN_HALF * rng.uniform(-1.0, 1.0, npos)
    phases = rng.uniform(0.0, 2 * math.pi, npos)
    # ---- per-run draws (positions x runs): jitter, V0 and tau_v factors
    jit = imp.jitter * JITTER_SD * rng.standard_normal((npos, N_ACT))
    v0f = 1.0 + imp.drive * V0_SD * rng.standard_normal((npos, N_ACT))
    tauf = 1.0 + imp.drive * TAU_SD * rng.standard_normal((npos, N_ACT))
    vjit = imp.jitter * JITTER_SD * rng.standard_normal(N_VOLT)
    vv0 = 1.0 + imp.drive * V0_SD * rng.standard_normal(N_VOLT)
    vtau = 1.0 + imp.drive * TAU_SD * rng.standard_normal(N_VOLT)

    systems = [build_system(p, piezo, pos if pos in AUX else None) for pos in POSITIONS]
    names = [(pos, "_res", "_res_rate") for pos in POSITIONS]
    # nominal retraction per position: peaks, resonance normalisation, runner/flange scales
    onset = t_c + p["t0"]
    nominal = [Drive(V0, tau, onset)] * npos
    span = T_END - onset - min(0.0, *(min(s.lags.values()) for s in systems))
    atol = tolerances(systems, nominal, span)
    nom = dict(zip(POSITIONS, integrate(systems, nominal, times, names, atol=atol)))
    res_norm = float(np.max(np.hypot(nom["x_base"]["_res"], nom["x_base"]["_res_rate"])))
    raw_peak = {pos: float(np.max(np.abs(nom[pos][pos]))) for pos in POSITIONS}
    scale = {pos: 1.0 for pos in POSITIONS}
    for pos, (_src, _fc, _z, sign, num, ratio) in AUX.items():
        scale[pos] = sign * raw_peak[num] / (ratio * raw_peak[pos])
    peak = {pos: raw_peak[pos] * abs(scale[pos]) for pos in POSITIONS}

    # every actuated run is its own retraction
    drives = [Drive(V0 * v0f[i, r], tau * tauf[i, r], onset + jit[i, r])
              for i in range(npos) for r in range(N_ACT)]
    runs = integrate([systems[i] for i in range(npos) for _ in range(N_ACT)], drives, times,
                     [names[i] for i in range(npos) for _ in range(N_ACT)],
                     atol=np.repeat(atol, N_ACT, axis=0))
    disp = np.zeros((npos, N_ACT, times.size))
    for i, pos in enumerate(POSITIONS):
        for r in range(N_ACT):
            y = runs[i * N_ACT + r]
            sig = y[pos] * scale[pos]
            res = math.cos(phases[i]) * y["_res"] + math.sin(phases[i]) * y["_res_rate"]
            sig = sig + imp.resonance * RES_AMP * peak[pos] * res / res_norm
            sig = sig + imp.nonlinear * NONLIN_A * sig ** 2 / peak[pos]
            disp[i, r] = gains[i] * sig
    pink_h = _pink_filter(_PINK_LEN)
    noise_act = np.stack([[_noise(rng, times.size, imp, pink_h) for _ in range(N_ACT)]
                          for _ in range(npos)])
    noise_only = np.stack([[_noise(rng, times.size, imp, pink_h) for _ in range(N_NOISE)]
                           for _ in range(npos)])
    disp = disp + noise_act
    volt = np.empty((N_VOLT, vtimes.size))
    for r in range(N_VOLT):
        start = t_c + vjit[r]
        v0r = V0 * vv0[r]
        drop = v0r * np.exp(-np.clip(vtimes - start, 0.0, None) / (tau * vtau[r]))
        volt[r] = drop + VOLT_NOISE * rng.standard_normal(vtimes.size)

    truth = {
        "generator": GENERATOR,
        "seed": int(seed),
        "piezo": int(piezo),
        "truth_spread": float(truth_spread),
        "parameters": {n: float(p[n]) for n in FITTED_DEFAULT},
        "imperfections": asdict(imp),
        "constants": {n: float(v) for n, v in p.items() if n not in FITTED_DEFAULT},
        "realisation": {
            "positions": list(POSITIONS),
            "gain": gains.tolist(),
            "resonance_phase": phases.tolist(),
            "noiseless_peak_m": [peak[pos] for pos in POSITIONS],
            "trigger_jitter_s": jit.tolist(),
            "V0_factor": v0f.tolist(),
            "tau_v_factor": tauf.tolist(),
            "voltage_trigger_jitter_s": vjit.tolist(),
            "voltage_V0_factor": vv0.tolist(),
            "voltage_tau_v_factor": vtau.tolist(),
        },
        "layout": {"rate_hz": RATE, "t_end_s": T_END, "t_c_s": t_c, "unit": "um",
                   "actuated_runs": N_ACT, "noise_runs": N_NOISE, "voltage_runs": N_VOLT,
                   "voltage_rate_hz": V_RATE},
    }
    _write(out, times, vtimes, disp, noise_only, volt, truth)
    return truth


def _write(out: Path, times, vtimes, disp, noise_only, volt, truth):
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        rows = ["position,kind,run,file,unit"]
        for i, pos in enumerate(POSITIONS):
            (tmp / pos).mkdir()
            for r in range(disp.shape[1]):
                f = f"{pos}/run{r + 1:02d}.csv"
                _fmt_csv(tmp / f, times, disp[i, r] * 1e6, "time_s,displacement_um")
                rows.append(f"{pos},actuated,{r + 1},{f},um")
            for r in range(noise_only.shape[1]):
                f = f"{pos}/noise{r + 1:02d}.csv"
                _fmt_csv(tmp / f, times, noise_only[i, r] * 1e6, "time_s,displacement_um")
                rows.append(f"{pos},noise,{r + 1},{f},um")
        (tmp / "voltage").mkdir()
        for r in range(volt.shape[0]):
            f = f"voltage/ret{r + 1:02d}.csv"
            _fmt_csv(tmp / f, vtimes, volt[r], "time_s,voltage_V", yfmt="%.8g")
            rows.append(f",voltage,{r + 1},{f},V")
        (tmp / "manifest.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
        (tmp / "truth.json").write_text(json.dumps(truth, indent=1) + "\n", encoding="utf-8")
        if out.exists():
            out.rmdir()                       # empty (checked by the caller)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


# ============================================================================ CLI


def _parse_strength(items):
    out = {}
    names = {f.name for f in fields(Imperfections)}
    for it in items or ():
        name, sep, val = it.partition("=")
        if not sep or name not in names:
            raise SystemExit(f"--strength expects NAME=X with NAME in {sorted(names)}, got {it!r}")
        try:
            out[name] = float(val)
        except ValueError:
            raise SystemExit(f"--strength {name}: not a number: {val!r}") from None
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description="sim2: independent GPRM campaign simulator")
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--out", required=True, help="campaign folder to write (new or empty)")
    ap.add_argument("--preset", choices=sorted(PRESETS), default="default")
    ap.add_argument("--strength", action="append", metavar="NAME=X",
                    help="imperfection strength, e.g. --strength noise=2 (repeatable)")
    ap.add_argument("--truth-spread", type=float, default=0.1)
    ap.add_argument("--piezo", type=int, choices=(1, 2), default=2)
    a = ap.parse_args(argv)
    t = _time.perf_counter()
    try:
        imp = replace(PRESETS[a.preset], **_parse_strength(a.strength))
        make_campaign(a.out, a.seed, imp, truth_spread=a.truth_spread, piezo=a.piezo)
    except (FileExistsError, ValueError) as e:
        raise SystemExit(f"sim2: {e}") from None
    print(f"sim2: wrote {a.out} (seed {a.seed}, {a.preset}, {_time.perf_counter() - t:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
