"""Release telemetry: the NetCDF format, reading it with checks, and release velocities.

Format (``format = "gprm-telemetry"``, ``format_version = 1``; see docs/flight.md):

* dims ``release`` (coordinate of ids, e.g. ``R01``) and ``sample``;
* ``time(release, sample)`` s, strictly increasing within a release; a release shorter than the
  longest one is padded at the end with NaN time (and NaN data);
* ``release_time(release)`` s, in the same time base as ``time``;
* test-mass displacement ``x, y, z(release, sample)`` m and attitude ``theta`` (about x),
  ``eta`` (about y), ``phi`` (about z) ``(release, sample)`` rad; ``phi`` is optional (no axis
  uses it). Each may carry a ``noise_std`` attribute (sensor white-noise std per sample, same
  unit); with it the line fit is weighted by it, without it the scatter of the residuals is
  used;
* optional ``<var>_std(release, sample)`` per-sample standard deviations (weights of the
  weighted line fit, they take precedence over ``noise_std``);
* synthetic files add ``truth_impact_time(release)`` s, ``truth_velocity(release, axis)`` and
  ``attrs`` ``seed``, ``truth_json``.

The release velocity per axis (Fig. 11a) is the slope of a weighted straight line through the
samples after the release time (within ``fit_window`` seconds if given) with its standard
error.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from gprm.errors import GprmInputError

FORMAT = "gprm-telemetry"
FORMAT_VERSION = 1

AXES: tuple[str, ...] = ("vx", "vz_xz", "wy", "vy", "vz_yz", "wx")
"""The six velocity components (INTERFACES.md): x–z plane (v_x, v_z, ω_y), y–z plane
(v_y, v_z, ω_x)."""

AXIS_CHANNEL = {"vx": "x", "vz_xz": "z", "wy": "eta", "vy": "y", "vz_yz": "z", "wx": "theta"}
"""Telemetry channel whose slope gives each axis' velocity."""

AXIS_UNIT = {"vx": "m/s", "vz_xz": "m/s", "wy": "rad/s", "vy": "m/s", "vz_yz": "m/s",
             "wx": "rad/s"}
CHANNELS = ("x", "y", "z", "theta", "eta", "phi")
CHANNEL_UNIT = {"x": "m", "y": "m", "z": "m", "theta": "rad", "eta": "rad", "phi": "rad"}
REQUIRED = ("x", "y", "z", "theta", "eta")


@dataclass(frozen=True)
class Release:
    """One release: its samples (padding removed), in SI."""

    id: str
    release_time: float
    time: np.ndarray                 # (T,)
    data: dict                       # channel -> (T,)
    sigma: dict                      # channel -> (T,) or None (unknown, use residuals)


@dataclass(frozen=True)
class Telemetry:
    releases: tuple[Release, ...]
    source: str
    attrs: dict
    truth_impact_time: np.ndarray | None = None   # (R,) synthetic only
    truth_velocity: np.ndarray | None = None      # (R, 6) synthetic only


@dataclass(frozen=True)
class LineFit:
    """Slope (velocity) of the line through a release's post-release samples."""

    value: float
    stderr: float
    intercept: float
    n: int
    reduced_chi2: float
    weighted: bool


def fit_release_velocity(t, y, sigma=None, *, t_release: float = 0.0) -> LineFit:
    """Weighted least-squares line y = a + v (t − t_release); returns v and its stderr.

    With ``sigma`` (per-sample std, or scalar) the weights are 1/σ² and the stderr is the
    formal one, sqrt((XᵀWX)⁻¹)₁₁; without, equal weights and the stderr scaled by the residual
    scatter (σ̂² = RSS/(n − 2)).
    """
    t = np.asarray(t, float) - t_release
    y = np.asarray(y, float)
    n = t.size
    weighted = sigma is not None
    w = (np.ones(n) if sigma is None
         else 1.0 / np.broadcast_to(np.asarray(sigma, float), (n,)) ** 2)
    X = np.stack([np.ones(n), t], axis=1)
    A = X.T @ (w[:, None] * X)
    b = X.T @ (w * y)
    cov = np.linalg.inv(A)
    coef = cov @ b
    res = y - X @ coef
    chi2 = float(np.sum(w * res ** 2))
    dof = max(n - 2, 1)
    if not weighted:
        cov = cov * chi2 / dof
    return LineFit(float(coef[1]), float(np.sqrt(cov[1, 1])), float(coef[0]), n, chi2 / dof,
                   weighted)


# --------------------------------------------------------------------------------------------
# units at the edge (the project's pint registry, as for campaigns and parameter files)
# --------------------------------------------------------------------------------------------
KIND_SI = {"length": "m", "angle": "rad", "time": "s"}
CHANNEL_KIND = {"x": "length", "y": "length", "z": "length", "theta": "angle",
                "eta": "angle", "phi": "angle"}


