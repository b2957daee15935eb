"""The CSV directory layout of a campaign (docs/data-formats.md), so a lab can export into it.

```
CAMPAIGN_DIR/
  manifest.csv          position,kind,run,file[,unit]
  x_base/run01.csv      time_s,value    (one file per run; any file names)
  ...
```

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

import contextlib
import csv
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import xarray as xr

from gprm.campaign.data import (POSITIONS, RATE_RTOL, _unit_factor, campaign_dataset,
                                sha256_files, validate_campaign)
from gprm.errors import GprmInputError

KINDS = ("actuated", "noise", "voltage")


@contextlib.contextmanager
def _text_errors(src: str, field: str):
    """Turn undecodable, binary or unreadable CSV files into one-line input errors."""
    try:
        yield
    except UnicodeDecodeError as exc:
        raise GprmInputError(f"is not UTF-8 text (byte {exc.start}: {exc.reason}); save the "
                             "CSV as UTF-8", source=src, field=field) from None
    except csv.Error as exc:
        raise GprmInputError(f"is not a readable CSV file ({exc})", source=src,
                             field=field) from None
    except OSError as exc:
        raise GprmInputError(f"cannot be read ({exc.strerror or exc})", source=src,
                             field=field) from None


def _read_two_columns(path: Path) -> tuple[np.ndarray, np.ndarray]:
    src = str(path)
    if not path.is_file():
        raise GprmInputError("data file listed in the manifest does not exist", source=src,
                             field="file")
    rows = []
    lines = []
    with _text_errors(src, "value"), path.open(newline="", encoding="utf-8") as fh:
        for lineno, row in enumerate(csv.reader(fh), start=1):
            if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
                continue
            if len(row) < 2:
                raise GprmInputError(f"line {lineno}: expected 2 columns (time_s, value)",
                                     source=src, field="value")
            try:
                rows.append((float(row[0]), float(row[1])))
                lines.append(lineno)
            except ValueError:
                if rows:
                    raise GprmInputError(f"line {lineno}: not a number: {row[:2]}",
                                         source=src, field="value") from None
                continue  # header row
    if not rows:
        raise GprmInputError("holds no samples (empty)", source=src, field="value")
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


def read_manifest(path: Path) -> list[dict]:
    src = str(path)
    if not path.is_file():
        raise GprmInputError("campaign directory has no manifest.csv", source=src,
                             field="manifest")
    with _text_errors(src, "manifest"), path.open(newline="", encoding="utf-8") as fh:
        lines = [ln for ln in fh if ln.strip() and not ln.lstrip().startswith("#")]
    if any("\0" in ln for ln in lines):
        raise GprmInputError("is not a text CSV file (holds NUL bytes)", source=src,
                             field="manifest")
    reader = csv.DictReader(lines)
    need = {"position", "kind", "run", "file"}
    if reader.fieldnames is None or not need <= {f.strip() for f in reader.fieldnames}:
        raise GprmInputError(f"header must name the columns {sorted(need)} (optional 'unit')",
                             source=src, field="manifest")
    out = []
    for i, row in enumerate(reader, start=2):
        row = {k.strip(): (v or "").strip() for k, v in row.items() if k is not None}
        kind = row["kind"].lower()
        if kind not in KINDS:
            raise GprmInputError(f"row {i}: kind {row['kind']!r} is not one of {KINDS}",
                                 source=src, field="kind")
        if kind != "voltage" and row["position"] not in POSITIONS:
            raise GprmInputError(f"row {i}: unknown position {row['position']!r}", source=src,
                                 field="position")
        try:
            run = int(row["run"])
        except ValueError:
            raise GprmInputError(f"row {i}: run {row['run']!r} is not an integer", source=src,
                                 field="run") from None
        if not row["file"]:
            raise GprmInputError(f"row {i}: empty file name", source=src, field="file")
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
            v = v * _unit_factor(unit, si, str(mpath), "unit")
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
    fs = (ref_t.size - 1) / (ref_t[-1] - ref_t[0])
    vkw = {}
    if volt:
        vkw = {"voltage": np.stack([volt[k] for k in sorted(volt)]), "vtime": vref_t}
    ds = campaign_dataset(disp, noise, ref_t, sample_rate=fs, attrs={"source": str(root)},
                          **vkw)
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
    scale = 1.0 / _unit_factor(unit, "m", str(root), "unit")
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
