"""The flight stage's files, each with its reader and writer side by side (docs/flight.md):

- telemetry (format ``gprm-telemetry``): :func:`telemetry_dataset` (the layout),
  :func:`write_telemetry`, :func:`load_telemetry` (NetCDF or CSV; checked by
  :func:`telemetry_from_dataset`), :func:`telemetry_csv_dataset`; the synthetic truth and the
  generator's options: :func:`truth_attrs_and_vars` / :func:`read_truth`,
  :func:`synth_option_attrs` / :func:`read_synth_options`;
- the impact result (``gprm impact``): the JSON document and its NetCDF sidecar of velocity
  curves, :func:`write_impact` / :func:`read_impact`, :func:`impact_curves_dataset` /
  :func:`read_impact_curves`.

Velocities are split by unit: linear axes (``velocity_axis``: vx, vz_xz, vy, vz_yz) in
``m s-1``, angular axes (``angular_axis``: wy, wx) in ``rad s-1`` (CF-1.10: one unit per
variable). Files written before (velocities along one mixed-unit ``axis``, JSON strings in the
attributes ``truth_json`` and ``options_json``) read through the same functions.
"""

from __future__ import annotations

import csv
import dataclasses
import os
import re
from pathlib import Path

import numpy as np
import xarray as xr

from gprm._io import (atomic_paths, json_text, write_text_to, open_netcdf, read_json, write_netcdf_atomic, write_netcdf_to)
from gprm.errors import GprmInputError
from gprm.flight.telemetry import (ANGULAR_AXES, AXES, CHANNEL_KIND, CHANNEL_UNIT, CHANNELS,
                                   LINEAR_AXES, REQUIRED, Release, Telemetry)
from gprm import validate
from gprm.validate import legacy_json_attr

FORMAT = "gprm-telemetry"
FORMAT_VERSION = 1

CHANNEL_LONG_NAME = {"x": "test-mass displacement along x",
                     "y": "test-mass displacement along y",
                     "z": "test-mass displacement along z",
                     "theta": "test-mass rotation about x", "eta": "test-mass rotation about y",
                     "phi": "test-mass rotation about z"}
TM_LINEAR = ("vx", "vy", "vz")
TM_ANGULAR = ("wx", "wy", "wz")


def _axis_coords() -> dict:
    return {"velocity_axis": ("velocity_axis", list(LINEAR_AXES),
                              {"long_name": "linear velocity axis (x-z plane: vx, vz_xz; y-z "
                               "plane: vy, vz_yz)"}),
            "angular_axis": ("angular_axis", list(ANGULAR_AXES),
                             {"long_name": "angular velocity axis (x-z plane: wy; y-z plane: "
                              "wx)"})}


# ============================================================================ telemetry
# units at the edge (the project's pint registry, as for campaigns and parameter files)
KIND_SI = {"length": "m", "angle": "rad", "time": "s"}


def unit_factor(unit, kind: str, *, source: str, field: str) -> float:
    """Factor converting ``unit`` (pint or UDUNITS syntax: ``mm``, ``um``, ``µrad``, ``deg``,
    ``ms``, …; None or empty: SI) of a ``kind`` (length, angle, time) to SI
    (:func:`gprm.validate.unit_factor`). A unit that is not of that kind, or not a unit: a
    GprmInputError naming the field and the kind."""
    if unit is None or str(unit).strip() == "":
        return 1.0
    u = str(unit).strip()
    art = "an" if kind[0] in "aeiou" else "a"
    try:
        return validate.unit_factor(u, KIND_SI[kind], source, field)
    except GprmInputError:
        raise GprmInputError(f"unit {u!r} is not {art} {kind} unit (convertible to "
                             f"{KIND_SI[kind]})", source=source, field=field) from None


