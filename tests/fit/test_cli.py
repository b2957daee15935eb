"""``gprm fit`` end to end on a small synthetic mean-signals file, and its input errors."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from gprm.fit.sandwich import Systematics
from typer.testing import CliRunner

from gprm.cli import app
from gprm.fit.files import load_fit
from gprm.params import paper

sys.path.insert(0, str(Path(__file__).parent))
from means_factory import make_means  # noqa: E402


@pytest.fixture(scope="module")
def means_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("fitcli") / "means.nc"
    make_means(paper(), seed=4).to_netcdf(path)
    return path


def test_gprm_fit_writes_json_and_sidecar(means_file, tmp_path):
    out = tmp_path / "fit.json"
    r = CliRunner().invoke(app, ["fit", str(means_file), "--out", str(out), "--starts", "3",
                                 "--chunk", "3", "--max-iter", "8", "--band-samples", "0",
                                 "--seed", "2", "--workers", "0", "--boot", "5"])
    assert r.exit_code == 0, r.output
    d = json.loads(out.read_text())
    assert d["starts"]["requested"] == 3 and d["seed"] == 2
    assert d["starts"]["max_iter"] == 8 and d["starts"]["chunk_size"] == 3
    from gprm.fit.api import FitOptions

    assert d["starts"]["stall_window"] == FitOptions().stall_window
    assert d["starts"]["stall_tol"] == FitOptions().stall_tol
    assert out.with_suffix(".nc").exists()
    assert not Path(str(out) + ".ckpt").exists()        # checkpoints removed after success
    # by default the 23 parameters of Table 3 and the three alignment offsets are fitted
    assert sum(p["fitted"] for p in d["parameters"].values()) == 26
    assert all(d["parameters"][n]["fitted"] for n in ("dt_x_head", "dt_y_base", "dt_y_head"))
    # every fit loads, with its identified set, intervals and posterior draws
    fm = load_fit(out)
    assert len(fm.names) == 26 and fm.has_uncertainty and fm.draws.shape == (400, 26)
    assert d["uncertainty"]["method"] == "sandwich"
    # the default method is built from the data: no generator constants, and it lists the
    # systematics it marginalised and the adequacy verdict
    assert "calibration" not in d["uncertainty"]
    syst = d["uncertainty"]["details"]["systematics"]
    assert set(syst) == set(d["signals"])
    assert all(v["gain_sd"] == pytest.approx(Systematics().gain_sd) for v in syst.values())
    assert d["uncertainty"]["adequacy"]["verdict"] in ("adequate", "not described")
    # every fitted parameter is in exactly one of the three lists
    lists = (d["identified"], d["leans_on_prior"], d["not_determined"])
    assert sorted(sum(lists, [])) == sorted(fm.names)
    # identified: narrow and mostly the data's variance; leaning: narrow, mostly the prior's
    share = {n: v["prior"] for n, v in d["uncertainty"]["details"]["variance_shares"].items()}
    for name in fm.names:
        narrow = d["parameters"][name]["contraction"] < d["uncertainty"]["identified_threshold"]
        mostly_prior = share[name] >= d["uncertainty"]["prior_share_threshold"]
        assert (name in d["identified"]) == (narrow and not mostly_prior), name
        assert (name in d["leans_on_prior"]) == (narrow and mostly_prior), name
    for name in fm.names:
        e = d["parameters"][name]
        # centred on the best fit: the best fit lies inside every interval
        assert e["interval"]["lower"] < e["value"] < e["interval"]["upper"], name
        assert e["identified"] == (name in d["identified"])
        assert e.get("leans_on_prior", False) == (name in d["leans_on_prior"])
    # issue 22: without a terminal (here) the progress is plain lines on stderr, and the line
    # after them tells the starts' best from the polished chi-square the report shows
    err = r.stderr if hasattr(r, "stderr") else r.output
    assert "fit: started" in err and "fit: 3/3 starts (100 %), best start chi2 (before " \
        "polish)" in err, err
    import numpy as np
    import xarray as xr

    with xr.open_dataset(out.with_suffix(".nc")) as side:
        best_start = float(np.nanmin(side["chi2"].values))
    assert f"best start chi2 {best_start:.6g} before the polish" in err, err
    assert f"chi2 {d['chi2']:.6g} after it" in err, err
    assert f"chi-square {d['chi2']:.6g}" in r.stdout                # the report's number
    # issue 22: an alignment offset starts at 0 (its registry default; the paper gives no
    # initial value), and the report says so instead of repeating the fitted value
    show = CliRunner().invoke(app, ["show", str(out)])
    assert show.exit_code == 0, show.output
    for name in ("dt_x_head", "dt_y_base", "dt_y_head"):
        e = d["parameters"][name]
        assert e["initial"] == 0.0 and e["value"] != 0.0, (name, e)
        line = next(ln for ln in show.stdout.splitlines() if ln.split()[:1] == [name])
        assert "(init = 0)" in line, line
    # the 23 of Table 3 keep the paper's initial values
    assert d["parameters"]["v2"]["initial"] == pytest.approx(2.8e-3)


@pytest.mark.parametrize("args, text", [
    (["--starts", "0"], "--starts': must be >= 1"),
    (["--sigma", "var"], "sem or std"),
    (["--window", "0.5,0.6"], "outside the data"),
    (["--window", "0.5 0.6"], "--window"),
    (["--seed", "-1"], "'--seed': must be >= 0, got -1"),
    (["--stall-window", "-1"], "--stall-window"),
    (["--uncertainty", "bootstrap"], "--uncertainty"),
    (["--prior-width", "-1"], "--prior-width"),
    (["--prior-width", "0"], "--prior-width"),
    (["--boot", "2"], "--boot"),
    (["--race", "3:x"], "Invalid value for '--race'"),
    (["--race", "6:5,3:2"], "--race: race points must come at increasing iterations"),
])
def test_gprm_fit_bad_options(means_file, tmp_path, args, text):
    r = CliRunner().invoke(app, ["fit", str(means_file), "--out", str(tmp_path / "f.json"),
                                 *args])
    assert r.exit_code == 2
    assert text in r.output
    assert not (tmp_path / "f.json").exists()


def test_gprm_fit_stall_window_reaches_the_starts(means_file, tmp_path):
    """--stall-window 2 with a huge tolerance stops every start after exactly 2 iterations;
    --stall-window 0 switches the rule off."""
    import xarray as xr

    base = ["--starts", "3", "--chunk", "3", "--max-iter", "8", "--band-samples", "0",
            "--workers", "0", "--prune-after", "0"]
    out = tmp_path / "a.json"
    r = CliRunner().invoke(app, ["fit", str(means_file), "--out", str(out), *base,
                                 "--stall-window", "2", "--stall-tol", "1e9"])
    assert r.exit_code == 0, r.output
    with xr.open_dataset(out.with_suffix(".nc")) as ds:
        assert set(ds["status"].values.astype(str)) == {"stalled"}
        assert set(ds["iterations"].values.tolist()) == {2}
    out0 = tmp_path / "b.json"
    r = CliRunner().invoke(app, ["fit", str(means_file), "--out", str(out0), *base,
                                 "--stall-window", "0"])
    assert r.exit_code == 0, r.output
    with xr.open_dataset(out0.with_suffix(".nc")) as ds:
        assert "stalled" not in set(ds["status"].values.astype(str))


def test_gprm_fit_race_reaches_the_starts_and_the_file_records_it(means_file, tmp_path):
    """--race 1:2 on 5 starts of one chunk: after one iteration only 2 go on, the other 3
    stop with status raced after exactly 1 iteration; fit.json counts them and records the
    schedule, and the report's starts line names them. Without --race nothing is raced."""
    import json

    import xarray as xr

    base = ["--starts", "5", "--chunk", "5", "--max-iter", "6", "--band-samples", "0",
            "--workers", "0", "--prune-after", "0", "--stall-window", "0"]
    out = tmp_path / "a.json"
    r = CliRunner().invoke(app, ["fit", str(means_file), "--out", str(out), *base,
                                 "--race", "1:2"])
    assert r.exit_code == 0, r.output
    with xr.open_dataset(out.with_suffix(".nc")) as ds:
        status = ds["status"].values.astype(str)
        assert (status == "raced").sum() == 3
        assert set(ds["iterations"].values[status == "raced"].tolist()) == {1}
    st = json.loads(out.read_text())["starts"]
    assert st["raced"] == 3 and st["race"] == [[1, 2]]
    assert "raced 3," in r.stdout
    out0 = tmp_path / "b.json"
    r = CliRunner().invoke(app, ["fit", str(means_file), "--out", str(out0), *base])
    assert r.exit_code == 0, r.output
    st0 = json.loads(out0.read_text())["starts"]
    assert st0["raced"] == 0 and st0["race"] == []


