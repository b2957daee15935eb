"""Impact time per release and axis: first crossing of the measured release velocity with the
predicted velocity-vs-impact-time curve (Section 4.1, Fig. 11b-c).

Error bar (linear propagation at the crossing t*): the measured velocity's standard error s_m
and the curve's band σ_c(t*) are independent, and both move the crossing by their size over
the local slope of the curve, so σ_t = sqrt(s_m² + σ_c(t*)²) / |dv/dt(t*)|.
A release/axis without a crossing gets ``value = None`` with a reason.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class ImpactTime:
    value: float | None
    stderr: float | None
    slope: float | None = None
    sigma_curve: float | None = None
    reason: str | None = None

    def to_json(self) -> dict:
        d: dict[str, Any] = {"value": self.value, "stderr": self.stderr}
        if self.value is not None:
            d["slope"] = self.slope
            d["sigma_curve"] = self.sigma_curve
        if self.reason is not None:
            d["reason"] = self.reason
        return d


def first_crossing(time, curve, sigma, v_meas: float, s_meas: float) -> ImpactTime:
    """First time the curve (T,) crosses the measured velocity ``v_meas`` (± ``s_meas``).

    The crossing is searched between consecutive grid points where the curve is defined
    (an exact touch of a grid point counts); t* by linear interpolation, slope from the
    bracketing points, σ_c interpolated (NaN σ_c counts as 0 and is flagged by the reason
    field staying empty only when finite).
    """
    t = np.asarray(time, float)
    c = np.asarray(curve, float)
    s = np.asarray(sigma, float)
    fin = np.isfinite(c)
    if not fin.any():
        return ImpactTime(None, None, reason="no impact possible in the window (the contact "
                                             "point never approaches the indent face)")
    d = c - v_meas
    ok = fin[:-1] & fin[1:]
    touch = fin & (d == 0)
    cross = ok & (np.sign(d[:-1]) * np.sign(d[1:]) < 0)
    cand = np.flatnonzero(cross | touch[:-1])
    if touch[-1]:
        cand = np.append(cand, t.size - 1)
    if cand.size == 0:
        lo, hi = float(np.nanmin(c)), float(np.nanmax(c))
        where = "above" if v_meas > hi else ("below" if v_meas < lo else "between pieces of")
        return ImpactTime(None, None, reason=f"no crossing: measured {v_meas:.6g} is {where} "
                                             f"the predicted range [{lo:.6g}, {hi:.6g}]")
    i = int(cand[0])
    if touch[i] and (i == t.size - 1 or not ok[i]):
        j0, j1 = (i - 1, i) if i > 0 and fin[i - 1] else (i, i + 1)
        ts = t[i]
    else:
        j0, j1 = i, i + 1
        ts = t[i] + d[i] / (d[i] - d[i + 1]) * (t[i + 1] - t[i]) if d[i] != 0 else t[i]
    if j1 >= t.size or not (fin[j0] and fin[j1]):
        return ImpactTime(float(ts), None, reason="crossing at an isolated point: slope unknown")
    slope = (c[j1] - c[j0]) / (t[j1] - t[j0])
    w = 0.0 if t[j1] == t[j0] else (ts - t[j0]) / (t[j1] - t[j0])
    sc = (1 - w) * s[j0] + w * s[j1]
    sc = 0.0 if not np.isfinite(sc) else float(sc)
    if slope == 0:
        return ImpactTime(float(ts), None, 0.0, sc, reason="zero slope at the crossing")
    st = float(np.sqrt(s_meas ** 2 + sc ** 2) / abs(slope))
    return ImpactTime(float(ts), st, float(slope), sc)


# --------------------------------------------------------------------------------------------
# rising-branch crossings and their spread over the model's draws (issue 14)
# --------------------------------------------------------------------------------------------
def rising_branch(curves) -> np.ndarray:
    """Mask (..., T) of each curve's first rising branch: the first contiguous run of finite
    values, up to and including the peak of |curve| in it. An impact on this branch is
    identified by its velocity; beyond the peak the same velocity occurs twice."""
    c = np.atleast_2d(np.asarray(curves, float))
    fin = np.isfinite(c)
    T = c.shape[-1]
    idx = np.arange(T)
    any_fin = fin.any(-1)
    i0 = np.argmax(fin, -1)
    after = fin | (idx < i0[:, None])           # first gap after i0 ends the run
    i1 = np.where(after.all(-1), T, np.argmin(after, -1))
    run = (idx >= i0[:, None]) & (idx < i1[:, None]) & any_fin[:, None]
    ipk = np.argmax(np.where(run, np.abs(np.nan_to_num(c)), -1.0), -1)
    return run & (idx <= ipk[:, None])


def branch_crossings(time, curves, v, *, with_slope: bool = False):
    """First crossing time of ``v`` (scalar or (N,)) on each curve's rising branch
    (curves (N, T)), linear interpolation; NaN where the branch does not reach ``v``.
    ``with_slope``: also return the curve's slope over the bracketing interval (N,)."""
    t = np.asarray(time, float)
    c = np.atleast_2d(np.asarray(curves, float))
    v = np.broadcast_to(np.asarray(v, float), c.shape[:1])
    br = rising_branch(c)
    d = np.where(br, c - v[:, None], np.nan)
    s0, s1 = np.sign(d[:, :-1]), np.sign(d[:, 1:])
    ok = np.isfinite(d[:, :-1]) & np.isfinite(d[:, 1:])
    cross = ok & ((s0 * s1 < 0) | (s0 == 0))
    has = cross.any(-1)
    i = np.argmax(cross, -1)
    r = np.arange(c.shape[0])
    d0, d1 = d[r, i], d[r, np.minimum(i + 1, t.size - 1)]
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(d0 == 0, 0.0, d0 / (d0 - d1))
    j = np.minimum(i + 1, t.size - 1)
    ts = t[i] + frac * (t[j] - t[i])
    ts = np.where(has, ts, np.nan)
    if not with_slope:
        return ts
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = np.where(has & (j > i), (d1 - d0) / (t[j] - t[i]), np.nan)
    return ts, slope