def load_telemetry(path: str | os.PathLike) -> Telemetry:
    """Read and check telemetry (synthetic or real: the same reader and checks): a NetCDF file
    of the ``gprm-telemetry`` format, or a CSV file (:func:`telemetry_csv_dataset`)."""
    src = str(path)
    if not Path(path).exists():
        raise GprmInputError("telemetry file does not exist (a NetCDF or CSV file)", source=src)
    if Path(path).suffix.lower() in (".csv", ".txt"):
        return telemetry_from_dataset(telemetry_csv_dataset(path), source=src)
    ds = open_netcdf(path, what="telemetry NetCDF")
    return telemetry_from_dataset(ds, source=src)


def _csv_header(col: str):
    """``name [unit]`` or ``name (unit)`` or ``name`` -> (name, unit or None)."""
    m = re.fullmatch(r"\s*([A-Za-z_][A-Za-z0-9_]*)\s*(?:[\[(]\s*([^\])]*?)\s*[\])])?\s*", col)
    if not m:
        return col.strip(), None
    return m.group(1), m.group(2)


def telemetry_csv_dataset(path: str | os.PathLike):
    """Read measured telemetry from a CSV file (one row per sample) into the NetCDF layout.

    Columns (header names, units in brackets or parentheses, e.g. ``x [mm]``,
    ``theta (µrad)``; no unit: SI): ``release`` (id), ``time``, ``release_time`` (the release
    instant, the same on every row of a release), ``x, y, z`` (length), ``theta, eta``
    (angle), optional ``phi`` and ``<channel>_std`` (per-sample std, the channel's kinds of
    unit). Rows of a release must be in time order; releases may have different lengths;
    blank lines and lines starting with ``#`` are skipped. Every problem is a GprmInputError
    naming the file, the column and the line.
    """
    src = str(path)
    if not Path(path).exists():
        raise GprmInputError("telemetry CSV does not exist", source=src)
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            lines = [(i + 1, ln) for i, ln in enumerate(fh)
                     if ln.strip() and not ln.lstrip().startswith("#")]
        rows = list(csv.reader([ln for _, ln in lines], skipinitialspace=True))
    except (UnicodeDecodeError, csv.Error, OSError) as exc:
        raise GprmInputError(f"cannot be read as CSV ({type(exc).__name__}: {exc})",
                             source=src) from None
    if len(rows) < 2:
        raise GprmInputError("cannot be read as CSV (no header and data rows)", source=src)
    header, body, lineno = rows[0], rows[1:], [n for n, _ in lines[1:]]
    for k, r in enumerate(body):
        if len(r) != len(header):
            raise GprmInputError(f"line {lineno[k]}: {len(r)} fields, the header has "
                                 f"{len(header)}", source=src)
    cols: dict[str, tuple[int, str | None]] = {}      # name -> (column index, unit)
    for j, h in enumerate(header):
        name, unit = _csv_header(str(h))
        if name in cols:
            raise GprmInputError("column given twice", source=src, field=name)
        cols[name] = (j, unit)
    for need in ("release", "time", "release_time") + REQUIRED:
        if need not in cols:
            raise GprmInputError(f"missing column (have: {', '.join(cols)})", source=src,
                                 field=need)
    rel = np.array([r[cols["release"][0]].strip() for r in body], dtype=object)
    ids = list(dict.fromkeys(rel))
    num = {}
    for name, (c, unit) in cols.items():
        if name == "release":
            continue
        base = name[:-4] if name.endswith("_std") else name
        kind = ("time" if name in ("time", "release_time") else CHANNEL_KIND.get(base))
        if kind is None:
            continue                               # unknown extra column: ignored
        vals = np.empty(len(body))
        for k, r in enumerate(body):
            try:
                vals[k] = float(r[c])
            except ValueError:
                vals[k] = np.nan
            if not np.isfinite(vals[k]):
                raise GprmInputError(f"line {lineno[k]}: not a finite number ({r[c]!r})",
                                     source=src, field=name)
        num[name] = vals * unit_factor(unit, kind, source=src, field=name)
    R = len(ids)
    idx = [np.flatnonzero(rel == r) for r in ids]
    S = max(i.size for i in idx)
    arr = {n: np.full((R, S), np.nan) for n in num if n != "release_time"}
    trel = np.empty(R)
    for k, (r, ii) in enumerate(zip(ids, idx)):
        if ii.size > 1 and np.any(np.diff(ii) != 1):
            raise GprmInputError(f"release {r}: its rows are not contiguous (line "
                                 f"{lineno[int(ii[np.argmax(np.diff(ii) != 1) + 1])]})",
                                 source=src, field="release")
        tr = num["release_time"][ii]
        if np.ptp(tr) != 0:
            raise GprmInputError(f"release {r}: release_time differs between its rows",
                                 source=src, field="release_time")
        trel[k] = tr[0]
        for n in arr:
            arr[n][k, :ii.size] = num[n][ii]
    data = {n: a for n, a in arr.items() if n in CHANNELS}
    stds = {n[:-4]: a for n, a in arr.items() if n.endswith("_std") and n[:-4] in CHANNELS}
    return telemetry_dataset(ids, arr["time"], trel, data, stds=stds,
                             attrs={"title": "GPRM release telemetry (imported from CSV)",
                                    "source": src})


