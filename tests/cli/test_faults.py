"""Fault injection (issue 22, "nothing lost, nothing wrong accepted"): what gprm does when the
disk is full, the output folder is read-only, an input is damaged, the process is stopped, or
an option cannot work, and that it never deletes a file it did not write.

Each test runs the real command, in this process where that is safe, else in a subprocess
(a damaged NetCDF file hangs the library in the process that opens it; a file-size limit and
SIGTERM apply to a whole process). What a user must see: one line naming the file or the
option and the cause, no traceback, no file that gprm did not write removed or changed, no
temporary file left behind.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from typer.testing import CliRunner

import gprm
from gprm.cli import app
from gprm.errors import GprmInputError, GprmOutputError

sys.path.insert(0, str(Path(__file__).parents[1] / "fit"))
from means_factory import make_means  # noqa: E402

SRC = str(Path(gprm.__file__).resolve().parents[1])
DAMAGED = Path(__file__).parents[1] / "io" / "damaged" / "telemetry_hangs.nc"
#: a small run: 6 starts, 40 band samples, 2 synthetic releases, in this process
SMALL = ["--quick", "--starts", "6", "--workers", "0"]


def _env(tmp_path: Path, **extra) -> dict:
    env = dict(os.environ, PYTHONPATH=SRC + os.pathsep + os.environ.get("PYTHONPATH", ""),
               GPRM_LOG_DIR=str(tmp_path / "logs"), PYTHONDONTWRITEBYTECODE="1")
    env.pop("GPRM_DEBUG", None)
    env.update(extra)
    return env


def _gprm(args, cwd: Path, *, env: dict, timeout: float, preexec_fn=None, code=None):
    """``gprm ARGS`` in a subprocess (``code``: a Python preamble run before the CLI)."""
    cmd = [sys.executable, "-m", "gprm.cli", *args] if code is None else \
        [sys.executable, "-c", code + "\nfrom gprm.cli import main\nmain()", *args]
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout, preexec_fn=preexec_fn)


def _invoke(args, tmp_path: Path):
    """``gprm ARGS`` in this process; an internal error's log would go to tmp_path/logs."""
    old = os.environ.get("GPRM_LOG_DIR")
    os.environ["GPRM_LOG_DIR"] = str(tmp_path / "logs")
    try:
        return CliRunner().invoke(app, [str(a) for a in args])
    finally:
        if old is None:
            del os.environ["GPRM_LOG_DIR"]
        else:
            os.environ["GPRM_LOG_DIR"] = old


def _snapshot(root: Path) -> dict:
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob("*"))}


def _parts(root: Path) -> list[str]:
    return sorted(p.name for p in root.rglob("*.part"))


