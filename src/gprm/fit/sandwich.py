"""The default uncertainty (``sandwich``): the error of the mean signals estimated from the
campaign itself, propagated through the fit's linearised estimator, with the instrument's
systematics marginalised (issue 21; docs/fitting.md, "The default uncertainty").

The best fit x^ minimises ``|r(x)|^2 + |p(x)|^2`` (r: the data residuals weighted by
sigma(t), N rows; p: the weak prior's P rows with weight w, gprm.fit.prior). In the prior's
coordinates u (ln x for positive parameters) the estimator moves with a perturbation e of the
weighted data as ``du = B e`` with ``B = H^-1 J^T``, ``H = J^T J + w^2 diag(1/sd^2)`` (J the
data Jacobian in u). Its covariance is the sandwich ``B S B^T`` plus the prior's share, for the
covariance S of the weighted data's error, which is not assumed but estimated in three
independent ways, each from the data:

``runs``
    the spread of the synchronised, aligned runs behind each mean signal (the mean-signals
    file's ``runs``): ``S_runs = sum_r d_r d_r^T / (R (R - 1))`` with d_r a run's deviation
    from the mean, per signal (positions are measured in separate runs, so the blocks are
    independent). Run-to-run drive variation, trigger jitter left after synchronisation,
    noise, drift: whatever differs between runs, with its full time correlation.
``residuals``
    the fit's own residuals, with their time correlation: a heteroskedasticity- and
    autocorrelation-consistent (HAC) estimate per signal over the scores ``B[:, t] r_t``,
    prewhitened by an AR(2) of the residuals (:func:`prewhitened_scores`) and summed with a
    Parzen window of ``max_lag`` samples, and the small-sample factor N / (N - p_eff) (p_eff
    the trace of the hat matrix). This is what sees model
    mismatch common to all runs (an unmodelled resonance, a nonlinearity, a gain error that
    the shared parameters cannot absorb): residuals that are larger or more correlated than
    the runs' spread explains.
``systematics``
    the instrument's per-channel gain (calibration) error and timing offset, marginalised
    with the priors the user states (:class:`Systematics`): a gain error g of signal s moves
    its data by g y_s (the model signal), a timing error by -tau dy_s/dt. Each is a rank-one
    term ``sd^2 (B v)(B v)^T``; a gain error the parameters can absorb therefore widens
    exactly what it would bias. A signal whose own lag is held fixed also carries its
    alignment's error, estimated from the data (the mean's noise at the alignment time over
    its slope); where the lag is fitted it absorbs that error exactly, and the lag lives in
    the aligned data's axis, so nothing is added (docs/fitting.md, "The time axis of a
    campaign's truth"). Every signal's timing error also carries the time shift the runs'
    synchronisation took out of their spread but left in their mean (the file's
    ``sync_timing_sd``, gprm.campaign.preprocess.sync_timing_sd): the runs cannot show it,
    and the lags (and what is read on the fit's time axis) err by it (docs/fitting.md, "The
    time shift the synchronisation hides"); so does the shift it takes for the drive varying
    between runs, read from the runs' shapes (:func:`drive_shift_sd`).
    The fitted model's crossing offset (:func:`crossing_offsets`) is reported, not added:
    the lags live in the aligned data's time axis, which the offset does not make uncertain
    (docs/fitting.md, "The time axis of a campaign's truth").

The statistical part is the larger of the first two in the matrix sense (``V_runs +
[V_res - V_runs]_+``): with a model that describes the data both estimate the same thing and
agree; where the model does not, the residuals are larger than the runs' spread and their
estimate takes over. On the lags' rows and columns it is the runs' part alone: a lag
absorbs a time shift, which the residuals therefore cannot show, and the timing parts carry
(docs/fitting.md, "The lags' excess, and the drive's hidden time shift (stop 45)"). A
parameter's interval keeps the excess only where its own ratio of the two estimates passes
an F test (:func:`excess_mask`, stop 51); the posterior draws keep all of it.
Systematics and the prior's share add to it. The intervals are centred on the best fit:
nothing is re-centred, so the best fit lies inside every interval; each side is stretched
where the objective is flatter than its quadratic model
(:func:`shape_factors`) or where the estimator's spread grows toward that side
(:func:`variance_factors`). Nothing here depends on how a campaign was made (no generator,
no constant measured on synthetic data).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.special import chdtri, fdtri, ndtri

from gprm.campaign.preprocess import (PreprocessConfig, alignment_shift,
                                      detrended_noise_cross, detrended_noise_factor,
                                      detrended_noise_variance)
from gprm.errors import GprmInputError
from gprm.fit.covariance import normal_factor, standardised, symmetric_root
from gprm.fit.draws import inflation, project_draws
from gprm.fit.engine import polish_kwargs
from gprm.fit.lm import levenberg_marquardt_batch
from gprm.fit.methods import FitState
from gprm.fit.objective import Objective
from gprm.fit.prior import Prior
from gprm.fit.starts import LMOptions
from gprm.fit.uncertainty import CONTRACTION, HeldFixed, Uncertainty, determined
from gprm.params import LAG_PARAMETERS, batch_from_vectors
from gprm.simulate import observe
from gprm.simulate.core import ROW_LAGS


#: the per-source coverage study's headline for the report (benchmarks/bench_sources.py;
#: docs/fitting.md, "Coverage per source")
COVERAGE_HEADLINE = (
    "Measured per source of data, 20 campaigns each, on the identified parameters (those "
    "that lean on the prior not counted): the 95 % intervals held the truth in 97.0 % on the "
    "exact model with white noise, 98.0 % on an independently written simulator with white "
    "noise and 93.9 % with all its imperfections, 95.1 % on gprm's own generator, and "
    "92.6-97.5 % with trigger jitter, drive variation between runs, an unmodelled mode, "
    "coloured noise, drift, the nonlinear correction or per-channel gain errors alone; the 68 % "
    "intervals 62.2-75.5 % against the 60-76 % aimed at (inside both on all 18 sources); on "
    "the sources whose drive varies between runs the x-plane B support (k_Bx, c_Bx, d2) held "
    "it at 95 % in 90.9-100 % but at 68 % only in 33-49 % on gprm's generator and the drive "
    "sources; the post-impact velocity curves' "
    "bands hold the truth in 91-100 % at 95 % and 68-85 % at 68 % (inside both targets on 4 "
    "of the 18 sources: conservative)")


#: the F quantile of :attr:`Systematics.excess_test` by default: the median, so that a
#: parameter's interval keeps the residuals' excess where the ratio of its residual estimate
#: to its runs' estimate is larger than two estimates of one variance give more often than
#: not
EXCESS_QUANTILE = 0.5


@dataclass(frozen=True)
class Systematics:
    """Priors on the instrument's per-channel systematics (standard deviations, SI), stated
    by the user (parameter file ``[systematics]``, ``gprm fit --gain-sd/--timing-sd``).

    gain_sd: relative calibration (gain) error of each laser channel, 1 (default 0: an
    interferometer's displacement scale comes from its laser wavelength, so a stated default
    would be a guess; whatever gain error the residuals show is estimated and used anyway,
    ``estimate_gain``; docs/fitting.md, "Instrument systematics"). timing_sd: s, timing
    offset of each channel beyond what the alignment fits (default 0: each signal is aligned
    at its own threshold crossing and its lag is fitted, docs/model.md, so a constant channel
    delay is absorbed; where a signal's lag is held fixed, the alignment's own error is
    estimated from the data and added, ``alignment_noise``). ``per_signal``: optional
    overrides ``{signal: (gain_sd, timing_sd)}``.
    """

    gain_sd: float = 0.0
    timing_sd: float = 0.0
    per_signal: tuple[tuple[str, float, float], ...] = ()
    #: also estimate the gain errors' sd from the residuals and use the larger
    estimate_gain: bool = True
    #: widen each side of an interval where the objective is flatter than its quadratic
    #: approximation (:func:`shape_factors`)
    shape_check: bool = True
    #: stretch each side of an interval to z sds of the estimator linearised where the side
    #: ends (:func:`variance_factors`)
    variance_check: bool = True
    #: which signals' alignment noise (:func:`alignment_sd`) joins their timing error:
    #: "fixed-lags" (default) those whose own lag (:func:`own_lag`) is not fitted, which
    #: nothing else absorbs; "all" every signal (stop 39's default, a development check:
    #: a fitted lag absorbs it exactly, so it only widens the lags); "none"
    alignment_noise: str = "fixed-lags"
    #: Student's t also where the residuals' kernel estimate is the larger statistical part,
    #: with its degrees of freedom (:func:`residual_dof`); False: only the runs' part counts
    #: as estimated (stop 37-40)
    residual_dof: bool = True
    #: every signal's timing error includes the time shift the synchronisation took out of
    #: the runs' spread but left in their mean (FitData.sync_timing_sd, where the file has
    #: it); False: not (stops 1-42, a development check)
    sync_timing: bool = True
    #: put the posterior draws back on the data (gprm.fit.draws): each projected onto the
    #: parameter sets whose residuals are the linearisation's at the draw, those that cannot
    #: be dropped; False: the Gaussian's draws as they are (stops 1-43, a development check)
    project_draws: bool = True
    #: every signal's timing error includes the time shift the synchronisation takes out of
    #: the runs' spread when the drive varies between runs (:func:`drive_shift_sd`, from the
    #: runs' own shape deviations); False: not (stops 1-44, a development check)
    drive_timing: bool = True
    #: the residuals' excess over the runs' covariance also on the lags (stops 1-44); the
    #: default keeps it off them, whose error is a time shift the timing parts carry
    #: (docs/fitting.md, "The lags' excess, and the drive's hidden time shift")
    excess_on_lags: bool = False
    #: the residuals' kernel (HAC) estimate's lag window in samples; None: a quarter of the
    #: fit window's samples (:func:`default_max_lag`, stops 1-46); "auto": Andrews' (1991)
    #: plug-in from the prewhitened residuals (:func:`plugin_lag`). A development check of
    #: how the estimate's noise (its degrees of freedom, :func:`residual_dof`) depends on it
    hac_lag: int | str | None = None
    #: stretch each side of an interval to where the objective *re-minimised over the other
    #: parameters* (the profile) has risen as far as the interval's own z says, in the
    #: sandwich's variance of that parameter (:func:`profile_factors`); False: not (stops
    #: 1-48, a development check)
    profile_check: bool = True
    #: the residuals' excess over the runs' covariance reaches a parameter's interval only
    #: where that parameter's own ratio V_res,kk / V_runs,kk exceeds this quantile of
    #: F(nu_res, nu_runs) (:func:`excess_mask`; stop 51's default, the median); None: every
    #: parameter the matrix positive part reaches (stops 1-50). docs/fitting.md, "The
    #: residuals' excess tested per parameter"
    excess_test: float | None = EXCESS_QUANTILE
    #: the test also thins the excess in the posterior draws, and so in every prediction
    #: (stop 50's development check, measured: the independent simulator's overshoots fall
    #: under their target); False (the default): the draws keep the whole excess, untested,
    #: because a prediction combines parameters and the excess along a combination can be
    #: real where no single parameter's ratio shows it
    excess_test_draws: bool = False
    #: how the posterior draws are stretched to the intervals' factors (each side and level
    #: of each parameter): "coordinates" (the default) maps each parameter's coordinate of
    #: the correlated draw, so its marginal quantiles are the intervals, but a combination
    #: that the data hold tight loosens wherever its parameters' factors differ;
    #: development checks (docs/fitting.md, "The draws stretched otherwise (stop 57)",
    #: measured, not adopted): "whitened-all" maps the independent normals behind the draw,
    #: one per parameter of the correlation matrix's symmetric root (:func:`stretch_whitened`),
    #: so that no combination is stretched more than the most stretched parameter;
    #: "whitened" so for the identified parameters and the lags, the others by coordinate;
    #: "identified" by coordinate, the identified parameters and the lags only
    draws_stretch: str = "coordinates"
    #: instead of the drive term, each run's drive shift put back into its deviation along
    #: y' (:func:`drive_put_back`: the regression with a time-warp column, kept on the
    #: signals whose runs show it), so the runs' part keeps the shift's cross term with the
    #: rest of the run, the runs' noise's share subtracted in expectation; False (the
    #: default): the drive term. A development check (docs/fitting.md, "The drive's shift put
    #: back into each run (stop 60)")
    drive_put_back: bool = False

    def __post_init__(self):
        if self.draws_stretch not in DRAWS_STRETCH:
            raise GprmInputError(f"must be one of {', '.join(DRAWS_STRETCH)}, got "
                                 f"{self.draws_stretch!r}", field="systematics.draws_stretch")
        if self.alignment_noise not in ALIGNMENT_NOISE:
            raise GprmInputError(f"must be one of {', '.join(ALIGNMENT_NOISE)}, got "
                                 f"{self.alignment_noise!r}", field="systematics.alignment_noise")
        for name in ("gain_sd", "timing_sd"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) \
                    or v < 0:
                raise GprmInputError(f"must be a finite number >= 0, got {v!r}",
                                     field=f"systematics.{name}")
        for entry in self.per_signal:
            if len(entry) != 3 or not all(np.isfinite(v) and v >= 0 for v in entry[1:]):
                raise GprmInputError(f"per-signal entry {entry!r} must be (signal, gain_sd, "
                                     "timing_sd) with finite values >= 0",
                                     field="systematics.per_signal")
        if self.excess_test is not None and (
                isinstance(self.excess_test, bool) or not isinstance(self.excess_test, float)
                or not 0.0 < self.excess_test < 1.0):
            raise GprmInputError(f"must be a quantile in (0, 1) or None, got "
                                 f"{self.excess_test!r}", field="systematics.excess_test")
        if self.hac_lag is not None and self.hac_lag != "auto" and (
                isinstance(self.hac_lag, bool) or not isinstance(self.hac_lag, int)
                or self.hac_lag < 0):
            raise GprmInputError(f"must be an integer >= 0, 'auto' or None, got "
                                 f"{self.hac_lag!r}", field="systematics.hac_lag")

    def for_signal(self, signal: str) -> tuple[float, float]:
        for s, g, t in self.per_signal:
            if s == signal:
                return float(g), float(t)
        return float(self.gain_sd), float(self.timing_sd)

    def to_json(self) -> dict:
        return {"gain_sd": self.gain_sd, "timing_sd_s": self.timing_sd,
                "estimate_gain": self.estimate_gain, "shape_check": self.shape_check,
                "variance_check": self.variance_check,
                "alignment_noise": self.alignment_noise,
                "residual_dof": self.residual_dof, "sync_timing": self.sync_timing,
                "project_draws": self.project_draws,
                "drive_timing": self.drive_timing, "excess_on_lags": self.excess_on_lags,
                "hac_lag": self.hac_lag, "profile_check": self.profile_check,
                "excess_test": self.excess_test,
                "excess_test_draws": self.excess_test_draws,
                "draws_stretch": self.draws_stretch,
                "drive_put_back": self.drive_put_back,
                "per_signal": {s: {"gain_sd": g, "timing_sd_s": t}
                               for s, g, t in self.per_signal}}


@dataclass(frozen=True)
class SandwichParts:
    """The pieces of the default covariance in u (each (P, P)) and what they came from."""

    runs: np.ndarray | None         # from the runs' spread (None: the file has no runs)
    residuals: np.ndarray           # HAC estimate from the fit's residuals
    statistical: np.ndarray         # the larger of the two (matrix sense)
    gain: np.ndarray                # per-channel gain errors, marginalised
    timing: np.ndarray              # per-channel timing errors (stated + alignment)
    interpolation: np.ndarray       # the preprocessing's interpolation error (from data)
    prior: np.ndarray               # the prior's share
    total: np.ndarray
    timing_sd: np.ndarray           # (n_signals,) s, the timing sd used per signal
    gain_sd: np.ndarray             # (n_signals,) 1, the gain sd used per signal
    gain_estimated: float           # 1, the gain errors' sd the residuals show
    alignment_sd: np.ndarray        # (n_signals,) s, the alignment's own error (from data)
    p_eff: float
    max_lag: int
    #: (S, P) each signal's runs part of every parameter's variance (None: no runs)
    runs_by_signal: np.ndarray | None = None
    n_runs: int = 0

    def share(self) -> dict[str, np.ndarray]:
        """Each source's share of every parameter's variance (P,) (they sum to 1)."""
        tot = np.clip(np.diag(self.total), 1e-300, None)
        return {k: np.diag(v) / tot for k, v in (("statistical", self.statistical),
                                                   ("gain", self.gain),
                                                   ("timing", self.timing),
                                                   ("interpolation", self.interpolation),
                                                   ("prior", self.prior))}


def _psd_part(A: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh(0.5 * (A + A.T))
    return (V * np.clip(w, 0.0, None)) @ V.T


def bartlett(lag: np.ndarray, max_lag: int) -> np.ndarray:
    """Bartlett (Newey-West) lag weights 1 - lag / (max_lag + 1)."""
    return np.clip(1.0 - lag / (max_lag + 1.0), 0.0, None)


def parzen(lag: np.ndarray, max_lag: int) -> np.ndarray:
    """Parzen lag weights at x = lag / (max_lag + 1): 1 - 6x^2 + 6x^3 up to x = 1/2,
    2 (1 - x)^3 beyond. Like Bartlett's they give a covariance that is never negative
    definite, but their spectral window's side lobes fall as 1/omega^4 instead of 1/omega^2,
    so strong residual power away from zero frequency (an unmodelled resonance several
    periods long inside the window) leaks far less into the estimate."""
    x = np.asarray(lag, float) / (max_lag + 1.0)
    return np.where(x <= 0.5, 1.0 - 6.0 * x ** 2 + 6.0 * x ** 3,
                    np.where(x <= 1.0, 2.0 * (1.0 - x) ** 3, 0.0))


KERNELS = {"bartlett": bartlett, "parzen": parzen}
#: the residual HAC's lag window (docs/fitting.md: why Parzen)
DEFAULT_KERNEL = "parzen"


def lag_weights(T: int, max_lag: int, kernel: str = "bartlett") -> np.ndarray:
    """The HAC's weights of lags 1 .. min(max_lag, T - 1) for a series of T samples (lag 0
    has weight 1)."""
    return KERNELS[kernel](np.arange(1, min(max_lag, T - 1) + 1), max_lag)


def hac_meat(E: np.ndarray, max_lag: int, kernel: str = "bartlett") -> np.ndarray:
    """Kernel-weighted sum over one signal's scores E (T, P): sum_t e_t e_t^T plus the lag
    terms up to ``max_lag`` weighted by ``kernel`` (``bartlett``: Newey-West)."""
    S = E.T @ E
    for lag, wl in enumerate(lag_weights(E.shape[0], max_lag, kernel), start=1):
        G = E[lag:].T @ E[:-lag]
        S += wl * (G + G.T)
    return S


def default_max_lag(T: int) -> int:
    """Bartlett window of the residual HAC: a quarter of the window's samples (the signals'
    mismatch is correlated over tens of microseconds, the window holds ~47 samples)."""
    return max(1, T // 4)


#: Andrews' (1991) constant of the Parzen kernel's optimal bandwidth, S_T = 2.6614 (a T)^(1/5)
PARZEN_BANDWIDTH = 2.6614


def plugin_lag(series) -> int:
    """The Parzen window's lag for the HAC over these series (each (T,), the signals'
    prewhitened residuals, their innovations): Andrews' (1991, Econometrica 59, 817) plug-in
    for the Parzen kernel, S_T = 2.6614 (alpha(2) T)^(1/5), with alpha(2) from an AR(1)
    fitted to each series a (coefficient rho_a, clipped to +-:data:`MAX_ROOT` as the
    prewhitening filter's roots are, innovation variance s_a^2),
    sum_a 4 rho_a^2 s_a^4 / (1 - rho_a)^8 / sum_a s_a^4 / (1 - rho_a)^4. Parzen's weight of
    lag l is k(l / S_T), so the window's ``max_lag`` (weights k(l / (max_lag + 1))) is
    round(S_T) - 1, at least 0 and at most :func:`default_max_lag` (a quarter of the
    samples: what stops 1-46 used everywhere). Series without correlation give 0 (lag 0
    alone: the prewhitened White estimate)."""
    num = den = 0.0
    T = 0
    for u in series:
        u = np.asarray(u, float)
        if u.size < 4:
            continue
        T = max(T, u.size)
        a, b = u[1:], u[:-1]
        bb = float(b @ b)
        if bb <= 0:
            continue
        rho = float(np.clip((a @ b) / bb, -MAX_ROOT, MAX_ROOT))
        s2 = float(np.mean((a - rho * b) ** 2))
        num += 4.0 * rho ** 2 * s2 ** 2 / (1.0 - rho) ** 8
        den += s2 ** 2 / (1.0 - rho) ** 4
    if T == 0 or den <= 0:
        return 0
    S_T = PARZEN_BANDWIDTH * (num / den * T) ** 0.2
    return int(min(max(round(S_T) - 1, 0), default_max_lag(T)))


def alignment_sd(obj: Objective, y: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """(n_signals,) s: the error of each signal's alignment, estimated from the data: the
    noise of the mean at the alignment time (sem there, or noise_std / sqrt(R)) over the
    slope there (the data's where it is steeper), at most one sample. Zero where the alignment
    time is outside the window."""
    d = obj.data
    t_a = float(d.attrs.get("align_time", np.nan))
    out = np.zeros(len(d.signals))
    if not np.isfinite(t_a) or not (d.time[0] <= t_a <= d.time[-1]):
        return out
    k = int(np.argmin(np.abs(d.time - t_a)))
    dt = float(np.median(np.diff(d.time)))
    for s in range(len(d.signals)):
        if d.runs is not None:
            noise = float(np.std(d.runs[s, :, k], ddof=1) / np.sqrt(d.runs.shape[1]))
        elif d.sigma_kind == "sem":
            noise = float(d.sigma[s, k])
        else:
            noise = float(d.sigma[s, k]) / np.sqrt(float(d.attrs.get("n_runs", 10)))
        # the slope there: the model's, or the data's where the model is flatter (a fit whose
        # onset sits elsewhere); the estimate is capped at one sample, the resolution the
        # crossing is bracketed to before its refinement
        data_slope = abs(float(np.gradient(d.values[s], d.time)[k]))
        slope = max(abs(float(dy[s, k])), data_slope)
        out[s] = min(noise / slope, dt) if slope > 0 else dt
    return out


#: the lag every signal is evaluated behind (gprm.simulate.observe): dy/dt = -dy/dt0
#: (:func:`time_derivative`)
ORIGIN_LAG = "t0"


#: the choices of :attr:`Systematics.alignment_noise`
ALIGNMENT_NOISE = ("fixed-lags", "all", "none")
#: the ways the draws are stretched to the intervals (Systematics.draws_stretch)
DRAWS_STRETCH = ("coordinates", "whitened", "whitened-all", "identified")


def own_lag(signal: str) -> str:
    """The lag parameter that moves ``signal`` alone: t0 for the reference x_base, t1 for
    z_bk, the alignment offset of the others (gprm.simulate.core.ROW_LAGS)."""
    return ROW_LAGS.get(signal, (ORIGIN_LAG,))[-1]


def alignment_noise_used(obj: Objective, mode: str = "fixed-lags") -> np.ndarray:
    """(n_signals,) bool: whose alignment noise joins the signal's timing error under
    ``mode`` (:attr:`Systematics.alignment_noise`): with "fixed-lags", the signals whose own
    lag (:func:`own_lag`) the objective does not fit."""
    signals = obj.data.signals
    if mode == "all":
        return np.ones(len(signals), bool)
    if mode == "none":
        return np.zeros(len(signals), bool)
    fitted = set(getattr(obj, "names", ()))
    return np.array([own_lag(s) not in fitted for s in signals])


def crossing_offsets(obj: Objective, y: np.ndarray) -> np.ndarray:
    """(n_signals,) s: how far the fitted model's own threshold crossing lies from the data's.

    Preprocessing moved each mean so that its first sustained crossing of ``threshold_factor``
    x its noise std is at ``crossing_time`` (within half a sample of the file's
    ``align_time``; ``align_time`` itself for older files), and the fitted lags
    live in that time base. The same rule applied to the model at the best fit (``y``, (S, T)
    on the data's window) should find its crossing there too. Where it does not, the data's
    crossing was moved by something the model does not have (an unmodelled resonance or
    nonlinearity near the onset, a drive whose shape varies, a run-to-run offset the
    synchronisation left): the offset (crossing_time - the model's crossing) is a diagnostic
    of the onset, not an error of the lags, which are estimated in the data's aligned axis
    (docs/fitting.md, "The time axis of a campaign's truth"). Zero where the file lacks the
    rule's attributes, the window does not hold the alignment time, or the model never crosses."""
    d = obj.data
    out = np.zeros(len(d.signals))
    t_a = float(d.attrs.get("align_time", np.nan))
    factor = float(d.attrs.get("threshold_factor", np.nan))
    hold = int(d.attrs.get("hold", 1))
    if d.noise_std is None or not (np.isfinite(t_a) and np.isfinite(factor)) \
            or not (d.time[0] < t_a < d.time[-1]):
        return out
    cross = getattr(d, "crossing_time", None)         # older files: at align_time
    for s in range(len(d.signals)):
        thr = factor * float(d.noise_std[s])
        if not (thr > 0 and np.all(np.isfinite(y[s]))):
            continue
        target = t_a if cross is None else float(cross[s])
        shift = alignment_shift(d.time, y[s], thr, align_time=target, hold=hold)
        if shift is not None and np.isfinite(shift):
            out[s] = float(shift)
    return out


def gain_variance(Ju: np.ndarray, Hinv: np.ndarray, R: np.ndarray, y: np.ndarray,
                  sigma: np.ndarray, runs: np.ndarray | None, *,
                  max_lag: int | None = None) -> float:
    """The variance of the per-channel gain errors the residuals show (method of moments,
    unbiased; may be negative by chance): :func:`gain_moments`'s estimate."""
    return gain_moments(Ju, Hinv, R, y, sigma, runs, max_lag=max_lag).variance


@dataclass(frozen=True)
class GainMoments:
    """The gain errors' variance estimate of :func:`gain_moments` and its standard deviation
    where there is no gain error (``null_sd``): ``variance / null_sd`` is the estimate in
    units of its own noise, about N(0, 1) on data without gain errors."""

    variance: float
    null_sd: float

    @property
    def z(self) -> float:
        return self.variance / self.null_sd if self.null_sd > 0 else 0.0

    @property
    def sd(self) -> float:
        """The standard deviation: the square root of the variance clipped at 0."""
        return float(np.sqrt(max(self.variance, 0.0)))


def gain_moments(Ju: np.ndarray, Hinv: np.ndarray, R: np.ndarray, y: np.ndarray,
                 sigma: np.ndarray, runs: np.ndarray | None, *,
                 max_lag: int | None = None) -> GainMoments:
    """The variance of the per-channel gain errors the residuals show (method of moments,
    unbiased; may be negative by chance), and its noise without gain errors.

    A gain error g_s of signal s adds g_s G_s to the weighted data (G_s = y_s / sigma_s on
    that signal's rows). The fit absorbs what the parameters can mimic; what is left is
    m_s = (I - J H^-1 J^T) G_s. With independent g_s of variance v, E[(m_s^T r)^2] =
    v sum_k (m_s^T m_k)^2 + m_s^T S m_s (S the covariance of the residuals' other part).
    Summed over the signals this gives v. It assumes the part of the gain errors the data
    see has the size of the part they do not.

    m_s^T S m_s is estimated from the data: from the runs' spread where the file has runs
    (else white noise of unit weight), and, with ``max_lag``, also from the residuals left
    when the best-fitting gains are taken out (the HAC sum of the scores m_s r_t, Bartlett
    window ``max_lag``), the larger of the two: residual structure that is not a gain error
    (an unmodelled resonance, a nonlinearity common to every run) projects on the gain
    directions too, and without this it would be read as a gain error and counted twice
    (once here, once in the residuals' own covariance).

    The null standard deviation: without gain errors the projections p = M^T r are
    Gaussian with covariance C (from the runs, each signal's row and column scaled up where
    the residuals say more), so sum_s p_s^2 has variance 2 tr(C^2) (the estimate's noise
    that a clip at 0 turns into a positive bias: docs/fitting.md, "Where the clean sources'
    width goes").

    Ju: (N, P) data Jacobian in u; Hinv: the inverse of the fit's H; R: (S, T) weighted
    residuals; y: (S, T) model signals; sigma: (S, T) weights; runs: (S, n, T)."""
    S, T = R.shape
    N = S * T
    G = np.zeros((N, S))
    for s in range(S):
        G[s * T:(s + 1) * T, s] = y[s] / sigma[s]
    M = G - Ju @ (Hinv @ (Ju.T @ G))                          # (N, S)
    r = R.reshape(-1)
    proj = M.T @ r                                            # (S,)
    MM = M.T @ M
    if runs is not None and runs.shape[1] >= 2:
        n_r = runs.shape[1]
        C = np.zeros((S, S))
        for s in range(S):
            dev = (runs[s] - runs[s].mean(axis=0)) / sigma[s][None, :]
            z = dev @ M[s * T:(s + 1) * T, :]                 # (R, S)
            C += z.T @ z / (n_r * (n_r - 1))
    else:
        C = MM.copy()
    noise = np.diag(C).copy()
    if max_lag is not None:
        g_hat = np.linalg.lstsq(MM, proj, rcond=None)[0]
        e = (r - M @ g_hat).reshape(S, T)
        other = np.zeros(S)
        for s in range(S):
            Ms = M[s * T:(s + 1) * T, :]
            other += np.diag(hac_meat(prewhitened_scores(Ms.T, e[s], PREWHITEN_ORDER),
                                      max_lag, DEFAULT_KERNEL))
        raised = np.maximum(noise, other * N / max(N - S, 1))
        scale = np.sqrt(raised / np.where(noise > 0, noise, 1.0))
        C = C * np.outer(scale, scale)
        noise = raised
    den = float(np.sum(MM * MM))
    if den <= 0:
        return GainMoments(0.0, 0.0)
    return GainMoments(float(np.sum(proj ** 2 - noise)) / den,
                       float(np.sqrt(2.0 * np.sum(C * C))) / den)


def run_deviations(runs: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(S, R, T): each synchronised run's deviation from the mean, weighted by sigma.

    (Tried and rejected: adding back the part the synchronisation shift took out, s_r y'.
    With true trigger offsets, as a lab's runs have, it counted the removed offsets as error,
    and on trigger-offset campaigns most parameters stopped being identified; it did not help
    where the drive amplitude varies.)"""
    return (runs - runs.mean(axis=1, keepdims=True)) / sigma[:, None, :]


#: order of the autoregression each signal's residuals are prewhitened with before the HAC
PREWHITEN_ORDER = 2
#: largest modulus the prewhitening filter's roots may have (Andrews and Monahan's 0.97)
MAX_ROOT = 0.97


def ar_coefficients(r: np.ndarray, order: int) -> np.ndarray:
    """(order,) least-squares autoregression r_t = sum_k a_k r_{t-k} + u_t of one residual
    series, its characteristic roots shrunk to modulus <= :data:`MAX_ROOT` (a filter near a
    unit root would turn a long-run variance into a division by almost zero)."""
    r = np.asarray(r, float)
    T = r.size
    if order <= 0 or T <= 3 * order:
        return np.zeros(max(order, 0))
    X = np.column_stack([r[order - k - 1:T - k - 1] for k in range(order)])
    a = np.linalg.lstsq(X, r[order:], rcond=None)[0]
    roots = np.roots(np.concatenate([[1.0], -a]))
    big = np.abs(roots) > MAX_ROOT
    if big.any():
        roots[big] *= MAX_ROOT / np.abs(roots[big])
        a = -np.real(np.poly(roots))[1:]
    return a


@dataclass(frozen=True)
class Whitening:
    """One residual series written as an autoregression's impulse response driven by its
    innovations (:func:`whitening`): ``r = h * u`` (zero before the window). ``H`` (T, T) is
    the filter as a matrix, ``H[t, s] = h[t - s]`` for t >= s, so that the filtered
    sensitivities of :func:`prewhitened_scores` are one product ``B @ H``."""

    u: np.ndarray
    H: np.ndarray


def whitening(r: np.ndarray, order: int) -> Whitening | None:
    """The AR(``order``) whitening of the residual series r (T,) (:func:`ar_coefficients`);
    None where the autoregression is zero (order 0, too short a series)."""
    r = np.asarray(r, float)
    a = ar_coefficients(r, order)
    if not np.any(a):
        return None
    T = r.size
    u = r.copy()
    for k, ak in enumerate(a, start=1):
        u[k:] -= ak * r[:-k]
    h = np.zeros(T)
    h[0] = 1.0
    for t in range(1, T):
        h[t] = sum(a[k - 1] * h[t - k] for k in range(1, min(len(a), t) + 1))
    lag = np.arange(T)[:, None] - np.arange(T)[None, :]
    return Whitening(u, np.where(lag >= 0, h[np.clip(lag, 0, None)], 0.0))


def prewhitened_scores(B: np.ndarray, r: np.ndarray, order: int,
                       w: Whitening | None | str = "compute") -> np.ndarray:
    """(T, P) scores whose sum is exactly sum_t B[:, t] r_t but whose terms are closer to
    uncorrelated: the residuals r (T,) are written as an autoregression's impulse response h
    driven by its innovations u (r = h * u, zero before the window), so that
    sum_t B_t r_t = sum_s u_s (sum_k h_k B_{s+k}); the scores are u_s times that filtered B.

    This is Andrews and Monahan's prewhitening applied inside the sum: residual structure
    the autoregression captures (an oscillation, low-pass noise) is carried by the filter
    exactly instead of by the HAC window's lag terms, where a window of a quarter of the
    samples would leak an oscillation's power into the zero-frequency estimate or cut a slow
    correlation short. ``order`` 0 returns the plain scores B_t r_t. ``w``: the residuals'
    :func:`whitening` when already computed (it depends on r alone; the estimator's
    linearisation moves B, not r)."""
    B = np.asarray(B, float)
    r = np.asarray(r, float)
    if isinstance(w, str):
        w = whitening(r, order)
    if w is None:
        return (B * r[None, :]).T
    return ((B @ w.H) * w.u[None, :]).T


def statistical_covariance(Bs: np.ndarray, R: np.ndarray, dev: np.ndarray | None, max_lag: int,
                           p_eff: float, kernel: str = DEFAULT_KERNEL,
                           prewhiten: int = PREWHITEN_ORDER, whitenings=None):
    """(V_runs, V_res, V_stat) of the module docstring, from plain arrays.

    The residual part is the kernel HAC sum over each signal's :func:`prewhitened_scores`
    (AR order ``prewhiten``; 0: the plain scores B_t r_t; ``whitenings``: each signal's
    :func:`whitening` of R when already computed, for order ``prewhiten``).

    Bs: (P, S, T) the estimator's influence ``H^-1 J^T`` laid out per signal and time;
    R: (S, T) weighted residuals; dev: (S, n_runs, T) each run's deviation from the mean,
    weighted like the residuals (None: no runs); ``max_lag``: the HAC's Bartlett window;
    ``p_eff``: the fit's effective number of parameters (small-sample factor)."""
    P, S, T = Bs.shape
    N = S * T
    V_res = np.zeros((P, P))
    for s in range(S):
        w = whitenings[s] if whitenings is not None else "compute"
        V_res += hac_meat(prewhitened_scores(Bs[:, s, :], R[s], prewhiten, w), max_lag,
                          kernel)
    V_res *= N / max(N - p_eff, 1.0)
    if dev is None:
        return None, V_res, V_res
    V_runs = runs_covariance(Bs, dev)
    return V_runs, V_res, V_runs + _psd_part(V_res - V_runs)


def runs_covariance(Bs: np.ndarray, dev: np.ndarray) -> np.ndarray:
    """(P, P) the runs' part: the sample covariance of the runs' deviations ``dev`` (S,
    n_runs, T; :func:`run_deviations`) taken through the estimator's influence ``Bs`` (P, S,
    T), over n_runs (n_runs - 1): the covariance of the runs' mean, each signal's runs
    independent of the others'."""
    P, S, _ = Bs.shape
    n_r = dev.shape[1]
    V = np.zeros((P, P))
    for s in range(S):
        Z = dev[s] @ Bs[:, s, :].T                                   # (n_runs, P)
        V += Z.T @ Z / (n_r * (n_r - 1))
    return V


@dataclass(frozen=True)
class ErrorModel:
    """The weighted data's error as the campaign shows it, estimated once at the best fit and
    then propagated through the estimator wherever it is linearised (:func:`propagate`).

    R: (S, T) weighted residuals at the best fit; dev: (S, n_runs, T) the runs' weighted
    deviations from their mean (None: no runs); gain_sd, timing_sd, alignment_sd: (S,) the
    per-signal systematics used; gain_estimated: what the residuals show; p_eff, max_lag: the
    fit's effective number of parameters and the HAC's window; whitenings: each signal's
    prewhitening filter, which depends on R alone and is reused wherever the error is
    propagated (:func:`variance_factors` propagates it at ~100 points)."""

    R: np.ndarray
    dev: np.ndarray | None
    gain_sd: np.ndarray
    timing_sd: np.ndarray
    alignment_sd: np.ndarray
    gain_estimated: float
    p_eff: float
    max_lag: int
    crossing_offset: np.ndarray | None = None
    #: each signal's :func:`whitening` of R (AR order PREWHITEN_ORDER), computed once
    whitenings: tuple | None = None
    #: the gain estimate's variance in units of its own noise (:class:`GainMoments`)
    gain_z: float = 0.0
    #: (S,) s: the synchronisation's timing sd counted in ``timing_sd`` (0 where
    #: ``Systematics.sync_timing`` is off); None: the means file predates it
    sync_timing_sd: np.ndarray | None = None
    #: (S,) s: the drive's hidden time shift counted in ``timing_sd`` (:func:`drive_shift_sd`;
    #: 0 where ``Systematics.drive_timing`` is off); None: no runs to estimate it from
    drive_timing_sd: np.ndarray | None = None
    #: whether the residuals' excess over the runs' covariance reaches the lags
    #: (``Systematics.excess_on_lags``)
    excess_on_lags: bool = Systematics.excess_on_lags
    #: (P,) bool: the parameters the residuals' excess over the runs' covariance reaches
    #: (:func:`excess_mask`); None: every one
    excess_mask: np.ndarray | None = None
    #: (U, Cv, q): where the drive's shift was put back into the runs' deviations
    #: (``Systematics.drive_put_back``), what the runs' noise adds to their covariance
    #: through it, per signal (:func:`drive_put_back`); None: nothing put back
    put_back_noise: tuple | None = None


def _estimator(x: np.ndarray, J: np.ndarray, prior: Prior) -> tuple[np.ndarray, np.ndarray]:
    """(Ju (N, P), Hinv (P, P)): the weighted data Jacobian in the prior's coordinates and
    the inverse of the objective's Gauss-Newton Hessian there (prior included)."""
    Ju = J * prior.dx_du(x)[None, :]
    lam = float(prior.weight) ** 2 / prior.sd ** 2
    H = Ju.T @ Ju + np.diag(lam)
    return Ju, np.linalg.inv(0.5 * (H + H.T))


def _linearised(obj: Objective, x: np.ndarray, J: np.ndarray, prior: Prior,
                y: np.ndarray | None = None):
    """(Ju, Hinv, B (P, S, T), y (S, T), dy (S, T)): the estimator's linearisation at ``x``
    (physical (P,)), J (N, P) the weighted data residuals' Jacobian there, y the model
    signals there (computed when None)."""
    d = obj.data
    S, T = d.values.shape
    Ju, Hinv = _estimator(x, J, prior)
    B = (Hinv @ Ju.T).reshape(x.size, S, T)
    if y is None:
        y = obj.model(x[None]).y[0]                           # (S, T) m
    return Ju, Hinv, B, y, time_derivative(obj, x, J, y)


def time_derivative(obj: Objective, x: np.ndarray, J: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(S, T) m/s: the model signals' exact time derivative at ``x``.

    Every signal is the response at t - t0, so dy/dt = -dy/dt0: the t0 column of the
    weighted residuals' Jacobian J (N, P) (r = (data - y) / sigma) times sigma when t0 is
    fitted and the objective projects nothing off, else one simulation with t0's
    sensitivity (a projected objective's columns are projected: until stop 38 that column
    was taken there too, a derivative mixed across the signals, and the lags' intervals
    came out about ten times too narrow with a resonance marginalised). A finite difference
    of ``y`` on the data's grid will not do: with ~5 samples per period of the fastest modes it is visibly
    off (tests/fit/test_sandwich.py), so a timing error, which the fitted lags absorb
    exactly, leaked onto the physical parameters through the difference (docs/fitting.md,
    "What no spread shows": the timing part).
    ``np.gradient`` only where the object has no model to ask."""
    d = obj.data
    S, T = d.values.shape
    names = list(getattr(obj, "names", ()))
    if ORIGIN_LAG in names and getattr(obj, "projection", None) is None:
        return J[:, names.index(ORIGIN_LAG)].reshape(S, T) * d.sigma
    # with a projection (a resonance marginalised) J's columns are projected, mixing the
    # signals' rows: the model's own derivative takes one simulation
    if hasattr(obj, "base"):
        pb = batch_from_vectors(obj.base, names, np.asarray(x, float)[None])
        obs = observe(pb, d.time, d.signals, piezo=obj.piezo, sensitivities=(ORIGIN_LAG,),
                      z_bk_absolute=obj.z_bk_absolute)
        if obs.ok[0]:
            return -obs.dy[0, :, :, 0]
    return np.gradient(y, d.time, axis=1)


#: the drive's parameters whose run-to-run variation :func:`drive_shift_sd` reads from the
#: runs' shapes: its amplitude and its retraction time constant
DRIVE_PARAMETERS = ("V0", "tau_v")


def _baseline_times(d, i: int) -> np.ndarray:
    """s: signal i's baseline sample times (step 0's straight line) on the data's axis; none
    where the file does not say (the line's noise is then not counted)."""
    if d.baseline is None or d.time.size < 2:
        return np.empty(0)
    dt = float(d.time[1] - d.time[0])
    lo, hi = (float(v) for v in d.baseline[i])
    return lo + dt * np.arange(int(round((hi - lo) / dt)) + 1)


def drive_shift_sd(obj: Objective, x: np.ndarray, dy: np.ndarray) -> np.ndarray | None:
    """(S,) s: the time shift the runs' synchronisation takes out of their spread but leaves
    in their mean when the drive varies from run to run (None without runs).

    Synchronisation moves each run to match the reference's onset. A run whose drive differs
    (amplitude V0, retraction time tau_v) has a different shape, and the synchronisation
    takes that shape's component along the slope y' for a time shift: the run is moved by
    h_r = <g, S d_r>, with S the model's sensitivities to the drive's parameters, d_r the
    run's deviation of them and g = y' / |y'|^2 over the window. The synchronised runs then
    lack that component, so their spread cannot show it, while their mean keeps the runs'
    average of it: a time shift of variance Var(h) / R, every lag's error (docs/fitting.md,
    "The lags' excess, and the drive's hidden time shift (stop 45)"). ``sync_timing_sd``
    counts the same mechanism for the runs' noise; this counts it for the drive.

    Estimated from the runs themselves: each synchronised run's deviation from their mean is
    regressed (least squares) on [y', S_V0, S_tau_v] at the best fit (the sensitivities by
    central differences, the mechanism model without any projected nuisance); the drive
    part's projection on g is that run's h_r; its variance over the runs, less what the
    signal's white noise (``noise_std``) alone would give it, over R. That noise is the
    run's own along the projection and, where the file gives step 0's baseline
    (``FitData.baseline``), its straight line's noise extrapolated into the window
    (gprm.campaign.preprocess.detrended_noise_factor, as ``sync_timing_sd`` counts it; until
    stop 56 the line's part was left out, and on the white-noise source the term came out
    positive in most campaigns though the drive there never varies); where the file gives
    the noise runs' autocovariance (``FitData.noise_acov``) the noise has that correlation
    instead of being white (detrended_noise_variance; stop 56: on low-pass noise the term
    had been taking up the noise's correlation as a drive). ``dy`` (S, T) is the model
    signals' time derivative at ``x``."""
    d = obj.data
    W = drive_shift_weights(obj, x, dy)
    if W is None or d.runs is None:
        return None
    out = np.zeros(len(d.signals))
    for i in range(len(d.signals)):
        runs = d.runs[i]
        h_r = (runs - runs.mean(axis=0)) @ W[i]
        noise = run_noise_variance(d, i, W[i])
        out[i] = np.sqrt(max(float(np.var(h_r, ddof=1)) - noise, 0.0) / runs.shape[0])
    return out


def drive_shift_weights(obj: Objective, x: np.ndarray, dy: np.ndarray,
                        extra: np.ndarray | None = None) -> np.ndarray | None:
    """(S, T) s/m: weights w per signal such that w . (run - runs' mean) is the time shift
    h_r the synchronisation took out of a run whose drive differs (:func:`drive_shift_sd`):
    the least-squares regression of the run's deviation on [y', S_V0, S_tau_v] (+ ``extra``
    (S, T, k') columns, whose part is counted with the drive's), its non-y' part projected on
    g = y' / |y'|^2. None without runs or where the model fails at ``x``."""
    d = obj.data
    if d.runs is None or not hasattr(obj, "base"):
        return None
    names = list(getattr(obj, "names", ()))
    k = len(DRIVE_PARAMETERS)
    pb = batch_from_vectors(obj.base, names, np.repeat(np.asarray(x, float)[None], 2 * k, 0))
    steps = []
    for j, c in enumerate(DRIVE_PARAMETERS):
        h = 1e-4 * abs(float(np.asarray(pb[c]).ravel()[0]))
        pb[c] = np.asarray(pb[c], float).copy()
        pb[c][2 * j] += h
        pb[c][2 * j + 1] -= h
        steps.append(h)
    obs = observe(pb, d.time, d.signals, piezo=obj.piezo, z_bk_absolute=obj.z_bk_absolute)
    if not np.all(obs.ok):
        return None
    sens = [(obs.y[2 * j] - obs.y[2 * j + 1]) / (2 * h) for j, h in enumerate(steps)]
    W = np.zeros(d.values.shape)
    for i in range(len(d.signals)):
        slope = np.asarray(dy[i], float)
        ss = float(slope @ slope)
        if not ss > 0:
            continue
        cols = [slope] + [sv[i] for sv in sens]
        if extra is not None:
            cols += list(np.asarray(extra[i], float).reshape(slope.size, -1).T)
        A = np.stack(cols, axis=1)                                   # (T, 1 + k + k')
        g = slope / ss
        # h_r = w . (run_r - mean): the non-y' part of the regression, projected on g
        W[i] = np.linalg.pinv(A)[1:].T @ (A[:, 1:].T @ g)
    return W


def run_noise_variance(d, i: int, w: np.ndarray) -> float:
    """m^2 x w's units^2: Var<w, e> for one run's noise e of signal i after step 0 (its
    baseline line counted where the file gives it), with the noise runs' autocovariance
    where the file gives it, else white of sd ``noise_std`` (0 where unknown)."""
    tb = _baseline_times(d, i)
    if d.noise_acov is not None:
        return detrended_noise_variance(w, d.time, tb, d.noise_acov[i],
                                        float(d.time[1] - d.time[0]))
    n0 = float(d.noise_std[i]) if d.noise_std is not None else 0.0
    return n0 ** 2 * detrended_noise_factor(w, d.time, tb) if np.isfinite(n0) else 0.0


#: the level at which a signal's runs must show a drive shift above their noise for
#: :func:`drive_put_back` to put it back (the chi2(R - 1) / (R - 1) quantile)
PUT_BACK_LEVEL = 0.95


def drive_put_back(obj: Objective, x: np.ndarray, dy: np.ndarray, level: float = PUT_BACK_LEVEL):
    """(H (S, R) s, U (S, T), Cv (S, T), q (S,)) or None: each run's drive shift to put back
    into its weighted deviation along U = y' / sigma, and what that adds through the runs'
    noise (a development check, ``Systematics.drive_put_back``).

    The synchronisation leaves each run without its shape deviation's part along the slope,
    y' <g, d_r>, while the mean keeps the runs' average d; so the mean's error through the
    estimator is B d and the runs' part sees B (I - P_g) d_r. The drive term adds
    Var<g, d> / R along the lags alone and misses the cross term; putting h_r = <g, d_r> back
    into each run keeps it. h_r is read from the run by the drive term's regression
    (:func:`drive_shift_weights`) with a time-warp column (t - t_x) y' added, t_x the mean's
    crossing (a stiffness that differs between runs, to first order); only where the runs'
    variance of h exceeds its noise expectation at ``level`` of chi2(R - 1) / (R - 1), so
    that runs that do not vary do not take the shift's noise. The noise it carries into the
    runs' covariance, 2 sym(B Cv (B U)^T) + q (B U)(B U)^T over R in expectation, Cv the
    noise's covariance with h per weighted sample and q h's noise variance, is what
    :func:`propagate` subtracts."""
    d = obj.data
    if d.runs is None or d.runs.shape[1] < 2:
        return None
    S, R, T = d.runs.shape
    t_x = (np.full(S, PreprocessConfig().align_time) if d.crossing_time is None
           else np.asarray(d.crossing_time, float))
    warp = ((d.time[None, :] - t_x[:, None]) * dy)[:, :, None]
    W = drive_shift_weights(obj, x, dy, extra=warp)
    if W is None:
        return None
    crit = float(chdtri(R - 1, 1.0 - level) / (R - 1))
    H = np.zeros((S, R))
    U = np.asarray(dy, float) / d.sigma
    Cv = np.zeros((S, T))
    q = np.zeros(S)
    dt = float(d.time[1] - d.time[0])
    for i in range(S):
        h = (d.runs[i] - d.runs[i].mean(axis=0)) @ W[i]
        qi = run_noise_variance(d, i, W[i])
        if not (qi > 0 and np.var(h, ddof=1) > crit * qi):
            continue
        if d.noise_acov is not None:
            acov = d.noise_acov[i]
        elif d.noise_std is not None:
            acov = np.array([float(d.noise_std[i]) ** 2])
        else:
            continue
        H[i], q[i] = h, qi
        tb = _baseline_times(d, i)
        Cv[i] = detrended_noise_cross(W[i], d.time, tb, acov, dt) / d.sigma[i]
    return H, U, Cv, q


def _put_back_correction(Bs: np.ndarray, put_back, n_runs: int) -> np.ndarray:
    """(P, P): what the runs' noise adds to the runs' covariance through the put-back shifts
    (:func:`drive_put_back`), in expectation, through the estimator's influence Bs."""
    U, Cv, q = put_back
    P = Bs.shape[0]
    D = np.zeros((P, P))
    for s in range(Bs.shape[1]):
        if not q[s] > 0:
            continue
        bu, bc = Bs[:, s, :] @ U[s], Bs[:, s, :] @ Cv[s]
        D += (np.outer(bu, bc) + np.outer(bc, bu) + q[s] * np.outer(bu, bu)) / n_runs
    return D


def error_model(obj: Objective, x: np.ndarray, J: np.ndarray, r: np.ndarray, prior: Prior,
                systematics: Systematics = Systematics(), *,
                max_lag: int | str | None = None) -> ErrorModel:
    """Estimate the data's error at the best fit ``x`` (J, r: the weighted data residuals'
    Jacobian (N, P) and values (N,) there, prior rows excluded). ``max_lag``: the residuals'
    kernel window (None: ``systematics.hac_lag``)."""
    d = obj.data
    S, T = d.values.shape
    x = np.asarray(x, float)
    Ju, Hinv, B, y, dy = _linearised(obj, x, J, prior)
    # the residuals' lost degrees of freedom: the parameters' and the nuisances' the
    # objective projects off (an unmodelled resonance, gprm.fit.resonance)
    p_eff = float(np.trace(Ju @ B.reshape(x.size, -1))) + getattr(obj, "n_nuisance", 0)
    R = r.reshape(S, T)
    whitenings = tuple(whitening(R[s], PREWHITEN_ORDER) for s in range(S))
    if max_lag is None:
        max_lag = systematics.hac_lag
    if max_lag == "auto":
        max_lag = plugin_lag([R[s] if w is None else w.u for s, w in enumerate(whitenings)])
    L = default_max_lag(T) if max_lag is None else int(max_lag)
    dev = run_deviations(d.runs, d.sigma) if d.runs is not None else None
    a_sd = alignment_sd(obj, y, dy)
    # the mechanism model's own crossing against the data's, also where a resonance is
    # marginalised: a diagnostic of what the model lacks at the onset (fit.json, the report).
    # Not an error of the lags: they are estimated in the data's aligned axis, and the
    # offset is where that axis puts the mechanism's own crossing (until stop 39 it was
    # added to t0's variance; on the studies' campaigns the fitted t0 is within 0.2 us of
    # the truth in the data's axis while the offset is 1.7-2.8 us: docs/fitting.md)
    c_off = crossing_offsets(obj, y)
    g_sd = np.array([systematics.for_signal(s)[0] for s in d.signals])
    # the alignment's noise moves a signal's data and its place in the data's axis together:
    # a fitted lag absorbs it exactly and is estimated in that axis, so it is no error there.
    # A signal whose own lag is held fixed cannot follow it. (Stop 39 added it to every
    # signal, as a stand-in for an error of the axis's anchor, the reference run's timing:
    # that was the studies' yardstick erring, which took the reference run's trigger offset
    # for the time of the runs' average; docs/fitting.md, "The time axis of a campaign's
    # truth".)
    used = alignment_noise_used(obj, systematics.alignment_noise)
    # the time shift the synchronisation took out of the runs' spread but left in their
    # mean (gprm.campaign.preprocess.sync_timing_sd): an error of every signal's timing that
    # the runs' part cannot show; a fitted lag takes it (docs/fitting.md, "The time shift
    # the synchronisation hides")
    s_sd = (None if d.sync_timing_sd is None else
            np.asarray(d.sync_timing_sd, float) * bool(systematics.sync_timing))
    # the same for the drive varying between runs, read from the runs' shapes
    v_sd = drive_shift_sd(obj, x, dy) if systematics.drive_timing else None
    put_back = None
    if systematics.drive_put_back and dev is not None:
        pb = drive_put_back(obj, x, dy)
        if pb is not None:
            H, U, Cv, q = pb
            dev = dev + H[:, :, None] * U[:, None, :]
            put_back = (U, Cv, q)
            v_sd = None
    t_sd = np.array([np.sqrt(systematics.for_signal(s)[1] ** 2
                             + (a_sd[i] if used[i] else 0.0) ** 2
                             + (0.0 if s_sd is None else s_sd[i]) ** 2
                             + (0.0 if v_sd is None else v_sd[i]) ** 2)
                     for i, s in enumerate(d.signals)])
    gm = gain_moments(Ju, Hinv, R, y, d.sigma, d.runs, max_lag=L)
    if systematics.estimate_gain:
        g_sd = np.maximum(g_sd, gm.sd)
    return ErrorModel(R, dev, g_sd, t_sd, a_sd, gm.sd, p_eff, L, c_off, whitenings, gm.z, s_sd,
                      v_sd, bool(systematics.excess_on_lags), put_back_noise=put_back)


def _excess_on(V_runs: np.ndarray, V_stat: np.ndarray, mask) -> np.ndarray:
    """The statistical part with the residuals' excess over the runs' covariance kept on the
    parameters of ``mask`` (P,) bool only (:func:`excess_mask`): a principal block of a
    positive semi-definite matrix, so still one."""
    m = np.asarray(mask, float)
    return V_runs + (V_stat - V_runs) * np.outer(m, m)


def _sum_of_parts(*parts: np.ndarray) -> np.ndarray:
    """The sandwich's total, symmetrised, from its parts in :class:`SandwichParts` order."""
    total = sum(parts[1:], parts[0])
    return 0.5 * (total + total.T)


def with_excess_mask(parts: SandwichParts, mask) -> SandwichParts:
    """``parts`` as :func:`propagate` gives them for an error model carrying ``mask`` as its
    ``excess_mask``, without propagating again (the same error at the same point); without
    runs there is no excess to restrict, as there."""
    if parts.runs is None:
        return parts
    stat = _excess_on(parts.runs, parts.statistical, mask)
    return replace(parts, statistical=stat,
                   total=_sum_of_parts(stat, parts.gain, parts.timing, parts.interpolation,
                                       parts.prior))


def propagate(obj: Objective, x: np.ndarray, J: np.ndarray, prior: Prior,
              err: ErrorModel, y: np.ndarray | None = None) -> SandwichParts:
    """The covariance in u of the estimator linearised at ``x`` (physical (P,), J (N, P)
    there, y (S, T) the model signals there or None) for the data error ``err``: each
    source's share, and their sum."""
    d = obj.data
    S, T = d.values.shape
    x = np.asarray(x, float)
    P = x.size
    Ju, Hinv, Bs, y, dy = _linearised(obj, x, J, prior, y)
    V_runs, V_res, V_stat = statistical_covariance(Bs, err.R, err.dev, err.max_lag, err.p_eff,
                                                   whitenings=err.whitenings)
    if V_runs is not None and err.put_back_noise is not None and err.dev is not None:
        # the put-back shifts' noise, subtracted in expectation; what is left kept positive
        # semi-definite, the statistical part moved with it
        D = _put_back_correction(Bs, err.put_back_noise, int(err.dev.shape[1]))
        w, Q = np.linalg.eigh(0.5 * (V_runs - D + (V_runs - D).T))
        V_new = (Q * np.maximum(w, 0.0)) @ Q.T
        V_stat = V_stat + (V_new - V_runs)
        V_runs = V_new
    if V_runs is not None and not err.excess_on_lags:
        # the lags' error is a time shift, which the lags absorb from the residuals: the
        # excess reaches them only through the positive part's leak from other directions,
        # counting the shift the timing parts carry a second time (docs/fitting.md, "The
        # lags' excess, and the drive's hidden time shift"); the excess stays on every
        # other parameter
        lag = np.array([n in LAG_PARAMETERS for n in getattr(obj, "names", ())], bool)
        if lag.size == P and lag.any():
            E = V_stat - V_runs
            E[lag, :] = 0.0
            E[:, lag] = 0.0
            V_stat = V_runs + E
    if V_runs is not None and err.excess_mask is not None:
        V_stat = _excess_on(V_runs, V_stat, err.excess_mask)
    by_signal = None
    if err.dev is not None and err.dev.shape[1] >= 2:
        n_r = err.dev.shape[1]
        by_signal = np.stack([np.sum((err.dev[s] @ Bs[:, s, :].T) ** 2, axis=0)
                              for s in range(S)]) / (n_r * (n_r - 1))
    V_gain = np.zeros((P, P))
    V_time = np.zeros((P, P))
    V_interp = np.zeros((P, P))
    for s in range(S):
        if d.interpolation_error is not None:
            bi = Bs[:, s, :] @ (d.interpolation_error[s] / d.sigma[s])
            V_interp += np.outer(bi, bi)
        bg = Bs[:, s, :] @ (y[s] / d.sigma[s])
        bt = Bs[:, s, :] @ (dy[s] / d.sigma[s])
        V_gain += err.gain_sd[s] ** 2 * np.outer(bg, bg)
        V_time += err.timing_sd[s] ** 2 * np.outer(bt, bt)
    w2 = float(prior.weight) ** 2
    lam = w2 / prior.sd ** 2
    V_prior = Hinv @ np.diag(w2 * lam) @ Hinv
    return SandwichParts(V_runs, V_res, V_stat, V_gain, V_time, V_interp, V_prior,
                         _sum_of_parts(V_stat, V_gain, V_time, V_interp, V_prior),
                         err.timing_sd, err.gain_sd,
                         err.gain_estimated, err.alignment_sd, err.p_eff, err.max_lag,
                         by_signal, 0 if err.dev is None else int(err.dev.shape[1]))


#: steps along a parameter's posterior direction, in its standard deviations, at which the
#: objective's actual rise is compared with its quadratic approximation
SHAPE_STEPS = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0)


def _objective(obj: Objective, X: np.ndarray) -> np.ndarray:
    """The objective at physical rows X; inf where a set cannot be simulated."""
    try:
        with np.errstate(all="ignore"):
            out = np.asarray(obj.chi2(obj.to_normalised(X)), float)
    except (np.linalg.LinAlgError, FloatingPointError, ValueError):
        if X.shape[0] == 1:
            return np.array([np.inf])
        return np.concatenate([_objective(obj, X[i:i + 1]) for i in range(X.shape[0])])
    return np.where(np.isfinite(out), out, np.inf)


def shape_factors(obj: Objective, x: np.ndarray, Cu: np.ndarray, Ju: np.ndarray,
                  prior: Prior, *, reach: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) (P,) >= 1: how much farther than the linearisation says the objective
    actually has to go, on each side of each parameter, to rise as far as its quadratic
    approximation rises at ``reach`` standard deviations.

    Along parameter k's posterior direction v = C[:, k] / sd_k (u coordinates: the step that
    moves u_k by one sd and the others as they are expected to follow) the Gauss-Newton
    model of the objective phi = |r|^2 + |p|^2 rises by alpha^2 v^T H v. The objective itself
    is evaluated at alpha = SHAPE_STEPS on both sides (one batch of model runs, no Jacobian);
    where it rises more slowly (a curved valley, a second basin), the step alpha* at which it
    reaches the quadratic's rise at ``reach`` is found by interpolation and the side's
    factor is alpha* / reach (the largest step where it never does). It never narrows an
    interval. Where the objective falls below the best fit's, the factor is the largest too
    (the best fit is then not the minimum on that side)."""
    x = np.asarray(x, float)
    P = x.size
    u = prior.to_u(x)
    sd = np.sqrt(np.clip(np.diag(Cu), 1e-300, None))
    V = Cu / sd[None, :]                                     # column k: direction of k
    w2 = float(prior.weight) ** 2
    H = Ju.T @ Ju + np.diag(w2 / prior.sd ** 2)
    q = np.einsum("pk,pq,qk->k", V, H, V)                    # quadratic rise per alpha^2
    steps = np.array(SHAPE_STEPS)
    alphas = np.concatenate([-steps[::-1], steps])
    U = u[None, None, :] + alphas[None, :, None] * V.T[:, None, :]      # (P, A, P)
    X = prior.from_u(U.reshape(-1, P))
    lo_b, hi_b = obj.bounds()
    inside = np.all((X > lo_b) & (X < hi_b) & np.isfinite(X), axis=1)
    # only the parameters the linearisation calls identified are checked: the others' sd is
    # the prior's, and steps of several prior sds leave the model's domain
    checked = np.repeat(sd / prior.sd < CONTRACTION, alphas.size)
    inside &= checked
    phi = np.full(X.shape[0], np.inf)
    if inside.any():
        phi[inside] = _objective(obj, X[inside])
    phi0 = float(_objective(obj, x[None])[0])
    dphi = (phi - phi0).reshape(P, alphas.size)
    target = reach ** 2 * q
    out = []
    for side in (-1, 1):
        cols = np.nonzero(np.sign(alphas) == side)[0]
        cols = cols[np.argsort(np.abs(alphas[cols]))]
        a = np.abs(alphas[cols])
        f = np.ones(P)
        for k in range(P):
            if not checked[k * alphas.size]:
                continue
            d = dphi[k, cols]
            if np.any(d < -1e-9 * max(phi0, 1.0)):
                f[k] = a[-1] / reach
                continue
            hit = np.nonzero(d >= target[k])[0]
            if hit.size == 0:
                f[k] = a[-1] / reach
                continue
            j = hit[0]
            if j == 0:
                a_star = a[0] * np.sqrt(target[k] / max(d[0], 1e-300))
            else:
                a_star = np.interp(target[k], [d[j - 1], d[j]], [a[j - 1], a[j]])
            f[k] = max(1.0, a_star / reach)
        out.append(f)
    return out[0], out[1]


#: the most a side is stretched (the shape check's farthest step over its reach of 2 sd)
MAX_STRETCH = SHAPE_STEPS[-1] / 2.0


def variance_factors(obj: Objective, x: np.ndarray, Cu: np.ndarray, prior: Prior,
                     err: ErrorModel, z: float, *, iterations: int = 4,
                     tol: float = 0.02) -> tuple[np.ndarray,
                                                                                 np.ndarray]:
    """(lower, upper) (P,) >= 1: each side of parameter k's ``z``-interval stretched so that
    it reaches ``z`` standard deviations *of the estimator linearised where the side ends*.

    The sandwich's sd is the estimator's spread linearised at the best fit. Where the data's
    sensitivity to a parameter changes across its interval (a sloppy direction whose
    Jacobian turns, a lever arm that grows), the estimator's spread at a value on one side
    differs from that at the best fit, and a value theta is compatible with the estimate
    when ``|theta^ - theta| <= z sd(theta)``, with the spread evaluated *at theta*, as a
    score interval evaluates the variance under the value tested (Wilson's interval for a
    proportion does the same). Each side is found by fixed-point iteration along
    parameter k's posterior direction v_k = Cu[:, k] / sd_k (the other parameters following
    as expected): alpha <- z max(1, sd_k(u^ + alpha v_k) / sd_k(u^)), starting at z,
    ``iterations`` times or until no side moves by more than ``tol`` z (each iteration one
    batch of Jacobians), at most :data:`MAX_STRETCH` times z. The
    spread at each point is the same data error ``err`` (runs, residuals, systematics,
    all estimated at the best fit) propagated through the estimator linearised there. It
    never narrows an interval; only the parameters the linearisation identifies are
    checked."""
    x = np.asarray(x, float)
    P = x.size
    d = obj.data
    S, T = d.values.shape
    u = prior.to_u(x)
    sd = np.sqrt(np.clip(np.diag(Cu), 1e-300, None))
    V = Cu / sd[None, :]
    checked = np.nonzero(sd / prior.sd < CONTRACTION)[0]
    f = np.ones((2, P))
    if checked.size == 0:
        return f[0], f[1]
    lo_b, hi_b = obj.bounds()
    w = 1.0 / d.sigma
    alpha = np.full((2, checked.size), z)
    active = np.ones((2, checked.size), bool)
    for _ in range(iterations):
        sides = np.array([-1.0, 1.0])[:, None] * alpha                       # (2, K)
        U = u[None, None, :] + sides[:, :, None] * V.T[checked][None, :, :]  # (2, K, P)
        X = prior.from_u(U.reshape(-1, P))
        ok = np.all((X > lo_b) & (X < hi_b) & np.isfinite(X), axis=1) & active.reshape(-1)
        if not ok.any():
            break
        try:
            with np.errstate(all="ignore"):
                obs = obj.model(X[ok], jacobian=True)
        except (np.linalg.LinAlgError, FloatingPointError, ValueError):
            break
        ratio = np.ones(X.shape[0])
        for j, i in enumerate(np.nonzero(ok)[0]):
            Jp = (-obs.dy[j] * w[:, :, None]).reshape(S * T, P)
            if not (np.all(np.isfinite(Jp)) and np.all(np.isfinite(obs.y[j]))):
                ok[i] = False
                continue
            k = checked[i % checked.size]
            C = propagate(obj, X[i], Jp, prior, err, y=obs.y[j]).total
            ratio[i] = np.sqrt(max(C[k, k], 0.0)) / sd[k]
        new = np.clip(z * np.maximum(ratio.reshape(2, -1), 1.0), z, z * MAX_STRETCH)
        new = np.where(ok.reshape(2, -1), new, alpha)
        active &= np.abs(new - alpha) > tol * z
        alpha = np.maximum(alpha, new)
        if not active.any():
            break
    f[:, checked] = alpha / z
    return f[0], f[1]


#: the profile's points on each side of a parameter, in the sandwich's standard deviations
#: of it (:func:`profile_factors`); its outermost point bounds the stretch (8 sd: 4.1 z at
#: 95 %, as :data:`MAX_STRETCH`)
PROFILE_OFFSETS = (1.0, 2.0, 4.0, 8.0)
#: a profile point's polish: iterations and relative tolerance (the statistic needs the
#: objective to a small part of one variance scale)
PROFILE_ITER = 60
PROFILE_FTOL = 1e-9


def profile_crossing(offsets: np.ndarray, D: np.ndarray, z: float) -> float:
    """Where sqrt(D) first reaches ``z`` along one side: ``offsets`` (ascending, > 0, in sd)
    and the profile statistic ``D`` there (NaN or inf: not evaluated, beyond a bound). sqrt(D)
    is interpolated linearly from (0, 0), exact where the objective is quadratic. A side that
    never reaches ``z`` ends at its last evaluated point; one whose first point is not
    evaluated at 0 (never narrowed by the caller)."""
    o_prev, s_prev = 0.0, 0.0
    for o, d in zip(offsets, D):
        if not np.isfinite(d):
            return o_prev
        s = float(np.sqrt(max(d, 0.0)))
        if s >= z:
            return o_prev + (z - s_prev) * (o - o_prev) / (s - s_prev) if s > s_prev else o
        o_prev, s_prev = float(o), s
    return o_prev


def profile_factors(obj: Objective, x: np.ndarray, Cu: np.ndarray, Hinv: np.ndarray,
                    prior: Prior, lm: LMOptions, zs: tuple[float, ...]
                    ) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """Per level z in ``zs``, (lower, upper) (P,) >= 1: each side of parameter k's
    z-interval stretched to where its **profile** (the objective re-minimised over the
    other parameters, k held at each value) has risen to z^2 in the sandwich's variance of k.

    The profile statistic at u_k is D = (Phi(u_k) - Phi^) Hinv_kk / Cu_kk: the objective's
    rise over the best fit's, in units of its quadratic rise per unit of the Gauss-Newton
    variance Hinv_kk, rescaled to the sandwich's variance Cu_kk (the campaign's own error,
    of which Hinv_kk s2 is the noise's share). Where the objective is quadratic D = (u_k -
    u^_k)^2 / Cu_kk and the interval is the sandwich's. Where the data's minimum lies on a
    curved valley (the x-plane B support, k_Bx / c_Bx / d2, with run-to-run drive amplitude:
    docs/fitting.md "The x-plane support's profile (stop 49)") a straight line from the best
    fit (:func:`shape_factors`, :func:`variance_factors`) climbs the valley's wall at once,
    while the profile follows its floor, which can stay low for many standard deviations on
    one side. Points at :data:`PROFILE_OFFSETS` sd on each side of each parameter the
    linearisation identifies, all polished in one lock-step batch from the best fit with
    that parameter held; a point beyond the physical bounds or that cannot be simulated ends
    its side. Never narrows."""
    x = np.asarray(x, float)
    P = x.size
    u = prior.to_u(x)
    sd = np.sqrt(np.clip(np.diag(Cu), 1e-300, None))
    hk = np.clip(np.diag(Hinv), 1e-300, None)
    out = tuple((np.ones(P), np.ones(P)) for _ in zs)
    checked = np.nonzero(sd / prior.sd < CONTRACTION)[0]
    if checked.size == 0:
        return out
    offs = np.asarray(PROFILE_OFFSETS, float)
    K, M = checked.size, offs.size
    sides = np.array([-1.0, 1.0])
    # rows (side, parameter, offset): parameter k moved, the others at the best fit
    grid = np.repeat(u[None], 2 * K * M, axis=0).reshape(2, K, M, P)
    for i, k in enumerate(checked):
        grid[:, i, :, k] = u[k] + sides[:, None] * offs[None, :] * sd[k]
    U = grid.reshape(-1, P)
    kk = np.tile(np.repeat(checked, M), 2)
    lo_b, hi_b = obj.bounds()
    with np.errstate(all="ignore"):
        X = prior.from_u(U)
    ok = np.all((X > lo_b) & (X < hi_b) & np.isfinite(X), axis=1)
    phi = np.full(X.shape[0], np.inf)
    phi0 = float(_objective(obj, x[None])[0])
    if ok.any() and np.isfinite(phi0):
        rows = np.flatnonzero(ok)
        f = HeldFixed(obj, kk[rows])
        lo_n, hi_n = obj.bounds_normalised()
        kw = polish_kwargs(lm, PROFILE_ITER, PROFILE_FTOL)
        try:
            with np.errstate(all="ignore"):
                res = levenberg_marquardt_batch(f, obj.to_normalised(X[rows]),
                                                residuals=f.residuals, lower=lo_n,
                                                upper=hi_n, indexed=True, **kw)
            phi[rows] = np.where(np.isfinite(res.chi2), res.chi2, np.inf)
        except (np.linalg.LinAlgError, FloatingPointError, ValueError):
            return out
    # the statistic in the sandwich's variance; a point below the best fit (a lower minimum
    # along the valley) counts as 0
    D = ((phi - phi0) * (hk / sd ** 2)[kk]).reshape(2, K, M)
    for (f_lo, f_hi), z in zip(out, zs):
        for i, k in enumerate(checked):
            f_lo[k] = max(1.0, profile_crossing(offs, D[0, i], z) / z)
            f_hi[k] = max(1.0, profile_crossing(offs, D[1, i], z) / z)
    return out


#: the likelihood-ratio thresholds (chi-square, 1 dof) of the 95 % and 68 % levels: another
#: minimum whose objective lies within this many variance scales of the best is as
#: compatible with the data as the best fit's own interval edge
LR_THRESHOLD = {0.95: float(ndtri(0.975)) ** 2, 0.68: float(ndtri(0.84)) ** 2}


def alternative_factors(u: np.ndarray, sd: np.ndarray, U_alt: np.ndarray, D_alt: np.ndarray,
                        z: float, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) (P,) >= 1: each side of the ``z``-interval (centre u, sd ``sd``, in u)
    stretched so that the interval is the union of its own and the same interval around
    every other minimum ``U_alt`` (K, P) whose objective lies within ``threshold`` of the
    best (``D_alt`` (K,): the rise over the best in variance scales): a value the data fit
    as well as the best is inside the likelihood-ratio region, and a linearisation at the
    best fit alone cannot see it (the y-plane pair's two edges, docs/fitting.md, "Coverage
    per parameter")."""
    lo = np.ones(u.size)
    hi = np.ones(u.size)
    ok = np.isfinite(D_alt) & (D_alt <= threshold)
    if not ok.any():
        return lo, hi
    d = U_alt[ok] - u[None, :]                                            # (K', P)
    w = np.where(sd > 0, z * sd, np.inf)
    reach = 1.0 + np.abs(d) / w[None, :]
    lo = np.maximum(lo, np.max(np.where(d < 0, reach, 1.0), axis=0))
    hi = np.maximum(hi, np.max(np.where(d > 0, reach, 1.0), axis=0))
    return lo, hi


#: the other minima polished under the final objective: those whose unpolished rise is at most
#: this many variance scales, the lowest ALT_MAX of them
ALT_PREFILTER = 100.0
ALT_MAX = 16
#: two minima are one where their Mahalanobis distance under the fit's covariance Cu is at most
#: this: a minimum that near the best moves no interval side by more than ALT_SAME / z (1 % of
#: the 95 % half-width, 2 % of the 68 %), so telling it apart would not change what is reported
ALT_SAME = 0.02
#: the polish's relative chi-square tolerance: it leaves an end point of the best's basin
#: ~0.01 Mahalanobis units from the best (the demo's 1000-start fit), inside ALT_SAME
ALT_FTOL = 1e-9


def _distinct(U: np.ndarray, u0: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """Indices of the rows of U distinct from each other and from u0 (to 1e-4 prior sd)."""
    key = np.round((U - u0[None]) / sd[None], 4)
    _, first = np.unique(key, axis=0, return_index=True)
    first = np.sort(first)
    return first[np.max(np.abs(key[first]), axis=1) > 0]


def _distinct_minima(U: np.ndarray, D: np.ndarray, u0: np.ndarray,
                     Cu: np.ndarray) -> np.ndarray:
    """Indices of the rows of U (minima, D their rises), lowest rise first, whose Mahalanobis
    distance under ``Cu`` from u0 and from every lower row kept exceeds ALT_SAME.

    Whitened in the standardised coordinates (offsets over the sds, the correlation's
    eigen-decomposition, its eigenvalues floored at 1e-14 of the largest), so that the lags'
    ~1e-15 variances beside O(1) ones are not lost to the floor (until stop 51 Cu itself was
    decomposed, which under-weighed offsets along the lags)."""
    sd, R = standardised(Cu)
    sd = np.where(sd > 0, sd, 1.0)
    w, V = np.linalg.eigh(R)
    w = np.clip(w, np.max(np.abs(w)) * 1e-14 + 1e-300, None)
    Wt = (((U - u0[None]) / sd[None]) @ V) / np.sqrt(w)[None]    # whitened offsets
    kept: list[int] = []
    for i in np.argsort(D, kind="stable"):
        if np.linalg.norm(Wt[i]) <= ALT_SAME:
            continue
        if any(np.linalg.norm(Wt[i] - Wt[j]) <= ALT_SAME for j in kept):
            continue
        kept.append(int(i))
    return np.asarray(kept, int)


def alternative_minima(obj: Objective, x: np.ndarray, X_alt: np.ndarray | None,
                       prior: Prior, Cu: np.ndarray, lm: LMOptions = LMOptions()
                       ) -> tuple[np.ndarray, np.ndarray]:
    """(U (K, P) in the prior's coordinates, D (K,)): the multi-start's other end points that
    fit nearly as well, polished under the objective the best fit minimises (data and the
    prior weighed by the data's variance scale; the starts ran with the prior's first
    weight), distinct from each other and from the best fit ``x``, with the rise of that
    objective over the best in the variance scale s2 (the prior's weight squared). Only the
    ALT_MAX lowest within ALT_PREFILTER before the polish are polished (one batch, to
    ALT_FTOL). Distinct: further than ALT_SAME from the best and from every lower one in the
    Mahalanobis distance under the fit's covariance ``Cu`` (in u) (:func:`_distinct_minima`;
    a polished end point of the best's own basin lands nearer, and one that did not would
    widen an interval by a few per cent at most)."""
    x = np.asarray(x, float)
    P = x.size
    empty = (np.zeros((0, P)), np.zeros(0))
    if X_alt is None or len(X_alt) == 0:
        return empty
    X = np.asarray(X_alt, float)
    lo_b, hi_b = obj.bounds()
    X = X[np.all(np.isfinite(X) & (X > lo_b) & (X < hi_b), axis=1)]
    if X.shape[0] == 0:
        return empty
    u0 = prior.to_u(x[None])[0]
    X = X[_distinct(prior.to_u(X), u0, prior.sd)]
    if X.shape[0] == 0:
        return empty
    s2 = max(float(prior.weight) ** 2, 1e-300)
    phi = _objective(obj, np.vstack([x[None], X]))
    D0 = (phi[1:] - phi[0]) / s2
    keep = np.flatnonzero(np.isfinite(D0) & (D0 <= ALT_PREFILTER))
    keep = keep[np.argsort(D0[keep], kind="stable")][:ALT_MAX]
    if keep.size == 0:
        return empty
    lo, hi = obj.bounds_normalised()
    res = levenberg_marquardt_batch(obj, obj.to_normalised(X[keep]), lower=lo, upper=hi,
                                    residuals=obj.residuals,
                                    **polish_kwargs(lm, 200, ALT_FTOL))
    Xp = obj.to_physical(res.x)
    ok = np.isfinite(res.chi2) & np.all(np.isfinite(Xp), axis=1)
    if not ok.any():
        return empty
    Up = prior.to_u(Xp[ok])
    # the polish's chi2 is the objective there (data and weighted prior rows)
    Dp = (res.chi2[ok] - phi[0]) / s2
    idx = _distinct_minima(Up, Dp, u0, Cu)
    return Up[idx], Dp[idx]


def stretch_draws(Z: np.ndarray, sd: np.ndarray, f68: tuple, f95: tuple,
                  z: tuple[float, float]) -> np.ndarray:
    """Draws ``Z`` (n, P) from N(0, Cu) (sd (P,) their marginal sds) mapped, coordinate by
    coordinate and each side on its own, so that each parameter's marginal quantiles are the
    reported intervals at *both* levels: with t = Z_k / sd_k, |t| is mapped through the
    piecewise-linear g with g(0) = 0, g(z68) = z68 f68 and g(z95) = z95 f95 (f the side's
    stretch at that level, ``f68``/``f95`` = (lower (P,), upper (P,)), ``z`` = (z68, z95)),
    proportional below z68 and beyond z95. g is increasing (f95's knot is raised to f68's
    where it would fall below it), so the map keeps each draw's rank: the draw at the 84th
    (97.5th) percentile of t lands on the 68 % (95 %) interval's upper end. One stretch for
    every level would carry the 95 % sides' stretch into the bands' central part."""
    z68, z95 = z
    sd = np.where(sd > 0, sd, 1.0)
    t = Z / sd[None, :]
    a = np.abs(t)
    lower = t < 0
    k68 = z68 * np.where(lower, f68[0][None, :], f68[1][None, :])
    k95 = np.maximum(z95 * np.where(lower, f95[0][None, :], f95[1][None, :]), k68)
    g = np.where(a <= z68, a * k68 / z68,
                 np.where(a <= z95, k68 + (a - z68) * (k95 - k68) / (z95 - z68),
                          a * k95 / z95))
    return np.sign(t) * g * sd[None, :]


def masked(f: tuple, keep: np.ndarray) -> tuple:
    """Interval factors ``f`` = (lower (P,), upper (P,)) with 1 where ``keep`` is False."""
    return tuple(np.where(keep, side, 1.0) for side in f)


def stretch_whitened(E: np.ndarray, sd: np.ndarray, R_half: np.ndarray, f68: tuple,
                     f95: tuple, z: tuple[float, float],
                     whiten: np.ndarray | None = None) -> np.ndarray:
    """Draws (n, P) of N(0, S R S) (``sd``, ``R_half`` from :func:`symmetric_root`) built
    from standard normals ``E`` (n, P) with the intervals' factors applied to ``E`` rather
    than to the draw's coordinates: each column of E is mapped as :func:`stretch_draws`
    maps a coordinate (its sides, both levels), then the draw is S R^(1/2) E'.

    With every factor 1 these are the Gaussian's draws. The symmetric root ties column k of
    E to parameter k (it is the root closest to the identity), so parameter k's draws are
    stretched mostly by its own factors, exactly so where it is uncorrelated. What it buys:
    the draws' covariance S R^(1/2) F^2 R^(1/2) S (F the factors, one level, symmetric)
    lies between f_min^2 and f_max^2 times the Gaussian's in the matrix sense, so every
    combination of the parameters is stretched by a factor within the parameters' own
    range. Mapping the coordinates instead (``stretch_draws``, S F R F S) stretches a
    combination the data hold tight by |f_j - f_k| times the loose parameters' scale: the
    factors, each measured on one parameter's interval, then widen predictions that the
    data determine. What it costs: a parameter correlated with others is stretched by a
    weighted mean of their factors, so its marginal quantiles are near, not on, its
    interval's ends.

    ``whiten`` (P,) bool: the parameters stretched so (default every one); the others'
    coordinates are those of the unstretched draw S R^(1/2) E, mapped coordinate by
    coordinate as :func:`stretch_draws` maps them, and their factors stay out of the
    whitened map. A parameter the data leave undetermined can carry a large factor (an
    alternative minimum along a ridge) that would otherwise spread over every parameter
    correlated with it."""
    P = E.shape[1]
    sd = np.asarray(sd, float)
    w = np.ones(P, bool) if whiten is None else np.asarray(whiten, bool)
    out = stretch_draws(E, np.ones(P), masked(f68, w), masked(f95, w), z) @ R_half.T \
        * sd[None, :]
    if not w.all():
        rest = ~w
        Z = (E @ R_half.T)[:, rest] * sd[None, rest]
        out[:, rest] = stretch_draws(Z, sd[rest], tuple(side[rest] for side in f68),
                                     tuple(side[rest] for side in f95), z)
    return out


def runs_lead(parts: SandwichParts) -> np.ndarray:
    """(P,) where the runs' part of a parameter's variance is the larger statistical part
    (and can be counted: a file with runs, at least two); elsewhere the residuals' leads."""
    P = parts.total.shape[0]
    if parts.runs_by_signal is None or parts.runs is None or parts.n_runs < 2:
        return np.zeros(P, bool)
    return np.diag(parts.runs) >= np.clip(np.diag(parts.residuals), 0.0, None)


def statistical_dof(parts: SandwichParts, nu_res: np.ndarray | None = None) -> np.ndarray:
    """(P,) the effective degrees of freedom of each parameter's variance (Satterthwaite).

    The runs' part of signal s is b_s^T S_s b_s with S_s the sample covariance of R runs:
    sigma_s^2 chi2_{R-1} / (R - 1). Summed over the signals its degrees of freedom are
    (sum_s v_s)^2 / sum_s v_s^2 / (R - 1), between R - 1 and S (R - 1). The estimated part
    of a parameter's variance is the larger of the statistical two (the systematics and the
    prior count as known): where the runs' part leads, nu = V^2 / (V_runs^2 / nu_runs) for
    the parameter's whole variance V; where the residuals' kernel estimate leads and
    ``nu_res`` (P,) gives its degrees of freedom (:func:`residual_dof`), nu = V^2 / (V_res^2
    / nu_res); elsewhere infinite. Without runs only the residuals' part can count."""
    P = parts.total.shape[0]
    total = np.clip(np.diag(parts.total), 1e-300, None)
    nu = np.full(P, np.inf)
    v = parts.runs_by_signal
    vres = np.clip(np.diag(parts.residuals), 0.0, None)
    lead = runs_lead(parts)
    if v is not None and lead.any():
        vr = v.sum(axis=0)
        nu_runs = satterthwaite(v, parts.n_runs)
        nu = np.where(lead & (vr > 0),
                      total ** 2 / np.maximum(vr ** 2 / nu_runs, 1e-300), nu)
    if nu_res is not None:
        res = ~lead & (vres > 0) & np.isfinite(nu_res)
        nu = np.where(res, total ** 2 / np.maximum(vres ** 2 / np.where(res, nu_res, 1.0),
                                                   1e-300), nu)
    return nu


def residual_moments(Ju: np.ndarray, Hinv: np.ndarray, R: np.ndarray, max_lag: int,
                     p_eff: float, kernel: str = DEFAULT_KERNEL, whitenings=None,
                     projection: np.ndarray | None = None, rows: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, variance, target), each (P,): the residual kernel (HAC) estimate of each
    parameter's variance under a Gaussian working model of independent errors, and the
    variance it estimates.

    The estimate is a quadratic form in the data's error e: the residuals r = M e (M = I -
    Ju Hinv Ju^T, the fit linearised), each signal's innovations u_s = H_s^-1 r_s (its
    prewhitening filter, held fixed), and Q_j = N / (N - p_eff) sum_s u_s^T D_js K D_js u_s
    with K the lag window and D_js the filtered sensitivities of parameter j. With Sigma =
    diag(sigma_s^2) (each signal's residual mean square), E[Q] = tr(A Sigma) and Var[Q] =
    2 tr((A Sigma)^2) exactly; the target is B_j Sigma B_j^T (B = Hinv Ju^T).

    Ju: (N, P) the weighted data Jacobian in the prior's coordinates; Hinv: (P, P);
    R: (S, T) the weighted residuals; ``whitenings``: each signal's :func:`whitening`
    (None entries: no filter; None: computed from R); ``projection``: the orthonormal
    columns (N, k) the objective projects its residuals off (an unmodelled resonance,
    :mod:`gprm.fit.resonance`; Ju then is the projected Jacobian), so that M = I - Q Q^T -
    Ju Hinv Ju^T; ``rows``: (Q, P) combinations g of the parameters (in u) to give the
    moments of instead, each the estimate of g^T V g (None: the parameters themselves, the
    identity)."""
    R = np.asarray(R, float)
    S, T = R.shape
    N, P = Ju.shape
    B = Hinv @ Ju.T                                        # (P, N)
    M = np.eye(N) - Ju @ B
    if projection is not None:
        Q = np.asarray(projection, float)
        M -= Q @ Q.T
    if rows is not None:
        B = np.atleast_2d(np.asarray(rows, float)) @ B     # (Q, N)
        P = B.shape[0]
    if whitenings is None:
        whitenings = tuple(whitening(R[s], PREWHITEN_ORDER) for s in range(S))
    lag = np.abs(np.arange(T)[:, None] - np.arange(T)[None, :])
    K = np.concatenate([[1.0], lag_weights(T, max_lag, kernel), np.zeros(T)])[lag]
    Hs = [np.eye(T) if w is None else w.H for w in whitenings]
    Fs = [np.eye(T) if w is None else np.linalg.inv(w.H) for w in whitenings]
    sig2 = np.repeat(np.mean(R ** 2, axis=1), T)           # (N,) the working model
    C = (M * sig2[None, :]) @ M.T                          # Cov(r) = M Sigma M^T
    Bs = B.reshape(P, S, T)
    # G_js = D_js K D_js (P, T, T) per signal; Y_ss' = F_s C_ss' F_s'^T
    G = [K[None] * (g[:, :, None] * g[:, None, :]) for g in (Bs[:, s] @ Hs[s]
                                                               for s in range(S))]
    E = np.zeros(P)
    V = np.zeros(P)
    blk = [slice(s * T, (s + 1) * T) for s in range(S)]
    for s in range(S):
        for s2 in range(S):
            Y = Fs[s] @ C[blk[s], blk[s2]] @ Fs[s2].T
            if s == s2:
                E += np.einsum("pab,ba->p", G[s], Y)
            V += np.einsum("pab,pba->p", G[s] @ Y, G[s2] @ Y.T)
    fac = N / max(N - p_eff, 1.0)
    target = np.einsum("pn,n,pn->p", B, sig2, B)
    return fac * E, 2.0 * fac ** 2 * V, target


def residual_dof(Ju: np.ndarray, Hinv: np.ndarray, R: np.ndarray, max_lag: int,
                 p_eff: float, kernel: str = DEFAULT_KERNEL, whitenings=None,
                 projection: np.ndarray | None = None,
                 rows: np.ndarray | None = None) -> np.ndarray:
    """(P,) degrees of freedom of each parameter's residual kernel (HAC) variance estimate
    ((Q,) of each combination with ``rows``):
    Satterthwaite's nu = 2 E[Q]^2 / Var[Q] of :func:`residual_moments` (the degrees of
    freedom Bell and McCaffrey give a cluster-robust variance, here for a kernel one: a
    window of a quarter of ~47 samples per signal leaves it 4-12 on the studies' campaigns,
    where the runs' part has 9-45 with 10 runs). Same arguments."""
    E, V, _ = residual_moments(Ju, Hinv, R, max_lag, p_eff, kernel, whitenings, projection,
                               rows)
    return np.where(V > 0, 2.0 * E ** 2 / np.maximum(V, 1e-300), np.inf)


def dof_sources(parts: SandwichParts, nu: np.ndarray) -> list[str | None]:
    """(P,) which statistical part each finite degrees of freedom of :func:`statistical_dof`
    came from (:func:`runs_lead`): "runs" or "residuals" (None: infinite, the normal
    quantile)."""
    return [None if not np.isfinite(v) else ("runs" if r else "residuals")
            for v, r in zip(nu, runs_lead(parts))]


def satterthwaite(v: np.ndarray, R: int) -> np.ndarray:
    """(P,) degrees of freedom of sum_s v_s (v: (S, P)), each v_s a variance estimated from
    R runs (R - 1 degrees of freedom): (sum_s v_s)^2 / sum_s v_s^2 / (R - 1)."""
    v = np.asarray(v, float)
    return v.sum(axis=0) ** 2 / np.maximum(np.sum(v ** 2, axis=0) / (R - 1), 1e-300)


def excess_mask(parts: SandwichParts, nu_res: np.ndarray, q: float) -> np.ndarray | None:
    """(P,) bool: the parameters the residuals' excess over the runs' covariance reaches
    under the test of ``Systematics.excess_test`` = ``q``; None where there is nothing to
    test (no runs, or fewer than two).

    With a model that describes the data the residuals' kernel estimate and the runs' spread
    estimate the same variance, and their ratio V_res,kk / V_runs,kk for parameter k is about
    F-distributed with (nu_res, nu_runs) degrees of freedom (:func:`residual_dof`,
    :func:`satterthwaite`): two independent variance estimates. The positive part of the
    matrix difference keeps every direction in which the residuals' estimate happens to be
    the larger, and spills it onto parameters whose own ratio shows nothing, also on data
    with no mismatch (docs/fitting.md, "The residuals' excess tested per parameter (stop
    50)"). Here a parameter keeps the excess where its own ratio
    exceeds the F distribution's ``q`` quantile; elsewhere its statistical variance is the
    runs'. A parameter whose residual degrees of freedom are unknown keeps it. The
    default applies the test to the parameters' intervals only (``Systematics.excess_test``
    0.5, ``excess_test_draws`` False): a prediction combines parameters, and the excess
    along a combination can be real where no single parameter's ratio shows it (measured
    with the draws tested too: the independent simulator's overshoots fall under their
    target; and tested along each prediction's own gradient, stop 57, they fall under just
    the same: their own ratios show no excess either).
    The reference distribution is the working model's; the kernel estimate's shortfall under
    white errors (:func:`residual_dof`) makes the test drop the excess more often than 1 - q
    on clean data."""
    if parts.runs is None or parts.runs_by_signal is None or parts.n_runs < 2:
        return None
    runs = np.clip(np.diag(parts.runs), 1e-300, None)
    ratio = np.clip(np.diag(parts.residuals), 0.0, None) / runs
    nu_runs = satterthwaite(parts.runs_by_signal, parts.n_runs)
    nu = np.asarray(nu_res, float)
    ok = np.isfinite(nu) & (nu > 0) & np.isfinite(nu_runs) & (nu_runs > 0)
    crit = np.full(ratio.shape, -np.inf)
    crit[ok] = fdtri(nu[ok], nu_runs[ok], q)       # the F(nu, nu_runs) quantile q
    return ratio > crit


def student_factors(nu: np.ndarray, level: float) -> np.ndarray:
    """(P,) t_nu / z at the two-sided ``level``: how much wider an interval whose variance
    has nu degrees of freedom is than the normal one (1 where nu is infinite)."""
    from scipy.special import stdtrit     # Student's quantile (scipy.stats: 0.6 s to import)

    q = 0.5 + level / 2
    z = ndtri(q)
    nu = np.asarray(nu, float)
    fin = np.isfinite(nu)
    return np.where(fin, stdtrit(np.where(fin, np.maximum(nu, 1.0), 1.0), q) / z, 1.0)


def uncertainty(method: str, state: FitState) -> Uncertainty:
    """The ``sandwich`` method through the one interface (gprm.fit.methods)."""
    prior = state.prior
    if prior is None:
        raise ValueError("the sandwich uncertainty needs the fit's prior")
    syst = state.systematics if isinstance(state.systematics, Systematics) else Systematics()
    x = np.asarray(state.x, float)
    err = error_model(state.obj, x, state.J, state.r, prior, syst)
    parts = propagate(state.obj, x, state.J, prior, err)
    Ju, Hinv = _estimator(x, state.J, prior)
    # the residuals' kernel estimate's degrees of freedom: its Student factors (item 7 of
    # docs/fitting.md's default) and the excess test's reference distribution
    nu_res = residual_dof(Ju, Hinv, err.R, err.max_lag, err.p_eff, whitenings=err.whitenings,
                          projection=getattr(state.obj, "projection", None))
    mask = None
    # the covariance the posterior draws come from (the predictions' uncertainty)
    C_draws = parts.total
    if syst.excess_test is not None:
        mask = excess_mask(parts, nu_res, syst.excess_test)
        if mask is not None:
            # decided once at the best fit; every later propagation (the variance check's
            # points) carries the same error model
            err = replace(err, excess_mask=mask)
            parts = with_excess_mask(parts, mask)
            if syst.excess_test_draws:
                C_draws = parts.total
    u = prior.to_u(x)
    Cu = parts.total
    ones = np.ones(x.size)
    s_lo, s_hi = shape_factors(state.obj, x, Cu, Ju, prior) if syst.shape_check else \
        (ones, ones)
    sd_u = np.sqrt(np.clip(np.diag(Cu), 0.0, None))
    z95, z68 = ndtri(0.975), ndtri(0.84)
    v95 = variance_factors(state.obj, x, Cu, prior, err, z95) if syst.variance_check else \
        (ones, ones)
    v68 = variance_factors(state.obj, x, Cu, prior, err, z68) if syst.variance_check else \
        (ones, ones)
    f_lo, f_hi = np.maximum(s_lo, v95[0]), np.maximum(s_hi, v95[1])
    f68_lo, f68_hi = np.maximum(s_lo, v68[0]), np.maximum(s_hi, v68[1])
    U_alt, D_alt = alternative_minima(state.obj, x, state.alternatives, prior, Cu, state.lm)
    a95 = alternative_factors(u, sd_u, U_alt, D_alt, z95, LR_THRESHOLD[0.95])
    a68 = alternative_factors(u, sd_u, U_alt, D_alt, z68, LR_THRESHOLD[0.68])
    f_lo, f_hi = np.maximum(f_lo, a95[0]), np.maximum(f_hi, a95[1])
    f68_lo, f68_hi = np.maximum(f68_lo, a68[0]), np.maximum(f68_hi, a68[1])
    p95, p68 = profile_factors(state.obj, x, Cu, Hinv, prior, state.lm, (z95, z68)) \
        if syst.profile_check else ((ones, ones), (ones, ones))
    f_lo, f_hi = np.maximum(f_lo, p95[0]), np.maximum(f_hi, p95[1])
    f68_lo, f68_hi = np.maximum(f68_lo, p68[0]), np.maximum(f68_hi, p68[1])
    # the statistical share of the variance is estimated (from R runs, or from the
    # residuals by the kernel): Student's t with its Satterthwaite degrees of freedom
    # instead of the normal quantile
    nu = statistical_dof(parts, nu_res if syst.residual_dof else None)
    t95, t68 = student_factors(nu, 0.95), student_factors(nu, 0.68)
    f_lo, f_hi = f_lo * t95, f_hi * t95
    f68_lo, f68_hi = f68_lo * t68, f68_hi * t68
    lo95, hi95 = u - z95 * sd_u * f_lo, u + z95 * sd_u * f_hi
    lo68, hi68 = u - z68 * sd_u * f68_lo, u + z68 * sd_u * f68_hi
    contraction = sd_u * np.maximum(f_lo, f_hi) / prior.sd
    share = parts.share()
    # narrow, and mostly the data's variance (gprm.fit.uncertainty.determined)
    identified, leans = determined(contraction, share["prior"])
    # the reported covariance carries the wider side
    F = np.maximum(f_lo, f_hi)
    Cu_rep = Cu * np.outer(F, F)
    D = prior.dx_du(x)
    cov_x = Cu_rep * np.outer(D, D)
    # the draws keep the residuals' excess the parameters' own tests left out (unless
    # Systematics.excess_test_draws): a prediction combines parameters, and the excess along
    # a combination is untested (docs/fitting.md, "The residuals' excess tested per
    # parameter"); each is stretched by its parameter's interval factors
    L = normal_factor(C_draws)
    sd_draws = np.sqrt(np.clip(np.diag(C_draws), 0.0, None))
    f68_d, f95_d = (f68_lo, f68_hi), (f_lo, f_hi)
    # stop 57's development maps (Systematics.draws_stretch): "whitened" and "identified"
    # treat the identified parameters and the lags apart from the others
    mode = syst.draws_stretch
    apart = np.ones(x.size, bool)
    if mode in ("whitened", "identified"):
        apart = identified | np.array([n in LAG_PARAMETERS for n in state.obj.names], bool)
    if mode == "identified":
        f68_d, f95_d = masked(f68_d, apart), masked(f95_d, apart)
    R_half = symmetric_root(C_draws)[1] if mode.startswith("whitened") else None

    def propose(k: int, rnd: int = 0) -> np.ndarray:
        """k draws (offsets in u) of the Gaussian stretched to the intervals; proposal round
        ``rnd`` (0: the stream of stops 1-43)."""
        rng = np.random.default_rng([state.seed, 21] if rnd == 0 else [state.seed, 21, rnd])
        E = rng.standard_normal((int(k), x.size))
        if R_half is not None:
            return stretch_whitened(E, sd_draws, R_half, f68_d, f95_d, (z68, z95),
                                    whiten=apart)
        return stretch_draws(E @ L.T, sd_draws, f68_d, f95_d, (z68, z95))

    draws, draws_json = None, None           # draws_json: fit.json's account of them
    if state.n_draws > 0 and syst.project_draws:
        try:
            projected = project_draws(state.obj, x, propose, int(state.n_draws), state.lm,
                                      scale=inflation(Ju, Hinv, C_draws,
                                                      float(prior.weight) ** 2))
            draws, draws_json = projected.x, projected.to_json()
        except (np.linalg.LinAlgError, FloatingPointError, ValueError) as exc:
            # the intervals do not depend on it: the draws as drawn, and the file says why
            draws_json = {"not_projected": f"{type(exc).__name__}: {exc}"}
    if state.n_draws > 0 and draws is None:
        draws = prior.from_u(u[None] + propose(int(state.n_draws)))
    r = state.r
    # the variance scale the fit weighed its prior with (FitResult.objective rebuilds it)
    s2 = float(prior.weight) ** 2
    tau = s2 / max(float(r @ r) / max(state.obj.dof, 1), 1e-300)
    details = {
        "sources": {k: [float(v) for v in share[k]] for k in share},
        "statistical_from": "runs and residuals" if parts.runs is not None else
        "residuals (the mean-signals file has no runs)",
        "residual_over_runs": ([float(v) for v in np.sqrt(
            np.diag(parts.residuals) / np.clip(np.diag(parts.runs), 1e-300, None))]
            if parts.runs is not None else None),
        "systematics": {s: {"gain_sd": float(parts.gain_sd[i]),
                            "timing_sd_s": float(parts.timing_sd[i]),
                            "alignment_sd_s": float(parts.alignment_sd[i]),
                            # None: the means file predates it (not counted)
                            "sync_timing_sd_s": (None if err.sync_timing_sd is None
                                                 else float(err.sync_timing_sd[i])),
                            # None: no runs to read the drive's variation from
                            "drive_timing_sd_s": (None if err.drive_timing_sd is None
                                                  else float(err.drive_timing_sd[i])),
                            "crossing_offset_s": (float(err.crossing_offset[i])
                                                  if err.crossing_offset is not None else 0.0)}
                        for i, s in enumerate(state.obj.data.signals)},
        "degrees_of_freedom": [float(v) if np.isfinite(v) else None for v in nu],
        # the parameters the residuals' excess reached (Systematics.excess_test; None:
        # untested, every one the matrix positive part spills onto)
        "excess_reaches": None if mask is None else [bool(v) for v in mask],
        # whether the draws (the predictions) keep the excess the test left out
        "draws_excess": ("untested" if mask is None or not syst.excess_test_draws
                         else "tested"),
        "degrees_of_freedom_from": dof_sources(parts, nu),
        "stated": syst.to_json(),
        "gain_estimated": parts.gain_estimated,
        # the estimate's variance in units of its noise without gain errors: below ~2 it is
        # indistinguishable from none (used anyway: docs/fitting.md, "Where the clean
        # sources' width goes")
        "gain_estimated_z": float(err.gain_z),
        "max_lag": parts.max_lag, "p_eff": parts.p_eff,
        # the draws' projection onto the data (gprm.fit.draws; None: not projected)
        "draws": draws_json,
        "shape_factors": {"lower": [float(v) for v in s_lo], "upper": [float(v) for v in s_hi]},
        "variance_factors": {"lower": [float(v) for v in v95[0]],
                             "upper": [float(v) for v in v95[1]]},
        "profile_factors": {"lower": [float(v) for v in p95[0]],
                            "upper": [float(v) for v in p95[1]],
                            "lower_68": [float(v) for v in p68[0]],
                            "upper_68": [float(v) for v in p68[1]]},
        "alternative_minima": {
            "within_95": int(np.sum(D_alt <= LR_THRESHOLD[0.95])),
            "within_68": int(np.sum(D_alt <= LR_THRESHOLD[0.68])),
            "distinct": int(D_alt.size),
            "factors": {"lower": [float(v) for v in a95[0]],
                        "upper": [float(v) for v in a95[1]]}},
    }
    return Uncertainty(method, state.names, 0.5 * (cov_x + cov_x.T), prior.from_u(lo95),
                       prior.from_u(hi95), prior.from_u(lo68), prior.from_u(hi68), identified,
                       contraction, draws, s2, tau, details=details, leans_on_prior=leans)
