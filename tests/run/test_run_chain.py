"""``gprm run`` end to end on small settings (6 starts, 40 band samples, one process):

- ``gprm demo`` and ``gprm run`` on the demo's campaign write the same files with the same
  content (only paths and timings differ): the demo is the same code on a generated campaign;
- the campaign as a CSV folder gives the same fit as the NetCDF file, and ``--telemetry``
  takes the user's telemetry instead of synthetic releases;
- a run interrupted in the fit resumes after the last finished stage, a rerun skips
  everything, and a changed setting reruns only the stages after it;
- bad input is one line naming the file or flag, exit code 2.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

from gprm.cli import app

pytestmark = pytest.mark.slow

SMALL = ["--quick", "--starts", "6", "--workers", "0"]
STAGES = ("campaign", "preprocess", "fit", "predict", "telemetry", "impact")
#: keys whose values are wall-clock times, the command line, or where an import came from
VOLATILE = {"timings", "timings_s", "seconds", "started", "finished", "command",
            "imported_from", "imported_sha256"}


def _invoke(args):
    res = CliRunner().invoke(app, args)
    return res


def _ok(args):
    res = _invoke(args)
    assert res.exit_code == 0, res.output + repr(res.exception)
    return res


def _statuses(run: Path) -> dict:
    rec = json.loads((run / "run.json").read_text())
    return {k: v["status"] for k, v in rec["stages"].items()}


def _strip(obj, run: Path):
    """``obj`` without volatile keys, the run directory's path written as RUN."""
    if isinstance(obj, dict):
        return {k: _strip(v, run) for k, v in obj.items() if k not in VOLATILE}
    if isinstance(obj, list):
        return [_strip(v, run) for v in obj]
    if isinstance(obj, str):
        return obj.replace(str(run), "RUN")
    return obj


def _json(path: Path):
    return _strip(json.loads(path.read_text()), path.parent)


def _same_netcdf(a: Path, b: Path, roots: tuple[Path, Path] | None = None) -> None:
    """Same variables, coordinates and values; attributes equal except the run directory's
    path (``roots``, default the files' folders), timings and where an import came from."""
    ra, rb = roots or (a.parent, b.parent)
    with xr.open_dataset(a) as da, xr.open_dataset(b) as db:
        xr.testing.assert_equal(da, db)
        for name in list(da.variables) + [None]:
            aa = _strip(dict(da.attrs if name is None else da[name].attrs), ra)
            ab = _strip(dict(db.attrs if name is None else db[name].attrs), rb)
            assert set(aa) == set(ab), (a.name, name)
            for k in aa:
                va, vb = aa[k], ab[k]
                if isinstance(va, str) and va.startswith("{"):
                    va, vb = (_strip(json.loads(v), Path("RUN")) for v in (va, vb))
                np.testing.assert_equal(va, vb, err_msg=f"{a.name} {name} {k}")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A: gprm demo; B: gprm run on A's campaign.nc."""
    root = tmp_path_factory.mktemp("runs")
    a, b = root / "demo", root / "run"
    _ok(["demo", *SMALL, "--seed", "0", "--out", str(a)])
    out = _ok(["run", str(a / "campaign.nc"), *SMALL, "--seed", "0", "--out", str(b)]).output
    return root, a, b, out


def test_run_writes_every_stage_and_the_report(runs):
    _, _, b, output = runs
    assert _statuses(b) == {s: "ran" for s in STAGES} | {"report": "ran"}
    for name in ("campaign.nc", "means.nc", "fit.json", "fit.nc", "predict.nc",
                 "predict_piezo1.nc", "predict_ecc10.nc", "whatif.json", "telemetry.nc",
                 "impact.json", "impact.nc", "run.json", "report.html"):
        assert (b / name).stat().st_size > 0, name
    rec = json.loads((b / "run.json").read_text())
    assert rec["options"]["campaign"].endswith("campaign.nc")
    assert rec["options"]["fit"]["starts"] == 6 and rec["options"]["fit"]["fit_offsets"]
    assert "gprm run →" in output and "best χ²" in output and "Tukey" in output
    html = (b / "report.html").read_text()
    assert 'id="fig-trajectories"' in html
    assert "option fit.starts" in html and "option preprocess.align_time" in html


