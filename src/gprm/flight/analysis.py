"""Flight analysis pipeline (``gprm impact``): release velocities -> predicted curves ->
impact times -> Tukey test, as the JSON of INTERFACES.md plus a NetCDF sidecar of the curves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gprm.errors import GprmInputError
from gprm.flight.impact_time import impact_time_mc
from gprm.flight.joint import joint_impact_time
from gprm.flight.predicted import ImpactGeometry, velocity_curves
from gprm.flight.telemetry import AXES, AXIS_UNIT, release_velocities
from gprm.flight.tukey import tukey_range_test


@dataclass(frozen=True)
class AnalysisOptions:
    alpha: float = 0.01
    n_samples: int = 200
    n_times: int = 401
    seed: int = 0
    window: tuple | None = None
    fit_window: float | None = None
    min_samples: int = 5
    impact_model: str = "3d"


def _duplicate_axes(curves) -> set:
    """Axes that repeat an earlier axis: same telemetry channel and the same curves (both v_z
    axes of the one-contact 3D model). They keep their impact time (k = 6 for Tukey) but enter
    the joint estimate once."""
    from gprm.flight.telemetry import AXIS_CHANNEL

    dup = set()
    for i, a in enumerate(AXES):
        for b in AXES[:i]:
            if (AXIS_CHANNEL[a] == AXIS_CHANNEL[b]
                    and np.array_equal(curves.nominal[a], curves.nominal[b], equal_nan=True)
                    and (curves.samples is None
                         or np.array_equal(curves.samples[a], curves.samples[b],
                                           equal_nan=True))):
                dup.add(a)
    return dup


def analyze(model, tel, opts: AnalysisOptions = AnalysisOptions(), curves=None):
    """Run the flight analysis; returns ``(doc, curves)``: the JSON document and the
    :class:`~gprm.flight.predicted.VelocityCurves` used."""
    if opts.impact_model not in ("3d", "planar"):
        raise GprmInputError("must be 3d or planar", field="--impact-model")
    vel = release_velocities(tel, fit_window=opts.fit_window, min_samples=opts.min_samples)
    if curves is None:
        curves = velocity_curves(model, window=opts.window, n_times=opts.n_times,
                                 n_samples=opts.n_samples, seed=opts.seed,
                                 geometry=ImpactGeometry(impact_model=opts.impact_model))
    if curves.samples is None:
        raise GprmInputError("curves without their joint draws", field="curves")
    has_unc = bool(getattr(model, "has_uncertainty", True))
    dup = _duplicate_axes(curves)
    truth_t = tel.truth_impact_time
    releases = []
    groups = {a: [] for a in AXES}
    missing = []
    for ir, r in enumerate(tel.releases):
        v = vel[r.id]
        it = {}
        for ia, a in enumerate(AXES):
            res = impact_time_mc(curves.time, curves.nominal[a], curves.sigma[a],
                                 curves.samples[a], v[a].value, v[a].stderr,
                                 seed=opts.seed + 7919 * (ir + 1) + ia)
            it[a] = res
            if res.value is not None and res.stderr is not None:
                groups[a].append(res.value)
            else:
                missing.append({"release": r.id, "axis": a, "reason": res.reason})
        use = [a for a in AXES if a not in dup]
        jt = joint_impact_time({a: it[a].value for a in use}, {a: it[a].stderr for a in use},
                               {a: it[a].draws for a in use},
                               {a: it[a].draw_slopes for a in use})
        rec = {
            "id": r.id, "release_time": r.release_time,
            "velocity": {a: {"value": v[a].value, "stderr": v[a].stderr, "unit": AXIS_UNIT[a],
                             "n": v[a].n, "reduced_chi2": v[a].reduced_chi2,
                             "weighted": v[a].weighted} for a in AXES},
            "impact_time": {a: it[a].to_json() for a in AXES},
            "joint": jt.to_json()}
        if truth_t is not None:
            tt = float(truth_t[ir])
            rec["truth_impact_time"] = tt
            rec["error_sigma"] = {a: ((it[a].value - tt) / it[a].stderr
                                      if it[a].value is not None and it[a].stderr else None)
                                  for a in AXES}
            rec["joint"]["truth_in_ci95"] = (None if jt.ci95 is None
                                             else bool(jt.ci95[0] <= tt <= jt.ci95[1]))
        releases.append(rec)
    tk = None
    tukey_note = None
    try:
        tk = tukey_range_test(groups, alpha=opts.alpha)
    except GprmInputError as exc:  # too few crossings: report, do not fail
        tukey_note = f"Tukey test not possible: {exc.problem}"
    doc = {
        "format": "gprm-impact", "format_version": 1,
        "model_source": str(model.source), "telemetry": tel.source, "piezo": model.piezo,
        "impact_model": curves.meta.get("impact_model", opts.impact_model),
        "model_uncertainty": ("fit covariance and impact geometry" if has_unc else
                              "best fit only (the fit has no usable covariance): the bands "
                              "and error bars carry the impact geometry's uncertainty only"),
        "time_base": "s from the start of the retraction record (retraction command at t_c)",
        "window": [float(curves.time[0]), float(curves.time[-1])],
        "releases": releases,
        "missing": missing,
        "tukey": (tk.to_json() if tk is not None
                  else {"alpha": opts.alpha, "k": None, "df": None, "q_critical": None,
                        "pairs": [], "note": tukey_note}),
        "joint": _joint_summary(releases, opts.alpha),
        "curves": {"sidecar": None, "n_samples": curves.n_samples, "seed": curves.seed},
        "options": {k: (list(v) if isinstance(v, tuple) else v)
                    for k, v in opts.__dict__.items()},
    }
    if tk is not None:
        doc["tukey"]["all_compatible"] = not any(p.reject for p in tk.pairs)
    if truth_t is not None:
        doc["truth"] = {"impact_time": [float(x) for x in truth_t],
                        "summary": truth_summary(doc)}
    return doc, curves


def _joint_summary(releases, alpha) -> dict:
    """The joint estimates' χ² consistency check over the releases at level ``alpha``."""
    ps = [r["joint"]["p"] for r in releases if r["joint"].get("p") is not None]
    return {"alpha": alpha, "n": len(ps),
            "rejected": [r["id"] for r in releases
                         if r["joint"].get("p") is not None and r["joint"]["p"] < alpha],
            "all_consistent": all(p >= alpha for p in ps) if ps else None}


def truth_summary(doc) -> dict:
    """Found / within-2σ / joint-coverage counts of an impact document with truth."""
    n_tot = n_found = n_2s = n_j = n_jin = 0
    for r in doc["releases"]:
        if "truth_impact_time" not in r:
            continue
        for a in AXES:
            n_tot += 1
            z = r["error_sigma"][a]
            if z is not None:
                n_found += 1
                n_2s += abs(z) <= 2.0
        if r["joint"].get("truth_in_ci95") is not None:
            n_j += 1
            n_jin += r["joint"]["truth_in_ci95"]
    return {"impact_times": n_tot, "found": n_found, "within_2sigma": int(n_2s),
            "joint_releases": n_j, "joint_truth_in_ci95": int(n_jin)}
