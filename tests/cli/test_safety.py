"""Never destroy user data, never show a traceback, refuse what would not fit in memory,
keep the Dask cluster local (issue #13 items 4-7)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from gprm.cli import app
from gprm.errors import GprmInputError
from gprm.fit.engine import (CHECKPOINT_MARKER, Checkpoints, remove_checkpoints, run_multistart,
                             starts_memory)
from gprm.fit.starts import LMOptions, MultiStartOptions

sys.path.insert(0, str(Path(__file__).parents[1] / "fit"))
from means_factory import make_means  # noqa: E402


@pytest.fixture(scope="module")
def obj():
    from gprm.fit.objective import Objective, fit_data_from_means
    from gprm.params import paper

    return Objective.create(fit_data_from_means(make_means(paper(), seed=2)), paper())


OPTS = MultiStartOptions(n_starts=4, seed=5, chunk_size=2, lm=LMOptions(max_iter=4))


# ----------------------------------------------------------------------------- checkpoints

def test_an_unmarked_folder_with_files_is_refused_and_untouched(tmp_path):
    (tmp_path / "thesis.tex").write_text("years of work")
    with pytest.raises(GprmInputError, match="not a gprm checkpoint folder"):
        Checkpoints(tmp_path, "f")
    assert [p.name for p in tmp_path.iterdir()] == ["thesis.tex"]
    remove_checkpoints(tmp_path)                       # unmarked: nothing happens
    assert (tmp_path / "thesis.tex").read_text() == "years of work"


def test_removal_deletes_only_gprms_files(obj, tmp_path):
    ck = tmp_path / "new" / "ckpt"
    run_multistart(obj, OPTS, checkpoint_dir=ck)
    assert (ck / CHECKPOINT_MARKER).is_file() and len(list(ck.glob("chunk_*.npz"))) == 2
    (ck / "notes.txt").write_text("mine")              # a user file put there meanwhile
    remove_checkpoints(ck)
    assert [p.name for p in ck.iterdir()] == ["notes.txt"]   # folder kept: not empty
    (ck / "notes.txt").unlink()
    run_multistart(obj, OPTS, checkpoint_dir=ck)       # empty folder: adopted, not created
    remove_checkpoints(ck)
    assert ck.is_dir() and list(ck.iterdir()) == []    # a folder gprm did not create stays
    ck2 = tmp_path / "fresh"
    run_multistart(obj, OPTS, checkpoint_dir=ck2)
    remove_checkpoints(ck2)
    assert not ck2.exists()                            # gprm created it: removed


def test_a_damaged_chunk_is_run_again_with_the_same_result(obj, tmp_path):
    ck = tmp_path / "ck"
    full = run_multistart(obj, OPTS, checkpoint_dir=ck)
    chunk = sorted(ck.glob("chunk_*.npz"))[0]
    chunk.write_bytes(chunk.read_bytes()[:100])        # truncated
    again = run_multistart(obj, OPTS, checkpoint_dir=ck)
    for f in ("x0", "x", "chi2", "iterations", "status"):
        np.testing.assert_array_equal(getattr(full, f), getattr(again, f))
    assert np.load(chunk, allow_pickle=False)["x"].shape[0] == 2   # replaced by a whole one


def test_fit_cli_keeps_user_files_and_leaves_no_folder_on_refusal(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    make_means(__import__("gprm.params", fromlist=["paper"]).paper(), seed=2).to_netcdf("m.nc")
    args = ["fit", "m.nc", "--out", "f.json", "--starts", "2", "--chunk", "2", "--max-iter",
            "3", "--band-samples", "0", "--workers", "0"]
    # refused inside the fit (window outside the data): no checkpoint folder left behind
    r = CliRunner().invoke(app, args + ["--window", "0.5,0.6"])
    assert r.exit_code == 2 and not Path("f.json.ckpt").exists(), r.output
    # a successful fit with --checkpoint . keeps every file of the folder
    (tmp_path / "keep.txt").write_text("x")
    r = CliRunner().invoke(app, args + ["--checkpoint", "."])
    assert r.exit_code == 2 and "--checkpoint" in r.output  # '.' holds files: refused
    r = CliRunner().invoke(app, args + ["--checkpoint", "ck"])
    assert r.exit_code == 0, r.output
    assert not Path("ck").exists() and Path("keep.txt").read_text() == "x"
    assert Path("f.json").is_file() and Path("f.nc").is_file()


# ----------------------------------------------------------------------------- Dask

def test_local_cluster_binds_to_localhost_without_dashboard(obj, monkeypatch):
    import distributed

    seen = {}

    class FakeCluster:
        scheduler = None
        security = "the cluster's credentials"

        def __init__(self, **kw):
            seen.update(kw)

        def sync(self, fn, *args):
            seen["stopped_http"] = True

        def close(self):
            pass

    class FakeFuture:
        def __init__(self, v):
            self.v = v

        def result(self):
            return self.v

    class FakeClient:
        def __init__(self, cluster, **kw):
            seen["client_of"] = cluster
            seen.update({f"client_{k}": v for k, v in kw.items()})

        def submit(self, fn, task, pure=False):
            return FakeFuture(fn(task))

        def run(self, fn):
            seen["ran"] = fn.__name__

        def close(self):
            pass

    monkeypatch.setattr(distributed, "LocalCluster", FakeCluster)
    monkeypatch.setattr(distributed, "Client", FakeClient)
    monkeypatch.setattr(distributed, "as_completed", lambda futs: futs)
    ref = run_multistart(obj, OPTS)
    # the fit's own workers without a dashboard: a process pool, no Dask cluster at all
    # (nothing listens; stop 36)
    out = run_multistart(obj, OPTS, workers=2)
    assert seen == {}
    np.testing.assert_array_equal(ref.x, out.x)
    # the cluster the studies start (benchmarks/_studies.py) and a dashboard needs
    from gprm.fit.engine import local_cluster

    local_cluster(2)
    # no dashboard: distributed would serve one on 8787 for dashboard_address=None (issue 22)
    assert seen["host"] == "127.0.0.1" and seen["dashboard_address"] == "127.0.0.1:0"
    assert seen["scheduler_kwargs"] == {"dashboard": False} and seen["stopped_http"]
    # TLS with temporary credentials (issue 22)
    from distributed.security import Security

    assert seen["protocol"] == "tls://" and isinstance(seen["security"], Security)
    assert seen["security"].require_encryption
    from gprm.fit.commands import dask_dashboard

    seen.clear()
    with dask_dashboard("127.0.0.1:8787"):
        out = run_multistart(obj, OPTS, workers=2)
    assert seen["dashboard_address"] == "127.0.0.1:8787"
    assert seen["protocol"] == "tls://"
    assert seen["client_security"] == FakeCluster.security     # gprm's client uses them
    np.testing.assert_array_equal(ref.x, out.x)
    assert "stopped_http" not in seen and "ran" not in seen
    seen.clear()
    out = run_multistart(obj, OPTS, scheduler="tcp://10.1.2.3:8786")   # an existing cluster
    assert seen == {"client_of": "tcp://10.1.2.3:8786"}                 # no local cluster
    np.testing.assert_array_equal(ref.x, out.x)


# ----------------------------------------------------------------------------- crashes

def test_unexpected_error_is_one_line_and_a_log(tmp_path, monkeypatch):
    import gprm.params

    def boom(*a, **k):
        raise RuntimeError("something broke")

    monkeypatch.setattr(gprm.params, "load_params", boom)
    monkeypatch.setenv("GPRM_LOG_DIR", str(tmp_path / "logs"))
    monkeypatch.delenv("GPRM_DEBUG", raising=False)
    r = CliRunner().invoke(app, ["params"])
    lines = r.output.strip().splitlines()
    assert r.exit_code == 1 and len(lines) == 1, r.output
    assert "Traceback" not in r.output and "RuntimeError: something broke" in lines[0]
    log = Path(re.search(r"traceback in (\S+)", lines[0]).group(1))
    assert log.parent == tmp_path / "logs"
    text = log.read_text()
    assert "Traceback" in text and "something broke" in text and "gprm params" in text
    r = CliRunner().invoke(app, ["--debug", "params"])
    assert r.exit_code == 1 and "Traceback" in r.output and "something broke" in r.output


# ----------------------------------------------------------------------------- memory

def test_memory_guard_names_the_largest_value_that_fits(monkeypatch):
    import gprm.resources as res
    from gprm.resources import check_memory, largest_that_fits

    avail = 8_000_000_000
    per = starts_memory(1, 23)
    n = largest_that_fits(per, available=avail)
    check_memory(n, per, field="--starts", what="x", available=avail)        # fits
    with pytest.raises(GprmInputError) as e:
        check_memory(n + 1, per, field="--starts", what="x", available=avail)
    assert e.value.field == "--starts" and f"fits is {n}" in str(e.value)
    monkeypatch.setattr(res, "available_memory", lambda: avail)
    r = CliRunner().invoke(app, ["simulate", "--out", "unused.nc", "--rate", "1e12"])
    assert r.exit_code == 2, r.output
    rate_max = float(re.search(r"fits is (\S+) Hz", r.output).group(1))
    samples = rate_max * 1.2e-3 + 1
    assert 50e6 + 2000 * samples <= 0.8 * avail * 1.0001
    assert 50e6 + 2000 * samples * 1.01 > 0.8 * avail
    # impact's band samples (about 554 kB each, measured): refused before the model loads
    r = CliRunner().invoke(app, ["impact", "paper", "unused.nc", "--out", "unused.json",
                                 "--samples", "1000000"])
    assert r.exit_code == 2 and "--samples" in r.output, r.output
    n_max = int(re.search(r"fits is (\d+)", r.output).group(1))
    assert 250e6 + 600e3 * n_max <= 0.8 * avail < 250e6 + 600e3 * (n_max + 1)


# ----------------------------------------------------------------------------- outputs

def test_outputs_beside_inputs_are_fine_over_them_refused(tmp_path):
    from gprm._io import check_outputs, files_read_from

    run = tmp_path / "run"
    run.mkdir()
    (run / "fit.json").write_text("{}")
    (run / "report.html").write_text("<title>GPRM tip retraction</title> an old report")
    check_outputs({run / "report.html": "--out"},              # gprm's: a rerun replaces it
                  inputs=files_read_from(run, suffixes={".json"}))
    with pytest.raises(GprmInputError, match="would overwrite the input") as e:
        check_outputs({run / "fit.json": "--out"},
                      inputs=files_read_from(run, suffixes={".json"}))
    assert e.value.field == "--out"
    with pytest.raises(GprmInputError, match="also the output of --out"):
        check_outputs([(tmp_path / "a.nc", "--out"), (tmp_path / "./a.nc", "--whatif")])
    with pytest.raises(GprmInputError, match="holds|overwrite"):     # a folder over inputs
        check_outputs({}, inputs=[run / "fit.json"], folders={run: "--checkpoint"})
    assert sorted(p.name for p in run.iterdir()) == ["fit.json", "report.html"]


def test_an_unreachable_scheduler_is_an_input_error(obj, monkeypatch):
    import distributed

    def refuse(address):
        raise OSError(f"Timed out trying to connect to {address}")

    monkeypatch.setattr(distributed, "Client", refuse)
    with pytest.raises(GprmInputError, match="cannot connect to the Dask scheduler") as e:
        run_multistart(obj, OPTS, scheduler="tcp://127.0.0.1:1")
    assert e.value.field == "scheduler"


def _listening(pids) -> set[int]:
    import psutil

    ports = set()
    for pid in pids:
        try:
            for c in psutil.Process(pid).net_connections(kind="inet"):
                if c.status == psutil.CONN_LISTEN:
                    ports.add(c.laddr.port)
        except psutil.Error:
            pass
    return ports


def _port(address: str) -> int:
    return int(address.rsplit(":", 1)[1])


def test_the_real_local_cluster_listens_for_dask_only():
    """Issue 22: with the default settings the scheduler answered HTTP on 127.0.0.1:8787
    although --dashboard said "default: none". Started as gprm starts it, the cluster's
    processes listen on its Dask ports (scheduler, nannies, workers) and on nothing else: no
    dashboard, no HTTP endpoint at all."""
    import psutil
    from distributed import Client

    from gprm.fit.engine import _stop_http_server, local_cluster

    me = psutil.Process()
    before = _listening([me.pid])
    cluster = local_cluster(1)
    try:
        with Client(cluster) as client:
            client.run(_stop_http_server)
            assert client.submit(sum, [1, 2]).result() == 3           # the cluster works
            dask_ports = {_port(cluster.scheduler_address)}
            dask_ports |= {_port(a) for a in cluster.scheduler.workers}
            dask_ports |= {_port(n.address) for n in cluster.workers.values()}
            pids = [me.pid] + [c.pid for c in me.children(recursive=True)]
            ours = _listening(pids) - before
            assert 8787 not in ours
            assert ours == dask_ports, (ours, dask_ports)
    finally:
        cluster.close()


# A plain client, with no credentials or other temporary ones ("other"): refused (OSError: connection reset, certificate mismatch, timeout) or
# without a TLS context to try with (TypeError).
_INTRUDER = """
import sys
from distributed import Client
from distributed.security import Security
try:
    Client(sys.argv[1], timeout=5, security=Security.temporary() if sys.argv[2] == "other" else None).close()
    print("connected")
