"""Preprocessing a campaign into mean signals (Sec. 2, three steps; ``gprm preprocess``).

Per position:

0. *Baseline.* The interferometer's zero is arbitrary and drifts slowly: from each run a
   straight line fitted to its pre-motion part (the samples before the coarse motion onset,
   less a margin) is subtracted. The noise standard deviation ``noise_std`` is pooled over the
   noise runs, each about its own fitted straight line (ddof 2 per run).
1. *Synchronisation.* The reference run is the run closest (RMS over the motion window) to the
   pointwise median of all runs. Every other run r gets the sub-sample shift s_r minimising
   RMS[y_r(t + s_r) - y_ref(t)] over the motion window: an integer search over +-``max_lag``
   samples, then a bounded Brent search within +-1 sample of the best integer lag, with
   y_r(t + s) evaluated by a not-a-knot cubic spline through the samples of run r.
2. *Mean, std, sem* across the synchronised runs as functions of time (std with ddof 1,
   sem = std / sqrt(n_runs)).
3. *Alignment.* The mean signal is shifted so that its magnitude reaches
   ``threshold_factor`` x noise_std at ``align_time`` (1 ms). The crossing t_x is found on
   the synchronised mean as a continuous function, M(t) = mean_r spline_r(t + s_r) (the same
   interpolant as the output): M is scanned at 1/8 sample; t_x is the first up-crossing of
   |M| through the threshold after which |M| stays at or above it for ``hold`` (1) sample,
   refined by Brent's method on sign * M(t) = threshold. The hold skips sub-sample lobes that
   barely touch the threshold (x_base starts with one) and spline ringing before a kink
   (z_bk): without it the crossing jumps by about a sample with the sampling phase.
   Where |M| is already above the threshold at the record's start (baseline drift that a
   few runs do not average out), the scan starts instead at the last point before the
   coarse onset (step 0's ``onset_factor``) where |M| is below it (:func:`quiet_start`):
   the crossing that leads into the motion. Elsewhere the first crossing stands (a small
   first lobe of real motion, as x_base has, is the crossing).
   shift = align_time - t_x rounded to whole samples; new time = old time + shift, so the
   crossing lies within half a sample of align_time (``crossing_time``) and the fitted lags
   take up the remainder.

The synchronised runs are evaluated once more at (t' - shift + s_r) on the output grid (the
record grid restricted to where every position and run has data): the reference run (s_r = 0)
at its own samples, every other run interpolated once; mean, std and sem are taken over these.
The runs written to the file (``runs``, the fit's run-to-run covariance) are not these: each
is moved by s_r rounded to whole samples, so that every value is one the interferometer
measured, and the rest of its shift, at most half a sample, is written beside it
(``sync_remainder``). A cubic spline across the motion's onset, where the response has a
kink, errs by an amount that depends on the run's sampling phase; on campaigns with trigger
offsets that error biased k_lr and m1 (docs/data-formats.md, step 1). The fit completes the
move through the model's own shape (:mod:`gprm.fit.subsample`). For synthetic campaigns,
the truth is put on the aligned axis as the data were (``truth_shift``: the runs' average
of (trigger offset - synchronisation shift), the time of the mean of the synchronised runs,
plus the alignment's shift; ``truth_mean``: the noise-free truth moved by it): the aligned
means are compared with it, and the fit's lags with the truth's (docs/data-formats.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import xarray as xr
from scipy.interpolate import CubicSpline, make_interp_spline
from scipy.linalg import toeplitz
from scipy.optimize import brentq, minimize_scalar

import gprm
from gprm.campaign.data import MODEL_POSITIONS, POSITIONS, validate_campaign
from gprm.campaign.files import (generator_attrs, means_dataset, preprocess_attrs, read_generator,
                                 read_truth, truth_alignment)
from gprm.errors import GprmInputError

TABLE1 = (("x_head", "x_lr", 3.0), ("x_head", "x_fl", 17.0), ("y_head", "y_lr", 3.0),
          ("y_head", "y_fl", 21.0), ("z_bk", "z_fl", 26.0))
"""Table 1: (numerator, denominator, paper value) of the ratios of mean-signal maxima."""

UPSAMPLE = 8
"""The synchronised mean is scanned at 1/UPSAMPLE of a sample for the threshold crossing."""

HYPOTHESES = (
    ("flange fixed (Sec. 2, hypothesis 1)", ("x_fl", "y_fl", "z_fl"), 10.0),
    ("linear runner does not oscillate along x and y (Sec. 2, hypothesis 2)",
     ("x_lr", "y_lr"), 2.0),
)
"""Sec. 2 hypotheses: positions dropped, and the Table-1 ratio above which the data support it."""


@dataclass(frozen=True)
class PreprocessConfig:
    """Settings of the preprocessing (SI; lags in samples)."""

    # 1.01 ms, not 1.0 ms: at 1.0 ms the aligned crossing precedes the model's onset t_c + t0,
    # so the lag a fit needs is negative (about -6 us, docs/data-formats.md) while the registry
    # bounds t0 >= 0; 1.01 ms gives the positive lag the paper reports (t0 about 4 us). The
    # one recommended configuration (gprm.campaign.api.PreprocessOptions takes it from here).
    align_time: float = 1.01e-3
    threshold_factor: float = 2.0
    max_lag: int = 12                 # samples searched either side in the synchronisation
    sync_window: float = 0.3e-3       # s of motion after the coarse onset used for the RMS
    onset_factor: float = 10.0        # coarse onset: median run exceeds this x noise std
    baseline_margin: int = 4          # samples kept clear before (onset - max_lag)
    hold: int = 1                     # samples |mean| must stay >= threshold after a crossing


@dataclass(frozen=True)
class MeanSignals:
    """The preprocessing result; arrays over (signal, time) in the order ``signals``."""

    signals: tuple[str, ...]
    time: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    sem: np.ndarray
    noise_std: np.ndarray
    shift: np.ndarray
    n_runs: np.ndarray
    sync_shift: np.ndarray            # (signal, run) s, run r's synchronisation shift
    reference_run: np.ndarray
    table1: dict
    dropped: dict
    snr: dict
    attrs: dict = field(default_factory=dict)
    truth_shift: np.ndarray | None = None
    truth_mean: np.ndarray | None = None
    truth_shift_spread: np.ndarray | None = None

    no_crossing: tuple[str, ...] = ()
    truth: dict | None = None             # the campaign's truth (synthetic), name -> SI
    truth_alignment: dict | None = None   # files.truth_alignment (synthetic)
    #: (signal, run, time) m: each actuated run aligned onto the output grid and moved by its
    #: synchronisation shift rounded to whole samples (its own samples, not interpolated; the
    #: fit's run-to-run covariance); mean, std and sem are over the runs interpolated by the
    #: full sub-sample shift
    runs: np.ndarray | None = None
    #: (signal, time) m: the mean's cubic interpolation less a quintic one of the same runs at
    #: the same points: an estimate of the error the interpolation of step 3 adds
    interpolation_error: np.ndarray | None = None
    #: (signal,) s: where each mean's first sustained crossing lies on the output time axis,
    #: within half a sample of align_time (the shift is a whole number of samples);
    #: align_time for a signal that never crossed
    crossing_time: np.ndarray | None = None
    #: (signal, run) s: each run's synchronisation shift less the whole samples ``runs`` moved
    #: it by (within half a sample; 0 for the reference run): run r in ``runs`` matches the
    #: reference run at t - sync_remainder[r]
    sync_remainder: np.ndarray | None = None
    #: (signal,) s: the standard deviation of the time shift that the synchronisation takes
    #: out of the runs' spread but leaves in their mean (:func:`sync_timing_sd`)
    sync_timing_sd: np.ndarray | None = None
    #: (signal, 2) s: the first and last of the baseline samples step 0 fitted its straight
    #: line to, on the output time axis (the reference run's; a run moved by whole samples
    #: has them that many samples earlier or later), uniformly spaced like ``time``
    baseline: np.ndarray | None = None
    #: (signal, lag) m^2: the noise runs' autocovariance at lags 0.. samples of the record
    #: (:func:`noise_autocovariance`), the noise model of both hidden-shift terms
    noise_acov: np.ndarray | None = None

    def to_dataset(self) -> xr.Dataset:
        """The mean-signals NetCDF layout (:func:`gprm.campaign.files.means_dataset`)."""
        return means_dataset(self)


def _line_design(t_fit: np.ndarray, t_eval: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(X_fit, X_eval): a straight line's design at the times it is fitted to and at the
    times it is evaluated, both scaled by the fit times' mean and span."""
    tm, ts = t_fit.mean(), max(np.ptp(t_fit), 1e-30)
    return (np.stack([np.ones(t_fit.size), (t_fit - tm) / ts], axis=1),
            np.stack([np.ones(np.size(t_eval)), (np.asarray(t_eval, float) - tm) / ts], axis=1))


