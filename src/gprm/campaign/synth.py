"""Synthetic ground-test campaigns with known truth (``gprm synth campaign``).

The data come from a *richer* model than the one that is fitted, so a fit faces real-world
mismatch (docs/data-formats.md lists every ingredient and its size):

- the linear model (Eq. 2, exact batched solver) for every run, with run-to-run variability of
  the voltage drop (V0, tau_v) and of the mechanism parameters,
- the nonlinear correction: full nonlinear model minus linear model for the truth set,
  computed once and added to every run (shifted with the run's trigger offset),
- a small unmodelled, lightly damped higher mode excited at the retraction,
- flange and linear-runner motion (x_lr, y_lr, x_fl, y_fl, z_fl) from the forces the model's
  springs put on the runner, filtered by second-order supports (not part of the model),
- a random trigger offset per run (non-integer samples; applied exactly by moving the
  retraction command t_c of that run),
- interferometer noise (white + first-order low-pass coloured), slow drift and an arbitrary
  zero per run.

Everything is drawn from one ``numpy.random.default_rng(seed)``: same seed, same campaign.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import xarray as xr
from scipy.interpolate import CubicSpline
from scipy.signal import cont2discrete, lfilter

import gprm
from gprm.campaign.data import MODEL_POSITIONS, POSITIONS, campaign_dataset
from gprm.campaign.files import generator_attrs, truth_dataset
from gprm.errors import GprmInputError
from gprm.params import FITTED_DEFAULT, ParameterSet, batch, paper
from gprm.simulate import observe


@dataclass(frozen=True)
class Support:
    """A second-order support (flange or linear-runner degree of freedom): displacement =
    F / k filtered by omega^2 / (s^2 + 2 zeta omega s + omega^2), omega = 2 pi f."""

    k: float
    f: float
    zeta: float


@dataclass(frozen=True)
class SynthConfig:
    """Settings of a synthetic campaign (SI). Defaults: 10 actuated + 5 noise runs per
    position, 0..1.5 ms at 200 kHz (301 samples), 10 voltage runs at 1 MHz."""

    n_runs: int = 10
    n_noise: int = 5
    t_end: float = 1.5e-3
    rate: float = 200e3
    n_vruns: int = 10
    vrate: float = 1e6
    truth_spread: float = 0.05          # truth = paper * U(1 - s, 1 + s) on fitted parameters
    noise_white: float = 4e-10          # m, white interferometer noise std
    noise_coloured: float = 3e-10       # m, first-order low-pass noise std
    noise_corner: float = 5e3           # Hz, corner of the coloured noise
    drift_offset: float = 5e-9          # m, std of the arbitrary zero of each run
    drift_ramp: float = 3e-10           # m, std of the linear drift over the record
    drift_sine: float = 1.5e-10         # m, amplitude of a slow sinusoidal drift
    drift_freq: float = 300.0           # Hz
    trigger_max: float = 5.0            # samples, trigger offset ~ U(-max, max)
    v0_rel: float = 0.02                # relative std of the voltage drop amplitude per run
    tau_rel: float = 0.03               # relative std of tau_v per run
    param_rel: float = 0.003            # relative std of stiffness/damping per run
    mode_freq: float = 28e3             # Hz, unmodelled higher mode
    mode_zeta: float = 0.01
    mode_rel: float = 0.015             # its amplitude relative to each signal's peak
    nonlinear: bool = True              # add the nonlinear correction (slow: ~seconds)
    piezo: int = 2                      # the driven piezo (1 or 2; the campaign's drive)
    voltage_noise: float = 0.1          # V, white noise of the voltage traces
    runner_x: Support = field(default_factory=lambda: Support(6.5e7, 9e3, 0.05))
    runner_y: Support = field(default_factory=lambda: Support(5.2e7, 9e3, 0.05))
    flange_x: Support = field(default_factory=lambda: Support(1.4e8, 4e3, 0.1))
    flange_y: Support = field(default_factory=lambda: Support(3.0e8, 4e3, 0.1))
    flange_z: Support = field(default_factory=lambda: Support(3.6e7, 5e3, 0.1))

    @property
    def noise_std(self) -> float:
        """Injected interferometer noise std (white and coloured; drift excluded)."""
        return float(np.hypot(self.noise_white, self.noise_coloured))

    def validate(self) -> None:
        if self.n_runs < 2:
            raise GprmInputError(f"must be >= 2, got {self.n_runs}", field="--runs")
        if self.n_noise < 1:
            raise GprmInputError(f"must be >= 1, got {self.n_noise}", field="--noise-runs")
        if not (self.t_end > 1.2e-3 and np.isfinite(self.t_end) and self.t_end <= 0.1):
            raise GprmInputError(f"must be in (1.2 ms, 0.1 s], got {self.t_end}",
                                 field="--t-end")
        if not (self.rate > 0 and np.isfinite(self.rate)):
            raise GprmInputError(f"must be positive, got {self.rate}", field="--rate")
        if self.piezo not in (1, 2):
            raise GprmInputError(f"must be 1 or 2, got {self.piezo!r}", field="--piezo")


TRUTH_OVERSAMPLE = 10
"""The noise-free truth response is stored at this multiple of the record's sample rate."""