def test_demo_is_run_on_a_generated_campaign(runs):
    _, a, b, _ = runs
    files = sorted(p.name for p in a.iterdir())
    assert files == sorted(p.name for p in b.iterdir())
    for name in files:
        if name.endswith(".nc"):
            _same_netcdf(a / name, b / name)
        elif name == "run.json":
            ra, rb = (json.loads((d / name).read_text()) for d in (a, b))
            assert ra["summary"] == rb["summary"]
            assert {k: v["status"] for k, v in ra["stages"].items()} == \
                {k: v["status"] for k, v in rb["stages"].items()}
            for s in STAGES[1:]:       # every stage after the campaign: same settings
                assert ra["stages"][s]["settings"] == rb["stages"][s]["settings"], s
            # the same campaign file in (later files differ only in the paths they record)
            assert ra["stages"]["preprocess"]["inputs"] == rb["stages"]["preprocess"]["inputs"]
        elif name.endswith(".json"):
            assert _json(a / name) == _json(b / name), name
    # a NetCDF campaign is taken as it is
    assert (b / "campaign.nc").read_bytes() == (a / "campaign.nc").read_bytes()


def test_csv_campaign_folder_and_user_telemetry(runs):
    from gprm.campaign import load_campaign, write_campaign_dir

    root, a, b, _ = runs
    csv, d = root / "csv-campaign", root / "from-csv"
    write_campaign_dir(load_campaign(a / "campaign.nc"), csv)
    before = {p: p.read_bytes() for p in csv.rglob("*") if p.is_file()}
    _ok(["run", str(csv), "--telemetry", str(b / "telemetry.nc"), *SMALL, "--out", str(d)])
    assert _statuses(d) == {s: "ran" for s in STAGES} | {"report": "ran"}
    assert {p: p.read_bytes() for p in csv.rglob("*") if p.is_file()} == before  # untouched
    with xr.open_dataset(d / "campaign.nc") as ds:       # a CSV campaign says whence
        assert ds.attrs["imported_from"] == str(csv)
    # %.17g text round-trips the measurements exactly: the same means and the same fit (the
    # folder has no synthetic truth, so the truth_* variables and attributes are absent)
    with xr.open_dataset(b / "means.nc") as mb, xr.open_dataset(d / "means.nc") as md:
        assert set(md.data_vars) == {v for v in mb.data_vars
                                     if not v.startswith("truth") and v != "parameter_units"}
        xr.testing.assert_equal(mb[list(md.data_vars)], md)
    fb, fd = _json(b / "fit.json"), _json(d / "fit.json")
    assert fd["chi2"] == fb["chi2"] and fd["parameters"] == fb["parameters"]
    # the user's telemetry is taken as it is (not drawn from the fit)
    assert (d / "telemetry.nc").read_bytes() == (b / "telemetry.nc").read_bytes()
    rec = json.loads((d / "run.json").read_text())
    assert rec["stages"]["telemetry"]["settings"]["source"] == str(b / "telemetry.nc")
    assert rec["stages"]["telemetry"]["inputs"] == {}          # needs no fit
    assert _json(d / "impact.json") == _json(b / "impact.json")


