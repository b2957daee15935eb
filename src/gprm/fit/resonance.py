"""An unmodelled resonance of the mechanism as a nuisance of the fit (issue 21).

A structural mode the 9-coordinate model lacks (a flexible mode of the plunger, the runner or
the bench) is excited by the same piezo force that drives the retraction and adds, in every
signal, its response to that force: the response of x'' + 2 zeta w x' + w^2 x = f(t) to
the voltage-drop rate of the model's drive (Eq. 8, V ~ exp(-s / tau_v) after the command),

    g(s) = (exp(lam s) - exp(-s / tau_v)) / (lam + 1 / tau_v),  lam = -zeta w + i w sqrt(1 - zeta^2),

s the time since the drive's onset at that laser position (t_c + t0 + the position's lags),
zero before it. Each signal sees it with its own amplitude and phase (its own coupling to the
mode and its own lag): two columns per signal, Re g and Im g, weighted like the residuals.

What it does to a fit that ignores it. The part of the resonance that the model's columns can
imitate moves the parameters (a bias that no residual shows); the rest stays in the residuals,
where the sandwich's residual covariance prices it as if it were noise. On the per-source
coverage study it made the fit's intervals 1.6 times too wide on average and some parameters'
errors still 0.9 sd one way in every campaign (docs/fitting.md, "An unmodelled resonance as
a nuisance").

What the fit does instead (variable projection). The frequency and damping are found by a
search over the residuals (:func:`search`): for each (f, zeta) on a grid, the residuals'
chi-square drop when the 2S columns are fitted jointly with the parameters' own columns and
one gain column per channel (linearised at the fit), refined locally in f, zeta and an onset
shift.

Detection. The resonance counts as found where that drop is at least ``DETECT_RATIO`` times
what the same columns take from noise as the campaign shows it (:func:`noise_drop`: the
runs' deviations from their mean, scaled to the mean's noise), so that the noise's size and
time correlation are the data's own. The drop's F test against white residuals, Bonferroni
over the grid, is reported but does not decide: residuals of a campaign whose drive varies
between runs or whose noise is coloured are not white, and it "found" resonances there. The
gain columns keep a channel's gain error (the signal's own shape in the residuals) from
being read as a resonance. Where one is found, the fit minimises the residuals projected off the resonance's columns and off their derivatives
with respect to the frequency, the damping and the onset (:func:`projection`): that is the
joint least-squares fit with the 2S amplitudes, the frequency, the damping and an onset shift
as free nuisance parameters, linearised in the last three, and the amplitudes eliminated.
The sandwich then sees the projected Jacobian, so the nuisances' freedom widens every
parameter they trade off with, and the residuals no longer carry the resonance.

The search needs at least two periods in the window (``MIN_PERIODS``): a slower "resonance"
is a smooth curve over the window, indistinguishable from a drift or a drive-shape error,
and projecting it off took information from the model's own slow modes (measured on the
drive-variation and coloured-noise sources). Damping ratios from 0.1 % to 10 %: a structural
mode, not a broadband error.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import fdtrc

from gprm.fit.objective import Objective
from gprm.fit.prior import Prior
from gprm.params import batch_from_vectors
from gprm.simulate.core import ROW_LAGS

#: how many times its noise expectation (:func:`noise_drop`) the resonance's chi-square drop
#: must be to be taken as found (module docstring, "Detection")
DETECT_RATIO = 25.0
#: the fewest periods of the resonance the fit window must hold
MIN_PERIODS = 2.0
#: the highest frequency searched, as a fraction of the sample rate (Nyquist is 0.5)
MAX_FRACTION = 0.45
#: the search grid's frequency step (the window's own resolution is 1 / its length: ~4 kHz
#: for the default 0.23 ms) and damping ratios
FREQ_STEP = 500.0
DAMPINGS = (0.002, 0.005, 0.01, 0.02, 0.05, 0.1)
#: the damping ratios a structural mode is looked for in
DAMPING_RANGE = (0.001, 0.1)
#: the nuisances the projection frees beyond the amplitudes: frequency, damping, onset
DERIVATIVES = ("frequency", "damping", "onset")


@dataclass(frozen=True)
class Resonance:
    """A resonance found in a fit's residuals and marginalised (module docstring).

    frequency (Hz), damping (ratio), onset_shift (s, added to the model's drive onset at
    every position); amplitude (S,) m: the largest magnitude of its response in each signal;
    chi2_drop: what it removed from the residuals' chi-square at detection (the parameters'
    own columns free), over ``chi2_before``; p_value: its F test's, Bonferroni-adjusted for the
    search grid; ``basis`` (N, k): the orthonormal columns the fit's residuals are projected
    off (weighted data space), kept to rebuild the objective, not written to files."""

    frequency: float
    damping: float
    onset_shift: float
    amplitude: tuple
    signals: tuple
    chi2_drop: float
    chi2_before: float
    p_value: float
    n_columns: int
    noise_drop: float = float("nan")
    basis: np.ndarray | None = field(default=None, compare=False, repr=False)

    @property
    def ratio(self) -> float:
        """The chi-square drop over what noise alone would drop (the detection statistic)."""
        return self.chi2_drop / self.noise_drop if self.noise_drop > 0 else float("inf")

    def to_json(self) -> dict:
        return {"frequency_hz": self.frequency, "damping": self.damping,
                "onset_shift_s": self.onset_shift,
                "amplitude_m": {s: float(a) for s, a in zip(self.signals, self.amplitude)},
                "chi2_drop": self.chi2_drop, "chi2_before": self.chi2_before,
                "noise_drop": self.noise_drop, "ratio": self.ratio,
                "p_value": self.p_value, "nuisance_parameters": self.n_columns}

    @classmethod
    def from_json(cls, d: dict) -> "Resonance":
        amp = d.get("amplitude_m", {})
        return cls(float(d["frequency_hz"]), float(d["damping"]),
                   float(d.get("onset_shift_s", 0.0)), tuple(float(v) for v in amp.values()),
                   tuple(amp), float(d.get("chi2_drop", np.nan)),
                   float(d.get("chi2_before", np.nan)), float(d.get("p_value", np.nan)),
                   int(d.get("nuisance_parameters", 0)), float(d.get("noise_drop", np.nan)))

    def summary(self) -> str:
        return (f"an unmodelled resonance at {self.frequency / 1e3:.2f} kHz (damping "
                f"{100 * self.damping:.2g} %) took {self.chi2_drop:.4g} of the residuals' "
                f"chi-square {self.chi2_before:.4g}, {self.ratio:.3g} times what the noise "
                f"would (F test p = {self.p_value:.2g}); marginalised with {self.n_columns} "
                "nuisance parameters")


def onsets(obj: Objective, x: np.ndarray) -> tuple[np.ndarray, float]:
    """((S,) s, tau_v s): the drive's onset at each signal's position in the aligned time base
    (t_c + t0 + the position's lags, gprm.simulate.core.ROW_LAGS) and the voltage drop's time
    constant, at the physical parameters ``x``."""
    pb = batch_from_vectors(obj.base, obj.names, np.asarray(x, float)[None])

    def value(name):
        return float(np.asarray(pb[name]).ravel()[0])

    on = np.array([value("t_c") + value("t0") + sum(value(n) for n in ROW_LAGS.get(s, ()))
                   for s in obj.data.signals])
    return on, value("tau_v")


def poles(frequency, damping) -> np.ndarray:
    """lam = -zeta w + i w sqrt(1 - zeta^2) of the module docstring (broadcast)."""
    w = 2.0 * np.pi * np.asarray(frequency, float)
    z = np.asarray(damping, float)
    return -z * w + 1j * w * np.sqrt(np.clip(1.0 - z ** 2, 0.0, None))


def responses(time: np.ndarray, onset: float, tau_v: float, lam: np.ndarray) -> np.ndarray:
    """(G, T) complex: g(t - onset) of the module docstring for each pole of ``lam`` (G,)."""
    lam = np.atleast_1d(np.asarray(lam, complex))
    a = 1.0 / tau_v
    s = np.asarray(time, float) - onset
    sp = np.clip(s, 0.0, None)
    g = (np.exp(lam[:, None] * sp[None, :]) - np.exp(-a * sp)[None, :]) / (lam + a)[:, None]
    return np.where(s[None, :] > 0, g, 0.0)


def response(time: np.ndarray, onset: float, tau_v: float, frequency: float,
             damping: float) -> np.ndarray:
    """(T,) complex: g(t - onset) of the module docstring (zero before the onset)."""
    return responses(time, onset, tau_v, poles(frequency, damping))[0]


def basis(obj: Objective, x: np.ndarray, frequency: float, damping: float,
          onset_shift: float = 0.0, *, at: tuple | None = None) -> np.ndarray:
    """(N, 2S): Re g and Im g of each signal on its own rows, weighted (1 / sigma) like the
    residuals, laid out as the objective's residuals (signal after signal). ``at``:
    :func:`onsets` of ``x`` when already computed."""
    d = obj.data
    S, T = d.values.shape
    on, tau = onsets(obj, x) if at is None else at
    D = np.zeros((S * T, 2 * S))
    for s in range(S):
        g = response(d.time, on[s] + onset_shift, tau, frequency, damping) / d.sigma[s]
        D[s * T:(s + 1) * T, 2 * s] = g.real
        D[s * T:(s + 1) * T, 2 * s + 1] = g.imag
    return D


@dataclass(frozen=True)
class _Linearised:
    """The fit's own columns at x in the prior's coordinates, to free them in the search."""

    Ju: np.ndarray
    Hinv: np.ndarray
    r: np.ndarray            # the residuals with the columns' own least-squares part removed
    p_eff: float

    @classmethod
    def at(cls, J: np.ndarray, r: np.ndarray, x: np.ndarray, prior: Prior | None,
           extra: np.ndarray | None = None):
        """``extra`` (N, m): further columns freed without a prior (the channels' gains)."""
        if prior is None:
            Ju = np.asarray(J, float)
            lam = np.full(Ju.shape[1], 1e-12 * max(float(np.max(np.sum(Ju * Ju, 0))), 1.0))
        else:
            Ju = J * prior.dx_du(np.asarray(x, float))[None, :]
            lam = np.asarray(float(prior.weight) ** 2 / prior.sd ** 2, float)
        if extra is not None and extra.shape[1]:
            Ju = np.hstack([Ju, extra])
            lam = np.concatenate([np.broadcast_to(lam, (J.shape[1],)),
                                  1e-12 * np.maximum(np.sum(extra * extra, 0), 1e-300)])
        Hinv = np.linalg.inv(Ju.T @ Ju + np.diag(lam))
        rr = r - Ju @ (Hinv @ (Ju.T @ r))
        return cls(Ju, Hinv, rr, float(np.trace(Ju @ Hinv @ Ju.T)))

    def free(self, e: np.ndarray) -> np.ndarray:
        """``e`` (N,) less its least-squares part in the fit's columns."""
        return e - self.Ju @ (self.Hinv @ (self.Ju.T @ e))

    def drop(self, D: np.ndarray, e: np.ndarray | None = None) -> float:
        """The chi-square the columns D remove from the residuals (or from ``e`` (N,), already
        :meth:`free`), the fit's columns free."""
        Dt = D - self.Ju @ (self.Hinv @ (self.Ju.T @ D))
        b = Dt.T @ (self.r if e is None else e)
        G = Dt.T @ Dt
        try:
            c = np.linalg.lstsq(G, b, rcond=1e-12)[0]
        except np.linalg.LinAlgError:
            return 0.0
        return float(max(b @ c, 0.0))


def gain_columns(obj: Objective, x: np.ndarray) -> np.ndarray:
    """(N, S): each channel's gain error as a column (its model signal on its own rows,
    weighted). Freed in the search, so that a gain error's residual (the signal's own
    shape, less what the parameters absorbed) is not read as a resonance: without them a
    per-position gain error of up to 1 % was "found" as a resonance in 9 campaigns of 10 and
    projecting it off hid the gain error from the sandwich (95 % coverage 69 %)."""
    d = obj.data
    S, T = d.values.shape
    y = obj.model(np.asarray(x, float)[None]).y[0]
    G = np.zeros((S * T, S))
    for s in range(S):
        G[s * T:(s + 1) * T, s] = y[s] / d.sigma[s]
    return G


def frequency_grid(time: np.ndarray) -> np.ndarray:
    """The frequencies searched (Hz): MIN_PERIODS over the window up to MAX_FRACTION of the
    sample rate, FREQ_STEP apart."""
    span = float(time[-1] - time[0])
    rate = 1.0 / float(np.median(np.diff(time)))
    lo = MIN_PERIODS / span
    hi = MAX_FRACTION * rate
    if hi <= lo:
        return np.zeros(0)
    return np.arange(lo, hi + 1e-9, FREQ_STEP)


def grid_drops(obj: Objective, x: np.ndarray, lin: _Linearised, freqs: np.ndarray,
               dampings) -> np.ndarray:
    """(len(dampings), len(freqs)): :meth:`_Linearised.drop` of :func:`basis` at every grid
    point, for the whole grid at once. With M = I - Ju Hinv Ju^T (the fit's columns freed)
    and K = Ju^T D, the columns' Gram matrix is D^T M^T M D = D^T D - 2 K^T Hinv K +
    (Hinv K)^T Ju^T Ju (Hinv K), where D^T D is block-diagonal (each signal's two columns
    live on its own rows): no (N, 2S) matrix per grid point is formed. The same numbers as
    one :meth:`_Linearised.drop` per point to ~1e-9 relative
    (tests/fit/test_resonance.py)."""
    d = obj.data
    S, T = d.values.shape
    on, tau = onsets(obj, x)
    lam = poles(np.asarray(freqs, float)[None, :],
                np.asarray(dampings, float)[:, None]).reshape(-1)                   # (G,)
    n_g = lam.size
    Ju, Hinv = lin.Ju, lin.Hinv
    v = lin.free(lin.r)                                    # M r
    K = np.zeros((n_g, Ju.shape[1], 2 * S))
    DtD = np.zeros((n_g, 2 * S, 2 * S))
    b = np.zeros((n_g, 2 * S))
    for s in range(S):
        g = responses(d.time, on[s], tau, lam) / d.sigma[s][None, :]                # (G, T)
        block = slice(s * T, (s + 1) * T)
        parts = np.stack([g.real, g.imag], axis=2)                                   # (G, T, 2)
        K[:, :, 2 * s:2 * s + 2] = np.matmul(Ju[block].T[None], parts)
        DtD[:, 2 * s:2 * s + 2, 2 * s:2 * s + 2] = np.matmul(parts.transpose(0, 2, 1), parts)
        b[:, 2 * s:2 * s + 2] = np.matmul(parts.transpose(0, 2, 1), v[block])
    W = np.matmul(Hinv[None], K)                                                     # Hinv K
    Kt = K.transpose(0, 2, 1)
    Wt = W.transpose(0, 2, 1)
    Gm = DtD - 2.0 * np.matmul(Kt, W) + np.matmul(Wt, np.matmul((Ju.T @ Ju)[None], W))
    c = np.matmul(np.linalg.pinv(Gm, rcond=1e-12, hermitian=True), b[:, :, None])[:, :, 0]
    return np.maximum(np.sum(b * c, axis=1), 0.0).reshape(len(dampings), -1)


def _refine(obj, x, lin, f, z, on, f_min=0.0):
    """Local coordinate search of (frequency >= f_min, damping, onset) from the grid's
    best."""
    at = onsets(obj, x)
    best = lin.drop(basis(obj, x, f, z, on, at=at))
    steps = [FREQ_STEP / 2, 0.3, 1e-6]          # Hz, relative damping, s
    for _ in range(40):
        moved = False
        for k in range(3):
            for sign in (-1.0, 1.0):
                ff, zz, oo = f, z, on
                if k == 0:
                    ff = f + sign * steps[0]
                elif k == 1:
                    zz = float(np.clip(z * np.exp(sign * steps[1]), *DAMPING_RANGE))
                else:
                    oo = on + sign * steps[2]
                if ff <= max(f_min, 0.0):
                    continue
                val = lin.drop(basis(obj, x, ff, zz, oo, at=at))
                if val > best * (1 + 1e-12):
                    best, f, z, on, moved = val, ff, zz, oo, True
        if not moved:
            steps = [steps[0] / 2, steps[1] / 2, steps[2] / 2]
            if steps[0] < 1.0:
                break
    return best, f, z, on


def search(obj: Objective, x: np.ndarray, r: np.ndarray, J: np.ndarray,
           prior: Prior | None, *, near: Resonance | None = None) -> Resonance | None:
    """The resonance that removes most of the residuals ``r`` (N,) (weighted data residuals
    at the physical ``x``, J (N, P) their Jacobian), its F test against the residuals left;
    None where no frequency can be searched. ``near``: refine from this one instead of
    searching the grid (after the fit moved)."""
    d = obj.data
    S, T = d.values.shape
    freqs = frequency_grid(d.time)
    if freqs.size == 0 and near is None:
        return None
    lin = _Linearised.at(J, r, x, prior, gain_columns(obj, x))
    if near is None:
        drops = grid_drops(obj, x, lin, freqs, DAMPINGS)
        if not np.any(drops > 0):
            return None
        i, j = np.unravel_index(int(np.argmax(drops)), drops.shape)
        drop, f, z, on = _refine(obj, x, lin, float(freqs[j]), DAMPINGS[i], 0.0, freqs[0])
    else:
        drop, f, z, on = _refine(obj, x, lin, near.frequency, near.damping, near.onset_shift,
                                 freqs[0] if freqs.size else 0.0)
    k = 2 * S + len(DERIVATIVES)
    before = float(lin.r @ lin.r)
    dof = max(S * T - lin.p_eff - k, 1.0)
    F = (drop / (2 * S)) / max((before - drop) / dof, 1e-300)
    p = float(fdtrc(2 * S, dof, F))
    n_tests = max(freqs.size * len(DAMPINGS), 1)
    D = basis(obj, x, f, z, on)
    null = noise_drop(obj, lin, D, (before - drop) / dof)
    a = np.linalg.lstsq(np.hstack([lin.Ju, D]), r, rcond=None)[0][lin.Ju.shape[1]:]
    amp = []
    on_s, tau = onsets(obj, x)
    for s in range(S):
        g = response(d.time, on_s[s] + on, tau, f, z)
        amp.append(float(np.max(np.abs(a[2 * s] * g.real + a[2 * s + 1] * g.imag))))
    return Resonance(float(f), float(z), float(on), tuple(amp), tuple(d.signals), drop, before,
                     min(1.0, p * n_tests), k, null)


def noise_drop(obj: Objective, lin: _Linearised, D: np.ndarray, s2: float) -> float:
    """What the columns D would take from the residuals of the mean if they held noise only:
    the average drop over the runs' deviations from their mean, each scaled to the mean's
    noise (1 / sqrt(R - 1)), so that the noise's time correlation and size are the data's
    own; without runs, 2S times the variance the residuals leave (``s2``), white noise's."""
    d = obj.data
    runs = getattr(d, "runs", None)
    if runs is None or runs.shape[1] < 3:
        return float(D.shape[1] * max(s2, 1e-300))
    R = runs.shape[1]
    dev = (runs - runs.mean(axis=1, keepdims=True)) / d.sigma[:, None, :]
    drops = [lin.drop(D, lin.free(dev[:, k, :].reshape(-1) / np.sqrt(R - 1)))
             for k in range(R)]
    return max(float(np.mean(drops)), 1e-300)


def projection(obj: Objective, x: np.ndarray, r: np.ndarray, J: np.ndarray,
               prior: Prior | None, res: Resonance) -> np.ndarray:
    """(N, k) orthonormal: the resonance's 2S columns and, for its fitted amplitudes, its
    derivatives with respect to the frequency, the damping and the onset (module
    docstring), at the physical ``x`` with residuals ``r`` and Jacobian ``J`` there."""
    f, z, on = res.frequency, res.damping, res.onset_shift
    D = basis(obj, x, f, z, on)
    lin = _Linearised.at(J, r, x, prior)
    a = np.linalg.lstsq(np.hstack([lin.Ju, D]), r, rcond=None)[0][lin.Ju.shape[1]:]
    hf, hz, ho = f * 1e-4, z * 1e-3, 1e-8
    cols = [D,
            ((basis(obj, x, f + hf, z, on) - basis(obj, x, f - hf, z, on)) @ a / (2 * hf))[:, None],
            ((basis(obj, x, f, z + hz, on) - basis(obj, x, f, z - hz, on)) @ a / (2 * hz))[:, None],
            ((basis(obj, x, f, z, on + ho) - basis(obj, x, f, z, on - ho)) @ a / (2 * ho))[:, None]]
    A = np.hstack(cols)
    U, sv, _ = np.linalg.svd(A, full_matrices=False)
    keep = sv > 1e-10 * sv[0]
    return U[:, keep]


def fitted_part(obj: Objective, x: np.ndarray) -> np.ndarray:
    """(S, T) m: what the projection takes from the data at ``x`` (the resonance and its
    nuisances' least-squares part of the residuals), zero without a projection."""
    d = obj.data
    Q = getattr(obj, "projection", None)
    if Q is None:
        return np.zeros(d.values.shape)
    return projected_part(Q, d.values, d.sigma, obj.model(np.asarray(x, float)[None]).y[0])


def projected_part(basis: np.ndarray, values: np.ndarray, sigma: np.ndarray,
                   model: np.ndarray) -> np.ndarray:
    """(S, T) m: the part of the residuals ``values - model`` (S, T) that the orthonormal
    columns ``basis`` (S T, k; weighted by 1 / ``sigma``) hold: what a fit projected off
    them does not describe with its parameters (:func:`fitted_part` at a fit's point)."""
    S, T = values.shape
    raw = ((values - model) / sigma).reshape(-1)
    return (basis @ (basis.T @ raw)).reshape(S, T) * sigma


def marginalise(obj: Objective, x: np.ndarray, polish, *, jacobian,
                ratio: float = DETECT_RATIO, found: Resonance | None = None,
                at: tuple | None = None) -> tuple[Objective, np.ndarray, Resonance | None]:
    """Search the fit at ``x`` for a resonance; where one is found (its chi-square drop at
    least ``ratio`` times the noise's, :func:`noise_drop`),
    project it off (:func:`projection`), polish (``polish(obj, x) -> x``), refine the
    resonance at the polished point and polish once more. ``jacobian(obj, x) -> (r, J)``:
    the weighted data residuals and their physical Jacobian. Returns the objective the fit
    now minimises (``obj`` unchanged where nothing was found), its minimum and the
    resonance (None where none). ``found``, ``at``: the :func:`search` at ``x`` and the
    (r, J) it was made with, when already computed."""
    r, J = jacobian(obj, x) if at is None else at
    if found is None:
        found = search(obj, x, r, J, obj.prior)
    if found is None or not found.ratio >= ratio:
        return obj, x, None
    res = found
    cur = obj
    for _ in range(2):
        Q = projection(obj, x, r, J, obj.prior, res)
        cur = obj.with_projection(Q)
        x = polish(cur, x)
        r, J = jacobian(obj, x)
        res = search(obj, x, r, J, obj.prior, near=res) or res
    Q = projection(obj, x, r, J, obj.prior, res)
    cur = obj.with_projection(Q)
    x = polish(cur, x)
    res = Resonance(res.frequency, res.damping, res.onset_shift, res.amplitude, res.signals,
                    found.chi2_drop, found.chi2_before, found.p_value, Q.shape[1],
                    found.noise_drop, Q)
    return cur, x, res
