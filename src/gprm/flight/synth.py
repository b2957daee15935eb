"""Synthetic release telemetry with known impact times (``gprm synth telemetry``).

Per release (docs/flight.md):

1. truth: a parameter set drawn from the fit covariance (``FittedModel.sample``), an impact
   geometry drawn from :class:`~gprm.flight.predicted.GeometryUncertainty`, and an impact time
   drawn uniformly on a 0.1 µs grid over the plausible window (the span of times where the
   best-fit contact points approach the indent faces in both planes); a draw whose own contact
   points do not approach at its time is rejected and redrawn. ``truth_spread=False`` uses
   the best fit and nominal geometry instead (measurement noise only);
2. the TM velocity after the impact: by default (``truth_model="3d"``) from the one-contact
   3D impact of the plunger tip corner on the indent face with restitution and Coulomb
   friction (:func:`gprm.flight.predicted.tm_velocity_vs_time`, ``impact_model="3d"``; the
   friction coefficient is drawn with the geometry), a truth richer than the two-plane
   analysis of the paper; ``truth_model="planar"`` keeps the planar model in both planes,
   superposed (``z_from="sum"``: both contact lines strike, the TM's v_z is vz_xz + vz_yz;
   ``"xz"`` or ``"yz"`` keep one plane's v_z);
3. the TM displacement and attitude sampled by the GRS: ``rate`` (10 Hz) from ``pre`` s
   before to ``post`` s after the release, with a random sampling phase, at rest (a random
   µm-level offset) before the release and moving with the post-impact velocity after it,
   plus white noise (``pos_noise`` 2 nm, ``att_noise`` 1 µrad per sample).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from gprm.errors import GprmInputError
from gprm.flight.predicted import (GeometryUncertainty, ImpactGeometry, sample_geometries,
                                   tm_velocity_vs_time, default_window)
from gprm.flight.files import synth_option_attrs, telemetry_dataset
from gprm.flight.scenario import (COMPARED, OFFSETS, PARAMS, SCENARIOS, ScenarioPrior,
                                  draw_truths, scenario_grid)
from gprm.flight.telemetry import AXES
from gprm.params import batch
from gprm.simulate.kinematics import body_motion
from gprm.validate import check_int, check_number

TM_COMPONENTS = ("vx", "vy", "vz", "wx", "wy", "wz")


@dataclass(frozen=True)
class SynthOptions:
    """What defines a synthetic telemetry file (SI). Validated on construction (the one place
    these are checked); a bad value raises :class:`GprmInputError` naming the option.

    n_releases (>= 1) releases drawn with ``seed``; samples at ``rate`` (Hz) from ``pre`` s
    before to ``post`` s after each release; white noise ``pos_noise`` (m) and ``att_noise``
    (rad); ``truth_spread``: truth parameters and geometry drawn per release (else the best
    fit and nominal geometry); ``z_from``: the TM v_z with a planar truth (``sum``, ``xz``,
    ``yz``); ``grid_step`` (s) of the impact-time grid; ``window_mode``: ``identifiable`` or
    ``approach`` (:func:`plausible_window`); ``truth_model``: ``scenario`` (default, issue 23:
    :mod:`gprm.flight.scenario`, with ``scenario`` one of its
    :data:`~gprm.flight.scenario.SCENARIOS` or ``mixed``, each release's drawn from
    :data:`~gprm.flight.scenario.COMPARED`), ``3d`` or ``planar`` (issue 14);
    ``tm_offset`` (m): the scenario truths' largest lateral offset of the TM CoM from the head
    axis (:class:`~gprm.flight.scenario.ScenarioPrior`).
    """

    n_releases: int = 11
    seed: int = 0
    rate: float = 10.0
    pre: float = 2.0
    post: float = 5.0
    pos_noise: float = 2e-9
    att_noise: float = 1e-6
    truth_spread: bool = True
    z_from: str = "sum"
    grid_step: float = 1e-7
    window_mode: str = "identifiable"
    truth_model: str = "scenario"
    scenario: str = "two"
    tm_offset: float = ScenarioPrior.tm_offset

    def __post_init__(self):
        for name, lo in (("n_releases", 1), ("seed", 0)):
            check_int(name, getattr(self, name), lo)
        for name, positive in (("rate", True), ("pre", False), ("post", True),
                               ("pos_noise", True), ("att_noise", True), ("grid_step", True)):
            check_number(name, getattr(self, name), positive=positive)
        check_number("tm_offset", self.tm_offset, positive=False)
        if self.z_from not in ("sum", "xz", "yz"):
            raise GprmInputError(f"must be sum, xz or yz, got {self.z_from!r}", field="z_from")
        if self.truth_model not in ("scenario", "3d", "planar"):
            raise GprmInputError(f"must be scenario, 3d or planar, got {self.truth_model!r}",
                                 field="truth_model")
        if self.scenario not in SCENARIOS + ("mixed",):
            raise GprmInputError(f"must be one of {', '.join(SCENARIOS + ('mixed',))}, got "
                                 f"{self.scenario!r}", field="scenario")
        if self.window_mode not in ("identifiable", "approach"):
            raise GprmInputError(f"must be identifiable or approach, got "
                                 f"{self.window_mode!r}", field="window_mode")


def plausible_window(model, *, window=None, step: float = 1e-7, geometry=None,
                     mode: str = "identifiable"):
    """Grid times (s) where the impact is drawn, and their [first, last].

    ``mode="approach"``: the first contiguous interval of ``window`` in which the best-fit
    contact points approach the indent faces in both planes (the first approach: an impact, if
    any, happens there). ``mode="identifiable"`` (default): that interval cut at the earliest
    peak of the six |velocity| curves, where every curve is monotone, so a first crossing is
    the true one (beyond the peak the first-crossing rule of Sec. 4.1 picks the rising branch).
    """

    if mode not in ("identifiable", "approach"):
        raise GprmInputError("must be identifiable or approach", field="window_mode")
    pb0 = batch([model.params])
    w = default_window(pb0) if window is None else window
    t = np.arange(w[0], w[1] + 0.5 * step, step)
    out = tm_velocity_vs_time(body_motion(pb0, t, piezo=model.piezo), geometry)
    both = out["approaching_xz"][0] & out["approaching_yz"][0]
    if not both.any():
        raise GprmInputError("the model's contact points never approach the indent faces in "
                             "both planes: no plausible impact time", source=str(model.source))
    i0 = int(np.argmax(both))
    i1 = i0 + (int(np.argmin(both[i0:])) if not both[i0:].all() else both.size - i0)
    if mode == "identifiable":
        peaks = [i0 + int(np.argmax(np.abs(out[a][0, i0:i1]))) for a in AXES]
        i1 = max(min(peaks), i0 + 1)
    sel = t[i0:i1]
    return sel, (float(sel[0]), float(sel[-1]))


def synth_telemetry(model, opts: SynthOptions = SynthOptions(), *, geometry=None,
                    uncertainty=None):
    """Generate the synthetic telemetry :class:`xarray.Dataset` (see the module docstring)."""
    if not isinstance(opts, SynthOptions):
        raise GprmInputError(f"expected SynthOptions, got {type(opts).__name__}", field="opts")
    if opts.truth_model == "scenario":
        return _synth_scenarios(model, opts)
    geometry = replace(geometry or ImpactGeometry(), impact_model=opts.truth_model)
    uncertainty = uncertainty or GeometryUncertainty()
    rng = np.random.default_rng(opts.seed)
    R = int(opts.n_releases)
    grid, win = plausible_window(model, step=opts.grid_step, geometry=geometry,
                                 mode=opts.window_mode)
    pb0 = batch([model.params])
    if not opts.truth_spread:   # every candidate is the best fit: simulate it once
        vel0 = tm_velocity_vs_time(body_motion(pb0, grid, piezo=model.piezo), geometry)
    chosen_t: list[float] = []
    chosen_v: list[list[float]] = []
    chosen_idx: list[int] = []
    attempt = 0
    while len(chosen_t) < R and attempt < 20:
        nc = max(4 * (R - len(chosen_t)), 8)
        if opts.truth_spread:
            pc = model.sample(nc, seed=opts.seed * 1000 + attempt)
            geos = sample_geometries(geometry, uncertainty, nc, opts.seed * 1000 + 500 + attempt,
                                     pb0)
            vel = tm_velocity_vs_time(body_motion(pc, grid, piezo=model.piezo), geos)
        else:
            vel = {k: np.repeat(v, nc, axis=0) for k, v in vel0.items()}
        k = rng.integers(0, grid.size, size=nc)
        for j in range(nc):
            if len(chosen_t) >= R:
                break
            if vel["approaching_xz"][j, k[j]] and vel["approaching_yz"][j, k[j]]:
                chosen_t.append(grid[k[j]])
                chosen_v.append([vel[a][j, k[j]] for a in AXES]
                                + [vel["wz"][j, k[j]] if "wz" in vel else 0.0])
                chosen_idx.append(attempt)
        attempt += 1
    if len(chosen_t) < R:
        raise GprmInputError("could not draw plausible impacts (too few parameter draws "
                             "approach the indent faces)", source=str(model.source))
    tv = np.array(chosen_v)[:, :6]                # (R, 6) values in AXES order
    wz = np.array(chosen_v)[:, 6]
    a = {ax: tv[:, i] for i, ax in enumerate(AXES)}
    if opts.truth_model == "3d":    # one contact, one impulse: the TM's own six components
        vz, z_from = a["vz_xz"], None
    else:
        vz = {"sum": a["vz_xz"] + a["vz_yz"], "xz": a["vz_xz"], "yz": a["vz_yz"]}[opts.z_from]
        z_from = opts.z_from
    tm = np.stack([a["vx"], a["vy"], vz, a["wx"], a["wy"], wz], 1)
    truth = {"impact_time": list(map(float, chosen_t)), "window": list(win),
             "tm_velocity": {c: tm[:, i].tolist() for i, c in enumerate(TM_COMPONENTS)},
             "z_from": z_from, "truth_model": opts.truth_model,
             "truth_spread": opts.truth_spread}
    return _sampled(model, opts, rng, np.array(chosen_t), tm, tv, truth)


def _synth_scenarios(model, opts: SynthOptions):
    """Truths from the impact scenarios (:func:`gprm.flight.scenario.draw_truths`)."""
    rng = np.random.default_rng(opts.seed)
    R = int(opts.n_releases)
    kinds = (list(rng.choice(COMPARED, size=R)) if opts.scenario == "mixed"
             else [opts.scenario] * R)
    tr = draw_truths(model, [str(k) for k in kinds], opts.seed,
                     ScenarioPrior(tm_offset=opts.tm_offset), spread=opts.truth_spread)
    tm = tr.velocity                                       # vx vy vz wx wy wz
    comp = dict(zip(TM_COMPONENTS, tm.T))
    tv = np.stack([comp["vx"], comp["vz"], comp["wy"], comp["vy"], comp["vz"], comp["wx"]], 1)
    grid = scenario_grid(batch([model.params]))
    truth = {"impact_time": tr.t.tolist(), "window": [float(grid[0]), float(grid[-1])],
             "tm_velocity": {c: tm[:, i].tolist() for i, c in enumerate(TM_COMPONENTS)},
             "z_from": None, "truth_model": "scenario", "truth_spread": opts.truth_spread,
             "scenario": list(tr.scenario),
             "scenario_params": {k: tr.params[k].tolist() for k in PARAMS + OFFSETS},
             "contacts": tr.contacts.tolist()}
    return _sampled(model, opts, rng, tr.t, tm, tv, truth)


def _sampled(model, opts: SynthOptions, rng, chosen_t, tm, tv, truth):
    """The GRS samples of releases with TM velocities ``tm`` (R, 6) (module docstring)."""
    R = tm.shape[0]
    # sampling
    n_pre = int(round(opts.pre * opts.rate))
    n_post = int(round(opts.post * opts.rate))
    S = n_pre + n_post
    t_rel = 1000.0 * (1 + np.arange(R)) + rng.uniform(0, 100, R)   # release epochs, s
    phase = rng.uniform(0, 1.0 / opts.rate, R)
    time = t_rel[:, None] - opts.pre + phase[:, None] + np.arange(S)[None, :] / opts.rate
    dt = np.clip(time - t_rel[:, None], 0.0, None)
    data = {}
    chan = {"x": (tm[:, 0], opts.pos_noise), "y": (tm[:, 1], opts.pos_noise),
            "z": (tm[:, 2], opts.pos_noise), "theta": (tm[:, 3], opts.att_noise),
            "eta": (tm[:, 4], opts.att_noise), "phi": (tm[:, 5], opts.att_noise)}
    for c, (v, sig) in chan.items():
        scale = 1e-6 if c in ("x", "y", "z") else 1e-5
        off = rng.normal(0, scale, R)
        data[c] = off[:, None] + v[:, None] * dt + rng.normal(0, sig, (R, S))
    attrs = {"title": "synthetic GPRM release telemetry (gprm synth telemetry)",
             "source": f"synthetic from {model.source}", "seed": int(opts.seed),
             "sample_rate": float(opts.rate), "piezo": int(model.piezo),
             **synth_option_attrs(opts)}
    ds = telemetry_dataset([f"R{i + 1:02d}" for i in range(R)], time, t_rel, data,
                           noise_std={c: chan[c][1] for c in chan}, attrs=attrs,
                           truth_impact_time=np.array(chosen_t), truth_velocity=tv,
                           truth=truth)
    return ds
