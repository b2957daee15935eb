"""Impact risk against an available plunger-test-mass gap (the paper's stated next step, end of
Sec. 4.2).

Model (docs/prediction.md): the contact point P (M_xz in the x-z plane, M_yz in the y-z plane)
closes the gap when it moves along the unit closing direction n, the normal of the indent face
it faces, at ``indent_angle`` (alpha) to the z axis in its plane:
n_xz = (sin alpha, 0, cos alpha), n_yz = (0, sin alpha, cos alpha). With d(t) the displacement
of P from its initial position and g the available gap along n,

    clearance c(t) = g - n . d(t),   min clearance = min over the window of c(t),

and the contact point crosses the gap when min clearance < 0. With g ~ N(g0, sg^2) independent
of the parameters and parameter sets theta_s drawn from the fit covariance,

    P(cross) = mean_s Phi((max_t n . d_s(t) - g0) / sg)      (sg > 0; the indicator if sg = 0),

a Monte Carlo average over the parameter draws with the gap integrated exactly; its standard
error is the std of the terms / sqrt(S).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

from gprm.errors import GprmInputError
from gprm.fit.files import FittedModel
from gprm.params import batch
from gprm.predict.trajectories import default_times, sampled_points

CONTACTS: dict[str, str] = {"xz": "M_xz", "yz": "M_yz"}


def closing_direction(plane: str, angle: float) -> np.ndarray:
    """Unit vector n along which the contact point closes the gap (module docstring)."""
    if plane == "xz":
        return np.array([np.sin(angle), 0.0, np.cos(angle)])
    if plane == "yz":
        return np.array([0.0, np.sin(angle), np.cos(angle)])
    raise GprmInputError(f"must be xz or yz, got {plane!r}", field="plane")


@dataclass(frozen=True)
class ImpactRisk:
    """Per plane (``planes``): clearance over time and crossing probability.

    clearance (plane, T) best fit; clearance_lo/hi (plane, T) 2.5/97.5 % over parameter draws
    (gap at its nominal value); min_clearance (plane,) best fit; min_clearance_lo/hi;
    p_cross (plane,), p_cross_se (plane,); t_first_cross (plane,) best fit (NaN if none)."""

    time: np.ndarray
    planes: tuple[str, ...]
    gap: float
    gap_std: float
    angle: float
    clearance: np.ndarray
    clearance_lo: np.ndarray
    clearance_hi: np.ndarray
    min_clearance: np.ndarray
    min_clearance_lo: np.ndarray
    min_clearance_hi: np.ndarray
    p_cross: np.ndarray
    p_cross_se: np.ndarray
    t_first_cross: np.ndarray
    n_samples: int
    n_ok: int

    def to_json(self) -> dict:
        return {
            "gap_m": self.gap, "gap_std_m": self.gap_std, "indent_angle_rad": self.angle,
            "window_s": [float(self.time[0]), float(self.time[-1])],
            "samples": self.n_samples, "samples_ok": self.n_ok,
            "planes": {p: {"contact_point": CONTACTS[p],
                           "min_clearance_m": float(self.min_clearance[i]),
                           "min_clearance_p2_5_m": float(self.min_clearance_lo[i]),
                           "min_clearance_p97_5_m": float(self.min_clearance_hi[i]),
                           "p_cross": float(self.p_cross[i]),
                           "p_cross_se": float(self.p_cross_se[i]),
                           "t_first_cross_s": (None if not np.isfinite(self.t_first_cross[i])
                                               else float(self.t_first_cross[i]))}
                       for i, p in enumerate(self.planes)}}


def impact_risk(fm: FittedModel, gap: float, gap_std: float = 0.0, *, times=None,
                piezo: int = 2, samples: int = 500, seed: int = 0, angle: float | None = None,
                voltage=None) -> ImpactRisk:
    """Minimum clearance and crossing probability of M_xz (x-z) and M_yz (y-z)."""

    if not (np.isfinite(gap) and gap > 0):
        raise GprmInputError(f"must be a finite gap > 0, got {gap:g} m", field="gap")
    if not (np.isfinite(gap_std) and gap_std >= 0):
        raise GprmInputError(f"must be finite and >= 0, got {gap_std:g} m", field="gap_std")
    t = default_times() if times is None else np.asarray(times, float)
    ang = float(fm.params["indent_angle"] if angle is None else angle)
    planes = tuple(CONTACTS)
    pts = tuple(CONTACTS[p] for p in planes)
    n = np.stack([closing_direction(p, ang) for p in planes])            # (plane, 3)
    best, _, ok0 = sampled_points(batch([fm.params]), t, pts, piezo=piezo, voltage=voltage)
    if not ok0[0]:
        raise GprmInputError("the best-fit set cannot be simulated", field="parameters")
    close0 = np.einsum("pa,pat->pt", n, best[0])                         # (plane, T)
    clear0 = gap - close0
    first = np.full(len(planes), np.nan)
    for i in range(len(planes)):
        hit = np.flatnonzero(clear0[i] < 0)
        if hit.size:
            first[i] = t[hit[0]]
    nan = np.full(len(planes), np.nan)
    clo = chi = np.full_like(clear0, np.nan)
    mlo, mhi, pc, pse = nan, nan, nan, nan
    n_ok = 0
    if samples > 0:
        sp, _, ok = sampled_points(fm.sample(samples, seed), t, pts, piezo=piezo,
                                   voltage=voltage)
        sp = sp[ok]
        n_ok = int(ok.sum())
        if n_ok:
            close = np.einsum("pa,spat->spt", n, sp)                     # (S, plane, T)
            clear = gap - close
            clo, chi = np.quantile(clear, [0.025, 0.975], axis=0)
            mins = clear.min(axis=-1)
            mlo, mhi = np.quantile(mins, [0.025, 0.975], axis=0)
            peak = close.max(axis=-1)                                    # (S, plane)
            if gap_std > 0:
                terms = ndtr((peak - gap) / gap_std)
            else:
                terms = (peak > gap).astype(float)
            pc = terms.mean(axis=0)
            pse = terms.std(axis=0, ddof=1) / np.sqrt(n_ok) if n_ok > 1 else nan
    return ImpactRisk(time=t, planes=planes, gap=float(gap), gap_std=float(gap_std), angle=ang,
                      clearance=clear0, clearance_lo=clo, clearance_hi=chi,
                      min_clearance=clear0.min(axis=-1), min_clearance_lo=mlo,
                      min_clearance_hi=mhi, p_cross=pc, p_cross_se=pse, t_first_cross=first,
                      n_samples=int(samples), n_ok=n_ok)