_VARIED = ("k_lr", "k_Ax", "k_Bx", "c_Ax", "c_Bx", "k_Cy", "k_Dy", "c_Cy", "c_Dy")
_STATE_NAMES = ("x_base", "x_head", "y_base", "y_head", "z_bk", "x_A", "y_A", "eta", "theta",
                "z_lr", "x_A_dot", "y_A_dot", "eta_dot", "theta_dot")


def draw_truth(rng: np.random.Generator, spread: float, base: ParameterSet | None = None
               ) -> ParameterSet:
    """Truth around the paper set: each fitted parameter times U(1 - spread, 1 + spread)."""
    base = paper() if base is None else base
    mult = rng.uniform(1 - spread, 1 + spread, size=len(FITTED_DEFAULT))
    return base.with_values(**{n: base[n] * m for n, m in zip(FITTED_DEFAULT, mult)})


def _support_filter(sup: Support, rate: float):
    """Exact discretisation (first-order hold: exact for piecewise-linear force) of the
    support's transfer function; returns lfilter coefficients (b, a)."""
    w = 2 * np.pi * sup.f
    A = np.array([[0.0, 1.0], [-w * w, -2 * sup.zeta * w]])
    B = np.array([[0.0], [w * w / sup.k]])
    C = np.array([[1.0, 0.0]])
    D = np.array([[0.0]])
    Ad, Bd, Cd, Dd, _ = cont2discrete((A, B, C, D), 1.0 / rate, method="foh")
    from scipy.signal import ss2tf

    b, a = ss2tf(Ad, Bd, Cd, Dd)
    return np.atleast_1d(b[0]), a


def _filt(sup: Support, rate: float, force: np.ndarray) -> np.ndarray:
    b, a = _support_filter(sup, rate)
    return lfilter(b, a, force, axis=-1)  # starts at rest (force is 0 before the retraction)


def mechanism_signals(pb: dict, y: dict, cfg: SynthConfig, rate: float | None = None) -> dict:
    """All ten laser positions from the model states of a batch: the five Eq. 3 outputs and
    the flange / linear-runner points driven by the forces of the model's springs and dampers
    on the linear runner (lateral) and of the runner's nex-line spring on the flange (axial).
    Arrays (B, T)."""
    P = {k: np.asarray(v)[:, None] for k, v in pb.items()}
    xa, eta = y["x_A"], y["eta"]
    ya, th = y["y_A"], y["theta"]
    d1, d12 = P["d1"], P["d1"] + P["d2"]
    b1, b12 = P["b1"], P["b1"] + P["b2"]
    Fx = (P["k_Ax"] * (xa + d1 * eta) + P["k_Bx"] * (xa + d12 * eta)
          + P["c_Ax"] * (y["x_A_dot"] + d1 * y["eta_dot"])
          + P["c_Bx"] * (y["x_A_dot"] + d12 * y["eta_dot"]))
    Fy = (P["k_Cy"] * (ya - b1 * th) + P["k_Dy"] * (ya - b12 * th)
          + P["c_Cy"] * (y["y_A_dot"] - b1 * y["theta_dot"])
          + P["c_Dy"] * (y["y_A_dot"] - b12 * y["theta_dot"]))
    Fz = P["k_lr"] * y["z_lr"]
    fs = cfg.rate if rate is None else rate
    out = {k: y[k] for k in MODEL_POSITIONS}
    out["x_lr"] = _filt(cfg.runner_x, fs, Fx)
    out["y_lr"] = _filt(cfg.runner_y, fs, Fy)
    out["x_fl"] = _filt(cfg.flange_x, fs, cfg.runner_x.k * out["x_lr"])
    out["y_fl"] = _filt(cfg.flange_y, fs, cfg.runner_y.k * out["y_lr"])
    out["z_fl"] = _filt(cfg.flange_z, fs, Fz)
    return out


def _observe_states(pb: dict, times: np.ndarray, source: str, piezo: int = 2) -> dict:
    obs = observe(pb, times, _STATE_NAMES, piezo=piezo)
    if not obs.ok.all():
        b = int(np.argmin(obs.ok))
        raise GprmInputError(f"parameter set {b} cannot be simulated: {obs.reason[b]}",
                             source=source, field="truth")
    return {n: obs.y[:, i] for i, n in enumerate(_STATE_NAMES)}