except (OSError, TypeError) as exc:
    print("refused", type(exc).__name__)
"""


def test_the_real_local_cluster_refuses_clients_without_its_credentials(obj):
    """Issue 22: the scheduler did not authenticate, so another user of the machine could
    connect a client and run code in gprm's workers. Started as gprm starts it, the cluster
    speaks TLS with temporary credentials: a client without them (plain TCP, TLS without a
    certificate, or with other temporary credentials) cannot connect; gprm's fit through it
    still works."""
    from distributed import Client

    from gprm.fit.engine import local_cluster

    cluster = local_cluster(1)
    try:
        address = cluster.scheduler_address
        assert address.startswith("tls://127.0.0.1:")
        # each from its own process, as another user's would be (and distributed 2024.8
        # leaves its client event loop unusable after a failed connection)
        for addr, creds in ((address.replace("tls://", "tcp://"), "none"), (address, "none"),
                            (address, "other")):
            proc = subprocess.run([sys.executable, "-c", _INTRUDER, addr, creds],
                                  capture_output=True, text=True, timeout=120)
            assert proc.stdout.startswith("refused"), (addr, creds, proc.stdout, proc.stderr)
        with Client(cluster) as client:                     # the cluster's own credentials
            assert client.submit(sum, [1, 2]).result() == 3
    finally:
        cluster.close()
    ref = run_multistart(obj, OPTS)
    from gprm.fit.commands import dask_dashboard

    with dask_dashboard("127.0.0.1:0"):                     # gprm's fit over TLS
        out = run_multistart(obj, OPTS, workers=1)
    np.testing.assert_array_equal(ref.x, out.x)


def test_a_dashboard_asked_for_is_served():
    import urllib.request

    from gprm.fit.engine import local_cluster

    cluster = local_cluster(1, dashboard="127.0.0.1:0")
    try:
        port = cluster.scheduler.http_server.port
        assert port != 8787
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=10) as r:
            assert r.status == 200
    finally:
        cluster.close()


# ----------------------------------------------------------------------------- others' files

def test_an_existing_file_gprm_did_not_write_is_never_replaced(tmp_path):
    """check_outputs refuses an output path that holds a file gprm does not recognise as its
    own (the user's notes, another tool's NetCDF), names it and leaves it as it was; gprm's
    own files, and those a record lists as gprm's (``own``), may be replaced."""
    import xarray as xr

    from gprm._io import check_outputs, write_json_atomic, write_netcdf_atomic

    ds = xr.Dataset({"v": ("t", np.arange(3.0))})
    theirs = tmp_path / "theirs.nc"
    ds.to_netcdf(theirs)                                  # another tool's NetCDF
    notes = tmp_path / "notes.json"
    notes.write_text('{"my": "notes"}')
    before = {p: p.read_bytes() for p in (theirs, notes)}
    for path in (theirs, notes):
        with pytest.raises(GprmInputError, match="not a file gprm wrote") as e:
            check_outputs({path: "--out"})
        assert e.value.source == str(path) and e.value.field == "--out"
    assert {p: p.read_bytes() for p in before} == before
    check_outputs({theirs: "--out"}, own=[theirs])         # a run record says it is gprm's
    ours, ours_json = tmp_path / "ours.nc", tmp_path / "ours.json"
    write_netcdf_atomic(ds, ours)
    write_json_atomic(ours_json, {"format": "gprm-impact"})
    check_outputs({ours: "--out", ours_json: "--whatif", tmp_path / "new.nc": "--x"})