def _si_values(ds, name: str, kind: str, source: str) -> np.ndarray:
    """A variable's values as float SI: numeric type checked, ``units`` converted (a
    timedelta decoded by xarray counts as seconds)."""
    da = ds[name]
    vals = da.values
    if np.issubdtype(vals.dtype, np.timedelta64):
        return vals / np.timedelta64(1, "s")
    if not (np.issubdtype(vals.dtype, np.number) and not np.iscomplexobj(vals)):
        raise GprmInputError(f"values of type {vals.dtype} (expected real numbers)",
                             source=source, field=name)
    unit = da.attrs.get("units", da.encoding.get("units"))
    return np.asarray(vals, float) * unit_factor(unit, kind, source=source, field=name)


def telemetry_from_dataset(ds, *, source: str = "telemetry", min_releases: int = 2
                           ) -> Telemetry:
    """Check a telemetry :class:`xarray.Dataset` and split it into releases.

    Checks (each a GprmInputError naming the source, the variable and the problem): format,
    required variables and dimensions, real numeric types, units (``units`` attribute
    converted to SI: :func:`unit_factor`; none: SI), unique release ids, at least
    ``min_releases`` releases, strictly increasing time with NaN padding only at the end,
    finite release times and data, positive standard deviations, and no channel constant over
    a release (a stuck or filled channel)."""
    fmt = ds.attrs.get("format", FORMAT)
    if not isinstance(fmt, str) or fmt != FORMAT:
        raise GprmInputError(f"format {fmt!r}, expected {FORMAT!r}", source=source,
                             field="format")
    version = validate.check_attr(ds, validate.Attr("format_version", "integer"), str(source))
    if version is not None and version != FORMAT_VERSION:
        raise GprmInputError(f"format version {ds.attrs.get('format_version')}, this gprm "
                             f"reads {FORMAT_VERSION}", source=source, field="format_version")
    for v in ("time", "release_time") + REQUIRED:
        if v not in ds.variables:
            raise GprmInputError("missing variable", source=source, field=v)
    if "release" not in ds.dims:
        raise GprmInputError("missing dimension", source=source, field="release")
    ids = ([str(r) for r in ds["release"].values] if "release" in ds.coords
           else [f"R{i + 1:02d}" for i in range(ds.sizes["release"])])
    if len(set(ids)) != len(ids):
        raise GprmInputError("release ids are not unique", source=source, field="release")
    if len(ids) < min_releases:
        raise GprmInputError(f"{len(ids)} release(s); the analysis needs >= {min_releases} "
                             "(the paper has 11)", source=source, field="release")
    for v in ("time",) + tuple(c for c in CHANNELS if c in ds.variables) + tuple(
            f"{c}_std" for c in CHANNELS if f"{c}_std" in ds.variables):
        if set(ds[v].dims) != {"release", "sample"}:
            raise GprmInputError(f"dims {ds[v].dims}, expected ('release', 'sample')",
                                 source=source, field=v)
    if ds["release_time"].dims != ("release",):
        raise GprmInputError(f"dims {ds['release_time'].dims}, expected ('release',)",
                             source=source, field="release_time")
    ds = ds.transpose("release", "sample", ...)
    T = np.atleast_2d(_si_values(ds, "time", "time", source))
    trel = _si_values(ds, "release_time", "time", source).ravel()
    chans = [c for c in CHANNELS if c in ds.variables]
    arrs = {c: _si_values(ds, c, CHANNEL_KIND[c], source) for c in chans}
    stds = {c: _si_values(ds, f"{c}_std", CHANNEL_KIND[c], source) for c in chans
            if f"{c}_std" in ds.variables}
    releases = []
    for i, rid in enumerate(ids):
        t = T[i]
        fin = np.isfinite(t)
        nv = int(fin.sum())
        if nv and not fin[:nv].all():
            raise GprmInputError(f"release {rid}: NaN time inside the record (padding only at "
                                 "the end)", source=source, field="time")
        t = t[:nv]
        if nv < 2 or np.any(np.diff(t) <= 0):
            bad = int(np.argmax(np.diff(t) <= 0)) if nv >= 2 else 0
            raise GprmInputError(f"release {rid}: time not strictly increasing (at sample "
                                 f"{bad + 1})", source=source, field="time")
        if not np.isfinite(trel[i]):
            raise GprmInputError(f"release {rid}: non-finite release time", source=source,
                                 field="release_time")
        data, sig = {}, {}
        for c in chans:
            y = arrs[c][i, :nv]
            if not np.all(np.isfinite(y)):
                k = int(np.argmax(~np.isfinite(y)))
                raise GprmInputError(f"release {rid}: non-finite value at t = {t[k]:g} s",
                                     source=source, field=c)
            if c in REQUIRED and nv > 1 and np.ptp(y) == 0:
                raise GprmInputError(f"release {rid}: constant over the whole record (a stuck "
                                     "or filled channel)", source=source, field=c)
            data[c] = y
            s = None
            if c in stds:
                s = stds[c][i, :nv]
            elif "noise_std" in ds[c].attrs:
                s = np.full(nv, float(ds[c].attrs["noise_std"]) * unit_factor(
                    ds[c].attrs.get("units", ds[c].encoding.get("units")), CHANNEL_KIND[c],
                    source=source, field=c))
            if s is not None and not np.all(np.isfinite(s) & (s > 0)):
                raise GprmInputError(f"release {rid}: standard deviations must be finite and "
                                     "> 0", source=source, field=f"{c}_std")
            sig[c] = s
        releases.append(Release(rid, float(trel[i]), t, data, sig))
    truth_t = (np.asarray(ds["truth_impact_time"].values, float)
               if "truth_impact_time" in ds.variables else None)
    return Telemetry(tuple(releases), source, dict(ds.attrs), truth_t, _truth_velocity(ds),
                     _scenario_truth(ds) or None)


