"""The impact scenario read from the telemetry (issue 23, item 2; docs/flight.md §11).

For each release, a posterior over a scenario's unknowns (:data:`gprm.flight.scenario.PARAMS`:
gap fraction, contact height and azimuth, friction, restitution; and the impact time they
imply) given the measured TM velocity components with their standard errors and the fitted
model with its uncertainty, and the evidence of each scenario
(:data:`gprm.flight.scenario.COMPARED`: one contact in x–z, in y–z, two contacts), per
release and jointly over the releases.

Method (importance sampling from the prior, with the model's parameters marginalised in a
Gaussian approximation):

* ``n_draws`` draws φ_k of the scenario's unknowns from its prior
  (:class:`~gprm.flight.scenario.ScenarioPrior`) and ``n_model`` parameter sets θ_m from the fit
  (``FittedModel.sample``); for every pair the impact time t_mk (gap rule on θ_m's own motion)
  and the TM velocity y_mk (:func:`~gprm.flight.scenario.scenario_velocity`);
* for each φ_k, the mean μ_k and covariance C_k of (y, t) over the θ_m: the model's interval
  at φ_k; the TM's lateral offset from the head axis (``ScenarioPrior.tm_offset``) is
  marginalised by adding its first-order covariance of the angular components
  (:func:`~gprm.flight.scenario.offset_covariance`, averaged over the θ_m). The likelihood
  of a release's measurement y with standard errors σ is
  L_k = N(y; μ_k, C_k + diag(σ²) + diag(floor²)), ``floor`` a model-form allowance
  (:class:`InferenceOptions`); a φ_k at which fewer than ``min_valid`` of the θ_m give an
  impact has L_k = 0;
* posterior weights w_k ∝ L_k (the draws are from the prior); evidence Z = mean_k L_k (the
  prior-sampling estimate of the marginal likelihood); scenario probabilities Z_s / Σ Z
  (equal prior odds), jointly over releases with Σ_r log Z_{s,r} (one scenario for all);
  each release's reported scenario is chosen given the whole file
  (:func:`file_probabilities`: the file's releases share one scenario, or each has its own,
  prior odds 1:1), its choice on its own evidence kept beside it;
  :func:`pooled_probabilities` (the releases' scenarios drawn from frequencies the file
  shares) is a development measurement (docs/flight.md §11: it helps on files of one
  scenario and costs on mixed ones);
* intervals: weighted 2.5 / 97.5 % points of the φ_k; for the impact time, the mixture over
  k of the Gaussian conditionals t | y (linear-Gaussian in the θ_m), sampled.
* optionally (``InferenceOptions.n_refine``), a second importance stage per release and
  scenario around the first stage's posterior, pooled with the prior draws as a
  deterministic mixture (:func:`second_stage`): the same posterior and evidence with more
  effective draws.

Plain functions over arrays; the result is a frozen dataclass whose ``to_json()`` goes into
impact.json (``scenarios``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gprm.errors import GprmInputError
from gprm.flight.scenario import (COMPARED, COMPONENTS, OFFSETS, PARAMS, SCENARIO_GRID_STEP,
                                  SCENARIOS, ScenarioPrior, offset_covariance, plunger_frame,
                                  scenario_grid, scenario_velocity)
from gprm.validate import check_int

PARAM_UNIT = {"f": "1", "s": "m", "phi": "rad", "mu": "1", "e": "1", "t": "s"}


@dataclass(frozen=True)
class InferenceOptions:
    """What defines the scenario inference (SI). ``scenarios``: the compared scenarios;
    ``n_draws``: prior draws of the unknowns per scenario (the recovery of docs/flight.md §11
    is measured with the default); ``n_model``: parameter sets drawn from the fit; ``seed``;
    ``floor``: model-form standard deviation added to every component (linear m/s, angular
    rad/s); ``rel_floor``: and this fraction of each component's model mean; ``min_valid``:
    the fraction of the parameter sets that must give an impact at a draw; ``grid_step`` (s)
    of the motion; ``n_refine``: draws of a second importance stage per release and
    scenario around the first stage's posterior (:func:`second_stage`; 0: none, the
    default: measured in docs/flight.md §11, it raises the effective draws but not the
    calibration, at 1.5 s per release and scenario)."""

    scenarios: tuple[str, ...] = COMPARED
    n_draws: int = 20000
    n_model: int = 48
    seed: int = 0
    floor: tuple[float, float] = (0.2e-6, 10e-6)
    rel_floor: float = 0.02
    min_valid: float = 0.75
    grid_step: float = SCENARIO_GRID_STEP
    n_refine: int = 0

    def __post_init__(self):
        sc = tuple(self.scenarios)
        if not sc or any(s not in SCENARIOS for s in sc) or len(set(sc)) != len(sc):
            raise GprmInputError(f"expected distinct names among {', '.join(SCENARIOS)}, "
                                 f"got {self.scenarios!r}", field="scenarios")
        object.__setattr__(self, "scenarios", sc)
        check_int("n_draws", self.n_draws, 10)
        check_int("n_model", self.n_model, 8)
        check_int("seed", self.seed, 0)
        check_int("n_refine", self.n_refine, 0)
        if not 0 < self.min_valid <= 1:
            raise GprmInputError("must lie in (0, 1]", field="min_valid")


@dataclass(frozen=True)
class PriorPredictive:
    """A scenario's prior draws and the model's interval at each: ``params`` {name: (K,)},
    ``mean`` (K, 6) and ``cov`` (K, 6, 6) of the TM velocity over the parameter sets,
    ``t_mean`` (K,), ``t_cov`` (K, 6) covariance of t with the velocity, ``t_var`` (K,),
    ``valid`` (K,) where enough sets give an impact; ``p_impact`` (K,) the fraction of the
    sets that give one; ``log_iw`` (K,) ln(prior / proposal) of each draw when the draws are
    not the prior's (:func:`refined_predictive`; None: prior draws)."""

    scenario: str
    params: dict
    mean: np.ndarray
    cov: np.ndarray
    t_mean: np.ndarray
    t_cov: np.ndarray
    t_var: np.ndarray
    valid: np.ndarray
    p_impact: np.ndarray | None = None
    log_iw: np.ndarray | None = None


