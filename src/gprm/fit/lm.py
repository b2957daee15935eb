"""Levenberg-Marquardt as in the paper's Algorithm 1 (Sec. 3.1), for a batch of problems run
in lock-step.

One function, :func:`levenberg_marquardt_batch`, is the optimizer. It advances B independent
starting points of the same residual function together, so that one (batched) model
evaluation serves all of them; :func:`levenberg_marquardt` is the single-problem API, a batch
of one with an optional finite-difference Jacobian.

Algorithm 1 as implemented (for every row of the batch independently):

1. residuals ``r`` (their sum of squares is chi-square, Eq. 6 when they are the weighted
   residuals ``D e``) and Jacobian ``J = dr/dx`` at the current point;
2. the damped step solves ``[J^T J + lambda diag(J^T J)] dx = -J^T r``. It is computed from
   the equivalent least-squares problem ``[J; sqrt(lambda diag(J^T J))] dx ~ [-r; 0]`` by a
   QR factorisation (the same step, without squaring the condition number of ``J``);
3. the trial point is evaluated (residuals only when a residual-only function is given: the
   Jacobian is then computed for accepted points only);
4. a trial with a smaller chi-square is **accepted** and lambda is divided by 10; a trial with
   the same or larger chi-square (or non-finite residuals, or outside the bounds) is
   **rejected** -- the parameters stay where they were -- and lambda is multiplied by 10.
   (Algorithm 1 as printed moves to the trial point in both cases; keeping the old point on a
   worse step is what its text and its reference, Gavin 2019, intend, and is what makes
   chi-square non-increasing.)
5. stop when an accepted step changes chi-square by at most ``ftol * chi2 + ftol_abs``
   (epsilon_1 of Algorithm 1, relative and absolute), when chi-square falls to ``chi2_tol``
   or below (epsilon_2), when the iteration limit is reached, or when lambda exceeds
   ``lambda_max`` (no smaller chi-square can be found along the ever shorter steepest-descent
   steps: the point is a minimum to machine precision, or sits against a bound). Optionally
   (``stall_window`` k > 0) also when chi-square fell by at most ``stall_tol`` over the last
   k iterations: epsilon_1 measured over a window instead of one step, which stops a start
   creeping along a flat valley by many small accepted steps (status ``stalled``).

The damped step for every lambda tried at one Jacobian comes from one SVD of the scaled
reduced Jacobian ``R1 diag(d)^-1/2`` = U S V^T (R1 from a thin QR of J, d = diag(J^T J)):
``dx = -diag(d)^-1/2 V diag(s / (s^2 + lambda)) U^T Q1^T r``. This is the exact solution of
the damped normal equations, obtained without forming J^T J, and a rejected step (lambda x 10)
costs O(P^2) instead of a new factorisation.

Bounds (projected Levenberg-Marquardt): the trial point ``x + dx`` is projected onto the box
``lower < x < upper`` (clipped to 1e-9 max(1, |bound|) inside it) before it is evaluated, and
then accepted or rejected by the rule above. A parameter already at a bound (within the
margin) whose step points out of the box is frozen for that step, and the step of the other
parameters is recomputed without it (its Jacobian column zeroed), so they move as if the
bound were an equality. A parameter pushed against a bound therefore stays just inside it
while the others keep moving; merely rejecting steps that leave the box stalls the whole
start there instead. No transform is used, so the Jacobian, the covariance
(Eq. 7) and the iteration path are those of the untransformed problem; the caller reports
parameters that end at a bound (their Eq. 7 errors are not meaningful).

Geodesic acceleration (``geodesic=True``; Transtrum & Sethna 2012, "Improvements to the
Levenberg-Marquardt algorithm for nonlinear least-squares minimization"): the damped step
``v`` is taken as the velocity of a geodesic and corrected by half its acceleration ``a``,
the solution of the same damped system with the second directional derivative ``r''`` of the
residuals along ``v`` in place of ``r``: ``[J^T J + lambda D] a = -J^T r''``, reusing the
factors of the step (O(N P) more per trial). ``r''`` is estimated by one extra residual
evaluation, ``r'' ~ (2/h) [(r(x + h v) - r(x)) / h - J v]`` (``geo_h`` = h). The trial point is
``x + v + a/2``; it is evaluated only if ``2 |a| / |v| <= geo_alpha`` in the damping metric
(``|u|^2 = sum_k D_k u_k^2``), and is otherwise rejected as a worse step (lambda x 10, point
kept). The acceptance rule and the lambda updates are those of Algorithm 1. Rows with a
parameter held at a bound, or whose point ``x + h v`` leaves the box, take the plain step.
It shortens the crawl along narrow curved valleys (MGH17 from start 1: ~500 iterations
with ``damping="max"`` instead of ~2500).

An iteration is one trial step (accepted or rejected), as ``i`` in Algorithm 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

LAMBDA_MIN = 1e-15
BOUND_MARGIN = 1e-9

#: statuses that count as converged
CONVERGED = ("ftol", "chi2_tol", "lambda_max", "stalled")

MESSAGES = {
    "ftol": "chi-square changed by less than the tolerance on an accepted step",
    "chi2_tol": "chi-square fell below the threshold",
    "lambda_max": "no smaller chi-square found with the damping at its limit (a minimum to "
                  "machine precision, or against a bound)",
    "stalled": "chi-square fell by less than the tolerance over the last iterations (window)",
    "max_iter": "iteration limit reached",
    "failed": "residuals or Jacobian not finite at the starting point",
}


@dataclass(frozen=True)
class LMBatchResult:
    """Outcome for each row of the batch (arrays indexed by row)."""

    x: np.ndarray            # (B, P) final points
    chi2: np.ndarray         # (B,) sum of squared residuals at x
    chi2_0: np.ndarray       # (B,) at the start
    iterations: np.ndarray   # (B,) trial steps taken
    converged: np.ndarray    # (B,) bool
    status: np.ndarray       # (B,) str, a key of MESSAGES
    lam: np.ndarray          # (B,) final damping
    nfev: np.ndarray         # (B,) residual evaluations
    njev: np.ndarray         # (B,) Jacobian evaluations
    fun: np.ndarray          # (B, N) residuals at x
    jac: np.ndarray | None   # (B, N, P) Jacobian at x (None unless asked for)


@dataclass(frozen=True)
class LMResult:
    """Outcome of :func:`levenberg_marquardt` (one problem)."""

    x: np.ndarray
    chi2: float
    chi2_0: float
    iterations: int
    converged: bool
    status: str
    message: str
    lam: float
    nfev: int
    njev: int
    fun: np.ndarray
    jac: np.ndarray | None

    @property
    def success(self) -> bool:
        return self.converged


def reduce_jacobian(J: np.ndarray, r: np.ndarray):
    """Thin QR of a batch of Jacobians: ``R1`` (B, k, P), ``Q1^T r`` (B, k) and diag(J^T J)
    (B, P), k = min(N, P); R1 and Q1^T r come from the R factor of ``[J, r]``. The damped
    step depends on J and r only through these (an orthogonal change of the residual space),
    so they are computed once per Jacobian and reused while a start's steps are rejected and
    only lambda changes."""
    B, N, P = J.shape
    k = min(N, P)
    # R of [J, r] is [[R1, Q1^T r], [0, rho]]: one factorisation without forming Q
    R = np.linalg.qr(np.concatenate([J, r[:, :, None]], axis=2), mode="r")
    return R[:, :k, :P], R[:, :k, P], np.einsum("bnp,bnp->bp", J, J)


def _damping_diagonal(d: np.ndarray, dfloor: np.ndarray | None = None):
    """The damping diagonal (B, P) used with diag(J^T J) = ``d``: raised to ``dfloor`` (the
    ``damping="max"`` variant) and, for a zero column (a parameter with no effect, or held
    fixed by zeroing its column), to a tiny fraction of the row's largest entry so the system
    stays solvable; also returns the mask of zero columns, whose steps are set to exactly 0."""
    zero = d == 0
    if dfloor is not None:
        d = np.maximum(d, dfloor)
    dmax = np.max(d, axis=1, keepdims=True)
    return np.maximum(d, np.where(dmax > 0, dmax, 1.0) * 1e-30), zero


def damped_steps_reduced(R1: np.ndarray, qtr: np.ndarray, d: np.ndarray, lam: np.ndarray,
                         dfloor: np.ndarray | None = None) -> np.ndarray:
    """Steps of Algorithm 1 from :func:`reduce_jacobian`'s factors: the least-squares
    solution of ``[R1; sqrt(lam) diag(sqrt(d))] dx ~ [-Q1^T r; 0]``, i.e. of
    ``[J^T J + lam diag(J^T J)] dx = -J^T r``, with the damping diagonal of
    :func:`_damping_diagonal`. Used for the rows with parameters frozen at a bound (their
    columns of R1 and entries of d zeroed: J with those columns zeroed is Q1 times R1 with
    them zeroed, so Q1^T r is unchanged)."""
    B, k, P = R1.shape
    d, zero = _damping_diagonal(d, dfloor)
    A = np.concatenate([R1, np.sqrt(lam[:, None, None] * d[:, None, :])
                        * np.eye(P)[None]], axis=1)           # (B, k+P, P)
    Q, R = np.linalg.qr(A)
    rhs = -np.einsum("bkp,bk->bp", Q[:, :k, :], qtr)
    try:
        out = np.linalg.solve(R, rhs[..., None])[..., 0]
    except np.linalg.LinAlgError:
        out = np.full((B, P), np.nan)
        for b in range(B):
            try:
                out[b] = np.linalg.solve(R[b], rhs[b])
            except np.linalg.LinAlgError:
                pass
    out[zero] = 0.0
    return out


def scaled_svd(R1: np.ndarray, qtr: np.ndarray, d: np.ndarray,
               dfloor: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Factors of the damped steps at one Jacobian for every lambda (module docstring).

    From :func:`reduce_jacobian`'s ``R1`` (B, k, P), ``Q1^T r`` (B, k) and ``d`` = diag(J^T J)
    (B, P), with the same damping diagonal as :func:`damped_steps_reduced` (``dfloor``, a
    tiny floor for zero columns): the SVD ``R1 diag(d)^-1/2 = U S V^T`` gives
    ``W = diag(d)^-1/2 V`` (B, P, m), ``s`` (B, m) and ``g = U^T Q1^T r`` (B, m); then
    :func:`svd_steps` returns the step for any lambda. Rows of W of parameters with a zero
    Jacobian column are zero (their step is exactly 0). A row whose SVD fails (non-finite
    Jacobian) gets NaN factors, hence a NaN step, which the optimiser rejects."""
    d, zero = _damping_diagonal(d, dfloor)
    sq = np.sqrt(d)
    A = R1 / sq[:, None, :]
    B, k, P = A.shape
    m = min(k, P)
    try:
        U, sv, Vt = np.linalg.svd(A, full_matrices=False)
    except np.linalg.LinAlgError:
        U, sv, Vt = np.full((B, k, m), np.nan), np.full((B, m), np.nan), np.full((B, m, P), np.nan)
        for b in range(B):
            try:
                U[b], sv[b], Vt[b] = np.linalg.svd(A[b], full_matrices=False)
            except np.linalg.LinAlgError:
                pass
    W = Vt.transpose(0, 2, 1) / sq[:, :, None]
    W[zero] = 0.0
    return W, sv, np.einsum("bkm,bk->bm", U, qtr)


