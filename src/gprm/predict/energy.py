"""Kinetic-energy check (paper Sec. 3, Fig. 8): histograms of the time the kinetic energy
spends in each energy bin, from the model (with error bars from the parameter uncertainty) and
from the measured mean signals (with error bars from their standard error).

Two energies (docs/prediction.md gives the formulas):

- ``model_total``: the model's full kinetic energy, every body (m1; m2 with J2; m3; m4),
  exact velocities (:func:`gprm.simulate.kinematics.kinetic_energy`);
- ``point_energy``: the energy that can be formed from the five measured points
  (x_base, x_head, y_base, y_head, z_bk), Eq. ``E_5`` of the docs. It is applied in the same way
  (same time grid, same differentiation) to the measured mean signals and to the model's
  simulated measured points, which is the like-for-like comparison.

Histogram weights: the window's samples t_0..t_N carry trapezoid weights (dt/2 at both ends,
dt inside), so the histogram of each energy record sums to the window length t_N - t_0.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from gprm.errors import GprmInputError
from gprm.fit.files import FittedModel
from gprm.params import batch
from gprm.simulate.core import observe
from gprm.simulate.kinematics import body_motion, kinetic_energy

FIVE: tuple[str, ...] = ("x_base", "x_head", "y_base", "y_head", "z_bk")
DEFAULT_WINDOW: tuple[float, float] = (0.97e-3, 1.2e-3)


def differentiate(x: np.ndarray, times: np.ndarray) -> np.ndarray:
    """d/dt along the last axis: second-order central differences inside, one-sided
    second-order at the ends (``numpy.gradient`` with ``edge_order=2``)."""
    return np.gradient(x, times, axis=-1, edge_order=2)


def derivative_std(sigma: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Std of :func:`differentiate` for independent errors of std ``sigma`` at each sample.

    The derivative is linear with a three-point stencil, whose three points have distinct
    indices mod 3; differentiating ``sigma`` restricted to each residue class gives each
    stencil term D_kj sigma_j separately, so var_k = sum_r (D (sigma * [j = r mod 3]))_k^2
    exactly, on any (also non-uniform) grid."""
    s = np.asarray(sigma, float)
    idx = np.arange(s.shape[-1])
    var = np.zeros_like(s)
    for r in range(3):
        var += differentiate(np.where(idx % 3 == r, s, 0.0), times) ** 2
    return np.sqrt(var)


def point_energy(rates: Mapping[str, np.ndarray], pb: Mapping[str, np.ndarray]) -> np.ndarray:
    """E_5 (..., T) from the rates of the five measured points (docs/prediction.md).

    eta' = (x_head' - x_base') / (d_x_head - d_x_base), x_A' = x_base' - d_x_base eta';
    theta' = -(y_head' - y_base') / (d_y_head - d_y_base), y_A' = y_base' + d_y_base theta';
    an axis point at distance s from A moves laterally with (x_A' + s eta', y_A' - s theta');
    E_5 = 1/2 sum_i m_i [(x_A' + s_i eta')^2 + (y_A' - s_i theta')^2 + z_bk'^2]
          + 1/2 J2 (eta'^2 + theta'^2),  i = plunger (s = h2), spacer (h3), tip (h3 + h4).
    ``pb`` values are scalars or (B,) (broadcast against the leading axis of the rates)."""
    def p(n):
        v = np.asarray(pb[n], float)
        return v.reshape(v.shape + (1,) * (np.ndim(rates["x_base"]) - v.ndim)) if v.ndim else v

    eta = (rates["x_head"] - rates["x_base"]) / (p("d_x_head") - p("d_x_base"))
    xA = rates["x_base"] - p("d_x_base") * eta
    theta = -(rates["y_head"] - rates["y_base"]) / (p("d_y_head") - p("d_y_base"))
    yA = rates["y_base"] + p("d_y_base") * theta
    zd2 = rates["z_bk"] ** 2
    E = 0.5 * p("J2") * (eta ** 2 + theta ** 2)
    for m, s in ((p("m2"), p("h2")), (p("m3"), p("h3")), (p("m4"), p("h3") + p("h4"))):
        E = E + 0.5 * m * ((xA + s * eta) ** 2 + (yA - s * theta) ** 2 + zd2)
    return E