def _join_axes(lin: xr.DataArray, ang: xr.DataArray, *, axis: int) -> np.ndarray:
    """The linear (``velocity_axis``) and angular (``angular_axis``) components of a file
    joined back into one array along ``axis``, in the order of ``AXES``."""
    rows = [lin.sel(velocity_axis=a).values if a in LINEAR_AXES
            else ang.sel(angular_axis=a).values for a in AXES]
    return np.stack([np.asarray(r, float) for r in rows], axis=axis)


def _truth_velocity(ds) -> np.ndarray | None:
    """(R, 6) true velocities in AXES order: from ``truth_velocity(release, velocity_axis)``
    and ``truth_angular_velocity(release, angular_axis)``, or (older files) from
    ``truth_velocity(release, axis)``."""
    if "truth_velocity" not in ds.variables:
        return None
    tv = ds["truth_velocity"]
    if "axis" in tv.dims:
        return np.asarray(tv.transpose("release", "axis").values, float)
    return _join_axes(tv, ds["truth_angular_velocity"], axis=1)




def telemetry_dataset(ids, time, release_time, data: dict, *, noise_std: dict | None = None,
                      stds: dict | None = None, attrs: dict | None = None,
                      truth_impact_time=None, truth_velocity=None, truth: dict | None = None):
    """Build a telemetry :class:`xarray.Dataset` (``time`` and data (R, S) arrays, SI).

    data: channel -> (R, S); noise_std: channel -> per-sample white-noise std (an attribute
    of the channel); stds: channel -> (R, S) per-sample std (``<channel>_std``);
    truth_velocity: (R, 6) in AXES order (synthetic); truth: the rest of the synthetic truth
    (:func:`truth_attrs_and_vars`)."""
    ids = [str(i) for i in ids]
    dv: dict[str, tuple] = {
        "time": (("release", "sample"), np.asarray(time, float),
                 {"units": "s", "long_name": "sample time (NaN: padding after the end of a "
                  "shorter release)"}),
        "release_time": (("release",), np.asarray(release_time, float),
                         {"units": "s", "long_name": "test-mass release time"})}
    for c, y in data.items():
        a: dict[str, str | float] = {"units": CHANNEL_UNIT[c],
                                     "long_name": CHANNEL_LONG_NAME[c]}
        if noise_std and c in noise_std:
            a["noise_std"] = float(noise_std[c])
        dv[c] = (("release", "sample"), np.asarray(y, float), a)
    for c, y in (stds or {}).items():
        dv[f"{c}_std"] = (("release", "sample"), np.asarray(y, float),
                          {"units": CHANNEL_UNIT[c],
                           "long_name": f"standard deviation of {c} per sample"})
    coords = {"release": ("release", ids, {"long_name": "release id"})}
    if truth_impact_time is not None:
        dv["truth_impact_time"] = (("release",), np.asarray(truth_impact_time, float),
                                   {"units": "s", "long_name": "true impact time (from the "
                                    "start of the retraction record)"})
    if truth_velocity is not None:
        tv = np.asarray(truth_velocity, float)
        coords.update(_axis_coords())
        dv["truth_velocity"] = (("release", "velocity_axis"),
                                tv[:, [AXES.index(a) for a in LINEAR_AXES]],
                                {"units": "m s-1", "long_name": "true post-impact velocity "
                                 "along the linear axes"})
        dv["truth_angular_velocity"] = (("release", "angular_axis"),
                                        tv[:, [AXES.index(a) for a in ANGULAR_AXES]],
                                        {"units": "rad s-1", "long_name": "true post-impact "
                                         "angular velocity about the angular axes"})
    base = {"title": "GPRM release telemetry", "format": FORMAT,
            "format_version": FORMAT_VERSION}
    if truth is not None:
        tattrs, (tdata, tcoords) = truth_attrs_and_vars(truth)
        dv.update(tdata)
        coords.update(tcoords)
        base.update(tattrs)
    base.update(attrs or {})
    return xr.Dataset(dv, coords=coords, attrs=base)


