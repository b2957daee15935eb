"""One impact time per release from all axes together (issue 14, beyond the paper).

The per-axis impact times t_a of a release (:func:`gprm.flight.impact_time.impact_time_mc`)
estimate the same instant. Their errors are correlated: one model draw (parameters and impact
geometry) moves every axis' crossing, so the covariance Σ between axes is estimated from the
draws' crossing times t_{k,a} (the same joint draws for all axes). The joint estimate is the
generalised least-squares mean restricted to non-negative weights

    t_J = wᵀ t,  w = argmin wᵀ Σ w  subject to  Σ_a w_a = 1, w >= 0,   σ_J² = wᵀ Σ w

(without the restriction this is the GLS mean (1ᵀ Σ⁻¹ t) / (1ᵀ Σ⁻¹ 1); see
:func:`_nonnegative_gls_weights` for why it is restricted)
with its 95 % interval (below), and the consistency statistic
χ² = (t − t_J 1)ᵀ Σ⁻¹ (t − t_J 1) with A − 1 degrees of freedom (A axes used), the second
consistency check next to the paper's Tukey test.

Σ: the correlation matrix of the draws that cross on every used axis, scaled by each axis'
own error bar (which includes the nominal estimate's offset from the draws' mean). The 95 %
interval is t_J plus the weighted 2.5 and 97.5 % points of the draws' combined crossing
times wᵀ t_k about their weighted median (weights 1/|dv/dt|,
:func:`gprm.flight.impact_time.draw_weights`); with too few common draws it is
t_J ± 1.96 σ_J. Axes observing the same quantity with
the same curve (both v_z axes of the one-contact 3D model) are used once.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.stats import chi2 as chi2_dist

from gprm.flight.impact_time import _weighted_quantile, draw_weights

Z95 = 1.959963984540054


@dataclass(frozen=True)
class JointEstimate:
    value: float | None
    stderr: float | None
    ci95: tuple[float, float] | None
    chi2: float | None
    df: int | None
    p: float | None
    axes: tuple[str, ...]
    weights: tuple[float, ...]
    n_draws: int
    reason: str | None = None

    def to_json(self) -> dict:
        d: dict[str, Any] = {"value": self.value, "stderr": self.stderr,
             "ci95": list(self.ci95) if self.ci95 is not None else None,
             "chi2": self.chi2, "df": self.df, "p": self.p, "axes": list(self.axes),
             "weights": list(self.weights), "draws_used": self.n_draws}
        if self.reason is not None:
            d["reason"] = self.reason
        return d


def _nonnegative_gls_weights(Sig) -> np.ndarray:
    """Minimum-variance weights w (Σ w = 1) of correlated estimates, restricted to w >= 0:
    GLS on an active set, dropping the most negative weight until none is left. Without the
    restriction, nearly collinear axes get large weights of opposite signs, and the estimate
    extrapolates along a direction the finite set of draws pins down too tightly."""
    A = Sig.shape[0]
    act = list(range(A))
    while True:
        S = Sig[np.ix_(act, act)]
        x = np.linalg.lstsq(S, np.ones(len(act)), rcond=None)[0]
        w = x / x.sum() if x.sum() != 0 else np.full(len(act), 1.0 / len(act))
        if np.all(w >= 0) or len(act) == 1:
            out = np.zeros(A)
            out[act] = w
            return out
        del act[int(np.argmin(w))]


def joint_impact_time(times: dict, stderrs: dict, draws: dict, slopes: dict | None = None, *,
                      min_draws: int = 20) -> JointEstimate:
    """GLS combination of the per-axis impact times ``times`` {axis: t} with error bars
    ``stderrs`` and draws' crossing times ``draws`` {axis: (n,)} (see the module docstring).
    """

    axes = tuple(a for a in times if times[a] is not None and stderrs.get(a) is not None
                 and stderrs[a] > 0)
    if not axes:
        reason = ("no axis with an impact time" if all(v is None for v in times.values())
                  else "no axis with a positive error bar (the model has no spread)")
        return JointEstimate(None, None, None, None, None, None, (), (), 0, reason)
    t = np.array([times[a] for a in axes], float)
    s = np.array([stderrs[a] for a in axes], float)
    D = np.stack([np.asarray(draws[a], float) for a in axes], 1)      # (n, A)
    full = np.all(np.isfinite(D), 1)
    A = len(axes)
    if A == 1:
        return JointEstimate(float(t[0]), float(s[0]), (float(t[0] - Z95 * s[0]),
                             float(t[0] + Z95 * s[0])), None, 0, None, axes, (1.0,),
                             int(full.sum()))
    if full.sum() >= max(min_draws, A + 2):
        R = np.corrcoef(D[full].T)
        R = np.where(np.isfinite(R), R, 0.0)
        np.fill_diagonal(R, 1.0)
    else:   # too few common draws: independent axes (said in the reason)
        R = np.eye(A)
    Sig = R * np.outer(s, s)
    # eigen-floor for χ²: the draws' covariance is nearly singular (a few physical sources
    # move all axes together) and its smallest eigenvalues are poorly determined by a finite
    # set of draws; 1e-3 of the largest keeps the χ² test's size near nominal on synthetic
    # campaigns (docs/flight.md §5a, §9: seeds 100-119 to choose, 1000-1099 to check)
    lam, V = np.linalg.eigh(Sig)
    lam = np.maximum(lam, 1e-3 * lam.max())
    Si = (V / lam) @ V.T
    w = _nonnegative_gls_weights(Sig)
    tJ = float(w @ t)
    sJ = float(np.sqrt(w @ Sig @ w))
    r = t - tJ
    chi2 = float(r @ Si @ r)
    df = A - 1
    ci = (tJ - Z95 * sJ, tJ + Z95 * sJ)
    if full.sum() >= max(min_draws, A + 2):
        # the draws' own combined crossing times: each draw is a possible true curve, so
        # their weighted 2.5-97.5 % spread about their median, placed about t_J, is the
        # interval (no Gaussian tail assumption). Centred, because the draws that reach the
        # measured velocity on every axis are biased to large amplitudes and early times
        # (a draw just reaching it near its peak rarely does so on all axes at once)

        tk = D[full] @ w
        wk = (np.full(tk.size, 1.0 / tk.size) if slopes is None else
              draw_weights(np.stack([np.asarray(slopes[a], float) for a in axes], 1)[full]))
        lo, med, hi = (_weighted_quantile(tk, wk, q) for q in (0.025, 0.5, 0.975))
        ci = (tJ - (med - lo), tJ + (hi - med))
    return JointEstimate(tJ, sJ, ci, chi2, df,
                         float(chi2_dist.sf(chi2, df)), axes, tuple(map(float, w)),
                         int(full.sum()),
                         None if full.sum() >= max(min_draws, A + 2)
                         else "too few draws cross on every axis: axes taken as independent")