def draw_weights(slopes) -> np.ndarray:
    """Weights of the draws' crossing times: 1/|dv/dt| at the crossing (normalised).

    With a flat prior on the impact time, a draw's curve produces the measured velocity with a
    density in t proportional to 1/|dv/dt| at its crossing (change of variables v -> t): where
    the curve is flat, a wider span of impact times gives the same velocity. Slopes below a
    tenth of the median are floored there (the peak of a rising branch has zero slope).
    ``slopes`` (n,) or (n, A) (several axes: geometric mean over the axes); NaN -> weight 0.
    """
    a = np.abs(np.asarray(slopes, float))
    a2 = a if a.ndim == 2 else a[:, None]
    med = np.nanmedian(a2, axis=0) if np.isfinite(a2).any() else np.ones(a2.shape[1])
    with np.errstate(invalid="ignore", divide="ignore"):
        w = med / np.maximum(a2, 0.1 * med)
        w = np.exp(np.nanmean(np.log(w), axis=1)) if w.shape[1] > 1 else w[:, 0]
    w = np.where(np.isfinite(w), w, 0.0)
    tot = w.sum()
    return w / tot if tot > 0 else w


@dataclass(frozen=True)
class ImpactTimeMC:
    """An impact time with its spread over the model's joint draws.

    ``value`` the crossing of the nominal curve's rising branch (the paper's rule, restricted to
    the branch where the velocity identifies the time), or, where the measured velocity lies
    beyond the nominal peak, the median crossing of the draws that reach it; ``stderr`` the
    root-mean-square of (draw crossing − value) over the draws that cross, weighted by
    :func:`draw_weights` (each draw is a possible true curve, so this is the error of
    ``value`` from the model band and the measurement together); ``draws`` (n,) the draws'
    crossing times (NaN: the draw does not reach the measured velocity) and ``draw_slopes``
    their slopes, kept for the joint estimate.
    """

    value: float | None
    stderr: float | None
    method: str | None
    n_cross: int
    n_draws: int
    stderr_linear: float | None
    reason: str | None
    draws: np.ndarray
    draw_slopes: np.ndarray | None = None

    def to_json(self) -> dict:
        d: dict[str, Any] = {"value": self.value, "stderr": self.stderr}
        if self.value is not None:
            d.update(method=self.method, stderr_linear=self.stderr_linear,
                     draws_crossing=self.n_cross, draws=self.n_draws)
        if self.reason is not None:
            d["reason"] = self.reason
        return d


def impact_time_mc(time, nominal, sigma, samples, v_meas: float, s_meas: float, *,
                   seed: int = 0, min_fraction: float = 0.1) -> ImpactTimeMC:
    """Impact time of one release and axis from the nominal curve and the joint draws.

    Each draw k (one parameter set and impact geometry from the model's uncertainty) is a
    possible true curve; with the measured velocity v (+ its noise, s_m z_k) it gives the
    impact time t_k at which that curve would have produced v. The estimate is the nominal
    crossing (or the draws' weighted median where v is beyond the nominal peak), the error bar
    the weighted rms of t_k about it (weights 1/|dv/dt| at t_k, :func:`draw_weights`).
    Missing (``value`` None, with a reason) where fewer than ``min_fraction`` of the draws
    reach v or the nominal curve has no rising branch.
    """
    t = np.asarray(time, float)
    c = np.asarray(nominal, float)
    S = np.atleast_2d(np.asarray(samples, float))
    n = S.shape[0]
    rng = np.random.default_rng(seed)
    vk = v_meas + (s_meas if np.isfinite(s_meas) else 0.0) * rng.standard_normal(n)
    tk, sk = branch_crossings(t, S, vk, with_slope=True)
    ncross = int(np.isfinite(tk).sum())
    lin = first_crossing(t, np.where(rising_branch(c)[0], c, np.nan), sigma, v_meas, s_meas)
    if not np.isfinite(c).any():
        return ImpactTimeMC(None, None, None, ncross, n, None,
                            "no impact possible in the window (the contact point never "
                            "approaches the indent face)", tk, sk)
    if ncross < max(2, int(np.ceil(min_fraction * n))):
        br = np.where(rising_branch(c)[0], c, np.nan)
        pk = float(np.nanmax(np.abs(br)))
        return ImpactTimeMC(None, None, None, ncross, n, None,
                            f"no crossing: |measured| {abs(v_meas):.6g} vs the nominal "
                            f"peak {pk:.6g} of the rising branch; only {ncross} of {n} model "
                            "draws reach it", tk, sk)
    w = draw_weights(sk)
    fin = np.isfinite(tk)
    if lin.value is not None:
        value, method = float(lin.value), "nominal crossing"
    else:
        value, method = (_weighted_quantile(tk[fin], w[fin], 0.5),
                         "weighted median of the draws (beyond the nominal peak)")
    st = float(np.sqrt(np.sum(w[fin] * (tk[fin] - value) ** 2)))
    return ImpactTimeMC(value, st, method, ncross, n, lin.stderr, None, tk, sk)


def _weighted_quantile(x, w, q) -> float:
    """Quantile ``q`` of values ``x`` with weights ``w`` (step function of the sorted x)."""
    o = np.argsort(x)
    cw = np.cumsum(w[o])
    return float(x[o][min(int(np.searchsorted(cw, q * cw[-1])), x.size - 1)])
