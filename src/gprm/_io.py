"""Small file helpers shared by all stages: atomic writes and NetCDF reading with clear errors.

Outputs are written to a temporary file in the destination folder and moved into place, so an
interrupted or failed run never leaves a half-written file behind and never touches inputs.
"""

from __future__ import annotations

import contextlib
import csv
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
    if path.is_dir():
        raise GprmInputError("is a folder; expected a file to write", source=str(path))
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    except OSError as exc:
        raise GprmInputError(f"cannot write here ({exc.strerror or exc})",
                             source=str(path)) from None
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

    path = check_input_file(path, what=what)
    try:
        with xr.open_dataset(path, engine="netcdf4") as ds:
            return ds.load()
    except GprmInputError:
        raise
    except Exception as exc:  # corrupted or not NetCDF at all
        raise GprmInputError(f"cannot be read as {what} ({type(exc).__name__}: {exc})",
                             source=str(path)) from None


def read_json(path: str | os.PathLike, *, what: str = "JSON file") -> Any:
    path = check_input_file(path, what=what)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise GprmInputError(f"is not valid JSON ({exc})", source=str(path)) from None
    except OSError as exc:
        raise GprmInputError(f"cannot be read ({exc.strerror or exc})",
                             source=str(path)) from None
    except RecursionError:
        raise GprmInputError("is not valid JSON (nested too deeply)", source=str(path)) from None


# ----------------------------------------------------------------------------- paths

def check_input_file(path: str | os.PathLike, *, what: str = "input file") -> Path:
    """An existing, readable regular file (not a folder); returns it as a Path."""
    path = Path(path)
    if not path.exists():
        raise GprmInputError(f"{what} does not exist", source=str(path))
    if path.is_dir():
        raise GprmInputError(f"is a folder; expected a {what}", source=str(path))
    if not os.access(path, os.R_OK):
        raise GprmInputError(f"{what} is not readable (permission denied)", source=str(path))
    return path


def _same(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.resolve() == b.resolve()


def _probe_writable(folder: Path) -> str | None:
    """None when a file can be created in ``folder`` (or its nearest existing ancestor, which
    the write would create the folder in); else the reason. Tries for real (so read-only file
    systems and permissions are both seen, also when running as root) and leaves nothing."""
    f = folder
    while not f.exists():
        if f.parent == f:
            return "no existing parent folder"
        f = f.parent
    if not f.is_dir():
        return f"{f} is not a folder"
    try:
        fd, tmp = tempfile.mkstemp(prefix=".gprm-probe.", dir=f)
    except OSError as exc:
        return f"cannot create files in {f} ({exc.strerror or exc})"
    os.close(fd)
    os.unlink(tmp)
    return None


def check_outputs(outputs: dict | list[tuple[Any, str]], inputs=(), *,
                  folders: dict | None = None) -> None:
    """Refuse, before any work, outputs that cannot be written or would destroy data.

    ``outputs`` maps each file to be written to the option it comes from (a sidecar names its
    option too: ``{"fit.json": "--out", "fit.nc": "--out (sidecar)"}``; a list of
    ``(path, option)`` pairs where two options may name the same file); ``folders`` the same
    for output folders (a checkpoint folder). Refused: an output that is an existing folder
    (or a folder output that is a file), an output in a folder where no file can be created,
    an output that is one of ``inputs`` (for a folder output: one that holds an input), and
    two outputs that are the same file. Inputs are never opened for writing. A command that
    reads a folder lists the files it reads in it (:func:`files_read_from`).
    """
    folders = folders or {}
    ins = [Path(p) for p in inputs if p is not None]
    seen: list[tuple[Path, str]] = []
    pairs = outputs.items() if isinstance(outputs, dict) else outputs
    items = [*((Path(p), o, False) for p, o in pairs if p is not None),
             *((Path(p), o, True) for p, o in folders.items() if p is not None)]
    for path, opt, is_folder in items:
        if is_folder:
            if path.exists() and not path.is_dir():
                raise GprmInputError("is a file; expected a folder", source=str(path),
                                     field=opt)
        elif path.is_dir():
            raise GprmInputError("is a folder; expected a file to write", source=str(path),
                                 field=opt)
        for i in ins:
            if _same(path, i) or (is_folder and _is_inside(i, path)):
                raise GprmInputError(f"would overwrite the input {i}; choose another name",
                                     source=str(path), field=opt)
        for other, oopt in seen:
            if _same(path, other):
                raise GprmInputError(f"is also the output of {oopt}; choose another name",
                                     source=str(path), field=opt)
        seen.append((path, opt))
        why = _probe_writable(path if is_folder else path.parent)
        if why:
            raise GprmInputError(f"cannot be written: {why}", source=str(path), field=opt)


def files_read_from(folder: str | os.PathLike, suffixes) -> list[Path]:
    """The files of an input folder a command may read: every file with one of the endings
    ``suffixes`` (a run directory). A campaign folder lists its own
    (:func:`gprm.campaign.files.campaign_inputs`)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return [p for p in folder.iterdir() if p.is_file() and p.suffix in suffixes]


def _is_inside(child: Path, folder: Path) -> bool:
    try:
        child.resolve().relative_to(folder.resolve())
        return True
    except ValueError:
        return False


@contextlib.contextmanager
def text_errors(src: str, field: str):
    """Turn undecodable, binary or unreadable CSV text files into one-line input errors."""
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


def two_column_rows(path: Path, src: str, columns: str, field: str
                    ) -> tuple[list[tuple[float, float]], list[int]]:
    """The numeric rows of a two-column CSV text file (time and one value: a campaign's data
    file, a voltage trace) and the line number of each. Blank lines and lines starting with
    ``#`` are skipped, and so are non-numeric rows before the first number (a header). A row
    with fewer than two fields, a non-numeric one after the data began, no numeric row at
    all, or a file that is not readable UTF-8 CSV text is a :class:`GprmInputError` naming
    ``field`` (``columns`` names the two columns in the message)."""
    rows: list[tuple[float, float]] = []
    lines: list[int] = []
    with text_errors(src, field), path.open(newline="", encoding="utf-8") as fh:
        for lineno, row in enumerate(csv.reader(fh), start=1):
            if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
                continue
            if len(row) < 2:
                raise GprmInputError(f"line {lineno}: expected 2 columns ({columns})",
                                     source=src, field=field)
            try:
                rows.append((float(row[0]), float(row[1])))
                lines.append(lineno)
            except ValueError:
                if rows:            # a non-numeric row after the data began
                    raise GprmInputError(f"line {lineno}: not a number: {row[:2]}",
                                         source=src, field=field) from None
                continue            # a header row
    if not rows:
        raise GprmInputError("holds no samples (empty)", source=src, field=field)
    return rows, lines
