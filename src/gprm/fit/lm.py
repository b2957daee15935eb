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

Trust-region step control (``step_bound`` set; not used by the multi-start fit): instead of
Algorithm 1's lambda / 10 and x 10, lambda is chosen each iteration so that the step's scaled
length ``|D dx|`` (D^2 the damping diagonal, MINPACK's column scaling with ``damping="max"``)
is at most a bound delta -- lambda = 0 (the Gauss-Newton step) when that step is within it.
The SVD factors give ``|D dx| = |s g / (s^2 + lambda)|`` for any lambda, so the lambda of a
given bound is a scalar root (Newton's method on ``1/|D dx| - 1/delta``, as in More 1978).
delta starts at ``step_bound |D x0|`` and follows the ratio of the actual to the predicted
(linear-model) decrease of chi-square: halved (or cut further, down to 1/10) below 1/4,
doubled above 3/4. A step is accepted when chi-square decreases by at least 1e-4 of the
prediction. ``ftol`` then asks both decreases to be small, and a row stops (``xtol``) when
delta falls to ``xtol |D x|``. The bound keeps the first steps from a far start short: from
MGH10's first start the unbounded Gauss-Newton-like steps of Algorithm 1 throw the point into
a valley at b1 -> 0, b2, b3 -> infinity, where it crawls for thousands of iterations.

The standalone :func:`levenberg_marquardt` runs Algorithm 1 (MINPACK damping, geodesic
acceleration) and, only if that ends at the iteration limit, once more from the start with the
trust-region step control (``fallback``), returning the run with the smaller chi-square.

An iteration is one trial step (accepted or rejected), as ``i`` in Algorithm 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

LAMBDA_MIN = 1e-15
#: initial step bound (MINPACK's ``factor``) of the standalone optimizer's fallback run
FALLBACK_STEP_BOUND = 100.0
BOUND_MARGIN = 1e-9

#: statuses that count as converged
CONVERGED = ("ftol", "chi2_tol", "lambda_max", "stalled", "xtol")

MESSAGES = {
    "ftol": "chi-square changed by less than the tolerance on an accepted step",
    "chi2_tol": "chi-square fell below the threshold",
    "lambda_max": "no smaller chi-square found with the damping at its limit (a minimum to "
                  "machine precision, or against a bound)",
    "stalled": "chi-square fell by less than the tolerance over the last iterations (window)",
    "xtol": "the step bound (trust region) fell below xtol times the scaled size of x",
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


def _scaled_norms(sv: np.ndarray, g: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """``|D dx|`` of the damped steps of :func:`svd_steps` (D = sqrt of the damping diagonal):
    D W has orthonormal columns, so it is ``|s g / (s^2 + lam)|``; singular values 0 give 0
    (their direction is not in the range of J)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(sv > 0, sv * g / (sv * sv + lam[:, None]), 0.0)
    return np.sqrt(np.sum(c * c, axis=1))


def trust_region_lambda(sv: np.ndarray, g: np.ndarray, delta: np.ndarray,
                        n_iter: int = 40) -> np.ndarray:
    """The damping lambda whose step has scaled length ``|D dx| = delta`` (rows (B,)), or 0
    where the Gauss-Newton step (lambda = 0) is already within 1.1 delta: the step-bound
    (trust-region) form of Levenberg-Marquardt (More 1978, as MINPACK's ``lmpar``).

    ``phi(lambda) = |s g / (s^2 + lambda)|`` decreases from phi(0) to 0; Newton's method on
    ``1/phi(lambda) - 1/delta`` (concave in lambda) from lambda = 0 increases monotonically
    to the root; it stops within 10 percent of delta, as MINPACK does."""
    lam = np.zeros(delta.shape)
    phi = _scaled_norms(sv, g, lam)
    todo = phi > 1.1 * delta
    for _ in range(n_iter):
        if not todo.any():
            break
        i = np.nonzero(todo)[0]
        s2 = sv[i] * sv[i]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            c = np.where(sv[i] > 0, sv[i] * g[i] / (s2 + lam[i, None]), 0.0)
            ph = np.sqrt(np.sum(c * c, axis=1))
            dph = -np.sum(c * c / (s2 + lam[i, None]), axis=1) / ph      # d phi / d lambda
            # Newton on 1/phi - 1/delta: lambda += (phi - delta) phi / (delta |phi'|)
            step = (ph - delta[i]) * ph / (delta[i] * -dph)
        step = np.where(np.isfinite(step) & (step > 0), step, 0.0)
        lam[i] = lam[i] + step
        phi[i] = _scaled_norms(sv[i], g[i], lam[i])
        todo[i] = (np.abs(phi[i] - delta[i]) > 0.1 * delta[i]) & (step > 0)
    return lam


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


def _trust_region_update(better, chi_t, chi2, dx, R1, qtr, dd, lam, delta, idx, ftol):
    """Trust-region bookkeeping for the rows ``idx`` of one iteration: the ratio of the actual
    to the predicted decrease of chi-square (predicted by the linear model, ``|Q1^T r|^2 -
    |Q1^T r + R1 dx|^2``), acceptance (chi-square decreases by at least 1e-4 of the
    prediction) and the update of the step bound ``delta`` (in place), after More (1978):
    shrink it when the ratio is below 1/4 (by 1/2, or by the factor a quadratic along the
    step suggests, never below 1/10), double it when the ratio is above 3/4 or the step was
    a Gauss-Newton step. Returns the accepted rows and, per row, whether both the actual
    and the predicted decrease are within ``ftol`` of chi-square (MINPACK's ftol test)."""
    pnorm = np.sqrt(np.sum(dd * dx * dx, axis=1))
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        lin = qtr + np.einsum("bkp,bp->bk", R1, dx)
        pred = np.sum(qtr * qtr, axis=1) - np.sum(lin * lin, axis=1)
        act = chi2 - chi_t                                   # -inf for rejected trials
        ratio = np.where(pred > 0, act / pred, -np.inf)
        # directional derivative of chi2 along dx at 0: 2 r^T J dx = -2 (|J dx|^2 + lam|D dx|^2)
        jdx = np.sum((lin - qtr) ** 2, axis=1)
        dirder = -(jdx + lam * pnorm * pnorm)
        # step length that minimises the quadratic through chi2, dirder and chi_t, relative
        shrink = np.where(np.isfinite(act) & (act < 0), 0.5 * dirder / (dirder + 0.5 * act), 0.5)
    shrink = np.where(np.isfinite(shrink), shrink, 0.1)
    shrink = np.where((chi_t >= 100.0 * chi2) | (shrink < 0.1), 0.1, np.minimum(shrink, 0.5))
    d = delta[idx]
    low = ~(ratio >= 0.25)
    grow = ~low & ((lam == 0) | (ratio >= 0.75))
    d = np.where(low, shrink * np.minimum(d, 10.0 * pnorm), d)
    d = np.where(grow, 2.0 * pnorm, d)
    delta[idx] = np.where(np.isfinite(d) & (d > 0), d, delta[idx] * 0.1)
    accepted = better & (ratio >= 1e-4)
    small_pred = (np.abs(act) <= ftol * chi2) & (pred <= ftol * chi2) & (ratio <= 2.0)
    return accepted, small_pred


def levenberg_marquardt_batch(fun: Callable, X0: np.ndarray, *, residuals: Callable | None = None,
                              max_iter: int = 100, lambda0: float = 1e-2, ftol: float = 1e-8,
                              ftol_abs: float = 0.0, chi2_tol: float = 0.0,
                              lambda_max: float = 1e12, lower=None, upper=None,
                              keep_jacobian: bool = False, damping: str = "current",
                              prune: Callable | None = None, stall_window: int = 0,
                              stall_tol: float = 0.0, geodesic: bool = False,
                              geo_h: float = 0.1, geo_alpha: float = 0.75,
                              step_bound: float | None = None,
                              xtol: float = 1e-15) -> LMBatchResult:
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
    step_bound: None -- Algorithm 1's damping update (lambda / 10 on an accepted step,
        x 10 on a rejected one). A number -- trust-region step control instead (module
        docstring): lambda is chosen each iteration so that the step's scaled length
        ``|D dx|`` (D^2 = the damping diagonal) is at most the bound delta, which starts at
        ``step_bound * |D x0|`` (``step_bound`` if that is 0, MINPACK's ``factor``) and is
        updated from the ratio of the actual to the predicted decrease of chi-square; a step
        is accepted if chi-square decreases by at least 1e-4 of the predicted decrease; ``ftol``
        then needs both decreases small, and a row stops with status ``xtol`` once delta
        falls to ``xtol * |D x|``. Not used by the multi-start fit.
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
    tr = step_bound is not None
    if tr:
        dd0 = _damping_diagonal(np.einsum("bnp,bnp->bp", J, J), dmax)[0]
        delta = float(step_bound) * np.sqrt(np.sum(dd0 * X * X, axis=1))
        delta = np.where(np.isfinite(delta) & (delta > 0), delta, float(step_bound))
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
        if tr:
            lam[idx] = trust_region_lambda(SS[idx], SG[idx], delta[idx])
            with np.errstate(divide="ignore", invalid="ignore"):   # lambda 0: pseudo-inverse
                c = np.where(SS[idx] > 0, SS[idx] * SG[idx] / (SS[idx] ** 2 + lam[idx, None]),
                             0.0)
            dx = -np.einsum("bpm,bm->bp", SW[idx], c)
        else:
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
        if tr:
            better, small_pred = _trust_region_update(
                better, chi_t, chi2[idx], dx, R1[idx], QTr[idx],
                _damping_diagonal(DJ[idx], dfl)[0], lam[idx], delta, idx, ftol)
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
            if not tr:
                lam[acc] = np.maximum(lam[acc] / 10.0, LAMBDA_MIN)
        if not tr:
            lam[rej] *= 10.0
        # stopping rules
        small = (old - chi2[acc]) <= ftol * chi2[acc] + ftol_abs
        if tr:
            small &= small_pred[acc_local]
        low = chi2[acc] <= chi2_tol
        status[acc[low]] = "chi2_tol"
        status[acc[small & ~low]] = "ftol"
        active[acc[small | low]] = False
        if tr:
            xn = np.sqrt(np.sum(_damping_diagonal(DJ[idx], dfl)[0] * X[idx] ** 2, axis=1))
            tiny = idx[active[idx] & (delta[idx] <= xtol * xn)]
            status[tiny] = "xtol"
            active[tiny] = False
        else:
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
                        geo_h: float = 0.1, geo_alpha: float = 0.75,
                        step_bound: float | None = None, xtol: float = 1e-15,
                        fallback: bool = True) -> LMResult:
    """Minimise ``sum(residuals(x)**2)`` by Algorithm 1 (Levenberg-Marquardt).

    residuals: ``residuals(x, *args) -> (N,)``.
    jacobian: ``jacobian(x, *args) -> (N, P)`` (d residuals / d x); None: finite differences
        (``fd_method`` central or forward).
    max_iter, lambda0, ftol, ftol_abs, chi2_tol, lambda_max, lower, upper, damping,
        stall_window, stall_tol, geodesic, geo_h, geo_alpha: see
        :func:`levenberg_marquardt_batch` (this is the batch of one). Defaults here: the
        MINPACK damping (``max``) and geodesic acceleration (plain Algorithm 1,
        ``damping="current", geodesic=False``, loses MGH17 from start 1 to parameter
        evaporation).
    step_bound, xtol: trust-region step control instead of Algorithm 1's lambda updates
        (``levenberg_marquardt_batch``); None (default): Algorithm 1.
    fallback: when the run (Algorithm 1) stops at ``max_iter``, run once more from ``x0``
        with trust-region step control (step bound ``FALLBACK_STEP_BOUND`` = 100, MINPACK's
        ``factor``; no geodesic acceleration; the other options unchanged) and return the run
        with the smaller chi-square; ``iterations``, ``nfev`` and ``njev`` then count both
        runs. With these defaults all 27 NIST StRD problems reach their certified values to
        at least 4 digits from both starts (MGH10 from start 1 through the fallback).

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

    opts = dict(residuals=resb, max_iter=max_iter, lambda0=lambda0, ftol=ftol,
                ftol_abs=ftol_abs, chi2_tol=chi2_tol, lambda_max=lambda_max, lower=lower,
                upper=upper, keep_jacobian=True, damping=damping, stall_window=stall_window,
                stall_tol=stall_tol, geo_h=geo_h, geo_alpha=geo_alpha, xtol=xtol)
    b = levenberg_marquardt_batch(fun, x0[None], geodesic=geodesic, step_bound=step_bound,
                                  **opts)
    iterations, njev = int(b.iterations[0]), int(b.njev[0])
    if fallback and step_bound is None and b.status[0] == "max_iter":
        # Restart from x0 with MINPACK's step control: the bound on |D dx| keeps the first
        # steps from throwing the point into a far valley it then crawls along (MGH10 from
        # its first start); the better of the two runs is returned.
        b2 = levenberg_marquardt_batch(fun, x0[None], geodesic=False,
                                       step_bound=FALLBACK_STEP_BOUND, **opts)
        iterations += int(b2.iterations[0])
        njev += int(b2.njev[0])
        if b2.chi2[0] < b.chi2[0] or (b2.converged[0] and b2.chi2[0] <= b.chi2[0]):
            b = b2
    st = str(b.status[0])
    return LMResult(b.x[0], float(b.chi2[0]), float(b.chi2_0[0]), iterations,
                    bool(b.converged[0]), st, MESSAGES.get(st, st), float(b.lam[0]),
                    counter["nfev"], njev,
                    b.fun[0], None if b.jac is None else b.jac[0])