def svd_steps(W: np.ndarray, sv: np.ndarray, g: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Steps ``[J^T J + lam diag(J^T J)] dx = -J^T r`` from :func:`scaled_svd`'s factors:
    ``dx = -W (s g / (s^2 + lam))``, O(P^2) per row."""
    return -np.einsum("bpm,bm->bp", W, sv * g / (sv * sv + lam[:, None]))


def _chi2(r: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore", invalid="ignore"):
        c = np.sum(r * r, axis=1)
    return np.where(np.isfinite(c), c, np.inf)


def _geodesic_correction(fun, residuals, X, v, r, J, W, sv, lam, dd, free, lo_in, hi_in, h,
                         alpha, nfev, idx):
    """Geodesic acceleration for the rows of a batch (module docstring): returns the
    corrected steps ``v + a/2`` and a (rows,) bool of the rows whose ``2|a|/|v|`` exceeds
    ``alpha`` (to be rejected without evaluation); ``dd`` is the damping diagonal of the
    metric (:func:`_damping_diagonal`). Rows not ``free`` (a parameter held at a
    bound) or whose ``x + h v`` leaves the box keep ``v``. ``nfev`` is updated in place."""
    Xh = X + h * v
    ok = free & np.all(np.isfinite(Xh) & (Xh > lo_in) & (Xh < hi_in), axis=1)
    a = np.zeros_like(v)
    bad = np.zeros(v.shape[0], bool)
    e = np.nonzero(ok)[0]
    if e.size == 0:
        return v, bad
    rh = np.asarray(residuals(Xh[e]) if residuals is not None else fun(Xh[e])[0], float)
    nfev[idx[e]] += 1
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        rvv = (2.0 / h) * ((rh - r[e]) / h - np.einsum("bnp,bp->bn", J[e], v[e]))
        # [J^T J + lam D] a = -J^T r'' with J^T J + lam D = W diag(s^2 + lam) W^T
        c = np.einsum("bpm,bp->bm", W[e], np.einsum("bnp,bn->bp", J[e], rvv))
        a[e] = -np.einsum("bpm,bm->bp", W[e], c / (sv[e] ** 2 + lam[e, None]))
        d = dd[e]
        ratio = 2.0 * np.sqrt(np.sum(d * a[e] ** 2, axis=1) / np.sum(d * v[e] ** 2, axis=1))
        bad[e] = ratio > alpha
    return v + 0.5 * a, bad


def levenberg_marquardt_batch(fun: Callable, X0: np.ndarray, *, residuals: Callable | None = None,
                              max_iter: int = 100, lambda0: float = 1e-2, ftol: float = 1e-8,
                              ftol_abs: float = 0.0, chi2_tol: float = 0.0,
                              lambda_max: float = 1e12, lower=None, upper=None,
                              keep_jacobian: bool = False, damping: str = "current",
                              prune: Callable | None = None, stall_window: int = 0,
                              stall_tol: float = 0.0, geodesic: bool = False,
                              geo_h: float = 0.1, geo_alpha: float = 0.75) -> LMBatchResult:
    """Algorithm 1 for B starting points in lock-step (see the module docstring).

    fun: ``fun(X (b, P)) -> (r (b, N), J (b, N, P))`` for any number b of rows.
    residuals: optional ``residuals(X (b, P)) -> r (b, N)``; when given, trial points are
        evaluated with it and ``fun`` is called only at accepted points (worth it when the
        Jacobian costs much more than the residuals).
    lower, upper: bounds (P,) or scalars; trial points must lie strictly inside.
    damping: ``current`` -- Algorithm 1: lambda diag(J^T J) at the current point; ``max`` --
        lambda times the largest diag(J^T J) seen so far along the row's path (MINPACK's
        scaling). ``max`` keeps a parameter whose Jacobian column fades (an exponential
        rate running to infinity, as from MGH17's first start) damped.
    keep_jacobian: return the Jacobian at the final points (computed if not at hand).
    stall_window, stall_tol: stop a row (status ``stalled``) once chi-square fell by at most
        ``stall_tol`` over its last ``stall_window`` iterations (0: off).
    geodesic, geo_h, geo_alpha: geodesic acceleration (module docstring), its finite-
        difference step h (in units of the step) and its acceptance ratio alpha. Costs one
        more residual evaluation per trial (with ``residuals`` if given, else ``fun``).
    prune: optional ``prune(chi2 (B,), active (B,)) -> (B,) bool`` called each iteration;
        rows it marks stop with status ``pruned`` (used by the multi-start driver, which
        documents its rule).
    """
    X = np.array(X0, dtype=float, copy=True)
    if X.ndim != 2:
        raise ValueError("X0 must be 2-D (B, P)")
    B, P = X.shape
    lo = np.broadcast_to(np.asarray(-np.inf if lower is None else lower, float), (P,))
    hi = np.broadcast_to(np.asarray(np.inf if upper is None else upper, float), (P,))
    # the box the trial points are projected onto: strictly inside the bounds
    with np.errstate(invalid="ignore"):
        near_lo = np.where(np.isfinite(lo), BOUND_MARGIN * np.maximum(1.0, np.abs(lo)), 0.0)
        near_hi = np.where(np.isfinite(hi), BOUND_MARGIN * np.maximum(1.0, np.abs(hi)), 0.0)
    lo_in, hi_in = lo + near_lo, hi - near_hi
    r, J = fun(X)
    r = np.asarray(r, float)
    J = np.array(J, dtype=float)
    if r.ndim != 2 or r.shape[0] != B or J.shape != (B, r.shape[1], P):
        raise ValueError(f"fun must return r (B, N) and J (B, N, P); got {r.shape}, {J.shape}")
    chi2 = _chi2(r)
    chi2_0 = chi2.copy()
    finite_J = np.all(np.isfinite(J), axis=(1, 2))
    status = np.full(B, "", dtype=object)
    active = np.isfinite(chi2) & finite_J
    status[~active] = "failed"
    lam = np.full(B, float(lambda0))
    iters = np.zeros(B, int)
    nfev = np.ones(B, int)
    njev = np.ones(B, int)
    stale = np.zeros(B, bool)            # J not yet evaluated at the (accepted) point
    if damping not in ("current", "max"):
        raise ValueError(f"damping must be 'current' or 'max', got {damping!r}")
    dmax = np.einsum("bnp,bnp->bp", J, J) if damping == "max" else None
    kq = min(J.shape[1], P)
    R1 = np.zeros((B, kq, P))             # factors of the current J (reduce_jacobian)
    QTr = np.zeros((B, kq))
    DJ = np.zeros((B, P))
    SW = np.zeros((B, P, kq))             # and of its damped steps (scaled_svd)
    SS = np.zeros((B, kq))
    SG = np.zeros((B, kq))
    fresh = np.zeros(B, bool)
    stall_window = int(stall_window)
    if stall_window > 0:
        ring = np.empty((stall_window + 1, B))     # chi2 after the last iterations
        ring[0] = chi2

    for it in range(int(max_iter)):
        idx = np.nonzero(active)[0]
        if idx.size == 0:
            break
        if prune is not None:
            cut = np.asarray(prune(chi2, active), bool) & active
            if cut.any():
                status[cut] = "pruned"
                active &= ~cut
                idx = np.nonzero(active)[0]
                if idx.size == 0:
                    break
        st = idx[stale[idx]]
        if st.size:
            rr, JJ = fun(X[st])
            J[st] = JJ
            njev[st] += 1
            stale[st] = False
            fresh[st] = False
            if dmax is not None:
                dmax[st] = np.maximum(dmax[st], np.einsum("bnp,bnp->bp", JJ, JJ))
        dfl = None if dmax is None else dmax[idx]
        new = idx[~fresh[idx]]
        if new.size:
            R1[new], QTr[new], DJ[new] = reduce_jacobian(J[new], r[new])
            SW[new], SS[new], SG[new] = scaled_svd(R1[new], QTr[new], DJ[new],
                                                   None if dmax is None else dmax[new])
            fresh[new] = True
        dx = svd_steps(SW[idx], SS[idx], SG[idx], lam[idx])
        # parameters held at a bound by a step pointing out of the box are frozen and the
        # step of the others recomputed without them (active set)
        Xa = X[idx]
        blocked = (((Xa - lo_in <= near_lo) & (dx < 0)) | ((hi_in - Xa <= near_hi) & (dx > 0)))
        rows = np.nonzero(np.any(blocked, axis=1))[0]
        if rows.size:
            # J with the frozen columns zeroed is Q1 (R1 with them zeroed): same Q1^T r
            keep = ~blocked[rows]
            br = idx[rows]
            dx[rows] = damped_steps_reduced(R1[br] * keep[:, None, :], QTr[br], DJ[br] * keep,
                                            lam[br], None if dfl is None else dfl[rows])
        too_curved = np.zeros(idx.size, bool)
        if geodesic:
            dx, too_curved = _geodesic_correction(
                fun, residuals, Xa, dx, r[idx], J[idx], SW[idx], SS[idx], lam[idx],
                _damping_diagonal(DJ[idx], dfl)[0], ~np.any(blocked, axis=1), lo_in, hi_in,
                geo_h, geo_alpha, nfev, idx)
        Xt = np.clip(Xa + dx, lo_in, hi_in)                  # projection onto the box
        inside = np.all(np.isfinite(Xt) & (Xt > lo) & (Xt < hi), axis=1) & ~too_curved
        chi_t = np.full(idx.size, np.inf)
        ev = np.nonzero(inside)[0]
        rt = Jt = None
        if ev.size:
            if residuals is not None:
                rt = np.asarray(residuals(Xt[ev]), float)
            else:
                rt, Jt = fun(Xt[ev])
                rt, Jt = np.asarray(rt, float), np.asarray(Jt, float)
            chi_t[ev] = _chi2(rt)
            nfev[idx[ev]] += 1
        iters[idx] += 1
        better = chi_t < chi2[idx]
        if Jt is not None:
            better[ev] &= np.all(np.isfinite(Jt), axis=(1, 2))
        acc_local = np.nonzero(better)[0]
        acc = idx[acc_local]
        rej = idx[~better]
        old = chi2[acc]                                     # (fancy indexing: a copy)
        if acc.size:
            pos = np.searchsorted(ev, acc_local)            # rows of rt for accepted rows
            X[acc] = Xt[acc_local]
            r[acc] = rt[pos]
            fresh[acc] = False
            chi2[acc] = chi_t[acc_local]
            if Jt is not None:
                Ja = Jt[pos]
                J[acc] = Ja
                njev[acc] += 1
                if dmax is not None:
                    dmax[acc] = np.maximum(dmax[acc], np.einsum("bnp,bnp->bp", Ja, Ja))
            else:
                stale[acc] = True
            lam[acc] = np.maximum(lam[acc] / 10.0, LAMBDA_MIN)
        lam[rej] *= 10.0
        # stopping rules
        small = (old - chi2[acc]) <= ftol * chi2[acc] + ftol_abs
        low = chi2[acc] <= chi2_tol
        status[acc[low]] = "chi2_tol"
        status[acc[small & ~low]] = "ftol"
        active[acc[small | low]] = False
        stuck = rej[lam[rej] > lambda_max]
        status[stuck] = "lambda_max"
        active[stuck] = False
        if stall_window > 0:
            ring[(it + 1) % (stall_window + 1)] = chi2
            if it + 1 >= stall_window:
                # every active row has taken it + 1 iterations (lock-step from iteration 0)
                before = ring[(it + 1 - stall_window) % (stall_window + 1)]
                flat = active & (before - chi2 <= stall_tol)
                status[flat] = "stalled"
                active &= ~flat
    status[active] = "max_iter"
    jac = None
    if keep_jacobian:
        st = np.nonzero(stale)[0]
        if st.size:
            _, JJ = fun(X[st])
            J[st] = JJ
            njev[st] += 1
        jac = J
    converged = np.isin(status.astype(str), CONVERGED)
    return LMBatchResult(X, chi2, chi2_0, iters, converged, status.astype(str), lam, nfev,
                         njev, r, jac)


def finite_difference_jacobian(residuals: Callable, x: np.ndarray, r0: np.ndarray | None = None,
                               *, method: str = "central", rel_step: float | None = None,
                               lower=None, upper=None) -> np.ndarray:
    """Jacobian of ``residuals(x) -> (N,)`` at ``x`` by finite differences.

    central: (r(x+h) - r(x-h)) / 2h with h = eps^(1/3) max(|x|, 1e-8) (error O(h^2));
    forward: (r(x+h) - r(x)) / h with h = sqrt(eps) max(|x|, 1e-8). Near a bound the
    difference is taken one-sided, inwards.
    """
    x = np.asarray(x, float)
    eps = np.finfo(float).eps
    if rel_step is None:
        rel_step = eps ** (1 / 3) if method == "central" else np.sqrt(eps)
    lo = np.broadcast_to(np.asarray(-np.inf if lower is None else lower, float), x.shape)
    hi = np.broadcast_to(np.asarray(np.inf if upper is None else upper, float), x.shape)
    if r0 is None and method != "central":
        r0 = np.asarray(residuals(x), float)
    cols = []
    for k in range(x.size):
        h = rel_step * max(abs(x[k]), 1e-8)
        e = np.zeros_like(x)
        if method == "central" and x[k] - h > lo[k] and x[k] + h < hi[k]:
            e[k] = h
            xp, xm = x + e, x - e
            h2 = xp[k] - xm[k]
            cols.append((np.asarray(residuals(xp), float) - np.asarray(residuals(xm), float))
                        / h2)
            continue
        if r0 is None:
            r0 = np.asarray(residuals(x), float)
        step = h if x[k] + h < hi[k] else -h
        e[k] = step
        xp = x + e
        cols.append((np.asarray(residuals(xp), float) - r0) / (xp[k] - x[k]))
    return np.stack(cols, axis=-1)


def levenberg_marquardt(residuals: Callable, x0, jacobian: Callable | None = None, *,
                        args: tuple = (), max_iter: int = 1000, lambda0: float = 1e-2,
                        ftol: float = 1e-12, ftol_abs: float = 0.0, chi2_tol: float = 0.0,
                        lambda_max: float = 1e16, lower=None, upper=None,
                        fd_method: str = "central", damping: str = "max",
                        stall_window: int = 0, stall_tol: float = 0.0, geodesic: bool = True,
                        geo_h: float = 0.1, geo_alpha: float = 0.75) -> LMResult:
    """Minimise ``sum(residuals(x)**2)`` by Algorithm 1 (Levenberg-Marquardt).

    residuals: ``residuals(x, *args) -> (N,)``.
    jacobian: ``jacobian(x, *args) -> (N, P)`` (d residuals / d x); None: finite differences
        (``fd_method`` central or forward).
    max_iter, lambda0, ftol, ftol_abs, chi2_tol, lambda_max, lower, upper, damping,
        stall_window, stall_tol, geodesic, geo_h, geo_alpha: see
        :func:`levenberg_marquardt_batch` (this is the batch of one). Defaults here: the
        MINPACK damping (``max``) and geodesic acceleration, with which all 19 NIST StRD
        problems reach their certified values from both starts (plain Algorithm 1,
        ``damping="current", geodesic=False``, loses MGH17 from start 1 to parameter
        evaporation).

    Returns an :class:`LMResult` with ``x``, ``chi2`` (sum of squared residuals),
    ``converged``, ``iterations``, ``status``, ``message``, ``nfev``, ``njev``.
    """
    x0 = np.atleast_1d(np.asarray(x0, float))
    counter = {"nfev": 0}

    def res1(x):
        counter["nfev"] += 1
        return np.atleast_1d(np.asarray(residuals(x, *args), float))

    def jac1(x, r0):
        if jacobian is not None:
            return np.atleast_2d(np.asarray(jacobian(x, *args), float)).reshape(r0.size, x.size)
        return finite_difference_jacobian(res1, x, r0, method=fd_method, lower=lower,
                                          upper=upper)

    def fun(X):
        rs, Js = [], []
        for x in X:
            r = res1(x)
            rs.append(r)
            Js.append(jac1(x, r) if np.all(np.isfinite(r)) else np.full((r.size, x.size),
                                                                         np.nan))
        return np.stack(rs), np.stack(Js)

    def resb(X):
        return np.stack([res1(x) for x in X])

    b = levenberg_marquardt_batch(fun, x0[None], residuals=resb, max_iter=max_iter,
                                  lambda0=lambda0, ftol=ftol, ftol_abs=ftol_abs,
                                  chi2_tol=chi2_tol, lambda_max=lambda_max, lower=lower,
                                  upper=upper, keep_jacobian=True, damping=damping,
                                  stall_window=stall_window, stall_tol=stall_tol,
                                  geodesic=geodesic, geo_h=geo_h, geo_alpha=geo_alpha)
    st = str(b.status[0])
    return LMResult(b.x[0], float(b.chi2[0]), float(b.chi2_0[0]), int(b.iterations[0]),
                    bool(b.converged[0]), st, MESSAGES.get(st, st), float(b.lam[0]),
                    counter["nfev"], int(b.njev[0]),
                    b.fun[0], None if b.jac is None else b.jac[0])
