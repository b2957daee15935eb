"""The runs' sub-sample synchronisation, completed through the model (``gprm.fit.identify``).

``gprm preprocess`` moves each run by whole samples only, so that every sample of ``runs``
is one the interferometer measured; what of the run's estimated shift the rounding left,
``sync_remainder`` (signal, run), is at most half a sample: run r's samples match the
reference run's at t - sync_remainder[r] (docs/data-formats.md, step 1). Moving a run the
rest of the way needs its values between samples, and any interpolant of the samples errs
where the response has a kink (the motion's onset): a cubic spline there biased k_lr and m1
on campaigns with trigger offsets (docs/fitting.md, "The runs' sub-sample remainder").

The model is the one interpolant that knows the response's shape. At a parameter point x
each run is moved by the model's own change over its remainder,

    run_r(t) - [y(t - rem_r) - y(t)],

y the model signal at x on the data's time grid. Errors of x enter only through the change
over at most half a sample (second order), so two passes (best start, then the polished
point) settle it; the first is followed by a polish to PASS_FTOL, the second by the fit's
own final polish. The mean, and
sigma (sem or std, as the data were weighed), are then taken over the moved runs; they
replace the file's, which are over the spline-interpolated runs (the multi-start uses
those: the same weighting and nearly the same minimum).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from gprm.fit.objective import FitData, Objective, pooled_sigma

#: passes of correction and polish after the multi-start (the first at the best start, the
#: second at the point the first polish reached)
PASSES = 2

#: relative chi-square tolerance of the polish between two corrections (the last polish is
#: the caller's, at its own tolerance): the corrections change with the point at second order
#: only (over at most half a sample), so the intermediate point needs no more than the
#: multi-start's class of precision; 1e-12 there took about twice the iterations (200, the
#: limit, against 94 on the demo campaign; BENCHMARKS.md, "Fit speed targets", stop 36)
PASS_FTOL = 1e-9


def applies(data: FitData) -> bool:
    """Whether ``data`` carries runs with a sub-sample remainder still to move."""
    return data.sync_remainder is not None and data.runs is not None \
        and bool(np.any(data.sync_remainder != 0.0))


def run_corrections(obj: Objective, x: np.ndarray, remainder: np.ndarray) -> np.ndarray:
    """(S, R, T) m: y_s(t - remainder[s, r]) - y_s(t), the model's change over each run's
    sub-sample remainder at physical parameters ``x`` (P,), on ``obj.data``'s time grid.

    One simulation: every signal's shifted grids stacked into one time vector."""
    d = obj.data
    S, T = d.values.shape
    R = remainder.shape[1]
    shifts = np.concatenate([[0.0], remainder.reshape(-1)])
    times = (d.time[None, :] - shifts[:, None]).reshape(-1)
    y = obj.model(np.asarray(x, float)[None], times=times).y[0]          # (S, (1+S*R)*T)
    y = y.reshape(S, 1 + S * R, T)
    out = np.empty((S, R, T))
    for s in range(S):
        out[s] = y[s, 1 + s * R:1 + (s + 1) * R] - y[s, 0][None, :]
    return out


def corrected(data: FitData, corrections: np.ndarray) -> FitData:
    """``data`` with each run moved by ``corrections`` (S, R, T) (:func:`run_corrections`):
    the runs less their corrections, the mean and sigma taken over them again
    (``sigma_kind`` sem: std / sqrt(R); std: std; ddof 1; pooled over ``sigma_pool`` samples
    on each side as the file's was, gprm.fit.objective.pooled_sigma). They replace the file's
    mean and sigma, which ``gprm preprocess`` took over runs interpolated by a cubic spline;
    so the file's interpolation-error estimate goes too. The result carries no remainder
    (nothing is left to move)."""
    runs = data.runs - corrections
    R = runs.shape[1]
    std = runs.std(axis=1, ddof=1)
    sigma = pooled_sigma(std / np.sqrt(R) if data.sigma_kind == "sem" else std,
                         data.sigma_pool)
    # a sample where every run agrees exactly (never in measured data) keeps its weight
    sigma = np.where(sigma > 0, sigma, data.sigma)
    return replace(data, values=runs.mean(axis=1), sigma=sigma, runs=runs,
                   sync_remainder=None, interpolation_error=None)


def summary(signals, remainder: np.ndarray, corrections: np.ndarray) -> dict:
    """What the correction did, per signal, for fit.json: the largest remainder (s), the
    largest change of the mean (m) and of any run (m)."""
    return {s: {"max_remainder_s": float(np.max(np.abs(remainder[i]))),
                "max_mean_change_m": float(np.max(np.abs(corrections[i].mean(axis=0)))),
                "max_run_change_m": float(np.max(np.abs(corrections[i])))}
            for i, s in enumerate(signals)}


def correct_and_polish(obj: Objective, make_objective, x: np.ndarray, polish,
                       passes: int = PASSES, *, final_polish: bool = True):
    """(objective, x, corrections): ``passes`` rounds of moving the runs of ``obj.data`` (the
    measured data, with their remainder) through the model at the current point and
    polishing there. ``make_objective(data)`` builds the fit's objective on other data;
    ``polish(obj, x)`` returns the polished physical x. ``final_polish=False`` leaves out the
    last round's polish, for a caller whose own next step is a polish on the returned
    objective (``identify``'s polish with the prior weighed, at a tight tolerance)."""
    measured = obj.data
    if measured.runs is None or measured.sync_remainder is None:
        raise ValueError("the data carry no runs with a sub-sample remainder to move")
    remainder = measured.sync_remainder
    corr = np.zeros_like(measured.runs)
    for k in range(int(passes)):
        corr = run_corrections(obj, x, remainder)
        obj = make_objective(corrected(measured, corr))
        if final_polish or k < int(passes) - 1:
            x = polish(obj, x)
    return obj, x, corr
