"""Benchmark of the impact scenarios (issue 23, docs/flight.md §10-11):
`.venv/bin/python benchmarks/bench_scenarios.py [--observations [--tm-offset MM ...]]
[--recovery] [--likelihood-study] [--refine-study] [--oracle-study] [--geometry-study]
[--mixture-choice [--sets M]] [--pooled-choice [--sets M]] [--impact-times]
[--seeds N] [--seed0 S] [--releases R] [--draws K]`.

`--observations`: for every scenario of `gprm.flight.scenario.SCENARIOS`, N campaigns of R
releases (seeds S .. S+N-1, truths as `gprm synth telemetry paper --scenario NAME --seed s`
draws them), the paper's three observations counted over the releases: z not the largest
velocity component, the x–z share of the momentum (v_x² + v_z²)/|v|², every analysed component
(v_x, v_y, v_z, ω_x, ω_y) non-compliant (> 5 µm/s, > 100 µrad/s); ω_z's compliance apart.
With `--tm-offset MM ...`: one table of the three rim scenarios per largest TM offset (mm).

`--recovery`: N campaigns, each with R releases of every compared scenario (xz, yz, two; the
scenario i drawn with seed s + 10000 i, so that no two scenarios share their truths), written
as telemetry and read back, release velocities fitted, then the scenario posterior
(`gprm.flight.inference`, K prior draws per scenario): the right scenario chosen per release
and jointly over each file's R releases, and each unknown's truth inside its 95 % and central
50 % intervals.

`--likelihood-study`: on the same kind of truths (TM centred), each unknown's calibration
under the method's likelihood with the floor and allowance as they are, halved, doubled, and
under the exact mixture over the parameter sets (why μ's interval is too wide, §11); run it
on seeds other than the recovery's.

`--oracle-study`: the scenario choice's ceiling: N truths of each of xz, yz, two (seed S),
each classified by the scenarios' evidence at the truth's own parameter set (with enough
draws, what no method that must marginalise the fit's uncertainty can beat on average).

`--geometry-study`: on the recovery's truths, the method's prior predictives (the best fit's
contact geometry and masses for every parameter set) against ones with each set's own.

`--mixture-choice`: on the likelihood study's kind of truths, the scenario chosen per release
under the method's Gaussian summary of the parameter sets and under their exact mixture (M
sets, three floors): whether the choice is limited by the Gaussian or by marginalising the fit.

`--pooled-choice`: truths whose parameter set is drawn once per file (one mechanism) or per
release, each release's scenario chosen under the exact mixture over M sets weighted equally
or by the file's other releases (whether sharing the mechanism across releases recovers what
the oracle study says knowing the set allows).

`--impact-times`: the impact-time analysis (issue 14's) on scenario truths, per impact model.
Prints markdown."""

from __future__ import annotations

import argparse
import time

import numpy as np

from _machine import machine
from bench_flight import add_analysis, new_totals


def observations(fm, seeds, releases: int, tm_offset: float | None = None,
                 kinds=None) -> list[dict]:
    from gprm.flight.scenario import SCENARIOS, ScenarioPrior, draw_truths

    prior = ScenarioPrior() if tm_offset is None else ScenarioPrior(tm_offset=tm_offset)
    rows = []
    for kind in kinds or SCENARIOS:
        v = np.concatenate([draw_truths(fm, [kind] * releases, s, prior).velocity
                            for s in seeds])
        av = np.abs(v)
        share = (v[:, 0] ** 2 + v[:, 2] ** 2) / np.sum(v[:, :3] ** 2, 1)
        lim = np.array([5e-6] * 3 + [100e-6] * 3)
        rows.append({"scenario": kind, "n": len(v),
                     "z_not_largest": int(np.sum(av[:, 2] < np.maximum(av[:, 0], av[:, 1]))),
                     "share_median": float(np.median(share)),
                     "share_ge_0.9": int(np.sum(share >= 0.9)),
                     "all5_noncompliant": int(np.sum((av[:, :5] > lim[:5]).all(1))),
                     "all_three": int(np.sum((av[:, 2] < np.maximum(av[:, 0], av[:, 1]))
                                             & (share >= 0.9)
                                             & (av[:, :5] > lim[:5]).all(1))),
                     "compliant": [int(x) for x in np.sum(av <= lim, 0)],
                     "wz_q": [float(x) for x in np.percentile(av[:, 5], [50, 90])],
                     "mean_abs": [float(x) for x in av.mean(0)]})
    return rows


SCENARIO_SEED_STRIDE = 10000
"""--recovery: campaign seed s draws scenario i of COMPARED with seed s + 10000 i."""


def scenario_campaigns(fm, seeds, releases: int, mixed: bool = False, **synth):
    """(seed, scenario, truth dataset, telemetry, y, sigma) for each seed and each scenario of
    COMPARED: each scenario its own truths (with one seed for all three, the unknowns and the
    parameter sets drawn would repeat across the scenarios: one draw counted 3 times).
    ``mixed``: instead one file per seed whose releases each draw their scenario from
    COMPARED (``SynthOptions.scenario = "mixed"``; seed + 3 strides, a stream of its own).
    ``synth``: further SynthOptions (tm_offset, ...)."""
    from gprm.flight.files import telemetry_from_dataset
    from gprm.flight.inference import measured_components
    from gprm.flight.scenario import COMPARED
    from gprm.flight.synth import SynthOptions, synth_telemetry

    kinds = ((len(COMPARED), "mixed"),) if mixed else tuple(enumerate(COMPARED))
    for s in seeds:
        for i_kind, kind in kinds:
            ds = synth_telemetry(fm, SynthOptions(n_releases=releases,
                                                  seed=s + SCENARIO_SEED_STRIDE * i_kind,
                                                  scenario=kind, **synth))
            tel = telemetry_from_dataset(ds, source=f"seed {s}")
            y, sig = measured_components(tel)
            yield s, kind, ds, tel, y, sig


#: the prior probability of one scenario per file at which the recovery also scores the
#: file rule (gprm.flight.inference.file_probabilities; the method's is P_SAME)
FILE_P_SAME_CHECK = (0.1, 0.9)


