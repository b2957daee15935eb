"""A parameter set as NetCDF variables along a ``parameter`` dimension (docs/data-formats.md,
"Parameter tables").

Parameters have different units (kg, N/m, s, ...), which one CF ``units`` attribute cannot
say. A table therefore holds the values in SI in a float variable (``<prefix>_value``) whose
``comment`` points to the text variable ``parameter_units(parameter)`` with each parameter's
SI unit as a UDUNITS string. The names are the coordinate ``parameter``. Several tables of one
file share the dimension and ``parameter_units`` (they list the same parameters).
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from gprm.params.files import si_unit_strings

UNITS_COMMENT = "units vary along parameter: see parameter_units"


def parameter_table(values: dict, *, var: str, long_name: str,
                    fitted=None) -> xr.Dataset:
    """``values`` (name -> SI value) as ``var(parameter)`` with ``parameter_units``; with
    ``fitted`` (names) also ``parameter_fitted(parameter)`` (1 if fitted)."""
    names = list(values)
    data: dict[str, tuple] = {
        var: ("parameter", np.array([float(values[n]) for n in names], float),
              {"long_name": long_name, "comment": UNITS_COMMENT}),
        "parameter_units": ("parameter", np.array(si_unit_strings(names), dtype=object),
                            {"long_name": "SI unit of each parameter (UDUNITS)"}),
    }
    if fitted is not None:
        f = set(fitted)
        data["parameter_fitted"] = ("parameter", np.array([n in f for n in names], np.int8),
                                    {"long_name": "1 if the parameter was fitted",
                                     "units": "1", "flag_values": np.array([0, 1], np.int8),
                                     "flag_meanings": "fixed fitted"})
    return xr.Dataset(data, coords={"parameter": ("parameter", np.array(names, dtype=object),
                                                  {"long_name": "parameter name "
                                                   "(docs/model.md)"})})


def read_parameter_table(ds, var: str) -> dict | None:
    """The table ``var(parameter)`` of ``ds`` as ``{name: SI value}``; None where absent."""
    if var not in ds.variables:
        return None
    names = [str(n) for n in np.asarray(ds["parameter"].values).ravel()]
    return {n: float(v) for n, v in zip(names, np.asarray(ds[var].values, float).ravel())}


def read_fitted(ds) -> list[str] | None:
    """The names flagged in ``parameter_fitted``; None where absent."""
    if "parameter_fitted" not in ds.variables:
        return None
    names = [str(n) for n in np.asarray(ds["parameter"].values).ravel()]
    return [n for n, f in zip(names, np.asarray(ds["parameter_fitted"].values)) if f]
