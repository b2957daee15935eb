"""Posterior draws put back on the data: the Gaussian's draws projected onto the parameter
sets that reproduce what the linearisation promised, and those that cannot dropped.

The default uncertainty (gprm.fit.sandwich) draws from a Gaussian in the prior's
coordinates u (log for positive parameters), each coordinate stretched to its reported
interval. Along a direction the data barely see (the y-plane spring pair, whose sum,
moment and second moment the data fix while the split is left to the prior; docs/fitting.md,
"Identifiability") the Gaussian spreads a draw as far as the prior allows, and two things
move it off the set of parameters that fit: the ridge is straight in x, not in log x, and
the stretch scales k_Cy and k_Dy by different factors. The draws' y-plane sum then lies
7-14 % above the fit with +-23-29 % spread where the data fix it to under 1 %, and the
predicted curves (which depend on it) are not the data's (stop 43, bench_combination.py
--ridge).

:func:`project_draws` moves every draw u_d to the nearest parameter set whose residuals are
the linearisation's at u_d:

    minimise over u   | r(u) - [r(u^) + J_u (u_d - u^)] |^2

with r the objective's full residuals (weighted data rows and the prior's rows, which are
linear in u and so hold the draw's coordinates along directions the data do not see). For
a linear model the minimum is u_d itself: the projection changes nothing the Gaussian got
right. It is a batched Levenberg-Marquardt run from the draws (each row its own target,
``indexed``), a few iterations each. A draw the projection cannot bring to its target
(misfit above the chi-square quantile :data:`ACCEPT_LEVEL` with P degrees of freedom, in the
fit's variance scale times the covariance's inflation over the noise, :func:`inflation`)
asks for outputs no parameter set near it produces: the data rule it out at second order,
and it is dropped; more are drawn until ``n`` are kept or :data:`MAX_ROUNDS` rounds have
run. The misfits spread over ten decades: on six sources the median proposal ends at
0.01-0.2 of the threshold and the 90th percentile at 190-3200 times it; 15-27 % end within a
factor 10 of it, the proposals whose fate its level decides (``benchmarks/bench_draws.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.special import chdtri

from gprm.fit.engine import polish_kwargs
from gprm.fit.lm import Box, levenberg_marquardt_batch
from gprm.fit.objective import Objective
from gprm.fit.starts import LMOptions

#: a projected draw is kept when its misfit to its target, in the fit's variance scale, is
#: below this quantile of chi-square with P degrees of freedom
ACCEPT_LEVEL = 0.99
#: Levenberg-Marquardt iterations per projection, its relative tolerance, and the misfit (in
#: the fit's variance scale) at which a draw has reached its target: a twentieth of one
#: noise unit, so what is left adds at most ~5 % to a determined direction's variance
PROJECT_ITER = 15
PROJECT_FTOL = 1e-2
PROJECT_REACHED = 0.05
#: proposal rounds at most (the second and later sized by the first's acceptance)
MAX_ROUNDS = 3


@dataclass(frozen=True)
class ProjectedDraws:
    """Draws kept after projection (``x``, physical (k, P), k <= n) and, for every proposal,
    its misfit to its target in the fit's variance scale (``misfit``, (m,); inf where the
    model could not be simulated) and whether it was kept (``kept``, (m,))."""

    x: np.ndarray
    misfit: np.ndarray
    kept: np.ndarray
    threshold: float
    scale: float = 1.0

    @property
    def n_proposed(self) -> int:
        return int(self.misfit.size)

    @property
    def acceptance(self) -> float:
        """The share of proposals that passed the threshold (kept or not needed)."""
        return float(np.mean(self.misfit <= self.threshold)) if self.misfit.size \
            else float("nan")

    def to_json(self) -> dict:
        finite = self.misfit[np.isfinite(self.misfit)]
        return {"kept": int(self.x.shape[0]), "proposed": self.n_proposed,
                "scale": float(self.scale),
                "threshold": float(self.threshold), "acceptance": self.acceptance,
                "misfit_median": float(np.median(finite)) if finite.size else None}


def project(obj: Objective, x: np.ndarray, U: np.ndarray, lm: LMOptions = LMOptions(), *,
            max_iter: int = PROJECT_ITER, ftol: float = PROJECT_FTOL,
            reached: float = PROJECT_REACHED) -> tuple[np.ndarray, np.ndarray]:
    """(X (m, P) physical, misfit (m,) in the variance scale): the draws ``U`` (m, P, offsets
    from the best fit ``x`` in the prior's coordinates) projected as the module says, under
    the objective ``obj`` (its prior weighed as in the fit)."""
    prior = obj.prior
    if prior is None:
        raise ValueError("projecting draws needs the fit's prior")
    x = np.asarray(x, float)
    U = np.atleast_2d(np.asarray(U, float))
    xn = obj.to_normalised(x)[None]
    r0, Jn = obj(xn)
    Ju = Jn[0] / obj.scale[None, :] * prior.dx_du(x)[None, :]
    target = r0[0][None, :] + U @ Ju.T                    # (m, N + P) the linearisation's
    u0 = prior.to_u(x[None])[0]
    lo, hi = obj.bounds_normalised()
    # the start: the draw's linear image in x where that lies inside the bounds (nearer the
    # y-plane ridge, which is straight in x: less time than from exp(u_d), BENCHMARKS.md
    # "The draws put back on the data"), else the draw itself; the target, not the start,
    # decides where a row ends
    with np.errstate(all="ignore"):
        X_exp = prior.from_u(u0[None] + U)
        X_lin = x[None] + U * prior.dx_du(x)[None]
        lo_x, hi_x = obj.to_physical(lo), obj.to_physical(hi)
        box = Box.of(lo, hi, x.size)             # the optimiser's box strictly inside the bounds
        X0 = np.clip(obj.to_normalised(np.where((X_lin > lo_x) & (X_lin < hi_x), X_lin, X_exp)),
                     box.lo_in, box.hi_in)

    def both(X, rows):
        r, J = obj(X)
        return r - target[rows], J

    def values(X, rows):
        return obj.residuals(X) - target[rows]

    s2 = max(float(prior.weight) ** 2, 1e-300)
    kw = polish_kwargs(lm, max_iter, ftol, trust_region=False)
    kw["chi2_tol"] = reached * s2
    # a proposal that is not a finite point (an overflowing draw) is not projected: dropped
    fin = np.flatnonzero(np.all(np.isfinite(X0), axis=1) & np.all(np.isfinite(target), axis=1))
    X = np.full(X0.shape, np.nan)
    misfit = np.full(X0.shape[0], np.inf)
    if fin.size:
        with np.errstate(all="ignore"):
            res = levenberg_marquardt_batch(
                lambda Xr, rows: both(Xr, fin[rows]), X0[fin],
                residuals=lambda Xr, rows: values(Xr, fin[rows]),
                lower=lo, upper=hi, indexed=True, **kw)
        X[fin] = obj.to_physical(res.x)
        misfit[fin] = np.where(np.isfinite(res.chi2), res.chi2 / s2, np.inf)
    return X, misfit


def inflation(Ju: np.ndarray, Hinv: np.ndarray, Cu: np.ndarray, s2: float) -> float:
    """How much wider the reported covariance ``Cu`` (in u) is than the noise alone, in the
    data space: tr(Ju Cu Ju^T) / (s2 tr(Ju Hinv Ju^T)), Ju the weighted data Jacobian in u,
    Hinv the inverse Gauss-Newton Hessian (prior included), s2 the variance scale. 1 when the
    covariance is the noise's; the misfit a draw may keep scales with it (the covariance
    says outputs that far from the fit's are plausible)."""
    num = float(np.trace(Ju @ Cu @ Ju.T))
    den = float(s2) * float(np.trace(Ju @ Hinv @ Ju.T))
    return num / den if den > 0 and np.isfinite(num) else 1.0


def acceptance_threshold(n_params: int, scale: float = 1.0,
                         level: float = ACCEPT_LEVEL) -> float:
    """The misfit (in the fit's variance scale) up to which a projected draw is kept: the
    chi-square quantile ``level`` with ``n_params`` degrees of freedom times
    max(``scale``, 1), ``scale`` the covariance's :func:`inflation`."""
    # from scipy.special (scipy.stats costs the fit 0.6 s of import)
    return float(chdtri(int(n_params), 1.0 - level)) * max(float(scale), 1.0)


def project_draws(obj: Objective, x: np.ndarray, propose: Callable[[int, int], np.ndarray],
                  n: int, lm: LMOptions = LMOptions(), *, scale: float = 1.0,
                  level: float = ACCEPT_LEVEL, max_rounds: int = MAX_ROUNDS) -> ProjectedDraws:
    """``n`` draws (fewer if :data:`MAX_ROUNDS` rounds do not give them) projected and kept as
    the module says. ``propose(k, round)`` returns k proposals as offsets (k, P) from ``x``
    in the prior's coordinates (the same ``round`` gives the same proposals: reproducible).
    ``scale``: the covariance's :func:`inflation` (the threshold is the chi-square quantile
    times max(scale, 1)). The kept draws are the first ``n`` kept in proposal order."""
    P = np.asarray(x).size
    threshold = acceptance_threshold(P, scale, level)
    Xs, misfits = [], []
    kept_total = 0
    want = int(n)
    for rnd in range(int(max_rounds)):
        if kept_total >= n:
            break
        U = np.asarray(propose(want, rnd), float)
        X, m = project(obj, x, U, lm)
        Xs.append(X)
        misfits.append(m)
        kept_total += int(np.sum(m <= threshold))
        rate = max(kept_total / sum(v.size for v in misfits), 0.1)
        want = int(np.ceil((n - kept_total) / rate * 1.2)) + 8
    X = np.vstack(Xs) if Xs else np.zeros((0, P))
    misfit = np.concatenate(misfits) if misfits else np.zeros(0)
    ok = misfit <= threshold
    take = np.flatnonzero(ok)[:int(n)]
    kept = np.zeros(misfit.size, bool)
    kept[take] = True
    return ProjectedDraws(X[take], misfit, kept, threshold, float(scale))