def prior_predictive(model, kind: str, opts: InferenceOptions,
                     prior: ScenarioPrior | None = None, *, frame=None, pb0=None
                     ) -> PriorPredictive:
    """The prior draws of scenario ``kind`` and the model's mean and covariance of the TM
    velocity and the impact time at each (module docstring)."""
    from gprm.params import batch

    prior = prior or ScenarioPrior()
    pb0 = batch([model.params]) if pb0 is None else pb0
    if frame is None:
        frame = model_frame(model, opts, pb0)
    rng = np.random.default_rng([opts.seed, SCENARIOS.index(kind)])
    return predictive_at(kind, prior.draw(opts.n_draws, rng), frame, pb0, opts, prior)


def predictive_at(kind: str, p: dict, frame, pb0, opts: InferenceOptions,
                  prior: ScenarioPrior) -> PriorPredictive:
    """The model's mean and covariance of the TM velocity and the impact time over the
    parameter sets of ``frame`` at given draws ``p`` ({name: (K,)} of :data:`PARAMS`) of
    scenario ``kind`` (module docstring); the draws' offsets are set to zero (marginalised in
    closed form)."""
    p = {k: np.asarray(p[k], float) for k in PARAMS}
    K = p["f"].size
    # the TM's lateral offset is marginalised in closed form (first order, Gaussian:
    # offset_covariance), not sampled: the draws keep the TM centred
    p.update({k: np.zeros(K) for k in OFFSETS})
    s_tm = float(np.ravel(pb0["s_tm"])[0])
    chunk = max(1, 4_000_000 // max(1, frame.A.shape[0] * frame.time.size))
    parts = []
    for a in range(0, K, chunk):
        out = scenario_velocity(kind, frame, pb0, {k: v[a:a + chunk] for k, v in p.items()},
                                prior)
        parts.append(set_moments(np.stack([out[c] for c in COMPONENTS], -1), out["t"],
                                 out["ok"], opts, prior, s_tm))
    mom = {k: np.concatenate([q[k] for q in parts]) for k in parts[0]}
    return PriorPredictive(kind, p, mom["mean"], mom["cov"], mom["t_mean"], mom["t_cov"],
                           mom["t_var"], mom["valid"], mom["p_impact"])


def set_moments(y: np.ndarray, t: np.ndarray, ok: np.ndarray, opts: InferenceOptions,
                prior: ScenarioPrior, s_tm: float) -> dict:
    """Per draw k, the moments of (TM velocity, impact time) over the parameter sets that give
    an impact: ``y`` (M, K, 6) velocities, ``t`` (M, K) impact times, ``ok`` (M, K) where
    an impact happens. Returns {mean (K, 6), cov (K, 6, 6) with the offset's covariance
    added, t_mean (K,), t_cov (K, 6), t_var (K,), valid (K,): at least ``opts.min_valid``
    of the sets give an impact, p_impact (K,)} (NaN where not valid)."""
    K = ok.shape[1]
    out = {"mean": np.full((K, 6), np.nan), "cov": np.full((K, 6, 6), np.nan),
           "t_mean": np.full(K, np.nan), "t_cov": np.full((K, 6), np.nan),
           "t_var": np.full(K, np.nan), "p_impact": ok.mean(0)}
    out["valid"] = out["p_impact"] >= opts.min_valid
    for k in np.flatnonzero(out["valid"]):
        m = ok[:, k]
        Y = np.concatenate([y[m, k], t[m, k, None]], -1)   # (n, 7)
        mu = Y.mean(0)
        C = np.cov(Y, rowvar=False)
        if prior.tm_offset > 0:
            C[:6, :6] += offset_covariance(Y[:, :3], s_tm, prior.tm_offset).mean(0)
        out["mean"][k], out["cov"][k] = mu[:6], C[:6, :6]
        out["t_mean"][k], out["t_cov"][k], out["t_var"][k] = mu[6], C[6, :6], C[6, 6]
    return out


def second_stage(pp: PriorPredictive, w: np.ndarray, n: int, prior: ScenarioPrior,
                 rng: np.random.Generator, *, inflate: float = 2.0):
    """The draws of a second importance stage for one release: ``n`` draws from a normal
    fitted to the first stage's posterior (``w`` over ``pp``'s prior draws; its covariance
    times ``inflate``²), restricted to the prior's box (rejection; the box mass of the normal
    estimated from the rejected draws), as {name: (n,)} of :data:`PARAMS`; and ln π − ln q of
    the pooled draws (``pp``'s then the new, (K + n,)), q = (K π + n g) / (K + n) the
    deterministic mixture of the prior π and the restricted normal g, so that weights
    ∝ L π / q and the evidence mean(L π / q) estimate the same posterior and evidence as the
    prior draws alone, with more draws where the posterior is (docs/flight.md §11)."""
    if pp.log_iw is not None:
        raise GprmInputError("refine the prior's draws only", field="pp")
    check_int("n", n, 1)
    b = prior.bounds()
    lo = np.array([b[k][0] for k in PARAMS])
    hi = np.array([b[k][1] for k in PARAMS])
    X = np.stack([pp.params[k] for k in PARAMS], 1)
    w = np.asarray(w, float)
    m = w @ X
    C = (X - m).T @ ((X - m) * w[:, None]) / max(1e-12, 1.0 - np.sum(w * w))
    # a floor of 1e-3 of the box: a posterior on one draw still gives a proper normal
    C = inflate ** 2 * C + np.diag((1e-3 * (hi - lo)) ** 2)
    L = np.linalg.cholesky(C)
    acc, got, tried = [], 0, 0
    while got < n and tried < 1000 * n:
        z = m + rng.standard_normal((max(4 * n, 20000), lo.size)) @ L.T
        tried += z.shape[0]
        acc.append(z[np.all((z >= lo) & (z <= hi), 1)])
        got += acc[-1].shape[0]
    if got == 0:
        raise GprmInputError("the first stage's posterior lies outside the prior's box",
                             field="pp")
    box = got / tried
    Z = np.concatenate(acc)[:n]
    allx = np.concatenate([X, Z])
    r = np.linalg.solve(L, (allx - m).T)
    log_g = (-0.5 * np.sum(r * r, 0) - np.sum(np.log(np.diag(L)))
             - 0.5 * lo.size * np.log(2 * np.pi) - np.log(box))
    log_pi = -np.sum(np.log(hi - lo))
    K1, n2 = X.shape[0], Z.shape[0]
    log_q = np.logaddexp(np.log(K1) + log_pi, np.log(n2) + log_g) - np.log(K1 + n2)
    return {k: Z[:, i] for i, k in enumerate(PARAMS)}, log_pi - log_q


def pooled(pp: PriorPredictive, new: PriorPredictive, log_iw: np.ndarray) -> PriorPredictive:
    """``pp``'s draws and ``new``'s as one set with the importance log ratios ``log_iw`` of
    :func:`second_stage`."""
    def cat(a, c):
        return None if a is None or c is None else np.concatenate([a, c])
    return PriorPredictive(pp.scenario, {k: cat(pp.params[k], new.params[k]) for k in PARAMS},
                           cat(pp.mean, new.mean), cat(pp.cov, new.cov),
                           cat(pp.t_mean, new.t_mean), cat(pp.t_cov, new.t_cov),
                           cat(pp.t_var, new.t_var), cat(pp.valid, new.valid),
                           cat(pp.p_impact, new.p_impact), np.asarray(log_iw, float))


def refined_predictive(pp: PriorPredictive, w: np.ndarray, n: int, frame, pb0,
                       opts: InferenceOptions, prior: ScenarioPrior,
                       rng: np.random.Generator, *, inflate: float = 2.0) -> PriorPredictive:
    """``pp`` pooled with ``n`` draws of a second importance stage around the first stage's
    posterior ``w`` (:func:`second_stage`), the model's interval computed at the new draws
    (:func:`predictive_at`) on the same parameter sets ``frame``."""
    p, log_iw = second_stage(pp, w, n, prior, rng, inflate=inflate)
    return pooled(pp, predictive_at(pp.scenario, p, frame, pb0, opts, prior), log_iw)


def model_frame(model, opts: InferenceOptions, pb0=None):
    """The plunger motions of ``opts.n_model`` parameter sets drawn from the fit."""
    from gprm.params import batch
    from gprm.simulate.kinematics import body_motion

    pb0 = batch([model.params]) if pb0 is None else pb0
    grid = scenario_grid(pb0, step=opts.grid_step)
    return plunger_frame(body_motion(model_sets(model, opts), grid, piezo=model.piezo))


def model_sets(model, opts: InferenceOptions) -> dict:
    """The ``opts.n_model`` parameter sets (a batch) whose motions :func:`model_frame` holds."""
    return model.sample(opts.n_model, seed=opts.seed + 17)


def _weighted_quantiles(x, w, q):
    o = np.argsort(x)
    cw = np.cumsum(w[o])
    cw /= cw[-1]
    return np.interp(q, cw - 0.5 * w[o] / w.sum(), x[o])


@dataclass(frozen=True)
class ScenarioFit:
    """One release under one scenario: ``log_evidence`` (natural log, the velocity's units
    SI), ``ess`` the effective number of draws, and per unknown (PARAMS and ``t``) the
    posterior median and 95 % interval ``{name: (median, lo, hi)}``."""

    scenario: str
    log_evidence: float
    ess: float
    summary: dict

    def to_json(self) -> dict:
        return {"scenario": self.scenario, "log_evidence": _f(self.log_evidence),
                "ess": _f(self.ess),
                "params": {k: {"median": _f(v[0]), "ci95": [_f(v[1]), _f(v[2])],
                               "unit": PARAM_UNIT[k]} for k, v in self.summary.items()}}


def _f(x):
    return None if x is None or not np.isfinite(x) else float(x)


def _log_likelihood(pp: PriorPredictive, y: np.ndarray, sigma: np.ndarray, use: np.ndarray,
                    opts: InferenceOptions):
    """ln L_k of every prior draw (K,) (−inf where not valid), with the valid draws'
    covariances S (Kv, d, d) and residuals r (Kv, d) over the measured components ``idx``."""
    idx = np.flatnonzero(use)
    K = pp.valid.size
    v = pp.valid
    mu = pp.mean[v][:, idx]
    C = pp.cov[v][:, idx][:, :, idx]
    fl = np.array([opts.floor[0]] * 3 + [opts.floor[1]] * 3)[idx]
    extra = sigma[idx] ** 2 + fl ** 2 + (opts.rel_floor * mu) ** 2
    S = C + extra[:, None, :] * np.eye(idx.size)
    r = y[idx] - mu
    L = np.linalg.cholesky(S)
    z = np.linalg.solve(L, r[..., None])[..., 0]
    logdet = 2 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), -1)
    ll = -0.5 * np.sum(z * z, -1) - 0.5 * logdet - 0.5 * idx.size * np.log(2 * np.pi)
    logL = np.full(K, -np.inf)
    logL[v] = ll
    return logL, S, r, idx