def _one_error_line(text: str) -> str:
    lines = [ln for ln in text.strip().splitlines() if ln.startswith("gprm: ")]
    assert len(lines) == 1, text
    assert "Traceback" not in text and "internal error" not in text, text
    return lines[0]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A finished small run directory (gprm demo), made once; tests copy it."""
    out = tmp_path_factory.mktemp("faults") / "base"
    r = CliRunner().invoke(app, ["demo", *SMALL, "--out", str(out)])
    assert r.exit_code == 0, r.output + repr(r.exception)
    return out


@pytest.fixture
def run_copy(run_dir, tmp_path):
    dst = tmp_path / "run"
    shutil.copytree(run_dir, dst)
    return dst


# ----------------------------------------------------------------------------- 1. data loss

def test_a_run_that_fails_keeps_every_file_it_did_not_write(tmp_path):
    """``gprm run bad.nc --out U`` where U holds files of the run's names: the user's own
    (not gprm's) are refused before anything runs; gprm's own (an earlier run's fit.json,
    fit.nc, means.nc and impact.json): the blocked stages leave them as they were, no later
    stage takes the earlier means.nc as its input, and neither the summary nor the report
    presents them as results."""
    u = tmp_path / "U"
    u.mkdir()
    theirs = {"fit.json": b'{"my": "fit"}', "means.nc": b"my means"}
    for name, data in theirs.items():
        (u / name).write_bytes(data)
    bad = tmp_path / "bad.nc"
    bad.write_bytes(np.random.default_rng(0).bytes(1000))
    r = _invoke(["run", bad, *SMALL, "--out", u], tmp_path)
    assert r.exit_code == 2 and "not a file gprm wrote" in r.output, r.output
    assert sorted(p.name for p in u.iterdir()) == sorted(theirs)
    assert all((u / n).read_bytes() == d for n, d in theirs.items())
    import xarray as xr

    from gprm._io import write_netcdf_atomic

    for name in ("fit.nc", "means.nc"):                # NetCDF files gprm wrote
        write_netcdf_atomic(xr.Dataset({"v": ("t", np.arange(3.0))}), u / name)
    mine = {"fit.json": b'{"model": "gprm-3d", "my": "fit"}',
            "impact.json": b'{"format": "gprm-impact"}',
            **{n: (u / n).read_bytes() for n in ("fit.nc", "means.nc")}}
    for name, data in mine.items():
        (u / name).write_bytes(data)
    r = _invoke(["run", bad, *SMALL, "--out", u], tmp_path)
    assert r.exit_code == 1, r.output
    assert "stage(s) failed: campaign: " + str(bad) in r.output
    for name, data in mine.items():
        assert (u / name).read_bytes() == data, name
    rec = json.loads((u / "run.json").read_text())
    st = rec["stages"]
    assert st["campaign"]["status"] == "failed"
    assert {k: st[k]["status"] for k in ("preprocess", "fit", "predict", "impact")} == \
        dict.fromkeys(("preprocess", "fit", "predict", "impact"), "blocked")
    assert st["preprocess"]["kept"] == ["means.nc"] and st["fit"]["kept"] == ["fit.json",
                                                                            "fit.nc"]
    assert rec["summary"] == {}                      # the user's fit is not this run's result
    html = (u / "report.html").read_text()
    assert "fit.json was not made by the last run and is not shown" in html
    assert sorted(p.name for p in u.iterdir()) == sorted([*mine, "run.json", "report.html"])


def test_a_stage_that_stops_half_way_removes_only_what_it_wrote(tmp_path):
    """A two-file stage that wrote its first file and failed: that file goes (it was written
    in this call), a file of its second name that was there before stays."""
    from gprm.run.engine import Stage, run_stages

    def half(run, opts, step):
        from gprm._io import write_text_atomic

        write_text_atomic(run / "one.txt", "written now")   # as gprm's stages write
        raise RuntimeError("disk trouble")

    (tmp_path / "two.txt").write_text("the user's")
    stages = (Stage("s", "S", (), ("one.txt", "two.txt"), lambda o: {}, half),)
    res = run_stages(tmp_path, SimpleNamespace(seed=0), stages, report_html=False)
    assert [r.status for r in res.records] == ["failed"]
    assert not (tmp_path / "one.txt").exists()
    assert (tmp_path / "two.txt").read_text() == "the user's"
    assert json.loads((tmp_path / "run.json").read_text())["stages"]["s"]["kept"] == \
        ["two.txt"]


@pytest.mark.slow
@pytest.mark.parametrize("argv", [
    ["predict", "{run}/fit.json", "--out", "{run}/fit.nc"],
    ["predict", "{run}", "--out", "{run}/fit.nc"],
    ["synth", "telemetry", "{run}/fit.json", "--out", "{run}/fit.nc"],
], ids=["predict", "predict-run-folder", "synth-telemetry"])
def test_no_command_replaces_the_sidecar_of_the_fit_it_reads(run_copy, tmp_path, argv):
    before = _snapshot(run_copy)
    r = _invoke([a.format(run=run_copy) for a in argv], tmp_path)
    assert r.exit_code == 2, r.output
    line = _one_error_line(r.output)
    assert f"--out {run_copy}/fit.nc: would overwrite the sidecar of the input " \
           f"{run_copy}/fit.json" in line
    assert _snapshot(run_copy) == before


def test_check_outputs_counts_a_json_inputs_sidecar_as_an_input(tmp_path):
    from gprm._io import check_outputs

    fit = tmp_path / "f.json"
    with pytest.raises(GprmInputError, match="sidecar of the input") as e:
        check_outputs({tmp_path / "f.nc": "--out"}, inputs=[fit])
    assert e.value.field == "--out"
    check_outputs({tmp_path / "g.nc": "--out"}, inputs=[fit])          # another name: fine


# ----------------------------------------------------------------------------- 6. damaged input

def test_a_damaged_netcdf_ends_in_one_line_within_seconds(tmp_path):
    """One inverted byte makes the NetCDF library loop forever on this file; gprm reads it in
    a child process with a time limit and names it."""
    t0 = time.monotonic()
    r = _gprm(["impact", "paper", str(DAMAGED), "--out", "i.json"], tmp_path,
              env=_env(tmp_path, GPRM_READ_TIMEOUT="3"), timeout=120)
    took = time.monotonic() - t0
    assert r.returncode == 2, r.stdout + r.stderr
    line = _one_error_line(r.stderr)
    assert line.startswith(f"gprm: error: {DAMAGED}: cannot be read as telemetry NetCDF")
    assert took < 60, took
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _process_state(pid: int) -> str:
    """The kernel's view of a process that does not stop (state, signal masks, threads,
    children), for a failure message."""
    try:
        status = Path(f"/proc/{pid}/status").read_text().splitlines()
    except OSError:
        return "no /proc entry"
    keep = ("State", "Threads", "SigPnd", "ShdPnd", "SigBlk", "SigIgn", "SigCgt")
    lines = [x for x in status if x.split(":")[0] in keep]
    for k in _children(pid):
        with contextlib.suppress(OSError):
            st = Path(f"/proc/{k}/status").read_text().splitlines()
            lines.append(f"child {k}: " + " ".join(x for x in st if x.startswith("State")))
    return "; ".join(lines)


def _children(pid: int) -> list[int]:
    try:
        text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    except OSError:
        return []
    return [int(x) for x in text.split()]


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs Linux /proc")
def test_ctrl_c_stops_a_read_that_hangs(tmp_path):
    # Ctrl-C at a terminal reaches a process whose SIGINT is the default; a suite run in the
    # background (`cmd &` in a script, nohup) hands its children SIGINT ignored, and gprm
    # keeps a signal its caller ignores, so the child gets the terminal's disposition here.
    # faulthandler: should the process not stop, SIGABRT makes it print where it is.
    p = subprocess.Popen([sys.executable, "-m", "gprm.cli", "impact", "paper", str(DAMAGED),
                          "--out", "i.json"], cwd=tmp_path,
                         env=_env(tmp_path, GPRM_READ_TIMEOUT="600", PYTHONFAULTHANDLER="1"),
                         preexec_fn=_default_sigint,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        kids: list[int] = []
        while time.monotonic() < deadline and p.poll() is None:
            kids = _children(p.pid)
            if kids:                      # the child reading the file is running (stuck)
                break
            time.sleep(0.05)
        if p.poll() is not None:
            pytest.skip("this NetCDF library does not hang on the damaged file")
        time.sleep(1.0)
        p.send_signal(signal.SIGINT)
        try:
            out, err = p.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            state = _process_state(p.pid)
            p.send_signal(signal.SIGABRT)
            out, err = p.communicate(timeout=20)
            pytest.fail(f"still running 20 s after SIGINT; {state}; its stacks:\n{err}")
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate()
    assert p.returncode == 130, out + err
    assert _one_error_line(err) == "gprm: interrupted; unfinished outputs were not written"
    for k in kids:                        # the stuck reader was stopped too
        assert not Path(f"/proc/{k}").exists() or \
            "zombie" in Path(f"/proc/{k}/status").read_text().lower()


def test_a_reader_that_loops_or_crashes_is_an_input_error(tmp_path, monkeypatch):
    """The same guard, independent of which bytes make this NetCDF library fail: the read
    loops (stopped at the time limit) or crashes the process that does it."""
    import gprm._io as io
    from gprm.params import paper

    def nc(name):
        p = tmp_path / name
        make_means(paper(), seed=1).to_netcdf(p)
        return p

    monkeypatch.setenv("GPRM_READ_TIMEOUT", "0.5")
    monkeypatch.setattr(io, "_read_everything", lambda path: time.sleep(60))
    t0 = time.monotonic()
    with pytest.raises(GprmInputError, match=r"did not finish within 0.5\d* s") as e:
        io.open_netcdf(nc("slow.nc"), what="mean-signals file")
    assert time.monotonic() - t0 < 10 and e.value.source.endswith("slow.nc")
    monkeypatch.setattr(io, "_read_everything",
                        lambda path: os.kill(os.getpid(), signal.SIGSEGV))
    with pytest.raises(GprmInputError, match=r"crashed on it \(signal 11"):
        io.open_netcdf(nc("crash.nc"), what="mean-signals file")
    monkeypatch.undo()
    assert "mean" in io.open_netcdf(nc("fine.nc"))          # a sound file reads as before


def test_a_file_without_a_netcdf_signature_is_refused_at_once(tmp_path):
    from gprm._io import open_netcdf

    p = tmp_path / "x.nc"
    p.write_bytes(b"PK\x03\x04 a zip file")
    with pytest.raises(GprmInputError, match="is not a NetCDF file"):
        open_netcdf(p)


# ----------------------------------------------------------------------------- 7. full disk

def _fsize_limit(nbytes: int):
    def limit():
        import resource

        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)     # the write gets EFBIG instead
        resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, nbytes))
    return limit


@pytest.fixture(scope="module")
def small_inputs(tmp_path_factory):
    from gprm.campaign.synth import SynthConfig, synth_campaign

    d = tmp_path_factory.mktemp("fault-inputs")
    synth_campaign(seed=3, config=SynthConfig(n_runs=2, n_noise=1, nonlinear=False)
                   ).to_netcdf(d / "c.nc")
    return d


@pytest.mark.parametrize("argv, out", [
    (["synth", "campaign", "--runs", "2", "--noise-runs", "1", "--no-nonlinear", "--out",
      "w/c.nc"], "w/c.nc"),
    (["preprocess", "{inputs}/c.nc", "--out", "w/m.nc"], "w/m.nc"),
    (["run", "{inputs}/c.nc", *SMALL, "--out", "w"], "w/campaign.nc"),
], ids=["synth-campaign", "preprocess", "run"])
def test_a_file_size_limit_is_one_line_naming_the_file_and_leaves_nothing(
        small_inputs, tmp_path, argv, out):
    """``ulimit -f 100``: the NetCDF library says only "HDF error"; gprm names the output and
    the cause, and leaves no partial or temporary file."""
    (tmp_path / "w").mkdir()
    r = _gprm([a.format(inputs=small_inputs) for a in argv], tmp_path, env=_env(tmp_path),
              timeout=300, preexec_fn=_fsize_limit(100 * 1024))
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert f"{out}: cannot be written: file too large" in last, r.stderr
    assert r.returncode == (1 if argv[0] == "run" else 2), r.stderr
    assert _parts(tmp_path) == []
    assert not (tmp_path / out).exists()


def _can_mount() -> bool:
    if shutil.which("unshare") is None or not hasattr(os, "geteuid") or os.geteuid() != 0:
        return False
    probe = subprocess.run(["unshare", "-m", "--propagation", "private", "sh", "-c",
                            "mount -t tmpfs -o size=64k tmpfs /mnt 2>/dev/null || "
                            "mount -t tmpfs -o size=64k tmpfs /tmp"],
                           capture_output=True, timeout=30)
    return probe.returncode == 0


CAN_MOUNT = _can_mount()


def _in_mount_ns(tmp_path: Path, folder: Path, options: str, args: list[str],
                 timeout: float = 300):
    """``gprm ARGS`` in a private mount namespace where ``folder`` is a tmpfs mounted with
    ``options`` (a read-only or a tiny file system; needs root and unshare)."""
    gprm_cmd = " ".join(f"'{a}'" for a in [sys.executable, "-m", "gprm.cli", *args])
    script = f"mount -t tmpfs -o {options} tmpfs '{folder}' && exec {gprm_cmd}"
    return subprocess.run(["unshare", "-m", "--propagation", "private", "sh", "-c", script],
                          cwd=tmp_path, env=_env(tmp_path), capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.skipif(not CAN_MOUNT, reason="needs root and unshare to mount a tmpfs")
def test_a_full_file_system_is_one_line_naming_the_file(tmp_path):
    full = tmp_path / "full"
    full.mkdir()
    r = _in_mount_ns(tmp_path, full, "size=64k", ["synth", "campaign", "--runs", "2",
                                                   "--noise-runs", "1", "--no-nonlinear",
                                                   "--out", str(full / "c.nc")])
    assert r.returncode == 2, r.stderr
    assert _one_error_line(r.stderr) == \
        f"gprm: error: {full}/c.nc: cannot be written: no space left on the device"
    assert list(full.iterdir()) == []       # the mount is gone: the real folder is empty


def test_write_failures_name_their_cause(tmp_path, monkeypatch):
    """The causes as the atomic writer reports them, whatever the library raised."""
    import gprm._io as io

    out = tmp_path / "o.nc"
    for err, cause in ((OSError(errno.ENOSPC, "No space left on device"), "no space left"),
                       (OSError(errno.EROFS, "Read-only file system"), "read-only file system"),
                       (OSError(errno.EFBIG, "File too large"), "file too large")):
        with pytest.raises(GprmOutputError, match=f"o.nc: cannot be written: {cause}"):
            with io.atomic_path(out) as tmp:
                tmp.write_text("half")
                raise err
    monkeypatch.setattr(io.os, "statvfs", lambda p: type(
        "S", (), {"f_bavail": 0, "f_frsize": 4096, "f_flag": 0})())
    with pytest.raises(GprmOutputError, match="no space left on the device"):
        with io.atomic_path(out):
            raise RuntimeError("NetCDF: HDF error")
    with pytest.raises(ValueError, match="a bug"):          # not a write failure: as it was
        with io.atomic_path(out):
            raise ValueError("a bug")
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- 8. read-only

@pytest.mark.skipif(not CAN_MOUNT, reason="needs root and unshare to mount a tmpfs")
@pytest.mark.parametrize("command", ["run", "demo"])
def test_a_read_only_output_folder_is_one_line_naming_it(small_inputs, tmp_path, command):
    """A read-only file system (root ignores chmod, so a read-only tmpfs is mounted in a
    private mount namespace): refused before any work, naming the folder and the cause."""
    ro = tmp_path / "ro"
    ro.mkdir()
    args = (["run", str(small_inputs / "c.nc")] if command == "run" else ["demo"]) + \
        [*SMALL, "--out", str(ro / "r")]
    r = _in_mount_ns(tmp_path, ro, "ro", args)
    assert r.returncode == 2, r.stdout + r.stderr
    line = _one_error_line(r.stderr)
    assert line == (f"gprm: error: --out {ro}/r: cannot be written: cannot create files in "
                    f"{ro} (Read-only file system)")


# ----------------------------------------------------------------------------- 9. stopped

#: in the subprocess: once the temporary file of predict_piezo1.nc is written (whole), the
#: process sends itself SIGTERM, as a batch system or `kill` would, before it is renamed
SIGTERM_DURING_PREDICT = """
import os, signal, time, sys
sys.argv = ["gprm", *sys.argv[1:]]
import xarray
_write = xarray.Dataset.to_netcdf
def to_netcdf(self, path=None, *a, **k):
    out = _write(self, path, *a, **k)
    if path is not None and os.path.basename(str(path)).startswith(".predict_piezo1.nc."):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(60)
    return out
