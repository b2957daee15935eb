"""Small file helpers shared by all stages: atomic writes and NetCDF reading with clear errors.

Outputs are written to a temporary file in the destination folder and moved into place, so an
interrupted or failed run never leaves a half-written file behind and never touches inputs.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Iterator

from gprm.errors import GprmInputError


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success move it onto ``path``.

    On an exception the temporary file is removed and ``path`` is left as it was.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        # mkstemp makes the file private (0600); give the output the usual mode (umask applies)
        os.chmod(tmp_path, 0o666 & ~_umask())
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_json_atomic(path: str | os.PathLike, obj: Any) -> None:
    write_text_atomic(path, json.dumps(obj, indent=2, allow_nan=False) + "\n")


CONVENTIONS = "CF-1.10"


def _history_entry() -> str:
    """What wrote the file: the gprm command line, or the Python API. No wall-clock time, so
    that the same inputs and seed still give byte-identical files (run.json has the times)."""
    import sys

    from gprm import __version__

    argv0 = os.path.basename(sys.argv[0]) if sys.argv else ""
    how = ("gprm " + " ".join(sys.argv[1:])) if argv0 == "gprm" else "the gprm Python API"
    return f"written by {how} (gprm {__version__})"


def cf_dataset(ds):
    """A copy of ``ds`` with the CF-1.10 global attributes (``Conventions``, ``history``
    appended to the one the data came with), ``units = "1"`` on integer and boolean
    variables without units (counts, indices, flags: dimensionless) and no ``_FillValue`` on
    float coordinate variables (CF 2.5.1). Float variables keep
    what their writer gave them; ``ds`` itself is not modified. A global ``units`` attribute
    (not CF) is dropped: every variable carries its own."""
    out = ds.copy(deep=False)
    out.attrs = dict(ds.attrs)
    out.attrs.pop("units", None)
    out.attrs["Conventions"] = CONVENTIONS
    entry = _history_entry()
    prev = str(ds.attrs.get("history", "")).rstrip("\n")
    out.attrs["history"] = entry if not prev else (
        prev if prev.endswith(entry) else f"{prev}\n{entry}")
    for name in list(out.variables):
        var = out.variables[name]
        if var.dims == (name,) and var.dtype.kind == "f":
            # CF 2.5.1: a coordinate variable has no missing values, hence no _FillValue
            var.encoding = {**var.encoding, "_FillValue": None}
        if var.dtype.kind in "iub" and "units" not in var.attrs and "units" not in \
                var.encoding:
            out.variables[name].attrs = {**var.attrs, "units": "1"}
    return out


def write_netcdf_atomic(ds, path: str | os.PathLike) -> None:
    """Write an xarray Dataset to NetCDF4 atomically, with the CF attributes of
    :func:`cf_dataset` (docs/data-formats.md, "Conventions")."""
    out = cf_dataset(ds)
    with atomic_path(path) as tmp:
        out.to_netcdf(tmp, engine="netcdf4")


def open_netcdf(path: str | os.PathLike, *, what: str = "NetCDF file"):
    """Load a NetCDF file fully into memory (the file is closed afterwards, never modified)."""
    import xarray as xr

    path = Path(path)
    if not path.exists():
        raise GprmInputError(f"{what} does not exist", source=str(path))
    try:
        with xr.open_dataset(path, engine="netcdf4") as ds:
            return ds.load()
    except GprmInputError:
        raise
    except Exception as exc:  # corrupted or not NetCDF at all
        raise GprmInputError(f"cannot be read as {what} ({type(exc).__name__}: {exc})",
                             source=str(path)) from None


def read_json(path: str | os.PathLike, *, what: str = "JSON file") -> Any:
    path = Path(path)
    if not path.exists():
        raise GprmInputError(f"{what} does not exist", source=str(path))
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise GprmInputError(f"is not valid JSON ({exc})", source=str(path)) from None
