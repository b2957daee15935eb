"""The identification's weak prior (a documented regulariser, issue 12).

The five measured signals do not determine every Table 3 parameter (docs/fitting.md,
"Identifiability"): two lateral springs at b1 and b1 + b2 act on the plunger only through
their sum and their first and second moments, so (k_Cy, k_Dy, b1, b2) has a direction the
data cannot see, and the x plane likewise. Without a prior the best fit slides along such a
valley to a corner (k_Dy -> 0 with b2 at 10 cm) and J^T J is singular there. The prior adds
one residual row per fitted parameter,

    positive parameters (physical lower bound 0):  r_k = (ln x_k - ln c_k) / w
    signed parameters (angles, offsets, lags):     r_k = (x_k - c_k) / (w * max(|c_k|, f_k))

with c the paper's initial values (Table 3; the centre of the random starts, i.e. what the
user already assumes), w the width (default 1.25: a factor 3.5 at one standard deviation, 11.6
at two) and f_k a floor by dimension (20 mrad, 2 mm, 10 us) for centres near zero. It is weak:
where the data determine a parameter they outweigh it by orders of magnitude; where they do
not, it alone fixes the value and the reported interval is the prior's (the parameter is then
reported as not determined, never with a small error).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gprm.params import REGISTRY, ParameterSet

#: default prior width (log units for positive parameters; relative for signed ones)
DEFAULT_WIDTH = 1.25

_FLOOR = {"rad": 0.02, "mrad": 0.02, "mm": 2e-3, "m": 2e-3, "us": 10e-6, "s": 10e-6}


@dataclass(frozen=True)
class Prior:
    """Independent prior on the fitted parameters (SI), in the coordinates u of the fit's
    uncertainty: u = ln x where ``log`` is set, else u = x.

    centre: (P,) c_k, SI.  sd: (P,) prior standard deviation of u_k.  log: (P,) bool.
    weight: multiplies the residual rows (the square root of the data's variance scale, so
    that chi2 / s2 + sum r_prior^2 is the negative log posterior up to a constant).
    """

    names: tuple[str, ...]
    centre: np.ndarray
    sd: np.ndarray
    log: np.ndarray
    weight: float = 1.0

    def to_u(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.log, np.log(np.where(self.log, np.maximum(X, 1e-300), 1.0)), X)

    def from_u(self, U: np.ndarray) -> np.ndarray:
        U = np.asarray(U, float)
        return np.where(self.log, np.exp(np.where(self.log, U, 0.0)), U)

    def dx_du(self, X: np.ndarray) -> np.ndarray:
        """dx/du (diagonal), SI."""
        return np.where(self.log, np.asarray(X, float), 1.0)

    def residuals(self, X: np.ndarray) -> np.ndarray:
        """Prior rows (B, P) for physical rows X (B, P)."""
        return self.weight * (self.to_u(X) - self.to_u(self.centre)) / self.sd

    def jacobian(self, X: np.ndarray) -> np.ndarray:
        """d rows / d x (B, P), diagonal entries (the rows are separable)."""
        X = np.asarray(X, float)
        with np.errstate(divide="ignore"):
            du_dx = np.where(self.log, 1.0 / np.maximum(X, 1e-300), 1.0)
        return self.weight * du_dx / self.sd

    def with_weight(self, weight: float) -> "Prior":
        return Prior(self.names, self.centre, self.sd, self.log, float(weight))

    def interval(self, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
        """The prior's own central interval (SI): what is reported for a parameter the data
        do not determine."""
        from scipy.stats import norm

        z = norm.ppf(0.5 + level / 2)
        c = self.to_u(self.centre)
        return self.from_u(c - z * self.sd), self.from_u(c + z * self.sd)


def default_prior(base: ParameterSet, names, width: float = DEFAULT_WIDTH) -> Prior:
    """The documented default prior of the module docstring for ``names``."""
    names = tuple(names)
    if not (np.isfinite(width) and width > 0):
        raise ValueError(f"prior width must be > 0, got {width}")
    centre = base.initial_vector(names)
    lower = np.array([base.bounds.get(n, (REGISTRY[n].lower, REGISTRY[n].upper))[0]
                      for n in names])
    log = (lower == 0.0) & (centre > 0)
    floor = np.array([_FLOOR.get(REGISTRY[n].unit, 0.0) for n in names])
    scale = np.maximum(np.abs(centre), floor)
    scale = np.where(scale > 0, scale, 1.0)
    sd = np.where(log, width, width * scale)
    return Prior(names, centre, sd, log)
