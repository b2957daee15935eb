"""The exact batched solver with sensitivities (modal superposition).

For z' = A z + b u(t - t_s), z(t_s) = 0 (static equilibrium at V(0); u is the change of the
voltage from V(0)), diagonalise A = V diag(lambda) V^-1 and write beta = V^-1 b. Then

    z(t) = V [beta_i I_i(tau)],     I_i(tau) = int_0^tau exp(lambda_i (tau - s)) u(s) ds,

with tau = t - t_s. The modal convolutions I_i have closed forms for the default profile
(step + exponential) and exact recursions for a piecewise-linear measured trace, so the
solution is exact at any time (sub-sample lags t0 and t1 included), with no time stepping.

Sensitivities. With dA = dA/dp and G = V^-1 dA V, the Frechet derivative of the matrix
exponential in the eigenbasis gives

    dz/dp = V h,  h_i = sum_{j != i} G_ij beta_j (I_i - I_j)/(lambda_i - lambda_j)
                       + G_ii beta_i J_i + (V^-1 db)_i I_i,

where J_i = dI_i/dlambda_i. The lags enter through tau: dz/dt0 = -z'(t). The formulas need
distinct eigenvalues; sets whose eigenvalues nearly coincide (relative gap below
``GAP_TOL``) or whose eigenvectors are ill-conditioned are flagged, not silently returned.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gprm.model.linear import NSTATE, StateSpace, raw_derivatives, state_space

GAP_TOL = 1e-7
COND_TOL = 1e10

# ------------------------------------------------------------------ phi functions (stable)
_F1 = np.array([1.0 / np.prod(np.arange(1, k + 2, dtype=float)) for k in range(18)])   # 1/(k+1)!
_F2 = np.array([1.0 / np.prod(np.arange(1, k + 3, dtype=float)) for k in range(18)])   # 1/(k+2)!
_D1 = np.array([(k + 1) * _F2[k] for k in range(18)])                                   # (k+1)/(k+2)!
_D2 = np.array([(k + 1) / np.prod(np.arange(1, k + 4, dtype=float)) for k in range(18)])  # (k+1)/(k+3)!
_SMALL = 0.5


def _series(z, coef):
    out = np.zeros_like(z)
    for c in coef[::-1]:
        out = out * z + c
    return out


def _phi(z, direct, coef):
    z = np.asarray(z, dtype=complex)
    small = np.abs(z) < _SMALL
    with np.errstate(all="ignore"):
        out = direct(np.where(small, 1.0, z))
    return np.where(small, _series(z, coef), out)


def phi1(z):
    """(e^z - 1)/z."""
    return _phi(z, lambda z: np.expm1(z) / z, _F1)


def phi2(z):
    """(e^z - 1 - z)/z^2."""
    return _phi(z, lambda z: (np.expm1(z) - z) / z ** 2, _F2)


def dphi1(z):
    """d/dz phi1 = (e^z (z - 1) + 1)/z^2."""
    return _phi(z, lambda z: (np.expm1(z) * (z - 1) + z) / z ** 2, _D1)


def dphi2(z):
    """d/dz phi2 = (e^z - 1)/z^2 - 2 (e^z - 1 - z)/z^3."""
    return _phi(z, lambda z: np.expm1(z) / z ** 2 - 2 * (np.expm1(z) - z) / z ** 3, _D2)


# ------------------------------------------------------------------ modal convolutions

def conv_default(lam, tau, V0, tau_v):
    """I, J = dI/dlam and u for u(s) = V0 (exp(-s/tau_v) - 1), s >= 0 (0 before).

    lam: (B, n) complex; tau: (B, T) real; V0, tau_v: (B,). Returns I, J (B, n, T) and u
    (B, T). With a = 1/tau_v, L = lam:
    I = V0 [(e^{L t} - e^{-a t})/(L + a) - (e^{L t} - 1)/L], J = dI/dL, each divided
    difference switched to its Taylor series where its argument is small (|z| < 0.5).
    """
    a = (1.0 / tau_v)[:, None, None]
    t = np.clip(tau, 0.0, None)[:, None, :]
    L = lam[:, :, None]
    z = L * t
    E = np.exp(z)
    ea = np.exp(-a * t)
    za = (L + a) * t
    s0 = np.abs(z) < _SMALL
    sa = np.abs(za) < _SMALL
    with np.errstate(all="ignore"):
        term_a = (E - ea) / (L + a)
        dterm_a = (t * E - term_a) / (L + a)
        term_0 = (E - 1.0) / L
        dterm_0 = (t * E - term_0) / L
    tt = np.broadcast_to(t, z.shape)
    if sa.any():
        # small (L + a) t: e^{-a t} t phi1((L + a) t) and its derivative, by series
        eat = np.broadcast_to(ea * t, z.shape)[sa]
        term_a[sa] = eat * _series(za[sa], _F1)
        dterm_a[sa] = eat * tt[sa] * _series(za[sa], _D1)
    if s0.any():
        term_0[s0] = tt[s0] * _series(z[s0], _F1)
        dterm_0[s0] = tt[s0] ** 2 * _series(z[s0], _D1)
    V0b = V0[:, None, None]
    u = V0[:, None] * (np.exp(-np.clip(tau, 0, None) / tau_v[:, None]) - 1.0)
    return V0b * (term_a - term_0), V0b * (dterm_a - dterm_0), np.where(tau > 0, u, 0.0)


def conv_trace(lam, tau, knot_t, knot_u):
    """I, J and u for a piecewise-linear input with knots (knot_t, knot_u), knot_u[0] = 0,
    held constant after the last knot and zero before the first. tau: (B, T) is the time on
    the knots' axis. Exact recursions over the knots, then within the segment."""
    Bn, n = lam.shape
    K = knot_t.size
    h = np.diff(knot_t)
    Ik = np.zeros((Bn, n, K), complex)
    Jk = np.zeros((Bn, n, K), complex)
    for k in range(K - 1):
        z = lam * h[k]
        e = np.exp(z)
        slope = (knot_u[k + 1] - knot_u[k]) / h[k]
        S = knot_u[k] * h[k] * phi1(z) + slope * h[k] ** 2 * phi2(z)
        dS = knot_u[k] * h[k] ** 2 * dphi1(z) + slope * h[k] ** 3 * dphi2(z)
        Ik[:, :, k + 1] = e * Ik[:, :, k] + S
        Jk[:, :, k + 1] = h[k] * e * Ik[:, :, k] + e * Jk[:, :, k] + dS
    # segment of each evaluation time
    idx = np.clip(np.searchsorted(knot_t, tau, side="right") - 1, 0, K - 1)  # (B, T)
    before = tau < knot_t[0]
    d = np.where(before, 0.0, tau - knot_t[idx])                               # (B, T)
    slope_all = np.append(np.diff(knot_u) / h, 0.0)                           # hold after last
    uk = knot_u[idx]
    sk = slope_all[idx]
    Ig = np.take_along_axis(Ik, np.broadcast_to(idx[:, None, :], (Bn, n) + idx.shape[1:]), 2)
    Jg = np.take_along_axis(Jk, np.broadcast_to(idx[:, None, :], (Bn, n) + idx.shape[1:]), 2)
    z = lam[:, :, None] * d[:, None, :]
    e = np.exp(z)
    dd = d[:, None, :]
    ukk, skk = uk[:, None, :], sk[:, None, :]
    I = e * Ig + ukk * dd * phi1(z) + skk * dd ** 2 * phi2(z)
    J = dd * e * Ig + e * Jg + ukk * dd ** 2 * dphi1(z) + skk * dd ** 3 * dphi2(z)
    u = np.where(before, 0.0, uk + sk * d)
    I = np.where(before[:, None, :], 0.0, I)
    J = np.where(before[:, None, :], 0.0, J)
    return I, J, u


