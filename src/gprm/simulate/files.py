"""The simulation NetCDF (``gprm simulate``; docs/data-formats.md): its layout
(:func:`simulation_dataset`), writer (:func:`write_simulation`) and reader
(:func:`read_simulation`, checked against :data:`SIMULATION`), and the parameter set it was
made with (:func:`read_parameters`)."""

from __future__ import annotations

import os

import numpy as np
import xarray as xr

import gprm
from gprm._io import open_netcdf, write_netcdf_atomic
from gprm.errors import GprmInputError
from gprm.params import ParameterSet
from gprm.params.netcdf import parameter_table, read_parameter_table
from gprm.simulate.core import COORDS, OUTPUTS, SimulationResult
from gprm.validate import Schema, Var, check_dataset, legacy_json_attr

UNITS = {"z_lr": "m", "z_A": "m", "x_A": "m", "y_A": "m", "eta": "rad", "theta": "rad",
         "mu3": "m", "mu4": "m", "q": "C", "x_base": "m", "x_head": "m", "y_base": "m",
         "y_head": "m", "z_bk": "m", "voltage": "V"}
DESCRIPTIONS = {
    "z_lr": "linear-runner axial displacement", "z_A": "plunger back axial displacement "
    "relative to the linear runner", "x_A": "plunger back lateral x", "y_A": "plunger back "
    "lateral y", "eta": "plunger rotation about y", "theta": "plunger rotation about x",
    "mu3": "spacer displacement along the actuation axis", "mu4": "tip displacement along the "
    "actuation axis", "q": "piezo charge", "x_base": "Eq. 3 x_A + eta d_x_base",
    "x_head": "Eq. 3 x_A + eta d_x_head", "y_base": "Eq. 3 y_A - theta d_y_base",
    "y_head": "Eq. 3 y_A - theta d_y_head", "z_bk": "Eq. 3 z_A(t - t1)",
    "voltage": "piezo voltage as applied (after the lag t0)"}


def simulation_dataset(res: SimulationResult, params: ParameterSet, *, index: int = 0,
                       source: str = "", z_bk_absolute: bool = False) -> xr.Dataset:
    """One simulated set as an xarray Dataset (coordinate ``time``, SI units)."""
    data = {}
    for name in COORDS:
        data[name] = ("time", res.coords[name][index])
    for name in OUTPUTS:
        data[name] = ("time", res.outputs[name][index])
    data["voltage"] = ("time", np.asarray(res.voltage)[index])
    ds = xr.Dataset(data, coords={"time": ("time", res.time)})
    ds["time"].attrs = {"units": "s", "long_name": "time from the start of the record"}
    for name in data:                                  # the data variables, by name
        ds[name].attrs = {"units": UNITS[name], "long_name": DESCRIPTIONS[name]}
    if z_bk_absolute:
        ds["z_bk"].attrs["long_name"] = "(z_lr + z_A)(t - t1), absolute plunger back"
    ds.attrs = {
        "title": "gprm simulation of the GPRM tip retraction",
        "model": "gprm-3d", "piezo": int(res.piezo), "gprm_version": gprm.__version__,
        "convention": "changes from the initial static equilibrium at V(0)",
        "parameter_source": params.source, "input": source or "default profile (docs/spec.md)",
    }
    return ds.merge(parameter_table(dict(params.values), var="parameter_value",
                                    long_name="parameter value of the simulation (SI)"))


#: the simulation NetCDF: every coordinate and output of the model on ``time``
SIMULATION = Schema("simulation NetCDF", (
    Var("time", ("time",), "s", increasing=True, min_size=2),
    *(Var(n, ("time",), UNITS[n]) for n in (*COORDS, *OUTPUTS, "voltage")),
))


def write_simulation(ds: xr.Dataset, path: str | os.PathLike) -> None:
    """Write a simulation dataset (:func:`simulation_dataset`) atomically."""
    write_netcdf_atomic(ds, path)


def read_simulation(path: str | os.PathLike) -> xr.Dataset:
    """Read and check a simulation NetCDF (SI units; schema :data:`SIMULATION`)."""
    ds = open_netcdf(path, what="simulation NetCDF")
    return check_dataset(ds, SIMULATION, str(path))


def read_parameters(ds) -> dict:
    """The parameter set (name -> SI value) a simulation file was made with; files written
    before it became the variable ``parameter_value`` stored it as ``parameters_json``."""
    values = read_parameter_table(ds, "parameter_value")
    if values is not None:
        return values
    doc = legacy_json_attr(ds.attrs, "parameters_json", source="", strict=False)
    if not isinstance(doc, dict):
        raise GprmInputError("no parameter set (parameter_value)",
                             source=str(ds.attrs.get("source", "simulation NetCDF")),
                             field="parameter_value")
    return {str(k): float(v) for k, v in doc.items() if isinstance(v, (int, float))}
