"""Small file helpers shared by all stages: atomic writes and NetCDF reading with clear errors.

Outputs are written to a temporary file in the destination folder and moved into place, so an
interrupted or failed run never leaves a half-written file behind and never touches inputs.
The temporary file's name says who made it (``.NAME.gprm-HOST-PID-XXXXXXXX.part``): one that a
killed gprm process left behind is removed by the next write into that folder
(:func:`remove_stale_temps`), and nothing else ever is. A write that fails for want of space,
a file-size limit, a read-only file system or permissions is a :class:`GprmOutputError`
naming the file and the cause, and leaves no temporary file.

NetCDF inputs are untrusted: a damaged file can make the NetCDF/HDF5 library loop forever or
crash the process. :func:`open_netcdf` checks the file's signature, then reads it once in a
child process with a time limit (:func:`probe_netcdf`) before loading it here.
"""

from __future__ import annotations

import atexit
import contextlib
import csv
import errno
import hashlib
import json
import os
import re
import socket
import stat
import tempfile
import time
from pathlib import Path
from typing import Any, Iterator

from gprm.errors import GprmInputError, GprmOutputError

# ----------------------------------------------------------------------------- writing

#: temporary files of writes in progress in this process (removed if the process exits
#: before the write finishes, e.g. on SIGTERM: gprm.cli turns it into an exception)
_LIVE_TEMPS: set[Path] = set()


def _host_tag() -> str:
    return hashlib.sha256(socket.gethostname().encode()).hexdigest()[:6]


def temp_prefix(name: str) -> str:
    """The start of the name of a temporary file gprm writes ``name`` through."""
    return f".{name}.gprm-{_host_tag()}-{os.getpid()}-"


#: a temporary file of gprm's: .NAME.gprm-HOST-PID-RANDOM.part (RANDOM: mkstemp's letters)
_TEMP_RE = re.compile(r"\.(?P<name>.+)\.gprm-(?P<host>[0-9a-f]{6})-(?P<pid>\d+)-"
                      r"[A-Za-z0-9_]+\.part")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:             # exists, owned by someone else
        return True
    return True


def remove_stale_temps(folder: str | os.PathLike, name: str | None = None) -> list[Path]:
    """Remove the temporary files (``.NAME.gprm-HOST-PID-*.part``) that a gprm process on
    this host left in ``folder`` when it was killed before it could clean up (its PID is no
    longer running); with ``name``, only those of that output. Nothing else is touched (not
    even a file named like gprm 0.1.0's temporaries, ``.NAME.XXXXXXXX.part``: nothing in such
    a name says who made it), and a folder that cannot be listed is left alone. Returns what
    was removed."""
    folder = Path(folder)
    host, me = _host_tag(), os.getpid()
    removed: list[Path] = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for e in entries:
        m = _TEMP_RE.fullmatch(e.name)
        if m is None:
            continue
        if m["host"] != host or (name is not None and m["name"] != name):
            continue
        if int(m["pid"]) == me or _pid_alive(int(m["pid"])):
            continue
        with contextlib.suppress(OSError):
            if e.is_file(follow_symlinks=False):
                os.unlink(e.path)
                removed.append(Path(e.path))
    return removed


def _cleanup_live_temps() -> None:
    for p in list(_LIVE_TEMPS):
        with contextlib.suppress(OSError):
            p.unlink()
    _LIVE_TEMPS.clear()


atexit.register(_cleanup_live_temps)

#: errno -> what a user is told
_ERRNO_CAUSES = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file too large (a file-size limit, e.g. ulimit -f, was reached)",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.ENOTDIR: "a component of the path is a file, not a folder",
    errno.EISDIR: "is a folder",
    errno.ENAMETOOLONG: "file name too long",
    errno.EIO: "input/output error",
}


def _fsize_limit() -> int | None:
    try:
        import resource
    except ImportError:  # pragma: no cover - not POSIX
        return None
    soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    return None if soft == resource.RLIM_INFINITY else int(soft)


def write_failure_cause(exc: BaseException, folder: Path, size: int | None = None) -> str:
    """Why a write into ``folder`` failed, in words: the errno of an OSError, else (the
    NetCDF library reports only "HDF error") the state of the file system and of the
    file-size limit; ``size``: how large the temporary file had grown."""
    if isinstance(exc, OSError) and exc.errno in _ERRNO_CAUSES:
        return _ERRNO_CAUSES[exc.errno]
    limit = _fsize_limit()
    if limit is not None and size is not None and size + (1 << 16) >= limit:
        return (f"file too large (the file-size limit, ulimit -f, is {limit} bytes)")
    try:
        st = os.statvfs(folder)
        if st.f_bavail * st.f_frsize < (1 << 20):
            return "no space left on the device"
        if st.f_flag & getattr(os, "ST_RDONLY", 1):
            return "read-only file system"
    except OSError:
        pass
    if isinstance(exc, OSError):
        return exc.strerror or str(exc)
    return f"{type(exc).__name__}: {exc}"