def nonlinear_correction(truth: ParameterSet, times: np.ndarray, piezo: int = 2) -> dict:
    """Full nonlinear minus linear response of the five model outputs for ``truth`` (m),
    driven by ``piezo``."""
    from gprm.simulate import simulate
    from gprm.simulate.nonlinear import simulate_nonlinear

    lin = simulate(truth, time=times, piezo=piezo)
    # rtol 1e-5: the correction (<= 2e-10 m) is then accurate to ~1e-13 m (checked against
    # rtol 1e-9), at a fraction of the cost
    nl = simulate_nonlinear(truth, time=times, rtol=1e-5, piezo=piezo)
    return {k: nl.outputs[k][0] - lin.outputs[k][0] for k in MODEL_POSITIONS}


def _mode(times, onset, amp, cfg, tau_v: float = 10e-6):
    """The unmodelled mode (frequency ``mode_freq``, damping ``mode_zeta``) excited from
    ``onset`` (B,) by a force pulse proportional to the rate of the voltage drop,
    exp(-s/tau_v): x'' + 2 zeta w x' + w^2 x ~ exp(-s/tau_v). Its response
    Im[(e^{lam s} - e^{-s/tau_v}) / (lam + 1/tau_v)] starts with zero value and slope, and is
    scaled so that its largest magnitude is ``amp`` (B,). Returns (B, T)."""
    w = 2 * np.pi * cfg.mode_freq
    lam = -cfg.mode_zeta * w + 1j * w * np.sqrt(1 - cfg.mode_zeta ** 2)
    a = 1.0 / tau_v
    s = times[None, :] - np.asarray(onset, float)[:, None]
    sp = np.clip(s, 0, None)
    g = np.imag((np.exp(lam * sp) - np.exp(-a * sp)) / (lam + a))
    ss = np.linspace(0, 10 / (cfg.mode_zeta * w + a), 20001)
    gmax = np.max(np.abs(np.imag((np.exp(lam * ss) - np.exp(-a * ss)) / (lam + a))))
    return np.where(s > 0, np.asarray(amp, float)[:, None] * g / gmax, 0.0)


def _coloured(rng, shape, cfg):
    a = np.exp(-2 * np.pi * cfg.noise_corner / cfg.rate)
    e = rng.standard_normal(shape)
    x0 = rng.standard_normal(shape[:-1] + (1,))
    b = [np.sqrt(1 - a * a)]
    y, _ = lfilter(b, [1.0, -a], e, axis=-1, zi=a * x0)
    return cfg.noise_coloured * y


def _noise_and_drift(rng, shape, times, cfg):
    white = cfg.noise_white * rng.standard_normal(shape)
    col = _coloured(rng, shape, cfg)
    lead = shape[:-1]
    offset = cfg.drift_offset * rng.standard_normal(lead + (1,))
    ramp = cfg.drift_ramp * rng.standard_normal(lead + (1,)) * (times / times[-1])
    phase = rng.uniform(0, 2 * np.pi, lead + (1,))
    sine = cfg.drift_sine * np.sin(2 * np.pi * cfg.drift_freq * times + phase)
    return white + col + offset + ramp + sine


