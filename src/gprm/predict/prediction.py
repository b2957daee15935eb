"""What the prediction stage computes, :class:`Prediction`, and its dataset, the layout of
the prediction NetCDF (``predict.nc``; docs/prediction.md, format_version
:data:`FORMAT_VERSION`): :func:`prediction_dataset`.

The result and its layout live together so that neither the stage (:mod:`gprm.predict.core`,
which computes a Prediction) nor the file module (:mod:`gprm.predict.files`, which writes and
reads the dataset) needs the other: the import graph of the package has no circle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

import gprm
from gprm.fit.files import FittedModel
from gprm.params.netcdf import parameter_table
from gprm.predict.energy import EnergyCheck
from gprm.predict.masses import MassTable, mass_arrays
from gprm.predict.risk import CONTACTS, ImpactRisk
from gprm.predict.scenarios import Scenario
from gprm.predict.trajectories import AXES, Trajectories
from gprm.predict.whatif import DEFINITION

FORMAT_VERSION = 1


@dataclass(frozen=True)
class Prediction:
    fm: FittedModel               # the scenario's model (values and covariance)
    scenario: Scenario
    trajectories: Trajectories
    overshoot: np.ndarray         # (point, 3) best fit, over the trajectory span
    energy: EnergyCheck
    masses: MassTable             # Fig. 7
    risk: ImpactRisk | None
    seed: int
    means_source: str | None

    def to_xarray(self):
        """The prediction as the dataset of its file (``predict.nc``, docs/prediction.md;
        :func:`prediction_dataset`)."""
        return prediction_dataset(self)

    def to_json(self) -> dict:
        """The prediction's headline numbers, JSON-able: the scenario, the best-fit overshoot
        of each point on each axis (m), the masses (Fig. 7), the impact risk where a gap was
        given, and what uncertainty the bands carry. The time series are in
        :meth:`to_xarray`."""
        tr = self.trajectories
        return {
            "scenario": self.scenario.to_json(),
            "overshoot_m": {p: dict(zip(("x", "y", "z"), map(float, self.overshoot[i])))
                            for i, p in enumerate(tr.points)},
            "masses": self.masses.to_json(),
            "impact_risk": None if self.risk is None else self.risk.to_json(),
            "uncertainty": self.fm.uncertainty_note,
            "seed": int(self.seed),
            "means_source": self.means_source,
        }


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
        **({"sidecar_ignored": pred.fm.sidecar_note} if pred.fm.sidecar_note else {}),
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