def _is_write_failure(exc: BaseException, tmp: Path) -> bool:
    """An error of the file system or of the NetCDF library while writing ``tmp`` (as
    opposed to a bug in what is being written, which stays an internal error, or an error
    reading another file, which names that file itself)."""
    if isinstance(exc, GprmInputError):
        return False
    if isinstance(exc, OSError):
        named = [f for f in (exc.filename, exc.filename2) if f is not None]
        return not named or any(_same_name(f, tmp) for f in named)
    return isinstance(exc, RuntimeError) and "NetCDF" in str(exc)


def _same_name(a, b: Path) -> bool:
    try:
        return os.path.abspath(os.fsdecode(a)) == os.path.abspath(b)
    except (TypeError, ValueError):
        return False


def output_error(path: Path, exc: BaseException, size: int | None = None) -> GprmOutputError:
    return GprmOutputError(f"cannot be written: {write_failure_cause(exc, path.parent, size)}",
                           source=str(path))


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success move it onto ``path``.

    On an exception the temporary file is removed and ``path`` is left as it was; a failure
    of the file system (no space, a file-size limit, read-only, permissions) or of the
    NetCDF library while writing becomes a :class:`GprmOutputError` naming ``path`` and the
    cause. Temporary files that killed gprm processes left for ``path`` are removed first.
    """
    with atomic_paths([path]) as (tmp,):
        yield tmp


@contextlib.contextmanager
def atomic_paths(paths) -> Iterator[tuple[Path, ...]]:
    """:func:`atomic_path` for several files that belong together (a JSON and its
    sidecar): yield one temporary path beside each; only when the block has written every
    one are they moved into place, in the order given. A failure while writing any of them
    leaves every path as it was (no output replaced, no temporary file left)."""
    paths = [Path(p) for p in paths]
    for path in paths:
        if path.is_dir():
            raise GprmInputError("is a folder; expected a file to write", source=str(path))
    tmps: list[Path] = []
    try:
        for path in paths:
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                remove_stale_temps(path.parent, path.name)
                fd, tmp = tempfile.mkstemp(prefix=temp_prefix(path.name), suffix=".part",
                                           dir=path.parent)
            except OSError as exc:
                raise output_error(path, exc) from None
            os.close(fd)
            tmps.append(Path(tmp))
            _LIVE_TEMPS.add(tmps[-1])
        yield tuple(tmps)
        # mkstemp makes the file private (0600); give the output the usual mode (umask applies)
        for tmp_path in tmps:
            os.chmod(tmp_path, 0o666 & ~_umask())
        for tmp_path, path in zip(tmps, paths):
            os.replace(tmp_path, path)
            with contextlib.suppress(OSError):
                st = os.stat(path)
                _WRITTEN[os.path.abspath(path)] = (st.st_dev, st.st_ino)
    except BaseException as exc:
        failed = None
        for tmp_path, path in zip(tmps, paths):
            size = None
            with contextlib.suppress(OSError):
                size = tmp_path.stat().st_size
            if failed is None and isinstance(exc, Exception) and _is_write_failure(exc, tmp_path):
                failed = (path, size)
            with contextlib.suppress(OSError):
                tmp_path.unlink()
        if failed is not None:
            raise output_error(failed[0], exc, failed[1]) from None
        raise
    finally:
        for tmp_path in tmps:
            _LIVE_TEMPS.discard(tmp_path)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def json_text(obj: Any) -> str:
    """The text gprm writes a JSON document as."""
    return json.dumps(obj, indent=2, allow_nan=False) + "\n"


def write_json_atomic(path: str | os.PathLike, obj: Any) -> None:
    write_text_atomic(path, json_text(obj))


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
    with atomic_path(path) as tmp:
        write_netcdf_to(ds, tmp)


def write_netcdf_to(ds, tmp: Path) -> None:
    """Write ``ds`` with the CF attributes of :func:`cf_dataset` to ``tmp``, a path
    :func:`atomic_paths` gave (several outputs written together)."""
    cf_dataset(ds).to_netcdf(tmp, engine="netcdf4")


# ----------------------------------------------------------------------------- reading NetCDF

_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_CLASSIC_SIGNATURES = (b"CDF\x01", b"CDF\x02", b"CDF\x05")

#: seconds a NetCDF file may take to be read once in the child process, at least (plus one
#: second per 25 MB); ``GPRM_READ_TIMEOUT`` overrides the base
READ_TIMEOUT_S = 10.0

#: files already read once in a child: (device, inode, size, mtime) -> True
_PROBED: dict[tuple, bool] = {}


def check_netcdf_signature(path: Path, what: str) -> None:
    """Refuse a file that is not NetCDF by its first bytes: the HDF5 signature (at 0, 512,
    1024, ... as the NetCDF library looks for it) or a classic NetCDF header."""
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            head = fh.read(8)
            if size == 0:
                raise GprmInputError(f"is empty; expected a {what}", source=str(path))
            if head[:4] in _CLASSIC_SIGNATURES or head == _HDF5_SIGNATURE:
                return
            off = 512
            while off + 8 <= size and off <= (1 << 30):
                fh.seek(off)
                if fh.read(8) == _HDF5_SIGNATURE:
                    return
                off *= 2
    except OSError as exc:
        raise GprmInputError(f"cannot be read ({exc.strerror or exc})",
                             source=str(path)) from None
    raise GprmInputError(f"is not a NetCDF file (no NetCDF or HDF5 signature); expected a "
                         f"{what}", source=str(path))


def _read_everything(path: str) -> None:
    """Open ``path`` with the NetCDF library and read every attribute and variable of every
    group, in slices of a few MB (the child's work in :func:`probe_netcdf`)."""
    import netCDF4

    with netCDF4.Dataset(path, "r") as root:
        groups = [root]
        while groups:
            g = groups.pop()
            for a in g.ncattrs():
                g.getncattr(a)
            for v in g.variables.values():
                v.set_auto_maskandscale(False)
                for a in v.ncattrs():
                    v.getncattr(a)
                if v.ndim == 0 or v.shape[0] == 0:
                    v[...]
                    continue
                row = max(1, int(v.size // v.shape[0])) * getattr(v.dtype, "itemsize", 64)
                step = max(1, (8 << 20) // max(1, row))
                for i in range(0, v.shape[0], step):
                    v[i:i + step]
            groups.extend(g.groups.values())


def _timeout(size: int) -> float:
    base = READ_TIMEOUT_S
    with contextlib.suppress(ValueError):
        base = float(os.environ.get("GPRM_READ_TIMEOUT", base))
    return base + size / 25e6


def probe_netcdf(path: Path, what: str) -> None:
    """Read ``path`` once in a forked child process, with a time limit: a damaged file that
    makes the NetCDF/HDF5 library loop or crash ends in a :class:`GprmInputError` naming the
    file (within :data:`READ_TIMEOUT_S` seconds) instead of hanging or killing gprm. Ctrl-C
    stops the child and is raised here. A file read this way before (same inode, size and
    modification time) is not read again. Without ``os.fork`` this does nothing."""
    if not hasattr(os, "fork"):  # pragma: no cover - not POSIX
        return
    try:
        st = path.stat()
    except OSError:
        return                  # the open that follows says why
    key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
    if key in _PROBED:
        return
    import netCDF4  # noqa: F401  (imported before the fork: the child only reads)

    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:                                            # the child
        code = 0
        try:
            import signal

            os.close(r)
            for s in (signal.SIGINT, signal.SIGTERM):
                signal.signal(s, signal.SIG_DFL)
            # what the libraries print (HDF5 diagnostics, a crash dump) stays off the console
            import faulthandler

            faulthandler.disable()
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 1)
            os.dup2(null, 2)
            try:
                _read_everything(str(path))
            except BaseException as exc:                    # noqa: BLE001 - reported
                os.write(w, f"{type(exc).__name__}: {exc}".encode("utf-8", "replace")[:2000])
                code = 3
        finally:
            os._exit(code)
    os.close(w)
    limit = _timeout(st.st_size)
    deadline = time.monotonic() + limit
    status = None
    try:
        delay = 0.001
        while True:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                break
            if time.monotonic() > deadline:
                break
            time.sleep(delay)
            delay = min(0.05, delay * 2)
    except BaseException:               # Ctrl-C, SIGTERM: stop the child, then go on
        _kill(pid)
        os.close(r)
        raise
    if not done:
        _kill(pid)
        os.close(r)
        raise GprmInputError(f"cannot be read as {what}: reading it did not finish within "
                             f"{limit:.3g} s (the file is probably damaged)", source=str(path))
    with os.fdopen(r, "rb") as fh:
        message = fh.read().decode("utf-8", "replace").strip()
    code = os.waitstatus_to_exitcode(status)
    if code < 0:
        raise GprmInputError(f"cannot be read as {what}: the NetCDF library crashed on it "
                             f"(signal {-code}; the file is probably damaged)",
                             source=str(path))
    if code != 0:
        raise GprmInputError(f"cannot be read as {what} ({message or f'exit code {code}'})",
                             source=str(path))
    _PROBED[key] = True


def _kill(pid: int) -> None:
    import signal

    with contextlib.suppress(OSError):
        os.kill(pid, signal.SIGKILL)
    with contextlib.suppress(OSError):
        os.waitpid(pid, 0)


def open_netcdf(path: str | os.PathLike, *, what: str = "NetCDF file"):
    """Load a NetCDF file fully into memory (the file is closed afterwards, never modified).

    The file is untrusted: its signature is checked and it is read once in a child process
    with a time limit first (:func:`probe_netcdf`), so a damaged file is a one-line
    :class:`GprmInputError` naming it, never a hang or a crash."""
    import xarray as xr

    path = check_input_file(path, what=what)
    check_netcdf_signature(path, what)
    probe_netcdf(path, what)
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
                  folders: dict | None = None, own=(), sidecars=()) -> None:
    """Refuse, before any work, outputs that cannot be written or would destroy data.

    ``outputs`` maps each file to be written to the option it comes from (a sidecar names its
    option too: ``{"fit.json": "--out", "fit.nc": "--out (sidecar)"}``; a list of
    ``(path, option)`` pairs where two options may name the same file); ``folders`` the same
    for output folders (a checkpoint folder). Refused: an output that is an existing folder
    (or a folder output that is a file), an output in a folder where no file can be created,
    an output that is one of ``inputs`` or the sidecar of one (a JSON input's ``.nc`` of the
    same name: ``fit.json`` is read with ``fit.nc``; for a folder output: one that holds an
    input), and two outputs that are the same file. Inputs are never opened for writing. A
    command that reads a folder lists the files it reads in it (:func:`files_read_from`).
    Every command calls this once, before any work, with all its outputs and inputs.
    """
    folders = folders or {}
    ins: list[tuple[Path, str]] = []
    for p in inputs:
        if p is None:
            continue
        p = Path(p)
        ins.append((p, f"the input {p}"))
        if p.suffix == ".json":
            ins.append((p.with_suffix(".nc"), f"the sidecar of the input {p}"))
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
        for i, label in ins:
            if _same(path, i) or (is_folder and _is_inside(i, path)):
                raise GprmInputError(f"would overwrite {label}; choose another name",
                                     source=str(path), field=opt)
        for other, oopt in seen:
            if _same(path, other):
                raise GprmInputError(f"is also the output of {oopt}; choose another name",
                                     source=str(path), field=opt)
        seen.append((path, opt))
        if not is_folder:
            _check_replaceable(path, opt, own)
        why = _probe_writable(path if is_folder else path.parent)
        if why:
            raise GprmInputError(f"cannot be written: {why}", source=str(path), field=opt)
    for side, doc in sidecars:
        side, doc = Path(side), Path(doc)
        if side.is_file() and not sidecar_of(doc, side):
            raise GprmInputError(f"exists and is not the sidecar of an existing {doc.name}; "
                                 f"writing {doc.name} would replace it, which gprm does "
                                 "not do: move it or choose another --out",
                                 source=str(side), field="--out")


def _check_replaceable(path: Path, opt: str, own) -> None:
    """Refuse an existing file at the output ``path`` that gprm must not replace: a symbolic
    link (even a dangling one), a write-protected file, or a file gprm did not write
    (:func:`written_by_gprm`) and that is not one of ``own``."""
    try:
        st = path.lstat()
    except OSError:
        return                                   # nothing there: nothing to replace
    if stat.S_ISLNK(st.st_mode):
        raise GprmInputError("is a symbolic link; gprm writes plain files and does not "
                             "replace a link: name the file itself or another path",
                             source=str(path), field=opt)
    if not stat.S_ISREG(st.st_mode):
        return                                   # a folder: refused by the caller
    if not st.st_mode & 0o222:
        raise GprmInputError("is write-protected (read-only); gprm does not replace it: "
                             "make it writable or choose another name",
                             source=str(path), field=opt)
    if not any(_same(path, Path(o)) for o in own) and not written_by_gprm(path):
        raise GprmInputError("exists and is not a file gprm wrote; gprm replaces only its "
                             "own files: move it or choose another name",
                             source=str(path), field=opt)


def _json_object(path: Path, max_bytes: int = 64 << 20) -> dict | None:
    """The JSON object in ``path`` (at most ``max_bytes``), or None where the file is
    larger, unreadable, not JSON or not an object: for judging a file, not for reading an
    input (:func:`read_json` names the problem)."""
    try:
        if path.stat().st_size > max_bytes:
            return None
        d = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    return d if isinstance(d, dict) else None


def sidecar_of(doc: Path, side: Path) -> bool:
    """Whether the JSON file ``doc`` is a gprm result that names ``side`` as its sidecar
    (a fit's ``sidecar.name``, an impact result's ``curves.sidecar``)."""
    d = _json_object(doc)
    if d is None:
        return False
    fit_side, curves = d.get("sidecar"), d.get("curves")
    names = (fit_side.get("name") if isinstance(fit_side, dict) else None,
             curves.get("sidecar") if isinstance(curves, dict) else None)
    return side.name in names


#: what :func:`_history_entry` writes into every NetCDF file gprm makes
_HISTORY_MARK = re.compile(rb"written by (?:gprm |the gprm Python API )")
#: the start of what ``gprm report`` writes (its title) and of a parameter file gprm writes
_REPORT_MARK = b"<title>GPRM tip retraction"
_PARAMS_MARK = b"# gprm parameter file"


def written_by_gprm(path: str | os.PathLike, chunk: int = 1 << 22) -> bool:
    """Whether the existing file ``path`` is recognisably one gprm wrote, by its content
    (whatever its name ends in):

    - a NetCDF file (its signature) whose attributes hold gprm's history entry
      (:func:`_history_entry`, in every NetCDF file gprm writes; an attribute is stored as
      plain bytes, so the file is scanned for it chunk by chunk, without opening it as
      NetCDF);
    - a JSON object whose ``format`` or ``model`` names gprm (``gprm-...``: the fit, impact
      and design results), whose ``versions`` lists gprm (run.json), or a what-if table
      (``definition`` and ``ratios``);
    - the report (its title) and a parameter file (its first line).

    False for anything else and for a file that cannot be read: gprm replaces only what it
    recognises as its own (:func:`check_outputs`). A file edited by other tools that kept
    gprm's marks (xarray keeps a NetCDF's history) still counts as gprm's."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(1 << 16)
            if head[:4] in _CLASSIC_SIGNATURES or head[:8] == _HDF5_SIGNATURE:
                overlap, tail = 64, b""
                fh.seek(0)
                while True:
                    block = fh.read(chunk)
                    if not block:
                        return False
                    seen = tail + block
                    if _HISTORY_MARK.search(seen):
                        return True
                    tail = seen[-overlap:]
        if head.lstrip()[:1] == b"{":
            d = _json_object(path)
            if d is None:
                return False
            named = any(isinstance(d.get(k), str) and d[k].startswith("gprm")
                        for k in ("format", "model"))
            versions = d.get("versions")
            return (named or (isinstance(versions, dict) and "gprm" in versions)
                    or {"definition", "ratios"} <= d.keys())
        return _REPORT_MARK in head or head.startswith(_PARAMS_MARK)
    except OSError:
        return False


#: files this process moved into place (:func:`atomic_paths`): absolute path -> (device,
#: inode) of what it wrote there, so that a run can tell its own writes from a file someone
#: put at the same name meanwhile (:func:`written_here`)
_WRITTEN: dict[str, tuple[int, int]] = {}


def written_here(path: str | os.PathLike) -> bool:
    """Whether ``path`` is still the very file this process wrote there (same device and
    inode as when :func:`atomic_paths` moved it into place)."""
    key = os.path.abspath(path)
    try:
        st = os.stat(key)
    except OSError:
        return False
    return _WRITTEN.get(key) == (st.st_dev, st.st_ino)


def write_text_to(tmp: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to the temporary path ``tmp`` of :func:`atomic_paths`; an
    error of the file system names ``tmp`` (a failed write() carries no file name, so the
    group's message would otherwise name the wrong file)."""
    try:
        tmp.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror, str(tmp)) from exc


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


def excerpt(text: object, limit: int = 40) -> str:
    """A short, safe quotation of input text for an error message: printable ASCII only
    (anything else shown as ``?``), at most ``limit`` characters (cut with ``...``), quoted.
    Error lines never echo more of a file than this."""
    s = "".join(c if " " <= c <= "~" else "?" for c in str(text))
    return repr(s if len(s) <= limit else s[: limit - 3] + "...")


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
                    raise GprmInputError(f"line {lineno}: not a number: "
                                         f"{excerpt(','.join(row[:2]))}",
                                         source=src, field=field) from None
                continue            # a header row
    if not rows:
        raise GprmInputError("holds no samples (empty)", source=src, field=field)
    return rows, lines