def test_gprm_fit_file_without_sigma(tmp_path):
    path = tmp_path / "nosigma.nc"
    make_means(paper(), seed=4).drop_vars(["sem", "std"]).to_netcdf(path)
    r = CliRunner().invoke(app, ["fit", str(path), "--out", str(tmp_path / "f.json")])
    assert r.exit_code == 2
    assert "sem" in r.output and str(path) in r.output


@pytest.mark.slow
def test_killed_run_resumes_to_the_identical_result(means_file, tmp_path):
    """``gprm fit`` killed (SIGKILL) after its first checkpoint, then rerun: the same files
    as an uninterrupted run (apart from timings)."""
    import os
    import signal
    import subprocess
    import time

    args = ["--starts", "6", "--chunk", "1", "--max-iter", "15", "--band-samples", "0",
            "--seed", "5", "--workers", "0"]
    gprm = str(Path(sys.executable).with_name("gprm"))
    ref = tmp_path / "ref.json"
    assert CliRunner().invoke(app, ["fit", str(means_file), "--out", str(ref),
                                    *args]).exit_code == 0
    out = tmp_path / "killed.json"
    ck = Path(str(out) + ".ckpt")
    proc = subprocess.Popen([gprm, "fit", str(means_file), "--out", str(out), *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    t0 = time.time()
    while not list(ck.glob("chunk_*.npz")) and time.time() - t0 < 60 and proc.poll() is None:
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    done = len(list(ck.glob("chunk_*.npz")))
    assert 1 <= done < 6 and not out.exists()
    assert CliRunner().invoke(app, ["fit", str(means_file), "--out", str(out),
                                    *args]).exit_code == 0
    a, b = json.loads(ref.read_text()), json.loads(out.read_text())
    for d in (a, b):
        d.pop("timings_s")
        d["data"].pop("source")
        d["sidecar"].pop("name")       # ref.nc / killed.nc; their checksums must agree
    assert a == b


def test_checkpoints_of_another_run_are_refused_naming_the_option(means_file, tmp_path):
    """A marked checkpoint folder whose chunks belong to other inputs or options: refused
    during the run, with the option named as typed; nothing is added to the folder and
    nothing but gprm's own bookkeeping files (no chunk was written) is removed."""
    from gprm.fit.engine import CHECKPOINT_MARKER

    ck = tmp_path / "ck"
    ck.mkdir()
    (ck / CHECKPOINT_MARKER).write_text("gprm\n")
    (ck / "fingerprint.txt").write_text("another run\n")
    before = sorted(p.name for p in ck.iterdir())
    r = CliRunner().invoke(app, ["fit", str(means_file), "--out", str(tmp_path / "f.json"),
                                 "--starts", "3", "--workers", "0", "--checkpoint", str(ck)])
    assert r.exit_code == 2, r.output
    assert "--checkpoint" in r.output and "other inputs or options" in r.output
    assert set(p.name for p in ck.iterdir()) <= set(before)
    assert not (tmp_path / "f.json").exists()


@pytest.mark.parametrize("starts, cores, expect", [(200, 2, 0), (1000, 2, 2), (1000, 1, 0),
                                                   (1000, 16, 4), (50, 16, 0)])
def test_the_default_workers_are_the_fastest_on_two_cores(means_file, tmp_path, monkeypatch,
                                                          starts, cores, expect):
    """Issue 22: the default was one worker per core, also for a fit of one chunk (200
    starts), which two workers only slow down (docs/fitting.md, "Scale"). Now: one per core,
    at most one per chunk of starts, none where that is fewer than two. gprm run and gprm
    demo take the same default."""
    import gprm.fit.api
    import gprm.fit.engine
    from gprm.run import RunOptions
    from gprm.run.commands import make_options

    seen = {}

    def fake_run_fit(means, opts, **kw):
        seen["workers"] = kw["workers"]
        raise KeyboardInterrupt("stop here")

    monkeypatch.setattr(gprm.fit.engine, "usable_cores", lambda: cores)
    monkeypatch.setattr(gprm.fit.api, "run_fit", fake_run_fit)
    CliRunner().invoke(app, ["fit", str(means_file), "--out", str(tmp_path / "f.json"),
                             "--starts", str(starts)])
    assert seen["workers"] == expect
    assert make_options(RunOptions, quick=False, seed=0, starts=starts,
                        workers=None).workers == expect
    assert make_options(RunOptions, quick=True, seed=0, starts=None, workers=None).workers == 0
    assert make_options(RunOptions, quick=False, seed=0, starts=None, workers=3).workers == 3


def test_gprm_fit_defaults_are_the_librarys():
    """Every option of ``gprm fit`` that names a FitOptions field defaults to that field's
    default (the command writes its defaults out, to start without importing the fit)."""
    from dataclasses import fields

    import typer.main

    from gprm.fit.api import FitOptions

    fit = typer.main.get_command(app).commands["fit"]
    lib = {f.name: getattr(FitOptions(), f.name) for f in fields(FitOptions)}
    shared = [p for p in fit.params if p.name in lib and p.default is not None
              and not isinstance(p.default, bool)]
    assert {"starts", "max_iter", "stall_window", "stall_tol", "chunk"} <= {p.name for p in shared}
    for p in shared:
        if p.name != "window":          # given as text there ("0.97ms,1.2ms"), SI here
            assert p.default == lib[p.name], p.name
