"""One validation layer at the file boundary: a schema per file format, read through by every
command.

A :class:`Schema` lists the variables of a NetCDF format (:class:`Var`: dimensions, unit,
finiteness, range, strictly increasing for coordinates) and its attributes (:class:`Attr`:
type and range). :func:`check_dataset` checks a loaded Dataset against a schema and returns a
copy in SI units (a ``units`` attribute such as ``ms`` or ``um`` is converted; one that cannot
be converted is refused). Every problem is a :class:`GprmInputError` naming the file and the
field. Matching lengths follow from the dimensions: variables that share a dimension share its
length in an xarray Dataset, and the schema fixes which dimensions each variable has.

The schemas here (``CAMPAIGN``, ``MEANS``) cover the type-level checks; the format readers
(:func:`gprm.campaign.data.validate_campaign`, :func:`gprm.fit.objective.fit_data_from_means`)
add the format's own rules (positions, runs, windows) on the checked data. Each format's reader
(``gprm.campaign.files``, ``gprm.simulate.files``, ``gprm.predict.files``,
``gprm.flight.files``) applies its schema.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass

import numpy as np
import xarray as xr

from gprm.errors import GprmInputError

__all__ = ["Var", "Attr", "Schema", "check_attr", "check_dataset", "pint_unit", "unit_factor",
           "CAMPAIGN", "MEANS", "SCHEMAS"]


@dataclass(frozen=True)
class Var:
    """A variable (or coordinate) of a NetCDF format."""

    name: str
    dims: tuple[str, ...]
    unit: str | None = None          # SI unit; None: dimensionless or labels
    required: bool = True
    numeric: bool = True
    finite: bool = True
    min: float | None = None
    min_open: bool = False
    increasing: bool = False         # strictly increasing (1-D coordinates)
    min_size: int = 1                # of the last dimension
    unique: bool = False             # labels (1-D): no repeats


@dataclass(frozen=True)
class Attr:
    """A global attribute: ``number`` (finite real, optional lower bound), ``integer`` (a
    whole number) or ``string``."""

    name: str
    kind: str = "number"
    required: bool = False
    min: float | None = None
    min_open: bool = False


@dataclass(frozen=True)
class Schema:
    name: str
    vars: tuple[Var, ...]
    attrs: tuple[Attr, ...] = ()


_UD_POWER = re.compile(r"(?<=[A-Za-z\u00b5\u03bc])\^?(-?\d+)(?!\d|\.\d)")
_UD_DOT = re.compile(r"(?<=[A-Za-z\u00b5\u03bc\d)])\s*\.\s*(?=[A-Za-z\u00b5\u03bc(])")


def pint_unit(unit: str) -> str:
    """A UDUNITS unit string (as CF files carry: ``m s-1``, ``kg m2``, ``m.s-1``) in the
    syntax of pint (``m s**-1``); pint's own syntax (``m/s``, ``um``) passes unchanged."""
    u = _UD_POWER.sub(r"**\1", str(unit).strip())
    return _UD_DOT.sub(" * ", u)


def unit_factor(unit: str, si: str, src: str, field: str) -> float:
    """The factor converting ``unit`` (pint syntax: ``um``, ``ms``, ``mV``...) to the SI unit
    ``si``; a unit that cannot be converted is a :class:`GprmInputError` naming ``field``."""
    from gprm.units import known_factor, ureg

    try:
        f = known_factor(unit, si)
        if f is None:
            f = float(ureg().Quantity(1.0, pint_unit(unit)).to(pint_unit(si)).magnitude)
    except Exception as exc:
        raise GprmInputError(f"units {unit!r} cannot be converted to {si} "
                             f"({type(exc).__name__})", source=src, field=field) from None
    if not (math.isfinite(f) and f > 0):
        raise GprmInputError(f"units {unit!r} give a factor {f:g} to {si}", source=src,
                             field=field)
    return f