def posterior_weights(pp: PriorPredictive, y: np.ndarray, sigma: np.ndarray, use: np.ndarray,
                      opts: InferenceOptions) -> np.ndarray:
    """The normalised posterior weights w_k (K,) of the prior draws ``pp.params`` given one
    release (as :func:`fit_release`; zeros if no draw is valid), e.g. for the posterior's
    CDF at a known truth."""
    logL = _log_likelihood(pp, y, sigma, use, opts)[0]
    if pp.log_iw is not None:
        logL = logL + pp.log_iw
    mx = np.max(logL)
    if not np.isfinite(mx):
        return np.zeros(logL.size)
    w = np.exp(logL - mx)
    return w / w.sum()


def fit_release(pp: PriorPredictive, y: np.ndarray, sigma: np.ndarray, use: np.ndarray,
                opts: InferenceOptions, rng: np.random.Generator) -> ScenarioFit:
    """The posterior of one release (measured ``y`` (6,), standard errors ``sigma`` (6,),
    ``use`` (6,) the components measured) under the scenario of ``pp``."""
    logL, S, r, idx = _log_likelihood(pp, y, sigma, use, opts)
    if pp.log_iw is not None:       # draws not the prior's: L π / q (refined_predictive)
        logL = logL + pp.log_iw
    K, v = pp.valid.size, pp.valid
    mx = np.max(logL)
    if not np.isfinite(mx):
        return ScenarioFit(pp.scenario, -np.inf, 0.0, {})
    w = np.exp(logL - mx)
    logZ = mx + np.log(w.sum()) - np.log(K)
    w /= w.sum()
    ess = 1.0 / np.sum(w * w)
    summ = {}
    for k in PARAMS:
        q = _weighted_quantiles(pp.params[k], w, [0.5, 0.025, 0.975])
        summ[k] = tuple(float(x) for x in q)
    # impact time: mixture over the draws of the Gaussian conditional t | y
    Sinv_r = np.linalg.solve(S, r[..., None])[..., 0]            # (Kv, d)
    ct = pp.t_cov[v][:, idx]
    tmean = pp.t_mean[v] + np.sum(ct * Sinv_r, -1)
    tvar = pp.t_var[v] - np.sum(ct * np.linalg.solve(S, ct[..., None])[..., 0], -1)
    tsd = np.sqrt(np.clip(tvar, 0, None))
    wv = w[v]
    pick = rng.choice(wv.size, size=4000, p=wv / wv.sum())
    ts = tmean[pick] + tsd[pick] * rng.standard_normal(pick.size)
    summ["t"] = tuple(float(x) for x in np.quantile(ts, [0.5, 0.025, 0.975]))
    return ScenarioFit(pp.scenario, float(logZ), float(ess), summ)


