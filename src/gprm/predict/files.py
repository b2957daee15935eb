"""The prediction NetCDF (``gprm predict --out F.nc``); its format is defined in
docs/prediction.md (format_version 1)."""

from __future__ import annotations

import json

import numpy as np
import xarray as xr

import gprm
from gprm.predict.core import Prediction
from gprm.predict.masses import mass_arrays
from gprm.predict.trajectories import AXES
from gprm.predict.whatif import DEFINITION

FORMAT_VERSION = 1


def prediction_dataset(pred: Prediction) -> xr.Dataset:
    tr, en = pred.trajectories, pred.energy
    P3T = ("point", "axis", "time")
    v = {}

    def put(name, dims, data, units, long):
        v[name] = xr.Variable(dims, np.asarray(data, float), {"units": units, "long_name": long})

    put("pos", P3T, tr.pos, "m", "best-fit displacement from the initial equilibrium position")
    put("vel", P3T, tr.vel, "m/s", "best-fit velocity (exact, from the simulated rates)")
    put("pos_initial", ("point", "axis"), tr.static, "m",
        "initial equilibrium position; origin at point A at rest, ground axes")
    for k, u, lab in (("pos", "m", "displacement"), ("vel", "m/s", "velocity")):
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
    coords = {"time": ("time", tr.time, {"units": "s", "long_name": "record time"}),
              "point": ("point", list(tr.points)), "axis": ("axis", list(AXES)),
              "etime": ("etime", en.time, {"units": "s", "long_name": "energy record time"}),
              "body": ("body", [str(x) for x in ma["names"]])}
    if pred.risk is not None:
        r = pred.risk
        put("clearance", ("plane", "time"), r.clearance, "m",
            "gap minus displacement of the contact point along the closing direction")
        put("clearance_p2_5", ("plane", "time"), r.clearance_lo, "m", "2.5 % over samples")
        put("clearance_p97_5", ("plane", "time"), r.clearance_hi, "m", "97.5 % over samples")
        put("min_clearance", ("plane",), r.min_clearance, "m", "best-fit minimum clearance")
        put("p_cross", ("plane",), r.p_cross, "1",
            "probability that the contact point crosses the gap")
        put("p_cross_se", ("plane",), r.p_cross_se, "1", "Monte Carlo standard error")
        coords["plane"] = ("plane", list(r.planes))
    ds = xr.Dataset(v, coords=coords)
    sc = pred.scenario
    ds.attrs = {
        "title": "gprm prediction of the GPRM plunger motion at the tip retraction",
        "model": "gprm-3d", "format_version": FORMAT_VERSION,
        "gprm_version": gprm.__version__, "source": pred.fm.source,
        "piezo": int(sc.piezo), "scenario_json": json.dumps(sc.to_json()),
        "scale_eccentricity": float(sc.scale_eccentricity),
        "seed": int(pred.seed), "samples": int(tr.n_samples), "samples_ok": int(tr.n_ok),
        "energy_samples_ok": int(en.n_ok),
        "band": "2.5 % and 97.5 % quantiles over parameter sets drawn from the fit's "
                "uncertainty method (FittedModel.sample)",
        "uncertainty": pred.fm.uncertainty_note,
        "convention": "positions in the ground frame, origin at point A at rest; pos is the "
                      "change from the initial equilibrium position pos_initial",
        "overshoot_definition": DEFINITION,
        "energy_window_s": json.dumps(list(en.window)),
        "energy_formula": "E_5: docs/prediction.md",
        "means_source": pred.means_source or "",
    }
    if pred.risk is not None:
        ds.attrs["impact_risk_json"] = json.dumps(pred.risk.to_json())
    # the parameter set used, as variables (the masses table is the mass_* variables above)
    return ds.merge(parameters_dataset(dict(pred.fm.params.values), pred.fm.names))


def parameters_dataset(values: dict, fitted) -> xr.Dataset:
    """A parameter set as variables along ``parameter``: ``parameter_value`` (SI, units in
    the coordinate ``parameter_units``) and ``parameter_fitted`` (1 if fitted)."""
    from gprm.params.files import si_unit_strings

    names = list(values)
    ds = xr.Dataset(
        {"parameter_value": ("parameter", np.array([values[n] for n in names], float),
                             {"long_name": "parameter value (SI)",
                              "comment": "units vary along parameter: see parameter_units"}),
         "parameter_fitted": ("parameter", np.array([n in set(fitted) for n in names],
                                                    np.int8),
                              {"long_name": "1 if the parameter was fitted", "units": "1"})},
        coords={"parameter": ("parameter", names),
                "parameter_units": ("parameter", si_unit_strings(names),
                                    {"long_name": "SI unit of each parameter"})})
    return ds


def read_parameters(ds) -> tuple[dict, list]:
    """``(values, fitted names)`` of a prediction file; older files stored them as the JSON
    attributes ``parameters_json``, ``fitted_json``."""
    if "parameter_value" in ds:
        names = [str(n) for n in ds["parameter"].values]
        vals = {n: float(v) for n, v in zip(names, ds["parameter_value"].values)}
        fitted = [n for n, f in zip(names, ds["parameter_fitted"].values) if f]
        return vals, fitted
    return (json.loads(ds.attrs.get("parameters_json", "{}")),
            json.loads(ds.attrs.get("fitted_json", "[]")))