def _check_var(ds, v: Var, src: str) -> xr.Variable:
    da = ds[v.name]
    if tuple(da.dims) != v.dims:
        raise GprmInputError(f"dimensions must be {v.dims}, got {tuple(da.dims)}", source=src,
                             field=v.name)
    if v.dims and da.shape[-1] < v.min_size:
        raise GprmInputError(f"needs at least {v.min_size} values along {v.dims[-1]}, got "
                             f"{da.shape[-1]}", source=src, field=v.name)
    if not v.numeric:
        if v.unique:
            labels = [str(x) for x in np.asarray(da.values).ravel()]
            rep = sorted({x for x in labels if labels.count(x) > 1})
            if rep:
                raise GprmInputError(f"repeated label(s) {rep}", source=src, field=v.name)
        return da.variable
    if da.dtype.kind not in "iuf":      # bool, strings, objects, complex, dates: refused
        raise GprmInputError(f"must hold real numbers, got dtype {da.dtype}", source=src,
                             field=v.name)
    arr = np.asarray(da.values, float)
    factor = 1.0
    if v.unit is not None:
        unit = da.attrs.get("units")
        if unit is not None and not isinstance(unit, str):
            raise GprmInputError(f"units attribute must be text, got {unit!r}", source=src,
                                 field=v.name)
        if unit is not None and unit not in ("", v.unit):
            factor = unit_factor(unit, v.unit, src, v.name)
    if v.finite and not np.all(np.isfinite(arr)):
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        raise GprmInputError(f"holds {bad} NaN or Inf value(s)", source=src, field=v.name)
    arr = arr * factor
    if v.min is not None:
        fin = arr[np.isfinite(arr)]
        low = fin < v.min if not v.min_open else fin <= v.min
        if np.any(low):
            raise GprmInputError(f"values must be {'>' if v.min_open else '>='} {v.min:g}"
                                 f"{' ' + v.unit if v.unit else ''}, got {fin[low][0]:g}",
                                 source=src, field=v.name)
    if v.increasing and arr.size > 1 and not np.all(np.diff(arr) > 0):
        raise GprmInputError("must be strictly increasing", source=src, field=v.name)
    attrs = dict(da.attrs)
    if v.unit is not None:
        attrs["units"] = v.unit
    return xr.Variable(da.dims, arr, attrs)    # by position: no alignment on old coords


def _check_attr(ds, a: Attr, src: str):
    if a.name not in ds.attrs:
        if a.required:
            raise GprmInputError("attribute missing", source=src, field=a.name)
        return None
    val = ds.attrs[a.name]
    if a.kind == "string":
        if not isinstance(val, str):
            raise GprmInputError(f"attribute must be text, got {val!r}", source=src,
                                 field=a.name)
        return val
    arr = np.asarray(val)
    if arr.dtype.kind not in "iuf" or arr.size != 1:
        raise GprmInputError(f"attribute must be one {'whole ' if a.kind == 'integer' else ''}"
                             f"number, got {val!r}", source=src, field=a.name)
    x = float(arr.reshape(()))
    if not math.isfinite(x):
        raise GprmInputError(f"attribute must be finite, got {x}", source=src, field=a.name)
    if a.kind == "integer":
        if x != int(x):
            raise GprmInputError(f"attribute must be a whole number, got {val!r}", source=src,
                                 field=a.name)
        xi = int(x)
        if a.min is not None and xi < a.min:
            raise GprmInputError(f"attribute must be >= {a.min:g}, got {xi}", source=src,
                                 field=a.name)
        return xi
    if a.min is not None and (x < a.min or (a.min_open and x == a.min)):
        raise GprmInputError(f"attribute must be {'>' if a.min_open else '>='} {a.min:g}, "
                             f"got {x:g}", source=src, field=a.name)
    return x


def check_attr(ds, attr: Attr, source: str):
    """The global attribute ``attr`` of ``ds`` checked (None where absent and optional); a
    wrong type or value is a :class:`GprmInputError` naming it."""
    return _check_attr(ds, attr, str(source))