def _log_evidence(fits, scenarios) -> np.ndarray:
    """(R, K) the releases' ``fits`` natural-log evidences of ``scenarios`` (-inf where a
    scenario has none)."""
    L = np.array([[f[s].log_evidence for s in scenarios] for f in fits],
                 float).reshape(len(fits), len(scenarios))
    return np.where(np.isfinite(L), L, -np.inf)


@dataclass(frozen=True)
class ScenarioInference:
    """Scenario fits of every release: ``fits[r][scenario]`` (:class:`ScenarioFit`);
    ``probability[r][scenario]`` and ``chosen[r]``: each release's scenario given the whole
    file (:func:`file_probabilities`: one scenario for the file or each release its own);
    ``probability_alone``, ``chosen_alone``: on the release's own evidence (equal prior
    odds); ``joint``: the scenarios' summed log evidence and probabilities over the releases
    (one scenario for all), the one chosen, and the posterior probability that the releases
    share one scenario (``p_same``, prior ``p_same_prior``); ``components``: the velocity
    components used."""

    ids: tuple[str, ...]
    fits: tuple[dict, ...]
    probability: tuple[dict, ...]
    chosen: tuple[str | None, ...]
    joint: dict
    components: tuple[str, ...]
    options: dict
    probability_alone: tuple[dict, ...] = ()
    chosen_alone: tuple[str, ...] = ()

    def log_evidence(self) -> np.ndarray:
        """(R, K) each release's natural-log evidence of each compared scenario, in
        ``options["scenarios"]`` order (-inf where a scenario has none)."""
        return _log_evidence(self.fits, self.options["scenarios"])

    def to_json(self) -> dict:
        return {"method": "importance sampling from the prior; model parameters marginalised "
                          "in a Gaussian approximation (docs/flight.md §11)",
                "components": list(self.components), "options": self.options,
                "releases": [{"id": i, "chosen": c,
                              "probability": {k: _f(v) for k, v in p.items()},
                              "chosen_alone": ca,
                              "probability_alone": {k: _f(v) for k, v in pa.items()},
                              "fits": {k: f.to_json() for k, f in fits.items()}}
                             for i, c, p, ca, pa, fits in zip(
                                 self.ids, self.chosen, self.probability, self.chosen_alone,
                                 self.probability_alone, self.fits)],
                "joint": self.joint}