def test_written_by_gprm_reads_each_kind_by_its_content(tmp_path):
    import xarray as xr

    from gprm._io import written_by_gprm, write_netcdf_atomic

    cases = {"fit.json": '{"model": "gprm-3d", "chi2": 1}', "run.json": '{"versions": '
             '{"gprm": "0.1.0"}}', "w.json": '{"definition": "x", "ratios": {}}',
             "r.html": "<html><title>GPRM tip retraction: x</title>",
             "p.toml": "# gprm parameter file (values)\n[parameters]\n"}
    for name, text in cases.items():
        (tmp_path / name).write_text(text)
        assert written_by_gprm(tmp_path / name), name
    not_ours = {"a.json": '{"model": "other"}', "b.json": "[1, 2]", "c.json": "{broken",
                "d.html": "<title>my page</title>", "e.toml": "[parameters]\n",
                "f.txt": "written by gprm (gprm 0.1.0)",   # the mark outside a NetCDF file
                "g.nc": "notes: written by gprm users"}
    for name, text in not_ours.items():
        (tmp_path / name).write_text(text)
        assert not written_by_gprm(tmp_path / name), name
    assert not written_by_gprm(tmp_path / "missing.nc")
    ds = xr.Dataset({"v": ("t", np.arange(3.0))})
    write_netcdf_atomic(ds, tmp_path / "g.nc")
    assert written_by_gprm(tmp_path / "g.nc")
    assert written_by_gprm(tmp_path / "g.nc", chunk=5)       # the mark across chunk ends
    ds.to_netcdf(tmp_path / "x.nc")
    assert not written_by_gprm(tmp_path / "x.nc")
    write_netcdf_atomic(ds, tmp_path / "pred.nc4")       # by content, whatever the name
    assert written_by_gprm(tmp_path / "pred.nc4")
    (tmp_path / "w.txt").write_text('{"model": "gprm-3d"}')
    assert written_by_gprm(tmp_path / "w.txt")