def check_dataset(ds, schema: Schema, source: str):
    """Check ``ds`` against ``schema``; a copy with the schema's variables in SI units."""
    src = str(source)
    out = ds.copy()
    for v in schema.vars:
        if v.name not in ds.variables:
            if v.required:
                raise GprmInputError(f"variable missing ({schema.name})", source=src,
                                     field=v.name)
            continue
        checked = _check_var(ds, v, src)
        if v.name in ds.coords:
            out = out.assign_coords({v.name: checked})
        else:
            out[v.name] = checked
    for a in schema.attrs:
        x = _check_attr(ds, a, src)
        if x is not None:
            out.attrs[a.name] = x
    return out


#: the campaign NetCDF (docs/data-formats.md)
CAMPAIGN = Schema("campaign NetCDF", (
    Var("time", ("time",), "s", increasing=True, min_size=8),
    Var("position", ("position",), numeric=False, unique=True),
    Var("displacement", ("position", "run", "time"), "m"),
    Var("noise", ("position", "noise_run", "time"), "m"),
    Var("voltage", ("vrun", "vtime"), "V", required=False),
    Var("vtime", ("vtime",), "s", required=False, increasing=True),
), (Attr("sample_rate", "number", min=0.0, min_open=True), Attr("seed", "integer")))

#: the mean-signals NetCDF of ``gprm preprocess`` (docs/data-formats.md)
MEANS = Schema("mean-signals NetCDF", (
    Var("time", ("time",), "s", increasing=True, min_size=2),
    Var("signal", ("signal",), numeric=False, unique=True),
    Var("mean", ("signal", "time"), "m"),
    Var("std", ("signal", "time"), "m", required=False, min=0.0),
    Var("sem", ("signal", "time"), "m", required=False, min=0.0),
    Var("noise_std", ("signal",), "m", required=False, min=0.0),
    Var("shift", ("signal",), "s", required=False),
    Var("n_runs", ("signal",), required=False, min=1.0),
    Var("runs", ("signal", "run", "time"), "m", required=False),
    Var("interpolation_error", ("signal", "time"), "m", required=False),
    Var("sync_remainder", ("signal", "run"), "s", required=False),
    Var("crossing_time", ("signal",), "s", required=False),
), (Attr("align_time", "number", min=0.0, min_open=True),
    Attr("sample_rate", "number", min=0.0, min_open=True),
    Attr("record_duration", "number", min=0.0, min_open=True), Attr("seed", "integer")))

SCHEMAS = {"campaign": CAMPAIGN, "means": MEANS}


def legacy_json_attr(attrs, key: str, *, source: str, default=None, strict: bool = True):
    """The JSON document an older gprm file stored in the attribute ``key`` (tabular metadata
    are variables now, docs/data-formats.md), or ``default`` where the attribute is absent.
    Text that is not valid JSON is a :class:`GprmInputError` naming ``key`` (``strict``) or
    gives ``default`` (for optional settings a reader can do without)."""
    raw = attrs.get(key)
    if raw is None:
        return default
    try:
        return json.loads(raw)
    except (TypeError, ValueError, RecursionError):
        if not strict:
            return default
        raise GprmInputError("attribute is not valid JSON", source=source,
                             field=key) from None


def check_int(name: str, v, lo: int) -> None:
    """An option that must be an integer (not a bool) of at least ``lo``; else a
    :class:`GprmInputError` naming ``name`` (the option dataclasses' ``__post_init__``)."""
    if isinstance(v, bool) or not isinstance(v, int) or v < lo:
        raise GprmInputError(f"must be an integer, at least {lo}; got {v!r}", field=name)


def check_number(name: str, v, *, positive: bool = False) -> None:
    """An option that must be a finite number >= 0 (> 0 with ``positive``), not a bool."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
            or v < 0 or (positive and v == 0):
        raise GprmInputError(f"must be a finite number {'> 0' if positive else '>= 0'}, "
                             f"got {v!r}", field=name)
