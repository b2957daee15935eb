"""The campaign's files, each with its reader and writer side by side (docs/data-formats.md):

- the campaign NetCDF: :func:`write_campaign`, :func:`load_campaign` (also reads a CSV folder);
- the CSV folder a lab exports (``manifest.csv`` plus one file per run):
  :func:`write_campaign_dir`, :func:`read_campaign_dir`, :func:`read_manifest`;
- the mean-signals NetCDF of ``gprm preprocess``: :func:`means_dataset` (the layout),
  :func:`write_means`, :func:`read_means`;
- the metadata both NetCDF files carry, as variables and plain attributes (CF-1.10, no JSON
  strings), with a typed accessor each: the synthetic truth (:func:`truth_dataset`,
  :func:`read_truth`, :func:`has_truth`), the generator settings (:func:`generator_attrs`,
  :func:`read_generator`), the preprocessing settings (:func:`preprocess_attrs`,
  :func:`read_preprocess_settings`), the tables of the means (:func:`tables_dataset`,
  :func:`read_tables`), the truth after alignment (:func:`read_truth_alignment`) and the
  positions whose mean never crossed the threshold (:func:`read_no_crossing`).

Every reader applies the format's schema (:mod:`gprm.validate`) and the format's own rules, and
also reads files written before the metadata became variables (``*_json`` attributes).

CSV folder layout::

    CAMPAIGN_DIR/
      manifest.csv          position,kind,run,file[,unit]
      x_base/run01.csv      time_s,value    (one file per run; any file names)
      ...

- ``manifest.csv``: header ``position,kind,run,file`` and an optional ``unit`` column. ``kind``
  is ``actuated``, ``noise`` or ``voltage``; ``position`` one of the ten laser positions (empty
  for ``voltage``); ``run`` an integer label (runs are ordered by it); ``file`` a path relative
  to the manifest; ``unit`` the unit of the value column (pint syntax, e.g. ``m``, ``um``,
  ``nm``, ``V``; empty = SI: m for displacement, V for voltage). Blank lines and lines starting
  with ``#`` are ignored.
- each data file: two comma-separated columns, time in seconds and the value; one optional
  header row (any non-numeric first row), ``#`` comment lines ignored. All actuated and noise
  files must share one time base (same number of samples, same uniform sample rate); voltage
  files share their own.
"""

from __future__ import annotations

import csv
import dataclasses
import difflib
import hashlib
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import xarray as xr

from gprm._io import excerpt, open_netcdf, text_errors, two_column_rows, write_netcdf_atomic
from gprm.campaign.data import POSITIONS, RATE_RTOL, campaign_dataset, validate_campaign
from gprm.errors import GprmInputError
from gprm.validate import CAMPAIGN, MEANS, check_dataset, legacy_json_attr, unit_factor


# ============================================================================ campaign NetCDF

def write_campaign(ds: xr.Dataset, path: str | os.PathLike) -> None:
    """Validate and write a campaign NetCDF atomically."""
    validate_campaign(ds, source=str(path))
    write_netcdf_atomic(ds, path)


def load_campaign(path: str | os.PathLike) -> xr.Dataset:
    """Read and validate a campaign: a NetCDF file or a CSV directory with ``manifest.csv``.

    The input is only read. The returned Dataset carries ``source`` and ``campaign_sha256``
    attributes (the hash of the file, or of the manifest and data files of a directory).
    """
    path = Path(path)
    if path.is_dir():
        return read_campaign_dir(path)
    if not path.exists():
        raise GprmInputError("campaign file does not exist", source=str(path))
    ds = open_netcdf(path, what="campaign NetCDF")
    ds = check_dataset(ds, CAMPAIGN, str(path))          # types, units, finiteness, order
    ds = validate_campaign(ds, source=str(path))
    ds.attrs["source"] = str(path)
    ds.attrs["campaign_sha256"] = sha256_files([path])
    return ds