def unit_factor(unit, kind: str, *, source: str, field: str) -> float:
    """Factor converting ``unit`` (pint syntax: ``mm``, ``um``, ``µrad``, ``deg``, ``ms``, …;
    None or empty: SI) of a ``kind`` (length, angle, time) to SI. A unit that is not of that
    kind, or not a unit: a GprmInputError naming the field."""
    import pint

    from gprm.params.files import ureg

    if unit is None or str(unit).strip() == "":
        return 1.0
    u = str(unit).strip()
    art = "an" if kind[0] in "aeiou" else "a"
    try:
        return float(ureg().Quantity(1.0, u).to(KIND_SI[kind]).magnitude)
    except (pint.errors.PintError, AttributeError, ValueError, TypeError, KeyError):
        raise GprmInputError(f"unit {u!r} is not {art} {kind} unit (convertible to "
                             f"{KIND_SI[kind]})", source=source, field=field) from None


def load_telemetry(path: str | os.PathLike) -> Telemetry:
    """Read and check telemetry (synthetic or real: the same reader and checks): a NetCDF file
    of the ``gprm-telemetry`` format, or a CSV file (:func:`telemetry_csv_dataset`)."""
    from pathlib import Path

    from gprm._io import open_netcdf

    src = str(path)
    if Path(path).suffix.lower() in (".csv", ".txt"):
        return telemetry_from_dataset(telemetry_csv_dataset(path), source=src)
    ds = open_netcdf(path, what="telemetry NetCDF")
    return telemetry_from_dataset(ds, source=src)


def _csv_header(col: str):
    """``name [unit]`` or ``name (unit)`` or ``name`` -> (name, unit or None)."""
    import re

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
    from pathlib import Path

    import csv

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
    cols = {}
    for j, c in enumerate(header):
        name, unit = _csv_header(str(c))
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
    import xarray as xr

    dv = {n: (("release", "sample"), a, {"units": "s" if n == "time" else
                                         CHANNEL_UNIT[n[:-4] if n.endswith("_std") else n]})
          for n, a in arr.items()}
    dv["release_time"] = (("release",), trel, {"units": "s"})
    return xr.Dataset(dv, coords={"release": ids},
                      attrs={"format": FORMAT, "format_version": FORMAT_VERSION,
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
    if fmt != FORMAT:
        raise GprmInputError(f"format {fmt!r}, expected {FORMAT!r}", source=source,
                             field="format")
    if int(ds.attrs.get("format_version", FORMAT_VERSION)) != FORMAT_VERSION:
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
    truth_v = (np.asarray(ds["truth_velocity"].transpose("release", "axis").values, float)
               if "truth_velocity" in ds.variables else None)
    return Telemetry(tuple(releases), source, dict(ds.attrs), truth_t, truth_v)


def release_velocities(tel: Telemetry, *, fit_window: float | None = None,
                       min_samples: int = 5) -> dict[str, dict[str, LineFit]]:
    """Release velocity per release and axis (Fig. 11a): ``{release id: {axis: LineFit}}``.

    Uses the samples with release_time < t (<= release_time + fit_window). Fewer than
    ``min_samples`` such samples is an input error naming the release and channel.
    """
    out = {}
    for r in tel.releases:
        sel = r.time > r.release_time
        if fit_window is not None:
            sel &= r.time <= r.release_time + fit_window
        n = int(sel.sum())
        if n < min_samples:
            raise GprmInputError(f"release {r.id}: {n} samples after the release time "
                                 f"{r.release_time:g} s (need >= {min_samples})",
                                 source=tel.source, field="time")
        fits = {}
        for ax in AXES:
            c = AXIS_CHANNEL[ax]
            s = r.sigma[c]
            fits[ax] = fit_release_velocity(r.time[sel], r.data[c][sel],
                                            None if s is None else s[sel],
                                            t_release=r.release_time)
        out[r.id] = fits
    return out


def telemetry_dataset(ids, time, release_time, data: dict, *, noise_std: dict | None = None,
                      attrs: dict | None = None, truth_impact_time=None, truth_velocity=None):
    """Build a telemetry :class:`xarray.Dataset` (``time`` and data (R, S) arrays, SI)."""
    import xarray as xr

    ids = [str(i) for i in ids]
    dv = {"time": (("release", "sample"), np.asarray(time, float),
                   {"units": "s", "long_name": "sample time"}),
          "release_time": (("release",), np.asarray(release_time, float),
                           {"units": "s", "long_name": "test-mass release time"})}
    for c, y in data.items():
        a = {"units": CHANNEL_UNIT[c]}
        if noise_std and c in noise_std:
            a["noise_std"] = float(noise_std[c])
        dv[c] = (("release", "sample"), np.asarray(y, float), a)
    coords = {"release": ids}
    if truth_impact_time is not None:
        dv["truth_impact_time"] = (("release",), np.asarray(truth_impact_time, float),
                                   {"units": "s", "long_name": "true impact time (from the "
                                    "start of the retraction record)"})
    if truth_velocity is not None:
        coords["axis"] = list(AXES)
        dv["truth_velocity"] = (("release", "axis"), np.asarray(truth_velocity, float),
                                {"units": "m/s or rad/s (per axis)"})
    base = {"format": FORMAT, "format_version": FORMAT_VERSION}
    base.update(attrs or {})
    return xr.Dataset(dv, coords=coords, attrs=base)
