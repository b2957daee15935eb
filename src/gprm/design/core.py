"""Experimental design: which measurement determines what the fitted campaign could not
(issue 25; docs/design.md).

The measure of a design D (a set of blocks) is its expected posterior in the prior's
coordinates u: for each of the fit's posterior draws x_d (and the best fit),

    C_d(D) = [diag(1 / w^2) + sum_{b in D} F_b(x_d) / kappa]^-1,

with w the prior's sd (gprm.fit.prior), F_b the Fisher information of block b
(:mod:`gprm.design.information`) and kappa the calibration of the noise model to the fit (the
variance factor that makes the base campaign's predicted sd match the fit's reported sd, in
median over the identified parameters; 1 without a fit). The reported sd is sqrt(mean_d
diag C_d): the expected posterior variance over the fit's posterior, so that a design is not
judged at a single point. Where there is a fit, each parameter's sd is then multiplied by
s_k = (the fit's reported sd) / (the base campaign's sd from the line above): what the
noise model misses of the fit's own error (model mismatch the fit's sandwich sees, a
non-Gaussian valley) is carried over to every design, so that the base campaign reproduces
the fit and a candidate changes it by its information. The release predictions' sd is sqrt(diag(G C G^T)) with C the mean
of the C_d and G their gradients at the best fit (:mod:`gprm.design.predictions`).

Where the fit says how its variance splits (the default ``sandwich``: fit.json
``uncertainty.details``), the carry-over is done in **two parts** (:func:`variance_parts`):
the part of each parameter's variance that averages down over runs (the runs' spread, the
alignment) and the part that does not (the residuals' excess over the runs' spread: model
mismatch; the gain and stated timing errors; in older fits the time origin of t0). Each part
has its own information (``block_information(component=...)``), calibration kappa and
per-parameter carry-over, and a design's variance is their sum: more runs shrink only the
first. The first is split once more (:func:`_carry`): what the noise model explains at the
base (kappa 1), which shrinks with a design's information, and the excess, the mechanism
and its drive varying from run to run, which only more runs of the same measurement average
(:func:`same_measurement`; docs/design.md, "The runs' part: run-to-run variation"); the
share of that excess the runs' amplitude and timing errors explain through the fit's
estimator follows a design's window and channels instead
(:func:`gprm.design.information.run_error_leak`; "The part of E a window changes").
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from gprm.design.config import MODEL_CHANNELS, Block, Channel, DesignConfig
from gprm.design.information import (NoiseModel, RunErrorPieces, block_information,
                                     drive_signals, estimate_noise, run_error_leak,
                                     run_error_pieces)
from gprm.design.predictions import ReleasePredictions, release_predictions
from gprm.fit.files import FittedModel, load_model, read_fit_document, read_fit_sidecar
from gprm.fit.objective import DEFAULT_WINDOW
from gprm.fit.prior import DEFAULT_WIDTH, Prior, default_prior
from gprm.fit.uncertainty import determined
from gprm.params import ALIGNMENT_OFFSETS

#: the generator's noise when there is no fit to estimate it from (SynthConfig: white and
#: coloured interferometer noise; drive amplitude spread per run)
DEFAULT_NOISE = NoiseModel(float(np.hypot(4e-10, 3e-10)), 0.02)
Z95 = 1.959963984540054
#: the y-plane spring pair and the structural statement about it (docs/fitting.md)
Y_SPRINGS = ("k_Cy", "k_Dy")


@dataclass(frozen=True)
class DesignEvaluation:
    """One design (the base campaign plus ``additions``): expected posterior sd in u (P,),
    identified mask, 95 % intervals (SI), release predictions' sd (K,), cost in hours."""

    additions: tuple[str, ...]
    sd_u: np.ndarray
    identified: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    pred_sd: np.ndarray
    hours: float
    runs: int
    gain: dict = field(default_factory=dict)
    #: (P,) the prior's share of each parameter's expected variance (with ``sd_u``, what
    #: gprm.fit.uncertainty.determined counts identified or leaning on the prior by)
    prior_share: np.ndarray | None = None


@dataclass(frozen=True)
class DesignResult:
    names: tuple[str, ...]
    best: np.ndarray
    prior_sd: np.ndarray
    log: np.ndarray
    base: DesignEvaluation
    candidates: tuple[DesignEvaluation, ...]
    ranking: tuple[str, ...]
    recommended: DesignEvaluation
    selection: str
    predictions: ReleasePredictions
    noise: NoiseModel
    fit_sd_u: np.ndarray | None
    #: the carry-over: one part ("all") or two ("runs", "floor"); see variance_parts
    parts: tuple
    config: DesignConfig
    source: str
    base_block: Block
    synth: dict
    y_springs: dict
    timings: dict
    alone: tuple[dict, ...] = ()

    def evaluation(self, name: str) -> DesignEvaluation:
        for e in self.candidates:
            if e.additions == (name,):
                return e
        raise KeyError(name)


