"""Release telemetry: what a release is (:class:`Release`, :class:`Telemetry`) and its release
velocities (Fig. 11a). The telemetry file (NetCDF and CSV) is read and written in
:mod:`gprm.flight.files` (format ``gprm-telemetry``; docs/flight.md).

The release velocity per axis is the slope of a weighted straight line through the samples
after the release time (within ``fit_window`` seconds if given) with its standard error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gprm.errors import GprmInputError

AXES: tuple[str, ...] = ("vx", "vz_xz", "wy", "vy", "vz_yz", "wx")
"""The six velocity components (docs/spec.md): x–z plane (v_x, v_z, ω_y), y–z plane
(v_y, v_z, ω_x)."""

AXIS_CHANNEL = {"vx": "x", "vz_xz": "z", "wy": "eta", "vy": "y", "vz_yz": "z", "wx": "theta"}
"""Telemetry channel whose slope gives each axis' velocity."""

AXIS_UNIT = {"vx": "m s-1", "vz_xz": "m s-1", "wy": "rad s-1", "vy": "m s-1", "vz_yz": "m s-1",
             "wx": "rad s-1"}
"""UDUNITS unit of each axis' velocity (SI)."""
LINEAR_AXES: tuple[str, ...] = tuple(a for a in AXES if AXIS_UNIT[a] == "m s-1")
ANGULAR_AXES: tuple[str, ...] = tuple(a for a in AXES if AXIS_UNIT[a] == "rad s-1")
CHANNELS = ("x", "y", "z", "theta", "eta", "phi")
CHANNEL_UNIT = {"x": "m", "y": "m", "z": "m", "theta": "rad", "eta": "rad", "phi": "rad"}
REQUIRED = ("x", "y", "z", "theta", "eta")
CHANNEL_KIND = {"x": "length", "y": "length", "z": "length", "theta": "angle",
                "eta": "angle", "phi": "angle"}


@dataclass(frozen=True)
class Release:
    """One release: its samples (padding removed), in SI."""

    id: str
    release_time: float
    time: np.ndarray                 # (T,)
    data: dict                       # channel -> (T,)
    sigma: dict                      # channel -> (T,) or None (unknown, use residuals)


@dataclass(frozen=True)
class Telemetry:
    releases: tuple[Release, ...]
    source: str
    attrs: dict
    truth_impact_time: np.ndarray | None = None   # (R,) synthetic only
    truth_velocity: np.ndarray | None = None      # (R, 6) synthetic only
    truth_scenario: dict | None = None            # synthetic scenario truths (issue 23)


@dataclass(frozen=True)
class LineFit:
    """Slope (velocity) of the line through a release's post-release samples."""

    value: float
    stderr: float
    intercept: float
    n: int
    reduced_chi2: float
    weighted: bool


def fit_release_velocity(t, y, sigma=None, *, t_release: float = 0.0) -> LineFit:
    """Weighted least-squares line y = a + v (t − t_release); returns v and its stderr.

    With ``sigma`` (per-sample std, or scalar) the weights are 1/σ² and the stderr is the
    formal one, sqrt((XᵀWX)⁻¹)₁₁; without, equal weights and the stderr scaled by the residual
    scatter (σ̂² = RSS/(n − 2)).
    """
    t = np.asarray(t, float) - t_release
    y = np.asarray(y, float)
    n = t.size
    weighted = sigma is not None
    w = (np.ones(n) if sigma is None
         else 1.0 / np.broadcast_to(np.asarray(sigma, float), (n,)) ** 2)
    X = np.stack([np.ones(n), t], axis=1)
    A = X.T @ (w[:, None] * X)
    b = X.T @ (w * y)
    cov = np.linalg.inv(A)
    coef = cov @ b
    res = y - X @ coef
    chi2 = float(np.sum(w * res ** 2))
    dof = max(n - 2, 1)
    if not weighted:
        cov = cov * chi2 / dof
    return LineFit(float(coef[1]), float(np.sqrt(cov[1, 1])), float(coef[0]), n, chi2 / dof,
                   weighted)


def release_velocities(tel: Telemetry, *, fit_window: float | None = None,
                       min_samples: int = 5) -> dict[str, dict[str, LineFit]]:
    """Release velocity per release and axis (Fig. 11a): ``{release id: {axis: LineFit}}``.

    Uses the samples with release_time < t (<= release_time + fit_window). Fewer than
    ``min_samples`` such samples is an input error naming the release and channel.
    """
    out = {}
    for r in tel.releases:
        sel = r.time > r.release_time
        if fit_window is not None:
            sel &= r.time <= r.release_time + fit_window
        n = int(sel.sum())
        if n < min_samples:
            raise GprmInputError(f"release {r.id}: {n} samples after the release time "
                                 f"{r.release_time:g} s (need >= {min_samples})",
                                 source=tel.source, field="time")
        fits = {}
        for ax in AXES:
            c = AXIS_CHANNEL[ax]
            s = r.sigma[c]
            fits[ax] = fit_release_velocity(r.time[sel], r.data[c][sel],
                                            None if s is None else s[sel],
                                            t_release=r.release_time)
        out[r.id] = fits
    return out