def write_telemetry(ds: xr.Dataset, path: str | os.PathLike) -> None:
    """Write a telemetry dataset atomically, after checking it as the reader would."""
    telemetry_from_dataset(ds, source=str(path), min_releases=1)
    write_netcdf_atomic(ds, path)


def truth_attrs_and_vars(truth: dict) -> tuple[dict, tuple[dict, dict]]:
    """The synthetic truth of :func:`gprm.flight.synth.synth_telemetry` (``impact_time``,
    ``window``, ``tm_velocity``, ``z_from``, ``truth_model``, ``truth_spread``) as plain
    attributes and variables, ``(attrs, (data_vars, coords))``: the window as the scalars
    ``truth_window_start``, ``truth_window_end`` (s); the test mass's velocity after the
    impact as ``truth_tm_velocity(release, tm_axis)`` (m s-1) and
    ``truth_tm_angular_velocity(release, tm_angular_axis)`` (rad s-1). The impact times are
    the variable ``truth_impact_time``."""
    tm = truth["tm_velocity"]
    attrs = {"truth_model": str(truth["truth_model"]),
             "truth_z_from": "none" if truth.get("z_from") is None else str(truth["z_from"]),
             "truth_spread": int(bool(truth["truth_spread"]))}
    data = {
        "truth_window_start": ((), float(truth["window"][0]),
                               {"units": "s", "long_name": "start of the window the true "
                                "impact times were drawn in"}),
        "truth_window_end": ((), float(truth["window"][1]),
                             {"units": "s", "long_name": "end of the window the true impact "
                              "times were drawn in"}),
        "truth_tm_velocity": (("release", "tm_axis"),
                              np.stack([np.asarray(tm[c], float) for c in TM_LINEAR], 1),
                              {"units": "m s-1", "long_name": "true velocity of the test "
                               "mass after the impact"}),
        "truth_tm_angular_velocity": (("release", "tm_angular_axis"),
                                      np.stack([np.asarray(tm[c], float)
                                                for c in TM_ANGULAR], 1),
                                      {"units": "rad s-1", "long_name": "true angular "
                                       "velocity of the test mass after the impact"}),
    }
    coords = {"tm_axis": ("tm_axis", list(TM_LINEAR), {"long_name": "test-mass axis"}),
              "tm_angular_axis": ("tm_angular_axis", list(TM_ANGULAR),
                                  {"long_name": "test-mass rotation axis"})}
    if truth.get("scenario") is not None:     # scenario truths (issue 23)
        data["truth_scenario"] = (("release",), np.array([str(x) for x in truth["scenario"]]),
                                  {"long_name": "true impact scenario (docs/flight.md §10)"})
        for k, v in truth["scenario_params"].items():
            unit, name = SCENARIO_PARAM_UNITS[k]
            data[f"truth_scenario_{k}"] = (("release",), np.asarray(v, float),
                                           {"units": unit, "long_name": f"true {name}"})
        data["truth_contacts"] = (("release",), np.asarray(truth["contacts"], int),
                                  {"long_name": "number of contacts that pushed"})
    return attrs, (data, coords)


