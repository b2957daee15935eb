"""Bootstrap refits of an identification (issue 12): the whole chain repeated on campaigns that
resemble the measured one, each refitted from the best fit.

The opt-in uncertainty method ``generator-bootstrap`` (:func:`uncertainty`): the only module
of ``gprm.fit`` that imports the synthetic generator (an import contract in pyproject.toml).

- :func:`parametric_bootstrap`: campaigns *synthesised from the best fit* with the synthetic
  campaign generator (every mismatch ingredient: nonlinear correction, unmodelled mode,
  flange and runner motion, trigger offsets, run-to-run variability, coloured noise and
  drift), preprocessed with the measured campaign's preprocessing settings and refitted. The
  refits scatter like the estimator does, *and* they are offset from the best fit the way the
  estimator is offset from the truth by the mismatch the generator models: that offset is the
  estimate of the fit's bias. On a real campaign it captures the mismatch the generator
  models, not mismatch it does not know (docs/fitting.md says so).
- :func:`run_bootstrap`: the measured campaign's runs resampled with replacement per position,
  preprocessed and refitted: run-to-run variability and noise, no model mismatch.

Both return the refits (B, P), SI; :func:`from_bootstrap` turns them
into intervals and draws.
"""

from __future__ import annotations

from dataclasses import fields, replace
from typing import Any, Mapping, Sequence

import numpy as np
import xarray as xr

from gprm.campaign.files import read_generator, read_preprocess_settings
from gprm.campaign.preprocess import PreprocessConfig, preprocess
from gprm.campaign.synth import Support, SynthConfig, nonlinear_correction, synth_campaign
from scipy.stats import norm

from gprm.fit.calibration import MISMATCH_CALIBRATION, calibration_factors
from gprm.fit.covariance import normal_factor
from gprm.fit.engine import polish_best
from gprm.fit.methods import FitState
from gprm.fit import subsample
from gprm.fit.objective import FitData, Objective, fit_data_from_means
from gprm.fit.prior import Prior
from gprm.fit.starts import LMOptions
from gprm.fit.uncertainty import CONTRACTION, Uncertainty, estimate, replace_method
from gprm.params.registry import ALIGNMENT_OFFSETS, LAG_PARAMETERS


def preprocess_config(attrs: dict) -> PreprocessConfig:
    """The preprocessing settings a mean-signals file was made with (its attributes,
    :func:`gprm.campaign.files.read_preprocess_settings`), defaults where absent."""
    d = read_preprocess_settings(attrs)
    names = {f.name for f in fields(PreprocessConfig)}
    return PreprocessConfig(**{k: v for k, v in d.items() if k in names})


def synth_config(data: FitData) -> SynthConfig:
    """Generator settings for campaigns like the measured one: the generator's own settings
    where the campaign was synthetic (:func:`gprm.campaign.files.read_generator`), else the
    defaults with the measured campaign's number of runs, sample rate, record length and noise
    level."""
    attrs = data.attrs
    names = {f.name for f in fields(SynthConfig)}
    d = read_generator(attrs)
    if d is not None:
        try:
            # the file's settings: their types are known only at run time
            kw: dict[str, Any] = {k: (Support(*v) if isinstance(v, list) else v)
                                  for k, v in d.items() if k in names}
            return SynthConfig(**kw)
        except (TypeError, ValueError):
            pass
    cfg = SynthConfig()
    rate = float(attrs.get("sample_rate", cfg.rate))
    dur = float(attrs.get("record_duration", cfg.t_end))
    noise = attrs.get("noise_std_median")
    kw = {"rate": rate, "t_end": dur - 1.0 / rate}
    if noise is not None and np.isfinite(noise) and noise > 0:
        scale = float(noise) / cfg.noise_std
        kw.update(noise_white=cfg.noise_white * scale, noise_coloured=cfg.noise_coloured * scale)
    return replace(cfg, **kw)


