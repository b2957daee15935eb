"""The prediction NetCDF (``gprm predict --out F.nc``; docs/prediction.md, format_version 1):
its layout (:func:`prediction_dataset`), writer (:func:`write_prediction`), reader
(:func:`read_prediction`, checked against :data:`PREDICTION`) and typed accessors of its
metadata (:func:`read_parameters`, :func:`read_scenario`, :func:`read_energy_window`,
:func:`read_impact_risk`); and the what-if table of ``gprm predict --whatif``
(:func:`write_whatif`, :func:`read_whatif`). Files written before the metadata became
variables (the JSON attributes ``parameters_json``, ``fitted_json``, ``scenario_json``,
``energy_window_s``, ``impact_risk_json``) read too."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np
import xarray as xr

import gprm
from gprm._io import open_netcdf, read_json, write_json_atomic, write_netcdf_atomic
from gprm.errors import GprmInputError
from gprm.params.netcdf import parameter_table, read_fitted, read_parameter_table
from gprm.predict.masses import mass_arrays
from gprm.predict.risk import CONTACTS
from gprm.predict.trajectories import AXES
from gprm.predict.whatif import DEFINITION
from gprm.validate import Schema, Var, check_dataset, legacy_json_attr

if TYPE_CHECKING:                      # the type only: core builds its dataset from here
    from gprm.predict.core import Prediction

FORMAT_VERSION = 1


def prediction_dataset(pred: Prediction) -> xr.Dataset:
    tr, en = pred.trajectories, pred.energy
    P3T = ("point", "axis", "time")
    v = {}

    def put(name, dims, data, units, long):
        v[name] = xr.Variable(dims, np.asarray(data, float), {"units": units, "long_name": long})

    put("pos", P3T, tr.pos, "m", "best-fit displacement from the initial equilibrium position")
    put("vel", P3T, tr.vel, "m s-1", "best-fit velocity (exact, from the simulated rates)")
    put("pos_initial", ("point", "axis"), tr.static, "m",
        "initial equilibrium position; origin at point A at rest, ground axes")
    for k, u, lab in (("pos", "m", "displacement"), ("vel", "m s-1", "velocity")):
        put(f"{k}_p2_5", P3T, getattr(tr, f"{k}_lo"), u, f"{lab}: 2.5 % quantile over samples")
        put(f"{k}_p97_5", P3T, getattr(tr, f"{k}_hi"), u,
            f"{lab}: 97.5 % quantile over samples")
        put(f"{k}_std", P3T, getattr(tr, f"{k}_std"), u, f"{lab}: std over samples")
        put(f"{k}_std_linear", P3T, getattr(tr, f"{k}_std_lin"), u,
            f"{lab}: linear std sqrt(J C J^T)")
    put("pos_samples", ("sample",) + P3T, tr.samples_pos, "m",
        "displacement of the first sampled parameter sets (for plotting)")
    put("overshoot", ("point", "axis"), pred.overshoot, "m", DEFINITION.split(";")[0])
    # kinetic energy (Fig. 8)
    put("ke_weight", ("etime",), en.weights, "s", "time weight of each sample in the window")
    put("ke_model_total", ("etime",), en.model_total, "J",
        "model kinetic energy, all bodies (m1, m2 + J2, m3, m4), best fit")
    put("ke_model_point", ("etime",), en.model_point, "J",
        "E_5 from the model's five measured points, best fit")
    nanT = np.full(en.time.size, np.nan)
    nanB = np.full(en.edges.size - 1, np.nan)
    put("ke_measured", ("etime",), nanT if en.measured_point is None else en.measured_point,
        "J", "E_5 from the measured mean signals")
    put("ke_measured_std", ("etime",),
        nanT if en.measured_point_std is None else en.measured_point_std, "J",
        "linear std of ke_measured from the sem of the signals")
    put("ke_edges", ("ebin_edge",), en.edges, "J", "bin edges of the E_5 histograms")
    put("ke_total_edges", ("ebin_edge",), en.edges_total, "J",
        "bin edges of the all-bodies histogram")
    for name, arr, long in (
            ("hist_model_point", en.hist_model_point, "time per E_5 bin, model best fit"),
            ("hist_model_point_err", en.hist_model_point_err,
             "std over parameter samples of hist_model_point"),
            ("hist_measured", en.hist_measured, "time per E_5 bin, measured"),
            ("hist_measured_err", en.hist_measured_err,
             "std over noise draws (sem) of hist_measured"),
            ("hist_model_total", en.hist_model_total,
             "time per all-bodies energy bin (ke_total_edges), model best fit"),
            ("hist_model_total_err", en.hist_model_total_err,
             "std over parameter samples of hist_model_total")):
        put(name, ("ebin",), nanB if arr is None else arr, "s", long)
    # masses (Fig. 7)
    ma = mass_arrays(pred.masses)
    put("mass_fitted", ("body",), ma["fitted"], "kg", "fitted mass")
    put("mass_stderr", ("body",), ma["stderr"], "kg", "standard error of the fitted mass")
    put("mass_nominal", ("body",), ma["nominal"], "kg", "CAD nominal mass (Table 3)")
    put("mass_paper", ("body",), ma["paper_3d"], "kg", "paper's 3D fit (Table 3)")
    put("mass_paper_stderr", ("body",), ma["paper_3d_stderr"], "kg", "its uncertainty")
    a, b = (float(x) for x in en.window)
    put("energy_window_start", (), a, "s", "start of the kinetic-energy window")
    put("energy_window_end", (), b, "s", "end of the kinetic-energy window")
    coords = {"time": ("time", tr.time, {"units": "s", "long_name": "record time"}),
              "point": ("point", list(tr.points), {"long_name": "body point"}),
              "axis": ("axis", list(AXES), {"long_name": "ground axis"}),
              "etime": ("etime", en.time, {"units": "s", "long_name": "energy record time"}),
              "body": ("body", [str(x) for x in ma["names"]], {"long_name": "body"})}
    attrs = {}
    if pred.risk is not None:
        r = pred.risk
        put("clearance", ("plane", "time"), r.clearance, "m",
            "gap minus displacement of the contact point along the closing direction")
        put("clearance_p2_5", ("plane", "time"), r.clearance_lo, "m", "2.5 % over samples")
        put("clearance_p97_5", ("plane", "time"), r.clearance_hi, "m", "97.5 % over samples")
        put("min_clearance", ("plane",), r.min_clearance, "m", "best-fit minimum clearance")
        put("min_clearance_p2_5", ("plane",), r.min_clearance_lo, "m",
            "minimum clearance: 2.5 % quantile over samples")
        put("min_clearance_p97_5", ("plane",), r.min_clearance_hi, "m",
            "minimum clearance: 97.5 % quantile over samples")
        put("p_cross", ("plane",), r.p_cross, "1",
            "probability that the contact point crosses the gap")
        put("p_cross_se", ("plane",), r.p_cross_se, "1", "Monte Carlo standard error")
        put("t_first_cross", ("plane",), r.t_first_cross, "s",
            "best-fit time the contact point first crosses the gap (NaN: never)")
        put("gap", (), r.gap, "m", "nominal gap between contact point and indent face")
        put("gap_std", (), r.gap_std, "m", "standard deviation of the gap")
        put("indent_angle", (), r.angle, "rad", "indent angle of the closing direction")
        v["contact_point"] = xr.Variable(("plane",), np.array([CONTACTS[p] for p in r.planes],
                                                              dtype=object),
                                         {"long_name": "body point that may touch the face"})
        coords["plane"] = ("plane", list(r.planes), {"long_name": "impact plane"})
        attrs = {"risk_samples": int(r.n_samples), "risk_samples_ok": int(r.n_ok)}
    ds = xr.Dataset(v, coords=coords)
    sc = pred.scenario
    ds.attrs = {
        "title": "gprm prediction of the GPRM plunger motion at the tip retraction",
        "model": "gprm-3d", "format_version": FORMAT_VERSION,
        "gprm_version": gprm.__version__, "source": pred.fm.source,
        "scenario_name": str(sc.name), "piezo": int(sc.piezo),
        "scale_eccentricity": float(sc.scale_eccentricity),
        "seed": int(pred.seed), "samples": int(tr.n_samples), "samples_ok": int(tr.n_ok),
        "energy_samples_ok": int(en.n_ok),
        "band": "2.5 % and 97.5 % quantiles over parameter sets drawn from the fit's "
                "uncertainty method (FittedModel.sample)",
        "uncertainty": pred.fm.uncertainty_note,
        "convention": "positions in the ground frame, origin at point A at rest; pos is the "
                      "change from the initial equilibrium position pos_initial",
        "overshoot_definition": DEFINITION,
        "energy_formula": "E_5: docs/prediction.md",
        "means_source": pred.means_source or "",
        **attrs,
    }
    # the parameter set used, as variables (the masses table is the mass_* variables above);
    # parameter_overridden marks the scenario's overrides
    return ds.merge(parameters_dataset(dict(pred.fm.params.values), pred.fm.names,
                                       overridden=sc.overrides))


def parameters_dataset(values: dict, fitted, overridden=()) -> xr.Dataset:
    """A parameter set as variables along ``parameter``: ``parameter_value`` (SI, units in
    ``parameter_units``), ``parameter_fitted`` (1 if fitted) and ``parameter_overridden``
    (1 if the scenario pinned it)."""
    ds = parameter_table(values, var="parameter_value", long_name="parameter value (SI)",
                         fitted=fitted)
    ds["parameter_overridden"] = ("parameter", np.array([n in set(overridden) for n in values],
                                                        np.int8),
                                  {"long_name": "1 if the scenario overrides the parameter",
                                   "units": "1", "flag_values": np.array([0, 1], np.int8),
                                   "flag_meanings": "as_fitted overridden"})
    return ds


#: the prediction NetCDF (the variables every prediction file has)
PREDICTION = Schema("prediction NetCDF", (
    Var("time", ("time",), "s", increasing=True),
    Var("point", ("point",), numeric=False, unique=True),
    Var("axis", ("axis",), numeric=False, unique=True),
    Var("pos", ("point", "axis", "time"), "m"),
    Var("vel", ("point", "axis", "time"), "m s-1"),
    Var("pos_initial", ("point", "axis"), "m"),
    Var("pos_p2_5", ("point", "axis", "time"), "m", finite=False),
    Var("pos_p97_5", ("point", "axis", "time"), "m", finite=False),
))


def write_prediction(pred_or_ds, path: str | os.PathLike) -> None:
    """Write a prediction (a :class:`Prediction` or its dataset) atomically."""
    ds = pred_or_ds if isinstance(pred_or_ds, xr.Dataset) else prediction_dataset(pred_or_ds)
    write_netcdf_atomic(ds, path)


def read_prediction(path: str | os.PathLike, *, what: str = "prediction NetCDF") -> xr.Dataset:
    """Read and check a prediction NetCDF (schema :data:`PREDICTION`, SI units)."""
    ds = open_netcdf(path, what=what)
    fmt = ds.attrs.get("format_version", FORMAT_VERSION)
    if int(np.asarray(fmt).ravel()[0]) != FORMAT_VERSION:
        raise GprmInputError(f"format version {fmt}, this gprm reads {FORMAT_VERSION}",
                             source=str(path), field="format_version")
    return check_dataset(ds, PREDICTION, str(path))


def _legacy(ds, key: str, default):
    return legacy_json_attr(ds.attrs, key, default=default,
                            source=str(ds.attrs.get("source", "prediction NetCDF")))


def read_parameters(ds) -> tuple[dict, list]:
    """``(values, fitted names)`` of a prediction file; older files stored them as the JSON
    attributes ``parameters_json``, ``fitted_json``."""
    vals = read_parameter_table(ds, "parameter_value")
    if vals is not None:
        return vals, read_fitted(ds) or []
    return _legacy(ds, "parameters_json", {}), _legacy(ds, "fitted_json", [])


def read_scenario(ds) -> dict:
    """The scenario of a prediction file: ``{"name", "piezo", "scale_eccentricity",
    "overrides": {name: SI value}}`` (older files: ``scenario_json``)."""
    if "scenario_name" in ds.attrs:
        over = {}
        if "parameter_overridden" in ds.variables:
            values = read_parameter_table(ds, "parameter_value") or {}
            over = {n: v for (n, v), f in zip(values.items(), ds["parameter_overridden"].values)
                    if f}
        return {"name": str(ds.attrs["scenario_name"]), "piezo": int(ds.attrs["piezo"]),
                "scale_eccentricity": float(ds.attrs["scale_eccentricity"]),
                "overrides": over}
    return _legacy(ds, "scenario_json", {})


def read_energy_window(ds) -> tuple[float, float] | None:
    """The kinetic-energy window (s) of a prediction file (older files:
    ``energy_window_s``)."""
    if "energy_window_start" in ds.variables:
        return float(ds["energy_window_start"].values), float(ds["energy_window_end"].values)
    w = _legacy(ds, "energy_window_s", None)
    return None if w is None else (float(w[0]), float(w[1]))


def read_impact_risk(ds) -> dict | None:
    """The gap-risk summary of a prediction file, the dict of ``ImpactRisk.to_json``; None
    where the prediction has no risk (older files: ``impact_risk_json``)."""
    if "gap" not in ds.variables:
        return _legacy(ds, "impact_risk_json", None)

    def f(var, i):
        return float(ds[var].values[i])

    planes = {}
    for i, p in enumerate(str(x) for x in ds["plane"].values):
        t = f("t_first_cross", i)
        planes[p] = {"contact_point": str(ds["contact_point"].values[i]),
                     "min_clearance_m": f("min_clearance", i),
                     "min_clearance_p2_5_m": f("min_clearance_p2_5", i),
                     "min_clearance_p97_5_m": f("min_clearance_p97_5", i),
                     "p_cross": f("p_cross", i), "p_cross_se": f("p_cross_se", i),
                     "t_first_cross_s": t if np.isfinite(t) else None}
    time = ds["time"].values
    return {"gap_m": float(ds["gap"].values), "gap_std_m": float(ds["gap_std"].values),
            "indent_angle_rad": float(ds["indent_angle"].values),
            "window_s": [float(time[0]), float(time[-1])],
            "samples": int(ds.attrs["risk_samples"]),
            "samples_ok": int(ds.attrs["risk_samples_ok"]), "planes": planes}


# ----------------------------------------------------------------------------- what-if table

def write_whatif(table, path: str | os.PathLike) -> None:
    """Write a what-if table (the :class:`~gprm.predict.whatif.WhatIf` of
    :func:`gprm.predict.whatif.whatif`, ``gprm predict --whatif``, or its ``to_json()``) as
    JSON, atomically."""
    write_json_atomic(path, table.to_json() if hasattr(table, "to_json") else table)


def read_whatif(path: str | os.PathLike) -> dict:
    """A what-if table, checked to be one (an object with the lists ``scenarios`` and
    ``ratios``)."""
    doc = read_json(path, what="what-if table")
    for key in ("scenarios", "ratios"):
        if not isinstance(doc, dict) or not isinstance(doc.get(key), list):
            raise GprmInputError(f"not a what-if table (no list {key!r})", source=str(path),
                                 field=key)
    return doc