def _line_residuals(noise: np.ndarray, time: np.ndarray) -> np.ndarray:
    """(T, N): each noise run (N, T) less the straight line fitted to all of it, one run per
    column."""
    X, _ = _line_design(time, time)
    coef, *_ = np.linalg.lstsq(X, noise.T, rcond=None)
    return noise.T - X @ coef


def noise_std(noise: np.ndarray, time: np.ndarray) -> float:
    """Pooled std of noise runs (N, T) about a straight line fitted to each run (ddof 2)."""
    res = _line_residuals(noise, time)
    return float(np.sqrt(np.sum(res ** 2) / (noise.shape[0] * (time.size - 2))))


#: order of the autoregression fitted to each position's noise runs (:func:`noise_autocovariance`)
NOISE_AR_ORDER = 3


def noise_autocovariance(noise: np.ndarray, time: np.ndarray, order: int = NOISE_AR_ORDER
                         ) -> np.ndarray:
    """(T,) m^2: the autocovariance at lags 0..T-1 samples of an autoregression of order
    ``order`` fitted to the noise runs (N, T) by Yule-Walker, the runs pooled, each about a
    straight line fitted to it (as :func:`noise_std`).

    The first order + 1 lags are the runs' pooled sample autocovariances (ddof 2 at lag 0,
    so lag 0 is noise_std^2); the rest follow the fitted recursion
    c_h = sum_k phi_k c_(h-k), so the whole function is a valid (positive definite)
    autocovariance whatever the record's length (where the first lags' Toeplitz matrix is not
    positive definite, which the pooled estimate is in practice, the noise is taken as
    white beyond lag 0). White noise gives phi ~ 0 and c_h ~ 0 for
    h > 0; low-pass or drifting noise a slowly decaying c. A model rather than the raw
    sample autocovariance at every lag, because a campaign has few noise runs (five of 300
    samples in the generator's): the raw estimate at long lags is noise, and a quadratic
    form over hundreds of samples sums it (docs/fitting.md, "Step 0's line and the noise's
    own correlation in the hidden shifts (stop 56)")."""
    N = np.atleast_2d(np.asarray(noise, float))
    T = N.shape[1]
    res = np.ascontiguousarray(_line_residuals(N, time).T)
    p = int(min(max(order, 0), T - 3))
    c = np.array([np.sum(res[:, :T - h] * res[:, h:]) for h in range(p + 1)])
    c /= N.shape[0] * np.concatenate([[T - 2], T - np.arange(1, p + 1)])
    out = np.zeros(T)
    out[0] = c[0]
    if p > 0 and c[0] > 0 and np.linalg.eigvalsh(toeplitz(c)).min() > 0:
        phi = np.linalg.solve(toeplitz(c[:p]), c[1:])
        out[: p + 1] = c
        for h in range(p + 1, T):
            out[h] = float(phi @ out[h - 1::-1][:p])        # c_(h-1), ..., c_(h-p)
    return out