def test_links_and_write_protected_files_are_not_replaced(tmp_path):
    import xarray as xr

    from gprm._io import check_outputs, write_netcdf_atomic

    ours = tmp_path / "p.nc"
    write_netcdf_atomic(xr.Dataset({"v": ("t", np.arange(3.0))}), ours)
    link = tmp_path / "link.nc"
    link.symlink_to(ours)
    dangling = tmp_path / "dangling.nc"
    dangling.symlink_to(tmp_path / "nowhere" / "x.nc")
    for path in (link, dangling):
        with pytest.raises(GprmInputError, match="symbolic link"):
            check_outputs({path: "--out"})
    ours.chmod(0o444)
    with pytest.raises(GprmInputError, match="write-protected"):
        check_outputs({ours: "--out"})
    assert link.is_symlink() and dangling.is_symlink()


def test_a_sidecar_name_held_by_a_campaign_is_refused(tmp_path):
    """`gprm fit --out campaign.json` beside a campaign.nc (which gprm wrote: a campaign)
    must not replace it: a sidecar is replaced only where the existing JSON names it."""
    import xarray as xr

    from gprm._io import check_outputs, write_netcdf_atomic

    side, doc = tmp_path / "campaign.nc", tmp_path / "campaign.json"
    write_netcdf_atomic(xr.Dataset({"v": ("t", np.arange(3.0))}), side)
    before = side.read_bytes()
    with pytest.raises(GprmInputError, match="not the sidecar of an existing campaign.json"):
        check_outputs({doc: "--out", side: "--out (its .nc sidecar)"}, sidecars=[(side, doc)])
    doc.write_text('{"model": "gprm-3d", "sidecar": {"name": "campaign.nc"}}')
    check_outputs({doc: "--out", side: "--out (its .nc sidecar)"}, sidecars=[(side, doc)])
    assert side.read_bytes() == before


