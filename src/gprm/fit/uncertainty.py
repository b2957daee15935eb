"""Uncertainty of the identified parameters: the methods compared in docs/fitting.md
("Calibrated uncertainty") and the identifiability verdict of every fit (issue 12).

Methods (``METHODS``), all evaluated at the best fit x^ of the (prior-regularised) objective,
with J the Jacobian of the weighted data residuals r (N rows, P parameters):

``eq7``
    The paper's Eq. 7, kept as it is: C = (r^T r / (N - P)) (J^T J)^-1 (gprm.fit.covariance).
    Undefined where J^T J is singular.
``eq7-corr``
    Eq. 7 with the residuals' time correlation: the factor r^T r / (N - P) assumes N
    independent residuals, but model mismatch makes neighbouring samples move together. It
    is multiplied by tau = 1 + 2 sum_l (1 - l/(L+1)) rho_l, the integrated autocorrelation of
    the residuals (Bartlett window, L = T/4 lags, rho averaged over the signals weighted by
    their residual energy): N / tau residuals are effectively independent.
``laplace-prior``
    The Laplace approximation of the posterior with the weak prior of gprm.fit.prior, in the
    coordinates u of the prior (ln x for positive parameters): precision
    H = J_u^T J_u / s2 + diag(1 / sd_prior^2), s2 = tau r^T r / (N - P) (the eq7-corr
    scale). Always defined. Intervals are u^ +/- z sqrt(diag H^-1) mapped back to x (so a
    positive parameter's interval stays positive), and draws from N(u^, H^-1) mapped back are
    what later stages propagate.

``parametric-bootstrap`` (the default), ``bootstrap-runs``, ``mcmc``
    See :func:`from_bootstrap` (gprm.fit.bootstrap) and :func:`from_mcmc`.

Identified: a parameter whose posterior standard deviation in u is below ``CONTRACTION`` (0.3)
of the prior's, i.e. the data shrank the prior's variance at least ~11-fold, **and** whose
variance is not mostly the prior's (the prior's share below ``PRIOR_SHARE``, 1/2; methods
that split the variance: ``laplace-prior``, ``mcmc`` and the default ``sandwich``). A narrow
interval can still be the prior's: a parameter the data tie to another one they do not see
(b1, the y-plane springs' lever arm, tied through their moments to the split of k_Cy and
k_Dy that only the prior fixes) is narrow because the prior holds the other one, and where it
lies depends on where the prior is centred. Such a parameter *leans on the prior*
(``Uncertainty.leans_on_prior``): reported with its interval and that label, not counted
identified (docs/fitting.md, "Parameters that lean on the prior"). Every other parameter is
reported as not determined, with the interval the posterior gives (close to the prior's),
never a small standard error.

Also here, on the best fit: uncertainty bands on the fitted signals (:func:`compute_bands`)
and profile likelihoods of a parameter (:func:`profile_likelihood`) or of a predicted quantity
(:func:`profile_prediction`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtri

from gprm.fit.covariance import CovarianceError, covariance, normal_factor, sample_normal
from gprm.fit.lm import levenberg_marquardt_batch
from gprm.fit.objective import Objective
from gprm.fit.prior import Prior
from gprm.fit.starts import LMOptions
from gprm.fit.methods import DEFAULT_METHOD, METHODS, FitState

__all__ = ["METHODS", "DEFAULT_METHOD", "Uncertainty", "estimate", "uncertainty"]
#: posterior sd / prior sd below which a parameter counts as identified
CONTRACTION = 0.3
#: the prior's share of a parameter's variance at or above which it is not counted identified
#: however narrow its interval (it leans on the prior: the module docstring)
PRIOR_SHARE = 0.5


def determined(contraction: np.ndarray, prior_share: np.ndarray | None,
               threshold: float = CONTRACTION) -> tuple[np.ndarray, np.ndarray]:
    """(identified, leans_on_prior), (P,) bool each, from each parameter's posterior sd over
    the prior's (``contraction``) and the prior's share of its variance (``prior_share``;
    None: not split, the contraction alone decides). Narrow (contraction below
    ``threshold``, :data:`CONTRACTION` for a fit) and mostly the data's: identified; narrow
    and at least :data:`PRIOR_SHARE` the prior's: leans on the prior; the rest: not
    determined. gprm.design counts a design's parameters with it too."""
    c = np.asarray(contraction, float)
    narrow = c < threshold
    if prior_share is None:
        return narrow, np.zeros(c.shape, bool)
    leans = narrow & (np.asarray(prior_share, float) >= PRIOR_SHARE)
    return narrow & ~leans, leans