# ----------------------------------------------------------------------------- pieces
def _fit_window_and_rate(fm: FittedModel) -> tuple[tuple[float, float], float, dict | None]:
    """The fit's window, the data's sample rate and its sidecar data (sigma, model) where
    the model is a fit file; the defaults for ``paper``."""
    if fm.source == "paper":
        return DEFAULT_WINDOW, 200e3, None
    doc = read_fit_document(fm.source)
    w = doc.get("window") or list(DEFAULT_WINDOW)
    window = (float(w[0]), float(w[1]))
    try:
        side = read_fit_sidecar(fm.source)
    except Exception:                 # no usable sidecar: the defaults for the noise
        return window, 200e3, None
    t = np.asarray(side["time"].values, float)
    rate = float(np.round(1.0 / np.median(np.diff(t)))) if t.size > 1 else 200e3
    sig = np.asarray(side["data_sigma"].values, float)
    model = (np.asarray(side["model_best"].values, float) if "model_best" in side.variables
             else np.asarray(side["data_mean"].values, float))
    unc = doc.get("uncertainty") or {}
    det = unc.get("details") or {}
    syst = det.get("systematics") or {}
    s2 = unc.get("s2")
    res = (unc.get("adequacy") or {}).get("resonance") or {}
    resonance = ((float(res["frequency_hz"]), float(res["damping"]),
                  float(res.get("onset_shift_s", 0.0)))
                 if isinstance(res, dict) and "frequency_hz" in res else ())
    return window, rate, {
        "resonance": resonance,
        "sigma": sig, "model": model,
        "s2": float(s2) if isinstance(s2, (int, float)) and np.isfinite(s2) else 1.0,
        "gain": tuple((k, float(v.get("gain_sd") or 0.0)) for k, v in syst.items()
                      if isinstance(v, dict)),
        "align": tuple((k, _alignment_counted(v, det.get("stated") or {}, k))
                       for k, v in syst.items() if isinstance(v, dict)),
        # the synchronisation's hidden shifts, of the runs' noise and of their drive
        # (both average down over runs)
        "sync": tuple((k, float(np.hypot(float(v.get("sync_timing_sd_s") or 0.0),
                                         float(v.get("drive_timing_sd_s") or 0.0))))
                      for k, v in syst.items() if isinstance(v, dict))}


def _alignment_counted(entry: dict, stated: dict, signal: str) -> float:
    """s: the alignment noise the fit counted in ``signal``'s timing error: its timing sd
    beyond the stated one and the synchronisation's, of the runs' noise and (since stop 45)
    of their drive (the sandwich combines them in quadrature, and since stop 40 adds the
    alignment's only where the signal's own lag is held fixed: gprm.fit.sandwich); a file
    without the timing sd: its alignment sd."""
    a_sd = float(entry.get("alignment_sd_s") or 0.0)
    used = entry.get("timing_sd_s")
    if not isinstance(used, (int, float)):
        return a_sd
    per = (stated.get("per_signal") or {}).get(signal) or {}
    st = float(per.get("timing_sd_s", stated.get("timing_sd_s")) or 0.0)
    sync = float(entry.get("sync_timing_sd_s") or 0.0)
    drive = float(entry.get("drive_timing_sd_s") or 0.0)
    return float(min(a_sd, np.sqrt(max(float(used) ** 2 - st ** 2 - sync ** 2 - drive ** 2,
                                       0.0))))


def prior_of(fm: FittedModel, width: float | None = None) -> Prior:
    """The fit's prior (its documented default with the fit's width; gprm.fit.prior)."""
    if width is None:
        width = DEFAULT_WIDTH
        if fm.source != "paper":
            unc = read_fit_document(fm.source).get("uncertainty") or {}
            width = float(((unc.get("prior") or {}).get("width")) or DEFAULT_WIDTH)
    return default_prior(fm.params, fm.names, width)


def draws_of(fm: FittedModel, n: int, seed: int) -> np.ndarray:
    """(n, P) SI: the best fit and n - 1 of the fit's posterior draws."""
    x = fm.params.vector(fm.names)
    if n <= 1 or not fm.has_uncertainty:
        return x[None]
    pb = fm.sample(n - 1, seed)
    return np.vstack([x[None], np.stack([pb[k] for k in fm.names], 1)])