SCENARIO_PARAM_UNITS = {"f": ("1", "gap as a fraction of the largest excursion"),
                        "s": ("m", "contact height on the head"),
                        "phi": ("rad", "azimuth of the contact on the head"),
                        "mu": ("1", "friction coefficient"), "e": ("1", "restitution"),
                        "tm_dx": ("m", "TM CoM offset from the head axis along x"),
                        "tm_dy": ("m", "TM CoM offset from the head axis along y")}
"""Unit and meaning of each scenario unknown in the telemetry file
(``truth_scenario_<name>``)."""


def read_truth(ds) -> dict | None:
    """The synthetic truth of a telemetry dataset (the dict :func:`truth_attrs_and_vars`
    takes), None for measured telemetry. Older files: the JSON attribute ``truth_json``."""
    if "truth_tm_velocity" in ds.variables:
        lin, ang = ds["truth_tm_velocity"], ds["truth_tm_angular_velocity"]
        tm = {c: [float(x) for x in lin.sel(tm_axis=c).values] for c in TM_LINEAR}
        tm.update({c: [float(x) for x in ang.sel(tm_angular_axis=c).values]
                   for c in TM_ANGULAR})
        z = str(ds.attrs.get("truth_z_from", "none"))
        return {"impact_time": [float(x) for x in ds["truth_impact_time"].values],
                "window": [float(ds["truth_window_start"].values),
                           float(ds["truth_window_end"].values)],
                "tm_velocity": {c: tm[c] for c in ("vx", "vy", "vz", "wx", "wy", "wz")},
                "z_from": None if z == "none" else z,
                "truth_model": str(ds.attrs["truth_model"]),
                "truth_spread": bool(int(ds.attrs["truth_spread"])),
                **_scenario_truth(ds)}
    return legacy_json_attr(ds.attrs, "truth_json",
                            source=str(ds.attrs.get("source", "telemetry")))