def _detrended_weights(w: np.ndarray, t_w: np.ndarray, t_base: np.ndarray,
                       acov: np.ndarray, dt: float):
    """(a, C, iw, ib, line): step 0 as weights on one grid of ``dt`` over the baseline and
    the window. <w, e - line> = a^T e, a = w on the window (indices iw) less
    X_b (X_b^T X_b)^-1 X_w^T w on the baseline (indices ib); C_ij = acov[|i - j|] (0 beyond
    its length); line (n_w, n_b) the baseline line's value at the window's times (None
    without a baseline)."""
    w = np.asarray(w, float)
    t_w = np.asarray(t_w, float)
    t_base = np.asarray(t_base, float) if np.size(t_base) >= 2 else np.empty(0)
    acov = np.asarray(acov, float)
    t0 = float(np.concatenate([t_w, t_base]).min())
    iw = np.rint((t_w - t0) / dt).astype(int)
    ib = np.rint((t_base - t0) / dt).astype(int)
    n = int(max(iw.max(), ib.max(initial=0))) + 1
    a = np.zeros(n)
    np.add.at(a, iw, w)
    line = None
    if t_base.size:
        Xb, Xw = _line_design(t_base, t_w)
        np.add.at(a, ib, -Xb @ np.linalg.solve(Xb.T @ Xb, Xw.T @ w))
        line = Xw @ np.linalg.solve(Xb.T @ Xb, Xb.T)
    C = toeplitz(np.concatenate([acov, np.zeros(max(n - acov.size, 0))])[:n])
    return a, C, iw, ib, line