#: the concentration of the Dirichlet prior on a file's scenario frequencies (1: uniform over
#: the frequencies; :func:`pooled_probabilities`, a development measurement)
POOL_ALPHA = 1.0


def pooled_probabilities(logz, alpha: float = POOL_ALPHA) -> np.ndarray:
    """(R, K) each release's scenario probabilities given every release of its file: the
    releases exchangeable, each one's scenario drawn from the file's frequencies pi over the K
    scenarios, pi ~ Dirichlet(alpha), so that

        P(s_r = k | y) ∝ Z_rk sum over the others' scenarios of prod_r' Z_r's_r'
                         DirMult(counts with s_r = k; alpha),

    DirMult the Dirichlet-multinomial probability of an assignment, prod_j Gamma(alpha + n_j)
    up to factors common to every assignment. Exact: the others' assignments enter only
    through their counts, summed by a recursion over the releases on the count lattice
    (n_1 .. n_K-1; n_K the rest), (R + 1)^(K - 1) states. ``logz`` (R, K) natural-log
    evidences Z_rk; a release with no finite evidence takes no part and gets NaN. With one
    release, or alpha -> infinity, the release's own probabilities (equal prior odds);
    with many releases of one scenario, that scenario's prior weight for each of them grows
    to (alpha + R - 1) / (K alpha + R - 1)."""
    from scipy.special import gammaln

    L = np.asarray(logz, float)
    R, K = L.shape
    out = np.full((R, K), np.nan)
    ok = np.flatnonzero(np.any(np.isfinite(L), axis=1))
    if ok.size == 0:
        return out
    Lok = np.where(np.isfinite(L[ok]), L[ok], -np.inf)
    P = np.exp(Lok - Lok.max(axis=1, keepdims=True))       # each row's largest 1, none 0
    n = ok.size
    if K == 1:
        out[ok] = 1.0
        return out
    shape = (n,) * (K - 1)       # counts n_1 .. n_{K-1} of the n - 1 others (< n each)
    grids = np.meshgrid(*[np.arange(n)] * (K - 1), indexing="ij")
    for i in range(n):
        W = np.zeros(shape)
        W[(0,) * (K - 1)] = 1.0
        for j in range(n):
            if j == i:
                continue
            new = W * P[j, K - 1]               # scenario K: the counts stay
            for k in range(K - 1):              # scenario k: n_k + 1
                sh = [slice(None)] * (K - 1)
                src = [slice(None)] * (K - 1)
                sh[k], src[k] = slice(1, None), slice(None, -1)
                new[tuple(sh)] += W[tuple(src)] * P[j, k]
            W = new
        rest = (n - 1) - np.sum(grids, axis=0)
        valid = np.asarray(rest >= 0)
        counts = list(grids) + [np.maximum(rest, 0)]    # the invalid states masked below
        base = sum(gammaln(alpha + c) for c in counts)
        logg = np.array([base + np.log(alpha + counts[k]) for k in range(K)])
        with np.errstate(divide="ignore", invalid="ignore"):
            lw = np.where(valid & (W > 0), np.log(np.where(W > 0, W, 1.0)), -np.inf)
        t = lw[None] + np.where(valid[None], logg, -np.inf)
        m = np.max(t)
        S = np.exp(t - m).reshape(K, -1).sum(1)
        q = P[i] * S
        out[ok[i]] = q / q.sum() if q.sum() > 0 else np.nan
    return out


