"""Fit results: best start, covariance (Eq. 7), standard errors, correlations, reduced
chi-square, uncertainty bands on the fitted signals, profile likelihoods, and the fit files
(JSON of INTERFACES.md with a NetCDF sidecar).
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

import gprm
from gprm._io import write_json_atomic, write_netcdf_atomic
from gprm.errors import GprmInputError
from gprm.fit.covariance import parameters_at_bounds, sample_normal
from gprm.fit.files import FORMAT_VERSION, MODEL_NAME
from gprm.fit.lm import levenberg_marquardt_batch
from gprm.fit.multistart import (LMOptions, MultiStartOptions, StartsOutcome, run_multistart,
                                 starts_to_dataset)
from gprm.fit.objective import FitData, Objective
from gprm.fit.prior import DEFAULT_WIDTH, Prior, default_prior
from gprm.fit.uncertainty import (DEFAULT_METHOD, Uncertainty, estimate, from_mcmc,
                                  time_correlation_factor)
from gprm.params import REGISTRY, ParameterSet


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


@dataclass(frozen=True)
class FitResult:
    names: tuple[str, ...]
    params: ParameterSet               # the best fit (fitted names take their best values)
    chi2: float
    dof: int
    covariance: np.ndarray | None      # (P, P) SI, or None
    covariance_message: str
    at_bounds: tuple[str, ...]
    starts: StartsOutcome
    options: MultiStartOptions
    data: FitData
    piezo: int
    bands: Bands | None = None
    profiles: tuple[Profile, ...] = ()
    timings: dict = field(default_factory=dict)
    z_bk_absolute: bool = False
    polish: dict = field(default_factory=dict)
    #: the chosen method's uncertainty (intervals, identified, draws) and the paper's Eq. 7
    uncertainty: Uncertainty | None = None
    eq7: Uncertainty | None = None
    prior: Prior | None = None

    def combinations(self) -> list[dict]:
        """What the data determine among the not-identified parameters
        (:func:`gprm.fit.uncertainty.identifiable_combinations`)."""
        if self.uncertainty is None or self.prior is None:
            return []
        from gprm.fit.uncertainty import identifiable_combinations

        return identifiable_combinations(self.uncertainty, self.prior, self.x)

    def objective(self) -> Objective:
        """The objective the best fit minimises (its prior weighed by the data's variance
        scale), e.g. to refit bootstrap campaigns or profile a parameter."""
        prior = self.prior
        if prior is not None and self.uncertainty is not None and np.isfinite(self.uncertainty.s2):
            prior = prior.with_weight(np.sqrt(self.uncertainty.s2))
        return Objective.create(self.data, self.params, self.names, piezo=self.piezo,
                                z_bk_absolute=self.z_bk_absolute, prior=prior)

    @property
    def identified(self) -> tuple[str, ...]:
        if self.uncertainty is None:
            return ()
        return tuple(n for n, k in zip(self.names, self.uncertainty.identified) if k)

    @property
    def x(self) -> np.ndarray:
        return self.params.vector(self.names)

    @property
    def reduced_chi2(self) -> float:
        return self.chi2 / self.dof

    @property
    def stderr(self) -> np.ndarray:
        if self.covariance is None:
            return np.full(len(self.names), np.nan)
        return np.sqrt(np.diag(self.covariance))

    @property
    def correlation(self) -> np.ndarray | None:
        if self.covariance is None:
            return None
        s = self.stderr
        return self.covariance / np.outer(s, s)

    # ------------------------------------------------------------------ report
    def summary(self) -> str:
        """A readable fit report (lmfit-like)."""
        from gprm.params import from_si

        lines = [f"[[Fit]] model {MODEL_NAME}, piezo {self.piezo}, sigma={self.data.sigma_kind}",
                 f"    starts: {self.starts.chi2.size}, converged "
                 f"{int(self.starts.converged.sum())}, at best (dchi2<=1) "
                 f"{self.starts.n_at_best()}",
                 f"    chi-square {self.chi2:.6g}, dof {self.dof}, reduced "
                 f"{self.reduced_chi2:.4g}",
                 "[[Parameters]]"]
        u = self.uncertainty
        for k, (name, v, e) in enumerate(zip(self.names, self.x, self.stderr)):
            unit = REGISTRY[name].unit
            ev = from_si(e, name) if np.isfinite(e) else float("nan")
            line = f"    {name:>9} = {from_si(v, name):12.6g} +/- {ev:.3g} {unit}"
            if u is not None and np.isfinite(u.lower95[k]):
                line += (f"   95%: [{from_si(u.lower95[k], name):.4g}, "
                         f"{from_si(u.upper95[k], name):.4g}]")
                line += "" if u.identified[k] else "   (not determined)"
            lines.append(line)
        if self.covariance is None:
            lines.append(f"    (no covariance: {self.covariance_message})")
        if self.at_bounds:
            lines.append(f"    at a bound: {', '.join(self.at_bounds)}")
        return "\n".join(lines)

    def to_json_dict(self) -> dict:
        from gprm.params import from_si

        corr = self.correlation
        u = self.uncertainty
        params = {}
        for name in REGISTRY:
            fitted = name in self.names
            err = None
            entry = {}
            if fitted:
                k = self.names.index(name)
                e = self.stderr[k]
                err = float(e) if np.isfinite(e) else None
                spec = self.params.bounds.get(name, (REGISTRY[name].lower, REGISTRY[name].upper))
                entry["initial"] = float(self.params.initial_vector((name,))[0])
                entry["at_bound"] = (("lower" if np.isclose(self.params[name], spec[0],
                                                            rtol=0, atol=1e-12 * max(1, abs(spec[0])))
                                      else "upper") if name in self.at_bounds else None)
                if u is not None:
                    entry["identified"] = bool(u.identified[k])
                    entry["interval"] = {"level": 0.95, "lower": _num(u.lower95[k]),
                                         "upper": _num(u.upper95[k]), "method": u.method}
                    entry["interval68"] = {"level": 0.68, "lower": _num(u.lower68[k]),
                                           "upper": _num(u.upper68[k])}
                    entry["contraction"] = _num(u.contraction[k])
                if self.eq7 is not None:
                    entry["stderr_eq7"] = _num(self.eq7.stderr[k])
            params[name] = {"value": float(self.params[name]), "stderr": err,
                            "unit": _si_unit(name), "fitted": fitted,
                            "display_unit": REGISTRY[name].unit,
                            "display_value": float(from_si(self.params[name], name)), **entry}
        best = self.starts.best_index
        d = {
            "model": MODEL_NAME, "format_version": FORMAT_VERSION, "piezo": self.piezo,
            "version": gprm.__version__, "seed": self.options.seed,
            "window": [float(self.data.window[0]), float(self.data.window[1])],
            "signals": list(self.data.signals), "sigma": self.data.sigma_kind,
            "z_bk_absolute": self.z_bk_absolute,
            "parameters": params,
            "chi2": float(self.chi2), "dof": int(self.dof),
            "reduced_chi2": float(self.reduced_chi2),
            "covariance_message": self.covariance_message,
            "uncertainty": self._uncertainty_json(),
            "identified": list(self.identified),
            "not_determined": [n for n in self.names if n not in self.identified],
            "identifiable_combinations": self.combinations(),
            "parameters_at_bounds": list(self.at_bounds),
            "correlation": {"names": list(self.names),
                            "matrix": None if corr is None else corr.tolist()},
            "starts": {"requested": int(self.options.n_starts),
                       "converged": int(self.starts.converged.sum()),
                       "failed": int(np.sum(np.char.startswith(self.starts.status.astype(str),
                                                               "failed"))),
                       "pruned": int(np.sum(self.starts.status.astype(str) == "pruned")),
                       "best_index": int(best), "n_at_best": self.starts.n_at_best(),
                       "prune_after": self.options.prune_after,
                       "prune_factor": self.options.prune_factor,
                       "prune_rate_window": self.options.prune_rate_window,
                       "stall_window": self.options.lm.stall_window,
                       "stall_tol": self.options.lm.stall_tol,
                       "max_iter": self.options.lm.max_iter,
                       "chunk_size": self.options.chunk_size,
                       "spread": self.options.spread, "sampling": self.options.sampling},
            "profiles": [{"name": p.name, "grid": p.grid.tolist(),
                          "chi2": [_num(c) for c in p.chi2],
                          "lower": _num(p.lower), "upper": _num(p.upper),
                          "lower95": _num(p.lower95), "upper95": _num(p.upper95),
                          "statistic": "(Phi - Phi_min) / s2",
                          "identifiable": p.identifiable} for p in self.profiles],
            "data": {"source": self.data.source, "n_obs": self.data.n_obs,
                     "sha256": _data_hash(self.data)},
            "polish": self.polish,
            "band_samples": 0 if self.bands is None else int(self.bands.n_samples),
            "timings_s": self.timings,
        }
        if "truth_json" in self.data.attrs:
            d["data"]["truth_available"] = True
        return d

    def _uncertainty_json(self) -> dict:
        u = self.uncertainty
        if u is None:
            return {"method": "eq7", "note": self.covariance_message}
        from gprm.fit.uncertainty import CONTRACTION

        d = {"method": u.method, "note": u.message if u.message != "ok" else
             ("posterior of the prior-regularised fit (Laplace); identified = posterior sd "
              f"below {CONTRACTION} of the prior's" if u.method == "laplace-prior" else
              "linearised covariance"),
             "s2": _num(u.s2), "tau": _num(u.tau), "identified_threshold": CONTRACTION,
             "draws": 0 if u.draws is None else int(len(u.draws))}
        if self.prior is not None:
            d["prior"] = {"width": float(self.prior.sd[self.prior.log][0])
                          if self.prior.log.any() else None,
                          "centre": "initial values (Table 3)", "docs": "docs/fitting.md"}
        if self.eq7 is not None:
            d["eq7_message"] = self.eq7.message
        return d

    def sidecar_dataset(self) -> xr.Dataset:
        ds = starts_to_dataset(self.starts)
        ds = ds.assign_coords(signal=list(self.data.signals), time=self.data.time)
        ds["data_mean"] = (("signal", "time"), self.data.values)
        ds["data_sigma"] = (("signal", "time"), self.data.sigma)
        if self.bands is not None:
            b = self.bands
            ds["model_best"] = (("signal", "time"), b.best)
            ds["band_linear_std"] = (("signal", "time"), b.linear_std)
            ds["band_sample_std"] = (("signal", "time"), b.sample_std)
            ds["band_sample_lo"] = (("signal", "time"), b.sample_lo)
            ds["band_sample_hi"] = (("signal", "time"), b.sample_hi)
            ds.attrs["band_samples"] = b.n_samples
        if self.covariance is not None:
            ds["covariance"] = (("param", "param2"), self.covariance)
            ds = ds.assign_coords(param2=list(self.names))
            ds["covariance"].attrs.update(
                long_name="parameter covariance of the uncertainty method (SI)",
                comment="units vary: param_units[param] * param_units[param2]")
        if self.uncertainty is not None and self.uncertainty.draws is not None:
            ds["posterior_draws"] = (("draw", "param"), self.uncertainty.draws, {
                "long_name": f"parameter sets from the uncertainty method "
                f"({self.uncertainty.method}), SI; later stages propagate these",
                "comment": "units vary along param: param_units[param]"})
        for v in ("data_mean", "data_sigma", "model_best", "band_linear_std",
                  "band_sample_std", "band_sample_lo", "band_sample_hi"):
            if v in ds:
                ds[v].attrs["units"] = "m"
        ds["time"].attrs["units"] = "s"
        ds.attrs.update({"model": MODEL_NAME, "gprm_version": gprm.__version__,
                         "seed": self.options.seed})
        return ds

    def write(self, out: str | Path) -> Path:
        """Write the JSON and its sidecar (same name, ``.nc``)."""
        out = Path(out)
        side = out.with_suffix(".nc")
        write_netcdf_atomic(self.sidecar_dataset(), side)
        write_json_atomic(out, self.to_json_dict())
        return side


def _num(x):
    return float(x) if np.isfinite(x) else None


def _si_unit(name: str) -> str:
    from gprm.params.files import ureg

    q = ureg().Quantity(1.0, REGISTRY[name].unit).to_base_units()
    u = f"{q.units:~}".replace(" ", "")
    return {"rad": "rad", "": "1"}.get(u, u)


def _data_hash(data: FitData) -> str:
    h = hashlib.sha256()
    for a in (data.time, data.values, data.sigma):
        h.update(np.ascontiguousarray(a, float).tobytes())
    return h.hexdigest()[:16]


# ----------------------------------------------------------------------------- uncertainty

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


class _FixedOne:
    """The objective with parameter k held fixed: its Jacobian column is zero, so the damped
    step never moves it (see :func:`gprm.fit.lm.scaled_svd`). Each row keeps its own fixed
    value, whatever subset of rows the lock-step optimizer evaluates."""

    def __init__(self, obj: Objective, k: int):
        self.obj, self.k = obj, k

    def __call__(self, X):
        r, J = self.obj(X)             # J is a new array each call: zeroed in place
        J[:, :, self.k] = 0.0
        return r, J

    def residuals(self, X):
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
    f = _FixedOne(obj, k)
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
    never-moving coordinate (its Jacobian column is zero, as in :class:`_FixedOne`), so each
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


# ----------------------------------------------------------------------------- the whole fit

def identify(data: FitData, base: ParameterSet, opts: MultiStartOptions = MultiStartOptions(),
             *, piezo: int = 2, names=None, workers: int = 0, scheduler: str | None = None,
             checkpoint_dir=None, progress=None, profile: bool = False, band_samples: int = 200,
             z_bk_absolute: bool = False, stop_after: int | None = None,
             uncertainty: str = DEFAULT_METHOD, prior_width: float | None = DEFAULT_WIDTH,
             n_draws: int = 400, n_boot: int = 40) -> FitResult:
    """Multi-start identification of ``names`` (default: the set's fitted parameters).

    With ``prior_width`` (default) every start minimises chi-square plus the weak prior of
    :mod:`gprm.fit.prior`; the best start is then polished with the prior weighed against
    the data's variance scale s2 (negative log posterior chi2 / s2 + prior), and the
    uncertainty comes from ``uncertainty`` (:mod:`gprm.fit.uncertainty`). ``prior_width=None``
    is the paper's unregularised fit (its uncertainty then is Eq. 7 or eq7-corr).
    """
    t_start = time.perf_counter()
    fit_names = tuple(base.fitted if names is None else names)
    prior = None if prior_width is None else default_prior(base, fit_names, prior_width)
    if prior is None and uncertainty in ("laplace-prior", "parametric-bootstrap", "mcmc"):
        raise GprmInputError("the laplace-prior uncertainty needs a prior (a prior width)",
                             field="--uncertainty")
    obj = Objective.create(data, base, fit_names, piezo=piezo, z_bk_absolute=z_bk_absolute,
                           prior=prior)
    starts = run_multistart(obj, opts, workers=workers, scheduler=scheduler,
                            checkpoint_dir=checkpoint_dir, progress=progress,
                            stop_after=stop_after)
    t_ms = time.perf_counter() - t_start
    best = starts.best_index
    x, polish = polish_best(obj, starts.x[best], opts.lm)
    r, J = _data_jacobian(obj, x)
    if prior is not None:
        # weigh the prior against the data's variance scale, then polish again
        s2 = time_correlation_factor(r, len(data.signals)) * float(r @ r) / obj.dof
        obj = obj.with_prior(prior.with_weight(np.sqrt(max(s2, 1e-300))))
        x, polish2 = polish_best(obj, x, opts.lm)
        polish = {**polish, "posterior": polish2, "s2": s2}
        r, J = _data_jacobian(obj, x)
    chi2 = float(r @ r)
    eq7 = estimate("eq7", x, J, r, obj.dof, len(data.signals), prior, obj.names)
    base_method = ("laplace-prior" if uncertainty in ("parametric-bootstrap", "mcmc")
                   else uncertainty)
    unc = eq7 if uncertainty == "eq7" else estimate(
        base_method, x, J, r, obj.dof, len(data.signals), prior, obj.names,
        n_draws=n_draws, seed=opts.seed)
    t_b = time.perf_counter()
    if uncertainty == "parametric-bootstrap":
        from gprm.fit.bootstrap import bootstrap_uncertainty

        unc = bootstrap_uncertainty(obj, x, unc, prior, uncertainty, n_boot=n_boot,
                                    seed=opts.seed, lm=opts.lm, n_draws=n_draws)
    elif uncertainty == "mcmc":
        unc = from_mcmc(obj, x, unc, prior, seed=opts.seed, n_draws=n_draws)
    cov, msg = unc.covariance, unc.message
    lo, hi = obj.bounds_normalised()
    at_b = tuple(np.asarray(obj.names)[parameters_at_bounds(obj.to_normalised(x), lo, hi)]
                 .tolist())
    if at_b and cov is not None:
        msg = f"ok (parameters at a bound: {', '.join(at_b)}; their errors are not reliable)"
    params = base.with_values(**dict(zip(obj.names, map(float, x))))
    bands = compute_bands(obj, x, cov, n_samples=band_samples, seed=opts.seed,
                          draws=unc.draws)
    profiles = ()
    if profile:
        s2p = unc.s2 if np.isfinite(unc.s2) else 1.0
        sdu = (unc.contraction * prior.sd if prior is not None and unc.method == "laplace-prior"
               else unc.stderr)
        profiles = tuple(profile_likelihood(obj, x, n, s2=s2p, sd_u=sdu[i], lm=opts.lm)
                         for i, n in enumerate(obj.names))
    timings = {"multistart": round(t_ms, 3), "uncertainty": round(time.perf_counter() - t_b, 3),
               "total": round(time.perf_counter() - t_start, 3)}
    return FitResult(obj.names, params, chi2, obj.dof, cov, msg, at_b, starts, opts, data,
                     piezo, bands, profiles, timings, z_bk_absolute, polish, unc, eq7, prior)


def _data_jacobian(obj: Objective, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted data residuals r (N,) and their Jacobian d r / d x (N, P), physical x; the
    prior's rows left out."""
    r, Jn = obj(obj.to_normalised(x)[None])
    n = obj.data.n_obs
    return r[0, :n], Jn[0, :n] / obj.scale


def polish_best(obj: Objective, x: np.ndarray, lm: LMOptions, *, max_iter: int = 200,
                ftol: float = 1e-12) -> tuple[np.ndarray, dict]:
    """Continue Algorithm 1 from the best start with a tight tolerance (relative chi-square
    change 1e-12, no absolute part), so that the reported best fit does not depend on the
    looser stopping rule used for the many starts. Chi-square can only decrease."""
    lo, hi = obj.bounds_normalised()
    kw = lm.as_kwargs()
    kw.update(max_iter=max_iter, ftol=ftol, ftol_abs=0.0, stall_window=0)
    res = levenberg_marquardt_batch(obj, obj.to_normalised(x)[None], lower=lo, upper=hi,
                                    residuals=obj.residuals, **kw)
    info = {"chi2_before": float(res.chi2_0[0]), "chi2_after": float(res.chi2[0]),
            "iterations": int(res.iterations[0]), "status": str(res.status[0])}
    if not np.isfinite(res.chi2[0]) or res.chi2[0] > res.chi2_0[0]:
        return x, info
    return obj.to_physical(res.x[0]), info