def block_hours(block: Block, cfg: DesignConfig, base: Block, name: str = "") -> float:
    c = cfg.cost
    per = block.runs * c.hours_per_run + block.noise_runs * c.hours_per_noise_run
    hours = per * len(block.channels) * len(block.drives)
    new_pos = [ch for ch in block.channels if ch.name not in base.channel_names]
    hours += c.hours_per_new_position * len(new_pos)
    same_profile = block.voltage == 1.0 and block.retraction == 1.0
    new_drives = [d for d in block.drives if not (same_profile and d in base.drives)]
    hours += c.hours_per_new_drive * len(new_drives)
    return float(hours + cfg.extra(name))


def _posterior(P0: np.ndarray, F: np.ndarray, kappa: float) -> np.ndarray:
    """(D, P, P) posterior covariances for information F (D, P, P)."""
    H = P0[None] + F / kappa
    return np.linalg.inv(H)


def _calibrate(P0: np.ndarray, F_base: np.ndarray, fit_sd: np.ndarray,
               mask: np.ndarray) -> float:
    """kappa such that median_k(sd_pred_k / sd_fit_k) = 1 over ``mask`` (bisection in
    log kappa over 1e-3 .. 1e6)."""
    def ratio(k):
        C = _posterior(P0, F_base, k)
        sd = _mean_sd(C)
        return float(np.median(sd[mask] / fit_sd[mask]))

    lo, hi = np.log(1e-3), np.log(1e6)
    if ratio(np.exp(lo)) >= 1:
        return float(np.exp(lo))
    if ratio(np.exp(hi)) <= 1:
        return float(np.exp(hi))
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if ratio(np.exp(mid)) < 1:
            lo = mid
        else:
            hi = mid
    return float(np.exp(0.5 * (lo + hi)))


def _gain(before: np.ndarray, after: np.ndarray, groups: np.ndarray) -> dict:
    """Geometric-mean factor by which the predictions' sd shrink, per group and overall
    (the mean of the groups' log factors)."""
    out = {}
    logs = []
    for g in ("overshoot", "velocity"):
        m = groups == g
        if m.any():
            lg = float(np.mean(np.log(before[m] / after[m])))
            out[g] = float(np.exp(lg))
            logs.append(lg)
    out["release"] = float(np.exp(np.mean(logs))) if logs else 1.0
    return out


