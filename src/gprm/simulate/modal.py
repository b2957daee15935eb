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

where J_i = dI_i/dlambda_i. The lags enter through tau: dz/dt0 = -z'(t); an output row with
an extra lag (t1 for z_bk, an alignment offset for x_head, y_base, y_head) is evaluated at
tau minus that lag, and its derivative with respect to that lag is minus its rate. The formulas need
distinct eigenvalues; sets whose eigenvalues nearly coincide (relative gap below
``GAP_TOL``) or whose eigenvectors are ill-conditioned are flagged, not silently returned.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from gprm.model.linear import NSTATE, StateSpace, coordinate_derivatives, state_space
from gprm.params.registry import NO_EXACT_SENSITIVITY

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

_D1_SHORT = _D1[:10]          # |w| < _SMALL_J: truncation below 1e-15 relative
_SMALL_J = 0.05


UNIFORM_TOL = 1e-12
"""Relative spread of the sample spacing below which a time axis counts as uniform (then
exp(lambda t) is built from powers, :func:`exp_lt`); the error this admits in exp(lambda t)
is below |lambda| h UNIFORM_TOL, about 1e-12 for the model's fastest modes at 200 kHz."""


def exp_lt(lam, tau, period=None):
    """exp(lam t) (B, n, T) for t = max(tau, 0); lam (B, n), tau (B, T).

    ``period``: tau's columns are consecutive blocks of this length (one per lag group),
    each possibly a uniform grid. Where they are (spacing h equal to ``UNIFORM_TOL``), the
    exponentials are products exp(lam t_1) exp(lam h K i) exp(lam h j) over the live samples
    (t > 0, first live time t_1, sample k = k_1 + K i + j) with K ~ sqrt(T): about 2 sqrt(T)
    complex exponentials per mode and block instead of T, each factor exact to rounding.
    Elsewhere (or for a non-uniform axis) it is np.exp directly.
    """
    Bn, T = tau.shape
    G = T // period if period and period >= 4 and T % period == 0 else 0
    tg = tau.reshape(Bn, G, period) if G else None
    d = None if tg is None else np.diff(tg, axis=2)
    h = 0.0 if d is None else float(np.mean(d))
    if not (h > 0 and np.max(np.abs(d - h)) <= UNIFORM_TOL * h):
        return np.exp(lam[:, :, None] * np.clip(tau, 0.0, None)[:, None, :])
    k1 = np.minimum(np.sum(tg <= 0.0, axis=2), period - 1)             # first live sample
    # first live time (B, G); a block with no live sample gets 0 (its entries are all 1)
    t1 = np.maximum(np.take_along_axis(tg, k1[:, :, None], axis=2)[:, :, 0], 0.0)
    K = int(np.ceil(np.sqrt(period)))
    nb = -(-period // K)
    small = np.exp(lam[:, :, None] * (h * np.arange(K)))                # (B, n, K)
    big = np.exp(lam[:, :, None] * (h * K * np.arange(nb)))             # (B, n, nb)
    powers = (big[:, :, :, None] * small[:, :, None, :]).reshape(Bn, -1, nb * K)
    j = np.arange(period)[None, None, :] - k1[:, :, None]               # (B, G, period)
    idx = np.clip(j, 0, period - 1)
    E = np.take_along_axis(powers[:, :, None, :period], idx[:, None], axis=3)
    E *= np.exp(lam[:, :, None] * t1[:, None, :])[..., None]            # (B, n, G, period)
    E = np.where(((j >= 0) & (tg > 0.0))[:, None], E, 1.0)
    return E.reshape(Bn, -1, T)


def conv_default(lam, tau, V0, tau_v, need_J=True, period=None):
    """I, J = dI/dlam and u for u(s) = V0 (exp(-s/tau_v) - 1), s >= 0 (0 before).

    lam: (B, n) complex; tau: (B, T) real; V0, tau_v: (B,). Returns I, J (B, n, T) (J None
    unless ``need_J``) and u (B, T). ``period``: see :func:`exp_lt`. With a = 1/tau_v,
    L = lam, E = e^{L t}:

        I = V0 [I_a - I_0],  I_a = (E - e^{-a t})/(L + a),  I_0 = (E - 1)/L,
        J = V0 [(t E - I_a)/(L + a) - (t E - I_0)/L].

    They are evaluated with the per-mode factors c1 = -a/(L (L + a)), c2 = 1/(L + a) and
    c3 = 1/L taken out, I = V0 [c1 E + c3 - c2 e^{-a t}] and
    J = V0 [c1 E (t - c2 - c3) + c2^2 e^{-a t} - c3^2]: a few products per entry instead of
    quotients. Where an argument w = L t or (L + a) t is small (|w| < 0.1) these sums
    cancel, and those few entries are recomputed from the accurate forms: I_0 and I_a with
    expm1 (e.g. I_a = e^{-a t} expm1((L + a) t)/(L + a)), J's terms t^2 phi1'(w) by their
    Taylor series where |w| < 0.05 (10 terms, truncation < 1e-15). Elsewhere the sums lose
    at most about three digits to cancellation (relative error ~1e-13 of the term).
    """
    E, ea, I, u, small = conv_default_base(lam, tau, V0, tau_v, period)
    J = conv_default_J(lam, tau, V0, tau_v, E, ea, small) if need_J else None
    return I, J, u


def _factors(lam, tau, tau_v):
    """The per-entry pieces both I and J are made of: a = 1/tau_v, t = max(tau, 0), L, L + a,
    the live entries (t > 0) and the per-mode factors c3 = 1/L, c2 = 1/(L + a)."""
    a = (1.0 / tau_v)[:, None, None]
    t = np.clip(tau, 0.0, None)[:, None, :]
    L = lam[:, :, None]
    La = L + a
    with np.errstate(all="ignore"):
        return a, t, L, La, t > 0, 1.0 / L, 1.0 / La


def conv_default_base(lam, tau, V0, tau_v, period=None):
    """:func:`conv_default` without J: E = e^{L t} (B, n, T), e^{-a t} (B, 1, T), I, u and
    the entries recomputed from the accurate forms (``small``, (B, n, T) bool), so that J can
    be computed later (:func:`conv_default_J`) with the same values as one call with
    ``need_J`` (each entry's arithmetic is the same)."""
    a, t, L, La, live, c3, c2 = _factors(lam, tau, tau_v)
    E = exp_lt(lam, tau, period)
    ea = np.exp(-a * t)
    u = np.where(tau > 0, V0[:, None] * (np.exp(-t[:, 0] / tau_v[:, None]) - 1.0), 0.0)
    with np.errstate(all="ignore"):
        I = (-a * c3 * c2) * E + (c3 - c2 * ea)
    # where an argument is small (|L t| or |(L + a) t| < 0.1) the sums cancel, or I is not
    # finite: those entries come from the accurate forms
    small = ((np.abs(L) * t < 0.1) | (np.abs(La) * t < 0.1) | ~np.isfinite(I)) & live
    if small.any():
        Lm, Lam, tm, eam, Em = _masked(small, L, La, t, ea, E)
        I[small] = _term_a(Lam, tm, eam, Em) - _term_0(Lm, tm, Em)
    I = V0[:, None, None] * np.where(live, I, 0.0)
    return E, ea, I, u, small


def conv_default_J(lam, tau, V0, tau_v, E, ea, small):
    """J = dI/dlam of :func:`conv_default` from the E, e^{-a t} and ``small`` of
    :func:`conv_default_base` for the same arguments."""
    a, t, L, La, live, c3, c2 = _factors(lam, tau, tau_v)
    with np.errstate(all="ignore"):
        J = (-a * c3 * c2) * E * (t - c2 - c3) + (c2 * c2) * ea - c3 * c3
    if small.any():
        Lm, Lam, tm, eam, Em = _masked(small, L, La, t, ea, E)
        t0 = _term_0(Lm, tm, Em)
        ta = _term_a(Lam, tm, eam, Em)
        J[small] = _dterm_a(Lam, tm, eam, Em, ta) - _dterm_0(Lm, tm, Em, t0)
    return V0[:, None, None] * np.where(live, J, 0.0)


def _masked(m, L, La, t, ea, E):
    """L, L + a, t, e^{-a t} and E at the entries ``m`` (E's shape), 1-D."""
    return tuple(np.broadcast_to(v, E.shape)[m] for v in (L, La, t, ea)) + (E[m],)


def _term_0(L, t, E):
    """(E - 1)/L with E = e^{L t}, accurate for small L t (entries, 1-D)."""
    z = L * t
    with np.errstate(all="ignore"):
        return np.where(np.abs(z) < 0.1, np.expm1(z) / L, (E - 1.0) / L)


def _term_a(La, t, ea, E):
    """(E - e^{-a t})/(L + a), accurate for small (L + a) t, and t e^{-a t} at L = -a."""
    za = La * t
    with np.errstate(all="ignore"):
        out = np.where(np.abs(za) < 0.1, ea * np.expm1(za) / La, (E - ea) / La)
    zero = La == 0
    out[zero] = (ea * t)[zero]
    return out


def _dterm_0(L, t, E, term_0):
    """(t E - I_0)/L = t^2 phi1'(L t), by its series for small L t (entries, 1-D)."""
    z = L * t
    with np.errstate(all="ignore"):
        direct = (t * E - term_0) / L
    return np.where(np.abs(z) < _SMALL_J, t * t * _series(z, _D1_SHORT), direct)


def _dterm_a(La, t, ea, E, term_a):
    """(t E - I_a)/(L + a) = e^{-a t} t^2 phi1'((L + a) t), by its series for small
    (L + a) t (entries, 1-D)."""
    za = La * t
    with np.errstate(all="ignore"):
        direct = (t * E - term_a) / La
    return np.where(np.abs(za) < _SMALL_J, ea * t * t * _series(za, _D1_SHORT), direct)


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
    """Observables y (B, n_obs, T); dy (B, n_obs, T, P) or None; ok (B,) and reason (B,);
    the batch's :class:`Spectrum` (to evaluate the same sets again without recomputing it)."""

    y: np.ndarray
    dy: np.ndarray | None
    ok: np.ndarray
    reason: np.ndarray
    sens_names: tuple[str, ...]
    spectrum: "Spectrum | None" = None
    convolutions: "Convolutions | None" = None


@dataclass(frozen=True)
class Convolutions:
    """The default profile's modal convolutions of one :func:`solve` call, kept so that a
    later call for the same sets, times and lags (the Jacobian at a point whose residuals
    were just evaluated) computes only J (:func:`conv_default_J`): the times ``tv`` (B, T'),
    the modes ``lam`` (B, S), V0 and tau_v (B,) they were made for, and E = e^{lam t},
    e^{-t/tau_v}, I (B, S, T'), u (B, T') and the entries taken from the accurate forms
    (``small``). Each row's values are its own (elementwise arithmetic), so a subset of rows
    (``take``) serves a subset of the sets."""

    tv: np.ndarray
    lam: np.ndarray
    V0: np.ndarray
    tau_v: np.ndarray
    E: np.ndarray
    ea: np.ndarray
    I: np.ndarray
    u: np.ndarray
    small: np.ndarray

    def take(self, rows) -> "Convolutions":
        rows = np.asarray(rows)
        return Convolutions(*(getattr(self, f.name)[rows] for f in fields(self)))

    def matching(self, lam, tv, V0, tau_v):
        """(E, ea, I, u, small) for these modes (the first S of each row's), times and drive, or
        None where they are not exactly the ones these were made for."""
        S = lam.shape[1]
        if (S > self.lam.shape[1] or tv.shape != self.tv.shape
                or not np.array_equal(tv, self.tv) or not np.array_equal(V0, self.V0)
                or not np.array_equal(tau_v, self.tau_v)
                or not np.array_equal(lam, self.lam[:, :S])):
            return None
        return self.E[:, :S], self.ea, self.I[:, :S], self.u, self.small[:, :S]


@dataclass(frozen=True)
class Spectrum:
    """The eigen-decomposition A = V diag(lam) V^-1 (W = V^-1) of a batch's state matrix, its
    state space ``ss`` and health ``ok``/``reason``; failed sets hold a copy of a good set
    (their results are masked). It depends on the parameter sets only, not on the times,
    outputs or sensitivities asked for, and each row is computed independently of the other
    rows (LAPACK per matrix), so a row can be reused bit for bit."""

    ss: StateSpace
    lam: np.ndarray
    V: np.ndarray
    W: np.ndarray
    ok: np.ndarray
    reason: np.ndarray

    def take(self, rows) -> "Spectrum":
        """The spectrum of a subset (or reordering) of the batch's sets."""
        rows = np.asarray(rows)
        ss = StateSpace(self.ss.A[rows], self.ss.b[rows], self.ss.E[rows])
        return Spectrum(ss, self.lam[rows], self.V[rows], self.W[rows], self.ok[rows],
                        self.reason[rows])


def spectrum(pb: dict, piezo: int, desc=None) -> Spectrum:
    """Eigen-decomposition of the state matrix for a batch ``pb`` (see :class:`Spectrum`)."""
    ss = state_space(pb, piezo, desc)
    with np.errstate(all="ignore"):
        lam, V = np.linalg.eig(ss.A)
        W = _inv(V)
    ok, reason = _health(lam, V, W)
    # Replace failed sets by a harmless copy of a good one (results are masked by ``ok``).
    if not ok.all() and ok.any():
        good = int(np.argmax(ok))
        bad = ~ok
        lam[bad], V[bad], W[bad] = lam[good], V[good], W[good]
        for key in ("A", "b", "E"):
            getattr(ss, key)[bad] = getattr(ss, key)[good]
    return Spectrum(ss, lam, V, W, ok, reason)


def _inv(V):
    """Batched inverse; sets whose eigenvector matrix is exactly singular get NaN."""
    try:
        return np.linalg.inv(V)
    except np.linalg.LinAlgError:
        W = np.full_like(V, np.nan)
        for k in range(V.shape[0]):
            try:
                W[k] = np.linalg.inv(V[k])
            except np.linalg.LinAlgError:
                pass
        return W


def _health(lam, V, W):
    with np.errstate(all="ignore"):
        scale = np.max(np.abs(lam), axis=-1)
        diff = np.abs(lam[:, :, None] - lam[:, None, :])
        n = lam.shape[-1]
        diff[:, np.arange(n), np.arange(n)] = np.inf
        gap = diff.min(axis=(1, 2)) / scale
        cond = np.linalg.norm(V, axis=(1, 2)) * np.linalg.norm(W, axis=(1, 2))
        smallest = np.min(np.abs(lam), axis=-1) / scale
    reason = np.full(lam.shape[0], "", dtype=object)
    reason[~np.all(np.isfinite(lam), axis=-1)] = "non-finite eigenvalues"
    reason[(reason == "") & (smallest < 1e-12)] = ("singular stiffness: a free (zero-frequency) "
                                                   "mode")
    reason[(reason == "") & (lam.real.max(axis=-1) >= 0)] = "unstable: eigenvalue with Re >= 0"
    reason[(reason == "") & (gap < GAP_TOL)] = "near-repeated eigenvalues"
    reason[(reason == "") & ~(cond < COND_TOL)] = "ill-conditioned eigenvectors"
    return reason == "", reason


# rows of the state holding the 9 coordinates (8 positions and q); velocity rows 8..15
_COORD_ROWS = np.r_[0:8, 16]
_SPECIAL = ("t0", "t1", "V0", "t_c")
LAG_PARAMS = ("t1", "dt_x_head", "dt_y_base", "dt_y_head")
"""Parameters that only shift output rows in time (never in the equations of motion)."""


def _row_lags(lags, nobs: int) -> tuple[tuple[str, ...], ...]:
    """Per-row lag names; a boolean mask (the older form: True = lagged by t1) is accepted."""
    if isinstance(lags, np.ndarray) and lags.dtype == bool:
        return tuple(("t1",) if f else () for f in lags)
    lags = tuple(tuple(x) for x in lags)
    if len(lags) != nobs:
        raise ValueError(f"{len(lags)} row lags for {nobs} rows")
    return lags


def lag_groups(pb: dict, lags, Bn: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Rows with equal extra lag (B,) in every set share one group: ``[(lag, rows mask)]``.

    ``lags[r]`` names the parameters whose sum is row r's lag (missing from ``pb``: 0). Rows
    whose lags are equal for the whole batch (e.g. every alignment offset 0) are merged, so
    the convolutions are computed once per distinct lag, not once per row.
    """
    groups: list[tuple[np.ndarray, np.ndarray]] = []
    cache: dict[tuple[str, ...], np.ndarray] = {}
    for r, names in enumerate(lags):
        key = tuple(sorted(names))
        if key not in cache:
            v = np.zeros(Bn)
            for n in key:
                if n in pb:
                    v = v + np.broadcast_to(np.asarray(pb[n], float), (Bn,))
            cache[key] = v
        lag = cache[key]
        for glag, rows in groups:
            if np.array_equal(glag, lag):
                rows[r] = True
                break
        else:
            rows = np.zeros(len(lags), bool)
            rows[r] = True
            groups.append((lag, rows))
    return groups


def _real_matmul(a, b):
    """Re(a @ b) for complex a, b without forming the complex product."""
    return a.real @ b.real - a.imag @ b.imag


def solve(pb: dict, times: np.ndarray, H: np.ndarray, lags, *, piezo: int,
          trace=None, sens: tuple[str, ...] = (), dH: dict | None = None,
          desc=None, spec: Spectrum | None = None,
          conv: Convolutions | None = None, keep_conv: bool = False) -> ModalSolution:
    """Evaluate observables ``y = H z`` at record ``times`` for a batch ``pb``.

    H: (B, n_obs, 17) rows over the state. lags: per row, a tuple of parameter names whose
    sum is the row's extra lag (row r is evaluated at t - lag_r, on top of t0, which acts
    on the input); ``()`` for none. A boolean mask (True: lagged by t1) is accepted too.
    trace: a VoltageTrace or None (default profile from V0, t_c, tau_v in ``pb``).
    sens: parameter names for sensitivities: any EOM parameter, t0, any lag parameter
    (``LAG_PARAMS``; zero for rows it does not lag), V0 (default profile), and names in
    ``dH`` (output-map parameters: name -> (B, n_obs, 17) dH/dp).

    Sensitivities of an EOM parameter p (module docstring) need, per kept mode i,
    c_i = sum_j G_ij beta_j / (lambda_i - lambda_j) + (V^-1 db)_i and G_ii, and per output
    row o and kept mode j, sum_i (HV)_oi G_ij / (lambda_i - lambda_j). With
    G = Psi X, Psi = (V^-1)[:, velocity rows] E_vv^-1 (left eigenvectors on the equations) and
    X = -(dK Xi + dC Xi Lambda + dM Xi Lambda^2) (Xi: coordinate rows of V), all three are
    contractions of one real matrix product [rows of Y^T and D beta Y^T] @ dQ over all P
    parameters at once, where Y = [Xi; Xi Lambda; Xi Lambda^2] and dQ stacks dK, dC, dM; the
    17 x 17 matrices G are never formed.

    spec: the sets' :class:`Spectrum` from an earlier call (skips the eigen-decomposition).
    conv: the :class:`Convolutions` an earlier call kept (``keep_conv``) for the same sets;
    used where they match these modes, times and drive exactly (then only J is computed),
    ignored otherwise.
    """
    times = np.asarray(times, float)
    Bn = pb["t0"].shape[0]
    T = times.size
    nobs = H.shape[1]
    dH = dH or {}
    names = tuple(sens)
    lags = _row_lags(lags, nobs)
    spec = spectrum(pb, piezo, desc) if spec is None else spec
    ss, lam, V, W, ok, reason = spec.ss, spec.lam, spec.V, spec.W, spec.ok, spec.reason
    if not ok.any():
        nanY = np.full((Bn, nobs, T), np.nan)
        dy = None if not names else np.full(nanY.shape + (len(names),), np.nan)
        return ModalSolution(nanY, dy, ok, reason, names, spec)
    # Conjugate symmetry: A is real, so modes come in conjugate pairs whose contributions are
    # conjugate. Order modes [Im > 0, real, Im < 0] and keep the first S of them with weights
    # 2 (pair), 1 (real), 0 (padding where a set has fewer pairs than the batch maximum).
    key = np.where(lam.imag > 0, 0, np.where(lam.imag == 0, 1, 2))
    perm = np.argsort(key, axis=1, kind="stable")
    lam = np.take_along_axis(lam, perm, 1)
    V = np.take_along_axis(V, perm[:, None, :], 2)
    W = np.take_along_axis(W, perm[:, :, None], 1)
    key = np.take_along_axis(key, perm, 1)
    S = int(np.max(np.sum(key < 2, axis=1)))
    wS = np.choose(key[:, :S], [2.0, 1.0, 0.0])                   # (B, S)
    lamS = lam[:, :S]
    betaS = np.einsum("bij,bj->bi", W[:, :S], ss.b)               # (B, S)
    HV = H @ V                                                     # (B, n_obs, 17)
    HVw = HV[:, :, :S] * (wS * betaS)[:, None, :]                  # (B, n_obs, S)

    t0 = pb["t0"]
    ts = pb["t_c"] + t0 if trace is None else t0
    tau = times[None, :] - ts[:, None]
    # one group per distinct row lag; all groups' times in one evaluation of the convolutions
    grouped = lag_groups(pb, lags, Bn) if nobs else [(np.zeros(Bn), np.zeros(0, bool))]
    groups = [rows for _, rows in grouped]
    tv = np.concatenate([tau - g[:, None] if g.any() else tau for g, _ in grouped], axis=1)
    kept = None
    if trace is None:
        V0, tau_v = pb["V0"], pb["tau_v"]
        parts = None if conv is None else conv.matching(lamS, tv, V0, tau_v)
        E, ea, I, u, small = parts if parts is not None else conv_default_base(
            lamS, tv, V0, tau_v, period=T)
        J = conv_default_J(lamS, tv, V0, tau_v, E, ea, small) if names else None
        if keep_conv:
            kept = Convolutions(tv, lamS, V0, tau_v, E, ea, I, u, small)
    else:
        kt, ku = trace.knots(0.0)
        I, J, u = conv_trace(lamS, tv, kt, ku)
    conv_res = []
    for k in range(len(groups)):
        sl = slice(k * T, (k + 1) * T)
        conv_res.append((I[..., sl], None if J is None else J[..., sl], u[:, sl]))
    y = np.empty((Bn, nobs, T))
    for k, rows in enumerate(groups):
        y[:, rows] = _real_matmul(HVw[:, rows], conv_res[k][0])

    dy = None
    if names:
        dyT = np.zeros((Bn, T, nobs, len(names)))                 # filled in (B, T, o, P)
        dy = dyT.transpose(0, 2, 1, 3)                              # (B, o, T, P) view
        lag_names = set(LAG_PARAMS).union(*map(set, lags))
        eom = [n for n in names if n not in _SPECIAL and n not in lag_names and n not in dH]
        unknown = [n for n in eom if n not in pb or n in NO_EXACT_SENSITIVITY]
        if unknown:
            raise KeyError(f"no sensitivity for {unknown}" + (
                " (tau_v acts on the input profile: difference the outputs instead)"
                if "tau_v" in unknown else ""))
        if eom:
            _eom_sensitivities(pb, piezo, eom, ss, lam, V, W, HV, S, wS, betaS, conv_res,
                               groups, dyT, np.array([names.index(e) for e in eom]))
        rates: dict[int, np.ndarray] = {}

        def rate(k):
            """Re of H z'(t - lag) for group k's rows (B, n_rows, T), computed once."""
            if k not in rates:
                I, J, u = conv_res[k]
                rows = groups[k]
                rates[k] = _real_matmul(HVw[:, rows], lamS[:, :, None] * I + u[:, None, :])
            return rates[k]

        for j, name in enumerate(names):
            if name in ("t0", "t_c"):
                if name == "t_c" and trace is not None:
                    continue  # t_c does not act on a measured trace
                for k, rows in enumerate(groups):
                    dy[..., j][:, rows] = -rate(k)
            elif name in lag_names:
                # d/d(lag) of y(t - lag) = -y'(t - lag), on the rows this lag acts on
                acts = np.array([name in lg for lg in lags], bool)
                for k, rows in enumerate(groups):
                    sub = acts[rows]
                    if sub.any():
                        dy[..., j][:, rows & acts] = -rate(k)[:, sub]
            elif name == "V0":
                if trace is not None:
                    raise KeyError("V0 sensitivity is defined for the default profile only")
                dy[..., j] = y / pb["V0"][:, None, None]
            elif name in dH:
                VS = V[:, :, :S] * (wS * betaS)[:, None, :]
                acts = np.any(dH[name] != 0, axis=(0, 2))
                for k, rows in enumerate(groups):
                    if not (rows & acts).any():
                        continue
                    z = _real_matmul(VS, conv_res[k][0])            # (B, 17, T)
                    dy[..., j][:, rows] = dH[name][:, rows] @ z
    if not ok.all():
        y[~ok] = np.nan
        if dy is not None:
            dy[~ok] = np.nan
    return ModalSolution(y, dy, ok, reason, names, spec, kept)


def _sparse_product(R, sd):
    """R (B, r, 27) @ dQ (B, 27, 9 P) where dQ is given by its non-zero entries: one batched
    product over only the columns of R that meet a non-zero entry (17 of 27 for the fitted
    set) and only the target columns (a, p) that receive one (70 of 207). (Alternatives
    measured: gather-and-reduce and per-entry updates with the batch innermost were not faster
    once the result is laid out for the contractions that follow.)"""
    Bn, r, _ = R.shape
    out = np.zeros((Bn, r, 9 * sd.n_params))
    if sd.e.size == 0:
        return out
    col = sd.a * sd.n_params + sd.p
    ue, ei = np.unique(sd.e, return_inverse=True)
    uc, ci = np.unique(col, return_inverse=True)
    dQc = np.zeros((Bn, ue.size, uc.size))
    dQc[:, ei, ci] = sd.vals.reshape(Bn, -1)       # (e, a, p) triples are unique
    out[:, :, uc] = R[:, :, ue] @ dQc
    return out


def _eom_sensitivities(pb, piezo, eom, ss, lam, V, W, HV, S, wS, betaS, conv_res, groups,
                       dyT, idx):
    """dy/dp for parameters ``eom`` of the equations of motion (see ``solve``), written into
    ``dyT[:, :, :, idx]`` (dyT: (B, T, n_obs, P_all))."""
    Bn, nobs = HV.shape[:2]
    P = len(eom)
    n = NSTATE
    sd = coordinate_derivatives(pb, piezo, eom)
    XiT = V[:, _COORD_ROWS, :].transpose(0, 2, 1)                  # (B, 17, 9): Xi^T
    YT = np.concatenate([XiT, XiT * lam[:, :, None], XiT * (lam ** 2)[:, :, None]], axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        D = 1.0 / (lam[:, :S, None] - lam[:, None, :])             # (B, S, 17): 1/(l_i - l_j)
    D[:, np.arange(S), np.arange(S)] = 0.0
    beta = np.einsum("bij,bj->bi", W, ss.b)
    DbYT = (D * beta[:, None, :]) @ YT                             # (B, S, 27)
    # db = -E^-1 dE b: only the (velocity, q) rows of E change; as a vector over dQ's columns
    bb = np.zeros((Bn, 1, 27))
    bb[:, 0, 9 + 8] = ss.b[:, 16]                                  # dC[:, q] * b_q
    bb[:, 0, 18:26] = ss.b[:, 8:16]                                # dM[:, :8] * b_v
    R = np.concatenate([YT[:, :S].real, DbYT.real, YT[:, :S].imag, DbYT.imag, bb], axis=1)
    out = _sparse_product(R, sd).reshape(Bn, 4 * S + 1, 9, P)     # R @ dQ, (a, p) columns
    Xs = np.empty((Bn, S, 9, P), complex)                          # X[:, a, j] for j < S
    Xs.real = out[:, :S]
    Xs.imag = out[:, 2 * S:3 * S]
    Xs *= -1.0
    c1 = np.empty((Bn, S, 9, P), complex)                          # sum_j D_ij beta_j X[:, a, j]
    c1.real = out[:, S:2 * S]
    c1.imag = out[:, 3 * S:4 * S]
    c1 += out[:, None, 4 * S]                                      # + dE b on the equations
    c1 *= -1.0
    Psi = W[:, :, 8:] @ np.linalg.inv(ss.E[:, 8:, 8:])             # (B, 17, 9)
    PsiS = Psi[:, :S, None, :]                                     # (B, S, 1, 9)
    c = (PsiS @ c1)[:, :, 0, :]                                    # (B, S, P)
    dg = (PsiS @ Xs)[:, :, 0, :] * betaS[:, :, None]               # G_ii beta_i
    # Z[j, o, a] = sum_i HV[o, i] D'[i, j] Psi[i, a] with D'[i, j] = 1/(l_i - l_j), j < S
    Dc = np.zeros((Bn, n, S), complex)
    with np.errstate(divide="ignore", invalid="ignore"):
        Dc[:] = 1.0 / (lam[:, :, None] - lam[:, None, :S])
    Dc[:, np.arange(S), np.arange(S)] = 0.0
    HD = HV[:, None, :, :] * Dc.transpose(0, 2, 1)[:, :, None, :]  # (B, S, o, 17)
    Z = (HD.reshape(Bn, S * nobs, n) @ Psi).reshape(Bn, S, nobs, 9)
    HVP = Z @ Xs                                                   # (B, S, o, P)
    # dy[o, t, p] = Re sum_i (L[i, o, p] I_i(t) + N[i, o, p] J_i(t)), i < S
    HVt = HV[:, :, :S].transpose(0, 2, 1)[..., None]               # (B, S, o, 1)
    w = wS[:, :, None, None]
    L = (HVt * c[:, :, None, :] - betaS[:, :, None, None] * HVP) * w
    N = HVt * (dg * wS[:, :, None])[:, :, None, :]                 # (B, S, o, P)
    LN = np.concatenate([L.real, L.imag, N.real, N.imag], axis=1)  # (B, 4S, o, P)
    T = conv_res[0][0].shape[-1]
    for k, rows in enumerate(groups):
        I, J, _ = conv_res[k]
        IJ = np.concatenate([I.real, -I.imag, J.real, -J.imag], axis=1).transpose(0, 2, 1)
        r = np.flatnonzero(rows)
        if r.size == 0:
            continue
        LNr = LN[:, :, r].reshape(Bn, 4 * S, r.size * P)
        val = (IJ @ LNr).reshape(Bn, T, r.size, P)
        if np.array_equal(r, np.arange(r[0], r[-1] + 1)):
            dyT[:, :, r[0]:r[-1] + 1, idx] = val
        else:
            for k, rr in enumerate(r):
                dyT[:, :, rr, idx] = val[:, :, k]