def detrended_noise_variance(w: np.ndarray, t_w: np.ndarray, t_base: np.ndarray,
                             acov: np.ndarray, dt: float) -> float:
    """m^2 x w's units^2: Var<w, e> for a run's noise e of autocovariance ``acov`` (lags
    0.. in samples of ``dt``) after step 0 (the straight line fitted to the baseline samples
    at ``t_base`` subtracted), w weights at the sample times ``t_w`` (one axis, s).

    <w, e - line> = a^T e over the baseline and window samples (:func:`_detrended_weights`),
    so Var = a^T C a. With acov = (sd^2, 0, 0, ...) this is sd^2 times
    :func:`detrended_noise_factor`."""
    a, C, *_ = _detrended_weights(w, t_w, t_base, acov, dt)
    return float(a @ C @ a)


def detrended_noise_cross(w: np.ndarray, t_w: np.ndarray, t_base: np.ndarray,
                          acov: np.ndarray, dt: float) -> np.ndarray:
    """(n_w,) m^2 x w's units: Cov(e'(t_i), <w, e'>) for each window time t_i of ``t_w``,
    e' = a run's noise after step 0 (the straight line fitted to the baseline samples at
    ``t_base`` subtracted), of autocovariance ``acov`` (lags 0.. in samples of ``dt``); the
    vector whose inner product with w is :func:`detrended_noise_variance` (and with another
    weight vector v, the covariance of <v, e'> and <w, e'>)."""
    a, C, iw, ib, line = _detrended_weights(w, t_w, t_base, acov, dt)
    Ca = C @ a
    return Ca[iw] if line is None else Ca[iw] - line @ Ca[ib]


def sync_timing_sd(splines, shifts: np.ndarray, win: np.ndarray, noise_sd: float,
                   time: np.ndarray, n_base: int, acov: np.ndarray | None = None) -> float:
    """s: the standard deviation of the time shift that step 1 takes out of the runs' spread
    but leaves in their mean.

    Step 1 moves run r by the shift that best matches the reference over ``win``; to first
    order its noise e_r moves it by <g, e_r - e_ref> (g = y' / |y'|^2 over the window, y' the
    synchronised runs' mean slope per sample). Each synchronised run then lacks its noise's
    component along y' and carries the reference run's instead, so the runs' deviations from
    their mean have none along y', while the mean keeps the average noise's,
    y' <g, mean_r e_r>: a time shift of variance Var<g, e> / R that the runs' spread does not
    show (the data's time axis is anchored at the synchronisation's average,
    docs/data-formats.md). A fitted lag absorbs it: the lags' own error, and through them
    every prediction read on the fit's time axis (measured: docs/fitting.md, "The time
    shift the synchronisation hides").

    e_r is the run's noise after step 0 (its straight line fitted to the first ``n_base``
    samples and subtracted), white with sd ``noise_sd`` (the noise runs' pooled sd):
    Var<g, e> = noise_sd^2 (|g|^2 + c^T (X_b^T X_b)^-1 c), c = X_w^T g, X the line's design
    over the baseline (b) and the window (w), exactly. With ``acov`` (the noise's
    autocovariance, :func:`noise_autocovariance`; how preprocessing calls it since stop 56)
    e has that correlation instead of being white (:func:`detrended_noise_variance`): on
    low-pass noise the shift is larger than the white model's. (Projecting the noise runs
    themselves on g was tried: each noise run's own straight line takes out a tenth of the
    variance along a template that is mostly one-signed, as a slope over a rise is; and a
    campaign's few short noise runs give that projection too few independent placements.)
    ``splines``/``shifts``: step 1's per-run splines over the sample index and shifts
    (samples); ``win``: its window (sample indices after the baseline); ``time`` (T,) s.
    0 where the window has no slope."""
    R = len(splines)
    slope = np.mean([splines[r].derivative()(win + shifts[r]) for r in range(R)], axis=0)
    ss = float(slope @ slope)
    if ss <= 0 or not np.isfinite(noise_sd) or n_base < 2:
        return 0.0
    g = slope / ss
    dt = float(time[1] - time[0])
    if acov is None:
        var = noise_sd ** 2 * detrended_noise_factor(g, time[win], time[:n_base])
    else:
        var = detrended_noise_variance(g, time[win], time[:n_base], acov, dt)
    return dt * float(np.sqrt(max(var, 0.0) / R))


def detrended_noise_factor(w: np.ndarray, t_w: np.ndarray, t_base: np.ndarray) -> float:
    """Var<w, e> / noise_sd^2 for a run's white noise e after step 0: |w|^2 + c^T (X_b^T
    X_b)^-1 c, c = X_w^T w, exactly.

    Step 0 fits a straight line to each run's baseline samples (times ``t_base``) and
    subtracts it from the whole run, so the run keeps its own noise (|w|^2) and, along ``w``
    (weights at the times ``t_w``), the line's error extrapolated from the baseline: X the
    line's design, over the baseline (b) and at t_w (w). Every time on one axis (s); the
    baseline as :func:`_detrend` takes it. Used by :func:`sync_timing_sd` and by the fit's
    drive term (gprm.fit.sandwich.drive_shift_sd)."""
    w = np.asarray(w, float)
    t_base = np.asarray(t_base, float)
    if t_base.size < 2:
        return float(w @ w)
    Xb, Xw = _line_design(t_base, t_w)
    c = Xw.T @ w
    return float(w @ w) + float(c @ np.linalg.solve(Xb.T @ Xb, c))