def variance_parts(doc: dict, names: tuple[str, ...], fit_var: np.ndarray, x: np.ndarray,
                   log: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(A, B) (P,): the fit's variance in u (``fit_var``) split into the part that averages
    down over runs (A) and the part that does not (B), from what the sandwich recorded
    (fit.json ``uncertainty.details``; None where it did not: other methods, older files).

    Per parameter, of the variance shares (statistical, gain, timing, interpolation, prior):
    the statistical share is the larger of the runs' and the residuals' covariance; with
    rho = ``residual_over_runs``^2 (the residuals' variance over the runs'), 1/rho of it is
    the runs' (A) and the rest the residuals' excess, mismatch common to every run (B), but
    where the excess test left the excess out of the parameter's variance
    (``excess_reaches`` false: all of it the runs'). The
    gain share (stated and estimated gain errors) is B. The timing share is the alignment's
    (A) where no timing error is stated, else B; for t0 in fit files made before stop 39 the
    time origin's variance (``time_origin_sd_s``, then the crossing offset on t0; the default
    no longer adds it) is taken out of it into B. Interpolation and prior shares: A (they
    shrink as the data grow). A fit of mean signals without their runs (no
    ``residual_over_runs``) is not split."""
    unc = doc.get("uncertainty") or {}
    det = unc.get("details") or {}
    shares = det.get("variance_shares")
    rr = det.get("residual_over_runs")
    if not isinstance(shares, dict) or not all(n in shares for n in names):
        return None
    if not isinstance(rr, list) or len(rr) != len(names):
        return None                 # no runs in the mean-signals file: nothing to split by
    reach = det.get("excess_reaches")
    stated_t = float((det.get("stated") or {}).get("timing_sd_s") or 0.0)
    origin = float(det.get("time_origin_sd_s") or 0.0)
    A = np.zeros(len(names))
    B = np.zeros(len(names))
    for i, n in enumerate(names):
        sh = {k: float(v) if isinstance(v, (int, float)) and np.isfinite(v) else 0.0
              for k, v in shares[n].items()}
        tot = sum(sh.values())
        if not tot > 0 or not np.isfinite(fit_var[i]):
            return None
        st = sh.get("statistical", 0.0) / tot
        rho = float(rr[i]) ** 2 if isinstance(rr[i], (int, float)) else 1.0
        if isinstance(reach, list) and i < len(reach) and reach[i] is False:
            rho = 1.0           # the excess test left the residuals' excess out of it
        runs_frac = 1.0 / rho if rho > 1.0 else 1.0
        a = st * runs_frac + (sh.get("interpolation", 0.0) + sh.get("prior", 0.0)) / tot
        b = st * (1.0 - runs_frac) + sh.get("gain", 0.0) / tot
        t = sh.get("timing", 0.0) / tot
        if n == "t0" and origin > 0:
            o = min((origin / (x[i] if log[i] else 1.0)) ** 2 / fit_var[i], t)
            b, t = b + o, t - o
        if stated_t > 0:
            b += t
        else:
            a += t
        A[i], B[i] = a * fit_var[i], b * fit_var[i]
    return A, B


@dataclass(frozen=True)
class _Part:
    """One part of the carry-over: its base information, calibration and per-parameter
    scale (the fit's part sd over the calibrated model's); for the runs' part, the
    run-to-run variation (``per_run``, (P, P) covariance in u of the base campaign's mean
    of ``runs`` runs; None for the other parts): see :func:`_carry`."""

    component: str
    kappa: float
    scale: np.ndarray
    per_run: np.ndarray | None = None
    runs: int = 0
    #: (P,) the share of each parameter's run-to-run variance (diagonal of ``per_run``) that
    #: the runs' amplitude and timing errors explain through the fit's estimator
    #: (gprm.design.information.run_error_leak), and that leak's variance at the base
    #: (``leak_base``); None: not split (the whole carried as a covariance in u)
    explained: np.ndarray | None = None
    leak_base: np.ndarray | None = None

    def per_run_variance(self, runs: int, leak: np.ndarray | None = None) -> np.ndarray:
        """(P, P): the run-to-run part of a campaign that averages ``runs`` (> 0) runs of
        the base's measurement (the runs' part only). With ``leak`` (P,), the campaign's
        :func:`gprm.design.information.run_error_leak`, each parameter's ``explained``
        share follows the leak (leak / leak_base: how the campaign's window and channels
        separate a gain or a time shift from the parameter) and the rest the runs; the
        correlations are kept."""
        if self.per_run is None:
            raise ValueError(f"the {self.component} part has no run-to-run variation")
        if runs <= 0:
            raise ValueError(f"a campaign averages at least one run, got {runs}")
        r = self.runs / runs
        V = self.per_run * r
        if leak is None or self.explained is None or self.leak_base is None:
            return V
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(self.leak_base > 0, np.asarray(leak, float) / self.leak_base, r)
        f = np.sqrt(np.clip((self.explained * ratio + (1.0 - self.explained) * r) / r,
                            0.0, None))
        return V * np.outer(f, f)

    def with_leak(self, leak_base: np.ndarray) -> "_Part":
        """This part with its run-to-run variance split by the base campaign's leak
        (:func:`gprm.design.information.run_error_leak`): the share each parameter's leak
        explains, at most all of it."""
        if self.per_run is None:
            return self
        d = np.clip(np.diag(self.per_run), 0.0, None)
        with np.errstate(divide="ignore", invalid="ignore"):
            ex = np.where(d > 0, np.minimum(leak_base, d) / d, 0.0)
        return replace(self, explained=ex, leak_base=np.asarray(leak_base, float))


def _carry(P0: np.ndarray, F_base: np.ndarray, part_sd: np.ndarray, ident: np.ndarray,
           component: str, *, runs: int = 0) -> _Part:
    """The part's carry-over from the base campaign.

    The part that does not average down (``floor``, or ``all`` for an unsplit fit): kappa
    (median match over the identified parameters where the part is not negligible) and the
    per-parameter scale that makes the base reproduce it.

    The runs' part (``runs``, with the base's ``runs``): the fit's runs-part variance A is
    split into what the noise model's own information explains at the base, V = the
    posterior variance with kappa = 1 (white noise, the runs' amplitude spread and the
    alignment, as measured: they average down over runs *and* over samples), and the
    excess A - V where positive: the mechanism and its drive varying from run to run (each
    run a slightly different stiffness, drive amplitude, retraction time, trigger), which a
    campaign averages over its runs but not over a longer record or window
    (docs/design.md, "The runs' part: run-to-run variation"). The first keeps the
    per-parameter scale min(sqrt(A / V), 1); the second is kept as a covariance in u with
    the base posterior's correlations and variances A - V, and a design divides it by its
    number of runs of the same measurement."""
    if component == "runs" and runs > 0:
        C = _posterior(P0, F_base, 1.0)
        raw = _mean_sd(C)
        excess = np.clip(part_sd ** 2 - raw ** 2, 0.0, None)
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(raw > 0, np.minimum(part_sd / raw, 1.0), 0.0)
            Cm = C.mean(0)
            Cm = 0.5 * (Cm + Cm.T)
            d = np.sqrt(np.clip(np.diag(Cm), 0.0, None))
            corr = np.where(np.outer(d, d) > 0, Cm / np.outer(d, d), 0.0)
        np.fill_diagonal(corr, 1.0)
        e = np.sqrt(excess)
        return _Part(component, 1.0, np.where(np.isfinite(r), r, 0.0),
                     corr * np.outer(e, e), int(runs))
    mask = ident & (part_sd > 0)
    kappa = _calibrate(P0, F_base, part_sd, mask) if mask.any() else 1.0
    raw = _mean_sd(_posterior(P0, F_base, kappa))
    r = part_sd / raw
    return _Part(component, kappa, np.where(np.isfinite(r) & (r >= 0), r, 0.0))


def same_measurement(block: Block, base: Block) -> bool:
    """Whether ``block`` repeats the base campaign's measurement of the mechanism (every
    model position, the base's drives and voltage profile), so that its runs average the
    same run-to-run variation: more runs, or a longer record or window. Other positions,
    drives or voltage profiles are not counted (their runs' variation is not measured by the
    fit)."""
    return (set(MODEL_CHANNELS) <= set(block.channel_names) and block.drives == base.drives
            and block.voltage == base.voltage and block.retraction == base.retraction)


# ----------------------------------------------------------------------------- entry point
def run_design(model, config: DesignConfig | None = None, *, candidates_path=None,
               alone: tuple[Block, ...] = ()) -> DesignResult:
    """Evaluate the candidates of ``config`` (default: the documented set) as additions to
    the base campaign of ``model`` (a fit JSON, a run folder, ``paper`` or a FittedModel),
    rank them and select the best additions within the cost budget (docs/design.md).
    ``alone``: blocks whose prediction as a campaign of their own (what a fit of that
    campaign alone should report) is wanted too: ``result.alone`` (the validation's)."""
    t_start = time.perf_counter()
    fm = load_model(model)
    window, rate, data = _fit_window_and_rate(fm)
    if config is None:
        from gprm.design.config import read_design_config

        config = read_design_config(candidates_path, window=window)
    cfg = config
    names = fm.names
    prior = prior_of(fm)
    log = np.asarray(prior.log, bool)
    sd0 = np.asarray(prior.sd, float)
    P0 = np.diag(1.0 / sd0 ** 2)
    X = draws_of(fm, cfg.n_draws, cfg.seed)
    dx_du = np.where(log[None], X, 1.0)
    # the noise model
    if data is not None:
        n0, v = estimate_noise(data["sigma"], data["model"], cfg.base_runs)
        extra = {"mismatch": max(data["s2"] - 1.0, 0.0), "gain": data["gain"],
                 "align": data["align"], "sync": data["sync"],
                 "resonance": data["resonance"]}
    else:
        n0, v = DEFAULT_NOISE.white, DEFAULT_NOISE.variability
        extra = {}
    n0 = cfg.noise_white if cfg.noise_white is not None else n0
    v = cfg.variability if cfg.variability is not None else v
    noise1 = NoiseModel(n0, v, 1.0, base_runs=cfg.base_runs, base_rate=rate, **extra)
    base = Block(tuple(Channel(n) for n in MODEL_CHANNELS), (fm.piezo,), runs=cfg.base_runs,
                 noise_runs=cfg.base_noise_runs, record=max(1.5e-3, window[1]), rate=rate,
                 window=window)
    fitted_lags = tuple(ch for ch, off in ALIGNMENT_OFFSETS.items() if off in names)
    lag_sd = float(default_prior(fm.params, ("dt_x_head",)).sd[0])

    # the fit's own sd in u, and (the sandwich's) split of its variance into two parts
    fit_sd = None
    split = None
    xb = fm.params.vector(names)
    ident = np.zeros(len(names), bool)
    if fm.covariance is not None and fm.source != "paper":
        fit_sd = np.sqrt(np.clip(np.diag(fm.covariance), 0, None)) / np.where(log, xb, 1.0)
        ident = np.array([n in (fm.identified or ()) for n in names])
        if cfg.calibrate and n0 > 0:
            split = variance_parts(read_fit_document(fm.source), names, fit_sd ** 2, xb, log)
    comps = ("runs", "floor") if split is not None else ("all",)

    def terms(block: Block) -> tuple[dict, RunErrorPieces | None]:
        """The block's information per component and, where the runs' part is split off,
        its run errors (gprm.design.information.run_error_pieces): one simulation."""
        sig = drive_signals(fm.params, names, X, block, z_bk_absolute=fm.z_bk_absolute)
        F = {k: block_information(fm.params, names, X, dx_du, block, noise1,
                                  gain_sd=cfg.gain_sd, timing_sd=cfg.timing_sd,
                                  lag_sd=lag_sd, fitted_lag_channels=fitted_lags,
                                  z_bk_absolute=fm.z_bk_absolute, component=k, signals=sig)
             for k in comps}
        pieces = (run_error_pieces(fm.params, names, X, dx_du, block, noise1, signals=sig)
                  if split is not None else None)
        return F, pieces

    t0 = time.perf_counter()
    F_base, pieces_base = terms(base)
    cand_terms = {c.name: terms(c.block) for c in cfg.candidates}
    F_cand = {n: t[0] for n, t in cand_terms.items()}
    pieces_cand = {n: t[1] for n, t in cand_terms.items()}
    t_info = time.perf_counter() - t0
    # the calibration and the per-parameter carry-over: what the noise model misses of the
    # fit's sd, carried over to every design (docs/design.md)
    if split is not None:
        parts = tuple(_carry(P0, F_base[k], np.sqrt(v), ident, k, runs=base.runs)
                      for k, v in zip(comps, split))
    else:
        kappa = 1.0
        scale = np.ones(len(names))
        if fit_sd is not None and cfg.calibrate:
            if ident.any():
                kappa = _calibrate(P0, F_base["all"], fit_sd, ident)
            r = fit_sd / _mean_sd(_posterior(P0, F_base["all"], kappa))
            scale = np.where(np.isfinite(r) & (r > 0), r, 1.0)
        parts = (_Part("all", kappa, scale),)
    noise = replace(noise1, kappa=parts[0].kappa if len(parts) == 1 else 1.0)
    # the runs' amplitude and timing errors through each campaign's estimator: the share
    # of the run-to-run variation they explain follows a candidate's window and channels
    leak0 = np.zeros(len(names))
    if pieces_base is not None:
        leak0 = run_error_leak([pieces_base], P0)
        parts = tuple(p.with_leak(leak0) for p in parts)
    t0 = time.perf_counter()
    preds = release_predictions(fm, sd0, log)
    t_pred = time.perf_counter() - t0
    groups = np.array(preds.group)
    ub = prior.to_u(xb)
    hours_of = {c.name: block_hours(c.block, cfg, base, c.name) for c in cfg.candidates}
    runs_of = {c.name: c.block.runs * len(c.block.channels) * len(c.block.drives)
               for c in cfg.candidates}
    # the runs that average the base's run-to-run variation, per candidate
    repeats = {c.name: c.block.runs if same_measurement(c.block, base) else 0
               for c in cfg.candidates}

    def evaluate(adds: tuple[str, ...], ref: DesignEvaluation | None) -> DesignEvaluation:
        var = np.zeros(len(names))
        prior_var = np.zeros(len(names))
        Cm = np.zeros((len(names), len(names)))
        for part in parts:
            k = part.component
            F = F_base[k] + sum((F_cand[a][k] for a in adds), np.zeros_like(F_base[k]))
            C = _posterior(P0, F, part.kappa)
            var = var + _mean_sd(C) ** 2 * part.scale ** 2
            prior_var = prior_var + _prior_variance(C, P0) * part.scale ** 2
            Cm = Cm + C.mean(0) * np.outer(part.scale, part.scale)
            if part.per_run is not None:
                # an addition can be left out of the fit, so it never makes the runs'
                # errors reach a parameter more than at the base (the fit's weights are not
                # those that would minimise it with the added runs' own errors)
                leak = np.minimum(run_error_leak(
                    [pieces_base] + [pieces_cand[a] for a in adds], P0), leak0)
                V = part.per_run_variance(base.runs + sum(repeats[a] for a in adds), leak)
                var, Cm = var + np.diag(V), Cm + V
        sd = np.minimum(np.sqrt(var), sd0)
        psd = np.sqrt(np.clip(np.einsum("kp,pq,kq->k", preds.gradient, Cm, preds.gradient),
                              1e-300, None))
        lo = prior.from_u(ub - Z95 * sd)
        hi = prior.from_u(ub + Z95 * sd)
        gain = {} if ref is None else _gain(ref.pred_sd, psd, groups)
        share = prior_var / np.clip(var, 1e-300, None)
        return DesignEvaluation(adds, sd, _identified(sd, sd0, share, cfg.identified_threshold),
                                lo, hi, psd, float(sum(hours_of[a] for a in adds)),
                                int(sum(runs_of[a] for a in adds)), gain, share)

    base_ev = evaluate((), None)
    cands = tuple(evaluate((c.name,), base_ev) for c in cfg.candidates)
    ranking = tuple(e.additions[0] for e in sorted(
        cands, key=lambda e: (-e.gain["release"], e.hours, e.additions[0])))
    # selection within the budget
    budget, kmax = cfg.cost.budget, cfg.cost.max_additions
    affordable = [c.name for c in cfg.candidates if hours_of[c.name] <= budget]
    n_subsets = sum(math.comb(len(affordable), k) for k in range(1, kmax + 1))
    best = base_ev
    if n_subsets <= cfg.exhaustive_limit:
        selection = f"exhaustive over {n_subsets} subsets"
        for k in range(1, min(kmax, len(affordable)) + 1):
            for adds in itertools.combinations(affordable, k):
                if sum(hours_of[a] for a in adds) > budget:
                    continue
                ev = evaluate(adds, base_ev)
                if _better(ev, best):
                    best = ev
    else:
        selection = "greedy (largest gain per added hour)"
        chosen: tuple[str, ...] = ()
        while len(chosen) < kmax:
            spent = sum(hours_of[a] for a in chosen)
            opts = [a for a in affordable if a not in chosen and spent + hours_of[a] <= budget]
            if not opts:
                break
            evs = [evaluate(chosen + (a,), base_ev) for a in opts]
            cur = best.gain.get("release", 1.0)
            rate_ = [(np.log(e.gain["release"] / cur)) / max(hours_of[a], 1e-9)
                     for e, a in zip(evs, opts)]
            j = int(np.argmax(rate_))
            if rate_[j] <= 0:
                break
            chosen, best = chosen + (opts[j],), evs[j]
    synth = synth_configuration(best.additions, cfg, base)
    if synth["block"] is not None:
        synth["predicted"] = evaluate_block(fm, synth["block"], cfg, noise, P0, X, dx_du,
                                            prior, ub, sd0, lag_sd, fitted_lags, parts, base)
    alone_ev = tuple(evaluate_block(fm, b, cfg, noise, P0, X, dx_du, prior, ub, sd0, lag_sd,
                                    fitted_lags, parts, base) for b in alone)
    y = y_spring_statement(names, base_ev, cands, cfg)
    timings = {"information": round(t_info, 3), "predictions": round(t_pred, 3),
               "total": round(time.perf_counter() - t_start, 3)}
    return DesignResult(names, xb, sd0, log, base_ev, cands, ranking, best, selection, preds,
                        noise, fit_sd, parts, cfg, str(fm.source), base, synth, y, timings,
                        alone_ev)


def _prior_variance(C: np.ndarray, P0: np.ndarray) -> np.ndarray:
    """(P,) the prior's part of each parameter's variance, averaged over the draws: the mean
    of diag(C P0 C) for posterior covariances C (D, P, P) = (P0 + F / kappa)^-1 (the data's
    part is diag(C F C) / kappa; the two sum to diag C)."""
    return np.mean(np.einsum("dip,pq,dqi->di", C, P0, C), 0)


def _identified(sd: np.ndarray, sd0: np.ndarray, share: np.ndarray,
                threshold: float) -> np.ndarray:
    """Identified as a fit says it (gprm.fit.uncertainty.determined), the prior's ``share``
    of the variance from :func:`_prior_variance`."""
    return determined(sd / sd0, share, threshold)[0]


def _mean_sd(C: np.ndarray) -> np.ndarray:
    """(P,) the sd in u from a stack of posterior covariances (D, P, P): each parameter's
    variance averaged over the draws D, then its square root."""
    return np.sqrt(np.mean(np.diagonal(C, axis1=1, axis2=2), 0))


def _better(a: DesignEvaluation, b: DesignEvaluation) -> bool:
    ga, gb = a.gain.get("release", 1.0), b.gain.get("release", 1.0)
    if not np.isclose(ga, gb, rtol=1e-9):
        return ga > gb
    return a.hours < b.hours


def evaluate_block(fm: FittedModel, block: Block, cfg: DesignConfig, noise: NoiseModel,
                   P0, X, dx_du, prior: Prior, ub, sd0, lag_sd, fitted_lags,
                   parts: tuple[_Part, ...], base: Block) -> dict:
    """Predicted sd and 95 % intervals of a campaign made of ``block`` alone (what a fit of
    that campaign should report): the validation's prediction."""
    var = np.zeros(len(fm.names))
    prior_var = np.zeros(len(fm.names))
    noise1 = replace(noise, kappa=1.0)
    sig = drive_signals(fm.params, fm.names, X, block, z_bk_absolute=fm.z_bk_absolute)
    for part in parts:
        F = block_information(fm.params, fm.names, X, dx_du, block, noise1,
                              gain_sd=cfg.gain_sd, timing_sd=cfg.timing_sd, lag_sd=lag_sd,
                              fitted_lag_channels=fitted_lags, z_bk_absolute=fm.z_bk_absolute,
                              component=part.component, signals=sig)
        C = _posterior(P0, F, part.kappa)
        var = var + _mean_sd(C) ** 2 * part.scale ** 2
        prior_var = prior_var + _prior_variance(C, P0) * part.scale ** 2
        if part.per_run is not None:
            # a campaign of its own: its runs average the variation if it repeats the
            # base's measurement; else it is taken as the base's (not measured otherwise)
            runs = block.runs if same_measurement(block, base) else part.runs
            leak = run_error_leak([run_error_pieces(fm.params, fm.names, X, dx_du, block,
                                                    noise1, signals=sig)], P0)
            var = var + np.diag(part.per_run_variance(runs, leak))
    sd = np.minimum(np.sqrt(var), sd0)
    share = prior_var / np.clip(var, 1e-300, None)
    return {"sd_u": sd, "identified": _identified(sd, sd0, share, cfg.identified_threshold),
            "lower": prior.from_u(ub - Z95 * sd), "upper": prior.from_u(ub + Z95 * sd)}


def synth_configuration(additions: tuple[str, ...], cfg: DesignConfig, base: Block) -> dict:
    """The recommended campaign as ``gprm synth campaign`` options where the generator can
    make it as one campaign that ``gprm fit`` fits: the generator measures the ten positions
    with one piezo at the nominal voltage profile and 200 kHz, so the additions it can
    simulate within the base campaign are more runs of the five model positions (and a
    longer record, fitted over a longer window); the others are listed as not simulated,
    with the reason."""
    cands = {c.name: c for c in cfg.candidates}
    runs, noise_runs, t_end, w1 = base.runs, base.noise_runs, base.record, base.window[1]
    simulated, not_simulated = [], {}
    for a in additions:
        b = cands[a].block
        why = []
        if set(b.channel_names) != set(MODEL_CHANNELS):
            why.append("channels other than the five model positions")
        if b.drives != base.drives:
            why.append("another drive in the same campaign (a campaign of its own: "
                       "gprm synth campaign --piezo 1; gprm fit fits one drive at a time)")
        if b.voltage != 1.0 or b.retraction != 1.0:
            why.append("a voltage profile other than the nominal one")
        if b.rate != 200e3:
            why.append("a sample rate other than 200 kHz")
        if b.window[0] != base.window[0]:
            why.append("another window start")
        if why:
            not_simulated[a] = "gprm synth campaign cannot make " + ", ".join(why)
            continue
        simulated.append(a)
        runs += b.runs
        noise_runs = max(noise_runs, b.noise_runs)
        t_end = max(t_end, b.record)
        w1 = max(w1, b.window[1])
    block = None
    if not not_simulated:
        block = replace(base, runs=runs, noise_runs=noise_runs, record=t_end,
                        window=(base.window[0], w1))
    t_end_arg = t_end if t_end > 1.2e-3 else 1.5e-3
    return {"simulated": simulated, "not_simulated": not_simulated, "runs": runs,
            "noise_runs": noise_runs, "t_end": t_end_arg,
            "window": (base.window[0], w1),
            "synth_command": (f"gprm synth campaign --runs {runs} --noise-runs {noise_runs} "
                              f"--t-end {t_end_arg * 1e3:g}ms --piezo {base.drives[0]} "
                              "--truth TRUTH.toml --seed N --out campaign.nc"),
            "fit_command": (f"gprm fit means.nc --window {base.window[0] * 1e3:g}ms,"
                            f"{w1 * 1e3:g}ms --piezo {base.drives[0]} --out fit.json"),
            "block": block}


def y_spring_statement(names, base_ev: DesignEvaluation, cands, cfg: DesignConfig) -> dict:
    """Whether any candidate determines the y-plane spring pair, and why none can."""
    idx = [names.index(n) for n in Y_SPRINGS if n in names]
    if not idx:
        return {"fitted": False, "text": "k_Cy and k_Dy are not fitted"}
    which = [e.additions[0] for e in cands if all(e.identified[i] for i in idx)]
    contraction = {e.additions[0]: [float(e.sd_u[i]) for i in idx] for e in cands}
    if which:
        text = ("determined (posterior sd below "
                f"{cfg.identified_threshold:g} of the prior's) by: {', '.join(which)}")
    else:
        text = ("no candidate in the set determines k_Cy and k_Dy separately. Structurally: "
                "the two lateral springs at b1 and b1 + b2 act on the plunger, and on "
                "anything a laser can see (plunger points, tip, runner, the force on the "
                "runner), only through K0 = k_Cy + k_Dy, K1 = k_Cy b1 + k_Dy (b1 + b2) and "
                "K2 = k_Cy b1^2 + k_Dy (b1 + b2)^2 (docs/fitting.md): four parameters, three "
                "numbers, whatever the drive, voltage profile, position, record or sample "
                "rate. Only the dampers at the same points break the tie, and they act at "
                "the noise level. What determines the pair is information from outside the "
                "dynamics: a measured attachment point (b1 or b2) or a static stiffness "
                "test of one spring")
    return {"fitted": True, "determined_by": which, "text": text,
            "sd_u_base": [float(base_ev.sd_u[i]) for i in idx], "sd_u": contraction}