def recovery(fm, seeds, releases: int, draws: int, rel_floor: float | None = None,
             refine: int = 0, mixed: bool = False) -> dict:
    """The scenario posterior's recovery on the files of :func:`scenario_campaigns`: the
    scenario chosen per release on its own evidence, per release given the file
    (``pooled``: gprm.flight.inference.pooled_probabilities) and jointly (one for the file;
    on ``mixed`` files not scored, the file having no one scenario), and each unknown's
    coverage under the release's true scenario."""
    from gprm.flight.inference import (InferenceOptions, file_probabilities,
                                       infer_scenarios, model_frame, posterior_weights,
                                       pooled_probabilities, prior_predictives,
                                       refined_predictive)
    from gprm.flight.scenario import COMPARED, PARAMS, SCENARIOS, ScenarioPrior
    from gprm.params import batch

    out = {"n": 0, "right": 0, "by_truth": {k: [0, 0] for k in COMPARED},
           "covered": {k: 0 for k in PARAMS + ("t",)}, "ess_median": [], "confusion": {},
           "width": {k: [] for k in PARAMS}, "covered50": {k: 0 for k in PARAMS},
           "below": {k: 0 for k in PARAMS + ("t",)}, "above": {k: 0 for k in PARAMS + ("t",)},
           "joint": {k: [0, 0] for k in COMPARED}, "joint_confusion": {},
           "pooled": 0, "pooled_by_truth": {k: [0, 0] for k in COMPARED},
           "pooled_confusion": {},
           "file": 0, "file_by_truth": {k: [0, 0] for k in COMPARED},
           "file_confusion": {}, "file_p_same": [],
           # the file rule's prior odds varied (FILE_P_SAME_CHECK): right choices
           "file_check": {q: 0 for q in FILE_P_SAME_CHECK},
           "files": []}
    bounds = ScenarioPrior().bounds()
    opts = InferenceOptions(n_draws=draws, n_refine=refine,
                            **({} if rel_floor is None else {"rel_floor": rel_floor}))
    t0 = time.process_time()
    pps = prior_predictives(fm, opts)         # once: it depends on the model and options only
    out["pp_cpu_s"] = time.process_time() - t0
    pb0 = batch([fm.params])
    frame = model_frame(fm, opts, pb0)
    for seed, file_kind, ds, tel, y, sig in scenario_campaigns(fm, seeds, releases, mixed):
        truth = ds  # truth variables
        res = infer_scenarios(fm, [r.id for r in tel.releases], y, sig, opts,
                              predictive=pps)
        L = res.log_evidence()
        sc = res.options["scenarios"]
        if not mixed:
            # the scenario chosen jointly over the file's releases (one scenario for all)
            out["joint"][file_kind][0] += res.joint["chosen"] == file_kind
            out["joint"][file_kind][1] += 1
            count(out["joint_confusion"], file_kind, res.joint["chosen"])
        # the per-release choices given the file: the method's (res.chosen, the file rule
        # at P_SAME) and the Dirichlet pooling's
        pooled = pooled_probabilities(L)
        given = {"pooled": [sc[int(np.argmax(p))] if np.all(np.isfinite(p)) else None
                            for p in pooled], "file": res.chosen}
        out["file_p_same"].append(res.joint["p_same"])
        out["files"].append((seed, file_kind, L))
        check = {q: file_probabilities(L, q)[0] for q in FILE_P_SAME_CHECK}
        for i in range(len(tel.releases)):
            kind = str(truth["truth_scenario"].values[i]) if mixed else file_kind
            for q, probs in check.items():
                out["file_check"][q] += bool(np.all(np.isfinite(probs[i]))) and \
                    sc[int(np.argmax(probs[i]))] == kind
            for rule, chosen in given.items():
                pc = chosen[i]
                okp = pc == kind
                out[rule] += okp
                out[f"{rule}_by_truth"][kind][0] += okp
                out[f"{rule}_by_truth"][kind][1] += 1
                count(out[f"{rule}_confusion"], kind, pc)
            out["n"] += 1
            ok = res.chosen_alone[i] == kind
            out["right"] += ok
            out["by_truth"][kind][0] += ok
            out["by_truth"][kind][1] += 1
            count(out["confusion"], kind, res.chosen_alone[i])
            f = res.fits[i][kind]
            out["ess_median"].append(f.ess)
            # the posterior's CDF at the truth (PIT): inside the central 50 %?
            yi, si, ui = np.nan_to_num(y[i]), np.nan_to_num(sig[i]), np.isfinite(y[i])
            pp = pps[kind]
            w = posterior_weights(pp, yi, si, ui, opts)
            if refine and w.any():  # the draws infer_scenarios used (the same stream)
                pp = refined_predictive(pp, w, refine, frame, pb0, opts, ScenarioPrior(),
                                        np.random.default_rng([opts.seed, 7, i,
                                                               SCENARIOS.index(kind)]))
                w = posterior_weights(pp, yi, si, ui, opts)
            for p in PARAMS:
                tv = float(truth[f"truth_scenario_{p}"].values[i])
                pit = float(np.sum(w[pp.params[p] <= tv]))
                out["covered50"][p] += abs(pit - 0.5) <= 0.25
            for p in PARAMS + ("t",):
                tv = (float(truth["truth_impact_time"].values[i]) if p == "t"
                      else float(truth[f"truth_scenario_{p}"].values[i]))
                _, lo, hi = f.summary[p]
                out["covered"][p] += lo <= tv <= hi
                out["below"][p] += tv < lo
                out["above"][p] += tv > hi
                if p in bounds:     # the 95 % interval over the prior's central 95 %
                    out["width"][p].append((hi - lo) / (0.95 * np.subtract(
                        *bounds[p][::-1])))
    out["ess_median"] = float(np.median(out["ess_median"]))
    out["width"] = {k: float(np.median(v)) for k, v in out["width"].items()}
    if not mixed:
        out["composite"] = composite_files(out["files"], opts.scenarios)
    return out


def composite_files(files, scenarios, minority=(1, 2, 3)) -> dict:
    """Files of one scenario with a few releases of another, built from ``files`` ((seed,
    scenario, (R, K) log evidences in ``scenarios`` order) of files of one scenario): for
    each seed and each ordered pair (A, B) of the scenarios' files, the releases of A with
    the first m of them replaced by B's first m (m in ``minority``; the releases are
    independent given the model, so their evidences combine into a file as they are). The scenario chosen per release on its
    own evidence and given the file (gprm.flight.inference.file_probabilities), counted
    apart for the majority's and the minority's releases: what the file rule costs where a
    file is almost, but not quite, of one scenario."""
    from gprm.flight.inference import file_probabilities

    by_seed: dict = {}
    for seed, kind, L in files:
        by_seed.setdefault(seed, {})[kind] = L
    out = {m: {"files": 0, "same": 0, "majority": [0, 0, 0], "minority": [0, 0, 0]}
           for m in minority}       # [alone right, given the file right, releases]
    for per in by_seed.values():
        for a, La in per.items():
            for b, Lb in per.items():
                if a == b:
                    continue
                for m in minority:
                    L = np.vstack([Lb[:m], La[m:]])
                    truth = [b] * m + [a] * (La.shape[0] - m)
                    P, p = file_probabilities(L)
                    t = out[m]
                    t["files"] += 1
                    t["same"] += p > 0.5
                    for i, k in enumerate(truth):
                        part = t["minority"] if i < m else t["majority"]
                        part[0] += scenarios[int(np.argmax(L[i]))] == k
                        part[1] += bool(np.all(np.isfinite(P[i]))) and \
                            scenarios[int(np.argmax(P[i]))] == k
                        part[2] += 1
    return out


def count(confusion: dict, truth: str, chosen) -> None:
    """One more ``truth->chosen`` in a confusion tally."""
    key = f"{truth}->{chosen}"
    confusion[key] = confusion.get(key, 0) + 1


def weighted_interval(x, w, truth):
    """The weighted draws' central 95 % interval (lo, hi) and the posterior CDF at the truth
    (its PIT: inside the central 50 % when within 0.25 of 0.5)."""
    from gprm.flight.inference import _weighted_quantiles

    lo, hi = _weighted_quantiles(x, w, [0.025, 0.975])
    return lo, hi, float(np.sum(w[x <= truth]))


def tally_unknowns(r: dict, params: dict, w, ds, i: int) -> None:
    """Adds release ``i``'s truth of every unknown inside its 95 % (``r["in95"]``) and its
    central 50 % (``r["in50"]``) interval of the weighted prior draws ``params``."""
    from gprm.flight.scenario import PARAMS

    for k in PARAMS:
        tv = float(ds[f"truth_scenario_{k}"].values[i])
        lo, hi, pit = weighted_interval(params[k], w, tv)
        r["in95"][k] += lo <= tv <= hi
        r["in50"][k] += abs(pit - 0.5) <= 0.25


def posterior_tally() -> dict:
    """An empty tally of :func:`tally_posterior`."""
    from gprm.flight.scenario import PARAMS

    return {"n": 0, "in95": {k: 0 for k in PARAMS}, "in50": {k: 0 for k in PARAMS},
            "sd": {k: [] for k in PARAMS}, "ess": []}


def tally_posterior(r: dict, params: dict, w, ds, i: int) -> None:
    """Adds release ``i``'s posterior (weights ``w`` over the prior draws ``params``) to a
    :func:`posterior_tally`: one release more, its effective number of draws, every
    unknown's coverage (:func:`tally_unknowns`) and its posterior sd over the prior's."""
    from gprm.flight.scenario import PARAMS

    r["n"] += 1
    r["ess"].append(1.0 / np.sum(w * w))
    tally_unknowns(r, params, w, ds, i)
    for k in PARAMS:
        x = params[k]
        m = np.sum(w * x)
        r["sd"][k].append(np.sqrt(np.sum(w * (x - m) ** 2)) / np.std(x))


def summarise_tallies(res: dict) -> dict:
    """Each tally of ``res`` with its effective draws and sds as medians over the releases."""
    for r in res.values():
        r["ess"] = float(np.median(r["ess"]))
        r["sd"] = {k: float(np.median(v)) for k, v in r["sd"].items()}
    return res


def _set_log_likelihood(Y, ok, y, sig, use, floor, rel_floor):
    """(sets, draws) ln N(y; y_mk, diag(σ² + floor² + (rel y_mk)²)) of the measured
    components ``use`` at every parameter set m and prior draw k (Y (M, K, 6), ok (M, K));
    −inf where the set gives no impact at the draw."""
    fl = np.array([floor[0]] * 3 + [floor[1]] * 3)[use]
    Yu = np.nan_to_num(Y[..., use])
    var = sig[use] ** 2 + fl ** 2 + (rel_floor * Yu) ** 2
    lp = -0.5 * np.sum((y[use] - Yu) ** 2 / var + np.log(2 * np.pi * var), -1)
    return np.where(ok, lp, -np.inf)


