"""The linear algebra of Levenberg-Marquardt (:mod:`gprm.fit.lm`) as plain functions over
batches of rows: the reduction of a Jacobian to its R factor, the damped steps for any lambda
from one SVD, the trust region's lambda of a step bound and its update from the ratio of the
actual to the predicted decrease, and the gradient cosines of the gtol test. No state; the
optimizer (:mod:`gprm.fit.lm`) composes them. The equations are in that module's docstring
and in docs/fitting.md."""

from __future__ import annotations

import numpy as np


def reduce_jacobian(J: np.ndarray, r: np.ndarray):
    """Thin QR of a batch of Jacobians: ``R1`` (B, k, P), ``Q1^T r`` (B, k) and diag(J^T J)
    (B, P), k = min(N, P); R1 and Q1^T r come from the R factor of ``[J, r]``. The damped
    step depends on J and r only through these (an orthogonal change of the residual space),
    so they are computed once per Jacobian and reused while a start's steps are rejected and
    only lambda changes."""
    B, N, P = J.shape
    k = min(N, P)
    # R of [J, r] is [[R1, Q1^T r], [0, rho]]: one factorisation without forming Q
    # numpy's stubs type every mode as a QRResult; mode="r" returns the array R alone
    R: np.ndarray = np.linalg.qr(  # type: ignore[assignment]
        np.concatenate([J, r[:, :, None]], axis=2), mode="r")
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


def in_range(sv: np.ndarray) -> np.ndarray:
    """(B, m) mask of the singular values that count as non-zero: above ``max(s) * m * eps``
    (the numerical rank, as ``numpy.linalg.matrix_rank`` decides it). The trust-region steps
    (lambda may be 0) drop the others: a rank-deficient J (MGH problem 34: two zero columns and
    a rank-one rest) otherwise gets steps of ``g / s`` with s at rounding level, which throw
    x to 1e14."""
    m = sv.shape[-1]
    with np.errstate(invalid="ignore"):
        top = np.max(np.where(np.isfinite(sv), sv, 0.0), axis=-1, keepdims=True)
        return sv > top * max(m, 1) * np.finfo(float).eps


def trust_region_lambda(sv: np.ndarray, g: np.ndarray, delta: np.ndarray,
                        n_iter: int = 40) -> np.ndarray:
    """The damping lambda whose step has scaled length ``|D dx| = delta`` (rows (B,)), or 0
    where the Gauss-Newton step (lambda = 0) is already within 1.1 delta: the step-bound
    (trust-region) form of Levenberg-Marquardt (More 1978, as MINPACK's ``lmpar``).

    ``phi(lambda) = |s g / (s^2 + lambda)|`` decreases from phi(0) to 0; Newton's method on
    ``1/phi(lambda) - 1/delta`` (concave in lambda) from lambda = 0 increases monotonically
    to the root; it stops within 10 percent of delta, as MINPACK does."""
    lam = np.zeros(delta.shape)
    rng = in_range(sv)                   # per row; sv does not change in the iteration

    def steps(i):
        """(c, s^2) of rows i at their current lambda: phi = |c|."""
        s2 = sv[i] * sv[i]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return np.where(rng[i], sv[i] * g[i] / (s2 + lam[i, None]), 0.0), s2

    c, _ = steps(np.arange(delta.size))
    phi = np.sqrt(np.sum(c * c, axis=1))
    todo = phi > 1.1 * delta
    for _ in range(n_iter):
        if not todo.any():
            break
        i = np.nonzero(todo)[0]
        c, s2 = steps(i)
        ph = phi[i]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            dph = -np.sum(c * c / (s2 + lam[i, None]), axis=1) / ph      # d phi / d lambda
            # Newton on 1/phi - 1/delta: lambda += (phi - delta) phi / (delta |phi'|)
            step = (ph - delta[i]) * ph / (delta[i] * -dph)
        step = np.where(np.isfinite(step) & (step > 0), step, 0.0)
        lam[i] = lam[i] + step
        c, _ = steps(i)
        phi[i] = np.sqrt(np.sum(c * c, axis=1))
        todo[i] = (np.abs(phi[i] - delta[i]) > 0.1 * delta[i]) & (step > 0)
    return lam


def _chi2(r: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore", invalid="ignore"):
        c = np.sum(r * r, axis=1)
    return np.where(np.isfinite(c), c, np.inf)


def _trust_region_update(better, chi_t, chi2, dx, R1, qtr, dd, lam, delta, idx, ftol,
                         ftol_abs=0.0):
    """Trust-region bookkeeping for the rows ``idx`` of one iteration: the ratio of the actual
    to the predicted decrease of chi-square (predicted by the linear model, ``|Q1^T r|^2 -
    |Q1^T r + R1 dx|^2``), acceptance (chi-square decreases by at least 1e-4 of the
    prediction) and the updated step bound ``delta`` (a new array), after More (1978):
    shrink it when the ratio is below 1/4 (by 1/2, or by the factor a quadratic along the
    step suggests, never below 1/10), double it when the ratio is above 3/4 or the step was
    a Gauss-Newton step. Returns the accepted rows, per row whether both the actual and the
    predicted decrease are within ``ftol`` of chi-square (MINPACK's ftol test), and the new
    ``delta``."""
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
    new = delta.copy()
    new[idx] = np.where(np.isfinite(d) & (d > 0), d, delta[idx] * 0.1)
    accepted = better & (ratio >= 1e-4)
    tol = ftol * chi2 + ftol_abs
    small_pred = (np.abs(act) <= tol) & (pred <= tol) & (ratio <= 2.0) & (tol > 0)
    return accepted, small_pred, new


def gradient_cosines(R1: np.ndarray, qtr: np.ndarray, d: np.ndarray,
                     chi2: np.ndarray) -> np.ndarray:
    """(B,) the largest cosine between the residual vector and a column of the Jacobian,
    ``max_j |(J^T r)_j| / (|J_j| |r|)``, from :func:`reduce_jacobian`'s factors
    (``J^T r = R1^T Q1^T r``, ``|J_j|^2 = d_j``) and ``chi2 = |r|^2``. Columns that are zero
    count as 0. MINPACK's gtol test (the user guide of MINPACK-1, More, Garbow, Hillstrom
    1980)."""
    gr = np.einsum("bkp,bk->bp", R1, qtr)
    rn = np.sqrt(chi2)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(d > 0, np.abs(gr) / np.sqrt(d) / rn[:, None], 0.0)
    c = np.where(np.isfinite(c), c, 0.0)
    return np.max(c, axis=1) if c.shape[1] else np.zeros(c.shape[0])