# ------------------------------------------------------------------ solver

@dataclass(frozen=True)
class ModalSolution:
    """Observables y (B, n_obs, T); dy (B, P, n_obs, T) or None; ok (B,) and reason (B,)."""

    y: np.ndarray
    dy: np.ndarray | None
    ok: np.ndarray
    reason: np.ndarray
    sens_names: tuple[str, ...]


def _eig(ss: StateSpace):
    lam, V = np.linalg.eig(ss.A)
    W = np.linalg.inv(V)
    return lam, V, W


def _health(lam, V, W):
    scale = np.max(np.abs(lam), axis=-1)
    diff = np.abs(lam[:, :, None] - lam[:, None, :])
    n = lam.shape[-1]
    diff[:, np.arange(n), np.arange(n)] = np.inf
    gap = diff.min(axis=(1, 2)) / scale
    cond = np.linalg.norm(V, axis=(1, 2)) * np.linalg.norm(W, axis=(1, 2))
    reason = np.full(lam.shape[0], "", dtype=object)
    reason[~np.all(np.isfinite(lam), axis=-1)] = "non-finite eigenvalues"
    reason[(reason == "") & (lam.real.max(axis=-1) >= 0)] = "unstable: eigenvalue with Re >= 0"
    reason[(reason == "") & (gap < GAP_TOL)] = "near-repeated eigenvalues"
    reason[(reason == "") & ~(cond < COND_TOL)] = "ill-conditioned eigenvectors"
    return reason == "", reason