def window_weights(times: np.ndarray, window: tuple[float, float]) -> np.ndarray:
    """Trapezoid weights (T,) over the samples inside ``window`` (zero outside); they sum to
    the span of the samples inside (= window length when its ends are samples)."""
    t = np.asarray(times, float)
    inside = (t >= window[0] - 1e-12) & (t <= window[1] + 1e-12)
    idx = np.flatnonzero(inside)
    if idx.size < 2:
        raise GprmInputError(f"window [{window[0]:g}, {window[1]:g}] s holds fewer than two "
                             f"samples of the record [{t[0]:g}, {t[-1]:g}] s", field="window")
    w = np.zeros_like(t)
    tt = t[idx]
    d = np.diff(tt)
    w[idx[:-1]] += d / 2
    w[idx[1:]] += d / 2
    return w


def histogram(E: np.ndarray, weights: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Time per energy bin (..., n_bins) for energy records (..., T) with time ``weights``.
    The last bin includes its upper edge."""
    E = np.asarray(E, float)
    nb = edges.size - 1
    k = np.clip(np.searchsorted(edges, E, side="right") - 1, 0, nb - 1)
    out = np.zeros(E.shape[:-1] + (nb,))
    flat_k = k.reshape(-1, E.shape[-1])
    flat_o = out.reshape(-1, nb)
    for r in range(flat_k.shape[0]):
        flat_o[r] = np.bincount(flat_k[r], weights=weights, minlength=nb)
    return out


@dataclass(frozen=True)
class EnergyCheck:
    """Fig. 8 data. Histograms are seconds per bin (n_bins,); ``*_err`` the std across
    parameter samples (model) or signal-noise draws (measured). Energies (T,) in J."""

    time: np.ndarray
    window: tuple[float, float]
    weights: np.ndarray
    edges: np.ndarray                     # bins of the like-for-like E_5 histograms
    edges_total: np.ndarray               # bins of the all-bodies histogram
    model_total: np.ndarray               # E (T,) best fit, all bodies
    model_point: np.ndarray               # E_5 (T,) best fit, from the model's five points
    measured_point: np.ndarray | None     # E_5 (T,) from the mean signals
    measured_point_std: np.ndarray | None  # (T,) linear propagation of the sem
    hist_model_total: np.ndarray
    hist_model_total_err: np.ndarray
    hist_model_point: np.ndarray
    hist_model_point_err: np.ndarray
    hist_measured: np.ndarray | None
    hist_measured_err: np.ndarray | None
    n_samples: int
    n_ok: int


def read_means(path) -> tuple[np.ndarray, dict, dict]:
    """Times, mean and sem (name -> (T,)) of the five fitted points from a mean-signals file
    (docs/data-formats.md), read by its format's reader."""
    from gprm.campaign.files import read_means as read_means_file

    src = str(path)
    ds = read_means_file(path, what="mean signals")
    for v in ("mean", "sem"):
        if v not in ds:
            raise GprmInputError("missing variable", source=src, field=v)
    names = [str(s) for s in np.asarray(ds["signal"].values)]
    t = np.asarray(ds["time"].values, float)
    mean, sem = {}, {}
    for n in FIVE:
        if n not in names:
            raise GprmInputError(f"signal {n!r} missing", source=src, field="signal")
        mean[n] = np.asarray(ds["mean"].sel(signal=n).values, float)
        sem[n] = np.asarray(ds["sem"].sel(signal=n).values, float)
        if not (np.all(np.isfinite(mean[n])) and np.all(np.isfinite(sem[n]))
                and np.all(sem[n] > 0)):
            raise GprmInputError(f"mean/sem of {n} must be finite with sem > 0", source=src,
                                 field="sem")
    if t.size < 3 or np.any(np.diff(t) <= 0):
        raise GprmInputError("time must increase with at least three samples", source=src,
                             field="time")
    return t, mean, sem


def energy_check(fm: FittedModel, *, piezo: int = 2, times=None, means=None,
                 window: tuple[float, float] = DEFAULT_WINDOW, n_bins: int = 20,
                 samples: int = 200, seed: int = 0, noise_draws: int = 200,
                 voltage=None) -> EnergyCheck:
    """Model and measured kinetic-energy histograms (Fig. 8).

    means: ``(times, mean, sem)`` as returned by :func:`read_means` (optional). The model is
    simulated on the same time grid as the measurement (default 200 kHz over 0..window end).
    """

    if n_bins < 1:
        raise GprmInputError(f"must be >= 1, got {n_bins}", field="n_bins")
    if means is not None:
        t = means[0]
    elif times is not None:
        t = np.asarray(times, float)
    else:
        t = np.arange(int(round(window[1] * 200e3)) + 1) / 200e3
    if window[0] < t[0] - 1e-12 or window[1] > t[-1] + 1e-12 or not window[1] > window[0]:
        raise GprmInputError(f"window [{window[0]:g}, {window[1]:g}] s is not inside the "
                             f"record [{t[0]:g}, {t[-1]:g}] s", field="window")
    w = window_weights(t, window)
    sel = w > 0

    # a record may start before the model's t = 0 (alignment shifts); the model is at rest
    # there (all changes and rates zero), so it is simulated from the first t >= 0 only
    k0 = int(np.searchsorted(t, 0.0))
    if k0 >= t.size:
        raise GprmInputError("the record ends before t = 0", field="time")

    def model_energies(pb):
        ts = t[k0:]
        m = body_motion(pb, ts, piezo=piezo, voltage=voltage)
        obs = observe(pb, ts, FIVE, piezo=piezo, voltage=voltage,
                      z_bk_absolute=fm.z_bk_absolute)
        pad = ((0, 0), (k0, 0))
        tot = np.pad(kinetic_energy(m)["total"], pad)
        rates = {n: differentiate(np.pad(obs.y[:, i], pad), t) for i, n in enumerate(FIVE)}
        return tot, point_energy(rates, pb), m.ok & obs.ok

    best = batch([fm.params])
    tot0, pt0, _ = model_energies(best)
    tot0, pt0 = tot0[0], pt0[0]
    tots = pts = np.zeros((0, t.size))
    n_ok = 0
    if samples > 0:
        tots, pts, ok = model_energies(fm.sample(samples, seed))
        tots, pts = tots[ok], pts[ok]
        n_ok = int(ok.sum())
    meas = meas_std = meas_draws = None
    if means is not None:
        _, mean, sem = means
        pbest = {k: v[0] for k, v in best.items()}
        rates = {n: differentiate(mean[n], t) for n in FIVE}
        meas = point_energy(rates, pbest)
        meas_std = _linear_energy_std(rates, {n: derivative_std(sem[n], t) for n in FIVE},
                                      pbest)
        rng = np.random.default_rng(seed + 1)
        draws = {n: differentiate(mean[n] + sem[n] * rng.standard_normal((noise_draws, t.size)),
                                  t) for n in FIVE}
        meas_draws = point_energy(draws, pbest)
    def edges_for(*arrays):
        top = max(float(np.max(a[..., sel])) for a in arrays if a is not None and a.size)
        return np.linspace(0.0, top * (1 + 1e-9) if top > 0 else 1.0, n_bins + 1)

    edges_total = edges_for(tot0, tots)
    edges = edges_for(pt0, pts, meas, meas_draws)

    def hist_err(E0, Es, edges):
        h = histogram(E0, w, edges)
        e = histogram(Es, w, edges).std(axis=0, ddof=1) if Es is not None and len(Es) > 1 \
            else np.full(n_bins, np.nan)
        return h, e

    hmt, hmt_e = hist_err(tot0, tots, edges_total)
    hmp, hmp_e = hist_err(pt0, pts, edges)
    hm = hm_e = None
    if meas is not None:
        hm, hm_e = hist_err(meas, meas_draws, edges)
    return EnergyCheck(time=t, window=(float(window[0]), float(window[1])), weights=w,
                       edges=edges, edges_total=edges_total, model_total=tot0, model_point=pt0, measured_point=meas,
                       measured_point_std=meas_std, hist_model_total=hmt,
                       hist_model_total_err=hmt_e, hist_model_point=hmp,
                       hist_model_point_err=hmp_e, hist_measured=hm, hist_measured_err=hm_e,
                       n_samples=int(samples), n_ok=n_ok)


def _linear_energy_std(rates, rate_std, pb) -> np.ndarray:
    """First-order std (T,) of E_5 from independent errors of the five point rates; dE/dr by
    an exact complex step (E_5 is a closed-form quadratic in the rates)."""
    h = 1e-30
    var = np.zeros_like(np.asarray(rates["x_base"], float))
    for n in FIVE:
        r = {k: (v + 1j * h if k == n else v + 0j) for k, v in rates.items()}
        dE = point_energy(r, pb).imag / h
        var = var + (dE * rate_std[n]) ** 2
    return np.sqrt(var)