def sha256_files(paths) -> str:
    h = hashlib.sha256()
    for p in paths:
        with open(p, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()


# ============================================================================ the truth

def truth_dataset(values: dict) -> xr.Dataset:
    """The true parameter set of a synthetic campaign as ``truth_value(parameter)`` (SI) with
    ``parameter_units(parameter)`` (docs/data-formats.md, "Parameter tables")."""
    from gprm.params.netcdf import parameter_table

    return parameter_table(values, var="truth_value",
                           long_name="true parameter value of the synthetic campaign (SI)")


def read_truth(ds) -> dict | None:
    """The synthetic truth (name -> SI value) of a campaign or mean-signals dataset, None where
    the data are not synthetic. Files written before the truth became a variable stored it
    as the JSON attribute ``truth_json``; they read too."""
    from gprm.params.netcdf import read_parameter_table

    values = read_parameter_table(ds, "truth_value")
    if values is not None:
        return values
    doc = legacy_json_attr(ds.attrs, "truth_json", source=_src(ds))
    if doc is None:
        return None
    if not isinstance(doc, dict):
        raise GprmInputError("attribute must hold a JSON object", source=_src(ds),
                             field="truth_json")
    return {str(k): float(v) for k, v in doc.items() if isinstance(v, (int, float))}


def has_truth(attrs) -> bool:
    """Whether the data behind ``attrs`` (global attributes of a campaign or mean-signals file,
    e.g. a fit's ``FitData.attrs``) are synthetic with a known truth: such files carry
    ``truth_source`` (older ones ``truth_json``)."""
    return "truth_source" in attrs or "truth_json" in attrs


def _src(ds) -> str:
    return str(getattr(ds, "attrs", {}).get("source", "NetCDF file"))


def _plain(v):
    """A NetCDF attribute value as a Python number, text or list."""
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    return v


# ============================================================================ generator settings

GENERATOR_PREFIX = "generator_"


def generator_attrs(config) -> dict:
    """The settings of a synthetic campaign (a ``SynthConfig`` or its ``asdict``) as plain
    global attributes ``generator_<field>``: numbers (booleans as 0/1); a support
    (``Support(k, f, zeta)``) as a number array ``[k, f, zeta]`` (N/m, Hz, 1)."""
    is_instance = dataclasses.is_dataclass(config) and not isinstance(config, type)
    d = dataclasses.asdict(config) if is_instance else dict(config)
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            v = np.array([float(x) for x in v.values()])
        elif isinstance(v, (list, tuple)):
            v = np.array([float(x) for x in v])
        elif isinstance(v, bool):
            v = int(v)
        out[GENERATOR_PREFIX + k] = v
    return out


def read_generator(attrs) -> dict | None:
    """The generator settings recorded in ``attrs`` (campaign or mean-signals file, or a fit's
    ``FitData.attrs``) as ``{field: value}``, a support as the list ``[k, f, zeta]``; None
    where the data are not synthetic. Reads the older ``generator_json`` attribute too."""
    out = {k[len(GENERATOR_PREFIX):]: _plain(v) for k, v in attrs.items()
           if k.startswith(GENERATOR_PREFIX) and k != "generator_json"}
    if out:
        return out
    d = legacy_json_attr(attrs, "generator_json", source="", strict=False)
    if not isinstance(d, dict):
        return None
    return {k: (list(v.values()) if isinstance(v, dict) else v) for k, v in d.items()}


# ============================================================================ mean signals

# preprocessing settings (fields of gprm.campaign.preprocess.PreprocessConfig), stored as
# plain global attributes of the same names
PREPROCESS_FIELDS = ("align_time", "threshold_factor", "max_lag", "sync_window",
                     "onset_factor", "baseline_margin", "hold")


def preprocess_attrs(config) -> dict:
    """The preprocessing settings (a ``PreprocessConfig``) as plain global attributes."""
    d = dataclasses.asdict(config)
    return {k: d[k] for k in PREPROCESS_FIELDS if k in d}


def read_preprocess_settings(attrs) -> dict:
    """The preprocessing settings a mean-signals file was made with (``{field: value}``,
    only those recorded; older files: the JSON attribute ``preprocess_json``)."""
    d = legacy_json_attr(attrs, "preprocess_json", source="", strict=False)
    out = dict(d) if isinstance(d, dict) else {}
    for k in PREPROCESS_FIELDS:
        if k in attrs:
            out[k] = _plain(attrs[k])
    return out


# Table 1, the dropped positions and the signal-to-noise summary are tables: in the file they
# are variables along their own key dimension (CF, docs/data-formats.md), not JSON strings.
_T1_FIELDS = (("value", "table1_value", "1", "ratio of the maxima (this campaign)"),
              ("paper", "table1_paper", "1", "ratio of the maxima in the paper's Table 1"),
              ("numerator_m", "table1_numerator", "m", "max |mean| of the numerator"),
              ("denominator_m", "table1_denominator", "m", "max |mean| of the denominator"))
_DROP_FIELDS = (("hypothesis", "dropped_hypothesis", None, "hypothesis of Sec. 2"),
                ("ratio", "dropped_ratio", None, "Table 1 ratio that is the evidence"),
                ("value", "dropped_value", "1", "value of that ratio"),
                ("paper", "dropped_paper", "1", "the paper's value of that ratio"),
                ("supported", "dropped_supported", "1", "1 if value >= support_threshold"),
                ("support_threshold", "dropped_support_threshold", "1",
                 "ratio needed to support the hypothesis"))
_SNR_FIELDS = (("peak_m", "snr_peak", "m", "max |mean|"),
               ("std_at_peak_m", "snr_std_at_peak", "m", "across-run std at the peak"),
               ("peak_over_std", "snr_peak_over_std", "1", "peak / std at the peak"),
               ("time_of_peak_s", "snr_time_of_peak", "s", "time of the peak"))
_KEY_NAMES = {"ratio": "name of the Table 1 ratio",
              "dropped_position": "position dropped by a hypothesis of Sec. 2",
              "snr_position": "laser position"}


def _table_vars(rows: dict, dim: str, fields) -> dict:
    keys = list(rows)
    out = {}
    for field, var, unit, long_name in fields:
        vals = [rows[k][field] for k in keys]
        if unit is None:
            arr = np.array(vals, dtype=str)
        elif field == "supported":
            arr = np.array(vals, dtype=np.int8)
        else:
            arr = np.array(vals, dtype=float)
        attrs = {"long_name": long_name} | ({} if unit is None else {"units": unit})
        out[var] = ((dim,), arr, attrs)
    return out


def tables_dataset(table1: dict, dropped: dict, snr: dict) -> xr.Dataset:
    """The mean-signals file's tables as variables: ``table1_*(ratio)``,
    ``dropped_*(dropped_position)``, ``snr_*(snr_position)``."""
    data = {}
    for rows, dim, fields in ((table1, "ratio", _T1_FIELDS),
                              (dropped, "dropped_position", _DROP_FIELDS),
                              (snr, "snr_position", _SNR_FIELDS)):
        data.update(_table_vars(rows, dim, fields))
    coords = {dim: (dim, list(rows), {"long_name": _KEY_NAMES[dim]})
              for dim, rows in (("ratio", table1), ("dropped_position", dropped),
                                ("snr_position", snr))}
    return xr.Dataset(data, coords=coords)


def read_tables(ds) -> tuple[dict, dict, dict]:
    """``(table1, dropped, snr)`` of a mean-signals dataset, as the dicts ``MeanSignals``
    holds; files written before the tables became variables (``*_json`` attributes) read
    too."""
    def table(dim, fields, legacy):
        if dim in ds.coords or dim in ds.dims:
            rows = {}
            for i, key in enumerate(ds[dim].values.astype(str)):
                row = {}
                for field, var, unit, _ in fields:
                    if var not in ds:
                        continue
                    x = ds[var].values[i]
                    row[field] = (str(x) if unit is None else bool(x) if field == "supported"
                                  else float(x))
                rows[str(key)] = row
            return rows
        raw = ds.attrs.get(legacy)
        return (legacy_json_attr(ds.attrs, legacy, source=_src(ds))
                if isinstance(raw, str) and raw else {})

    return (table("ratio", _T1_FIELDS, "table1_json"),
            table("dropped_position", _DROP_FIELDS, "dropped_json"),
            table("snr_position", _SNR_FIELDS, "snr_json"))


# the truth after alignment: scalars stored as variables (s); the per-signal equivalent lags
# follow from the truth's t0 and the variable truth_shift
_ALIGN_SCALARS = (("t0_expected_s", "truth_t0_expected",
                   "t0 a fit of the aligned means should find: truth t0 + mean truth_shift "
                   "of x_base, x_head, y_base, y_head"),
                  ("t1_expected_s", "truth_t1_expected",
                   "t1 a fit of the aligned means should find: truth t1 + truth_shift(z_bk) "
                   "- that mean"),
                  ("t0_plus_t1_equivalent_z_bk_s", "truth_t0_plus_t1_equivalent_z_bk",
                   "equivalent lag of z_bk: truth t0 + t1 + truth_shift(z_bk)"))
XY_SIGNALS = ("x_base", "x_head", "y_base", "y_head")


def truth_alignment(truth: dict, truth_shift: dict) -> dict:
    """The truth after alignment (docs/data-formats.md): per signal the truth's alignment
    shift, the equivalent lags of the x/y signals and z_bk, and the t0, t1 a fit of the aligned
    means should find."""
    ts = truth_shift
    xy = [ts[n] for n in XY_SIGNALS]
    return {
        "truth_shift_s": {n: float(v) for n, v in ts.items()},
        "t0_equivalent_s": {n: truth["t0"] + float(ts[n]) for n in XY_SIGNALS},
        "t0_expected_s": truth["t0"] + float(np.mean(xy)),
        "t0_plus_t1_equivalent_z_bk_s": truth["t0"] + truth["t1"] + float(ts["z_bk"]),
        "t1_expected_s": truth["t1"] + float(ts["z_bk"]) - float(np.mean(xy)),
    }


def read_truth_alignment(ds) -> dict | None:
    """The truth after alignment of a mean-signals dataset (the dict of
    :func:`truth_alignment`), None where the campaign was not synthetic. Older files stored it
    as the JSON attribute ``truth_alignment_json``."""
    if "truth_t0_expected" in ds.variables:
        truth = read_truth(ds) or {}
        ts = {str(k): float(v) for k, v in zip(ds["signal"].values, ds["truth_shift"].values)}
        out: dict[str, float | dict[str, float]] = {"truth_shift_s": ts}
        if "t0" in truth:
            out["t0_equivalent_s"] = {n: truth["t0"] + ts[n] for n in XY_SIGNALS if n in ts}
        for key, var, _ in _ALIGN_SCALARS:
            out[key] = float(ds[var].values)
        return out
    return legacy_json_attr(ds.attrs, "truth_alignment_json", source=_src(ds))


def read_no_crossing(ds) -> list[str]:
    """Signals whose mean never reached the threshold (they got the median shift of the
    others); older files: the JSON attribute ``no_crossing_json``."""
    if "no_crossing" in ds.variables:
        return [str(s) for s, f in zip(ds["signal"].values, ds["no_crossing"].values) if f]
    return list(legacy_json_attr(ds.attrs, "no_crossing_json", source=_src(ds), default=[]))


def means_dataset(ms) -> xr.Dataset:
    """The mean-signals NetCDF layout (docs/data-formats.md) of a
    :class:`gprm.campaign.preprocess.MeanSignals`."""
    sig = np.array(ms.signals, dtype=object)
    ds = xr.Dataset(
        {
            "mean": (("signal", "time"), ms.mean, {
                "units": "m", "long_name": "mean over the synchronised actuated runs"}),
            "std": (("signal", "time"), ms.std, {
                "units": "m", "long_name": "standard deviation across runs (ddof 1), "
                "sigma(t)"}),
            "sem": (("signal", "time"), ms.sem, {
                "units": "m", "long_name": "standard error of the mean, std/sqrt(n_runs)"}),
            "noise_std": (("signal",), ms.noise_std, {
                "units": "m", "long_name": "noise standard deviation from the noise runs"}),
            "shift": (("signal",), ms.shift, {
                "units": "s", "long_name": "alignment shift (new time = old time + "
                "shift; old time is the reference run's record time)"}),
            "n_runs": (("signal",), ms.n_runs.astype(np.int32), {
                "units": "1", "long_name": "runs averaged"}),
            "sync_shift": (("signal", "run"), ms.sync_shift, {
                "units": "s", "long_name": "synchronisation shift of each run relative "
                "to the reference run (run r at t + sync_shift matches the reference "
                "at t)"}),
            "reference_run": (("signal",), ms.reference_run.astype(np.int32), {
                "units": "1", "long_name": "index of the reference run"}),
            "no_crossing": (("signal",), np.array([s in set(ms.no_crossing)
                                                    for s in ms.signals], np.int8), {
                "units": "1", "long_name": "1 if the mean never reached the threshold (the "
                "signal got the median shift of the others)",
                "flag_values": np.array([0, 1], np.int8),
                "flag_meanings": "crossed never_crossed"}),
        },
        coords={"signal": ("signal", sig, {"long_name": "laser position"}),
                "time": ("time", ms.time, {
                    "units": "s", "long_name": "aligned time: each signal crosses "
                    "threshold_factor x noise_std at crossing_time, within half a sample "
                    "of align_time"}),
                "run": ("run", np.arange(ms.sync_shift.shape[1]),
                        {"long_name": "index of the actuated run"})})
    whole_samples = getattr(ms, "sync_remainder", None) is not None
    if getattr(ms, "runs", None) is not None:
        ds["runs"] = (("signal", "run", "time"), ms.runs, {
            "units": "m", "long_name": (
                "each actuated run aligned onto the output grid and moved by whole samples of "
                "its synchronisation shift (its own samples; the sub-sample rest is "
                "sync_remainder)" if whole_samples else
                "each actuated run synchronised and aligned onto the output grid (mean, std "
                "and sem are taken over these)")})
    if whole_samples:
        ds["sync_remainder"] = (("signal", "run"), ms.sync_remainder, {
            "units": "s", "long_name": "sync_shift less the whole samples runs were moved "
            "by: run r in runs matches the reference run at t - sync_remainder (the fit "
            "moves the runs the rest of the way)"})
    if getattr(ms, "interpolation_error", None) is not None:
        ds["interpolation_error"] = (("signal", "time"), ms.interpolation_error, {
            "units": "m", "long_name": "the mean's cubic-spline interpolation less a quintic "
            "one of the same runs at the same times (estimated interpolation error)"})
    if getattr(ms, "sync_timing_sd", None) is not None:
        ds["sync_timing_sd"] = (("signal",), ms.sync_timing_sd, {
            "units": "s", "long_name": "standard deviation of the time shift the "
            "synchronisation takes out of the runs' spread but leaves in their mean (from "
            "the noise runs and the mean's slope over the synchronisation window)"})
    if getattr(ms, "baseline", None) is not None:
        for j, end in enumerate(("start", "stop")):
            ds[f"baseline_{end}"] = (("signal",), np.asarray(ms.baseline, float)[:, j], {
                "units": "s", "long_name": f"the {'first' if j == 0 else 'last'} of the "
                "baseline samples each run's straight line was fitted to before the "
                "synchronisation (step 0), on the aligned time axis (the reference run's; "
                "the line's noise is part of every run)"})
    if getattr(ms, "noise_acov", None) is not None:
        ds["noise_acov"] = (("signal", "lag"), np.asarray(ms.noise_acov, float), {
            "units": "m2", "long_name": "autocovariance of the noise runs at lags 0.. record "
            "samples: an autoregression (order 3, Yule-Walker) fitted to the runs, each less "
            "its straight line; lag 0 is noise_std squared"})
    if getattr(ms, "crossing_time", None) is not None:
        ds["crossing_time"] = (("signal",), ms.crossing_time, {
            "units": "s", "long_name": "where the mean's first sustained crossing of "
            "threshold_factor x noise_std lies on the aligned time axis: within half a "
            "sample of align_time, the shift being whole samples (align_time where it "
            "never crossed)"})
    if ms.truth_shift is not None:
        ds["truth_shift"] = (("signal",), ms.truth_shift, {
            "units": "s", "long_name": "where the aligned axis puts the truth's own time: the "
            "runs' average of (trigger offset - synchronisation shift) plus the alignment "
            "shift (synthetic campaigns)"})
        ds["truth_shift_spread"] = (("signal",), ms.truth_shift_spread, {
            "units": "s", "long_name": "range of the truth's alignment shift over ten "
            "sampling phases (the rule's inherent jitter at this sample rate)"})
        ds["truth_mean"] = (("signal", "time"), ms.truth_mean, {
            "units": "m", "long_name": "noise-free truth response aligned by the same "
            "rule (synthetic campaigns)"})
    if ms.truth_alignment is not None:
        for key, var, long_name in _ALIGN_SCALARS:
            ds[var] = ((), float(ms.truth_alignment[key]),
                       {"units": "s", "long_name": long_name})
    ds.attrs = dict(ms.attrs)
    ds = ds.merge(tables_dataset(ms.table1, ms.dropped, ms.snr))
    if ms.truth is not None:
        ds = ds.merge(truth_dataset(ms.truth))
    return ds


def write_means(means, path: str | os.PathLike) -> None:
    """Write mean signals (a ``MeanSignals`` or its dataset) atomically."""
    ds = means if isinstance(means, xr.Dataset) else means_dataset(means)
    write_netcdf_atomic(ds, path)


def read_means(path: str | os.PathLike, *, what: str = "mean-signals file") -> xr.Dataset:
    """Read and check a mean-signals NetCDF (schema ``MEANS``; SI units). Its metadata:
    :func:`read_truth`, :func:`read_truth_alignment`, :func:`read_tables`,
    :func:`read_preprocess_settings`, :func:`read_generator`, :func:`read_no_crossing`."""
    ds = open_netcdf(path, what=what)
    return check_dataset(ds, MEANS, str(path))


# ============================================================================ CSV folder

KINDS = ("actuated", "noise", "voltage")


def _read_two_columns(path: Path) -> tuple[np.ndarray, np.ndarray]:
    src = str(path)
    if not path.is_file():
        raise GprmInputError("data file listed in the manifest does not exist", source=src,
                             field="file")
    rows, lines = two_column_rows(path, src, "time_s, value", "value")
    a = np.array(rows, float)
    t, v = a[:, 0], a[:, 1]
    if not np.all(np.isfinite(t)):
        i = int(np.argmax(~np.isfinite(t)))
        raise GprmInputError(f"time column holds NaN or Inf (line {lines[i]})", source=src,
                             field="time")
    if not np.all(np.isfinite(v)):
        i = int(np.argmax(~np.isfinite(v)))
        raise GprmInputError(f"value column holds NaN or Inf (line {lines[i]})", source=src,
                             field="value")
    if np.ptp(v) <= 0.0:
        raise GprmInputError(f"flat (dead) channel: all {v.size} values equal {v[0]:g}",
                             source=src, field="value")
    return t, v


def campaign_inputs(path: str | os.PathLike) -> list[Path]:
    """The files a command reads from a campaign (for :func:`gprm._io.check_outputs`): a
    NetCDF file itself, or a CSV folder with its ``manifest.csv`` and the files the manifest
    lists (as far as it can be read; a bad manifest is refused when the campaign is read)."""
    path = Path(path)
    if not path.is_dir():
        return [path]
    manifest = path / "manifest.csv"
    out = [path, manifest]
    try:
        out += [path / row["file"] for row in read_manifest(manifest)]
    except GprmInputError:
        pass
    return out


MANIFEST_COLUMNS = ("position", "kind", "run", "file", "unit")


def _check_inside(root: Path, name: str, src: str, row: int) -> None:
    """A manifest's ``file`` must name a file inside the campaign folder: relative, and still
    inside once resolved (``..`` and symbolic links followed)."""
    if Path(name).is_absolute() or name.startswith(("/", "\\")):
        raise GprmInputError(f"row {row}: file {excerpt(name)} is an absolute path; files must "
                             "be named relative to the campaign folder", source=src,
                             field="file")
    try:
        target = (root / name).resolve()
    except (OSError, RuntimeError):       # a symbolic-link loop
        target = None
    if target is None or not target.is_relative_to(root):
        raise GprmInputError(f"row {row}: file {excerpt(name)} is outside the campaign folder",
                             source=src, field="file")


def read_manifest(path: Path) -> list[dict]:
    """The rows of a campaign's ``manifest.csv``, checked: the header names only the columns
    of :data:`MANIFEST_COLUMNS` (an unknown or misspelt one is refused with the closest
    name, so that ``units`` is not silently ignored), each row's kind, position and run are
    valid, and its file lies inside the campaign folder."""
    src = str(path)
    if not path.is_file():
        raise GprmInputError("campaign directory has no manifest.csv", source=src,
                             field="manifest")
    with text_errors(src, "manifest"), path.open(newline="", encoding="utf-8") as fh:
        lines = [ln for ln in fh if ln.strip() and not ln.lstrip().startswith("#")]
    if any("\0" in ln for ln in lines):
        raise GprmInputError("is not a text CSV file (holds NUL bytes)", source=src,
                             field="manifest")
    reader = csv.DictReader(lines)
    header = [(f or "").strip() for f in (reader.fieldnames or [])]
    for name in header:
        if name not in MANIFEST_COLUMNS:
            close = difflib.get_close_matches(name, MANIFEST_COLUMNS, n=1, cutoff=0.5)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise GprmInputError(f"unknown column {excerpt(name)} in the header (expected "
                                 f"{', '.join(MANIFEST_COLUMNS)}, 'unit' optional){hint}",
                                 source=src, field="manifest")
    dup = sorted({n for n in header if header.count(n) > 1})
    missing = [n for n in MANIFEST_COLUMNS[:4] if n not in header]
    if dup or missing:
        what = f"repeats the column(s) {dup}" if dup else f"lacks the column(s) {missing}"
        raise GprmInputError(f"header {what} (expected {', '.join(MANIFEST_COLUMNS)}, 'unit' "
                             "optional)", source=src, field="manifest")
    root = path.parent.resolve()
    out = []
    for i, row in enumerate(reader, start=2):
        if None in row:
            raise GprmInputError(f"row {i}: more fields than the header's {len(header)}",
                                 source=src, field="manifest")
        row = {k.strip(): (v or "").strip() for k, v in row.items() if k is not None}
        kind = row["kind"].lower()
        if kind not in KINDS:
            raise GprmInputError(f"row {i}: kind {excerpt(row['kind'])} is not one of {KINDS}",
                                 source=src, field="kind")
        if kind != "voltage" and row["position"] not in POSITIONS:
            raise GprmInputError(f"row {i}: unknown position {excerpt(row['position'])}",
                                 source=src, field="position")
        try:
            run = int(row["run"])
        except ValueError:
            raise GprmInputError(f"row {i}: run {excerpt(row['run'])} is not an integer",
                                 source=src, field="run") from None
        if not row["file"]:
            raise GprmInputError(f"row {i}: empty file name", source=src, field="file")
        _check_inside(root, row["file"], src, i)
        out.append({"position": row["position"], "kind": kind, "run": run,
                    "file": row["file"], "unit": row.get("unit", "")})
    if not out:
        raise GprmInputError("manifest lists no files", source=src, field="manifest")
    return out


def _check_time(t: np.ndarray, ref_t: np.ndarray | None, src: str) -> None:
    dt = np.diff(t)
    if t.size < 2 or np.any(dt <= 0):
        raise GprmInputError("time is not strictly increasing", source=src, field="time")
    if np.max(np.abs(dt - dt.mean())) > RATE_RTOL * dt.mean() + 1e-15:
        raise GprmInputError("samples are not uniformly spaced", source=src, field="time")
    if ref_t is None:
        return
    if t.size != ref_t.size:
        raise GprmInputError(f"run has {t.size} samples, the others {ref_t.size} (runs of "
                             "unequal length)", source=src, field="time")
    rdt = (ref_t[-1] - ref_t[0]) / (ref_t.size - 1)
    if abs(dt.mean() - rdt) > 1e-4 * rdt:
        raise GprmInputError(f"sample rate {1 / dt.mean():g} Hz differs from the other runs "
                             f"({1 / rdt:g} Hz)", source=src, field="time")
    if np.max(np.abs(t - ref_t)) > 0.01 * rdt:
        raise GprmInputError("time base differs from the other runs (record start)",
                             source=src, field="time")


def read_campaign_dir(path: str | os.PathLike) -> xr.Dataset:
    """Import a CSV campaign directory into the campaign Dataset (validated, SI)."""
    root = Path(path)
    mpath = root / "manifest.csv"
    rows = read_manifest(mpath)
    files = [mpath]
    ref_t = None
    vref_t = None
    act: dict[str, dict[int, np.ndarray]] = {p: {} for p in POSITIONS}
    noi: dict[str, dict[int, np.ndarray]] = {p: {} for p in POSITIONS}
    volt: dict[int, np.ndarray] = {}
    for row in rows:
        fpath = root / row["file"]
        src = str(fpath)
        t, v = _read_two_columns(fpath)
        files.append(fpath)
        if row["kind"] == "voltage":
            _check_time(t, vref_t, src)
            vref_t = t if vref_t is None else vref_t
            unit, si, store = row["unit"] or "V", "V", volt
        else:
            _check_time(t, ref_t, src)
            ref_t = t if ref_t is None else ref_t
            unit, si = row["unit"] or "m", "m"
            store = (act if row["kind"] == "actuated" else noi)[row["position"]]
        if unit != si:
            v = v * unit_factor(unit, si, str(mpath), "unit")
        if row["run"] in store:
            raise GprmInputError(f"{row['kind']} run {row['run']} of {row['position'] or 'voltage'}"
                                 " listed twice", source=str(mpath), field="run")
        store[row["run"]] = v
    src = str(mpath)
    missing = [p for p in POSITIONS if not act[p]]
    if missing:
        raise GprmInputError(f"missing position(s) {missing} (no actuated runs)", source=src,
                             field="position")
    empty = [p for p in POSITIONS if not noi[p]]
    if empty:
        raise GprmInputError(f"the noise set is empty for position(s) {empty}", source=src,
                             field="noise")
    n_act = {p: len(act[p]) for p in POSITIONS}
    n_noi = {p: len(noi[p]) for p in POSITIONS}
    if len(set(n_act.values())) != 1:
        raise GprmInputError(f"positions have different numbers of actuated runs {n_act}",
                             source=src, field="run")
    if len(set(n_noi.values())) != 1:
        raise GprmInputError(f"positions have different numbers of noise runs {n_noi}",
                             source=src, field="noise")
    disp = np.stack([np.stack([act[p][k] for k in sorted(act[p])]) for p in POSITIONS])
    noise = np.stack([np.stack([noi[p][k] for k in sorted(noi[p])]) for p in POSITIONS])
    assert ref_t is not None  # set by the first actuated run, and every position has one
    fs = (ref_t.size - 1) / (ref_t[-1] - ref_t[0])
    voltage = np.stack([volt[k] for k in sorted(volt)]) if volt else None
    # without voltage runs vref_t is still None
    ds = campaign_dataset(disp, noise, ref_t, sample_rate=fs, attrs={"source": str(root)},
                          voltage=voltage, vtime=vref_t)
    ds = validate_campaign(ds, source=str(root))
    ds.attrs["source"] = str(root)
    ds.attrs["campaign_sha256"] = sha256_files(files)
    return ds


def write_campaign_dir(ds: xr.Dataset, path: str | os.PathLike, *, unit: str = "m") -> None:
    """Export a campaign Dataset to the CSV layout (atomically: written to a temporary folder
    beside ``path``, then moved into place; ``path`` must not exist). ``unit``: unit of the
    displacement files (the manifest records it)."""
    root = Path(path)
    if root.exists():
        raise GprmInputError("output directory exists already", source=str(root),
                             field="--out")
    ds = validate_campaign(ds, source=str(ds.attrs.get("source", "campaign")))
    scale = 1.0 / unit_factor(unit, "m", str(root), "unit")
    root.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{root.name}.", dir=root.parent))
    try:
        t = np.asarray(ds["time"].values, float)
        rows = []
        for p in POSITIONS:
            (tmp / p).mkdir()
            for kind, var, dim in (("actuated", "displacement", "run"),
                                   ("noise", "noise", "noise_run")):
                for j in range(ds.sizes[dim]):
                    fname = f"{p}/{kind}_{j:02d}.csv"
                    y = np.asarray(ds[var].sel(position=p).isel({dim: j}).values) * scale
                    _write_two(tmp / fname, t, y, f"displacement_{unit}")
                    rows.append((p, kind, j, fname, unit))
        if "voltage" in ds.variables:
            (tmp / "voltage").mkdir()
            vt = np.asarray(ds["vtime"].values, float)
            for j in range(ds.sizes["vrun"]):
                fname = f"voltage/voltage_{j:02d}.csv"
                _write_two(tmp / fname, vt, np.asarray(ds["voltage"].isel(vrun=j).values),
                           "voltage_V")
                rows.append(("", "voltage", j, fname, "V"))
        with (tmp / "manifest.csv").open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(["position", "kind", "run", "file", "unit"])
            w.writerows(rows)
        os.replace(tmp, root)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _write_two(path: Path, t: np.ndarray, y: np.ndarray, name: str) -> None:
    np.savetxt(path, np.column_stack([t, y]), fmt="%.17g", delimiter=",",
               header=f"time_s,{name}", comments="")