def _detrend(Y: np.ndarray, time: np.ndarray, n_base: int) -> np.ndarray:
    """Subtract from each run the straight line fitted to its first ``n_base`` samples."""
    X, Xf = _line_design(time[:n_base], time)
    coef, *_ = np.linalg.lstsq(X, Y[:, :n_base].T, rcond=None)
    return Y - (Xf @ coef).T


def first_crossing(f, t_start: float, t_stop: float, step: float, threshold: float,
                   hold: int = 1) -> float | None:
    """First time in [t_start, t_stop] at which |f(t)| reaches ``threshold`` and then stays at
    or above it for ``hold`` scan steps: f (vectorised, continuous) is scanned at ``step``; in
    the interval where |f| goes from below to at or above the threshold, the root of
    sign * f(t) = threshold is found by Brent's method. None if there is no such crossing (or
    |f| starts above the threshold: no incipient motion seen)."""
    tt = np.arange(t_start, t_stop + 0.5 * step, step)
    tt = tt[tt <= t_stop]
    y = f(tt)
    a = np.abs(y) >= threshold
    if a[0]:
        return None
    ok = a.copy()
    for k in range(1, hold):
        ok[:-k] &= a[k:]
        ok[-k:] = False
    start = ok & np.concatenate([[False], ~a[:-1]])
    if not start.any():
        return None
    i = int(np.argmax(start))
    sgn = np.sign(y[i])
    return float(brentq(lambda x: sgn * f(x) - threshold, tt[i - 1], tt[i],
                        xtol=1e-6 * step, rtol=4 * np.finfo(float).eps))


def quiet_start(f, t_start: float, t_onset: float, step: float, threshold: float) -> float:
    """The last scan point (step ``step``) in [t_start, t_onset] where |f| is below
    ``threshold``: where the search for the crossing that leads into the motion begins.
    ``t_start`` itself when |f| is at or above the threshold all the way (the crossing
    search then reports that no incipient motion is seen)."""
    tt = np.arange(t_start, max(t_onset, t_start) + 0.5 * step, step)
    tt = tt[tt <= max(t_onset, t_start)]
    below = np.flatnonzero(np.abs(f(tt)) < threshold)
    return float(tt[below[-1]]) if below.size else float(t_start)


def _sampled_crossing(f, time: np.ndarray, delay: float, threshold: float, hold: int
                      ) -> float | None:
    """The alignment rule applied to a continuous signal f sampled on ``time`` after a delay
    (samples f(time - delay)); returns the crossing on f's own time axis."""
    dt = time[1] - time[0]
    y = f(time - delay)
    cs = CubicSpline(time, y)
    tx = first_crossing(cs, time[0], time[-1], dt / UPSAMPLE, threshold,
                        hold=hold * UPSAMPLE + 1)
    return None if tx is None else tx - delay


def truth_axis_shift(shift, trigger_offset, sync_shift) -> np.ndarray:
    """(signals,) s: where the aligned means put a source's own time (its command at t_c),
    per signal: the time of the mean of the synchronised runs, i.e. the runs' average of
    (trigger offset - synchronisation shift), plus the alignment shift. ``shift`` (signals,),
    ``trigger_offset`` and ``sync_shift`` (signals, runs), all s: the source's offsets, and
    the synchronisation's (MeanSignals.sync_shift). (Stop 39 took the reference run's
    trigger offset alone, which differs by the synchronisation's average error: about the
    reference run's own timing error; docs/data-formats.md, "The truth after alignment, and
    what t0 means".)"""
    return (np.asarray(shift, float)
            + np.mean(np.asarray(trigger_offset, float) - np.asarray(sync_shift, float), axis=1))


def alignment_shift(time, y, threshold: float, *, align_time: float = 1.0e-3,
                    hold: int = 1) -> float | None:
    """The step-3 alignment applied to one sampled signal (for example a model output on the
    record grid): the shift that moves its first sustained crossing of ``threshold`` to
    ``align_time`` (new time = time + shift). None if it never crosses. Use it to compare a
    model with the mean signals on equal terms (docs/data-formats.md, "t0 after alignment")."""
    time = np.asarray(time, float)
    tx = _sampled_crossing(CubicSpline(time, np.asarray(y, float)), time, 0.0, threshold, hold)
    return None if tx is None else align_time - tx


