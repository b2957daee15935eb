"""The prediction NetCDF (``gprm predict --out F.nc``; docs/prediction.md, format_version 1):
its layout (:func:`prediction_dataset`, defined with the Prediction it lays out in
:mod:`gprm.predict.prediction`), writer (:func:`write_prediction`), reader
(:func:`read_prediction`, checked against :data:`PREDICTION`) and typed accessors of its
metadata (:func:`read_parameters`, :func:`read_scenario`, :func:`read_energy_window`,
:func:`read_impact_risk`); and the what-if table of ``gprm predict --whatif``
(:func:`write_whatif`, :func:`read_whatif`). Files written before the metadata became
variables (the JSON attributes ``parameters_json``, ``fitted_json``, ``scenario_json``,
``energy_window_s``, ``impact_risk_json``) read too."""

from __future__ import annotations

import os

import numpy as np
import xarray as xr

from gprm._io import (atomic_paths, json_text, write_text_to, open_netcdf, read_json, write_json_atomic,
                      write_netcdf_atomic, write_netcdf_to)
from gprm.errors import GprmInputError
from gprm.params.netcdf import read_fitted, read_parameter_table
from gprm.predict.prediction import FORMAT_VERSION, parameters_dataset, prediction_dataset
from gprm.validate import Schema, Var, check_dataset, legacy_json_attr

# the layout is public here too, where the file's readers and writers are
__all__ = ["FORMAT_VERSION", "PREDICTION", "parameters_dataset", "prediction_dataset",
           "read_energy_window", "read_impact_risk", "read_parameters", "read_prediction",
           "read_scenario", "read_whatif", "write_prediction", "write_whatif"]

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


def write_prediction(pred_or_ds, path: str | os.PathLike, whatif=None,
                     whatif_path: str | os.PathLike | None = None) -> None:
    """Write a prediction (a :class:`Prediction` or its dataset) atomically; with a what-if
    table (``whatif``, as :func:`write_whatif` takes it) and ``whatif_path``, both together
    (:func:`gprm._io.atomic_paths`: a failure writing either leaves both as they were)."""
    ds = pred_or_ds if isinstance(pred_or_ds, xr.Dataset) else prediction_dataset(pred_or_ds)
    if whatif_path is None:
        write_netcdf_atomic(ds, path)
        return
    doc = whatif.to_json() if hasattr(whatif, "to_json") else whatif
    with atomic_paths([path, whatif_path]) as (tmp, tmp_whatif):
        write_netcdf_to(ds, tmp)
        write_text_to(tmp_whatif, json_text(doc))


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