#: the prior probability that a file's releases share one scenario (the alternative: each
#: release its own, independently, with equal prior odds); :func:`file_probabilities`
P_SAME = 0.5


def file_probabilities(logz, p_same: float = P_SAME) -> tuple[np.ndarray, float]:
    """Each release's scenario probabilities given every release of its file, and the
    posterior probability that the file's releases share one scenario.

    Two hypotheses about a file of R releases and K scenarios, with prior weights ``p_same``
    and 1 - ``p_same``: *same*, one scenario for every release (equal prior odds over the
    K), evidence (1/K) sum_k prod_r Z_rk; *each*, every release its own scenario
    independently (equal prior odds), evidence prod_r (1/K) sum_k Z_rk. Then

        P(s_r = k | y) = P(same | y) prod_r' Z_r'k / sum_j prod_r' Z_r'j
                         + P(each | y) Z_rk / sum_j Z_rj.

    A file whose releases point to different scenarios makes *each* the more probable by
    the product of its releases' evidence ratios, and every release keeps its own choice; a
    file of one scenario lets its clear releases decide its ambiguous ones. With one release
    both hypotheses are the same and so is the result. ``logz`` (R, K) natural-log evidences
    Z_rk; a release with no finite evidence takes no part and gets NaN. Returns ((R, K),
    P(same | y)); NaN for P where no release has an evidence."""
    from scipy.special import logsumexp

    if not 0.0 <= float(p_same) <= 1.0:
        raise GprmInputError(f"must be a probability in [0, 1], got {p_same!r}",
                             field="p_same")
    L = np.asarray(logz, float)
    R, K = L.shape
    out = np.full((R, K), np.nan)
    ok = np.flatnonzero(np.any(np.isfinite(L), axis=1))
    if ok.size == 0:
        return out, float("nan")
    Lok = np.where(np.isfinite(L[ok]), L[ok], -np.inf)
    own = Lok - logsumexp(Lok, axis=1, keepdims=True)             # each release alone
    tot = Lok.sum(axis=0)                                          # (K,) one scenario for all
    z_same = float(logsumexp(tot))
    if not np.isfinite(z_same):         # no scenario has an evidence in every release
        out[ok] = np.exp(own)
        return out, 0.0
    with np.errstate(divide="ignore"):
        log_same = np.log(float(p_same)) + z_same - np.log(K)
        log_each = np.log(1.0 - float(p_same)) + float(
            np.sum(logsumexp(Lok, axis=1) - np.log(K)))
    p = float(np.exp(log_same - np.logaddexp(log_same, log_each)))
    out[ok] = p * np.exp(tot - z_same)[None, :] + (1.0 - p) * np.exp(own)
    return out, p


def probability_text(p: float) -> str:
    """A probability as a reader should see it: three decimals, "> 0.999" / "< 0.001" at
    the ends rather than a rounded 1 or 0 (written out in scientific notation below 1e-3)."""
    if p >= 0.9995:
        return "> 0.999"
    if p < 0.0005:
        return f"< 0.001 ({p:.1e})"
    return f"{p:.3f}"


def _probs(logz: dict) -> dict:
    a = np.array([logz[k] for k in logz])
    if not np.any(np.isfinite(a)):
        return {k: None for k in logz}
    p = np.exp(a - np.max(a))
    p /= p.sum()
    return {k: float(x) for k, x in zip(logz, p)}


def prior_predictives(model, opts: InferenceOptions = InferenceOptions(),
                      prior: ScenarioPrior | None = None) -> dict:
    """:func:`prior_predictive` of every scenario of ``opts`` (they depend on the model and
    the options only: computed once, they serve any number of releases)."""
    from gprm.params import batch

    pb0 = batch([model.params])
    frame = model_frame(model, opts, pb0)
    return {s: prior_predictive(model, s, opts, prior, frame=frame, pb0=pb0)
            for s in opts.scenarios}