def _scenario_truth(ds) -> dict:
    """The scenario part of a synthetic truth (empty for older truths)."""
    if "truth_scenario" not in ds.variables:
        return {}
    return {"scenario": [str(x) for x in ds["truth_scenario"].values],
            "scenario_params": {k: [float(x) for x in ds[f"truth_scenario_{k}"].values]
                                for k in SCENARIO_PARAM_UNITS
                                if f"truth_scenario_{k}" in ds.variables},
            "contacts": [int(x) for x in ds["truth_contacts"].values]}


SYNTH_PREFIX = "synth_"


def synth_option_attrs(opts) -> dict:
    """The options of a synthetic telemetry (``SynthOptions``) as plain attributes
    ``synth_<field>`` (booleans as 0/1)."""
    return {SYNTH_PREFIX + k: (int(v) if isinstance(v, bool) else v)
            for k, v in dataclasses.asdict(opts).items()}


def read_synth_options(attrs) -> dict | None:
    """The generator options recorded in a telemetry file, ``{field: value}``; None for
    measured telemetry. Older files: the JSON attribute ``options_json``."""
    out = {k[len(SYNTH_PREFIX):]: (v.item() if isinstance(v, np.generic) else v)
           for k, v in attrs.items() if k.startswith(SYNTH_PREFIX)}
    if out:
        return out
    d = legacy_json_attr(attrs, "options_json", source="", strict=False)
    return dict(d) if isinstance(d, dict) else None


# ============================================================================ impact result

IMPACT_FORMAT = "gprm-impact"
CURVES_FORMAT = "gprm-impact-curves"
CURVES_FORMAT_VERSION = 2
CURVE_QUANTITIES = {"nominal": "velocity the impact model gives (best fit, nominal geometry)",
                    "sigma": "standard deviation over the joint draws",
                    "sigma_fit": "standard deviation over the parameter draws",
                    "sigma_geometry": "standard deviation over the geometry draws",
                    "lo": "2.5 % quantile over the joint draws",
                    "hi": "97.5 % quantile over the joint draws"}


def impact_curves_dataset(curves) -> xr.Dataset:
    """The sidecar of an impact result: the velocity against the impact time per axis
    (``VelocityCurves``), split by unit into ``velocity_<q>(velocity_axis, time)`` (m s-1)
    and ``angular_velocity_<q>(angular_axis, time)`` (rad s-1) for q in nominal, sigma,
    sigma_fit, sigma_geometry, lo, hi."""
    dv: dict[str, tuple] = {}
    for q, long_name in CURVE_QUANTITIES.items():
        d = getattr(curves, q)
        dv[f"velocity_{q}"] = (("velocity_axis", "time"),
                               np.stack([d[a] for a in LINEAR_AXES]),
                               {"units": "m s-1",
                                "long_name": f"test-mass velocity: {long_name}"})
        dv[f"angular_velocity_{q}"] = (("angular_axis", "time"),
                                       np.stack([d[a] for a in ANGULAR_AXES]),
                                       {"units": "rad s-1",
                                        "long_name": f"test-mass angular velocity: "
                                                     f"{long_name}"})
    dv["approaching"] = (("plane", "time"),
                         np.stack([curves.approaching[p] for p in ("xz", "yz")]).astype("i1"),
                         {"units": "1", "long_name": "1 if the best-fit contact point "
                          "approaches the indent face at this impact time",
                          "flag_values": np.array([0, 1], np.int8),
                          "flag_meanings": "not_approaching approaching"})
    dv["plausible"] = (("time",), curves.plausible,
                       {"units": "1", "long_name": "fraction of joint samples approaching in "
                        "both planes"})
    coords = {"plane": ("plane", ["xz", "yz"], {"long_name": "impact plane"}),
              "time": ("time", curves.time, {"units": "s", "long_name": "impact time (from "
                                             "the start of the retraction record)"}),
              **_axis_coords()}
    return xr.Dataset(dv, coords=coords, attrs={
        "title": "GPRM test-mass velocity against impact time (gprm impact)",
        "format": CURVES_FORMAT, "format_version": CURVES_FORMAT_VERSION,
        "n_samples": curves.n_samples, "seed": curves.seed,
        "source": str(curves.meta.get("source", ""))})


