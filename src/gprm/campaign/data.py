"""The campaign data model (docs/spec.md, "Campaign file"): an xarray Dataset with

- ``displacement(position, run, time)`` m: the actuated runs (tip retractions),
- ``noise(position, noise_run, time)`` m: runs without actuation, same time base,
- ``voltage(vrun, vtime)`` V: the retraction voltage traces (optional),

``position`` holding the ten laser positions by name (Sec. 2, Fig. 2), ``time`` in s from the
start of the record, and attributes ``sample_rate`` (Hz) and, for synthetic
campaigns, ``seed`` and the truth (``truth_value(parameter)``). :func:`validate_campaign`
checks everything a later stage relies on and raises a one-line :class:`GprmInputError`
naming file and field. The files (NetCDF, CSV folder) are read and written in
:mod:`gprm.campaign.files`.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from gprm.errors import GprmInputError
from gprm.validate import unit_factor

POSITIONS: tuple[str, ...] = ("x_lr", "x_fl", "x_base", "x_head", "z_bk", "z_fl", "y_fl",
                              "y_lr", "y_base", "y_head")
"""The ten laser positions (Sec. 2), in the paper's order."""

MODEL_POSITIONS: tuple[str, ...] = ("x_base", "x_head", "y_base", "y_head", "z_bk")
"""Positions the model describes (Eq. 3); the others are flange and linear-runner points."""

DEAD_PTP = 1e-15
"""A run whose peak-to-peak range is at most this (m) is a flat (dead) channel."""

RATE_RTOL = 1e-6
"""Relative tolerance on sample spacing (uniformity and agreement with ``sample_rate``)."""


def campaign_dataset(displacement: np.ndarray, noise: np.ndarray, time: np.ndarray, *,
                     sample_rate: float, positions=POSITIONS, voltage: np.ndarray | None = None,
                     vtime: np.ndarray | None = None, attrs: dict | None = None,
                     extra: dict | None = None) -> xr.Dataset:
    """Assemble a campaign Dataset (SI arrays in, conventions and units attached)."""
    data: dict[str, tuple] = {
        "displacement": (("position", "run", "time"), np.asarray(displacement, float),
                         {"units": "m", "long_name": "interferometer displacement, actuated "
                          "runs (tip retraction)"}),
        "noise": (("position", "noise_run", "time"), np.asarray(noise, float),
                  {"units": "m", "long_name": "interferometer displacement, runs without "
                   "actuation"}),
    }
    coords = {
        "position": ("position", np.array(list(positions), dtype=object),
                     {"long_name": "laser position"}),
        "run": ("run", np.arange(np.shape(displacement)[1]),
                {"long_name": "index of the actuated run"}),
        "noise_run": ("noise_run", np.arange(np.shape(noise)[1]),
                      {"long_name": "index of the run without actuation"}),
        "time": ("time", np.asarray(time, float), {"units": "s",
                                                   "long_name": "time from the start of the "
                                                   "record"}),
    }
    if voltage is not None:
        data["voltage"] = (("vrun", "vtime"), np.asarray(voltage, float),
                           {"units": "V", "long_name": "piezo voltage of retraction runs"})
        coords["vrun"] = ("vrun", np.arange(np.shape(voltage)[0]),
                          {"long_name": "index of the voltage run"})
        coords["vtime"] = ("vtime", np.asarray(vtime, float),
                           {"units": "s", "long_name": "time from the start of the voltage "
                            "record"})
    for k, v in (extra or {}).items():
        data[k] = v
    ds = xr.Dataset(data, coords=coords)
    ds.attrs = {"title": "GPRM ground-test campaign", "sample_rate": float(sample_rate),
                "format": "gprm-campaign", "format_version": 1}
    ds.attrs.update(attrs or {})
    return ds


def _finite_check(arr: np.ndarray, src: str, field: str, labels) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        idx = np.argwhere(bad)[0]
        where = ", ".join(f"{n} {lab[i]}" for n, lab, i in zip(labels[0], labels[1], idx))
        raise GprmInputError(f"holds NaN or Inf samples ({int(bad.sum())}; first at {where})",
                             source=src, field=field)


