"""Flight analysis pipeline (``gprm impact``): release velocities -> predicted curves ->
impact times -> Tukey test, as the JSON of INTERFACES.md plus a NetCDF sidecar of the curves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gprm.errors import GprmInputError
from gprm.flight.impact_time import first_crossing
from gprm.flight.predicted import velocity_curves
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


def analyze(model, tel, opts: AnalysisOptions = AnalysisOptions(), curves=None):
    """Run the flight analysis; returns ``(doc, curves)``: the JSON document and the
    :class:`~gprm.flight.predicted.VelocityCurves` used."""
    vel = release_velocities(tel, fit_window=opts.fit_window, min_samples=opts.min_samples)
    if curves is None:
        curves = velocity_curves(model, window=opts.window, n_times=opts.n_times,
                                 n_samples=opts.n_samples, seed=opts.seed)
    releases = []
    groups = {a: [] for a in AXES}
    missing = []
    for r in tel.releases:
        v = vel[r.id]
        it = {}
        for a in AXES:
            res = first_crossing(curves.time, curves.nominal[a], curves.sigma[a],
                                 v[a].value, v[a].stderr)
            it[a] = res
            if res.value is not None and res.stderr is not None:
                groups[a].append(res.value)
            else:
                missing.append({"release": r.id, "axis": a, "reason": res.reason})
        releases.append({
            "id": r.id, "release_time": r.release_time,
            "velocity": {a: {"value": v[a].value, "stderr": v[a].stderr, "unit": AXIS_UNIT[a],
                             "n": v[a].n, "reduced_chi2": v[a].reduced_chi2,
                             "weighted": v[a].weighted} for a in AXES},
            "impact_time": {a: it[a].to_json() for a in AXES}})
    tk = None
    tukey_note = None
    try:
        tk = tukey_range_test(groups, alpha=opts.alpha)
    except GprmInputError as exc:  # too few crossings: report, do not fail
        tukey_note = f"Tukey test not possible: {exc.problem}"
    doc = {
        "format": "gprm-impact", "format_version": 1,
        "model_source": str(model.source), "telemetry": tel.source, "piezo": model.piezo,
        "time_base": "s from the start of the retraction record (retraction command at t_c)",
        "window": [float(curves.time[0]), float(curves.time[-1])],
        "releases": releases,
        "missing": missing,
        "tukey": (tk.to_json() if tk is not None
                  else {"alpha": opts.alpha, "k": None, "df": None, "q_critical": None,
                        "pairs": [], "note": tukey_note}),
        "curves": {"sidecar": None, "n_samples": curves.n_samples, "seed": curves.seed},
        "options": {k: (list(v) if isinstance(v, tuple) else v)
                    for k, v in opts.__dict__.items()},
    }
    if tk is not None:
        doc["tukey"]["all_compatible"] = not any(p.reject for p in tk.pairs)
    if tel.truth_impact_time is not None:
        doc["truth"] = {"impact_time": [float(x) for x in tel.truth_impact_time]}
    return doc, curves


def curves_dataset(curves, doc=None):
    """The velocity-vs-impact-time curves as an :class:`xarray.Dataset` (the sidecar)."""
    import xarray as xr

    dv = {}
    for name, d in (("nominal", curves.nominal), ("sigma", curves.sigma),
                    ("sigma_fit", curves.sigma_fit), ("sigma_geometry", curves.sigma_geometry),
                    ("lo", curves.lo), ("hi", curves.hi)):
        dv[name] = (("axis", "time"), np.stack([d[a] for a in AXES]),
                    {"units": "m/s (vx, vz_xz, vy, vz_yz) or rad/s (wy, wx)"})
    dv["approaching"] = (("plane", "time"),
                         np.stack([curves.approaching[p] for p in ("xz", "yz")]).astype("i1"))
    dv["plausible"] = (("time",), curves.plausible,
                       {"long_name": "fraction of joint samples approaching in both planes"})
    ds = xr.Dataset(dv, coords={"axis": list(AXES), "plane": ["xz", "yz"],
                                "time": ("time", curves.time, {"units": "s"})},
                    attrs={"format": "gprm-impact-curves", "n_samples": curves.n_samples,
                           "seed": curves.seed, "source": str(curves.meta.get("source", ""))})
    return ds