def infer_scenarios(model, ids, y, sigma, opts: InferenceOptions = InferenceOptions(),
                    prior: ScenarioPrior | None = None, *,
                    predictive: dict | None = None) -> ScenarioInference:
    """The scenario posterior of every release: ``y`` (R, 6) measured velocity components
    (:data:`~gprm.flight.scenario.COMPONENTS`, NaN where not measured), ``sigma`` (R, 6)
    their standard errors (module docstring); ``predictive``: :func:`prior_predictives` of
    this model and these options, if already computed."""
    if not isinstance(opts, InferenceOptions):
        raise GprmInputError(f"expected InferenceOptions, got {type(opts).__name__}",
                             field="opts")
    y = np.asarray(y, float)
    sigma = np.nan_to_num(np.asarray(sigma, float), nan=0.0)
    use = np.isfinite(y)
    pps = predictive if predictive is not None else prior_predictives(model, opts, prior)
    rng = np.random.default_rng([opts.seed, 99])
    if opts.n_refine:
        from gprm.params import batch

        pb0 = batch([model.params])
        frame = model_frame(model, opts, pb0)
    fits, probs, chosen = [], [], []
    total = {s: 0.0 for s in opts.scenarios}
    for r in range(y.shape[0]):
        yr = np.nan_to_num(y[r])
        fr = {}
        for s in opts.scenarios:
            pp = pps[s]
            if opts.n_refine:   # its own stream per release and scenario: order-free
                w = posterior_weights(pp, yr, sigma[r], use[r], opts)
                if w.any():
                    pp = refined_predictive(
                        pp, w, opts.n_refine, frame, pb0, opts, prior or ScenarioPrior(),
                        np.random.default_rng([opts.seed, 7, r, SCENARIOS.index(s)]))
            fr[s] = fit_release(pp, yr, sigma[r], use[r], opts, rng)
        pr = _probs({s: fr[s].log_evidence for s in opts.scenarios})
        fits.append(fr)
        probs.append(pr)
        chosen.append(max(opts.scenarios, key=lambda s: fr[s].log_evidence))
        for s in opts.scenarios:
            total[s] += fr[s].log_evidence
    jp = _probs(total)
    # each release's scenario given the file: one scenario for all, or each its own
    sc = list(opts.scenarios)
    given, p_same = file_probabilities(_log_evidence(fits, sc), P_SAME)
    probs_file = [{s: (None if not np.isfinite(g[j]) else float(g[j]))
                   for j, s in enumerate(sc)} for g in given]
    chosen_file = [sc[int(np.argmax(g))] if np.all(np.isfinite(g)) else None for g in given]
    joint = {"log_evidence": {s: _f(v) for s, v in total.items()}, "probability": jp,
             "chosen": (max(total, key=lambda s: total[s])
                        if any(np.isfinite(v) for v in total.values()) else None),
             "p_same": _f(p_same), "p_same_prior": P_SAME}
    comps = tuple(c for c, u in zip(COMPONENTS, use.all(0)) if u)
    return ScenarioInference(tuple(ids), tuple(fits), tuple(probs_file), tuple(chosen_file),
                             joint, comps, {"scenarios": list(opts.scenarios),
                                     "n_draws": opts.n_draws, "n_model": opts.n_model,
                                     "n_refine": opts.n_refine,
                                     "seed": opts.seed, "floor": list(opts.floor),
                                     "rel_floor": opts.rel_floor,
                                     "tm_offset": (prior or ScenarioPrior()).tm_offset},
                             tuple(probs), tuple(chosen))


def measured_components(tel, *, fit_window: float | None = None, min_samples: int = 5):
    """The measured TM velocity components of every release of a
    :class:`~gprm.flight.telemetry.Telemetry` as (y, sigma), each (R, 6) in
    :data:`~gprm.flight.scenario.COMPONENTS` order: the release-velocity line fits
    (:func:`~gprm.flight.telemetry.release_velocities`) of x, y, z, θ, η and, where the file
    has it, φ (else NaN: ω_z not measured)."""
    from gprm.flight.telemetry import fit_release_velocity, release_velocities

    vel = release_velocities(tel, fit_window=fit_window, min_samples=min_samples)
    axes = ("vx", "vy", "vz_xz", "wx", "wy")
    y = np.full((len(tel.releases), 6), np.nan)
    s = np.full((len(tel.releases), 6), np.nan)
    for i, r in enumerate(tel.releases):
        for j, a in enumerate(axes):
            y[i, j], s[i, j] = vel[r.id][a].value, vel[r.id][a].stderr
        phi = r.data.get("phi")
        if phi is not None and np.isfinite(phi).any():
            sel = r.time > r.release_time
            if fit_window is not None:
                sel &= r.time <= r.release_time + fit_window
            sp = r.sigma.get("phi")
            lf = fit_release_velocity(r.time[sel], phi[sel], None if sp is None else sp[sel],
                                      t_release=r.release_time)
            y[i, 5], s[i, 5] = lf.value, lf.stderr
    return y, s


LIMITS = {"vx": 5e-6, "vy": 5e-6, "vz": 5e-6, "wx": 100e-6, "wy": 100e-6, "wz": 100e-6}
"""The release requirement per component (the paper, Sec. 1: 5 µm/s, 100 µrad/s)."""