def test_interrupted_run_resumes_and_reruns_only_what_changed(runs):
    from gprm.run import RunOptions, run_chain

    root, a, b, _ = runs
    e = root / "resume"
    opts = RunOptions.make(quick=True, starts=6, campaign=a / "campaign.nc")

    def interrupt(stage, event, done, total):
        if stage == "fit" and event == "step":     # Ctrl-C during the fit
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_chain(e, opts, progress=interrupt, report_html=False)
    assert _statuses(e) == {"campaign": "ran", "preprocess": "ran", "fit": "interrupted"}
    assert not (e / "fit.json").exists()

    _ok(["run", str(a / "campaign.nc"), *SMALL, "--out", str(e)])
    assert _statuses(e) == {"campaign": "skipped", "preprocess": "skipped", "fit": "ran",
                            "predict": "ran", "telemetry": "ran", "impact": "ran",
                            "report": "ran"}
    assert _json(e / "fit.json") == _json(b / "fit.json")

    kept = {n: (e / n).read_bytes() for n in ("means.nc", "fit.json", "impact.json")}
    _ok(["run", str(a / "campaign.nc"), *SMALL, "--out", str(e)])
    assert set(_statuses(e).values()) == {"skipped", "ran"}
    assert [s for s, v in _statuses(e).items() if v == "ran"] == ["report"]
    assert {n: (e / n).read_bytes() for n in kept} == kept

    # fewer synthetic releases: the telemetry and the impact analysis rerun, the fit does not
    _ok(["run", str(a / "campaign.nc"), *SMALL, "--releases", "5", "--out", str(e)])
    st = _statuses(e)
    assert [s for s in STAGES if st[s] == "ran"] == ["telemetry", "impact"]
    assert len(json.loads((e / "impact.json").read_text())["releases"]) == 5


@pytest.mark.parametrize("args, text", [
    (["run", "no-such-campaign.nc", "--out", "{tmp}/x"], "no-such-campaign.nc: campaign "
                                                          "does not exist"),
    (["run", "{campaign}", "--telemetry", "nope.nc", "--out", "{tmp}/x"],
     "nope.nc: telemetry file does not exist (a NetCDF or CSV file)"),
    (["run", "{campaign}", "--telemetry", "nosuch.csv", "--out", "{tmp}/x"],
     "nosuch.csv: telemetry file does not exist (a NetCDF or CSV file)"),
    (["run", "{campaign}", "--starts", "0", "--out", "{tmp}/x"], "'--starts': must be >= 1"),
    (["run", "{campaign}", "--releases", "1", "--out", "{tmp}/x"], "'--releases': must be >= 2"),
])
def test_bad_input_is_one_line(runs, tmp_path, args, text):
    _, a, _, _ = runs
    args = [s.format(tmp=tmp_path, campaign=a / "campaign.nc") for s in args]
    res = _invoke(args)
    assert res.exit_code == 2, res.output
    assert text in res.output and "Traceback" not in res.output
    assert len(res.output.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()


def test_a_campaign_that_fails_to_load_is_a_failed_stage(runs, tmp_path):
    bad = tmp_path / "bad.nc"
    xr.Dataset({"x": ("t", np.zeros(3))}).to_netcdf(bad)
    res = _invoke(["run", str(bad), *SMALL, "--out", str(tmp_path / "r")])
    assert res.exit_code == 1
    assert "stage(s) failed: campaign: " + str(bad) in res.output
    st = _statuses(tmp_path / "r")
    assert st["campaign"] == "failed" and st["preprocess"] == "blocked"


def test_the_commands_defaults_reproduce_the_demo(runs, tmp_path):
    """One configuration: gprm preprocess and gprm fit with their defaults (only the run's
    starts, seed and band samples given) reproduce the demo's means and fit."""
    _, a, _, _ = runs
    c = tmp_path / "cli"
    c.mkdir()
    _ok(["preprocess", str(a / "campaign.nc"), "--out", str(c / "means.nc")])
    _same_netcdf(a / "means.nc", c / "means.nc", roots=(a, a))   # both read a/campaign.nc
    _ok(["fit", str(c / "means.nc"), "--out", str(c / "fit.json"), "--starts", "6",
         "--seed", "0", "--band-samples", "40", "--workers", "0"])
    assert _json(c / "fit.json") == _json(a / "fit.json")
