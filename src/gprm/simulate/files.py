"""The simulation NetCDF of INTERFACES.md (``gprm simulate``)."""

from __future__ import annotations

import json

import numpy as np
import xarray as xr

import gprm
from gprm.params import ParameterSet
from gprm.simulate.core import COORDS, OUTPUTS, SimulationResult

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
    for name in ds.data_vars:
        ds[name].attrs = {"units": UNITS[name], "long_name": DESCRIPTIONS[name]}
    if z_bk_absolute:
        ds["z_bk"].attrs["long_name"] = "(z_lr + z_A)(t - t1), absolute plunger back"
    ds.attrs = {
        "title": "gprm simulation of the GPRM tip retraction",
        "model": "gprm-3d", "piezo": int(res.piezo), "gprm_version": gprm.__version__,
        "convention": "changes from the initial static equilibrium at V(0)",
        "parameters_json": json.dumps(dict(params.values)),
        "parameter_source": params.source, "input": source or "default profile (MODEL.md)",
    }
    return ds