def _refit(obj: Objective, data: FitData, x_start: np.ndarray, lm: LMOptions,
           max_iter: int) -> np.ndarray:
    def make(d):
        return Objective(d, obj.base, obj.names, obj.scale, obj.piezo, obj.z_bk_absolute,
                         obj.prior)

    def polish(ob, x0):
        return polish_best(ob, x0, lm, max_iter=max_iter, ftol=1e-8)[0]

    ob = make(data)
    if subsample.applies(data):
        # the refit sees its runs as the fit saw its own (gprm.fit.subsample)
        return subsample.correct_and_polish(ob, make, x_start, polish)[1]
    return polish(ob, x_start)


def parametric_bootstrap(obj: Objective, x_hat: np.ndarray, *, n_boot: int = 40,
                         seed: int = 0, lm: LMOptions = LMOptions(),
                         max_iter: int = 40) -> np.ndarray:
    """Refits (B, P) of campaigns synthesised from ``x_hat`` (see the module docstring).

    ``obj``: the fit's objective (its data carry the preprocessing and generator settings in
    their attributes; its prior, if any, is kept in the refits)."""
    data = obj.data
    cfg = synth_config(data)
    pcfg = preprocess_config(data.attrs)
    truth = obj.base.with_values(**dict(zip(obj.names, map(float, x_hat))))
    n = int(np.floor(cfg.t_end * cfg.rate + 1e-9)) + 1
    corr = nonlinear_correction(truth, np.arange(n) / cfg.rate) if cfg.nonlinear else {}
    out = np.empty((int(n_boot), len(obj.names)))
    for b in range(int(n_boot)):
        camp = synth_campaign(truth, seed=int(np.random.SeedSequence([seed, 13, b])
                                              .generate_state(1)[0]),
                              config=cfg, correction=corr)
        means = preprocess(camp, pcfg).to_dataset()
        db = fit_data_from_means(means, window=data.window, sigma=data.sigma_kind,
                                 source=f"bootstrap {b}", sigma_pool=data.sigma_pool)
        out[b] = _refit(obj, db, x_hat, lm, max_iter) - time_base_shift(means, obj.names)
    return out


def time_base_shift(means: xr.Dataset, names) -> np.ndarray:
    """Per parameter (P,), how far preprocessing moved a synthetic campaign's time base.

    The lags are signed offsets in the *aligned* time base: aligning each mean signal at its
    threshold crossing moves the signal by ``truth_shift`` (known when the campaign is
    synthetic), so a refit estimates t0 + s(x_base), t1 + s(z_bk) - s(x_base) and
    dt_p + s(p) - s(x_base) rather than the lags the campaign was synthesised with. The
    parametric bootstrap subtracts this before comparing refits with the best fit: without
    it the alignment's shift passes for a bias of t0 (measured: intervals of t0 moved by
    0.3-0.5 us, several standard deviations, and the velocity curves' coverage with them).
    Zero for parameters that are not lags and where no shift is known."""
    out = np.zeros(len(names))
    if "truth_shift" not in means.variables:
        return out
    s = {str(k): float(v) for k, v in zip(means["signal"].values, means["truth_shift"].values)}
    s = {k: (v if np.isfinite(v) else 0.0) for k, v in s.items()}
    ref = s.get("x_base", 0.0)
    lag = {"t0": ref, "t1": s.get("z_bk", ref) - ref}
    lag.update({p: s.get(point, ref) - ref for point, p in ALIGNMENT_OFFSETS.items()})
    for i, n in enumerate(names):
        out[i] = lag.get(n, 0.0)
    return out