def synth_campaign(truth: ParameterSet | None = None, *, seed: int = 0,
                   config: SynthConfig | None = None, correction: dict | None = None
                   ) -> xr.Dataset:
    """Generate a synthetic campaign Dataset (see the module docstring). ``truth``: the true
    parameter set (default: drawn around the paper set with ``seed``). ``correction``: the
    nonlinear correction of this truth on the record's times, if already computed
    (:func:`nonlinear_correction`; it depends on the truth only, so a parametric bootstrap
    computes it once for all its campaigns)."""
    cfg = SynthConfig() if config is None else config
    cfg.validate()
    rng = np.random.default_rng(seed)
    truth_given = truth is not None
    if truth is None:
        truth = draw_truth(rng, cfg.truth_spread)
    src = truth.source if truth_given else "truth"
    n = int(np.floor(cfg.t_end * cfg.rate + 1e-9)) + 1
    times = np.arange(n) / cfg.rate
    dt = 1.0 / cfg.rate
    P, R = len(POSITIONS), cfg.n_runs

    # nominal (noise-free) response of the truth: linear + nonlinear correction + mode, on a
    # grid TRUTH_OVERSAMPLE times finer than the record (so checks need not interpolate it)
    fine = np.arange((n - 1) * TRUTH_OVERSAMPLE + 1) / (cfg.rate * TRUTH_OVERSAMPLE)
    tb = batch([truth])
    nominal = mechanism_signals(tb, _observe_states(tb, fine, src, cfg.piezo), cfg,
                                rate=cfg.rate * TRUTH_OVERSAMPLE)
    if not cfg.nonlinear:
        corr = {}
    else:
        corr = (nonlinear_correction(truth, times, cfg.piezo) if correction is None
                else correction)
    for k, c in corr.items():
        nominal[k] = nominal[k] + CubicSpline(times, c)(fine)[None]
    peak = {k: float(np.max(np.abs(nominal[k]))) for k in POSITIONS}
    onset0 = truth["t_c"] + truth["t0"]
    mode_amp = {k: cfg.mode_rel * peak[k] if k in MODEL_POSITIONS else 0.0 for k in POSITIONS}
    lag = {k: truth["t1"] if k == "z_bk" else 0.0 for k in POSITIONS}   # z laser lag (Eq. 3)
    clean = np.stack([nominal[k][0] + _mode(fine, np.array([onset0 + lag[k]]),
                                            np.array([mode_amp[k]]), cfg, truth["tau_v"])[0]
                      for k in POSITIONS])

    # per-run variability and trigger offsets (run (p, r) is retraction p*R + r)
    B = P * R
    pb = batch([truth] * B)
    v0_mult = 1 + cfg.v0_rel * rng.standard_normal(B)
    pb["V0"] = pb["V0"] * v0_mult
    pb["tau_v"] = pb["tau_v"] * (1 + cfg.tau_rel * rng.standard_normal(B))
    for name in _VARIED:
        pb[name] = pb[name] * (1 + cfg.param_rel * rng.standard_normal(B))
    offset = rng.uniform(-cfg.trigger_max, cfg.trigger_max, B) * dt
    pb["t_c"] = pb["t_c"] + offset
    runs = mechanism_signals(pb, _observe_states(pb, times, src, cfg.piezo), cfg)
    disp = np.empty((P, R, n))
    for i, k in enumerate(POSITIONS):
        sl = slice(i * R, (i + 1) * R)
        y = runs[k][sl].copy()
        if k in corr:
            cs = CubicSpline(times, corr[k])
            tt = times[None, :] - offset[sl, None]
            y += np.where(tt < times[0], 0.0, cs(np.clip(tt, times[0], times[-1])))
        y += _mode(times, onset0 + lag[k] + offset[sl], mode_amp[k] * v0_mult[sl], cfg,
                   truth["tau_v"])
        disp[i] = y
    disp += _noise_and_drift(rng, disp.shape, times, cfg)
    noise = _noise_and_drift(rng, (P, cfg.n_noise, n), times, cfg)

    # voltage traces of retraction runs (oscilloscope, faster sampling, no lag t0)
    nv = int(np.floor(cfg.t_end * cfg.vrate + 1e-9)) + 1
    vtime = np.arange(nv) / cfg.vrate
    v0 = truth["V0"] * (1 + cfg.v0_rel * rng.standard_normal(cfg.n_vruns))
    tau = truth["tau_v"] * (1 + cfg.tau_rel * rng.standard_normal(cfg.n_vruns))
    tcv = truth["t_c"] + rng.uniform(-cfg.trigger_max, cfg.trigger_max, cfg.n_vruns) * dt
    s = vtime[None, :] - tcv[:, None]
    volt = np.where(s <= 0, v0[:, None],
                    v0[:, None] * np.exp(-np.clip(s, 0, None) / tau[:, None]))
    volt = volt + cfg.voltage_noise * rng.standard_normal(volt.shape)

    attrs = {
        "title": "synthetic GPRM ground-test campaign (gprm synth campaign)",
        "source": "gprm synth campaign", "synthetic": 1, "seed": int(seed),
        "truth_source": truth.source if truth_given else f"drawn around paper (seed {seed})",
        **generator_attrs(cfg), "noise_std_injected": cfg.noise_std,
        "t_c": float(truth["t_c"]), "gprm_version": gprm.__version__,
        "voltage_sample_rate": float(cfg.vrate),
    }
    extra = {
        "trigger_offset": (("position", "run"), offset.reshape(P, R),
                           {"units": "s", "long_name": "injected trigger offset (the "
                            "retraction command of the run is at t_c + offset)"}),
        "truth_displacement": (("position", "truth_time"), clean,
                               {"units": "m", "long_name": "noise-free response of the truth "
                                "(nominal voltage, no offset, no variability, no drift)"}),
    }
    ds = campaign_dataset(disp, noise, times, sample_rate=cfg.rate, voltage=volt,
                          vtime=vtime, attrs=attrs, extra=extra)
    ds = ds.assign_coords(truth_time=("truth_time", fine, {
        "units": "s", "long_name": f"time of the noise-free truth ({TRUTH_OVERSAMPLE}x the "
        "record's sample rate)"}))
    return ds.merge(truth_dataset(dict(truth.values)))