def validate_campaign(ds: xr.Dataset, source: str = "campaign") -> xr.Dataset:
    """Check a campaign Dataset and return it with SI units (converted with pint if needed).

    Raises :class:`GprmInputError` (file, field, problem) for: missing variables, dimensions or
    positions; unknown positions; non-uniform or wrong sample rate; NaN/Inf samples; fewer than
    2 actuated runs; an empty noise set; a flat (dead) channel; an unsupported unit.
    """
    src = str(source)
    for var in ("displacement", "noise"):
        if var not in ds.variables:
            raise GprmInputError("variable missing", source=src, field=var)
    if ds["displacement"].dims != ("position", "run", "time"):
        raise GprmInputError(f"dimensions must be (position, run, time), got "
                             f"{ds['displacement'].dims}", source=src, field="displacement")
    if ds["noise"].dims != ("position", "noise_run", "time"):
        raise GprmInputError(f"dimensions must be (position, noise_run, time), got "
                             f"{ds['noise'].dims}", source=src, field="noise")
    names = [str(p) for p in ds["position"].values]
    missing = [p for p in POSITIONS if p not in names]
    if missing:
        raise GprmInputError(f"missing position(s) {missing}", source=src, field="position")
    unknown = [p for p in names if p not in POSITIONS]
    if unknown or len(set(names)) != len(names):
        raise GprmInputError(f"unknown or repeated position(s) {unknown or names}", source=src,
                             field="position")
    # units -> SI
    ds = ds.copy()
    for var, dim in (("displacement", "m"), ("noise", "m"), ("voltage", "V")):
        if var in ds.variables:
            unit = str(ds[var].attrs.get("units", dim))
            if unit != dim:
                ds[var] = ds[var] * unit_factor(unit, dim, src, var)
                ds[var].attrs["units"] = dim
    # time base and sample rate
    t = np.asarray(ds["time"].values, float)
    if t.size < 8:
        raise GprmInputError(f"needs at least 8 samples, got {t.size}", source=src, field="time")
    _finite_check(t, src, "time", (("sample",), (np.arange(t.size),)))
    dt = np.diff(t)
    if np.any(dt <= 0):
        raise GprmInputError("time is not strictly increasing", source=src, field="time")
    fs_data = 1.0 / float(np.mean(dt))
    if np.max(np.abs(dt - np.mean(dt))) > RATE_RTOL * np.mean(dt) + 1e-15:
        raise GprmInputError("samples are not uniformly spaced", source=src, field="time")
    fs = ds.attrs.get("sample_rate")
    if fs is None:
        fs = fs_data
    fs = float(fs)
    if not (np.isfinite(fs) and fs > 0) or abs(fs_data - fs) > 1e-4 * fs:
        raise GprmInputError(f"sample_rate attribute {fs:g} Hz disagrees with the time "
                             f"coordinate ({fs_data:g} Hz)", source=src, field="sample_rate")
    ds.attrs["sample_rate"] = fs
    # runs
    if ds.sizes["run"] < 2:
        raise GprmInputError(f"needs at least 2 actuated runs per position, got "
                             f"{ds.sizes['run']}", source=src, field="run")
    if ds.sizes["noise_run"] < 1:
        raise GprmInputError("the noise set is empty (no runs without actuation)", source=src,
                             field="noise")
    disp = np.asarray(ds["displacement"].values, float)
    noise = np.asarray(ds["noise"].values, float)
    pos = np.array(names, dtype=object)
    _finite_check(disp, src, "displacement", (("position", "run", "sample"),
                                              (pos, ds["run"].values, np.arange(t.size))))
    _finite_check(noise, src, "noise", (("position", "noise_run", "sample"),
                                        (pos, ds["noise_run"].values, np.arange(t.size))))
    for var, arr, rdim in (("displacement", disp, "run"), ("noise", noise, "noise_run")):
        ptp = np.ptp(arr, axis=-1)
        dead = ptp <= DEAD_PTP
        if dead.any():
            i, j = np.argwhere(dead)[0]
            raise GprmInputError(f"flat (dead) channel: position {names[i]} {rdim} "
                                 f"{ds[rdim].values[j]} is constant", source=src, field=var)
    if "voltage" in ds.variables:
        v = np.asarray(ds["voltage"].values, float)
        if ds["voltage"].dims != ("vrun", "vtime"):
            raise GprmInputError(f"dimensions must be (vrun, vtime), got {ds['voltage'].dims}",
                                 source=src, field="voltage")
        _finite_check(v, src, "voltage", (("vrun", "sample"),
                                          (ds["vrun"].values, np.arange(v.shape[1]))))
        vt = np.asarray(ds["vtime"].values, float)
        if vt.size > 1 and np.any(np.diff(vt) <= 0):
            raise GprmInputError("vtime is not strictly increasing", source=src, field="vtime")
    # canonical position order
    return ds.sel(position=list(POSITIONS))
