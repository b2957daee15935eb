"""Does the model describe the data? The adequacy verdict of every fit (issue 21).

Three checks on the best fit, each from the data alone:

- **chi-square**: the weighted residuals' sum of squares over N - p_eff degrees of freedom
  (p_eff the trace of the fit's hat matrix, prior included), with its p-value under the
  chi-square distribution (what it would be if the residuals were the sigma(t) the
  preprocessing measured, independent);
- **whiteness, per signal**: the Ljung-Box statistic Q = n (n + 2) sum_k rho_k^2 / (n - k)
  over the first ``lags`` autocorrelations of the signal's residuals, its p-value under
  chi-square(lags) (gprm's implementation is checked against statsmodels' acorr_ljungbox in
  tests/fit/test_sandwich.py), the lag-1 autocorrelation, and the residuals' spectrum: the
  frequency holding the most residual power and its share of it (an unmodelled resonance
  shows as a peak), with Fisher's exact test of that peak against white residuals (g, the
  largest periodogram ordinate over their sum, :func:`fisher_g`);
- **leave one signal out**: the fit polished again from the best fit without signal s, and
  its prediction of s: the mean squared weighted error of that prediction over the in-fit
  one. Near 1 the other signals predict s as well as s fits itself; much larger means the
  signals disagree about the parameters (mismatch that one signal's share cannot absorb).

Verdict: ``adequate`` where the chi-square's p-value is above 0.001 and no signal's
Ljung-Box p-value is below 0.001 / n_signals; otherwise ``not described``, with the reasons.
The default uncertainty (gprm.fit.sandwich) accounts for an inadequate model through the
residuals' own covariance; :func:`verdict_text` says so in the words of the report.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import chdtrc, comb

from gprm.fit.engine import polish_best, polish_kwargs
from gprm.fit.lm import levenberg_marquardt_batch
from gprm.fit.objective import Objective
from gprm.fit.resonance import fitted_part
from gprm.fit.prior import Prior
from gprm.fit.starts import LMOptions

P_CHI2 = 1e-3
P_WHITE = 1e-3
#: the leave-one-signal-out polishes: iteration limit and relative chi-square tolerance. They
#: keep Algorithm 1's damping update (not the other polishes' trust region): a left-out
#: signal's prediction moves along directions the kept signals leave flat, so where a polish
#: stops along them changes the ratio in its fifth digit; with Algorithm 1 the batched and
#: the direct polishes stop at the same iteration (tests/fit/test_fit_speed.py holds them
#: to 1e-6), with the trust region one iteration apart on a test's signal (3e-5)
LOSO_MAX_ITER = 60
LOSO_FTOL = 1e-10


def ljung_box(x: np.ndarray, lags: int) -> tuple[float, float]:
    """(Q, p-value) of the Ljung-Box test of ``x`` (1-D) over ``lags`` autocorrelations."""
    x = np.asarray(x, float)
    n = x.size
    x = x - x.mean()
    den = float(x @ x)
    if den <= 0 or lags < 1:
        return 0.0, 1.0
    q = 0.0
    for k in range(1, lags + 1):
        rho = float(x[k:] @ x[:-k]) / den
        q += rho * rho / (n - k)
    q *= n * (n + 2)
    return float(q), float(chdtrc(lags, q))


def periodogram(x: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """(frequencies, one-sided power spectral density) of ``x`` (1-D) with its mean removed
    and no window: ``|FFT|^2 / (fs n)``, doubled except at 0 and (n even) the Nyquist
    frequency -- scipy.signal.periodogram's defaults with ``detrend="constant"`` (checked
    against it in tests/fit/test_fit_speed.py; scipy.signal itself costs about a second
    of import)."""
    x = np.asarray(x, float)
    n = x.size
    p = np.abs(np.fft.rfft(x - x.mean())) ** 2 / (fs * n)
    if n % 2:
        p[1:] *= 2.0
    else:
        p[1:-1] *= 2.0
    return np.fft.rfftfreq(n, 1.0 / fs), p


def spectral_peak(x: np.ndarray, fs: float) -> tuple[float, float]:
    """(frequency, share of the power) of the largest bin of ``x``'s periodogram, DC
    excluded (NaN, NaN when there is no power beyond DC)."""
    f, pw = periodogram(x, fs)
    if pw.size > 1 and np.sum(pw[1:]) > 0:
        k = 1 + int(np.argmax(pw[1:]))
        return float(f[k]), float(pw[k] / np.sum(pw[1:]))
    return float("nan"), float("nan")


def fisher_g_pvalue(g: float, m: int) -> float:
    """P(G >= g) for Fisher's g statistic of m periodogram ordinates of white Gaussian
    noise (Fisher 1929): sum over j = 1 .. floor(1/g) of (-1)^(j-1) C(m, j) (1 - j g)^(m-1),
    exact; NaN outside 0 < g <= 1 or for m < 2."""
    if not (np.isfinite(g) and 0.0 < g <= 1.0) or m < 2:
        return float("nan")
    j = np.arange(1, int(np.floor(1.0 / g)) + 1, dtype=float)
    terms = (-1.0) ** (j - 1) * comb(m, j) * np.clip(1.0 - j * g, 0.0, None) ** (m - 1)
    return float(np.clip(np.sum(terms), 0.0, 1.0))


def fisher_g(x: np.ndarray) -> tuple[float, float, int]:
    """(g, p, m): Fisher's test for a periodicity in ``x`` (1-D): g the largest of the m
    periodogram ordinates at the Fourier frequencies strictly between 0 and Nyquist over
    their sum, p its exact tail probability under white Gaussian noise
    (:func:`fisher_g_pvalue`). A small p says one frequency holds more of the residual
    power than white residuals would put in any one bin: an unmodelled oscillation.
    Coloured residuals also give small p at low frequencies (the Ljung-Box test says so
    too); the frequency tells which."""
    x = np.asarray(x, float)
    n = x.size
    m = (n - 1) // 2
    if m < 2:
        return float("nan"), float("nan"), m
    ordinates = periodogram(x, 1.0)[1][1:m + 1]      # one constant factor: g is a ratio
    total = float(np.sum(ordinates))
    if not total > 0:
        return float("nan"), float("nan"), m
    g = float(np.max(ordinates) / total)
    return g, fisher_g_pvalue(g, m), m


@dataclass(frozen=True)
class SignalCheck:
    signal: str
    chi2_per_sample: float
    ljung_box_q: float
    ljung_box_p: float
    lags: int
    lag1: float
    peak_frequency: float        # Hz, the residual spectrum's largest bin (DC excluded)
    peak_share: float            # that bin's share of the residual power
    loso_ratio: float            # leave-this-signal-out prediction error / in-fit error
    peak_p: float = float("nan")  # Fisher's g test of the largest ordinate (fisher_g)

    def to_json(self) -> dict:
        return {"signal": self.signal, "chi2_per_sample": self.chi2_per_sample,
                "ljung_box_q": self.ljung_box_q, "ljung_box_p": self.ljung_box_p,
                "lags": self.lags, "lag1_autocorrelation": self.lag1,
                "peak_frequency_hz": self.peak_frequency, "peak_share": self.peak_share,
                "peak_p_fisher_g": self.peak_p, "loso_ratio": self.loso_ratio}


@dataclass(frozen=True)
class Adequacy:
    """The adequacy of one fit (module docstring)."""

    chi2: float
    dof: float
    p_value: float
    signals: tuple[SignalCheck, ...]
    adequate: bool
    reasons: tuple[str, ...]
    #: the unmodelled resonance the fit found and marginalised (gprm.fit.resonance.Resonance's
    #: JSON), or None
    resonance: dict | None = None

    @property
    def reduced_chi2(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else float("nan")

    def to_json(self) -> dict:
        return {"verdict": "adequate" if self.adequate else "not described",
                "chi2": self.chi2, "dof": self.dof, "reduced_chi2": self.reduced_chi2,
                "p_value": self.p_value, "reasons": list(self.reasons),
                "signals": [s.to_json() for s in self.signals],
                "resonance": self.resonance}

    @classmethod
    def from_json(cls, d: dict) -> "Adequacy":
        sig = tuple(SignalCheck(s["signal"], s["chi2_per_sample"], s["ljung_box_q"],
                                s["ljung_box_p"], int(s["lags"]), s["lag1_autocorrelation"],
                                s["peak_frequency_hz"], s["peak_share"], s["loso_ratio"],
                                s.get("peak_p_fisher_g", float("nan")))
                    for s in d.get("signals", []))
        return cls(float(d["chi2"]), float(d["dof"]), float(d["p_value"]), sig,
                   d.get("verdict") == "adequate", tuple(d.get("reasons", [])),
                   d.get("resonance"))


def leave_one_signal_out_each(obj: Objective, x: np.ndarray, lm: LMOptions = LMOptions(),
                              max_iter: int = LOSO_MAX_ITER) -> np.ndarray:
    """:func:`leave_one_signal_out` the direct way: one objective without signal s and one
    polish per signal (the reference the batched form is tested against)."""
    d = obj.data
    S = len(d.signals)
    y_fit = obj.model(np.asarray(x, float)[None]).y[0]
    own = np.mean(((d.values - y_fit) / d.sigma) ** 2, axis=1)
    out = np.full(S, np.nan)
    for s in range(S):
        keep = [i for i in range(S) if i != s]
        sub = Objective(d.subset(keep), obj.base, obj.names, obj.scale, obj.piezo,
                        obj.z_bk_absolute, obj.prior)
        xs, _ = polish_best(sub, np.asarray(x, float), lm, max_iter=max_iter, ftol=LOSO_FTOL,
                            trust_region=False)
        ys = obj.model(xs[None]).y[0]
        if np.all(np.isfinite(ys[s])):
            out[s] = float(np.mean(((d.values[s] - ys[s]) / d.sigma[s]) ** 2) / own[s])
    return out


@dataclass(frozen=True)
class LeftOut:
    """The objective ``obj`` with signal ``left[k]`` left out of row k of a batch: its
    residuals and Jacobian rows set to zero (the same sum of squares and normal equations as
    the objective without that signal), the prior's rows kept. For
    :func:`gprm.fit.lm.levenberg_marquardt_batch` with ``indexed=True``: every call gets the
    rows' indices in the batch."""

    obj: Objective
    left: np.ndarray

    def _keep(self, rows: np.ndarray) -> np.ndarray:
        """(b, N) True where a residual of the rows ``rows`` is kept."""
        d = self.obj.data
        S, T = d.values.shape
        per_signal = np.ones((rows.size, S, T), bool)
        per_signal[np.arange(rows.size), self.left[rows]] = False
        keep = per_signal.reshape(rows.size, S * T)
        if self.obj.prior is None:
            return keep
        return np.concatenate([keep, np.ones((rows.size, self.obj.n_params), bool)], axis=1)

    def __call__(self, Xn: np.ndarray, rows: np.ndarray):
        r, J = self.obj(Xn)
        keep = self._keep(np.asarray(rows))
        return np.where(keep, r, 0.0), np.where(keep[:, :, None], J, 0.0)

    def residuals(self, Xn: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return np.where(self._keep(np.asarray(rows)), self.obj.residuals(Xn), 0.0)


def leave_one_signal_out(obj: Objective, x: np.ndarray, lm: LMOptions = LMOptions(),
                         max_iter: int = LOSO_MAX_ITER) -> np.ndarray:
    """(n_signals,) the prediction error of each signal by the fit without it, over its
    in-fit error (mean squared weighted residuals).

    The n_signals polishes (each from ``x``, ``max_iter`` iterations, relative tolerance
    ``LOSO_FTOL``) run as one lock-step batch: one simulation of all rows per iteration
    (:class:`LeftOut`), and one for the fit and the n_signals predictions. The same numbers
    as :func:`leave_one_signal_out_each` to rounding (tests/fit/test_fit_speed.py)."""
    d = obj.data
    S = len(d.signals)
    x = np.asarray(x, float)
    x0n = obj.to_normalised(x)
    lo, hi = obj.bounds_normalised()
    fun = LeftOut(obj, np.arange(S))
    res = levenberg_marquardt_batch(fun, np.repeat(x0n[None], S, axis=0), lower=lo, upper=hi,
                                    residuals=fun.residuals, indexed=True,
                                    **polish_kwargs(lm, max_iter, LOSO_FTOL,
                                                    trust_region=False))
    # as polish_best: a row that did not end finite and no worse keeps x
    ok = np.isfinite(res.chi2) & (res.chi2 <= res.chi2_0)
    XS = np.where(ok[:, None], obj.to_physical(res.x), x[None])
    y = obj.model(np.concatenate([x[None], XS])).y                 # (1 + S, S, T)
    if obj.projection is not None:
        # the data the fit describes: less what the projection took (the resonance)
        y = y + fitted_part(obj, x)[None]
    own = np.mean(((d.values - y[0]) / d.sigma) ** 2, axis=1)
    out = np.full(S, np.nan)
    for s in range(S):
        ys = y[1 + s, s]
        if np.all(np.isfinite(ys)):
            out[s] = float(np.mean(((d.values[s] - ys) / d.sigma[s]) ** 2) / own[s])
    return out


def effective_parameters(J: np.ndarray, x: np.ndarray, prior: Prior | None) -> float:
    """p_eff = trace of the hat matrix J (J^T J + w^2 Lambda)^-1 J^T, in the prior's
    coordinates (the number of parameters the data determine; P without a prior)."""
    if prior is None:
        return float(np.linalg.matrix_rank(J))
    Ju = J * prior.dx_du(np.asarray(x, float))[None, :]
    H = Ju.T @ Ju + np.diag(float(prior.weight) ** 2 / prior.sd ** 2)
    return float(np.trace(np.linalg.solve(H, Ju.T @ Ju)))


def assess(obj: Objective, x: np.ndarray, r: np.ndarray, p_eff: float, *,
           lm: LMOptions = LMOptions(), loso: bool = True, resonance=None) -> Adequacy:
    """The adequacy checks of the module docstring for the fit at ``x`` with weighted data
    residuals ``r`` (N,) and effective number of parameters ``p_eff``. ``resonance``: the
    unmodelled resonance the fit marginalised (gprm.fit.resonance.Resonance), or None; its
    nuisances count against the degrees of freedom, and it is a reason the model does not
    describe the data."""
    d = obj.data
    S, T = d.values.shape
    R = np.asarray(r, float).reshape(S, T)
    chi2 = float(np.sum(R * R))
    dof = float(max(R.size - p_eff - obj.n_nuisance, 1.0))
    p = float(chdtrc(dof, chi2))
    lags = int(max(1, min(10, T // 5)))
    fs = 1.0 / float(np.median(np.diff(d.time))) if T > 1 else 1.0
    ratios = leave_one_signal_out(obj, x, lm) if loso else np.full(S, np.nan)
    checks = []
    for s in range(S):
        q, pq = ljung_box(R[s], lags)
        z = R[s] - R[s].mean()
        den = float(z @ z)
        lag1 = float(z[1:] @ z[:-1]) / den if den > 0 else 0.0
        pf, share = spectral_peak(R[s], fs)
        checks.append(SignalCheck(d.signals[s], float(np.mean(R[s] ** 2)), q, pq, lags, lag1,
                                  pf, share, float(ratios[s]), fisher_g(R[s])[1]))
    reasons = []
    if resonance is not None:
        reasons.append(resonance.summary())
    if p < P_CHI2:
        reasons.append(f"chi-square {chi2:.4g} on {dof:.0f} degrees of freedom (reduced "
                       f"{chi2 / dof:.3g}, p = {p:.2g}): the residuals are larger than the "
                       "runs' spread")
    for c in checks:
        if c.ljung_box_p < P_WHITE / S:
            reasons.append(f"{c.signal}: residuals not white (Ljung-Box p = "
                           f"{c.ljung_box_p:.2g}, lag-1 autocorrelation {c.lag1:.2f}, most "
                           f"power at {c.peak_frequency / 1e3:.3g} kHz"
                           + (f", Fisher's g p = {c.peak_p:.2g}" if np.isfinite(c.peak_p)
                              else "") + ")")
    return Adequacy(chi2, dof, p, tuple(checks), not reasons, tuple(reasons),
                    None if resonance is None else resonance.to_json())


def verdict_text(a: Adequacy, method: str, details: dict | None = None) -> str:
    """One paragraph for the report and ``gprm show``."""
    if a.adequate:
        head = (f"The model describes the data: reduced chi-square {a.reduced_chi2:.3g} "
                f"(p = {a.p_value:.2g}) and every signal's residuals are white.")
    else:
        head = ("The model does not describe the data: " + "; ".join(a.reasons) + ".")
    if a.resonance:
        head += (" The resonance's amplitudes, frequency, damping and onset are free "
                 "nuisance parameters of the fit (its residuals are projected off them), so "
                 "every parameter they trade off with is widened by them; the checks above "
                 "are of the residuals that remain.")
    if method != "sandwich":
        return head + (f" The intervals ({method}) do not use the residuals' structure.")
    ratio = (details or {}).get("residual_over_runs")
    if ratio:
        big = sum(1 for v in ratio if v > 1.2)
        tail = (f" The intervals take the larger of the runs' spread and the residuals' own "
                f"covariance: the residuals widen {big} of {len(ratio)} parameters by more "
                "than 20 %.")
    else:
        tail = (" The file has no runs: the intervals come from the residuals' own "
                "covariance.")
    return head + tail
