"""Fisher information of a measurement block about the fitted parameters, in the prior's
coordinates u (ln x for positive parameters, x for signed ones; gprm.fit.prior).

For one channel c of a block, with mean signal y_c(t; x) over R runs at the samples t_i of
the fit window, the noise model (docs/design.md) is

    mean = model + e_white + a_c y_c + tau_c dy_c/dt,
    e_white ~ N(0, n0^2 / R) per sample,
    a_c ~ N(0, g^2 + v^2 / R)      (the channel's gain error g and the runs' amplitude
                                    spread v, which averages down over R runs),
    tau_c ~ N(0, s_t^2)            (its timing error; a channel not in the fitted set also
                                    gets its own alignment lag, sd that of the fit's
                                    alignment offsets' prior),

and its information is J^T (n0^2/R I + V S V^T)^-1 J with J = d y_c / d u and V = [y_c,
dy_c/dt]: the nuisances a_c and tau_c marginalised (Woodbury). Channels are measured in
separate runs, so their information adds, and so does that of the block's drives.

Where the fit found an unmodelled resonance (gprm.fit.resonance; fit.json
``uncertainty.adequacy.resonance``), each channel also carries it as the fit does: its
response to the block's drive (the same frequency and damping, the channel's own onset) with
a free amplitude and phase, two more columns of V with no prior (their information is lost
whatever the runs), so that a design is credited only with what the fit can use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gprm.design.config import Block, Channel
from gprm.params import ParameterSet, batch_from_vectors
from gprm.simulate import observe
from gprm.simulate.kinematics import actuation_axis, named_points

#: the states a custom channel is built from (its linearised displacement)
_STATES = ("x_A", "y_A", "z_lr", "z_A", "eta", "theta", "mu4")


@dataclass(frozen=True)
class NoiseModel:
    """The data's error as the fit measured it (docs/design.md, "Noise model").

    white: n0, m per sample and run; variability: v, the runs' relative amplitude spread;
    mismatch: m2, the model mismatch's variance per sample in units of the base campaign's
    squared standard error (n0^2 + v^2 y^2) / base_runs, at base_rate (the fit's s2 - 1):
    it does not average down over runs, and its information per unit time does not grow with
    the sample rate (the mismatch is smooth); gain: the per-channel gain sd the fit used
    (stated and estimated from the residuals, which more runs do not reduce); align: the
    alignment's timing sd per channel at base_runs (it falls as 1/sqrt(runs)); sync: the
    time shift the runs' synchronisation hides from their spread, per channel at base_runs
    (gprm.campaign.preprocess.sync_timing_sd; it falls as 1/sqrt(runs) too).
    ``kappa`` scales every variance (the calibration to the fit's reported sd).
    """

    white: float
    variability: float
    kappa: float = 1.0
    mismatch: float = 0.0
    base_runs: int = 10
    base_rate: float = 200e3
    gain: tuple[tuple[str, float], ...] = ()
    align: tuple[tuple[str, float], ...] = ()
    sync: tuple[tuple[str, float], ...] = ()
    #: (frequency Hz, damping, onset shift s) of the unmodelled resonance the fit
    #: marginalised, or () where it found none
    resonance: tuple = ()

    def gain_of(self, channel: str) -> float:
        d = dict(self.gain)
        if channel in d:
            return d[channel]
        return float(np.median(list(d.values()))) if d else 0.0

    def align_of(self, channel: str) -> float:
        return dict(self.align).get(channel, 0.0)

    def sync_of(self, channel: str) -> float:
        """s at base_runs: the fit's value for a channel it had; for another channel the
        median of the fit's (its slope and noise unknown to the fit), 0 without any."""
        d = dict(self.sync)
        if channel in d:
            return d[channel]
        return float(np.median(list(d.values()))) if d else 0.0


def window_times(block: Block) -> np.ndarray:
    """The sample times of the block's fit window (s)."""
    k0 = int(np.ceil(block.window[0] * block.rate - 1e-9))
    k1 = int(np.floor(block.window[1] * block.rate + 1e-9))
    return np.arange(k0, k1 + 1) / block.rate


def _channel_coefficients(ch: Channel, pb: dict, names: tuple[str, ...]):
    """Coefficients (B, n_states) of the channel's displacement over ``_STATES`` and their
    derivatives {name: (B, n_states)} w.r.t. the parameters they depend on (gamma, rho
    through the actuation axis of a tip point)."""
    B = pb["t0"].shape[0]
    if ch.point:
        r = named_points({k: v[:1] for k, v in pb.items()})[ch.point].r[0]
        r = np.broadcast_to(r, (B, 3))      # the named point at the best fit, held fixed
    else:
        r = np.broadcast_to(np.asarray(ch.at, float), (B, 3))
    rx, ry, rz = r[:, 0], r[:, 1], r[:, 2]
    one, zero = np.ones(B), np.zeros(B)
    if ch.body == "runner":
        c = np.stack([zero, zero, one, zero, zero, zero, zero], -1)
        return c, {}
    if ch.axis == "x":
        c = np.stack([one, zero, zero, zero, rz, zero, zero], -1)
    elif ch.axis == "y":
        c = np.stack([zero, one, zero, zero, zero, -rz, zero], -1)
    else:
        c = np.stack([zero, zero, one, one, -rx, ry, zero], -1)
    dc: dict[str, np.ndarray] = {}
    if ch.body == "tip":
        k = "xyz".index(ch.axis)
        u = actuation_axis(pb)
        c[:, 6] = u[:, k]
        g, rho = pb["gamma"], pb["rho"]
        du = {"gamma": np.stack([np.cos(g), -np.sin(g) * np.sin(rho),
                                 -np.sin(g) * np.cos(rho)], -1),
              "rho": np.stack([zero, np.cos(g) * np.cos(rho), -np.cos(g) * np.sin(rho)], -1)}
        for n, d in du.items():
            if n in names:
                m = np.zeros_like(c)
                m[:, 6] = d[:, k]
                dc[n] = m
    return c, dc


def block_signals(params: ParameterSet, names: tuple[str, ...], X: np.ndarray, block: Block,
                  drive: int, *, z_bk_absolute: bool = False):
    """Model signals y (B, C, T), their sensitivities dy/dx (B, C, T, P) and time
    derivatives (B, C, T) of the block's channels under one drive, for parameter rows X
    (B, P, SI). Rows that cannot be simulated come back as NaN."""
    pb = batch_from_vectors(params, names, X)
    pb["V0"] = pb["V0"] * block.voltage
    pb["tau_v"] = pb["tau_v"] * block.retraction
    t = window_times(block)
    outs = tuple(c.name for c in block.channels if c.is_model_output)
    custom = tuple(c for c in block.channels if not c.is_model_output)
    obs_names = outs + (_STATES if custom else ())
    extra = () if "t0" in names else ("t0",)
    sens = tuple(names) + extra
    obs = observe(pb, t, obs_names, piezo=drive, sensitivities=sens,
                  z_bk_absolute=z_bk_absolute)
    y, dy = obs.y, obs.dy
    ys, dys = [], []
    for i, _ in enumerate(outs):
        ys.append(y[:, i])
        dys.append(dy[:, i])
    if custom:
        s = y[:, len(outs):]                          # (B, 7, T)
        ds = dy[:, len(outs):]                        # (B, 7, T, P+)
        for ch in custom:
            c, dc = _channel_coefficients(ch, pb, names)
            ys.append(np.einsum("bk,bkt->bt", c, s))
            d = np.einsum("bk,bktp->btp", c, ds)
            for n, m in dc.items():
                d[:, :, sens.index(n)] += np.einsum("bk,bkt->bt", m, s)
            dys.append(d)
    Y = np.stack(ys, 1)
    D = np.stack(dys, 1)
    ydot = -D[..., sens.index("t0")]                   # y(t - t0): dy/dt = -dy/dt0
    return Y, D[..., :len(names)], ydot


def drive_signals(params: ParameterSet, names: tuple[str, ...], X: np.ndarray, block: Block,
                  *, z_bk_absolute: bool = False) -> dict:
    """{drive: :func:`block_signals`} for each of the block's drives: the one simulation of a
    block that its information components and its run errors (:func:`run_error_pieces`)
    share."""
    return {d: block_signals(params, names, X, block, d, z_bk_absolute=z_bk_absolute)
            for d in block.drives}


def resonance_columns(params: ParameterSet, names: tuple[str, ...], X: np.ndarray,
                      block: Block, resonance: tuple) -> np.ndarray:
    """(B, C, T, 2): Re and Im of the resonance's response (gprm.fit.resonance.response) in
    each channel of the block's window, from each row's drive onset (t_c + t0 + the
    channel's lags for a model output) with the block's retraction time constant."""
    from gprm.fit.resonance import response
    from gprm.simulate.core import ROW_LAGS

    f, zeta, shift = resonance
    pb = batch_from_vectors(params, names, X)
    t = window_times(block)
    tau = np.asarray(pb["tau_v"], float) * block.retraction
    base = np.asarray(pb["t_c"], float) + np.asarray(pb["t0"], float) + shift
    out = np.zeros((X.shape[0], len(block.channels), t.size, 2))
    for ci, ch in enumerate(block.channels):
        lags = ROW_LAGS.get(ch.name, ()) if ch.is_model_output else ()
        on = base + sum(np.asarray(pb[n], float) for n in lags)
        for b in range(X.shape[0]):
            g = response(t, float(on[b]), float(tau[b]), f, zeta)
            out[b, ci, :, 0], out[b, ci, :, 1] = g.real, g.imag
    return out


#: the error components block_information can be restricted to (docs/design.md, "Two parts")
COMPONENTS = ("all", "runs", "floor")
#: the floor component's mismatch where the fit shows none, relative to the base campaign's
#: squared standard error: a level far below the noise, so that the floor is then carried by
#: the systematics (gain, timing) alone without dividing by a zero variance
MIN_FLOOR_MISMATCH = 1e-3


def block_information(params: ParameterSet, names: tuple[str, ...], X: np.ndarray,
                      dx_du: np.ndarray, block: Block, noise: NoiseModel, *,
                      gain_sd: float, timing_sd: float, lag_sd: float,
                      fitted_lag_channels=(), z_bk_absolute: bool = False,
                      component: str = "all", signals: dict | None = None) -> np.ndarray:
    """Fisher information (B, P, P) in u of one block at each parameter row X (B, P).

    ``gain_sd``, ``timing_sd``: the instrument's systematics (the block's own where it states
    them); ``lag_sd``: the sd of the own alignment lag of a channel that is neither one of
    ``fitted_lag_channels`` (whose lags are fitted parameters) nor x_base (the reference of
    t0). ``component``: ``all`` the whole noise model; ``runs`` only the error that averages
    down over the block's runs (white noise n0^2/R, the runs' amplitude spread v^2/R, the
    alignment's and the synchronisation's timing sd^2 x base_runs/R); ``floor`` only the error that does not (the model
    mismatch, the gain and stated timing errors). The own-lag nuisance is marginalised in
    both. ``signals``: :func:`drive_signals` of this block at these rows where the caller
    has them (one simulation for several components); None: simulated here."""
    if component not in COMPONENTS:
        raise ValueError(f"component must be one of {COMPONENTS}, got {component!r}")
    runs_part = component in ("all", "runs")
    floor_part = component in ("all", "floor")
    mismatch = noise.mismatch if component != "floor" else max(noise.mismatch,
                                                                 MIN_FLOOR_MISMATCH)
    g = block.gain_sd if block.gain_sd is not None else gain_sd
    ts = block.timing_sd if block.timing_sd is not None else timing_sd
    B, P = X.shape
    F = np.zeros((B, P, P))
    R = block.runs
    k = noise.kappa
    if signals is None:
        signals = drive_signals(params, names, X, block, z_bk_absolute=z_bk_absolute)
    for drive in block.drives:
        Y, D, Yd = signals[drive]
        Ju = D * dx_du[:, None, None, :]                        # (B, C, T, P)
        G = (resonance_columns(params, names, X, block, noise.resonance)
             if noise.resonance else None)
        for ci, ch in enumerate(block.channels):
            own_lag = not (ch.is_model_output and (ch.name == "x_base" or ch.name == "z_bk"
                                                   or ch.name in fitted_lag_channels))
            y = Y[:, ci]
            sem2 = (noise.white ** 2 + noise.variability ** 2 * y ** 2) / noise.base_runs
            var_w = k * (runs_part * noise.white ** 2 / R
                         + floor_part * mismatch * sem2 * block.rate / noise.base_rate)  # (B, T)
            var_a = k * (floor_part * (g ** 2 + noise.gain_of(ch.name) ** 2)
                         + runs_part * noise.variability ** 2 / R)
            var_t = k * (floor_part * ts ** 2
                         + runs_part * (noise.align_of(ch.name) ** 2
                                        + noise.sync_of(ch.name) ** 2) * noise.base_runs / R
                         + (lag_sd ** 2 if own_lag else 0.0))
            w = 1.0 / np.sqrt(var_w)
            J = Ju[:, ci] * w[..., None]                        # (B, T, P)
            V, s2 = [], []
            if var_a > 0:
                V.append(y * w)
                s2.append(var_a)
            if var_t > 0:
                V.append(Yd[:, ci] * w)
                s2.append(var_t)
            if G is not None:
                # the resonance's amplitude and phase: free (no prior)
                V += [G[:, ci, :, 0] * w, G[:, ci, :, 1] * w]
                s2 += [np.inf, np.inf]
            Fc = np.einsum("btp,btq->bpq", J, J)
            if V:
                Vm = np.stack(V, -1)                            # (B, T, k)
                VJ = np.einsum("btk,btp->bkp", Vm, J)
                VV = np.einsum("btk,btl->bkl", Vm, Vm)
                M = VV + np.diag(1.0 / np.asarray(s2))[None]
                if G is not None:
                    # a free column that is zero in this window (onset after it) carries
                    # nothing: a ridge far below the columns' own scale keeps M invertible
                    idx = np.arange(len(s2) - 2, len(s2))
                    dv = VV[:, idx, idx]
                    M[:, idx, idx] += np.where(dv > 0, 1e-12 * dv, 1.0)
                Fc = Fc - np.einsum("bkp,bkq->bpq", VJ, np.linalg.solve(M, VJ))
            F += Fc
    return 0.5 * (F + np.swapaxes(F, 1, 2))


def estimate_noise(data_sigma: np.ndarray, model: np.ndarray, runs: int) -> tuple[float, float]:
    """(n0, v) of :class:`NoiseModel` from a fit's data: its sigma (the standard error of the
    mean, per signal and sample) times sqrt(runs) is the runs' spread, modelled as
    n0^2 + v^2 y^2 (non-negative least squares on the relative misfit)."""
    from scipy.optimize import nnls

    s2 = (np.asarray(data_sigma, float) ** 2 * runs).ravel()
    y2 = (np.asarray(model, float) ** 2).ravel()
    ok = np.isfinite(s2) & np.isfinite(y2) & (s2 > 0)
    A = np.stack([np.ones(ok.sum()), y2[ok]], 1) / s2[ok, None]
    sol, _ = nnls(A, np.ones(ok.sum()))
    return float(np.sqrt(sol[0])), float(np.sqrt(sol[1]))


@dataclass(frozen=True)
class RunErrorPieces:
    """One block's share of :func:`run_error_leak`: its weighted information ``H`` (B, P, P)
    (no nuisance marginalised: the fit's own estimator) and ``cols`` (K, B, P), for each of
    its channels' mean amplitude and timing errors J^T W times the error's signature (the
    channel's signal and its time derivative) scaled by the error's sd at the block's
    runs."""

    H: np.ndarray
    cols: np.ndarray


def run_error_pieces(params: ParameterSet, names: tuple[str, ...], X: np.ndarray,
                     dx_du: np.ndarray, block: Block, noise: NoiseModel, *,
                     z_bk_absolute: bool = False, signals: dict | None = None
                     ) -> RunErrorPieces:
    """The pieces of :func:`run_error_leak` for one block at the parameter rows X (B, P);
    ``signals`` as :func:`block_information` takes them."""
    B, P = X.shape
    R = block.runs
    H = np.zeros((B, P, P))
    cols = []
    if signals is None:
        signals = drive_signals(params, names, X, block, z_bk_absolute=z_bk_absolute)
    for drive in block.drives:
        Y, D, Yd = signals[drive]
        Ju = D * dx_du[:, None, None, :]
        for ci, ch in enumerate(block.channels):
            y = Y[:, ci]
            # the fit's weights: one over the standard error of the block's mean
            w = np.sqrt(R / (noise.white ** 2 + noise.variability ** 2 * y ** 2))
            J = Ju[:, ci] * w[..., None]                        # (B, T, P)
            H += np.einsum("btp,btq->bpq", J, J)
            amp = noise.variability / np.sqrt(R)
            tim = np.hypot(noise.align_of(ch.name), noise.sync_of(ch.name)) * np.sqrt(
                noise.base_runs / R)
            cols.append(np.einsum("btp,bt->bp", J, y * w) * amp)
            cols.append(np.einsum("btp,bt->bp", J, Yd[:, ci] * w) * tim)
    return RunErrorPieces(H, np.asarray(cols).reshape(-1, B, P))


def run_error_leak(pieces, P0: np.ndarray) -> np.ndarray:
    """(P,) the variance in u, averaged over the draws, that the runs' amplitude and timing
    errors of the channels' means put into a campaign's estimate: each error e_k with
    signature s_k moves the weighted least-squares estimate (prior precision P0) by
    (P0 + J^T W J)^-1 J^T W s_k e_k. ``pieces``: :func:`run_error_pieces` of the campaign's
    blocks (their information and errors add; channels are measured in separate runs).

    The amplitude sd is the noise model's runs' spread v / sqrt(R) and the timing sd the
    alignment's and the synchronisation's at R runs; unlike the Fisher information of
    :func:`block_information`, which marginalises them as nuisances, the fit's estimator
    does not, so they reach the parameters, the more so the less the window tells a
    parameter's signature from a gain or a time shift (docs/design.md, "The runs' part:
    run-to-run variation")."""
    pieces = list(pieces)
    H = P0[None] + sum(p.H for p in pieces)
    cols = np.concatenate([p.cols for p in pieces])              # (K, B, P)
    G = np.linalg.solve(H[None], cols[..., None])[..., 0]         # (K, B, P)
    return np.mean(np.sum(G ** 2, axis=0), axis=0)