def modal_derivatives(pb, piezo, names, ss: StateSpace, V, lam, W):
    """G_p = V^-1 dA_s/dp V (B, P, 17, 17) and V^-1 db/dp (B, P, 17) for each name.

    Uses only the rows of the descriptor that change (8..16):
    G = (W[:, 8:] E_vv^-1) (dA_raw V - dE V Lambda), one batched product over all P.
    """
    dAr, dEr = raw_derivatives(pb, piezo, names)             # (B,P,9,17), (B,P,9,9)
    Bn, P = dAr.shape[:2]
    Wt = W[:, :, 8:] @ np.linalg.inv(ss.E[:, 8:, 8:])        # (B,17,9)
    VL = V[:, 8:, :] * lam[:, None, :]                       # rows 8.. of V Lambda (B,9,17)
    X = (dAr.reshape(Bn, P * 9, NSTATE) @ V).reshape(Bn, P, 9, NSTATE)
    X -= dEr @ VL[:, None]
    G = (Wt @ X.transpose(0, 2, 1, 3).reshape(Bn, 9, P * NSTATE))
    G = G.reshape(Bn, NSTATE, P, NSTATE).transpose(0, 2, 1, 3)
    gb = -(Wt[:, None] @ (dEr @ ss.b[:, None, 8:, None]))[..., 0]
    return G, gb