def synchronise(Y: np.ndarray, ref: int, win: np.ndarray, max_lag: int):
    """Sub-sample shifts (samples) s_r minimising RMS[y_r(i + s_r) - y_ref(i)] over indices
    ``win``; and the per-run splines (over the sample index)."""
    R, T = Y.shape
    idx = np.arange(T, dtype=float)
    splines = [CubicSpline(idx, Y[r]) for r in range(R)]
    target = Y[ref, win]
    shifts = np.zeros(R)
    lags = np.arange(-max_lag, max_lag + 1)
    for r in range(R):
        if r == ref:
            continue
        cost = [np.mean((Y[r, win + k] - target) ** 2) for k in lags]
        k = int(lags[int(np.argmin(cost))])
        sp = splines[r]
        res = minimize_scalar(lambda s: np.mean((sp(win + s) - target) ** 2),  # noqa: B023 (used in this iteration)
                              bounds=(k - 1.0, k + 1.0), method="bounded",
                              options={"xatol": 1e-5})
        shifts[r] = float(res.x)
    return shifts, splines


def _position(Y, N, time, cfg: PreprocessConfig, name: str, src: str,
              onset: int | None = None):
    """Steps 0-2 for one position: returns dict with noise std, baseline-corrected runs,
    reference, shifts (samples), splines, coarse onset index. ``onset``: the onset index to
    use where this position shows no motion above the noise (a position the model does not
    fit, e.g. a flange that barely moves); without it such a position is an input error."""
    T = time.size
    sn = noise_std(N, time)
    acov = noise_autocovariance(N, time)
    first = Y[:, : max(T // 5, 4)]
    y0 = Y - np.median(first, axis=1, keepdims=True)
    med0 = np.median(y0, axis=0)
    above = np.abs(med0) > cfg.onset_factor * sn
    if not above.any() and onset is not None:
        above = np.arange(T) >= onset
    if not above.any():
        raise GprmInputError(f"position {name}: no motion above {cfg.onset_factor:g} x the "
                             f"noise std ({sn:.3g} m) in the actuated runs", source=src,
                             field="displacement")
    i_on = int(np.argmax(above))
    n_base = i_on - cfg.max_lag - cfg.baseline_margin
    if n_base < 10:
        raise GprmInputError(f"position {name}: motion starts at sample {i_on}, too early "
                             "for a pre-motion baseline (need >= 10 samples before it)",
                             source=src, field="displacement")
    Yb = _detrend(Y, time, n_base)
    dt = time[1] - time[0]
    w_end = min(i_on + int(round(cfg.sync_window / dt)), T - cfg.max_lag - 3)
    win = np.arange(max(i_on - cfg.max_lag // 2, cfg.max_lag + 1), w_end)
    med = np.median(Yb, axis=0)
    ref = int(np.argmin(np.mean((Yb[:, win] - med[win]) ** 2, axis=1)))
    shifts, splines = synchronise(Yb, ref, win, cfg.max_lag)
    return dict(noise_std=sn, ref=ref, shifts=shifts, splines=splines, onset=i_on, runs=Yb,
                sync_timing_sd=sync_timing_sd(splines, shifts, win, sn, time, n_base, acov),
                baseline=(float(time[0]), float(time[n_base - 1])), noise_acov=acov)


def preprocess(campaign: xr.Dataset, config: PreprocessConfig | None = None) -> MeanSignals:
    """Synchronise, average and align a validated campaign (see the module docstring)."""
    cfg = PreprocessConfig() if config is None else config
    src = str(campaign.attrs.get("source", "campaign"))
    campaign = validate_campaign(campaign, source=src)
    time = np.asarray(campaign["time"].values, float)
    dt = float(time[1] - time[0])
    T = time.size
    disp = np.asarray(campaign["displacement"].sel(position=list(POSITIONS)).values, float)
    noise = np.asarray(campaign["noise"].sel(position=list(POSITIONS)).values, float)
    R = disp.shape[1]
    per = {}
    shift = np.zeros(len(POSITIONS))
    exact = np.full(len(POSITIONS), np.nan)          # the shifts before the rounding
    no_cross = []
    # the fitted positions first: a position outside the model that shows no motion above
    # its noise (a flange that barely moves) then takes their median onset
    order = sorted(range(len(POSITIONS)), key=lambda i: POSITIONS[i] not in MODEL_POSITIONS)
    onsets: list[int] = []
    for i in order:
        name = POSITIONS[i]
        fallback = int(np.median(onsets)) if name not in MODEL_POSITIONS and onsets else None
        d = _position(disp[i], noise[i], time, cfg, name, src, onset=fallback)
        if name in MODEL_POSITIONS:
            onsets.append(d["onset"])
        # the synchronised mean as a continuous function of the reference run's sample
        # index; its first crossing (scanned at 1/UPSAMPLE sample) gives the alignment
        lo = max(0.0, -d["shifts"].min())
        hi = min(T - 1.0, T - 1.0 - d["shifts"].max())
        sh, sps = d["shifts"], d["splines"]

        def M(k, sh=sh, sps=sps):
            return np.mean([sps[r](np.asarray(k) + sh[r]) for r in range(R)], axis=0)

        thr = cfg.threshold_factor * d["noise_std"]
        kx = first_crossing(M, lo, hi, 1.0 / UPSAMPLE, thr, hold=cfg.hold * UPSAMPLE + 1)
        if kx is None and abs(float(M(lo))) >= thr:
            # the mean starts above the threshold (baseline drift a few runs do not average
            # out): the crossing that leads into the motion
            kx = first_crossing(M, quiet_start(M, lo, min(float(d["onset"]), hi),
                                               1.0 / UPSAMPLE, thr),
                                hi, 1.0 / UPSAMPLE, thr, hold=cfg.hold * UPSAMPLE + 1)
        if kx is None:
            no_cross.append(name)
            shift[i] = np.nan
        else:
            # whole samples: the reference run is then not interpolated at all, and the
            # crossing lands within half a sample of align_time (``crossing_time``); the
            # fitted lags take up the rest. A sub-sample shift would interpolate every run
            # across the motion's onset, where the response has a kink; a cubic spline errs
            # there, enough to bias k_lr and m1 by about one sd on exact-model campaigns
            # (docs/data-formats.md, step 3)
            exact[i] = cfg.align_time - (time[0] + kx * dt)
            shift[i] = dt * np.round(exact[i] / dt)
        per[name] = d
    if no_cross:
        if set(no_cross) & set(MODEL_POSITIONS):
            bad = sorted(set(no_cross) & set(MODEL_POSITIONS))
            raise GprmInputError(f"position(s) {bad}: the mean signal shows no crossing of "
                                 f"{cfg.threshold_factor:g} x the noise std into the motion "
                                 "(it never reaches it, or stays above it from the record's "
                                 "start to the motion's onset); cannot align",
                                 source=src, field="displacement")
        exact[np.isnan(exact)] = np.nanmedian(exact)
        shift[np.isnan(shift)] = dt * np.round(exact[np.isnan(shift)] / dt)
    rounding = shift - exact                          # where each crossing now lies, - align
    sync = np.array([per[n]["shifts"] for n in POSITIONS]) * dt      # (P, R) s
    # output grid: record samples where every position and run has data
    src_lo = time[0] + shift[:, None] - sync                           # t' >= this
    src_hi = time[-1] + shift[:, None] - sync
    lo, hi = src_lo.max(), src_hi.min()
    tgrid = time[(time >= lo - 1e-12 * dt) & (time <= hi + 1e-12 * dt)]
    if not (tgrid.size >= 8 and tgrid[0] <= cfg.align_time <= tgrid[-1]):
        raise GprmInputError("alignment shifts leave no common time range around "
                             f"{cfg.align_time:g} s", source=src, field="time")
    P = len(POSITIONS)
    mean = np.empty((P, tgrid.size))
    std = np.empty_like(mean)
    runs = np.empty((P, R, tgrid.size))
    interp_err = np.empty_like(mean)
    remainder = np.zeros((P, R))
    for i, name in enumerate(POSITIONS):
        d = per[name]
        k = (tgrid - shift[i] - time[0]) / dt          # the record's sample index (whole)
        at = [np.clip(k + d["shifts"][r], 0, T - 1) for r in range(R)]
        A = np.stack([d["splines"][r](at[r]) for r in range(R)])
        # the interpolation's own error, estimated by a higher-order interpolant of the
        # same samples at the same points (docs/data-formats.md, step 3)
        idx = np.arange(T, dtype=float)
        A5 = np.stack([make_interp_spline(idx, d["runs"][r], k=5)(at[r]) for r in range(R)])
        interp_err[i] = A.mean(axis=0) - A5.mean(axis=0)
        mean[i] = A.mean(axis=0)
        std[i] = A.std(axis=0, ddof=1)
        # the file's runs: moved by whole samples only (each value a measured sample); the
        # sub-sample rest is sync_remainder, which the fit completes through the model
        whole = np.round(d["shifts"])
        runs[i] = np.stack([d["runs"][r][np.clip(np.rint(k + whole[r]), 0, T - 1).astype(int)]
                            for r in range(R)])
        remainder[i] = (d["shifts"] - whole) * dt
    sem = std / np.sqrt(R)
    nstd = np.array([per[n]["noise_std"] for n in POSITIONS])
    ref = np.array([per[n]["ref"] for n in POSITIONS])

    peaks = {n: float(np.max(np.abs(mean[i]))) for i, n in enumerate(POSITIONS)}
    table1 = {f"max({a})/max({b})": {"value": peaks[a] / peaks[b], "paper": p,
                                     "numerator_m": peaks[a], "denominator_m": peaks[b]}
              for a, b, p in TABLE1}
    dropped = {}
    by_den = {b: (a, p) for a, b, p in TABLE1}
    for text, names, need in HYPOTHESES:
        for n in names:
            num, p_ratio = by_den[n]
            r = peaks[num] / peaks[n]
            dropped[n] = {"hypothesis": text, "ratio": f"max({num})/max({n})", "value": r,
                          "paper": p_ratio, "supported": bool(r >= need),
                          "support_threshold": need}
    snr = {}
    for i, n in enumerate(POSITIONS):
        j = int(np.argmax(np.abs(mean[i])))
        snr[n] = {"peak_m": peaks[n], "std_at_peak_m": float(std[i, j]),
                  "peak_over_std": float(peaks[n] / std[i, j]), "time_of_peak_s": float(tgrid[j])}

    attrs = {
        "title": "GPRM mean signals (gprm preprocess)",
        "source": src, "sample_rate": float(campaign.attrs.get("sample_rate", 1.0 / dt)),
        "campaign_sha256": str(campaign.attrs.get("campaign_sha256", "")),
        **preprocess_attrs(cfg),
        "gprm_version": gprm.__version__,
        # the record's length (the parametric bootstrap synthesises campaigns like this one)
        "record_duration": float(time[-1] - time[0] + dt),
    }
    generator = read_generator(campaign.attrs)
    if generator is not None:
        attrs.update(generator_attrs(generator))
    truth_shift = truth_mean = None
    truth = read_truth(campaign)
    if truth is not None:
        attrs["truth_source"] = str(campaign.attrs.get("truth_source", "synthetic campaign"))
        attrs["seed"] = int(campaign.attrs.get("seed", -1))
    truth_spread = None
    if "truth_displacement" in campaign.variables:
        tt = np.asarray(campaign["truth_time"].values, float)
        clean = np.asarray(campaign["truth_displacement"].sel(position=list(POSITIONS)).values,
                           float)
        offs = (np.asarray(campaign["trigger_offset"].sel(position=list(POSITIONS)).values)
                if "trigger_offset" in campaign.variables else np.zeros((P, R)))
        truth_shift = truth_axis_shift(shift, offs, sync)
        truth_spread = np.empty(P)
        truth_mean = np.empty_like(mean)
        for i in range(P):
            cs = CubicSpline(tt, clean[i])
            thr = cfg.threshold_factor * nstd[i]
            # the rule's inherent jitter: its crossing on the truth over ten sampling phases
            crossings = [_sampled_crossing(cs, time, ph * dt / 10, thr, cfg.hold)
                         for ph in range(10)]
            phases = [x for x in crossings if x is not None]
            truth_spread[i] = float(np.ptp(phases)) if phases else np.nan
            ts_ = tgrid - truth_shift[i]
            truth_mean[i] = np.where(ts_ < tt[0], 0.0, cs(np.clip(ts_, tt[0], tt[-1])))
    alignment = None
    if truth is not None and truth_shift is not None:
        alignment = truth_alignment(truth, dict(zip(POSITIONS, truth_shift)))
    return MeanSignals(POSITIONS, tgrid, mean, std, sem, nstd, shift,
                       np.full(P, R), sync, ref, table1, dropped, snr, attrs,
                       truth_shift, truth_mean, truth_spread, tuple(no_cross), truth, alignment,
                       runs=runs, interpolation_error=interp_err, sync_remainder=remainder,
                       sync_timing_sd=np.array([per[n]["sync_timing_sd"] for n in POSITIONS]),
                       baseline=np.array([per[n]["baseline"] for n in POSITIONS]) + shift[:, None],
                       noise_acov=np.array([per[n]["noise_acov"] for n in POSITIONS]),
                       crossing_time=cfg.align_time + np.where(
                           [n in no_cross for n in POSITIONS], 0.0, rounding))
