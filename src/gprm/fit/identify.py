"""The whole identification (paper Sec. 3.1): the multi-start run of :mod:`gprm.fit.engine`,
the polish of the best start, the uncertainty of :mod:`gprm.fit.uncertainty` (with the
prior weighed against the data's variance scale), bands and profiles, gathered in a
:class:`gprm.fit.result.FitResult`.
"""

from __future__ import annotations

import time

import numpy as np

from gprm.errors import GprmInputError
from gprm.fit.adequacy import assess, effective_parameters
from gprm.fit.covariance import parameters_at_bounds
from gprm.fit.engine import polish_best, run_multistart, single_thread_blas
from gprm.fit.objective import FitData, Objective
from gprm.fit.prior import DEFAULT_WIDTH, default_prior
from gprm.fit.result import FitResult
from gprm.fit import resonance as resonance_mod
from gprm.fit import subsample
from gprm.fit.starts import MultiStartOptions
from gprm.fit.methods import DEFAULT_METHOD, NEEDS_PRIOR, FitState, compute
from gprm.fit.uncertainty import (Profile, compute_bands, estimate, profile_likelihood,
                                  time_correlation_factor)
from gprm.params import ParameterSet


@single_thread_blas()
def identify(data: FitData, base: ParameterSet, opts: MultiStartOptions = MultiStartOptions(),
             *, piezo: int = 2, names=None, workers: int = 0, scheduler: str | None = None,
             checkpoint_dir=None, progress=None, profile: bool = False, band_samples: int = 200,
             z_bk_absolute: bool = False, stop_after: int | None = None,
             uncertainty: str = DEFAULT_METHOD, prior_width: float | None = DEFAULT_WIDTH,
             n_draws: int = 400, n_boot: int = 40, systematics=None,
             executor=None, resonance: bool = True) -> FitResult:
    """Multi-start identification of ``names`` (default: the set's fitted parameters).

    With ``prior_width`` (default) every start minimises chi-square plus the weak prior of
    :mod:`gprm.fit.prior`; the best start is then polished with the prior weighed against
    the data's variance scale s2 (negative log posterior chi2 / s2 + prior), and the
    uncertainty comes from ``uncertainty`` (:mod:`gprm.fit.uncertainty`). ``prior_width=None``
    is the paper's unregularised fit (its uncertainty then is Eq. 7 or eq7-corr).
    ``systematics``: the instrument's stated systematics (gprm.fit.sandwich.Systematics;
    None: its documented defaults) the default method marginalises. ``executor``: a pool of
    local worker processes the caller made (:func:`gprm.fit.engine.local_pool`), used for
    the starts instead of ``workers``. ``resonance``: search the residuals for an unmodelled
    resonance of the mechanism and, where one is found, marginalise it
    (:mod:`gprm.fit.resonance`; with a prior only).

    Where the data carry runs moved by whole samples with their sub-sample remainder
    (``data.sync_remainder``, written by ``gprm preprocess``), the best start's point moves
    each run the rest of the way through the model (:mod:`gprm.fit.subsample`) before the
    polish; the result's ``data`` are the corrected data the fit and its uncertainty used.

    Runs with one BLAS thread (:func:`gprm.fit.engine.single_thread_blas`, as every chunk of
    starts does): the fit's matrices are small, and two threads on them were slower (the
    sandwich's eigendecompositions 1.1 s instead of 0.02 s on the 2-core machine) and change
    the last bits with the thread count.
    """
    t_start = time.perf_counter()
    fit_names = tuple(base.fitted if names is None else names)
    prior = None if prior_width is None else default_prior(base, fit_names, prior_width)
    if prior is None and uncertainty in NEEDS_PRIOR:
        raise GprmInputError(f"the {uncertainty} uncertainty needs a prior (a prior width)",
                             field="--uncertainty")
    obj = Objective.create(data, base, fit_names, piezo=piezo, z_bk_absolute=z_bk_absolute,
                           prior=prior)
    starts = run_multistart(obj, opts, workers=workers, scheduler=scheduler,
                            executor=executor,
                            checkpoint_dir=checkpoint_dir, progress=progress,
                            stop_after=stop_after)
    t_ms = time.perf_counter() - t_start
    best = starts.best_index
    x, polish = polish_best(obj, starts.x[best], opts.lm)
    remainder = data.sync_remainder
    if remainder is not None and subsample.applies(data):
        # the runs' sub-sample remainder, moved through the model at the best point so far
        # (gprm.fit.subsample): correct, polish, correct again at the polished point; the
        # polish in between at PASS_FTOL (the corrections depend on the point at second
        # order only), the last one the tight polish below
        obj, x, corr = subsample.correct_and_polish(
            obj, lambda d: Objective.create(d, base, fit_names, piezo=piezo,
                                            z_bk_absolute=z_bk_absolute, prior=prior),
            x, lambda o, x0: polish_best(o, x0, opts.lm, ftol=subsample.PASS_FTOL,
                                     settle=True)[0],
            final_polish=False)
        polish = {**polish, "subsample": subsample.summary(data.signals, remainder, corr)}
        data = obj.data
        if prior is None:
            x, polish_c = polish_best(obj, x, opts.lm)
            polish = {**polish, "corrected": polish_c}
    found = None
    if prior is not None and resonance:
        # an unmodelled resonance in the residuals: marginalised where found
        # (gprm.fit.resonance); the strongest candidate is recorded either way
        r0, J0 = _data_jacobian(obj, x)
        candidate = resonance_mod.search(obj, x, r0, J0, obj.prior)
        obj, x, found = resonance_mod.marginalise(
            obj, x, lambda o, x0: polish_best(o, x0, opts.lm, ftol=subsample.PASS_FTOL,
                                     settle=True)[0],
            jacobian=_data_jacobian, found=candidate, at=(r0, J0))
        if found is not None:
            polish = {**polish, "resonance": found.to_json()}
        elif candidate is not None:
            polish = {**polish, "resonance_search": {
                "found": False, "threshold": resonance_mod.DETECT_RATIO,
                "strongest": candidate.to_json()}}
    if prior is not None:
        # weigh the prior against the data's variance scale, then polish again (the residuals
        # alone here: the Jacobian is needed at the final point only; after the runs'
        # correction the point is the last pass's, not yet polished on its data: its chi2
        # lies above the minimum's by ~1e-4 relative, nothing in s2)
        r = obj.residuals(obj.to_normalised(x)[None])[0, :obj.data.n_obs]
        s2 = time_correlation_factor(r, len(data.signals)) * float(r @ r) / obj.dof
        obj = obj.with_prior(prior.with_weight(np.sqrt(max(s2, 1e-300))))
        x, polish2 = polish_best(obj, x, opts.lm)
        polish = {**polish, "posterior": polish2, "s2": s2}
    r, J = _data_jacobian(obj, x)
    chi2 = float(r @ r)
    eq7 = estimate("eq7", x, J, r, obj.dof, len(data.signals), prior, obj.names)
    t_b = time.perf_counter()
    state = FitState(obj, x, J, r, obj.prior, seed=opts.seed, n_draws=n_draws, lm=opts.lm,
                     n_boot=n_boot, systematics=systematics,
                     alternatives=np.asarray(starts.x, float))
    unc = eq7 if uncertainty == "eq7" else compute(uncertainty, state)
    t_a = time.perf_counter()
    adequacy = assess(obj, x, r, effective_parameters(J, x, obj.prior), lm=opts.lm,
                      resonance=found)
    t_adequacy = time.perf_counter() - t_a
    cov, msg = unc.covariance, unc.message
    lo, hi = obj.bounds_normalised()
    at_b = tuple(np.asarray(obj.names)[parameters_at_bounds(obj.to_normalised(x), lo, hi)]
                 .tolist())
    if at_b and cov is not None:
        msg = f"ok (parameters at a bound: {', '.join(at_b)}; their errors are not reliable)"
    params = base.with_values(**dict(zip(obj.names, map(float, x))))
    bands = compute_bands(obj, x, cov, n_samples=band_samples, seed=opts.seed,
                          draws=unc.draws)
    profiles: tuple[Profile, ...] = ()
    if profile:
        s2p = unc.s2 if np.isfinite(unc.s2) else 1.0
        sdu = (unc.contraction * prior.sd if prior is not None
               and unc.method in ("laplace-prior", "sandwich") else unc.stderr)
        profiles = tuple(profile_likelihood(obj, x, n, s2=s2p, sd_u=sdu[i], lm=opts.lm)
                         for i, n in enumerate(obj.names))
    timings = {"multistart": round(t_ms, 3), "uncertainty": round(t_a - t_b, 3),
               "adequacy": round(t_adequacy, 3),
               "total": round(time.perf_counter() - t_start, 3)}
    return FitResult(obj.names, params, chi2, obj.dof, cov, msg, at_b, starts, opts, data,
                     piezo, bands, profiles, timings, z_bk_absolute, polish, unc, eq7, prior,
                     systematics, adequacy, found)


def _data_jacobian(obj: Objective, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted data residuals r (N,) and their Jacobian d r / d x (N, P), physical x; the
    prior's rows left out."""
    r, Jn = obj(obj.to_normalised(x)[None])
    n = obj.data.n_obs
    return r[0, :n], Jn[0, :n] / obj.scale