def read_impact_curves(path: str | os.PathLike) -> xr.Dataset:
    """The velocity curves of an impact sidecar per axis: ``<q>(axis, time)`` in SI (m s-1 for
    the linear axes, rad s-1 for the angular ones) for q in nominal, sigma, sigma_fit,
    sigma_geometry, lo, hi, with ``approaching(plane, time)`` and ``plausible(time)``. Reads
    the older layout (format_version 1: the six axes along one ``axis``) too."""
    ds = open_netcdf(path, what="impact curves NetCDF")
    src = str(path)
    if ds.attrs.get("format", CURVES_FORMAT) != CURVES_FORMAT:
        raise GprmInputError(f"format {ds.attrs.get('format')!r}, expected {CURVES_FORMAT!r}",
                             source=src, field="format")
    if "axis" in ds.dims:
        return ds
    for q in CURVE_QUANTITIES:
        for v in (f"velocity_{q}", f"angular_velocity_{q}"):
            if v not in ds.variables:
                raise GprmInputError("missing variable", source=src, field=v)
    out = {}
    for q in CURVE_QUANTITIES:
        lin, ang = ds[f"velocity_{q}"], ds[f"angular_velocity_{q}"]
        out[q] = (("axis", "time"), _join_axes(lin, ang, axis=0),
                  {"long_name": CURVE_QUANTITIES[q],
                   "comment": "SI: m s-1 for vx, vz_xz, vy, vz_yz; rad s-1 for wy, wx"})
    for v in ("approaching", "plausible"):
        if v in ds.variables:
            out[v] = ds[v].variable
    coords = {"axis": ("axis", list(AXES)), "time": ds["time"].variable}
    if "plane" in ds.coords:
        coords["plane"] = ds["plane"].variable
    return xr.Dataset(out, coords=coords, attrs=dict(ds.attrs))


def impact_sidecar(out: str | os.PathLike) -> Path:
    """The curves' NetCDF file next to an impact JSON ``out`` (``impact.json`` ->
    ``impact.nc``); an ``out`` ending in ``.nc`` is refused (it would be its own sidecar)."""
    out = Path(out)
    if out.suffix == ".nc":
        raise GprmInputError("must not end in .nc (that name is the sidecar's)",
                             source=str(out), field="out")
    return out.with_suffix(".nc")


def write_impact(doc: dict, curves, out: str | os.PathLike) -> Path:
    """Write an impact result: the JSON ``out`` and its sidecar (:func:`impact_sidecar`: the
    velocity curves), together (:func:`gprm._io.atomic_paths`: a failure writing either
    leaves both as they were); ``doc["curves"]["sidecar"]`` names the sidecar."""
    out = Path(out)
    side = impact_sidecar(out)
    doc["curves"]["sidecar"] = side.name
    with atomic_paths([side, out]) as (tmp_side, tmp_out):
        write_netcdf_to(impact_curves_dataset(curves), tmp_side)
        write_text_to(tmp_out, json_text(doc))
    return side


def read_impact(path: str | os.PathLike) -> dict:
    """An impact result (the JSON of ``gprm impact``), checked to be one."""
    doc = read_json(path, what="impact result")
    fmt = doc.get("format", IMPACT_FORMAT) if isinstance(doc, dict) else type(doc).__name__
    if fmt != IMPACT_FORMAT:
        raise GprmInputError(f"format {fmt!r}, expected {IMPACT_FORMAT!r}", source=str(path),
                             field="format")
    return doc


def read_telemetry(path: str | os.PathLike) -> xr.Dataset:
    """A telemetry NetCDF as its dataset (for plotting), after the checks of
    :func:`load_telemetry` (any release count)."""
    ds = open_netcdf(path, what="telemetry NetCDF")
    telemetry_from_dataset(ds, source=str(path), min_releases=1)
    return ds
