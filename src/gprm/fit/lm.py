"""Levenberg-Marquardt as in the paper's Algorithm 1 (Sec. 3.1), for a batch of problems run
in lock-step.

:func:`levenberg_marquardt_batch` is the optimizer's front end. It advances B independent
starting points of the same residual function together, so that one (batched) model
evaluation serves all of them; :func:`levenberg_marquardt` is the single-problem API, a batch
of one with an optional finite-difference Jacobian.

Inside, the optimizer is a small frozen state, :class:`LMState` (points, residuals,
Jacobians, chi-square, lambda, status and counters per row, the factors of the current
Jacobians), advanced by pure functions: :func:`lm_init`, then per iteration :func:`lm_prune`
and :func:`lm_step` (:func:`refresh_jacobians`, :func:`refresh_factors`, :func:`propose`,
:func:`evaluate`, :func:`accept`), and :func:`lm_finish`; :func:`minimize_batch` runs them.
The variants are plug-in objects passed to it, chosen from the keyword options by
:func:`select_plugins`: the damping scale (:class:`Algorithm1Damping`, ``damping="current"``;
:class:`MinpackDamping`, ``"max"``), the control of lambda (:class:`Algorithm1Lambda`;
:class:`TrustRegion`, ``step_bound``) and the acceleration (:class:`NoAcceleration`;
:class:`GeodesicAcceleration`, ``geodesic=True``).

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

The standalone :func:`levenberg_marquardt` runs the trust-region step control by default
(initial bound ``STEP_BOUND |D x0|``, MINPACK's scale, no acceleration, no second run) with
MINPACK's three tests -- ``ftol`` on every evaluated step, ``xtol`` on the bound, ``gtol`` on
the cosines between r and the columns of J (:func:`gradient_cosines`) -- a budget of residual
evaluations ``max_nfev``, and the absolute floors ``ftol_abs`` and ``chi2_tol``; Algorithm 1,
the acceleration and a fallback run (reported separately in the result) are options
(docs/fitting.md, issue 24: it needs about MINPACK's evaluations where the previous defaults
needed ~12 times as many).

An iteration is one trial step (accepted or rejected), as ``i`` in Algorithm 1.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from gprm.fit.lm_algebra import (_chi2, _damping_diagonal,  # noqa: F401
                                 _trust_region_update, damped_steps_reduced, gradient_cosines,
                                 in_range, reduce_jacobian, scaled_svd, svd_steps,
                                 trust_region_lambda)

LAMBDA_MIN = 1e-15
#: initial step bound (MINPACK's ``factor``) of the standalone optimizer's fallback run
FALLBACK_STEP_BOUND = 100.0
BOUND_MARGIN = 1e-9
#: initial step bound of the standalone optimizer's trust region, ``STEP_BOUND |D x0|``:
#: MINPACK's factor 100 lets the first, nearly Gauss-Newton steps throw a parameter to where
#: its Jacobian column vanishes (NIST BoxBOD from start 1: b2 -> 110, then a stationary point
#: at chi-square 9772); 1 solves all 54 NIST runs and 2 more MGH runs with fewer evaluations
#: (benchmarks/bench_lm.py, docs/fitting.md)
STEP_BOUND = 1.0

#: statuses that count as converged
CONVERGED = ("ftol", "chi2_tol", "lambda_max", "stalled", "xtol", "gtol")
#: statuses that :attr:`LMResult.success` accepts: a convergence test met (``lambda_max`` and
#: ``stalled`` are stops without one, reported by ``converged`` only)
SUCCESS = ("ftol", "xtol", "gtol", "chi2_tol")
#: integer status codes (:attr:`LMResult.code`): negative for a failure to start, 0 for a
#: budget exhausted, positive for a stopping rule
CODES = {"failed": -1, "max_iter": 0, "max_nfev": 0, "gtol": 1, "ftol": 2, "xtol": 3,
         "chi2_tol": 4, "lambda_max": 5, "stalled": 6, "pruned": 7, "raced": 8}

MESSAGES = {
    "ftol": "chi-square changed by less than the tolerance on an accepted step",
    "chi2_tol": "chi-square fell below the threshold",
    "lambda_max": "no smaller chi-square found with the damping at its limit (a minimum to "
                  "machine precision, or against a bound)",
    "stalled": "chi-square fell by less than the tolerance over the last iterations (window)",
    "xtol": "the step bound (trust region) fell below xtol times the scaled size of x",
    "gtol": "the gradient is orthogonal to the residuals to within gtol (a stationary point)",
    "max_iter": "iteration limit reached",
    "max_nfev": "the budget of residual evaluations (max_nfev) is spent",
    "failed": "residuals or Jacobian not finite at the starting point: nothing was done",
    "pruned": "stopped by the caller's pruning rule",
    "raced": "stopped by the caller's racing rule (not among the best of its batch at a race "
             "point)",
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
    """Outcome of :func:`levenberg_marquardt` (one problem), named as SciPy's
    ``OptimizeResult`` of ``least_squares`` where it has a name: ``x``, ``cost`` (half the sum
    of squares), ``fun`` (residuals at x), ``jac``, ``nfev``, ``njev``, ``status`` (here the
    key of the stopping rule; ``code`` is its integer, :data:`CODES`), ``message`` and
    ``success`` (a convergence test met: :data:`SUCCESS`).

    ``chi2`` is the full sum of squares (chi-square when the residuals are weighted, Eq. 6);
    ``converged`` is true for any stop but a budget or a failed start (``lambda_max`` and
    ``stalled`` included); ``nfev`` counts the calls of the residual function (finite
    differences included), ``njev`` the Jacobians. With ``fallback`` a second run is never
    hidden: the counts cover both runs, and the run not returned is ``first_run`` (the second
    run won) or ``second_run`` (the first run won)."""

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
    first_run: LMResult | None = None
    second_run: LMResult | None = None

    @property
    def success(self) -> bool:
        return self.status in SUCCESS

    @property
    def cost(self) -> float:
        """Half the sum of squared residuals (SciPy's ``cost``)."""
        return 0.5 * self.chi2

    @property
    def code(self) -> int:
        return CODES.get(self.status, 0)


# ----------------------------------------------------------------------------- the pieces
#
# The optimizer is a small frozen state (:class:`LMState`) advanced by pure functions
# (:func:`lm_init`, :func:`lm_prune`, :func:`lm_step`, :func:`lm_finish`; a step is
# :func:`refresh_jacobians`, :func:`refresh_factors`, :func:`propose`, :func:`evaluate` and
# :func:`accept`), with the variants as plug-in objects: the damping scale
# (:class:`Algorithm1Damping`, :class:`MinpackDamping`), the control of lambda
# (:class:`Algorithm1Lambda`, :class:`TrustRegion`) and the acceleration
# (:class:`NoAcceleration`, :class:`GeodesicAcceleration`). Every function returns new arrays
# and leaves its inputs unchanged.


@dataclass(frozen=True)
class Problem:
    """The residual function of a batch: ``fun(X) -> (r, J)`` and, optionally, a cheaper
    ``residuals(X) -> r`` used for trial points (then ``fun`` runs at accepted points only)
    and ``jacobian(X, R) -> J``, the Jacobians at points whose residuals R are already known
    (then the residuals of an accepted point are not evaluated a second time).

    ``indexed``: the rows are B different problems evaluated together (the same model
    against different data, say); every function then also gets, as its last argument,
    ``rows``: the indices in the batch (into X0) of the rows it is given."""

    fun: Callable
    residuals: Callable | None = None
    jacobian: Callable | None = None
    indexed: bool = False

    def _args(self, rows: np.ndarray) -> tuple:
        return (rows,) if self.indexed else ()

    def both(self, X: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``fun`` at the rows ``rows`` of the batch (points X)."""
        return self.fun(X, *self._args(rows))

    def jacobians(self, X: np.ndarray, R: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Jacobians at points with known residuals R (``jacobian`` if given, else ``fun``)."""
        if self.jacobian is not None:
            return np.asarray(self.jacobian(X, R, *self._args(rows)), float)
        return np.asarray(self.both(X, rows)[1], float)

    def values(self, X: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Residuals only (``residuals`` if given, else the first output of ``fun``)."""
        if self.residuals is not None:
            return self.residuals(X, *self._args(rows))
        return self.both(X, rows)[0]

    def trial(self, X: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Residuals at trial points, and their Jacobian when it comes with them."""
        if self.residuals is not None:
            return np.asarray(self.residuals(X, *self._args(rows)), float), None
        r, J = self.both(X, rows)
        return np.asarray(r, float), np.asarray(J, float)


@dataclass(frozen=True)
class Box:
    """The bounds and the box strictly inside them that trial points are projected onto
    (``BOUND_MARGIN`` max(1, |bound|) inside each finite bound)."""

    lo: np.ndarray
    hi: np.ndarray
    near_lo: np.ndarray
    near_hi: np.ndarray
    lo_in: np.ndarray
    hi_in: np.ndarray

    @classmethod
    def of(cls, lower, upper, n_params: int) -> Box:
        P = n_params
        lo = np.broadcast_to(np.asarray(-np.inf if lower is None else lower, float), (P,))
        hi = np.broadcast_to(np.asarray(np.inf if upper is None else upper, float), (P,))
        with np.errstate(invalid="ignore"):
            near_lo = np.where(np.isfinite(lo), BOUND_MARGIN * np.maximum(1.0, np.abs(lo)), 0.0)
            near_hi = np.where(np.isfinite(hi), BOUND_MARGIN * np.maximum(1.0, np.abs(hi)), 0.0)
        return cls(lo, hi, near_lo, near_hi, lo + near_lo, hi - near_hi)

    def blocked(self, X: np.ndarray, dx: np.ndarray) -> np.ndarray:
        """(rows, P) parameters held at a bound by a step pointing out of the box."""
        return (((X - self.lo_in <= self.near_lo) & (dx < 0))
                | ((self.hi_in - X <= self.near_hi) & (dx > 0)))


@dataclass(frozen=True)
class Factors:
    """Per row: the factors of the current Jacobian (:func:`reduce_jacobian`: ``R1``,
    ``qtr`` = Q1^T r, ``d`` = diag(J^T J)) and of its damped steps (:func:`scaled_svd`:
    ``W``, ``s``, ``g``); ``fresh`` marks the rows whose factors belong to their current J."""

    R1: np.ndarray
    qtr: np.ndarray
    d: np.ndarray
    W: np.ndarray
    s: np.ndarray
    g: np.ndarray
    fresh: np.ndarray

    @classmethod
    def empty(cls, B: int, k: int, P: int) -> Factors:
        return cls(np.zeros((B, k, P)), np.zeros((B, k)), np.zeros((B, P)),
                   np.zeros((B, P, k)), np.zeros((B, k)), np.zeros((B, k)), np.zeros(B, bool))

    def outdated(self, rows: np.ndarray) -> Factors:
        """The same factors with ``rows`` marked as no longer belonging to their J."""
        fresh = self.fresh.copy()
        fresh[rows] = False
        return replace(self, fresh=fresh)


# ----------------------------------------------------------------------------- plug-ins

@dataclass(frozen=True)
class Algorithm1Damping:
    """Algorithm 1's damping: lambda diag(J^T J) at the current point (``damping="current"``)."""

    def init(self, J: np.ndarray) -> np.ndarray | None:
        return None

    def seen(self, scale, rows: np.ndarray, J_rows: np.ndarray):
        return scale

    def floor(self, scale, rows: np.ndarray) -> np.ndarray | None:
        return None


@dataclass(frozen=True)
class MinpackDamping:
    """MINPACK's scale: lambda times the largest diag(J^T J) seen so far along the row's path
    (``damping="max"``); its state is that running maximum (B, P)."""

    def init(self, J: np.ndarray) -> np.ndarray:
        return np.einsum("bnp,bnp->bp", J, J)

    def seen(self, scale: np.ndarray, rows: np.ndarray, J_rows: np.ndarray) -> np.ndarray:
        out = scale.copy()
        out[rows] = np.maximum(out[rows], np.einsum("bnp,bnp->bp", J_rows, J_rows))
        return out

    def floor(self, scale: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return scale[rows]


@dataclass(frozen=True)
class Algorithm1Lambda:
    """Algorithm 1's control of lambda: / 10 on an accepted step (not below ``LAMBDA_MIN``),
    x 10 on a rejected one; a row stops (``lambda_max``) once lambda exceeds ``lambda_max``."""

    lambda_max: float = 1e12

    def init(self, X: np.ndarray, J: np.ndarray, scale) -> None:
        return None

    def lambdas(self, lam: np.ndarray, s: np.ndarray, g: np.ndarray, delta) -> np.ndarray:
        return lam

    def steps(self, W: np.ndarray, s: np.ndarray, g: np.ndarray, lam: np.ndarray):
        return svd_steps(W, s, g, lam)

    def judge(self, better, chi_t, chi2, dx, R1, qtr, dd, lam, delta, idx, ftol, ftol_abs=0.0):
        """(accepted rows, per-row 'predicted decrease small' or None, new control state)."""
        return better, None, delta

    def next_lambda(self, lam: np.ndarray, idx, lam_idx, acc, rej) -> np.ndarray:
        lam = lam.copy()
        lam[acc] = np.maximum(lam[acc] / 10.0, LAMBDA_MIN)
        lam[rej] *= 10.0
        return lam

    def finished(self, X, active, delta, idx, rej, lam, dd) -> tuple[np.ndarray, str]:
        return rej[lam[rej] > self.lambda_max], "lambda_max"


@dataclass(frozen=True)
class TrustRegion:
    """Trust-region step control (module docstring): lambda chosen so that ``|D dx|`` is at
    most delta (:func:`trust_region_lambda`), delta updated from the ratio of the actual to
    the predicted decrease (:func:`_trust_region_update`); a row stops (``xtol``) once delta
    falls to ``xtol |D x|``. Its state is delta (B,)."""

    step_bound: float = FALLBACK_STEP_BOUND
    xtol: float = 1e-15

    def init(self, X: np.ndarray, J: np.ndarray, scale) -> np.ndarray:
        dd0 = _damping_diagonal(np.einsum("bnp,bnp->bp", J, J), scale)[0]
        delta = float(self.step_bound) * np.sqrt(np.sum(dd0 * X * X, axis=1))
        return np.where(np.isfinite(delta) & (delta > 0), delta, float(self.step_bound))

    def lambdas(self, lam: np.ndarray, s: np.ndarray, g: np.ndarray, delta) -> np.ndarray:
        return trust_region_lambda(s, g, delta)

    def steps(self, W: np.ndarray, s: np.ndarray, g: np.ndarray, lam: np.ndarray):
        with np.errstate(divide="ignore", invalid="ignore"):   # lambda 0: pseudo-inverse
            c = np.where(in_range(s), s * g / (s ** 2 + lam[:, None]), 0.0)
        return -np.einsum("bpm,bm->bp", W, c)

    def judge(self, better, chi_t, chi2, dx, R1, qtr, dd, lam, delta, idx, ftol, ftol_abs=0.0):
        return _trust_region_update(better, chi_t, chi2, dx, R1, qtr, dd, lam, delta, idx, ftol,
                                    ftol_abs)

    def next_lambda(self, lam: np.ndarray, idx, lam_idx, acc, rej) -> np.ndarray:
        lam = lam.copy()
        lam[idx] = lam_idx
        return lam

    def finished(self, X, active, delta, idx, rej, lam, dd) -> tuple[np.ndarray, str]:
        xn = np.sqrt(np.sum(dd * X[idx] ** 2, axis=1))
        return idx[active[idx] & (delta[idx] <= self.xtol * xn)], "xtol"


@dataclass(frozen=True)
class NoAcceleration:
    """The plain damped step."""

    def correct(self, problem: Problem, box: Box, X, v, r, J, W, s, lam, dd, free,
                rows=None):
        """(corrected steps, rows to reject unevaluated, rows that cost a residual call)."""
        return v, np.zeros(v.shape[0], bool), np.zeros(0, int)


@dataclass(frozen=True)
class GeodesicAcceleration:
    """Geodesic acceleration (module docstring): the step ``v`` corrected by half the
    acceleration ``a``; ``h`` the finite-difference step (in units of the step), ``alpha``
    the largest ``2|a|/|v|`` accepted."""

    h: float = 0.1
    alpha: float = 0.75

    def correct(self, problem: Problem, box: Box, X, v, r, J, W, s, lam, dd, free,
                rows=None):
        """``dd`` is the damping diagonal of the metric (:func:`_damping_diagonal`). Rows not
        ``free`` (a parameter held at a bound) or whose ``x + h v`` leaves the box keep
        ``v``. ``rows``: the rows' indices in the batch (None: 0, 1, ...)."""
        h = self.h
        Xh = X + h * v
        ok = free & np.all(np.isfinite(Xh) & (Xh > box.lo_in) & (Xh < box.hi_in), axis=1)
        a = np.zeros_like(v)
        bad = np.zeros(v.shape[0], bool)
        e = np.nonzero(ok)[0]
        if e.size == 0:
            return v, bad, e
        rh = np.asarray(problem.values(Xh[e], e if rows is None else rows[e]), float)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            rvv = (2.0 / h) * ((rh - r[e]) / h - np.einsum("bnp,bp->bn", J[e], v[e]))
            # [J^T J + lam D] a = -J^T r'' with J^T J + lam D = W diag(s^2 + lam) W^T
            c = np.einsum("bpm,bp->bm", W[e], np.einsum("bnp,bn->bp", J[e], rvv))
            a[e] = -np.einsum("bpm,bm->bp", W[e], c / (s[e] ** 2 + lam[e, None]))
            d = dd[e]
            ratio = 2.0 * np.sqrt(np.sum(d * a[e] ** 2, axis=1) / np.sum(d * v[e] ** 2, axis=1))
            bad[e] = ratio > self.alpha
        return v + 0.5 * a, bad, e


def select_plugins(*, damping: str = "current", geodesic: bool = False, geo_h: float = 0.1,
                   geo_alpha: float = 0.75, step_bound: float | None = None,
                   xtol: float = 1e-15, lambda_max: float = 1e12) -> tuple:
    """The plug-ins of the keyword options of :func:`levenberg_marquardt_batch`:
    ``(damping, control, acceleration)``."""
    damp: Algorithm1Damping | MinpackDamping
    if damping == "current":
        damp = Algorithm1Damping()
    elif damping == "max":
        damp = MinpackDamping()
    else:
        raise ValueError(f"damping must be 'current' or 'max', got {damping!r}")
    control = (Algorithm1Lambda(lambda_max) if step_bound is None
               else TrustRegion(float(step_bound), xtol))
    accel = GeodesicAcceleration(geo_h, geo_alpha) if geodesic else NoAcceleration()
    return damp, control, accel


@dataclass(frozen=True)
class Settings:
    """The stopping rules of a run (:func:`levenberg_marquardt_batch`)."""

    max_iter: int = 100
    lambda0: float = 1e-2
    ftol: float = 1e-8
    ftol_abs: float = 0.0
    chi2_tol: float = 0.0
    stall_window: int = 0
    stall_tol: float = 0.0
    keep_jacobian: bool = False
    gtol: float = 0.0               # stop when every column's cosine with r is <= gtol
    max_nfev: int | None = None     # stop a row once its residual evaluations reach it


# ----------------------------------------------------------------------------- the state

@dataclass(frozen=True)
class LMState:
    """Everything Algorithm 1 carries from one iteration to the next, per row of the batch."""

    it: int                     # iterations done (lock-step: the same for every active row)
    x: np.ndarray               # (B, P) current points
    r: np.ndarray               # (B, N) residuals there
    J: np.ndarray               # (B, N, P) Jacobians (of the last point evaluated with fun)
    chi2: np.ndarray            # (B,)
    chi2_0: np.ndarray          # (B,)
    lam: np.ndarray             # (B,) damping
    status: np.ndarray          # (B,) object: "" while running, else a key of MESSAGES
    active: np.ndarray          # (B,) bool
    iterations: np.ndarray      # (B,) trial steps taken
    nfev: np.ndarray            # (B,) residual evaluations
    njev: np.ndarray            # (B,) Jacobian evaluations
    stale: np.ndarray           # (B,) bool: J not yet evaluated at the (accepted) point
    factors: Factors
    scale: np.ndarray | None    # state of the damping plug-in
    delta: np.ndarray | None    # state of the lambda control plug-in
    ring: np.ndarray | None     # chi2 after the last iterations (stall window)


@dataclass(frozen=True)
class Proposal:
    """The trial steps of the active rows ``idx`` at one iteration."""

    idx: np.ndarray             # active rows
    lam: np.ndarray             # their lambda for this step
    dd: np.ndarray              # their damping diagonal
    dx: np.ndarray              # their steps (after the bounds and the acceleration)
    xt: np.ndarray              # trial points, projected onto the box
    inside: np.ndarray          # trial points to evaluate
    accel_rows: np.ndarray      # rows of idx whose acceleration cost a residual call


@dataclass(frozen=True)
class Trial:
    """Residuals (and Jacobians, without a residual-only function) at the evaluated trial
    points ``ev`` (positions in the proposal's rows)."""

    chi2: np.ndarray            # (rows,) inf where not evaluated
    ev: np.ndarray
    r: np.ndarray | None
    J: np.ndarray | None


def lm_init(problem: Problem, X0: np.ndarray, settings: Settings, damping, control) -> LMState:
    """The state at the starting points: residuals and Jacobians evaluated once; rows whose
    residuals or Jacobian are not finite are ``failed``."""
    X = np.array(X0, dtype=float, copy=True)
    if X.ndim != 2:
        raise ValueError("X0 must be 2-D (B, P)")
    B, P = X.shape
    r, J = problem.both(X, np.arange(B))
    r = np.array(r, dtype=float)
    J = np.array(J, dtype=float)
    if r.ndim != 2 or r.shape[0] != B or J.shape != (B, r.shape[1], P):
        raise ValueError(f"fun must return r (B, N) and J (B, N, P); got {r.shape}, {J.shape}")
    chi2 = _chi2(r)
    finite_J = np.all(np.isfinite(J), axis=(1, 2))
    status = np.full(B, "", dtype=object)
    active = np.isfinite(chi2) & finite_J
    status[~active] = "failed"
    scale = damping.init(J)
    ring = None
    if int(settings.stall_window) > 0:
        ring = np.empty((int(settings.stall_window) + 1, B))
        ring[0] = chi2
    return LMState(0, X, r, J, chi2, chi2.copy(), np.full(B, float(settings.lambda0)), status,
                   active, np.zeros(B, int), np.ones(B, int), np.ones(B, int), np.zeros(B, bool),
                   Factors.empty(B, min(J.shape[1], P), P), scale, control.init(X, J, scale),
                   ring)


def lm_prune(state: LMState, prune: Callable | None) -> LMState:
    """Stop the rows the ``prune`` rule marks: a boolean mask (status ``pruned``) or an array
    of statuses, ``""`` for the rows that go on and a key of :data:`MESSAGES` (``pruned``,
    ``raced``) for those that stop."""
    if prune is None:
        return state
    marks = np.asarray(prune(state.chi2, state.active))
    if marks.dtype == bool:
        cut, why = marks & state.active, np.full(marks.shape, "pruned", dtype=object)
    else:
        why = marks.astype(object)
        cut = (why != "") & state.active
    if not cut.any():
        return state
    status = state.status.copy()
    status[cut] = why[cut]
    return replace(state, status=status, active=state.active & ~cut)


def refresh_jacobians(state: LMState, problem: Problem, damping) -> LMState:
    """Evaluate ``fun`` at the active rows whose Jacobian is stale (accepted by residuals)."""
    idx = np.nonzero(state.active)[0]
    st = idx[state.stale[idx]]
    if not st.size:
        return state
    JJ = problem.jacobians(state.x[st], state.r[st], st)
    J = state.J.copy()
    J[st] = JJ
    njev = state.njev.copy()
    njev[st] += 1
    stale = state.stale.copy()
    stale[st] = False
    return replace(state, J=J, njev=njev, stale=stale, factors=state.factors.outdated(st),
                   scale=damping.seen(state.scale, st, JJ))


def refresh_factors(state: LMState, damping) -> LMState:
    """Factorise the Jacobians of the active rows whose factors are outdated."""
    idx = np.nonzero(state.active)[0]
    f = state.factors
    new = idx[~f.fresh[idx]]
    if not new.size:
        return state
    R1, qtr, d, W, s, g, fresh = (f.R1.copy(), f.qtr.copy(), f.d.copy(), f.W.copy(),
                                  f.s.copy(), f.g.copy(), f.fresh.copy())
    R1[new], qtr[new], d[new] = reduce_jacobian(state.J[new], state.r[new])
    W[new], s[new], g[new] = scaled_svd(R1[new], qtr[new], d[new],
                                        damping.floor(state.scale, new))
    fresh[new] = True
    return replace(state, factors=Factors(R1, qtr, d, W, s, g, fresh))


def propose(state: LMState, problem: Problem, box: Box, damping, control,
            acceleration) -> Proposal:
    """The damped steps of the active rows: lambda from the control, parameters held at a
    bound by a step pointing out of the box frozen and the step of the others recomputed
    without them (their Jacobian columns zeroed; same Q1^T r), then the acceleration, and
    the trial points projected onto the box."""
    idx = np.nonzero(state.active)[0]
    f = state.factors
    dfl = damping.floor(state.scale, idx)
    delta = None if state.delta is None else state.delta[idx]
    lam = control.lambdas(state.lam[idx], f.s[idx], f.g[idx], delta)
    dx = control.steps(f.W[idx], f.s[idx], f.g[idx], lam)
    Xa = state.x[idx]
    blocked = box.blocked(Xa, dx)
    rows = np.nonzero(np.any(blocked, axis=1))[0]
    if rows.size:
        keep = ~blocked[rows]
        br = idx[rows]
        dx[rows] = damped_steps_reduced(f.R1[br] * keep[:, None, :], f.qtr[br], f.d[br] * keep,
                                        lam[rows], None if dfl is None else dfl[rows])
    dd = _damping_diagonal(f.d[idx], dfl)[0]
    dx, too_curved, accel_rows = acceleration.correct(
        problem, box, Xa, dx, state.r[idx], state.J[idx], f.W[idx], f.s[idx], lam, dd,
        ~np.any(blocked, axis=1), idx)
    Xt = np.clip(Xa + dx, box.lo_in, box.hi_in)                 # projection onto the box
    inside = np.all(np.isfinite(Xt) & (Xt > box.lo) & (Xt < box.hi), axis=1) & ~too_curved
    return Proposal(idx, lam, dd, dx, Xt, inside, accel_rows)


def evaluate(prop: Proposal, problem: Problem) -> Trial:
    """Chi-square at the trial points inside the box (inf elsewhere)."""
    chi_t = np.full(prop.idx.size, np.inf)
    ev = np.nonzero(prop.inside)[0]
    rt = Jt = None
    if ev.size:
        rt, Jt = problem.trial(prop.xt[ev], prop.idx[ev])
        chi_t[ev] = _chi2(rt)
    return Trial(chi_t, ev, rt, Jt)


def accept(state: LMState, prop: Proposal, trial: Trial, settings: Settings, damping,
           control) -> LMState:
    """Algorithm 1's acceptance (a smaller chi-square, with the control's own test), the
    update of lambda and the stopping rules of the rows ``prop.idx``."""
    idx = prop.idx
    nfev = state.nfev.copy()
    nfev[idx[prop.accel_rows]] += 1
    nfev[idx[trial.ev]] += 1
    iters = state.iterations.copy()
    iters[idx] += 1
    f = state.factors
    better = trial.chi2 < state.chi2[idx]
    better, small_pred, delta = control.judge(better, trial.chi2, state.chi2[idx], prop.dx,
                                              f.R1[idx], f.qtr[idx], prop.dd, prop.lam,
                                              state.delta, idx, settings.ftol,
                                              settings.ftol_abs)
    if trial.J is not None:
        better[trial.ev] &= np.all(np.isfinite(trial.J), axis=(1, 2))
    acc_local = np.nonzero(better)[0]
    acc = idx[acc_local]
    rej = idx[~better]
    old = state.chi2[acc]
    X, r, J, chi2 = state.x, state.r, state.J, state.chi2
    njev, stale, factors, scale = state.njev, state.stale, f, state.scale
    if acc.size:
        assert trial.r is not None                          # accepted rows were evaluated
        pos = np.searchsorted(trial.ev, acc_local)         # rows of trial.r for accepted rows
        X, r, chi2 = X.copy(), r.copy(), chi2.copy()
        X[acc] = prop.xt[acc_local]
        r[acc] = trial.r[pos]
        chi2[acc] = trial.chi2[acc_local]
        factors = f.outdated(acc)
        if trial.J is not None:
            Ja = trial.J[pos]
            J = J.copy()
            J[acc] = Ja
            njev = njev.copy()
            njev[acc] += 1
            scale = damping.seen(scale, acc, Ja)
        else:
            stale = stale.copy()
            stale[acc] = True
    lam = control.next_lambda(state.lam, idx, prop.lam, acc, rej)
    status, active = state.status.copy(), state.active.copy()
    # stopping rules
    small = (old - chi2[acc]) <= settings.ftol * chi2[acc] + settings.ftol_abs
    if small_pred is not None:
        small &= small_pred[acc_local]
        # the trust region's ftol test judges every evaluated step, as MINPACK's does: near
        # the minimum a step whose change is at rounding level may be rejected (its chi-square
        # not smaller) while both the actual and the predicted change are within ftol
        rej_small = idx[small_pred & ~better & np.isfinite(trial.chi2)]
        status[rej_small] = "ftol"
        active[rej_small] = False
    low = chi2[acc] <= settings.chi2_tol
    status[acc[low]] = "chi2_tol"
    status[acc[small & ~low]] = "ftol"
    active[acc[small | low]] = False
    done, why = control.finished(X, active, delta, idx, rej, lam, prop.dd)
    status[done] = why
    active[done] = False
    if settings.max_nfev is not None:
        spent = idx[active[idx] & (nfev[idx] >= int(settings.max_nfev))]
        status[spent] = "max_nfev"
        active[spent] = False
    it = state.it + 1
    ring = state.ring
    if ring is not None:
        w = ring.shape[0] - 1
        ring = ring.copy()
        ring[it % (w + 1)] = chi2
        if it >= w:
            # every active row has taken it iterations (lock-step from iteration 0)
            before = ring[(it - w) % (w + 1)]
            flat = active & (before - chi2 <= settings.stall_tol)
            status[flat] = "stalled"
            active &= ~flat
    return replace(state, it=it, x=X, r=r, J=J, chi2=chi2, lam=lam, status=status,
                   active=active, iterations=iters, nfev=nfev, njev=njev, stale=stale,
                   factors=factors, scale=scale, delta=delta, ring=ring)


def stop_at_point(state: LMState, settings: Settings) -> LMState:
    """The rules that judge the current point alone, before a step is proposed: active rows
    with chi-square at most ``settings.chi2_tol`` stop (``chi2_tol``; a start at an exact
    zero-residual point), then those whose gradient cosine (:func:`gradient_cosines`, at their
    current, factorised Jacobian) is at most ``settings.gtol`` (``gtol``; off when 0)."""
    idx = np.nonzero(state.active)[0]
    low = state.chi2[idx] <= settings.chi2_tol
    flat = np.zeros(idx.size, bool)
    if settings.gtol > 0:
        f = state.factors
        flat = gradient_cosines(f.R1[idx], f.qtr[idx], f.d[idx],
                                state.chi2[idx]) <= settings.gtol
    if not (low.any() or flat.any()):
        return state
    status, active = state.status.copy(), state.active.copy()
    status[idx[flat]] = "gtol"
    status[idx[low]] = "chi2_tol"
    active[idx[low | flat]] = False
    return replace(state, status=status, active=active)


def lm_step(state: LMState, problem: Problem, box: Box, settings: Settings, damping, control,
            acceleration) -> LMState:
    """One iteration (one trial step) of every active row."""
    state = refresh_jacobians(state, problem, damping)
    state = refresh_factors(state, damping)
    state = stop_at_point(state, settings)
    if not state.active.any():
        return state
    prop = propose(state, problem, box, damping, control, acceleration)
    return accept(state, prop, evaluate(prop, problem), settings, damping, control)


def lm_finish(state: LMState, problem: Problem, settings: Settings) -> LMBatchResult:
    """The result: rows still running end with status ``max_iter``; the Jacobian at the final
    points is computed where stale when asked for."""
    status = state.status.copy()
    status[state.active] = "max_iter"
    jac = None
    njev = state.njev
    if settings.keep_jacobian:
        jac = state.J
        st = np.nonzero(state.stale)[0]
        if st.size:
            JJ = problem.jacobians(state.x[st], state.r[st], st)
            jac = jac.copy()
            jac[st] = JJ
            njev = njev.copy()
            njev[st] += 1
    converged = np.isin(status.astype(str), CONVERGED)
    return LMBatchResult(state.x, state.chi2, state.chi2_0, state.iterations, converged,
                         status.astype(str), state.lam, state.nfev, njev, state.r, jac)


def minimize_batch(problem: Problem, X0: np.ndarray, settings: Settings = Settings(), *,
                   damping=Algorithm1Damping(), control=Algorithm1Lambda(),
                   acceleration=NoAcceleration(), lower=None, upper=None,
                   prune: Callable | None = None) -> LMBatchResult:
    """Algorithm 1 for B starting points in lock-step with the given plug-ins (the keyword
    front end is :func:`levenberg_marquardt_batch`)."""
    state = lm_init(problem, X0, settings, damping, control)
    box = Box.of(lower, upper, state.x.shape[1])
    for _ in range(int(settings.max_iter)):
        if not state.active.any():
            break
        state = lm_prune(state, prune)
        if not state.active.any():
            break
        state = lm_step(state, problem, box, settings, damping, control, acceleration)
    return lm_finish(state, problem, settings)


def levenberg_marquardt_batch(fun: Callable, X0: np.ndarray, *, residuals: Callable | None = None,
                              max_iter: int = 100, lambda0: float = 1e-2, ftol: float = 1e-8,
                              ftol_abs: float = 0.0, chi2_tol: float = 0.0,
                              lambda_max: float = 1e12, lower=None, upper=None,
                              keep_jacobian: bool = False, damping: str = "current",
                              prune: Callable | None = None, stall_window: int = 0,
                              stall_tol: float = 0.0, geodesic: bool = False,
                              geo_h: float = 0.1, geo_alpha: float = 0.75,
                              step_bound: float | None = None,
                              xtol: float = 1e-15, jacobian: Callable | None = None,
                              gtol: float = 0.0, max_nfev: int | None = None,
                              indexed: bool = False) -> LMBatchResult:
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
    jacobian: optional ``jacobian(X (b, P), R (b, N)) -> J (b, N, P)`` at points whose
        residuals R are known (with ``residuals``: the accepted points' residuals are then not
        evaluated again).
    gtol: stop a row (status ``gtol``) when every column of its Jacobian has a cosine of at
        most gtol with its residuals (0: off). max_nfev: stop a row (status ``max_nfev``) once
        its residual evaluations reach it (None: off).
    prune: optional ``prune(chi2 (B,), active (B,)) -> (B,)`` called before each iteration:
        a bool mask (rows it marks stop with status ``pruned``) or statuses (``""``: go on;
        ``pruned`` or ``raced``: stop with that status); used by the multi-start driver,
        which documents its rules.
    indexed: the rows are B different problems that one call evaluates together (the same
        model against different data, as the adequacy's leave-one-signal-out fits): ``fun``,
        ``residuals`` and ``jacobian`` then take, as their last argument, the indices in X0
        of the rows they are given.
    """
    damp, control, accel = select_plugins(damping=damping, geodesic=geodesic, geo_h=geo_h,
                                          geo_alpha=geo_alpha, step_bound=step_bound,
                                          xtol=xtol, lambda_max=lambda_max)
    settings = Settings(max_iter=int(max_iter), lambda0=lambda0, ftol=ftol, ftol_abs=ftol_abs,
                        chi2_tol=chi2_tol, stall_window=int(stall_window), stall_tol=stall_tol,
                        keep_jacobian=keep_jacobian, gtol=gtol, max_nfev=max_nfev)
    return minimize_batch(Problem(fun, residuals, jacobian, indexed), X0, settings,
                          damping=damp, control=control, acceleration=accel, lower=lower,
                          upper=upper, prune=prune)


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
                        args: tuple = (), control: str = "trust-region",
                        max_nfev: int | None = None, max_iter: int | None = None,
                        ftol: float = 1e-10, xtol: float = 1e-10, gtol: float = 1e-10,
                        ftol_abs: float = 0.0, chi2_tol: float = 0.0,
                        step_bound: float = STEP_BOUND, lambda0: float = 1e-2,
                        lambda_max: float = 1e16, lower=None, upper=None,
                        fd_method: str = "central", damping: str = "max",
                        stall_window: int = 0, stall_tol: float = 0.0, geodesic: bool = False,
                        geo_h: float = 0.1, geo_alpha: float = 0.75,
                        fallback: bool = False) -> LMResult:
    """Minimise ``sum(residuals(x)**2)`` by Levenberg-Marquardt.

    residuals: ``residuals(x, *args) -> (N,)``.
    jacobian: ``jacobian(x, *args) -> (N, P)`` (d residuals / d x); None: finite differences
        (``fd_method`` central or forward).
    control: ``"trust-region"`` (default) -- lambda from a bound on the scaled step, the bound
        updated from the ratio of the actual to the predicted decrease (module docstring; the
        More 1978 form that MINPACK implements); ``"algorithm1"`` -- the paper's Algorithm 1
        (lambda / 10 on an accepted step, x 10 on a rejected one), as the multi-start fit
        runs it.
    max_nfev: budget of residual evaluations (those at trial points and of the geodesic
        correction; the evaluations of finite differences are not counted against it);
        None: ``1000 (P + 1)``. max_iter: budget of trial steps; None: no limit but max_nfev.
    ftol: stop when an accepted step decreased chi-square by at most ``ftol chi2 + ftol_abs``
        (trust region: the predicted decrease too). xtol: stop when the step bound is at most
        ``xtol |D x|`` (trust region only). gtol: stop when every column of J has a cosine
        of at most gtol with the residual vector (:func:`gradient_cosines`). chi2_tol: stop
        when chi-square falls to it or below (the absolute floor; 0: only an exact zero).
    step_bound: the trust region's initial bound, ``step_bound |D x0|`` (MINPACK's factor).
    lambda0, lambda_max, lower, upper, damping, stall_window, stall_tol, geodesic, geo_h,
        geo_alpha: see :func:`levenberg_marquardt_batch`.
    fallback: when the run ends at a budget (``max_iter``/``max_nfev``), run once more from
        ``x0`` with the other control and return the run with the smaller chi-square; the
        first run is then reported as ``first_run`` and the counts of the result cover both.
        Off by default.

    Returns an :class:`LMResult` (``x``, ``cost`` = chi2 / 2 as SciPy's, ``chi2``, ``success``,
    ``status``, ``code``, ``message``, ``nfev``, ``njev``, ``iterations``). A start whose
    residuals or Jacobian are not finite returns at once with status ``failed`` (code -1).
    """
    x0 = np.atleast_1d(np.asarray(x0, float))
    if control not in ("trust-region", "algorithm1"):
        raise ValueError(f"control must be 'trust-region' or 'algorithm1', got {control!r}")
    counter = {"nfev": 0}

    def res1(x):
        counter["nfev"] += 1
        return np.atleast_1d(np.asarray(residuals(x, *args), float))

    def jac1(x, r0):
        if not np.all(np.isfinite(r0)):
            return np.full((r0.size, x.size), np.nan)
        if jacobian is not None:
            return np.atleast_2d(np.asarray(jacobian(x, *args), float)).reshape(r0.size, x.size)
        return finite_difference_jacobian(res1, x, r0, method=fd_method, lower=lower,
                                          upper=upper)

    def resb(X):
        return np.stack([res1(x) for x in X])

    def jacb(X, R):
        return np.stack([jac1(x, r) for x, r in zip(X, R)])

    def fun(X):
        R = resb(X)
        return R, jacb(X, R)

    budget = int(max_nfev) if max_nfev is not None else 1000 * (x0.size + 1)
    iters = int(max_iter) if max_iter is not None else 10 * budget + 10

    def run(ctrl: str, accel: bool) -> tuple[LMBatchResult, int]:
        n0 = counter["nfev"]
        damp, ctl, acc = select_plugins(damping=damping, geodesic=accel, geo_h=geo_h,
                                        geo_alpha=geo_alpha,
                                        step_bound=step_bound if ctrl == "trust-region" else None,
                                        xtol=xtol, lambda_max=lambda_max)
        settings = Settings(max_iter=iters, lambda0=lambda0, ftol=ftol, ftol_abs=ftol_abs,
                            chi2_tol=chi2_tol, stall_window=int(stall_window),
                            stall_tol=stall_tol, keep_jacobian=True, gtol=gtol,
                            max_nfev=budget)
        b = minimize_batch(Problem(fun, resb, jacb), x0[None], settings, damping=damp,
                           control=ctl, acceleration=acc, lower=lower, upper=upper)
        return b, counter["nfev"] - n0

    def result(b: LMBatchResult, nfev: int, first: LMResult | None = None) -> LMResult:
        st = str(b.status[0])
        return LMResult(b.x[0], float(b.chi2[0]), float(b.chi2_0[0]), int(b.iterations[0]),
                        bool(b.converged[0]), st, MESSAGES.get(st, st), float(b.lam[0]),
                        nfev, int(b.njev[0]), b.fun[0], None if b.jac is None else b.jac[0],
                        first_run=first)

    b, n1 = run(control, geodesic)
    out = result(b, n1)
    if fallback and out.status in ("max_iter", "max_nfev"):
        other = "algorithm1" if control == "trust-region" else "trust-region"
        b2, n2 = run(other, False)
        second = result(b2, n2)
        its = out.iterations + second.iterations
        nfev, njev = out.nfev + second.nfev, out.njev + second.njev
        if second.chi2 < out.chi2 or (second.converged and second.chi2 <= out.chi2):
            out = replace(second, first_run=out, iterations=its, nfev=nfev, njev=njev)
        else:
            out = replace(out, second_run=second, iterations=its, nfev=nfev, njev=njev)
    return out