def prior_share_of(Cu: np.ndarray, prior_sd: np.ndarray) -> np.ndarray:
    """(P,) the prior's share of each parameter's variance in a Gaussian posterior of
    covariance ``Cu`` = (Hdata + Pr)^-1 in u, Pr = diag(1 / prior_sd^2): diag(Cu Pr Cu) /
    diag(Cu) (the data's share is diag(Cu Hdata Cu) / diag(Cu); the two sum to 1)."""
    Cu = np.asarray(Cu, float)
    part = np.einsum("ip,p,pi->i", Cu, 1.0 / np.asarray(prior_sd, float) ** 2, Cu)
    return part / np.clip(np.diag(Cu), 1e-300, None)


def time_correlation_factor(r: np.ndarray, n_signals: int, *, max_lag: int | None = None
                            ) -> float:
    """tau >= 1 of the module docstring for weighted residuals ``r`` (n_signals * T,), laid
    out signal after signal."""
    R = np.asarray(r, float).reshape(n_signals, -1)
    T = R.shape[1]
    L = max(1, T // 4) if max_lag is None else int(max_lag)
    R = R - R.mean(axis=1, keepdims=True)
    energy = np.sum(R * R, axis=1)
    if not np.any(energy > 0):
        return 1.0
    tau = 1.0
    for lag in range(1, min(L, T - 1) + 1):
        c = np.sum(R[:, :-lag] * R[:, lag:], axis=1)               # per-signal lag-l sums
        rho = float(np.sum(c) / np.sum(energy))
        tau += 2.0 * (1.0 - lag / (L + 1)) * rho
    return float(max(tau, 1.0))


@dataclass(frozen=True)
class Uncertainty:
    """The uncertainty of one fit by one method (SI; arrays over the fitted names).

    covariance: (P, P) linearised covariance in x (None where the method is undefined).
    lower95, upper95, lower68, upper68: central intervals (NaN where undefined).
    identified: (P,) bool; contraction: (P,) posterior/prior sd (NaN without a prior).
    draws: (n, P) parameter sets from the method, or None.  s2: the data's variance scale.
    tau: the time-correlation factor.  message: why a method is undefined, else "ok".
    calibration: the mismatch calibration factors applied (generator-bootstrap only).
    details: the method's ingredients (sandwich: variance shares, systematics, adequacy).
    """

    method: str
    names: tuple[str, ...]
    covariance: np.ndarray | None
    lower95: np.ndarray
    upper95: np.ndarray
    lower68: np.ndarray
    upper68: np.ndarray
    identified: np.ndarray
    contraction: np.ndarray
    draws: np.ndarray | None
    s2: float
    tau: float
    message: str = "ok"
    #: (name, factor) of the mismatch calibration applied to the intervals (gprm.fit.calibration)
    calibration: tuple[tuple[str, float], ...] = ()
    #: what the method built the intervals from (the sandwich's sources and systematics)
    details: dict = field(default_factory=dict)
    #: (P,) bool: narrow but mostly the prior's variance, so not identified (:func:`determined`;
    #: None: the method does not split its variance)
    leans_on_prior: np.ndarray | None = None

    @property
    def leaning(self) -> np.ndarray:
        """(P,) bool :attr:`leans_on_prior`, all False where the method does not split."""
        return (np.zeros(len(self.names), bool) if self.leans_on_prior is None
                else np.asarray(self.leans_on_prior, bool))

    @property
    def stderr(self) -> np.ndarray:
        if self.covariance is None:
            return np.full(len(self.names), np.nan)
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    def interval(self, level: float) -> tuple[np.ndarray, np.ndarray]:
        if np.isclose(level, 0.95):
            return self.lower95, self.upper95
        if np.isclose(level, 0.68):
            return self.lower68, self.upper68
        raise ValueError("levels 0.95 and 0.68 are stored")


def _gaussian(method, names, x, cov, s2, tau, message="ok", identified=None) -> Uncertainty:
    P = len(names)
    nan = np.full(P, np.nan)
    if cov is None:
        return Uncertainty(method, names, None, nan, nan, nan, nan,
                           np.zeros(P, bool) if identified is None else identified, nan,
                           None, s2, tau, message)
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    z95, z68 = ndtri(0.975), ndtri(0.84)
    ident = (se < 0.5 * np.abs(x)) if identified is None else identified
    return Uncertainty(method, names, cov, x - z95 * se, x + z95 * se, x - z68 * se,
                       x + z68 * se, ident, nan, None, s2, tau, message)


def estimate(method: str, x: np.ndarray, J: np.ndarray, r: np.ndarray, dof: int,
             n_signals: int, prior: Prior | None, names, *, n_draws: int = 400,
             seed: int = 0) -> Uncertainty:
    """The uncertainty of the fit at ``x`` (physical, (P,)) by ``method``.

    J: (N, P) Jacobian of the weighted data residuals ``r`` (N,) in physical units; the
    prior's rows are not part of them.
    """
    names = tuple(names)
    if method not in ("eq7", "eq7-corr", "laplace-prior"):
        raise ValueError(f"estimate() computes eq7, eq7-corr and laplace-prior, not {method!r}")
    x = np.asarray(x, float)
    tau = time_correlation_factor(r, n_signals)
    s2_eq7 = float(r @ r) / dof if dof > 0 else np.nan
    if method in ("eq7", "eq7-corr"):
        factor = 1.0 if method == "eq7" else tau
        try:
            cov = covariance(J, r, dof, names=names) * factor
            return _gaussian(method, names, x, cov, s2_eq7 * factor, tau)
        except CovarianceError as exc:
            return _gaussian(method, names, x, None, s2_eq7 * factor, tau, str(exc))
    if prior is None:
        raise ValueError("laplace-prior needs a prior")
    s2 = s2_eq7 * tau
    D = prior.dx_du(x)                                      # dx/du
    Ju = J * D[None, :]
    prec_prior = 1.0 / prior.sd ** 2
    H = Ju.T @ Ju / s2 + np.diag(prec_prior)
    # H is positive definite (the prior part is); solve in the prior-standardised frame
    Sd = prior.sd
    Hs = H * np.outer(Sd, Sd)
    w, V = np.linalg.eigh(0.5 * (Hs + Hs.T))
    w = np.maximum(w, 1e-12 * w[-1])
    Cu = (V / w) @ V.T * np.outer(Sd, Sd)
    sd_u = np.sqrt(np.diag(Cu))
    u = prior.to_u(x)
    z95, z68 = ndtri(0.975), ndtri(0.84)
    lo95, hi95 = prior.from_u(u - z95 * sd_u), prior.from_u(u + z95 * sd_u)
    lo68, hi68 = prior.from_u(u - z68 * sd_u), prior.from_u(u + z68 * sd_u)
    contraction = sd_u / prior.sd
    identified, leans = determined(contraction, prior_share_of(Cu, prior.sd))
    cov_x = Cu * np.outer(D, D)
    rng = np.random.default_rng([seed, 12])
    L = V * np.sqrt(1.0 / w)
    Z = rng.standard_normal((int(n_draws), len(names))) @ L.T * Sd[None, :]
    draws = prior.from_u(u[None] + Z) if n_draws > 0 else None
    return Uncertainty(method, names, 0.5 * (cov_x + cov_x.T), lo95, hi95, lo68, hi68,
                       identified, contraction, draws, s2, tau, leans_on_prior=leans)


def replace_method(u: Uncertainty, method: str, message: str) -> Uncertainty:
    from dataclasses import replace

    return replace(u, method=method, message=message)


def uncertainty(method: str, state: FitState) -> Uncertainty:
    """The methods of this module through the one interface (gprm.fit.methods): ``eq7``,
    ``eq7-corr``, ``laplace-prior`` and ``mcmc`` (a posterior sample started from the
    Laplace posterior)."""
    n_signals = len(state.obj.data.signals)
    if method == "mcmc":
        assert state.prior is not None
        lap = estimate("laplace-prior", state.x, state.J, state.r, state.obj.dof, n_signals,
                       state.prior, state.names, n_draws=state.n_draws, seed=state.seed)
        return from_mcmc(state.obj, state.x, lap, state.prior, seed=state.seed,
                         n_draws=state.n_draws)
    return estimate(method, state.x, state.J, state.r, state.obj.dof, n_signals, state.prior,
                    state.names, n_draws=state.n_draws, seed=state.seed)


def mcmc_chain(log_post, u0: np.ndarray, cov_u: np.ndarray, *, n_steps: int = 600,
               burn: int = 200, n_walkers: int | None = None, seed: int = 0) -> np.ndarray:
    """Posterior sample (n, P) in u by emcee's affine-invariant ensemble sampler.

    ``log_post(U)`` takes walkers (W, P) and returns (W,) log densities (-inf outside the
    support). The walkers start drawn from N(u0, cov_u) (the Laplace approximation), so that
    they span the posterior's undetermined directions from the first step; the first ``burn``
    steps are discarded."""
    import emcee

    P = u0.size
    W = int(n_walkers) if n_walkers else 2 * P + 2
    rng = np.random.default_rng([seed, 16])
    p0 = u0[None] + rng.standard_normal((W, P)) @ normal_factor(cov_u).T
    sampler = emcee.EnsembleSampler(W, P, log_post, vectorize=True)
    sampler._random = np.random.RandomState(int(rng.integers(2 ** 31)))
    sampler.run_mcmc(p0, int(n_steps), progress=False)
    return sampler.get_chain(discard=int(burn), flat=True)


def from_mcmc(obj, x: np.ndarray, laplace: Uncertainty, prior: Prior, *, n_steps: int = 600,
              burn: int = 200, seed: int = 0, n_draws: int = 400) -> Uncertainty:
    """The ``mcmc`` uncertainty: a posterior sample of the prior-regularised fit, the physical
    bounds as the prior's support, the likelihood scaled by the data's variance scale s2
    (as the Laplace posterior). Intervals are the sample's quantiles; identified as in the
    Laplace posterior. ``obj``: the fit's objective (prior rows weighted by sqrt(s2))."""
    s2 = laplace.s2
    lo, hi = obj.bounds()
    u = prior.to_u(np.asarray(x, float))
    D = prior.dx_du(x)
    cov_u = laplace.covariance / np.outer(D, D)

    def log_post(U):
        X = prior.from_u(U)
        inside = np.all((X > lo) & (X < hi) & np.isfinite(X), axis=1)
        out = np.full(U.shape[0], -np.inf)
        if inside.any():
            r = obj.residuals(obj.to_normalised(X[inside]))
            c = np.sum(r * r, axis=1)
            out[inside] = np.where(np.isfinite(c), -0.5 * c / s2, -np.inf)
        return out

    chain = mcmc_chain(log_post, u, cov_u, n_steps=n_steps, burn=burn, seed=seed)
    X = prior.from_u(chain)
    q = np.percentile(X, [2.5, 97.5, 16, 84], axis=0)
    rng = np.random.default_rng([seed, 17])
    draws = X[rng.integers(0, len(X), int(n_draws))] if n_draws > 0 else None
    cov = np.cov(X.T)
    return Uncertainty("mcmc", laplace.names, cov, q[0], q[1], q[2], q[3], laplace.identified,
                       laplace.contraction, draws, s2, laplace.tau,
                       f"ok ({len(chain)} samples after {burn} burn-in steps)",
                       leans_on_prior=laplace.leans_on_prior)


def identifiable_combinations(unc: Uncertainty, prior: Prior, x: np.ndarray, *,
                              max_terms: int = 4, min_weight: float = 0.05) -> list[dict]:
    """Combinations of the parameters that are *not* identified one by one but that the data
    do determine (e.g. the y-plane springs' total stiffness).

    In the prior's coordinates u, restricted to the not-identified parameters, the
    generalised eigenproblem C v = lambda Pr v (C the posterior covariance, Pr the prior's)
    gives directions whose posterior spread is sqrt(lambda) of the prior's; those below
    :data:`CONTRACTION` are determined. Each is reported as the product prod x_k^{v_k}
    (largest |v_k| = 1, terms below ``min_weight`` dropped) with its best value and 95 %
    interval (the posterior's, along v). Empty where all parameters are identified or the
    method has no covariance. Parameters that lean on the prior (narrow already, but the
    prior's) are not searched: each alone would be such a direction."""
    if unc.covariance is None:
        return []
    idx = np.nonzero(~np.asarray(unc.identified) & ~unc.leaning)[0]
    if idx.size == 0:
        return []
    x = np.asarray(x, float)
    D = prior.dx_du(x)
    Cu = (unc.covariance / np.outer(D, D))[np.ix_(idx, idx)]
    sp = prior.sd[idx]
    A = Cu / np.outer(sp, sp)                      # covariance relative to the prior's
    w, V = np.linalg.eigh(0.5 * (A + A.T))
    u = prior.to_u(x)[idx]
    names = [unc.names[k] for k in idx]
    out = []
    for lam, v in zip(w, V.T):
        if not lam < CONTRACTION ** 2:
            continue
        v = v / sp                                  # direction in u
        v = v / v[np.argmax(np.abs(v))]
        keep = np.abs(v) >= min_weight
        sd = float(np.sqrt(v @ Cu @ v))
        c = float(v @ u)
        log = bool(np.all(prior.log[idx][keep]))
        terms = {names[k]: round(float(v[k]), 3) for k in np.nonzero(keep)[0]}
        if len(terms) > max_terms:
            top = np.argsort(-np.abs(v))[:max_terms]
            terms = {names[k]: round(float(v[k]), 3) for k in top}
        f = np.exp if log else (lambda t: t)
        z = ndtri(0.975)
        out.append({"terms": terms, "form": "product of powers" if log else "linear",
                    "value": float(f(c)), "lower": float(f(c - z * sd)),
                    "upper": float(f(c + z * sd)),
                    "spread_vs_prior": float(np.sqrt(max(lam, 0.0)))})
    return out


# ---------------------------------------------------------------------- bands and profiles

@dataclass(frozen=True)
class Bands:
    """Model signals at the best fit with uncertainty bands, (n_signals, T) each."""

    time: np.ndarray
    best: np.ndarray
    linear_std: np.ndarray      # linear propagation sqrt(diag(J C J^T))
    sample_std: np.ndarray      # std over covariance samples
    sample_lo: np.ndarray       # 2.5 % over samples
    sample_hi: np.ndarray       # 97.5 %
    n_samples: int


@dataclass(frozen=True)
class Profile:
    """Profile likelihood of one parameter: grid (physical, ascending), the profile statistic
    D = (Phi - Phi_min) / s2 with Phi the minimised objective (chi-square plus the weighted
    prior) re-minimised over the other parameters, and the intervals where D <= 1 (68 %) and
    D <= 3.84 (95 %). An end is NaN where the profile does not rise to the threshold before
    the physical bound or the search limit: the data do not bound the parameter on that side.
    ``chi2`` holds D (kept under its old name in the files)."""

    name: str
    grid: np.ndarray
    chi2: np.ndarray
    lower: float
    upper: float
    lower95: float = float("nan")
    upper95: float = float("nan")

    @property
    def identifiable(self) -> bool:
        return bool(np.isfinite(self.lower95) and np.isfinite(self.upper95))


def compute_bands(obj: Objective, x: np.ndarray, cov: np.ndarray | None, *, n_samples=200,
                  seed: int = 0, draws: np.ndarray | None = None) -> Bands:
    """Bands on the fitted signals: linear propagation of the covariance, and the spread of
    model signals over ``n_samples`` parameter sets: the uncertainty method's ``draws`` where
    given, else draws from N(x, cov)."""
    o = obj.model(x[None], jacobian=cov is not None)
    best = o.y[0]
    nanb = np.full_like(best, np.nan)
    if cov is None:
        return Bands(obj.data.time, best, nanb, nanb, nanb, nanb, 0)
    J = o.dy[0]                                                   # (S, T, P)
    lin = np.sqrt(np.maximum(np.einsum("stp,pq,stq->st", J, cov, J), 0.0))
    if n_samples <= 0:
        return Bands(obj.data.time, best, lin, nanb, nanb, nanb, 0)
    rng = np.random.default_rng([seed, 3])
    if draws is not None and len(draws) >= 2:
        X = np.asarray(draws, float)[rng.integers(0, len(draws), n_samples)]
    else:
        X = sample_normal(x, cov, n_samples, rng)
    lo, hi = obj.bounds()
    X = X[np.all((X > lo) & (X < hi), axis=1)]           # physical sets only
    if X.shape[0] < 2:          # (almost) every draw non-physical: no sampled band
        return Bands(obj.data.time, best, lin, nanb, nanb, nanb, 0)
    ys = obj.model(X).y
    ok = np.all(np.isfinite(ys), axis=(1, 2))
    ys = ys[ok]
    if ys.shape[0] < 2:
        return Bands(obj.data.time, best, lin, nanb, nanb, nanb, 0)
    return Bands(obj.data.time, best, lin, ys.std(axis=0, ddof=1),
                 np.percentile(ys, 2.5, axis=0), np.percentile(ys, 97.5, axis=0),
                 int(ok.sum()))


class HeldFixed:
    """The objective with one parameter held fixed: its Jacobian column is zero, so the damped
    step never moves it (see :func:`gprm.fit.lm.scaled_svd`). Each row keeps its own fixed
    value, whatever subset of rows the lock-step optimizer evaluates. ``k``: the parameter's
    index, one for every row, or an array of one per row (then for the optimizer's
    ``indexed`` calls, which name the rows they evaluate)."""

    def __init__(self, obj: Objective, k):
        self.obj, self.k = obj, np.asarray(k, int)

    def __call__(self, X, rows=None):
        r, J = self.obj(X)             # J is a new array each call: zeroed in place
        k = self.k if self.k.ndim == 0 else self.k[rows]
        J[np.arange(X.shape[0]), :, k] = 0.0
        return r, J

    def residuals(self, X, rows=None):
        return self.obj.residuals(X)


def profile_likelihood(obj: Objective, x_best: np.ndarray, name: str, *, s2: float = 1.0,
                       sd_u: float | None = None, lm: LMOptions = LMOptions(),
                       max_extend: int = 3) -> Profile:
    """Profile likelihood of ``name`` at the best fit ``x_best`` (physical).

    The grid lives in the posterior's coordinate u of the parameter (ln x for a positive
    parameter under the prior, so the physical bound 0 is never crossed; else x), at
    -3 .. +3 posterior standard deviations ``sd_u`` (10 % of the value where not given). A
    side whose outer point has not risen to D = 3.84 is extended by doubling its reach, up to
    ``max_extend`` times (adaptive steps); points outside the physical bounds are not
    evaluated. Each grid point is a fit of the other parameters with this one fixed, started
    from the best fit, all in lock-step. The statistic is scaled by the data's variance scale
    ``s2`` (the same scale as the Laplace covariance), so its thresholds 1 and 3.84 match the
    68 % and 95 % intervals of that covariance where the problem is linear.
    """
    k = obj.names.index(name)
    prior = obj.prior
    log = bool(prior is not None and prior.log[k])
    to_u = (lambda v: np.log(v)) if log else (lambda v: v)
    from_u = (lambda v: np.exp(v)) if log else (lambda v: v)
    u0 = float(to_u(x_best[k]))
    h = float(sd_u) if sd_u is not None and np.isfinite(sd_u) and sd_u > 0 else \
        (0.1 if log else 0.1 * max(abs(x_best[k]), 1e-30))
    lo_b, hi_b = obj.bounds()
    xn = obj.to_normalised(x_best)
    f = HeldFixed(obj, k)
    kw = lm.as_kwargs()
    kw.update(ftol_abs=min(kw["ftol_abs"], 1e-4), stall_window=0)
    lo_n, hi_n = obj.bounds_normalised()
    phi0 = float(obj.chi2(xn[None])[0])
    pts: dict[float, float] = {}

    def run(offsets):
        us = [u0 + o * h for o in offsets]
        xs = np.array([from_u(u) for u in us])
        ok = (xs > lo_b[k]) & (xs < hi_b[k]) & np.isfinite(xs)
        if not ok.any():
            return
        X0 = np.repeat(xn[None], int(ok.sum()), axis=0)
        X0[:, k] = xs[ok] / obj.scale[k]
        res = levenberg_marquardt_batch(f, X0, residuals=f.residuals, lower=lo_n, upper=hi_n,
                                        **kw)
        for x, c in zip(xs[ok], res.chi2):
            pts[float(x)] = float(c) if np.isfinite(c) else np.nan

    offsets = [-3.0, -2.0, -1.0, -0.5, 0.5, 1.0, 2.0, 3.0]
    run(offsets)
    for side in (-1.0, 1.0):
        reach = 3.0
        for _ in range(max_extend):
            xs = sorted(pts)
            phi_min = min([phi0] + [v for v in pts.values() if np.isfinite(v)])
            edge = xs[0] if side < 0 else xs[-1]
            if np.isfinite(pts[edge]) and (pts[edge] - phi_min) / s2 >= 3.84:
                break
            reach *= 2.0
            run([side * reach * 0.75, side * reach])
    pts[float(x_best[k])] = phi0
    grid = np.array(sorted(pts))
    phi = np.array([pts[g] for g in grid])
    dchi = (phi - np.nanmin(phi)) / s2
    d = np.where(np.isfinite(dchi), dchi, np.inf)
    lower, upper = _crossings(grid, d, x_best[k], 1.0)
    lower95, upper95 = _crossings(grid, d, x_best[k], 3.84)
    return Profile(name, grid, dchi, lower, upper, lower95, upper95)


class _Constrained:
    """The objective with a soft constraint g(x) = c appended as one residual row
    ``weight * (g(x) - c) / scale``; the target c of each row rides along as an extra,
    never-moving coordinate (its Jacobian column is zero, as in :class:`HeldFixed`), so each
    row keeps its own target whatever subset of rows the lock-step optimizer evaluates. The
    row's gradient is a forward difference in the normalised coordinates."""

    def __init__(self, obj: Objective, quantity, scale: float, weight: float):
        self.obj, self.g, self.scale, self.weight = obj, quantity, scale, weight

    def _row(self, X, c):
        return self.weight * (self.g(self.obj.to_physical(X)) - c) / self.scale

    def __call__(self, Xa):
        X, c = Xa[:, :-1], Xa[:, -1]
        r, J = self.obj(X)
        B, P = X.shape
        h = 1e-6 * np.maximum(np.abs(X), 1e-3)
        Xh = np.repeat(X[:, None, :], P, axis=1)
        Xh[:, np.arange(P), np.arange(P)] += h
        gh = self._row(Xh.reshape(B * P, P), np.repeat(c, P)).reshape(B, P)
        g0 = self._row(X, c)
        Jg = (gh - g0[:, None]) / h
        Ja = np.concatenate([J, Jg[:, None, :]], axis=1)
        Ja = np.concatenate([Ja, np.zeros(Ja.shape[:2] + (1,))], axis=2)
        return np.concatenate([r, g0[:, None]], axis=1), Ja

    def residuals(self, Xa):
        X, c = Xa[:, :-1], Xa[:, -1]
        return np.concatenate([self.obj.residuals(X), self._row(X, c)[:, None]], axis=1)


def profile_prediction(obj: Objective, x_best: np.ndarray, quantity, name: str, *,
                       s2: float = 1.0, sd: float | None = None,
                       lm: LMOptions = LMOptions(), weight: float = 30.0) -> Profile:
    """Profile likelihood of a predicted quantity ``g = quantity(X)`` ((B, P) physical
    parameter rows -> (B,)), e.g. an overshoot of a body point: at targets
    g(x^) + (-3 .. 3) ``sd`` the objective is minimised with g held near the target by a soft
    constraint (:class:`_Constrained`), and each minimum is recorded at the value g actually
    takes there, so every point of the profile is exact whatever the constraint's slack.
    Statistic, thresholds and intervals as in :func:`profile_likelihood` (the grid holds
    values of g)."""
    xn = obj.to_normalised(x_best)
    g0 = float(quantity(x_best[None])[0])
    h = float(sd) if sd is not None and np.isfinite(sd) and sd > 0 else 0.1 * max(abs(g0), 1e-30)
    targets = g0 + h * np.array([-3.0, -2.0, -1.0, -0.5, 0.5, 1.0, 2.0, 3.0])
    lo, hi = obj.bounds_normalised()
    f = _Constrained(obj, quantity, h, weight)
    Xa = np.column_stack([np.repeat(xn[None], targets.size, axis=0), targets])
    kw = lm.as_kwargs()
    kw.update(ftol_abs=min(kw["ftol_abs"], 1e-4), stall_window=0)
    res = levenberg_marquardt_batch(f, Xa, residuals=f.residuals,
                                    lower=np.append(lo, -np.inf), upper=np.append(hi, np.inf),
                                    **kw)
    X = res.x[:, :-1]
    phi = obj.chi2(X)
    g = quantity(obj.to_physical(X))
    phi0 = float(obj.chi2(xn[None])[0])
    grid = np.append(g, g0)
    vals = np.append(phi, phi0)
    keep = np.isfinite(grid) & np.isfinite(vals)
    order = np.argsort(grid[keep])
    grid, vals = grid[keep][order], vals[keep][order]
    dchi = (vals - vals.min()) / s2
    lower, upper = _crossings(grid, dchi, g0, 1.0)
    lower95, upper95 = _crossings(grid, dchi, g0, 3.84)
    return Profile(name, grid, dchi, lower, upper, lower95, upper95)


def _crossings(grid, dchi, centre, level=1.0):
    lower = upper = np.nan
    left = np.nonzero((grid < centre) & (dchi >= level))[0]
    if left.size:
        i = left[-1]
        j = i + 1
        lower = np.interp(level, [min(dchi[j], level), dchi[i]], [grid[j], grid[i]])
    right = np.nonzero((grid > centre) & (dchi >= level))[0]
    if right.size:
        j = right[0]
        i = j - 1
        upper = np.interp(level, [min(dchi[i], level), dchi[j]], [grid[i], grid[j]])
    return lower, upper