def solve(pb: dict, times: np.ndarray, H: np.ndarray, lagged: np.ndarray, *, piezo: int,
          trace=None, sens: tuple[str, ...] = (), dH: dict | None = None,
          desc=None) -> ModalSolution:
    """Evaluate observables ``y = H z`` at record ``times`` for a batch ``pb``.

    H: (B, n_obs, 17) rows over the state; lagged: (n_obs,) bool, rows evaluated at t - t1.
    trace: a VoltageTrace or None (default profile from V0, t_c, tau_v in ``pb``).
    sens: parameter names for sensitivities: any EOM parameter, t0, t1, V0 (default profile),
    and names in ``dH`` (output-map parameters: name -> (B, n_obs, 17) dH/dp).
    """
    times = np.asarray(times, float)
    Bn = pb["t0"].shape[0]
    dH = dH or {}
    ss = state_space(pb, piezo, desc)
    with np.errstate(all="ignore"):
        lam, V, W = _eig(ss)
    ok, reason = _health(lam, V, W)
    # Replace failed sets by a harmless copy of a good one (results are masked by ``ok``).
    if not ok.all():
        good = int(np.argmax(ok)) if ok.any() else None
        if good is None:
            nanY = np.full((Bn, H.shape[1], times.size), np.nan)
            dy = None if not sens else np.full((Bn, len(sens)) + nanY.shape[1:], np.nan)
            return ModalSolution(nanY, dy, ok, reason, tuple(sens))
        bad = ~ok
        lam[bad], V[bad], W[bad] = lam[good], V[good], W[good]
        for key in ("A", "b", "E"):
            getattr(ss, key)[bad] = getattr(ss, key)[good]
    beta = np.einsum("bij,bj->bi", W, ss.b)
    # Conjugate symmetry: A is real, so modes come in conjugate pairs whose contributions are
    # conjugate. Order modes [Im > 0, real, Im < 0] and keep the first S of them with weights
    # 2 (pair), 1 (real), 0 (padding where a set has fewer pairs than the batch maximum).
    key = np.where(lam.imag > 0, 0, np.where(lam.imag == 0, 1, 2))
    perm = np.argsort(key, axis=1, kind="stable")
    lam = np.take_along_axis(lam, perm, 1)
    V = np.take_along_axis(V, perm[:, None, :], 2)
    W = np.take_along_axis(W, perm[:, :, None], 1)
    beta = np.take_along_axis(beta, perm, 1)
    key = np.take_along_axis(key, perm, 1)
    S = int(np.max(np.sum(key < 2, axis=1)))
    wS = np.choose(key[:, :S], [2.0, 1.0, 0.0])                   # (B, S)
    lamS, betaS = lam[:, :S], beta[:, :S]
    HV = H @ V                                                     # (B, n_obs, 17)
    HVS = HV[:, :, :S] * wS[:, None, :]

    t0 = pb["t0"]
    if trace is None:
        ts = pb["t_c"] + t0
    else:
        ts = t0
    tau = times[None, :] - ts[:, None]
    taus = {False: tau}
    if lagged.any():
        taus[True] = tau - pb["t1"][:, None]

    def conv(tv):
        if trace is None:
            return conv_default(lamS, tv, pb["V0"], pb["tau_v"])
        kt, ku = trace.knots(0.0)
        return conv_trace(lamS, tv, kt, ku)

    conv_res = {k: conv(tv) for k, tv in taus.items()}
    y = np.zeros((Bn, H.shape[1], times.size))
    for lag, (I, J, u) in conv_res.items():
        rows = lagged == lag
        y[:, rows] = np.real(HVS[:, rows] @ (betaS[:, :, None] * I))

    dy = None
    if sens:
        names = tuple(sens)
        dy = np.zeros((Bn, len(names), H.shape[1], times.size))
        eom = [n for n in names if n not in ("t0", "t1", "V0", "t_c") and n not in dH]
        unknown = [n for n in eom if n not in pb]
        if unknown:
            raise KeyError(f"no sensitivity for {unknown}")
        if eom:
            G, gb = modal_derivatives(pb, piezo, eom, ss, V, lam, W)
            P = len(eom)
            n = NSTATE
            with np.errstate(divide="ignore", invalid="ignore"):
                Dm = 1.0 / (lam[:, :, None] - lam[:, None, :])
            Dm[:, np.arange(n), np.arange(n)] = 0.0
            Pm = G * Dm[:, None]
            # only the kept modes i < S are needed as output modes (conjugates follow)
            c = np.einsum("bpij,bj->bpi", Pm[:, :, :S], beta) + gb[:, :, :S]   # (B, P, S)
            dg = np.diagonal(G, axis1=-2, axis2=-1)[:, :, :S] * betaS[:, None]
            nobs = HV.shape[1]
            PmS = Pm[..., :S].transpose(0, 2, 1, 3).reshape(Bn, n, P * S)
            HVP = (HV @ PmS).reshape(Bn, nobs, P, S)
            wS4 = wS[:, None, None, :]
            Lm = (HV[:, :, None, :S] * c[:, None] - HVP * betaS[:, None, None, :]) * wS4
            Nm = HV[:, :, None, :S] * dg[:, None] * wS4
            LN = np.concatenate([Lm, Nm], axis=-1)                      # (B, o, P, 2S)
            for lag, (I, J, u) in conv_res.items():
                rows = lagged == lag
                IJ = np.concatenate([I, J], axis=1)                     # (B, 2S, T)
                sub = LN[:, rows]
                val = (sub.reshape(Bn, -1, 2 * S) @ IJ).reshape(sub.shape[:3] + (times.size,))
                idx = [names.index(e) for e in eom]
                vr = np.real(val).transpose(0, 2, 1, 3)                 # (B, P, o_rows, T)
                for k, j in enumerate(idx):
                    dy[:, j, rows] = vr[:, k]
        for name in names:
            k = names.index(name)
            if name in ("t0", "t_c") or (name == "t1" and lagged.any()):
                for lag, (I, J, u) in conv_res.items():
                    if name == "t1" and not lag:
                        continue
                    rows = lagged == lag
                    rate = lamS[:, :, None] * I + u[:, None, :]
                    zdot = np.real(HVS[:, rows] @ (betaS[:, :, None] * rate))
                    if name == "t_c" and trace is not None:
                        continue  # t_c does not act on a measured trace
                    dy[:, k, rows] = -zdot
            elif name == "V0":
                if trace is not None:
                    raise KeyError("V0 sensitivity is defined for the default profile only")
                dy[:, k] = y / pb["V0"][:, None, None]
            elif name in dH:
                for lag, (I, J, u) in conv_res.items():
                    rows = lagged == lag
                    z = np.real((V[:, :, :S] * wS[:, None, :]) @ (betaS[:, :, None] * I))
                    dy[:, k, rows] = dH[name][:, rows] @ z
    if not ok.all():
        y[~ok] = np.nan
        if dy is not None:
            dy[~ok] = np.nan
    return ModalSolution(y, dy, ok, reason, tuple(sens))