xarray.Dataset.to_netcdf = to_netcdf
"""


@pytest.mark.slow
def test_sigterm_during_a_run_leaves_no_temporary_file_and_a_rerun_finishes(run_copy,
                                                                            tmp_path):
    (run_copy / "predict_piezo1.nc").unlink()             # the rerun redoes the predictions
    args = ["run", str(run_copy / "campaign.nc"), *SMALL, "--out", str(run_copy)]
    t0 = time.monotonic()
    r = _gprm(args, tmp_path, env=_env(tmp_path), timeout=300, code=SIGTERM_DURING_PREDICT)
    assert time.monotonic() - t0 < 250
    assert r.returncode == 128 + signal.SIGTERM, r.stderr
    assert r.stderr.strip().splitlines()[-1] == \
        "gprm: stopped by SIGTERM; unfinished outputs were not written"
    shown = r.stdout + r.stderr              # the stage is shown as run.json records it
    assert ": interrupted" in shown and not any(ln.endswith(": failed")
                                                for ln in shown.splitlines()), shown
    assert _parts(run_copy) == []
    rec = json.loads((run_copy / "run.json").read_text())
    assert rec["stages"]["predict"]["status"] == "interrupted"
    r = _invoke(args, tmp_path)                            # the rerun finishes the chain
    assert r.exit_code == 0, r.output
    assert (run_copy / "predict_piezo1.nc").is_file() and _parts(run_copy) == []


@pytest.mark.slow
def test_a_rerun_removes_the_temporary_files_a_killed_gprm_left_and_nothing_else(run_copy,
                                                                               tmp_path):
    from gprm._io import _host_tag

    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    dead = int(done.stdout)                                # a PID no process has now
    host = _host_tag()
    stale = [f".predict_piezo1.nc.gprm-{host}-{dead}-abcd1234.part"]
    alive = f".predict.nc.gprm-{host}-{os.getppid()}-zz11yy22.part"   # its writer runs
    users = [".notes.part", "draft.part", ".fit.json.backup.part", "notes.txt",
             ".notes.txt.abcd1234.part",                   # not a run file's name
             ".predict_piezo1.nc.k2j4_x9q.part"]           # like gprm 0.1.0's: not provably
    for name in [*stale, alive, *users]:
        (run_copy / name).write_text("x")
    r = _invoke(["run", run_copy / "campaign.nc", *SMALL, "--out", run_copy], tmp_path)
    assert r.exit_code == 0, r.output
    for name in stale:
        assert not (run_copy / name).exists(), name
    for name in [alive, *users]:
        assert (run_copy / name).read_text() == "x", name


def test_an_interrupted_write_removes_its_temporary_file(tmp_path):
    from gprm._io import atomic_path
    from gprm.cli import Terminated

    out = tmp_path / "o.txt"
    with pytest.raises(Terminated):
        with atomic_path(out) as tmp:
            tmp.write_text("half")
            assert ".o.txt.gprm-" in tmp.name
            raise Terminated(signal.SIGTERM)
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- 10. options

@pytest.fixture
def means_file(tmp_path, monkeypatch):
    from gprm.params import paper

    p = tmp_path / "m.nc"
    make_means(paper(), seed=2).to_netcdf(p)
    monkeypatch.chdir(tmp_path)
    return p


FIT = ["--starts", "4", "--chunk", "2", "--max-iter", "3", "--band-samples", "0",
       "--workers", "0"]


def test_a_nan_bound_is_refused_before_any_work_and_leaves_no_checkpoint(means_file,
                                                                         tmp_path):
    (tmp_path / "p.toml").write_text('[parameters]\nk_lr = { value = "1.64e6 N/m", '
                                     'upper = nan, fit = true }\n')
    r = _invoke(["fit", "m.nc", "--out", "f.json", "--params", "p.toml", *FIT], tmp_path)
    assert r.exit_code == 2, r.output
    assert _one_error_line(r.output) == ("gprm: error: p.toml: field 'k_lr': upper bound is "
                                         "NaN; give a number (-inf or inf for none)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.nc", "p.toml"]


def test_a_refusal_after_chunks_were_saved_removes_the_folder_it_created(means_file,
                                                                          tmp_path,
                                                                          monkeypatch):
    """The fit refuses its input half-way (after a chunk of starts was checkpointed): the
    checkpoint folder this call created goes; one that was there before keeps its chunks."""
    from gprm.fit import engine

    save = engine.Checkpoints.save

    def save_then_refuse(self, res):
        save(self, res)
        raise GprmInputError("refused half-way", source="m.nc", field="x")

    monkeypatch.setattr(engine.Checkpoints, "save", save_then_refuse)
    r = _invoke(["fit", "m.nc", "--out", "f.json", *FIT], tmp_path)
    assert r.exit_code == 2 and "refused half-way" in r.output, r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.nc"]
    engine.prepare_checkpoint_folder(tmp_path / "ck")  # there before: a resumed fit's
    r = _invoke(["fit", "m.nc", "--out", "f.json", *FIT, "--checkpoint", "ck"], tmp_path)
    assert r.exit_code == 2
    assert len(list((tmp_path / "ck").glob("chunk_*.npz"))) == 1


def test_band_samples_beyond_the_memory_are_refused_before_the_fit(means_file, tmp_path,
                                                                    monkeypatch):
    import gprm.fit.api
    import gprm.resources

    monkeypatch.setattr(gprm.resources, "available_memory", lambda: 200_000_000)
    monkeypatch.setattr(gprm.fit.api, "identify", lambda *a, **k: pytest.fail("fit ran"))
    args = ["fit", "m.nc", "--out", "f.json", *FIT[:-4], "--workers", "0"]
    r = _invoke([*args, "--band-samples", "1000"], tmp_path)
    assert r.exit_code == 2, r.output
    line = _one_error_line(r.output)
    assert line.startswith("gprm: error: --band-samples: 1000 band samples of ")
    n = int(line.rsplit("fits is ", 1)[1])
    assert 0 < n < 1000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.nc"]


def test_a_stop_signal_the_caller_ignores_stays_ignored():
    """``nohup gprm run ...`` must survive a hangup: an ignored SIGHUP is left ignored, while
    SIGTERM raises and every handler is restored afterwards."""
    from gprm.cli import Terminated, stop_signals_raise

    old = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    term = signal.getsignal(signal.SIGTERM)
    try:
        with pytest.raises(Terminated):
            with stop_signals_raise():
                assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(5)
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
        assert signal.getsignal(signal.SIGTERM) == term
    finally:
        signal.signal(signal.SIGHUP, old)


# ------------------------------------------------------- issue 22: the fit's sidecar is bound

@pytest.fixture(scope="module")
def two_fits(tmp_path_factory):
    """Two small fits (different seeds) with draws in their sidecars, written by write_fit."""
    from gprm.fit.api import FitOptions, run_fit
    from gprm.params import paper

    d = tmp_path_factory.mktemp("sidecars")
    means = make_means(paper(), seed=5)
    for name, seed in (("a", 2), ("b", 3)):
        (d / name).mkdir()
        run_fit(means, FitOptions(starts=3, chunk=3, max_iter=6, band_samples=5, seed=seed,
                                  uncertainty="laplace-prior")).write(d / name / "fit.json")
    return d


def _flip(p: Path, other: Path):
    b = bytearray(p.read_bytes())
    b[len(b) // 2] ^= 0x01
    p.write_bytes(bytes(b))


@pytest.mark.parametrize("damage, problem", [
    (lambda p, o: p.write_bytes(p.read_bytes()[: p.stat().st_size // 2]), "does not match"),
    (_flip, "does not match"),
    (lambda p, o: p.write_bytes(b""), "does not match"),
    (lambda p, o: p.write_bytes(b"not a NetCDF file at all"), "does not match"),
    (lambda p, o: shutil.copyfile(o, p), "does not match"),          # another fit's sidecar
    (lambda p, o: p.unlink(), "is missing"),
], ids=["truncated", "bit-flipped", "empty", "foreign", "another-fits", "missing"])
def test_a_sidecar_that_is_not_the_fits_own_is_refused_unless_ignored(two_fits, tmp_path,
                                                                      damage, problem):
    import xarray as xr

    work = tmp_path / "w"
    shutil.copytree(two_fits, work)
    fit, side = work / "a" / "fit.json", work / "a" / "fit.nc"
    good = _invoke(["predict", fit, "--out", tmp_path / "good.nc", "--samples", "40"],
                   tmp_path)
    assert good.exit_code == 0, good.output
    damage(side, work / "b" / "fit.nc")
    r = _invoke(["predict", fit, "--out", tmp_path / "p.nc", "--samples", "40"], tmp_path)
    line = _one_error_line(r.output)
    assert r.exit_code == 2 and str(fit) in line and str(side) in line and problem in line, line
    assert "--ignore-sidecar" in line and not (tmp_path / "p.nc").exists()
    r = _invoke(["predict", fit, "--out", tmp_path / "p.nc", "--samples", "40",
                 "--ignore-sidecar"], tmp_path)
    assert r.exit_code == 0, r.output
    assert "note: --ignore-sidecar: sidecar fit.nc ignored" in r.output, r.output
    ds = xr.open_dataset(tmp_path / "p.nc")
    assert "fit.nc ignored" in ds.attrs["sidecar_ignored"]
    assert "fit.nc ignored" in ds.attrs["uncertainty"]
    assert "sidecar_ignored" not in xr.open_dataset(tmp_path / "good.nc").attrs


def test_the_fit_records_its_sidecars_checksum_and_old_fits_read_with_a_warning(two_fits,
                                                                                tmp_path):
    import hashlib

    work = tmp_path / "w"
    shutil.copytree(two_fits, work)
    fit = work / "a" / "fit.json"
    doc = json.loads(fit.read_text())
    assert doc["sidecar"] == {"name": "fit.nc", "sha256": hashlib.sha256(
        (work / "a" / "fit.nc").read_bytes()).hexdigest()}
    del doc["sidecar"]                     # a fit.json of an older gprm
    fit.write_text(json.dumps(doc))
    r = _gprm(["predict", str(fit), "--out", str(tmp_path / "p.nc"), "--samples", "20"],
              tmp_path, env=_env(tmp_path), timeout=300)
    assert r.returncode == 0, r.stderr
    warn = [ln for ln in r.stderr.splitlines() if ln.startswith("gprm: warning:")]
    assert len(warn) == 1 and "records no checksum of its sidecar" in warn[0], r.stderr
