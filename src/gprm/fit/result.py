"""Fit results: best start, covariance (Eq. 7), standard errors, correlations, reduced
chi-square, uncertainty bands on the fitted signals, profile likelihoods, and the fit files
(JSON of INTERFACES.md with a NetCDF sidecar).
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

import gprm
from gprm._io import write_json_atomic, write_netcdf_atomic
from gprm.errors import GprmInputError
from gprm.fit.covariance import (CovarianceError, covariance, parameters_at_bounds,
                                 sample_normal)
from gprm.fit.files import FORMAT_VERSION, MODEL_NAME
from gprm.fit.lm import levenberg_marquardt_batch
from gprm.fit.multistart import (LMOptions, MultiStartOptions, StartsOutcome, run_multistart,
                                 starts_to_dataset)
from gprm.fit.objective import FitData, Objective
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
    """Profile likelihood of one parameter: grid (physical), chi-square minimised over the
    others, and the 68 % interval where Delta chi2 <= 1 (NaN where not reached)."""

    name: str
    grid: np.ndarray
    chi2: np.ndarray
    lower: float
    upper: float

    @property
    def identifiable(self) -> bool:
        return bool(np.isfinite(self.lower) and np.isfinite(self.upper))


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
        for name, v, e in zip(self.names, self.x, self.stderr):
            unit = REGISTRY[name].unit
            ev = from_si(e, name) if np.isfinite(e) else float("nan")
            lines.append(f"    {name:>6} = {from_si(v, name):12.6g} +/- {ev:.3g} {unit}")
        if self.covariance is None:
            lines.append(f"    (no covariance: {self.covariance_message})")
        if self.at_bounds:
            lines.append(f"    at a bound: {', '.join(self.at_bounds)}")
        return "\n".join(lines)

    def to_json_dict(self) -> dict:
        from gprm.params import from_si

        corr = self.correlation
        params = {}
        for name in REGISTRY:
            fitted = name in self.names
            err = None
            if fitted:
                e = self.stderr[self.names.index(name)]
                err = float(e) if np.isfinite(e) else None
            params[name] = {"value": float(self.params[name]), "stderr": err,
                            "unit": _si_unit(name), "fitted": fitted,
                            "display_unit": REGISTRY[name].unit,
                            "display_value": float(from_si(self.params[name], name))}
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
                long_name="parameter covariance (Eq. 7, SI)",
                comment="units vary: param_units[param] * param_units[param2]")
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
                  seed: int = 0) -> Bands:
    """Bands on the fitted signals: linear propagation and sampling of the covariance."""
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


def profile_likelihood(obj: Objective, x_best: np.ndarray, stderr: np.ndarray, name: str, *,
                       n_points: int = 13, width: float = 3.0,
                       lm: LMOptions = LMOptions()) -> Profile:
    """Profile likelihood of ``name``: chi-square minimised over the other parameters with
    ``name`` fixed on a grid of ``n_points`` over best +/- width*stderr (+/-10 % where no
    stderr). All grid points run in lock-step, each started from the best fit. The interval
    is where Delta chi2 <= 1 relative to the best fit (68 % for one parameter)."""
    k = obj.names.index(name)
    s = stderr[k] if np.isfinite(stderr[k]) and stderr[k] > 0 else 0.1 * abs(x_best[k])
    grid = x_best[k] + np.linspace(-width, width, n_points) * s
    xn = obj.to_normalised(x_best)
    X0 = np.repeat(xn[None], n_points, axis=0)
    X0[:, k] = grid / obj.scale[k]
    lo, hi = obj.bounds_normalised()
    inside = (X0[:, k] > lo[k]) & (X0[:, k] < hi[k])
    chi = np.full(n_points, np.nan)
    if inside.any():
        f = _FixedOne(obj, k)
        kw = lm.as_kwargs()
        kw.update(ftol_abs=min(kw["ftol_abs"], 1e-4), stall_window=0)
        res = levenberg_marquardt_batch(f, X0[inside], residuals=f.residuals, lower=lo,
                                        upper=hi, **kw)
        chi[inside] = np.where(np.isfinite(res.chi2), res.chi2, np.nan)
    c0 = float(np.sum(obj.residuals(xn[None]) ** 2))
    dchi = chi - min(c0, np.nanmin(np.append(chi, np.inf)))
    lower, upper = _crossings(grid, np.where(np.isfinite(dchi), dchi, np.inf), x_best[k])
    return Profile(name, grid, chi, lower, upper)


def _crossings(grid, dchi, centre):
    lower = upper = np.nan
    left = np.nonzero((grid < centre) & (dchi >= 1))[0]
    if left.size:
        i = left[-1]
        j = i + 1
        lower = np.interp(1.0, [dchi[j], dchi[i]], [grid[j], grid[i]])
    right = np.nonzero((grid > centre) & (dchi >= 1))[0]
    if right.size:
        j = right[0]
        i = j - 1
        upper = np.interp(1.0, [dchi[i], dchi[j]], [grid[i], grid[j]])
    return lower, upper


# ----------------------------------------------------------------------------- the whole fit

def identify(data: FitData, base: ParameterSet, opts: MultiStartOptions = MultiStartOptions(),
             *, piezo: int = 2, names=None, workers: int = 0, scheduler: str | None = None,
             checkpoint_dir=None, progress=None, profile: bool = False, band_samples: int = 200,
             z_bk_absolute: bool = False, stop_after: int | None = None) -> FitResult:
    """Multi-start identification of ``names`` (default: the set's fitted parameters)."""
    t_start = time.perf_counter()
    obj = Objective.create(data, base, names, piezo=piezo, z_bk_absolute=z_bk_absolute)
    starts = run_multistart(obj, opts, workers=workers, scheduler=scheduler,
                            checkpoint_dir=checkpoint_dir, progress=progress,
                            stop_after=stop_after)
    t_ms = time.perf_counter() - t_start
    best = starts.best_index
    x, polish = polish_best(obj, starts.x[best], opts.lm)
    xn = obj.to_normalised(x)
    r, Jn = obj(xn[None])
    chi2 = float(np.sum(r[0] ** 2))
    J = Jn[0] / obj.scale                                          # d r / d x (physical)
    cov, msg = None, "ok"
    try:
        cov = covariance(J, r[0], dof=obj.dof, names=obj.names)
    except CovarianceError as exc:
        msg = str(exc)
    lo, hi = obj.bounds_normalised()
    at_b = tuple(np.asarray(obj.names)[parameters_at_bounds(xn, lo, hi)].tolist())
    if at_b and cov is not None:
        msg = f"ok (parameters at a bound: {', '.join(at_b)}; their errors are not reliable)"
    params = base.with_values(**dict(zip(obj.names, map(float, x))))
    t_b = time.perf_counter()
    bands = compute_bands(obj, x, cov, n_samples=band_samples, seed=opts.seed)
    profiles = ()
    if profile:
        se = np.full(len(obj.names), np.nan) if cov is None else np.sqrt(np.diag(cov))
        profiles = tuple(profile_likelihood(obj, x, se, n, lm=opts.lm) for n in obj.names)
    timings = {"multistart": round(t_ms, 3), "uncertainty": round(time.perf_counter() - t_b, 3),
               "total": round(time.perf_counter() - t_start, 3)}
    return FitResult(obj.names, params, chi2, obj.dof, cov, msg, at_b, starts, opts, data,
                     piezo, bands, profiles, timings, z_bk_absolute, polish)


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