def test_fit_cli_refuses_to_replace_a_campaign_by_its_sidecar(tmp_path, monkeypatch):
    from gprm._io import write_netcdf_atomic
    from gprm.params import paper

    monkeypatch.chdir(tmp_path)
    make_means(paper(), seed=2).to_netcdf("m.nc")
    write_netcdf_atomic(make_means(paper(), seed=3), "run1.nc")   # gprm's, not a sidecar
    before = Path("run1.nc").read_bytes()
    r = CliRunner().invoke(app, ["fit", "m.nc", "--out", "run1.json", "--starts", "2",
                                 "--chunk", "2", "--max-iter", "3", "--band-samples", "0",
                                 "--workers", "0"])
    assert r.exit_code == 2 and "run1.nc" in r.output and "Traceback" not in r.output
    assert Path("run1.nc").read_bytes() == before and not Path("run1.json").exists()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_local_workers_die_with_a_killed_parent():
    """`kill -9` of a `gprm fit` must not leave its local worker processes idling for ever
    (they hold a copy of the pipe the parent would close): they are killed with it."""
    import time

    script = ("import os, signal\n"
              "from gprm.fit.engine import local_pool\n"
              "pool = local_pool(2)\n"
              "pids = {pool.submit(os.getpid).result() for _ in range(6)}\n"
              "print(' '.join(map(str, pids)), flush=True)\n"
              "os.kill(os.getpid(), signal.SIGKILL)\n")
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                       timeout=120)
    pids = [int(p) for p in r.stdout.split()]
    assert pids, r.stderr

    def alive(pid):
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            return False
        return state not in ("Z", "X")      # a zombie is dead, only not yet reaped

    deadline = time.monotonic() + 20
    while any(alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(alive(p) for p in pids)


def test_a_rerun_after_an_interrupted_import_is_not_refused(tmp_path):
    """A campaign taken as it was (no gprm history: another tool's NetCDF) and a record that
    no longer lists it (the call that recorded it was interrupted before the stage): the
    rerun with the same source finds the run's copy identical to it and goes on."""
    import shutil

    import xarray as xr

    from gprm.campaign.synth import synth_campaign
    from gprm.run.api import check_run_outputs
    from gprm.run.options import RunOptions

    src = tmp_path / "plain.nc"
    ds = synth_campaign(seed=1)
    ds.attrs.pop("history", None)
    ds.to_netcdf(src)                                      # not written by gprm
    run = tmp_path / "run"
    run.mkdir()
    shutil.copyfile(src, run / "campaign.nc")              # the copy an earlier call took
    (run / "run.json").write_text('{"versions": {"gprm": "0.1.0"}, "stages": {}}')  # gone
    check_run_outputs(run, RunOptions(campaign=src))
    other = tmp_path / "other.nc"
    xr.Dataset({"v": ("t", np.arange(3.0))}).to_netcdf(other)
    with pytest.raises(GprmInputError, match="not a file gprm wrote"):
        check_run_outputs(run, RunOptions(campaign=other))  # a different source: not its copy


def test_a_failed_stage_removes_only_the_file_it_wrote(tmp_path):
    """A file someone puts at an output's name while the stage runs is not the stage's: a
    failed stage removes only what this process moved into place (written_here)."""
    from types import SimpleNamespace

    from gprm._io import write_text_atomic
    from gprm.run.engine import Stage, run_stages

    def mine_then_theirs(run, opts, step):
        write_text_atomic(run / "one.txt", "written now")
        (run / "two.txt").write_text("the user's, put there meanwhile")
        raise RuntimeError("disk trouble")

    stages = (Stage("s", "S", (), ("one.txt", "two.txt"), lambda o: {}, mine_then_theirs),)
    res = run_stages(tmp_path, SimpleNamespace(seed=0), stages, report_html=False)
    assert [r.status for r in res.records] == ["failed"]
    assert not (tmp_path / "one.txt").exists()
    assert (tmp_path / "two.txt").read_text() == "the user's, put there meanwhile"