def _mixture_log_likelihood(Y, ok, y, sig, use, floor, rel_floor):
    """ln L_k (K,) of the prior draws under the exact mixture over the parameter sets:
    L_k = mean over the sets m giving an impact of N(y; y_mk, diag(σ² + floor² + (rel y_mk)²))
    (no Gaussian approximation of the sets' spread); draws with < 75 % impacts: −inf."""
    from scipy.special import logsumexp

    valid = ok.mean(0) >= 0.75
    lp = _set_log_likelihood(Y[:, valid], ok[:, valid], y, sig, use, floor, rel_floor)
    ll = np.full(valid.size, -np.inf)
    ll[valid] = logsumexp(lp, axis=0) - np.log(ok[:, valid].sum(0))
    return ll


def _mixture_weights(Y, ok, y, sig, use, floor, rel_floor):
    """Posterior weights of the prior draws under :func:`_mixture_log_likelihood`."""
    ll = _mixture_log_likelihood(Y, ok, y, sig, use, floor, rel_floor)
    w = np.exp(ll - ll.max())
    return w / w.sum()


def set_velocities(fm, opts, prior) -> dict:
    """Per compared scenario, every parameter set's velocity at each of the prior draws of
    :func:`gprm.flight.inference.prior_predictive` (the same stream, TM offsets zero): kind ->
    (Y (n_model, draws, 6), ok (n_model, draws)), before the Gaussian summary C_k."""
    from gprm.flight.inference import model_frame
    from gprm.flight.scenario import COMPARED, COMPONENTS, OFFSETS, SCENARIOS, scenario_velocity
    from gprm.params import batch

    pb0 = batch([fm.params])
    frame = model_frame(fm, opts, pb0)
    draws = opts.n_draws
    raw = {}
    for kind in COMPARED:
        p = prior.draw(draws, np.random.default_rng([opts.seed, SCENARIOS.index(kind)]))
        p.update({k: np.zeros(draws) for k in OFFSETS})
        Y = np.full((opts.n_model, draws, 6), np.nan)
        ok = np.zeros((opts.n_model, draws), bool)
        chunk = max(1, 4_000_000 // (opts.n_model * frame.time.size))
        for a in range(0, draws, chunk):
            sl = slice(a, min(draws, a + chunk))
            o = scenario_velocity(kind, frame, pb0, {k: v[sl] for k, v in p.items()}, prior)
            Y[:, sl] = np.stack([o[c] for c in COMPONENTS], -1)
            ok[:, sl] = o["ok"]
        raw[kind] = (Y, ok)
    return raw


def mixture_choice_study(fm, seeds, releases: int, draws: int, n_model: int) -> dict:
    """Is the per-release scenario choice limited by the Gaussian summary of the parameter
    sets (docs/flight.md §11)? On independent truths of xz, yz, two (TM centred, as the
    likelihood study), the scenario of each release chosen by the evidence (equal prior odds,
    Z = mean of L_k over the prior draws) under the method's Gaussian C_k and under the exact
    mixture over the same ``n_model`` parameter sets, with the method's floor and allowance,
    a quarter of the floor without the allowance, and the measurement's σ alone."""
    from scipy.special import logsumexp

    from gprm.flight.inference import InferenceOptions, _log_likelihood, prior_predictives
    from gprm.flight.scenario import COMPARED, ScenarioPrior

    prior = ScenarioPrior(tm_offset=0.0)
    opts = InferenceOptions(n_draws=draws, n_model=n_model)
    pps = prior_predictives(fm, opts, prior)
    raw = set_velocities(fm, opts, prior)
    f0 = opts.floor
    variants = {
        "Gaussian C_k, floor + 2 % (the method)": None,
        "exact mixture, floor + 2 %": (f0, opts.rel_floor),
        "exact mixture, floor / 4, no allowance": ((f0[0] / 4, f0[1] / 4), 0.0),
        "exact mixture, measurement σ only": ((0.0, 0.0), 0.0),
    }
    res = {v: {"n": 0, "right": 0, "confusion": {}} for v in variants}
    for _s, kind, _ds, tel, y, sig in scenario_campaigns(fm, seeds, releases, tm_offset=0.0):
        for i in range(len(tel.releases)):
            use = np.isfinite(y[i])
            yi, si = np.nan_to_num(y[i]), np.nan_to_num(sig[i])
            for v, spec in variants.items():
                logz = {}
                for k2 in COMPARED:
                    ll = (_log_likelihood(pps[k2], yi, si, use, opts)[0] if spec is None
                          else _mixture_log_likelihood(*raw[k2], yi, si, use, *spec))
                    logz[k2] = logsumexp(ll) - np.log(ll.size)
                chosen = max(COMPARED, key=lambda k2: logz[k2])
                r = res[v]
                r["n"] += 1
                r["right"] += chosen == kind
                count(r["confusion"], kind, chosen)
    return {"n_model": n_model, "variants": res}


def _aligned_frames(e: np.ndarray):
    """Two unit vectors a, b (K, 3) completing each unit vector e (K, 3) to a right-handed
    orthonormal frame."""
    h = np.where((np.abs(e[:, 0]) > 0.9)[:, None], np.array([0.0, 1, 0]),
                 np.array([1.0, 0, 0]))
    a = h - np.sum(h * e, 1)[:, None] * e
    a /= np.linalg.norm(a, axis=1)[:, None]
    return a, np.cross(e, a)


def aligned_coordinates(Y, e, a, b):
    """The TM velocity (..., K, 6) in coordinates aligned with it, per prior draw k's frame
    (e, a, b: (K, 3)): u = (ln |v|, n.a / n.e, n.b / n.e, omega / |v|) with n = v / |v| (its
    direction by the gnomonic projection about e). Returns u (..., K, 6), cos = n.e and |v|.
    The density of y is that of u times |det du/dy| = 1 / (|v|^(3 + A) cos^3), A the number
    of angular components (the gnomonic projection's 1 / cos^3 on the sphere, d ln|v| = d|v|
    / |v| with the volume |v|^2 d|v| d(direction), and 1 / |v| for each omega / |v|)."""
    v = Y[..., :3]
    r = np.linalg.norm(v, axis=-1)
    n = v / r[..., None]
    c = np.sum(n * e, -1)
    u = np.concatenate([np.log(r)[..., None], (np.sum(n * a, -1) / c)[..., None],
                        (np.sum(n * b, -1) / c)[..., None], Y[..., 3:] / r[..., None]], -1)
    return u, c, r


def aligned_moments(Y, ok, min_valid: float = 0.75) -> dict:
    """Per prior draw, the parameter sets' velocities (Y (M, K, 6), ok (M, K)) summarised
    by a Gaussian in :func:`aligned_coordinates` about their mean direction (the frame), with
    the Jacobian of the coordinates at their mean velocity (central differences) to carry the
    floor and the allowance over."""
    K = ok.shape[1]
    Yv = np.where(ok[..., None], Y, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = Yv[..., :3] / np.linalg.norm(Yv[..., :3], axis=-1)[..., None]
        e = np.nan_to_num(np.nansum(n, 0), nan=0.0)
    norm = np.linalg.norm(e, axis=1)
    e = np.where(norm[:, None] > 0, e / np.where(norm > 0, norm, 1.0)[:, None], [1.0, 0, 0])
    a, b = _aligned_frames(e)
    with np.errstate(invalid="ignore", divide="ignore"):
        U = aligned_coordinates(Yv, e, a, b)[0]
    cnt = ok.sum(0)
    m = np.where(cnt[:, None] > 0, np.nansum(np.where(ok[..., None], U, 0.0), 0)
                 / np.maximum(cnt, 1)[:, None], np.nan)
    d = np.where(ok[..., None], U - m, 0.0)
    S = np.einsum("mki,mkj->kij", d, d) / np.maximum(cnt - 1, 1)[:, None, None]
    mu = np.where(cnt[:, None] > 0, np.nansum(np.where(ok[..., None], Y, 0.0), 0)
                  / np.maximum(cnt, 1)[:, None], np.nan)
    G = np.zeros((K, 6, 6))
    for j in range(6):
        h = 1e-6 * np.maximum(np.abs(np.nan_to_num(mu[:, j])), 1e-9)
        p, q = mu.copy(), mu.copy()
        p[:, j] += h
        q[:, j] -= h
        with np.errstate(invalid="ignore", divide="ignore"):
            G[:, :, j] = (aligned_coordinates(p, e, a, b)[0]
                          - aligned_coordinates(q, e, a, b)[0]) / (2 * h[:, None])
    valid = (ok.mean(0) >= min_valid) & np.isfinite(m).all(1)
    return {"valid": valid, "e": e, "a": a, "b": b, "m": m, "S": S, "mu": mu, "G": G}


def aligned_log_likelihood(am: dict, y, sig, use, floor, rel_floor,
                           scale_only: bool = False) -> np.ndarray:
    """ln L_k (K,) of a release (y, sig, use as :func:`_set_log_likelihood`) under the
    Gaussian of :func:`aligned_moments`, as a density of y (the Jacobian of
    :func:`aligned_coordinates`), so that its evidence compares with the method's. The
    measurement's variance and the floor are carried into u by the Jacobian; the allowance
    either so too (rel_floor of each component) or, with ``scale_only``, as a common scale
    error of the velocity (rel_floor on ln |v| alone). −inf where the draw is not valid or
    the measured direction lies more than ~87° from its frame."""
    K = am["m"].shape[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        uy, c, r = aligned_coordinates(np.broadcast_to(y, (K, 6)), am["e"], am["a"], am["b"])
    ui = np.r_[0, 1, 2, 3 + np.flatnonzero(use[3:])]
    fl = np.array([floor[0]] * 3 + [floor[1]] * 3)
    D = sig ** 2 + fl ** 2 + (0.0 if scale_only else (rel_floor * am["mu"]) ** 2)
    D = np.where(use, np.broadcast_to(D, (K, 6)), 0.0)
    Sx = np.einsum("kij,kj,klj->kil", am["G"], D, am["G"])
    if scale_only:
        Sx[:, 0, 0] += rel_floor ** 2
    St = (am["S"] + Sx)[:, ui][:, :, ui]
    res = (uy - am["m"])[:, ui]
    ok = (am["valid"] & (c > 0.05) & np.isfinite(res).all(1)
          & np.isfinite(St).all((1, 2)))
    ll = np.full(K, -np.inf)
    L = np.linalg.cholesky(St[ok])
    z = np.linalg.solve(L, res[ok][..., None])[..., 0]
    logdet = 2 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), -1)
    jac = -(3 + int(use[3:].sum())) * np.log(r[ok]) - 3 * np.log(c[ok])
    ll[ok] = (-0.5 * np.sum(z * z, -1) - 0.5 * logdet - 0.5 * ui.size * np.log(2 * np.pi)
              + jac)
    return ll


def aligned_study(fm, seeds, releases: int, draws: int) -> dict:
    """Does a Gaussian in coordinates aligned with the velocity (magnitude, direction,
    omega / |v|: :func:`aligned_coordinates`) instead of the method's Gaussian C_k of the
    parameter sets' velocities narrow μ and separate one contact from two (docs/flight.md
    §11)? On independent truths of xz, yz, two (TM centred, as the likelihood study), per
    variant: the scenario chosen by the evidence (equal prior odds), and each unknown's
    coverage under the true scenario. Variants: the method; the aligned Gaussian for the
    one-contact scenarios (where sliding fixes the impulse's direction to μ) with the
    allowance carried per component or as a common scale error, and for all three."""
    from scipy.special import logsumexp

    from gprm.flight.inference import InferenceOptions, _log_likelihood, prior_predictives
    from gprm.flight.scenario import COMPARED, ScenarioPrior

    prior = ScenarioPrior(tm_offset=0.0)
    opts = InferenceOptions(n_draws=draws)
    pps = prior_predictives(fm, opts, prior)
    raw = set_velocities(fm, opts, prior)
    ams = {k: aligned_moments(*raw[k], opts.min_valid) for k in COMPARED}
    one = ("xz", "yz")
    variants = {   # scenario -> likelihood: "g" the method, "a" aligned, "s" aligned, scale
        "Gaussian C_k (the method)": {},
        "aligned, one contact; allowance per component": {k: "a" for k in one},
        "aligned, one contact; allowance as a common scale": {k: "s" for k in one},
        "aligned, all three; allowance as a common scale": {k: "s" for k in COMPARED},
    }
    res = {v: {**posterior_tally(), "right": 0, "confusion": {}} for v in variants}
    for _s, kind, ds, tel, y, sig in scenario_campaigns(fm, seeds, releases, tm_offset=0.0):
        for i in range(len(tel.releases)):
            use = np.isfinite(y[i])
            yi, si = np.nan_to_num(y[i]), np.nan_to_num(sig[i])
            lls = {}
            for k2 in COMPARED:
                lls["g", k2] = _log_likelihood(pps[k2], yi, si, use, opts)[0]
                for how in "as":
                    lls[how, k2] = aligned_log_likelihood(ams[k2], yi, si, use, opts.floor,
                                                          opts.rel_floor, how == "s")
            for name, forms in variants.items():
                logz = {k2: logsumexp(lls[forms.get(k2, "g"), k2])
                        - np.log(lls["g", k2].size) for k2 in COMPARED}
                chosen = max(COMPARED, key=lambda k2: logz[k2])
                r = res[name]
                r["right"] += chosen == kind
                count(r["confusion"], kind, chosen)
                ll = lls[forms.get(kind, "g"), kind]
                w = np.exp(ll - ll.max())
                tally_posterior(r, pps[kind].params, w / w.sum(), ds, i)
    return summarise_tallies(res)


def likelihood_study(fm, seeds, releases: int, draws: int) -> dict:
    """Why the friction's interval is too wide (docs/flight.md §11): on independent truths of
    xz, yz, two (TM centred: the question does not involve the offset), the posterior of every
    unknown under the Gaussian approximation of the parameter sets' spread (C_k, the method)
    with the floor and the 2 % allowance as they are, halved and doubled, and under the exact
    mixture over the same 48 parameter sets: the truth inside the 95 % and the central 50 %
    intervals, the posterior sd over the prior's, the effective number of draws."""
    from dataclasses import replace

    from gprm.flight.inference import InferenceOptions, posterior_weights, prior_predictives
    from gprm.flight.scenario import ScenarioPrior

    prior = ScenarioPrior(tm_offset=0.0)
    opts = InferenceOptions(n_draws=draws)
    pps = prior_predictives(fm, opts, prior)
    raw = set_velocities(fm, opts, prior)
    f0, r0 = opts.floor, opts.rel_floor
    variants = {
        "Gaussian C_k, floor + 2 % (the method)": ("gauss", opts),
        "Gaussian C_k, floor and allowance halved": (
            "gauss", replace(opts, floor=(f0[0] / 2, f0[1] / 2), rel_floor=r0 / 2)),
        "Gaussian C_k, floor and allowance doubled": (
            "gauss", replace(opts, floor=(f0[0] * 2, f0[1] * 2), rel_floor=r0 * 2)),
        "exact mixture over the 48 sets, floor + 2 %": ("mix", opts),
        "exact mixture over the 48 sets, floor + 5 %": ("mix", replace(opts, rel_floor=0.05)),
    }
    res = {v: posterior_tally() for v in variants}
    for _s, kind, ds, tel, y, sig in scenario_campaigns(fm, seeds, releases, tm_offset=0.0):
        for i in range(len(tel.releases)):
            use = np.isfinite(y[i])
            yi, si = np.nan_to_num(y[i]), np.nan_to_num(sig[i])
            for name, (how, o) in variants.items():
                w = (posterior_weights(pps[kind], yi, si, use, o) if how == "gauss"
                     else _mixture_weights(*raw[kind], yi, si, use, o.floor, o.rel_floor))
                tally_posterior(res[name], pps[kind].params, w, ds, i)
    return summarise_tallies(res)


def refine_study(fm, seeds, releases: int, draws: int, refine: int) -> dict:
    """Is it the sampling or the likelihood (docs/flight.md §11)? On independent truths of
    xz, yz, two (the default truth, TM offset included), for the true scenario of every
    release: the posterior of each unknown with the prior draws alone (stage 1) and pooled
    with ``refine`` second-stage draws around the method's stage-1 posterior (stage 2; one
    proposal serves every variant: it is wider than each of their posteriors), under the
    method's likelihood with the floor and allowance as they are, halved, quartered and
    none: the truth inside the 95 % interval (and below / above it), inside the central 50 %,
    the effective draws; and per scenario, μ's standardised error |posterior mean − truth| /
    posterior sd (median; about 0.67 for a calibrated normal posterior)."""
    from dataclasses import replace

    from gprm.flight.inference import (InferenceOptions, model_frame,
                                      posterior_weights, prior_predictives,
                                      refined_predictive)
    from gprm.flight.scenario import COMPARED, PARAMS, ScenarioPrior
    from gprm.params import batch

    base = InferenceOptions(n_draws=draws)
    prior = ScenarioPrior()
    pps = prior_predictives(fm, base, prior)
    pb0 = batch([fm.params])
    frame = model_frame(fm, base, pb0)
    f0, r0 = base.floor, base.rel_floor
    variants = {"floor + 2 % (the method)": base,
                "halved": replace(base, floor=(f0[0] / 2, f0[1] / 2), rel_floor=r0 / 2),
                "quartered": replace(base, floor=(f0[0] / 4, f0[1] / 4), rel_floor=r0 / 4),
                "none": replace(base, floor=(0.0, 0.0), rel_floor=0.0)}
    res = {(st, v): {"n": 0, "in95": {k: 0 for k in PARAMS}, "in50": {k: 0 for k in PARAMS},
                     "below": {k: 0 for k in PARAMS}, "above": {k: 0 for k in PARAMS},
                     "ess": []} for st in (1, 2) for v in variants}
    mu_z = {k: [] for k in COMPARED}
    rng = np.random.default_rng(5)
    for _s, kind, ds, tel, y, sig in scenario_campaigns(fm, seeds, releases):
        for i in range(len(tel.releases)):
            use = np.isfinite(y[i])
            yi, si = np.nan_to_num(y[i]), np.nan_to_num(sig[i])
            tv = {k: float(ds[f"truth_scenario_{k}"].values[i]) for k in PARAMS}
            pp1 = pps[kind]
            w1 = posterior_weights(pp1, yi, si, use, base)
            pp2 = refined_predictive(pp1, w1, refine, frame, pb0, base, prior, rng)
            x = pp1.params["mu"]
            m = np.sum(w1 * x)
            mu_z[kind].append(abs(m - tv["mu"]) / np.sqrt(np.sum(w1 * (x - m) ** 2)))
            for st, pp in ((1, pp1), (2, pp2)):
                for name, o in variants.items():
                    w = posterior_weights(pp, yi, si, use, o)
                    r = res[(st, name)]
                    r["n"] += 1
                    r["ess"].append(1.0 / np.sum(w * w))
                    for k in PARAMS:
                        lo, hi, pit = weighted_interval(pp.params[k], w, tv[k])
                        r["in95"][k] += lo <= tv[k] <= hi
                        r["below"][k] += tv[k] < lo
                        r["above"][k] += tv[k] > hi
                        r["in50"][k] += abs(pit - 0.5) <= 0.25
    for r in res.values():
        r["ess"] = float(np.median(r["ess"]))
    return {"variants": res, "mu_z": {k: float(np.median(v)) for k, v in mu_z.items()}}


def oracle_study(fm, seed: int, truths: int, draws: int) -> dict:
    """The scenario choice's ceiling (docs/flight.md §11): truths of xz, yz, two drawn as
    :func:`gprm.flight.scenario.draw_truths` draws them (a parameter set from the fit, each
    set's own geometry, the unknowns and the TM offset from the prior, an impact required),
    measured with the median standard errors of synthetic telemetry; each classified by the
    evidence of every scenario **at the truth's own parameter set** (the oracle: the fit's
    uncertainty removed), the unknowns integrated over ``draws`` prior draws, the offset
    marginalised as the method does (``offset_covariance``), with the measurement's σ alone
    and with the method's floor added. With enough draws no method that does not know the
    parameter set can choose better (on average); with few, the likelihood at one set is so
    sharp that the draws miss part of it and the count is a lower bound."""
    from dataclasses import replace

    from scipy.special import logsumexp

    from gprm.flight.inference import InferenceOptions, PriorPredictive, _log_likelihood
    from gprm.flight.scenario import (COMPARED, COMPONENTS, OFFSETS, ScenarioPrior,
                                      offset_covariance, plunger_frame, scenario_grid,
                                      scenario_velocity)
    from gprm.params import batch
    from gprm.simulate.kinematics import body_motion

    prior = ScenarioPrior()
    grid = scenario_grid(batch([fm.params]))
    sig = np.concatenate([s_ for *_, s_ in scenario_campaigns(fm, [seed], 11)])
    sigma = np.nanmedian(sig, 0)
    use = np.isfinite(sigma)
    # the method's Gaussian likelihood (_log_likelihood) at one set: C_k is the offset's alone
    method = InferenceOptions(rel_floor=0.0)
    variants = {"measurement σ only": replace(method, floor=(0.0, 0.0)),
                "σ and the method's floor": method}
    res = {v: {"n": 0, "right": 0, "confusion": {}} for v in variants}
    rng = np.random.default_rng([seed, 11])
    # the prior draws of each scenario's unknowns (the same for every truth; TM centred)
    q = {}
    for k2 in COMPARED:
        q[k2] = prior.draw(draws, np.random.default_rng([seed, 12, COMPARED.index(k2)]))
        q[k2].update({k: np.zeros(draws) for k in OFFSETS})
    for _ in range(truths):
        for kind in COMPARED:
            while True:     # one truth (draw_truths' rule: drawn again without an impact)
                pb = fm.sample(1, seed=int(rng.integers(1 << 30)))
                frame = plunger_frame(body_motion(pb, grid, piezo=fm.piezo))
                o = scenario_velocity(kind, frame, pb, prior.draw(1, rng), prior,
                                      per_set=True)
                if o["ok"][0, 0]:
                    break
            y = np.array([o[c][0, 0] for c in COMPONENTS])
            y = y + np.nan_to_num(sigma) * rng.standard_normal(6)
            logz = {v: {} for v in variants}
            for k2 in COMPARED:
                out = scenario_velocity(k2, frame, pb, q[k2], prior)
                Y = np.stack([out[c][0] for c in COMPONENTS], -1)
                C = offset_covariance(Y[:, :3], float(np.ravel(pb["s_tm"])[0]),
                                      prior.tm_offset)
                none = np.zeros(draws)
                pp = PriorPredictive(k2, q[k2], Y, C, none, np.zeros((draws, 6)), none,
                                     out["ok"][0])
                for v, o_ in variants.items():
                    ll = _log_likelihood(pp, y, np.nan_to_num(sigma), use, o_)[0]
                    logz[v][k2] = logsumexp(ll) - np.log(draws)
            for v in variants:
                chosen = max(COMPARED, key=lambda k2: logz[v][k2])
                r = res[v]
                r["n"] += 1
                r["right"] += chosen == kind
                count(r["confusion"], kind, chosen)
    return {"sigma": [float(x) for x in sigma], "variants": res}


class _OneSet:
    """The fit ``fm`` with every draw of its parameter sets the same one (seeded): a file of
    releases of one mechanism, whose parameter set is one draw of the fit's uncertainty."""

    def __init__(self, fm, seed: int):
        self._fm, self._seed = fm, int(seed)

    def __getattr__(self, name):
        return getattr(self._fm, name)

    def sample(self, n: int, seed: int = 0) -> dict:
        one = self._fm.sample(1, seed=self._seed)
        return {k: np.repeat(np.atleast_1d(v)[:1], n) for k, v in one.items()}


def pooled_choice_study(fm, seeds, releases: int, draws: int, n_model: int) -> dict:
    """Can the other releases of a file tell the per-release choice which parameter set the
    mechanism has (docs/flight.md §11)? On truths of xz, yz, two (TM centred), with the
    file's parameter set drawn once (``shared``: one mechanism) or per release (``per
    release``: as ``draw_truths`` draws them), the velocities measured with the median
    telemetry σ; each release's scenario chosen by the evidence under the exact mixture
    over ``n_model`` parameter sets with the method's floor and allowance, the sets weighted
    equally (``unpooled``) or by their likelihood given the file's other releases
    (``pooled``: p(set | others) ∝ Π over the others of the mean over scenarios of each
    one's evidence at that set). Also the median effective number of sets the pooled
    weights keep."""
    from scipy.special import logsumexp

    from gprm.flight.inference import InferenceOptions
    from gprm.flight.scenario import COMPARED, ScenarioPrior, draw_truths

    prior = ScenarioPrior(tm_offset=0.0)
    opts = InferenceOptions(n_draws=draws, n_model=n_model)
    raw = set_velocities(fm, opts, prior)
    sig = np.nanmedian(np.concatenate([s_ for *_, s_ in scenario_campaigns(fm, [0], 11)]), 0)
    sig = np.nan_to_num(sig)
    every = np.ones(6, bool)
    rng = np.random.default_rng([int(seeds[0]), 41])

    def per_set_logz(y):                                       # (scenarios, sets)
        return np.array([logsumexp(_set_log_likelihood(*raw[k], y, sig, every, opts.floor,
                                                       opts.rel_floor), axis=1)
                         - np.log(raw[k][0].shape[1]) for k in COMPARED])

    res: dict = {}
    for mode in ("shared", "per release"):
        ess = []
        for s in seeds:
            for ik, kind in enumerate(COMPARED):
                m = _OneSet(fm, 7 * s + ik) if mode == "shared" else fm
                tr = draw_truths(m, [kind] * releases, s + SCENARIO_SEED_STRIDE * ik, prior)
                y = tr.velocity + sig * rng.standard_normal(tr.velocity.shape)
                L = np.array([per_set_logz(yi) for yi in y])   # (R, K, M)
                marg = logsumexp(L, axis=1) - np.log(len(COMPARED))
                for i in range(len(y)):
                    lw = marg[np.arange(len(y)) != i].sum(0)
                    lw = lw - logsumexp(lw)
                    ess.append(float(np.exp(-logsumexp(2 * lw))))
                    for name, lz in (("unpooled", logsumexp(L[i], axis=1)),
                                     ("pooled", logsumexp(L[i] + lw, axis=1))):
                        r = res.setdefault((mode, name), {"n": 0, "right": 0, "confusion": {}})
                        chosen = COMPARED[int(np.argmax(lz))]
                        r["n"] += 1
                        r["right"] += chosen == kind
                        count(r["confusion"], kind, chosen)
        for name in ("unpooled", "pooled"):
            res[(mode, name)]["ess_median"] = float(np.median(ess))
    return {"n_model": n_model, "variants": res}


def per_set_predictives(fm, opts, prior) -> dict:
    """The method's prior predictives with **each parameter set's own** contact geometry,
    TM centre and masses (the points of ``named_points`` move with the fitted v2, g2,
    m2-m4), where the method takes the best fit's for every set: one ``scenario_velocity``
    call per set on the method's sets (``model_sets``) and prior draws, the moments as the
    method takes them (``set_moments``)."""
    from gprm.flight.inference import PriorPredictive, model_sets, set_moments
    from gprm.flight.scenario import (COMPARED, COMPONENTS, OFFSETS, SCENARIOS,
                                      _subset_frame, plunger_frame, scenario_grid,
                                      scenario_velocity)
    from gprm.params import batch
    from gprm.simulate.kinematics import body_motion

    pb0 = batch([fm.params])
    pm = model_sets(fm, opts)
    frame = plunger_frame(body_motion(pm, scenario_grid(pb0, step=opts.grid_step),
                                      piezo=fm.piezo))
    K, M = opts.n_draws, opts.n_model
    out = {}
    for kind in COMPARED:
        p = prior.draw(K, np.random.default_rng([opts.seed, SCENARIOS.index(kind)]))
        p.update({k: np.zeros(K) for k in OFFSETS})
        y, t, ok = np.full((M, K, 6), np.nan), np.full((M, K), np.nan), np.zeros((M, K), bool)
        for b in range(M):
            sb = {k: np.atleast_1d(v)[b:b + 1] if np.size(v) == M else v for k, v in pm.items()}
            o = scenario_velocity(kind, _subset_frame(frame, [b]), sb, p, prior)
            y[b] = np.stack([o[c][0] for c in COMPONENTS], -1)
            t[b], ok[b] = o["t"][0], o["ok"][0]
        mom = set_moments(y, t, ok, opts, prior, float(np.ravel(pb0["s_tm"])[0]))
        out[kind] = PriorPredictive(kind, p, mom["mean"], mom["cov"], mom["t_mean"],
                                    mom["t_cov"], mom["t_var"], mom["valid"], mom["p_impact"])
    return out


def geometry_study(fm, seeds, releases: int, draws: int) -> dict:
    """Does the method lose by taking the best fit's contact geometry and masses for every
    parameter set (docs/flight.md §11)? On the recovery's truths (each its set's own
    geometry), the scenario choice and each unknown's coverage with the method's prior
    predictives and with :func:`per_set_predictives`; the same likelihood otherwise."""
    from gprm.flight.inference import (InferenceOptions, infer_scenarios, posterior_weights,
                                       prior_predictives)
    from gprm.flight.scenario import PARAMS, ScenarioPrior

    prior, opts = ScenarioPrior(), InferenceOptions(n_draws=draws)
    variants = {"the best fit's geometry and masses for every set (the method)":
                prior_predictives(fm, opts, prior),
                "each set's own": per_set_predictives(fm, opts, prior)}
    res = {v: {"n": 0, "right": 0, "confusion": {}, "in95": {k: 0 for k in PARAMS},
               "in50": {k: 0 for k in PARAMS}} for v in variants}
    for _s, kind, ds, tel, y, sig in scenario_campaigns(fm, seeds, releases):
        for name, pps in variants.items():
            inf = infer_scenarios(fm, [r.id for r in tel.releases], y, sig, opts,
                                  predictive=pps)
            r = res[name]
            for i, chosen in enumerate(inf.chosen_alone):
                r["n"] += 1
                r["right"] += chosen == kind
                count(r["confusion"], kind, chosen)
                tally_unknowns(r, pps[kind].params,
                               posterior_weights(pps[kind], np.nan_to_num(y[i]),
                                                 np.nan_to_num(sig[i]), np.isfinite(y[i]),
                                                 opts), ds, i)
    return res


def impact_times(fm, seeds, releases: int, models, scenario: str = "two",
                 samples: int = 200) -> dict:
    """The impact-time analysis (issue 14's, `gprm impact --impact-model MODEL`) on scenario
    truths (`gprm synth telemetry --scenario SCENARIO`): per model, the totals of
    :func:`gprm.flight.analysis.truth_summary`, the joint chi2 and Tukey rejections; the
    curves of each model are computed once (they depend on the model and the seed only)."""
    from gprm.flight import AnalysisOptions, SynthOptions, analyze, synth_telemetry
    from gprm.flight.files import telemetry_from_dataset

    out = {}
    curves = {}
    for model in models:
        out[model] = {**new_totals(), "errors_us": []}
    for s in seeds:
        ds = synth_telemetry(fm, SynthOptions(n_releases=releases, seed=s, scenario=scenario))
        tel = telemetry_from_dataset(ds, source=f"seed {s}")
        for model in models:
            res = analyze(fm, tel, AnalysisOptions(impact_model=model, n_samples=samples),
                          curves=curves.get(model))
            curves[model] = res.curves
            doc = res.to_json()
            t = out[model]
            add_analysis(t, doc)
            t["errors_us"] += [(r["joint"]["value"] - r["truth_impact_time"]) * 1e6
                               for r in doc["releases"] if r["joint"].get("value") is not None]
    return out


def study_heading(title: str, a, t0: float, extra: str = "") -> None:
    """A study's markdown heading: its truths (campaigns, releases, seeds), draws and time."""
    print(f"### {title} ({a.seeds} campaigns × {a.releases} releases of each of xz, yz, two, "
          f"seeds {a.seed0}–{a.seed0 + a.seeds - 1} (+10000 per scenario); {a.draws} prior "
          f"draws{extra}; {time.perf_counter() - t0:.0f} s)\n")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--observations", action="store_true")
    ap.add_argument("--recovery", action="store_true")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--seed0", type=int, default=2000)
    ap.add_argument("--releases", type=int, default=11)
    ap.add_argument("--draws", type=int, default=20000)
    ap.add_argument("--rel-floor", type=float, default=None)
    ap.add_argument("--refine", type=int, default=0,
                    help="--recovery: draws of the second importance stage per release and "
                         "scenario (InferenceOptions.n_refine; 0: none)")
    ap.add_argument("--mixed", action="store_true",
                    help="--recovery: files whose releases each draw their scenario (one file "
                         "per seed) instead of one file per scenario")
    ap.add_argument("--impact-times", action="store_true")
    ap.add_argument("--scenario", default="two")
    ap.add_argument("--refine-study", action="store_true",
                    help="sampling or likelihood: stage 1 vs a second stage of --refine "
                         "draws, floors as they are, halved, quartered, none (§11)")
    ap.add_argument("--likelihood-study", action="store_true",
                    help="why the friction's interval is too wide (docs/flight.md §11); run "
                         "it on seeds other than the recovery's")
    ap.add_argument("--aligned-study", action="store_true",
                    help="the choice and the unknowns' coverage under a Gaussian aligned "
                         "with the velocity for the one-contact scenarios (§11)")
    ap.add_argument("--geometry-study", action="store_true",
                    help="the method's prior predictives against ones with each parameter "
                         "set's own contact geometry and masses (§11)")
    ap.add_argument("--oracle-study", action="store_true",
                    help="the scenario choice's ceiling: each truth classified at its own "
                         "parameter set (--seeds N: N truths of each scenario, seed --seed0)")
    ap.add_argument("--mixture-choice", action="store_true",
                    help="the per-release choice under the Gaussian summary of the parameter "
                         "sets and under their exact mixture (--sets N of them; §11)")
    ap.add_argument("--pooled-choice", action="store_true",
                    help="the per-release choice with the parameter set pooled over the "
                         "file's other releases, on truths with one set per file and one "
                         "per release (--sets N; §11)")
    ap.add_argument("--sets", type=int, default=48,
                    help="--mixture-choice, --pooled-choice: parameter sets from the fit "
                         "(n_model)")
    ap.add_argument("--tm-offset", type=float, nargs="+", default=None, metavar="MM",
                    help="--observations: the TM's largest lateral offset from the head "
                         "axis, mm (one table per value; default: ScenarioPrior's)")
    a = ap.parse_args()
    from gprm.fit.files import paper_model

    fm = paper_model()
    seeds = range(a.seed0, a.seed0 + a.seeds)
    print("## Impact scenarios (`gprm.flight.scenario`, `gprm.flight.inference`)\n")
    print(machine("numpy", "scipy"))
    print(f"- command: `.venv/bin/python benchmarks/bench_scenarios.py "
          f"{'--observations ' if a.observations else ''}{'--recovery ' if a.recovery else ''}"
          f"{'--impact-times ' if a.impact_times else ''}"
          f"{'--likelihood-study ' if a.likelihood_study else ''}"
          f"{'--aligned-study ' if a.aligned_study else ''}"
          f"{'--refine-study ' if a.refine_study else ''}"
          f"{'--oracle-study ' if a.oracle_study else ''}"
          f"{'--geometry-study ' if a.geometry_study else ''}"
          f"{'--mixture-choice --sets ' + str(a.sets) + ' ' if a.mixture_choice else ''}"
          f"{'--pooled-choice --sets ' + str(a.sets) + ' ' if a.pooled_choice else ''}"
          f"{'--scenario ' + a.scenario + ' ' if a.scenario != 'two' else ''}"
          f"{'--mixed ' if a.mixed else ''}"
          f"--seeds {a.seeds} --seed0 {a.seed0} --releases {a.releases} --draws {a.draws}"
          + ("" if a.rel_floor is None else f" --rel-floor {a.rel_floor}")
          + ("" if not a.refine else f" --refine {a.refine}")
          + ("" if a.tm_offset is None else " --tm-offset " + " ".join(map(str, a.tm_offset)))
          + "`\n")
    for off in (a.tm_offset or [None]) if a.observations else []:
        t0 = time.perf_counter()
        rows = observations(fm, seeds, a.releases, None if off is None else off * 1e-3,
                            None if off is None else ("xz", "yz", "two"))
        print(f"### The paper's three observations ({a.seeds} campaigns × {a.releases} "
              f"releases, seeds {a.seed0}–{a.seed0 + a.seeds - 1}"
              + ("" if off is None else f"; TM offset U(±{off} mm) in x and y")
              + f"; {time.perf_counter() - t0:.1f} s)\n")
        print("| scenario | z not the largest | x–z share median | share ≥ 0.9 | v_x, v_y, v_z, "
              "ω_x, ω_y all non-compliant | all three at once | compliant v_x, v_y, v_z, "
              "ω_x, ω_y, ω_z | mean abs v (µm/s) | mean abs ω (µrad/s) | \\|ω_z\\| median, "
              "90 % (µrad/s) |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            n = r["n"]
            def pc(k, r=r, n=n):
                return f"{r[k]}/{n} ({100 * r[k] / n:.0f} %)"
            m = r["mean_abs"]
            print(f"| {r['scenario']} | {pc('z_not_largest')} | {r['share_median']:.3f} | "
                  f"{pc('share_ge_0.9')} | {pc('all5_noncompliant')} | {pc('all_three')} | "
                  f"{', '.join(str(c) for c in r['compliant'])} | "
                  f"{m[0] * 1e6:.1f}, {m[1] * 1e6:.1f}, {m[2] * 1e6:.1f} | "
                  f"{m[3] * 1e6:.0f}, {m[4] * 1e6:.0f}, {m[5] * 1e6:.0f} | "
                  f"{r['wz_q'][0] * 1e6:.0f}, {r['wz_q'][1] * 1e6:.0f} |")
        print()
    if a.impact_times:
        t0 = time.perf_counter()
        models = ("two", "xz", "3d", "planar")
        out = impact_times(fm, seeds, a.releases, models, a.scenario)
        print(f"### Impact times on scenario truths ({a.seeds} campaigns × {a.releases} "
              f"releases of scenario {a.scenario}, seeds {a.seed0}–{a.seed0 + a.seeds - 1}; "
              f"{time.perf_counter() - t0:.0f} s)\n")
        print("| analysis (impact model) | found | within 2σ of truth | joint 95 % interval "
              "contains truth | joint error median, 90 % range (µs) | joint χ² rejects "
              "(α = 0.01) | campaigns where Tukey rejects |")
        print("|---|---|---|---|---|---|---|")
        for m, t in out.items():
            e = np.array(t["errors_us"])
            q = (np.percentile(e, [50, 5, 95]) if e.size else [np.nan] * 3)
            f = lambda a, b: f"{a}/{b} ({100 * a / max(b, 1):.1f} %)"  # noqa: E731
            print(f"| {m} | {f(t['found'], t['impact_times'])} | "
                  f"{f(t['within_2sigma'], t['found'])} | "
                  f"{f(t['joint_truth_in_ci95'], t['joint_releases'])} | "
                  f"{q[0]:+.1f} [{q[1]:+.1f}, {q[2]:+.1f}] | "
                  f"{f(t['chi2_rejects'], t['chi2_tests'])} | "
                  f"{t['tukey_rejecting_campaigns']}/{t['campaigns']} |")
        print()
    if a.likelihood_study:
        t0 = time.perf_counter()
        res = likelihood_study(fm, seeds, a.releases, a.draws)
        n = next(iter(res.values()))["n"]
        print(f"### Likelihood study ({a.seeds} campaigns × {a.releases} releases of each of "
              f"xz, yz, two, TM centred, seeds {a.seed0}.. (+10000 per scenario); {a.draws} "
              f"prior draws; {time.perf_counter() - t0:.0f} s)\n")
        print(f"Per unknown: truth inside the 95 % / the central 50 % interval (of {n}), "
              "posterior sd / prior sd (median).\n")
        from gprm.flight.scenario import PARAMS
        print("| likelihood | median effective draws | "
              + " | ".join(PARAMS) + " |")
        print("|---|---|" + "---|" * len(PARAMS))
        for name, r in res.items():
            print(f"| {name} | {r['ess']:.0f} | " + " | ".join(
                f"{100 * r['in95'][k] / n:.1f} / {100 * r['in50'][k] / n:.1f} %, "
                f"{r['sd'][k]:.2f}" for k in PARAMS) + " |")
        print()
    if a.aligned_study:
        t0 = time.perf_counter()
        res = aligned_study(fm, seeds, a.releases, a.draws)
        from gprm.flight.scenario import PARAMS
        n = next(iter(res.values()))["n"]
        study_heading("A Gaussian aligned with the velocity", a, t0)
        print(f"Right scenario per release; per unknown the truth inside the 95 % / the "
              f"central 50 % interval (of {n}), posterior sd / prior sd (median).\n")
        print("| likelihood | right scenario | confusion | median effective draws | "
              + " | ".join(PARAMS) + " |")
        print("|---|---|---|---|" + "---|" * len(PARAMS))
        for name, r in res.items():
            print(f"| {name} | {r['right']}/{n} ({100 * r['right'] / n:.1f} %) | "
                  + ", ".join(f"{k} {c}" for k, c in sorted(r["confusion"].items()))
                  + f" | {r['ess']:.0f} | " + " | ".join(
                      f"{100 * r['in95'][k] / n:.1f} / {100 * r['in50'][k] / n:.0f} %, "
                      f"{r['sd'][k]:.2f}" for k in PARAMS) + " |")
        print()
    if a.refine_study:
        t0 = time.perf_counter()
        out = refine_study(fm, seeds, a.releases, a.draws, a.refine or 1000)
        from gprm.flight.scenario import PARAMS
        n = next(iter(out["variants"].values()))["n"]
        study_heading("Sampling or likelihood", a, t0,
                      f", {a.refine or 1000} second-stage draws")
        print(f"Per unknown: truth inside the 95 % interval (below, above) / inside the "
              f"central 50 %, of {n}.\n")
        print("| stage | floor and allowance | median effective draws | "
              + " | ".join(PARAMS) + " |")
        print("|---|---|---|" + "---|" * len(PARAMS))
        for (st, name), r in out["variants"].items():
            print(f"| {st} | {name} | {r['ess']:.0f} | " + " | ".join(
                f"{100 * r['in95'][k] / n:.1f} ({r['below'][k]}, {r['above'][k]}) / "
                f"{100 * r['in50'][k] / n:.0f} %" for k in PARAMS) + " |")
        print("\nμ's |posterior mean − truth| / posterior sd, median (stage 1, the method; "
              "0.67 for a calibrated normal): "
              + ", ".join(f"{k} {v:.2f}" for k, v in out["mu_z"].items()) + "\n")
    if a.geometry_study:
        t0 = time.perf_counter()
        res = geometry_study(fm, seeds, a.releases, a.draws)
        from gprm.flight.scenario import PARAMS
        n = next(iter(res.values()))["n"]
        study_heading("Each parameter set's own geometry", a, t0)
        print(f"Right scenario per release, and per unknown the truth inside the 95 % / the "
              f"central 50 % interval (of {n}).\n")
        print("| prior predictive | right scenario | confusion | " + " | ".join(PARAMS) + " |")
        print("|---|---|---|" + "---|" * len(PARAMS))
        for name, r in res.items():
            print(f"| {name} | {r['right']}/{n} ({100 * r['right'] / n:.1f} %) | "
                  + ", ".join(f"{k} {c}" for k, c in sorted(r["confusion"].items())) + " | "
                  + " | ".join(f"{100 * r['in95'][k] / n:.1f} / {100 * r['in50'][k] / n:.0f} %"
                               for k in PARAMS) + " |")
        print()
    if a.mixture_choice:
        t0 = time.perf_counter()
        out = mixture_choice_study(fm, seeds, a.releases, a.draws, a.sets)
        study_heading(f"The choice under the exact mixture over {a.sets} parameter sets", a, t0)
        print("| likelihood | right scenario | confusion (truth->chosen) |\n|---|---|---|")
        for v, r in out["variants"].items():
            print(f"| {v} | {r['right']}/{r['n']} ({100 * r['right'] / r['n']:.1f} %) | "
                  + ", ".join(f"{k} {c}" for k, c in sorted(r["confusion"].items())) + " |")
        print()
    if a.pooled_choice:
        t0 = time.perf_counter()
        out = pooled_choice_study(fm, seeds, a.releases, a.draws, a.sets)
        study_heading(f"The choice with the parameter set pooled over a file's releases "
                      f"({a.sets} sets)", a, t0)
        print("| truths' parameter set | sets weighted | right scenario | confusion "
              "(truth->chosen) | median effective sets (pooled) |\n|---|---|---|---|---|")
        for (mode, v), r in out["variants"].items():
            print(f"| {mode} | {v} | {r['right']}/{r['n']} "
                  f"({100 * r['right'] / r['n']:.1f} %) | "
                  + ", ".join(f"{k} {c}" for k, c in sorted(r["confusion"].items()))
                  + f" | {r['ess_median']:.1f} |")
        print()
    if a.oracle_study:
        t0 = time.perf_counter()
        out = oracle_study(fm, a.seed0, a.seeds, a.draws)
        print(f"### The scenario choice at the truth's own parameter set ({a.seeds} truths of "
              f"each of xz, yz, two, seed {a.seed0}; {a.draws} prior draws per scenario; "
              f"{time.perf_counter() - t0:.0f} s)\n")
        print("measurement standard errors (median of synthetic telemetry): "
              + ", ".join(f"{c} {s_:.3g}" for c, s_ in zip(
                  ("vx", "vy", "vz", "wx", "wy", "wz"), out["sigma"])) + "\n")
        print("| likelihood | right scenario | confusion (truth->chosen) |\n|---|---|---|")
        for v, r in out["variants"].items():
            print(f"| {v} | {r['right']}/{r['n']} ({100 * r['right'] / r['n']:.1f} %) | "
                  + ", ".join(f"{k} {c}" for k, c in sorted(r["confusion"].items())) + " |")
        print()
    if a.recovery:
        t0 = time.perf_counter()
        out = recovery(fm, seeds, a.releases, a.draws, a.rel_floor, a.refine, a.mixed)
        n = out["n"]
        what = (f"{a.releases} releases each drawing its scenario from xz, yz, two, seeds "
                f"{a.seed0}–{a.seed0 + a.seeds - 1} (+30000)" if a.mixed else
                f"{a.releases} releases of each of xz, yz, two, seeds "
                f"{a.seed0}–{a.seed0 + a.seeds - 1} (+10000 per scenario)")
        print(f"### Scenario posterior: recovery ({a.seeds} campaigns × {what}; "
              f"{a.draws} prior draws per scenario"
              + (f", {a.refine} second-stage draws per release and scenario" if a.refine
                 else "") + f"; {time.perf_counter() - t0:.0f} s; prior predictives "
              f"{out['pp_cpu_s']:.1f} s CPU)\n")
        print(f"- right scenario chosen: {out['right']}/{n} "
              f"({100 * out['right'] / n:.1f} %); by truth: "
              + ", ".join(f"{k} {v[0]}/{v[1]}" for k, v in out["by_truth"].items()))
        print(f"- confusion (truth->chosen): {out['confusion']}")
        print(f"- right scenario chosen per release given the file (pooled): {out['pooled']}/{n}"
              f" ({100 * out['pooled'] / n:.1f} %); by truth: "
              + ", ".join(f"{k} {v[0]}/{v[1]}" for k, v in out["pooled_by_truth"].items())
              + f"; confusion {out['pooled_confusion']}")
        print(f"- right scenario chosen per release given the file (one scenario for all "
              f"or each its own, file_probabilities): {out['file']}/{n}"
              f" ({100 * out['file'] / n:.1f} %); by truth: "
              + ", ".join(f"{k} {v[0]}/{v[1]}" for k, v in out["file_by_truth"].items())
              + f"; confusion {out['file_confusion']}; P(one scenario | file) per file: "
              + ", ".join(f"{p:.2g}" for p in out["file_p_same"]))
        print("- the same with other prior probabilities of one scenario per file: "
              + ", ".join(f"{q:g}: {c}/{n} ({100 * c / n:.1f} %)"
                          for q, c in out["file_check"].items()))
        if "composite" in out:
            print("\n| files of one scenario with m releases of another | files | P(one scenario) "
                  "> 0.5 | majority's releases right: alone, given the file | minority's "
                  "releases right: alone, given the file |\n|---|---|---|---|---|")
            for m, t in out["composite"].items():
                ma, mi = t["majority"], t["minority"]
                print(f"| m = {m} | {t['files']} | {t['same']} | {ma[0]}/{ma[2]}, {ma[1]}/{ma[2]} "
                      f"| {mi[0]}/{mi[2]}, {mi[1]}/{mi[2]} |")
            print()
        jr = sum(v[0] for v in out["joint"].values())
        jn = sum(v[1] for v in out["joint"].values())
        print(f"- right scenario chosen jointly over a file's {a.releases} releases: {jr}/{jn}"
              f" ({100 * jr / max(jn, 1):.1f} %); by truth: "
              + ", ".join(f"{k} {v[0]}/{v[1]}" for k, v in out["joint"].items())
              + f"; confusion {out['joint_confusion']}")
        print(f"- median effective number of draws (true scenario): {out['ess_median']:.0f}\n")
        print("| unknown | truth inside the 95 % interval | below it, above it | inside the "
              "central 50 % | 95 % interval width / the prior's central 95 %, median |")
        print("|---|---|---|---|---|")
        for k, c in out["covered"].items():
            w = out["width"].get(k)
            c50 = out["covered50"].get(k)
            print(f"| {k} | {c}/{n} ({100 * c / n:.1f} %) | "
                  f"{out['below'][k]}, {out['above'][k]} | "
                  f"{'' if c50 is None else f'{c50}/{n} ({100 * c50 / n:.1f} %)'} | "
                  f"{'' if w is None else f'{w:.2f}'} |")
        print()


if __name__ == "__main__":
    main()
