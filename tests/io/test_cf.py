"""CF-1.10 attributes of every NetCDF gprm writes (issue 15 item 4)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

from gprm._io import cf_dataset, write_netcdf_atomic
from gprm.params.netcdf import UNITS_COMMENT

sys.path.insert(0, str(Path(__file__).parents[1] / "fit"))
from means_factory import make_means  # noqa: E402


def _toy():
    return xr.Dataset({"n": ("i", np.arange(3)), "flag": ("i", np.array([True, False, True])),
                       "y": ("i", np.ones(3))},
                      coords={"i": np.arange(3), "label": ("i", ["a", "b", "c"])},
                      attrs={"units": "SI (m)", "history": "made by hand"})


def test_cf_dataset_adds_conventions_history_and_dimensionless_units_without_touching_input():
    ds = _toy().assign_coords(t=("t", [0.0, 1.0]))
    ds["t"].encoding["_FillValue"] = np.nan

    def state(d):
        return ({v: (dict(d[v].attrs), dict(d[v].encoding)) for v in d.variables},
                dict(d.attrs))

    before = state(ds)
    out = cf_dataset(ds)
    assert state(ds) == before
    assert out["t"].encoding["_FillValue"] is None        # CF 2.5.1 (coordinate variable)
    assert out.attrs["Conventions"] == "CF-1.10" and "units" not in out.attrs
    assert out.attrs["history"].startswith("made by hand\nwritten by ")
    assert out["n"].attrs["units"] == "1" and out["flag"].attrs["units"] == "1"
    assert out["i"].attrs["units"] == "1"
    assert "units" not in out["y"].attrs                 # a float's unit is its writer's job
    assert "units" not in out["label"].attrs             # strings have none
    again = cf_dataset(out)                               # rewriting adds no duplicate line
    assert again.attrs["history"] == out.attrs["history"]


def test_written_file_reads_back_with_the_attributes(tmp_path):
    write_netcdf_atomic(_toy(), tmp_path / "t.nc")
    with xr.open_dataset(tmp_path / "t.nc") as back:
        assert back.attrs["Conventions"] == "CF-1.10" and "history" in back.attrs
        assert back["n"].attrs["units"] == "1"


def _float_vars_without_units(ds) -> list[str]:
    """Float variables without ``units``, less the parameter tables (their units vary along
    ``parameter``/``param`` and are given by ``parameter_units``/``param_units``)."""
    return [v for v in ds.variables if ds[v].dtype.kind == "f" and "units" not in ds[v].attrs
            and "param_units" not in ds[v].attrs.get("comment", "")
            and ds[v].attrs.get("comment") != UNITS_COMMENT]


#: every NetCDF kind gprm writes (the fixture writes each), all held to every CF
#: recommendation below
KINDS = ("campaign.nc", "means.nc", "sim.nc", "predict.nc", "telemetry.nc", "impact.nc",
         "fit.nc")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    from gprm.campaign.files import write_campaign
    from gprm.campaign.synth import SynthConfig, synth_campaign
    from gprm.cli import app
    from gprm.params import paper

    d = tmp_path_factory.mktemp("cf")
    write_campaign(synth_campaign(seed=1, config=SynthConfig(n_runs=2, n_noise=1,
                                                             nonlinear=False)),
                   d / "campaign.nc")
    make_means(paper(), seed=4).to_netcdf(d / "means_in.nc")

    def run(*args):
        r = CliRunner().invoke(app, [str(a) for a in args])
        assert r.exit_code == 0, r.output

    run("preprocess", d / "campaign.nc", "--out", d / "means.nc")
    run("simulate", "--out", d / "sim.nc", "--t-end", "1.1e-3")
    run("predict", "paper", "--out", d / "predict.nc", "--samples", 6, "--means",
        d / "means.nc", "--gap", "2um", "--t-end", 1.15e-3)
    run("synth", "telemetry", "paper", "--out", d / "telemetry.nc", "--releases", 3,
        "--no-spread")
    # 2000 scenario draws, not 20000: the sidecar's variables and attributes are the same,
    # and the step takes 8 s instead of 70
    run("impact", "paper", d / "telemetry.nc", "--out", d / "impact.json", "--samples", 4,
        "--scenario-draws", 2000)
    run("fit", d / "means_in.nc", "--out", d / "fit.json", "--starts", 3, "--chunk", 3,
        "--max-iter", 5, "--band-samples", 0, "--workers", 0)
    return d


@pytest.mark.parametrize("name", KINDS)
def test_gprm_files_follow_cf(files, name):
    with xr.open_dataset(files / name) as ds:
        assert ds.attrs["Conventions"] == "CF-1.10"
        assert ds.attrs["history"].startswith("written by")
        assert "units" not in ds.attrs
        assert _float_vars_without_units(ds) == []
        for v in ds.variables:
            if ds[v].dtype.kind in "iub":
                assert "units" in ds[v].attrs, v


@pytest.mark.parametrize("name", KINDS)
def test_every_variable_is_described_and_units_are_udunits(files, name):
    """long_name on every variable; every units string parses in UDUNITS (cf-units), with
    velocities in m s-1 or rad s-1 (never m/s or um/s)."""
    cf_units = pytest.importorskip("cf_units")
    with xr.open_dataset(files / name) as ds:
        assert ds.attrs.get("title")
        for v in ds.variables:
            assert ds[v].attrs.get("long_name"), v
            u = ds[v].attrs.get("units")
            if u is None:
                continue
            cf_units.Unit(u)                          # raises if UDUNITS cannot read it
            assert "/" not in u and "µ" not in u, (v, u)
        if "parameter_units" in ds:
            for u in ds["parameter_units"].values:
                cf_units.Unit(str(u))


@pytest.mark.parametrize("name", KINDS)
def test_no_attribute_is_a_json_string(files, name):
    """Tabular metadata are variables, configuration plain numbers or text: no attribute,
    global or of a variable, holds a JSON document (issue 15)."""
    with xr.open_dataset(files / name) as ds:
        attrs = [("global", k, a) for k, a in ds.attrs.items()]
        attrs += [(v, k, a) for v in ds.variables for k, a in ds[v].attrs.items()]
        bad = [(v, k) for v, k, a in attrs
               if isinstance(a, str) and a.strip()[:1] in ("{", "[")]
        assert bad == []
        assert not [k for k in ds.attrs if k.endswith("_json")]


def test_fit_sidecar_parameter_units(files):
    from gprm.params.files import ureg
    from gprm.params import REGISTRY

    with xr.open_dataset(files / "fit.nc") as ds:
        assert ds["chi2"].attrs["units"] == "1"
        for name, unit in zip(ds["param"].values.astype(str),
                              ds["param_units"].values.astype(str)):
            want = ureg().Quantity(1.0, REGISTRY[name].unit).to(unit).magnitude
            assert want == pytest.approx(ureg().Quantity(1.0, REGISTRY[name].unit)
                                         .to_base_units().magnitude)


def _cf_results(path):
    runner = pytest.importorskip("compliance_checker.runner")
    cs = runner.CheckSuite()
    cs.load_all_available_checkers()
    results, _ = cs.run_all(cs.load_dataset(str(path)), ["cf:1.10"], skip_checks=[])["cf:1.10"]
    return results


@pytest.mark.parametrize("name", KINDS)
def test_cf_checker_finds_no_problem_the_conventions_step_owns(files, name):
    """The IOOS compliance checker (``pip install ".[cf]"``), CF 1.10: Conventions, units
    recognised by UDUNITS, no _FillValue on coordinate variables."""
    results = _cf_results(files / name)
    owned = ("§2.5.1", "§3.1 ")
    problems = [(r.name, r.msgs) for r in results
                if r.name.startswith(owned) and r.msgs]
    assert problems == []
    assert not [m for r in results for m in r.msgs if "Conventions" in m]
    assert any(r.name.startswith("§3.1 ") for r in results)     # the checks did run


@pytest.mark.parametrize("name", KINDS)
def test_cf_checker_has_no_remark_but_the_record_time(files, name):
    """Every remark of the checker is answered, but one: it recommends ``standard_name =
    time`` on ``time``, which CF ties to units with a reference date ("s since ..."). The record
    time is seconds from the start of a record (the lab files have no calendar time), so it
    has no standard name (docs/data-formats.md, "Conventions")."""
    results = _cf_results(files / name)
    remarks = [(r.name, m) for r in results for m in r.msgs
               if not (r.name.startswith("§5.1 ") and "standard_name='time'" in m)]
    assert remarks == []