def run_bootstrap(campaign: xr.Dataset, obj: Objective, x_hat: np.ndarray, *,
                  n_boot: int = 40, seed: int = 0, lm: LMOptions = LMOptions(),
                  max_iter: int = 40) -> np.ndarray:
    """Refits (B, P) of the measured ``campaign`` with its actuated runs resampled with
    replacement (independently per position), preprocessed with the fit's settings."""
    data = obj.data
    pcfg = preprocess_config(data.attrs)
    rng = np.random.default_rng([seed, 14])
    disp = campaign["displacement"]
    R = disp.sizes["run"]
    out = np.empty((int(n_boot), len(obj.names)))
    for b in range(int(n_boot)):
        idx = rng.integers(0, R, (disp.sizes["position"], R))
        vals = np.take_along_axis(disp.transpose("position", "run", "time").values,
                                  idx[:, :, None], axis=1)
        camp = campaign.copy()
        camp["displacement"] = (("position", "run", "time"), vals, disp.attrs)
        means = preprocess(camp, pcfg).to_dataset()
        db = fit_data_from_means(means, window=data.window, sigma=data.sigma_kind,
                                 source=f"run bootstrap {b}", sigma_pool=data.sigma_pool)
        out[b] = _refit(obj, db, x_hat, lm, max_iter)
    return out


def bootstrap_uncertainty(obj: Objective, x: np.ndarray, laplace, prior, method: str, *,
                          n_boot: int = 40, seed: int = 0, lm: LMOptions = LMOptions(),
                          campaign: xr.Dataset | None = None, n_draws: int = 400,
                          calibration: Mapping[str, float] | None = MISMATCH_CALIBRATION):
    """The ``generator-bootstrap`` or ``bootstrap-runs`` (needs ``campaign``) uncertainty of
    a fit at ``x`` with objective ``obj`` (the fit's, weighted prior included) and its
    Laplace posterior ``laplace`` (:func:`from_bootstrap`, which applies
    ``calibration``)."""
    if method == "generator-bootstrap":
        refits = parametric_bootstrap(obj, x, n_boot=n_boot, seed=seed, lm=lm)
    elif method == "bootstrap-runs":
        if campaign is None:
            raise ValueError("bootstrap-runs needs the campaign")
        refits = run_bootstrap(campaign, obj, x, n_boot=n_boot, seed=seed, lm=lm)
    else:
        raise ValueError(f"not a bootstrap method: {method!r}")
    return from_bootstrap(method, x, refits, laplace, prior, n_draws=n_draws, seed=seed,
                          calibration=calibration)