CHECKED: tuple[str, ...] = ("vx", "vy", "vz", "wx", "wy")
"""The components whose non-compliance the observation "every component non-compliant" asks
for: the five the paper's analysis uses (Sec. 4.1: x, y, z, θ, η); ω_z (φ') is reported but
not asked for (a rim contact on the round head gives it no lever arm, docs/flight.md §10)."""

XZ_SHARE_ALMOST = 0.9
"""The x–z share of the momentum, (v_x² + v_z²)/|v|², at or above which we call the momentum
"almost totally in the x–z plane" (our threshold; the paper gives none)."""


def paper_observations(ids, y, sigma) -> dict:
    """The paper's three observations (Sec. 1) checked on measured components ``y`` (R, 6)
    with standard errors ``sigma``: per release whether z is not the largest linear component
    (|v_z| < max(|v_x|, |v_y|)), the x–z share (v_x² + v_z²)/|v|² of the linear momentum and
    whether it is >= :data:`XZ_SHARE_ALMOST`, and which measured components are
    non-compliant (|value| > limit, :data:`LIMITS`; "uncertain" where the limit lies within
    2 standard errors), all of :data:`CHECKED` non-compliant; and the counts over the
    releases."""
    y = np.asarray(y, float)
    sigma = np.asarray(sigma, float)
    rows = []
    for i, rid in enumerate(ids):
        v = y[i, :3]
        share = float((v[0] ** 2 + v[2] ** 2) / np.sum(v * v)) if np.all(np.isfinite(v)) \
            else None
        comp = {}
        for j, c in enumerate(COMPONENTS):
            if not np.isfinite(y[i, j]):
                continue
            a, s = abs(y[i, j]), (sigma[i, j] if np.isfinite(sigma[i, j]) else 0.0)
            comp[c] = ("uncertain" if abs(a - LIMITS[c]) <= 2 * s
                       else "non-compliant" if a > LIMITS[c] else "compliant")
        rows.append({"id": str(rid), "z_not_largest": bool(abs(v[2]) < max(abs(v[0]),
                                                                            abs(v[1]))),
                     "xz_share": share,
                     "xz_almost_all": None if share is None else share >= XZ_SHARE_ALMOST,
                     "components": comp,
                     "all_non_compliant": all(comp.get(c) == "non-compliant"
                                              for c in CHECKED)})
    n = len(rows)
    return {"releases": rows, "n": n,
            "z_not_largest": sum(r["z_not_largest"] for r in rows),
            "xz_almost_all": sum(bool(r["xz_almost_all"]) for r in rows),
            "xz_share_median": (float(np.median([r["xz_share"] for r in rows
                                                 if r["xz_share"] is not None]))
                                if n else None),
            "all_non_compliant": sum(r["all_non_compliant"] for r in rows),
            "xz_share_threshold": XZ_SHARE_ALMOST, "limits": dict(LIMITS),
            "checked": list(CHECKED),
            "components": [c for c in COMPONENTS if np.isfinite(y[:, COMPONENTS.index(c)]).all()]}


def scenario_document(model, tel, opts: InferenceOptions = InferenceOptions(), *,
                      fit_window: float | None = None, min_samples: int = 5) -> dict:
    """The ``scenarios`` part of impact.json for a loaded telemetry: the paper's observations
    on the measured components (:func:`paper_observations`), the scenario posterior of every
    release (:func:`infer_scenarios`) and, for synthetic telemetry with scenario truths only,
    the truths and whether each lies inside its 95 % interval (measured files have none and
    get none)."""
    ids = [r.id for r in tel.releases]
    y, s = measured_components(tel, fit_window=fit_window, min_samples=min_samples)
    inf = infer_scenarios(model, ids, y, s, opts)
    doc = inf.to_json()
    doc["observations"] = paper_observations(ids, y, s)
    tr = tel.truth_scenario
    if tr is not None and tel.truth_impact_time is not None:
        right = alone = 0
        for i, rec in enumerate(doc["releases"]):
            k = tr["scenario"][i]
            vals = {p: tr["scenario_params"][p][i] for p in PARAMS}
            vals["t"] = float(tel.truth_impact_time[i])
            fit = rec["fits"].get(k)
            inside = ({p: (None if fit is None or fit["params"].get(p) is None
                           or fit["params"][p]["ci95"][0] is None
                           else bool(fit["params"][p]["ci95"][0] <= v
                                     <= fit["params"][p]["ci95"][1]))
                       for p, v in vals.items()})
            rec["truth"] = {"scenario": k, "params": vals, "in_ci95": inside,
                            "chosen_right": rec["chosen"] == k,
                            "chosen_alone_right": rec["chosen_alone"] == k}
            right += rec["chosen"] == k
            alone += rec["chosen_alone"] == k
        doc["truth_summary"] = {"releases": len(doc["releases"]), "chosen_right": right,
                                "chosen_alone_right": alone}
    return doc
