"""The identification objective: chi-square of Eq. 6 over the five measured signals in a time
window, weighted by sigma(t), all signals fitted at once with shared parameters.

The fitter works on *normalised* parameters x_k / s_k, with s_k the magnitude of the paper's
initial value (so every unknown is O(1) although the physical values span 1e-6 .. 1e8). The
residual vector of one parameter set is ``(data - model) / sigma`` over signals x times, in
the order ``SIGNALS`` (the paper's q* of Eq. 5, appended signal after signal).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any
from functools import cached_property

import numpy as np
import xarray as xr

from gprm.errors import GprmInputError
from gprm.fit.prior import Prior
from gprm.validate import check_int
from gprm.params import REGISTRY, ParameterSet, batch_from_vectors
from gprm.simulate import OUTPUTS, observe

SIGNALS: tuple[str, ...] = OUTPUTS
DEFAULT_WINDOW = (0.97e-3, 1.2e-3)
#: samples on each side over which each signal's sigma(t)^2 is averaged before it weighs the
#: residuals (:func:`pooled_sigma`): 7 samples, so a campaign of R runs weighs each sample
#: with a variance of about 7 (R - 1) degrees of freedom instead of R - 1
SIGMA_POOL = 3


def pooled_sigma(sigma: np.ndarray, half_width: int) -> np.ndarray:
    """sigma(t) (..., T) with its square averaged over the ``half_width`` samples on each side
    of every sample (fewer at the ends); 0 returns ``sigma`` unchanged.

    Why: the standard error of a mean of R runs, taken sample by sample, is an estimate with
    R - 1 degrees of freedom. Weighting the residuals by its inverse makes each weighted
    error Student-t distributed with R - 1 dof, whose variance is (R - 1) / (R - 3) (9 / 7
    for ten runs), and the runs' own spread, weighted by the same estimate, cannot show it
    (its weighted spread is 1 by construction): the estimator is noisier than the runs'
    covariance says (the estimated-weights effect of weighted least squares, Bement and
    Williams 1969). Pooling the variance over neighbouring samples gives each weight about
    (2 half_width + 1) (R - 1) dof; the shape of sigma(t) over a few samples is kept.
    docs/fitting.md, "Weights pooled over neighbouring samples".
    """
    k = int(half_width)
    if k < 0:
        raise ValueError(f"half_width must be >= 0, got {half_width!r}")
    sigma = np.asarray(sigma, float)
    if k == 0:
        return sigma
    T = sigma.shape[-1]
    c = np.cumsum(np.concatenate([np.zeros(sigma.shape[:-1] + (1,)), sigma ** 2], axis=-1),
                  axis=-1)
    lo = np.clip(np.arange(T) - k, 0, T)
    hi = np.clip(np.arange(T) + k + 1, 0, T)
    return np.sqrt((c[..., hi] - c[..., lo]) / (hi - lo))


#: FitData's fields indexed by signal first (FitData.subset selects along them)
PER_SIGNAL_FIELDS = ("values", "sigma", "runs", "noise_std", "interpolation_error",
                     "crossing_time", "sync_remainder", "sync_timing_sd", "baseline",
                     "noise_acov")


@dataclass(frozen=True)
class FitData:
    """The data a fit sees: times (T,), values and sigma (n_signals, T), per signal."""

    time: np.ndarray
    values: np.ndarray
    sigma: np.ndarray
    signals: tuple[str, ...] = SIGNALS
    window: tuple[float, float] = DEFAULT_WINDOW
    sigma_kind: str = "sem"
    source: str = ""
    attrs: dict = field(default_factory=dict)
    #: (n_signals, R, T) m: the synchronised, aligned runs behind ``values`` (None where the
    #: mean-signals file does not carry them); the run-to-run covariance of the mean
    runs: np.ndarray | None = None
    #: (n_signals,) m: the noise std of each signal's noise runs (NaN where unknown)
    noise_std: np.ndarray | None = None
    #: (n_signals, T) m: the preprocessing's estimated interpolation error (None: unknown)
    interpolation_error: np.ndarray | None = None
    #: (n_signals,) s: where preprocessing put each mean's threshold crossing (within half a
    #: sample of the file's align_time; None: at align_time, as older files have it)
    crossing_time: np.ndarray | None = None
    #: (n_signals, R) s: what of each run's synchronisation shift the whole-sample move left
    #: (run r's samples match the reference run's at t - sync_remainder); the fit moves the
    #: runs the rest of the way through the model (gprm.fit.subsample). None: not known
    #: (older files, or runs interpolated to a common time), or already applied
    sync_remainder: np.ndarray | None = None
    #: samples on each side over which ``sigma`` was pooled (:func:`pooled_sigma`; 0: as
    #: given); a recomputed sigma (gprm.fit.subsample) is pooled the same way
    sigma_pool: int = 0
    #: (n_signals,) s: the sd of the time shift the synchronisation took out of the runs'
    #: spread but left in their mean (gprm.campaign.preprocess.sync_timing_sd; None: not
    #: known, older files), a timing error of each signal in the default uncertainty
    sync_timing_sd: np.ndarray | None = None
    #: (n_signals, 2) s: the first and last baseline sample of step 0's straight line on
    #: ``time``'s axis (gprm.campaign.preprocess.MeanSignals.baseline; None: not known, older
    #: files): the line's noise in the runs, counted by the drive term's noise correction
    baseline: np.ndarray | None = None
    #: (n_signals, L) m^2: the noise runs' autocovariance at lags 0..L-1 samples
    #: (gprm.campaign.preprocess.noise_autocovariance; None: not known, older files, and the
    #: noise is then taken as white of sd ``noise_std``)
    noise_acov: np.ndarray | None = None

    @property
    def n_obs(self) -> int:
        return int(self.values.size)

    def subset(self, keep) -> "FitData":
        """The same data for the signals ``keep`` (indices), with every per-signal field
        (:data:`PER_SIGNAL_FIELDS`) selected alike."""
        keep = list(keep)
        picked: dict[str, Any] = {f: None if getattr(self, f) is None else getattr(self, f)[keep]
                                  for f in PER_SIGNAL_FIELDS}
        return replace(self, signals=tuple(self.signals[i] for i in keep), **picked)


def fit_data_from_means(ds: xr.Dataset, *, window=DEFAULT_WINDOW, sigma: str = "sem",
                        source: str = "mean signals", sigma_pool: int = SIGMA_POOL
                        ) -> FitData:
    """Select the five fitted signals in ``window`` from a mean-signals dataset (the output
    of ``gprm preprocess``: dims ``signal``, ``time``; vars ``mean`` and ``std``/``sem``).

    sigma: ``sem`` (standard error of the mean signal; chi-square then follows its
    distribution, reduced chi-square ~ 1 for a correct model) or ``std`` (the paper's weighting
    by the standard deviation across runs). Eq. 7's covariance is the same for both, since it
    rescales by the residual variance. sigma_pool: the chosen sigma's square averaged over
    this many samples on each side within the window (:func:`pooled_sigma`; 0: sample by
    sample, as stops 1-41 weighed).
    """
    check_int("sigma_pool", sigma_pool, 0)
    for var in ("mean", sigma):
        if var not in ds.variables:
            raise GprmInputError(f"mean-signals file has no variable '{var}' (sigma '{sigma}' "
                                 "needs it)", source=source, field=var)
    if "signal" not in ds.dims or "time" not in ds.dims:
        raise GprmInputError("expected dimensions (signal, time)", source=source, field="mean")
    names = [str(s) for s in ds["signal"].values]
    missing = [s for s in SIGNALS if s not in names]
    if missing:
        raise GprmInputError(f"missing signal(s) {missing}", source=source, field="signal")
    lo, hi = float(window[0]), float(window[1])
    if not (lo < hi):
        raise GprmInputError(f"window start {lo} is not before its end {hi}", field="window")
    t = np.asarray(ds["time"].values, float)
    if lo < t.min() - 1e-12 or hi > t.max() + 1e-12:
        raise GprmInputError(f"window [{lo:g}, {hi:g}] s is outside the data "
                             f"[{t.min():g}, {t.max():g}] s", source=source, field="window")
    sel = (t >= lo - 1e-12) & (t <= hi + 1e-12)
    vals = np.stack([np.asarray(ds["mean"].sel(signal=s).values, float)[sel] for s in SIGNALS])
    sig = np.stack([np.asarray(ds[sigma].sel(signal=s).values, float)[sel] for s in SIGNALS])
    if not np.all(np.isfinite(vals)):
        raise GprmInputError("mean signal holds NaN or Inf in the window", source=source,
                             field="mean")
    if not np.all(np.isfinite(sig)) or np.any(sig <= 0):
        bad = SIGNALS[int(np.argmax(np.any(~(sig > 0), axis=1)))]
        raise GprmInputError(f"sigma must be finite and > 0 (signal {bad})", source=source,
                             field=sigma)
    runs = None
    if "runs" in ds.variables:
        runs = np.stack([np.asarray(ds["runs"].sel(signal=s).transpose("run", "time").values,
                                    float)[:, sel] for s in SIGNALS])
        if runs.shape[1] < 2 or not np.all(np.isfinite(runs)):
            raise GprmInputError("runs must be finite, at least two per signal",
                                 source=source, field="runs")
    nstd = None
    if "noise_std" in ds.variables:
        nstd = np.array([float(ds["noise_std"].sel(signal=s)) for s in SIGNALS])
    ierr = None
    if "interpolation_error" in ds.variables:
        ierr = np.stack([np.asarray(ds["interpolation_error"].sel(signal=s).values,
                                    float)[sel] for s in SIGNALS])
    cross = None
    if "crossing_time" in ds.variables:
        cross = np.array([float(ds["crossing_time"].sel(signal=s)) for s in SIGNALS])
    rem = None
    if runs is not None and "sync_remainder" in ds.variables:
        rem = np.stack([np.asarray(ds["sync_remainder"].sel(signal=s).values, float)
                        for s in SIGNALS])
        dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
        if rem.shape != runs.shape[:2] or not np.all(np.isfinite(rem)) \
                or np.any(np.abs(rem) > dt):
            raise GprmInputError("sync_remainder must be finite, one value per run and "
                                 "signal, each within one sample", source=source,
                                 field="sync_remainder")
    sync_sd = None
    if "sync_timing_sd" in ds.variables:
        sync_sd = np.array([float(ds["sync_timing_sd"].sel(signal=s)) for s in SIGNALS])
        if not np.all(np.isfinite(sync_sd)) or np.any(sync_sd < 0):
            raise GprmInputError("sync_timing_sd must be finite and >= 0, one value per "
                                 "signal", source=source, field="sync_timing_sd")
    base = None
    if "baseline_start" in ds.variables and "baseline_stop" in ds.variables:
        base = np.array([[float(ds[f"baseline_{e}"].sel(signal=s)) for e in ("start", "stop")]
                         for s in SIGNALS])
        dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
        if not np.all(np.isfinite(base)) or np.any(base[:, 1] - base[:, 0] < dt * 0.999):
            raise GprmInputError("baseline_start and baseline_stop must be finite, the stop "
                                 "at least one sample after the start, one value each per "
                                 "signal", source=source, field="baseline_start")
    acov = None
    if "noise_acov" in ds.variables:
        acov = np.stack([np.asarray(ds["noise_acov"].sel(signal=s).values, float)
                         for s in SIGNALS])
        if acov.ndim != 2 or not np.all(np.isfinite(acov)) or np.any(acov[:, 0] <= 0) \
                or np.any(np.abs(acov) > acov[:, :1] * (1 + 1e-9)):
            raise GprmInputError("noise_acov must be finite, one row of lags per signal, "
                                 "its lag 0 positive and no lag larger in size",
                                 source=source, field="noise_acov")
    return FitData(t[sel], vals, pooled_sigma(sig, sigma_pool), SIGNALS, (lo, hi), sigma,
                   source, dict(ds.attrs), runs, nstd, ierr, cross, rem, sigma_pool, sync_sd,
                   base, acov)


@dataclass(frozen=True)
class Objective:
    """Weighted residuals and their exact Jacobian for batches of normalised parameters."""

    data: FitData
    base: ParameterSet
    names: tuple[str, ...]
    scale: np.ndarray
    piezo: int = 2
    z_bk_absolute: bool = False
    #: the weak prior's rows appended to the residuals (gprm.fit.prior), or None
    prior: Prior | None = None
    #: (N, k) orthonormal columns in the weighted data space that the data residuals and
    #: their Jacobian are projected off: nuisances eliminated by variable projection (an
    #: unmodelled resonance, gprm.fit.resonance), or None
    projection: np.ndarray | None = field(default=None, compare=False, repr=False)
    # the parameter rows and prepared simulation of the last ``residuals`` call (see __call__)
    _last: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __getstate__(self):
        """Pickled (e.g. for a Dask task) without the cached rows of the last call."""
        return {**self.__dict__, "_last": {}}

    @classmethod
    def create(cls, data: FitData, base: ParameterSet, names=None, *, piezo: int = 2,
               z_bk_absolute: bool = False, prior: Prior | None = None,
               projection: np.ndarray | None = None) -> "Objective":
        names = tuple(base.fitted if names is None else names)
        if not names:
            raise GprmInputError("no parameters to fit", field="fit")
        p = len(names)
        if data.n_obs <= p:
            raise GprmInputError(f"too few observations ({data.n_obs}) for {p} parameters",
                                 source=data.source, field="window")
        init = base.initial_vector(names)
        cur = base.vector(names)
        scale = np.where(np.abs(init) > 0, np.abs(init), np.abs(cur))
        scale = np.where(scale > 0, scale, 1.0)
        if prior is not None and tuple(prior.names) != names:
            raise ValueError("prior names differ from the fitted names")
        obj = cls(data, base, names, scale, piezo, z_bk_absolute, prior)
        return obj if projection is None else obj.with_projection(projection)

    def with_prior(self, prior: Prior | None) -> "Objective":
        """The same objective with another prior (or none)."""
        return Objective(self.data, self.base, self.names, self.scale, self.piezo,
                         self.z_bk_absolute, prior, self.projection)

    def with_projection(self, projection: np.ndarray | None) -> "Objective":
        """The same objective with its data residuals projected off the orthonormal columns
        ``projection`` (N, k) (None: not projected)."""
        Q = None if projection is None else np.asarray(projection, float)
        if Q is not None and (Q.ndim != 2 or Q.shape[0] != self.data.n_obs):
            raise ValueError(f"a projection needs {self.data.n_obs} rows, got {Q.shape}")
        return Objective(self.data, self.base, self.names, self.scale, self.piezo,
                         self.z_bk_absolute, self.prior, Q)

    @property
    def n_nuisance(self) -> int:
        """The nuisances the projection eliminates (its columns)."""
        return 0 if self.projection is None else int(self.projection.shape[1])

    def _project(self, r: np.ndarray, J: np.ndarray | None = None):
        """Data rows of r (B, N') [and J (B, N', P)] projected off ``projection``."""
        Q = self.projection
        if Q is None:
            return r if J is None else (r, J)
        n = self.data.n_obs
        r = r.copy()
        r[:, :n] -= (r[:, :n] @ Q) @ Q.T
        if J is None:
            return r
        J = J.copy()
        J[:, :n] -= np.matmul(Q[None], np.matmul(Q.T[None], J[:, :n]))
        return r, J

    @property
    def n_params(self) -> int:
        return len(self.names)

    @property
    def dof(self) -> int:
        return self.data.n_obs - self.n_params - self.n_nuisance

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Physical bounds (P,) of the fitted parameters (the set's, else the registry's)."""
        b = [self.base.bounds.get(n, (REGISTRY[n].lower, REGISTRY[n].upper))
             for n in self.names]
        return np.array([v[0] for v in b], float), np.array([v[1] for v in b], float)

    def bounds_normalised(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds in the normalised coordinates the optimiser sees (scale > 0)."""
        lo, hi = self.bounds()
        return lo / self.scale, hi / self.scale

    def to_physical(self, Xn: np.ndarray) -> np.ndarray:
        return np.asarray(Xn) * self.scale

    def to_normalised(self, X: np.ndarray) -> np.ndarray:
        return np.asarray(X) / self.scale

    def model(self, X: np.ndarray, *, jacobian: bool = False, times=None, prepared=None,
              keep: bool = False):
        """Model signals for physical parameter rows X (B, P): y (B, S, T) [, dy (B,S,T,P)].
        ``keep``: keep the modal convolutions in the result's ``prepared`` (for a Jacobian
        at these rows next, :func:`gprm.simulate.core.observe`)."""
        X = np.atleast_2d(X)
        pb = batch_from_vectors(self.base, self.names, X)
        t = self.data.time if times is None else np.asarray(times, float)
        obs = observe(pb, t, self.data.signals, piezo=self.piezo,
                      sensitivities=self.names if jacobian else (),
                      z_bk_absolute=self.z_bk_absolute, prepared=prepared,
                      keep_convolutions=keep)
        return obs

    def _prepared_for(self, Xn: np.ndarray):
        """The last residual call's prepared simulation of exactly these rows, if it has all
        of them (Levenberg-Marquardt asks for the Jacobian at trial points it has just
        evaluated and accepted), else None."""
        entry = self._last.get("entry")          # (index, prepared) of one call, read once
        if entry is None:
            return None
        index, prepared = entry
        rows = [index.get(x.tobytes()) for x in Xn]
        if any(r is None for r in rows):
            return None
        return prepared.take(np.array(rows, int))

    def __call__(self, Xn: np.ndarray):
        """Residuals r (B, N) and Jacobian dr/dXn (B, N, P) for normalised rows Xn (B, P).

        Sets that cannot be simulated give NaN residuals (the optimiser treats them as a
        worse step, or as a failed start). Rows that the last :meth:`residuals` call
        evaluated reuse its eigen-decompositions and modal convolutions (bit-identical
        results; one decomposition and one set of exponentials per accepted point instead of
        two).
        """
        Xn = np.atleast_2d(np.asarray(Xn, float))
        obs = self.model(self.to_physical(Xn), jacobian=True, prepared=self._prepared_for(Xn))
        w = self._weights                                              # (S, T)
        r = ((self.data.values[None] - obs.y) * w[None]).reshape(Xn.shape[0], -1)
        J = (-obs.dy * w[None, :, :, None] * self.scale).reshape(Xn.shape[0], -1, Xn.shape[1])
        r, J = self._project(r, J)
        if self.prior is None:
            return r, J
        X = self.to_physical(Xn)
        Jp = np.zeros((Xn.shape[0], Xn.shape[1], Xn.shape[1]))
        idx = np.arange(Xn.shape[1])
        Jp[:, idx, idx] = self.prior.jacobian(X) * self.scale
        return (np.concatenate([r, self.prior.residuals(X)], axis=1),
                np.concatenate([J, Jp], axis=1))

    def residuals(self, Xn: np.ndarray) -> np.ndarray:
        """Residuals only (no sensitivities), for any batch of normalised rows."""
        Xn = np.atleast_2d(np.asarray(Xn, float))
        obs = self.model(self.to_physical(Xn), keep=True)
        self._last["entry"] = ({x.tobytes(): i for i, x in enumerate(Xn)}, obs.prepared)
        r = ((self.data.values[None] - obs.y) * self._weights[None]).reshape(Xn.shape[0], -1)
        r = self._project(r)
        if self.prior is None:
            return r
        return np.concatenate([r, self.prior.residuals(self.to_physical(Xn))], axis=1)

    @cached_property
    def _weights(self) -> np.ndarray:
        """1 / sigma (S, T): the weights D of Eq. 6, computed once per objective."""
        return 1.0 / self.data.sigma

    def chi2(self, Xn: np.ndarray) -> np.ndarray:
        """The minimised sum of squares (data chi-square plus the prior's rows, if any)."""
        r = self.residuals(Xn)
        return np.sum(r * r, axis=1)

    def data_chi2(self, Xn: np.ndarray) -> np.ndarray:
        """Chi-square of the data alone (Eq. 6), without the prior's rows."""
        r = self.residuals(Xn)[:, :self.data.n_obs]
        return np.sum(r * r, axis=1)