def from_bootstrap(method: str, x: np.ndarray, refits: np.ndarray, laplace: Uncertainty,
                   prior: Prior, *, n_draws: int = 400, seed: int = 0,
                   widen: Sequence[str] = LAG_PARAMETERS,
                   calibration: Mapping[str, float] | None = MISMATCH_CALIBRATION
                   ) -> Uncertainty:
    """Bootstrap-corrected posterior (methods ``generator-bootstrap``, ``bootstrap-runs``).

    In the prior's coordinates u, with u^ the best fit and u_b the refits (B, P): the bias
    b = mean(u_b) - u^ and the refits' standard deviations sd_b.

    - ``generator-bootstrap``: the Laplace posterior N(u^, C) re-centred at u^ - b. The
      refits of campaigns synthesised from the best fit are offset from it the way the
      estimate is offset from the truth by the model mismatch the generator contains; the
      posterior's spread (scaled by s2, which already carries the misfit) is kept. Measured
      in docs/fitting.md: the re-centring is what brings the intervals to their nominal
      coverage; the refits' own spread (about 0.7 of the posterior's) is too narrow.
      The exception are the lags (t0, t1 and the alignment offsets, ``LAG_PARAMETERS``):
      each mean signal is aligned at its own noisy threshold crossing, a timing error the
      fit's likelihood (on a fixed time base) cannot see and the refits, which preprocess
      their campaign again, do (their spread is 2-4 times the posterior's on the lags).
      There S = max(1, sd_b / sd_C) widens the posterior; it is what brings the velocity
      curves of Fig. 11, which hinge on t0, to their nominal coverage. ``widen`` names the
      parameters this applies to (``benchmarks/bench_bootstrap_rules.py`` compares choices).
      Last, each parameter's standard deviation is multiplied by its mismatch calibration
      factor F_k >= 1 (``calibration``, default :data:`gprm.fit.calibration.MISMATCH_CALIBRATION`;
      None or {} for none): the bias the refits cannot see for k_Bx, c_Bx and d2, measured
      on synthetic campaigns (gprm.fit.calibration says how and where).
    - ``bootstrap-runs``: the basic bootstrap, N(u^ - b, S C S) with S = diag(sd_b / sd_C)
      on the identified parameters (1 elsewhere: the refits of a prior-dominated parameter
      barely move, so their spread says nothing about it).

    Correlations are the posterior's. Identified as in the Laplace posterior, with the
    widened interval: ``contraction`` is the reported sd over the prior's, and a parameter
    counts as identified where it is below :data:`CONTRACTION` (and the Laplace posterior
    counts it identified, not leaning on the prior).
    """
    refits = np.asarray(refits, float)
    ok = np.all(np.isfinite(refits), axis=1)
    U = prior.to_u(refits[ok])
    u = prior.to_u(np.asarray(x, float))
    names = laplace.names
    if U.shape[0] < 5:
        return replace_method(laplace, method, f"only {U.shape[0]} usable refits; the "
                              "Laplace posterior stands in")
    bias = U.mean(axis=0) - u
    sd_b = U.std(axis=0, ddof=1)
    cov_u = laplace.covariance / np.outer(prior.dx_du(x), prior.dx_du(x))
    sd_l = np.sqrt(np.clip(np.diag(cov_u), 1e-300, None))
    applied: tuple[tuple[str, float], ...] = ()
    if method == "bootstrap-runs":
        s = np.where(laplace.identified, sd_b / sd_l, 1.0)
    else:
        wide = np.isin(np.asarray(names), list(widen))
        s = np.where(wide, np.maximum(1.0, sd_b / sd_l), 1.0)
        f = calibration_factors(names, calibration)
        s = s * f
        applied = tuple((n, float(v)) for n, v in zip(names, f) if v > 1.0)
    contraction = laplace.contraction * s
    identified = np.asarray(laplace.identified) & (contraction < CONTRACTION)
    leans = laplace.leaning & (contraction < CONTRACTION)
    centre = u - bias
    Cu = cov_u * np.outer(s, s)
    sd = np.sqrt(np.diag(Cu))
    z95, z68 = norm.ppf(0.975), norm.ppf(0.84)
    D = prior.dx_du(prior.from_u(centre))
    rng = np.random.default_rng([seed, 15])
    Z = rng.standard_normal((int(n_draws), len(names))) @ normal_factor(Cu).T
    cov_x = Cu * np.outer(D, D)
    return Uncertainty(method, names, 0.5 * (cov_x + cov_x.T),
                       prior.from_u(centre - z95 * sd), prior.from_u(centre + z95 * sd),
                       prior.from_u(centre - z68 * sd), prior.from_u(centre + z68 * sd),
                       identified, contraction,
                       prior.from_u(centre[None] + Z) if n_draws > 0 else None,
                       laplace.s2, laplace.tau, calibration=applied, leans_on_prior=leans)


def uncertainty(method: str, state: FitState) -> Uncertainty:
    """``generator-bootstrap`` through the one interface (gprm.fit.methods): the Laplace
    posterior re-centred and widened by refits of campaigns that gprm's synthetic generator
    makes from the best fit, with the mismatch calibration factors measured on that
    generator. Opt-in: it assumes the data's mismatch is the generator's (issue 21)."""
    assert state.prior is not None
    lap = estimate("laplace-prior", state.x, state.J, state.r, state.obj.dof,
                   len(state.obj.data.signals), state.prior, state.names,
                   n_draws=state.n_draws, seed=state.seed)
    return bootstrap_uncertainty(state.obj, state.x, lap, state.prior, method,
                                 n_boot=state.n_boot, seed=state.seed, lm=state.lm,
                                 n_draws=state.n_draws)
