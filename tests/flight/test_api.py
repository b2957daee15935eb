"""The flight stage's library entry points: validated options, the impact result as a frozen
dataclass with to_json / to_xarray / from_json, and run_impact + write_impact as the one
read -> compute -> write path of ``gprm impact`` and ``gprm run``."""

import dataclasses
import json

import numpy as np
import pytest

from gprm.errors import GprmInputError
from gprm.fit.files import load_model, paper_model
from gprm.flight import (AnalysisOptions, ImpactOptions, ImpactResult, SynthOptions,
                         TelemetryOptions, analyze, run_impact,
                         run_synth_telemetry, write_impact)

from gprm.flight.files import impact_curves_dataset, load_telemetry, telemetry_from_dataset


@pytest.fixture(scope="module")
def telemetry(tmp_path_factory):
    path = tmp_path_factory.mktemp("tel") / "telemetry.nc"
    ds = run_synth_telemetry("paper", TelemetryOptions(SynthOptions(n_releases=3, seed=2)))
    ds.to_netcdf(path)
    return path, ds


@pytest.fixture(scope="module")
def result(telemetry):
    return run_impact("paper", telemetry[0],   # the analysis only (scenarios: test_inference)
                      ImpactOptions(AnalysisOptions(n_samples=20, n_times=151, seed=3),
                                    scenarios=None))


@pytest.mark.parametrize("kw, field", [
    (dict(alpha=0.0), "alpha"), (dict(alpha=1.0), "alpha"), (dict(alpha=True), "alpha"),
    (dict(n_samples=1), "n_samples"), (dict(n_times=1), "n_times"), (dict(seed=-1), "seed"),
    (dict(min_samples=1), "min_samples"), (dict(window=(2e-3, 1e-3)), "window"),
    (dict(window=(-1e-3, 1e-3)), "window"), (dict(window=(1e-3,)), "window"),
    (dict(fit_window=0.0), "fit_window"), (dict(fit_window=float("nan")), "fit_window"),
    (dict(impact_model="2d"), "impact_model"),
])
def test_analysis_options_refuse_bad_values(kw, field):
    with pytest.raises(GprmInputError) as e:
        AnalysisOptions(**kw)
    assert e.value.field == field


@pytest.mark.parametrize("kw, field", [
    (dict(n_releases=0), "n_releases"), (dict(seed=-2), "seed"), (dict(rate=0.0), "rate"),
    (dict(post=-1.0), "post"), (dict(pre=-1.0), "pre"), (dict(pos_noise=0.0), "pos_noise"),
    (dict(att_noise=float("inf")), "att_noise"), (dict(grid_step=0.0), "grid_step"),
    (dict(z_from="xy"), "z_from"), (dict(truth_model="2d"), "truth_model"),
    (dict(window_mode="all"), "window_mode"),
])
def test_synth_options_refuse_bad_values(kw, field):
    with pytest.raises(GprmInputError) as e:
        SynthOptions(**kw)
    assert e.value.field == field


@pytest.mark.parametrize("piezo", [0, 3, True, "2"])
def test_piezo_is_checked_in_one_place(piezo):
    for make in (lambda: ImpactOptions(piezo=piezo), lambda: TelemetryOptions(piezo=piezo),
                 lambda: load_model("paper", piezo=piezo)):
        with pytest.raises(GprmInputError) as e:
            make()
        assert e.value.field == "piezo"


def test_the_flight_stage_takes_its_model_through_load_model():
    assert load_model("paper").piezo == 2
    assert load_model("paper", piezo=1).piezo == 1
    fm = paper_model()
    assert load_model(fm) is fm
    assert load_model(fm, piezo=1).piezo == 1 and load_model(fm, piezo=1).params is fm.params


def test_options_types_are_checked(telemetry):
    with pytest.raises(GprmInputError, match="ImpactOptions"):
        run_impact("paper", telemetry[0], AnalysisOptions())
    with pytest.raises(GprmInputError, match="AnalysisOptions"):
        ImpactOptions(analysis={"alpha": 0.01})
    with pytest.raises(GprmInputError, match="SynthOptions"):
        TelemetryOptions(synth=None)


def test_result_is_frozen_and_round_trips_through_json(result):
    assert isinstance(result, ImpactResult)
    with pytest.raises(dataclasses.FrozenInstanceError):
        result.piezo = 1
    doc = result.to_json()
    text = json.dumps(doc, allow_nan=False)              # JSON-able as written
    back = ImpactResult.from_json(json.loads(text), curves=result.curves)
    assert back.to_json() == doc
    assert doc["format"] == "gprm-impact" and doc["curves"]["sidecar"] is None
    assert len(doc["releases"]) == 3 and doc["truth"]["summary"]["impact_times"] == 18
    doc["releases"][0]["id"] = "changed"                 # a copy: the result is unchanged
    assert result.to_json()["releases"][0]["id"] != "changed"
    with pytest.raises(GprmInputError, match="curves"):
        ImpactResult.from_json(result.to_json()).to_xarray()
    with pytest.raises(GprmInputError):
        ImpactResult.from_json({"format": "gprm-fit"})
    partial = result.to_json()
    del partial["releases"]
    with pytest.raises(GprmInputError) as e:
        ImpactResult.from_json(partial)
    assert e.value.field == "releases"


def test_to_xarray_is_the_curves_sidecar(result):
    ds = result.to_xarray()
    assert ds.identical(impact_curves_dataset(result.curves))
    np.testing.assert_array_equal(ds["velocity_nominal"].sel(velocity_axis="vx").values,
                                  result.curves.nominal["vx"])
    np.testing.assert_array_equal(ds["angular_velocity_nominal"].sel(angular_axis="wy").values,
                                  result.curves.nominal["wy"])


def test_run_impact_is_analyze_on_the_loaded_inputs(telemetry, result):
    """The entry point adds nothing to the analysis: same document as analyze() called on the
    model and the telemetry read by hand (and on the dataset without a file)."""
    opts = AnalysisOptions(n_samples=20, n_times=151, seed=3)
    direct = analyze(paper_model(), load_telemetry(telemetry[0]), opts).to_json()
    assert result.to_json() == direct
    mem = run_impact(paper_model(), telemetry_from_dataset(telemetry[1],
                                                           source=str(telemetry[0])),
                     ImpactOptions(opts, scenarios=None))
    assert mem.to_json() == direct


def test_write_impact_writes_the_document_and_its_sidecar(result, tmp_path):
    import xarray as xr

    out = tmp_path / "impact.json"
    written = write_impact(result, out)
    assert written.sidecar == "impact.nc"
    assert json.loads(out.read_text()) == written.to_json()
    with xr.open_dataset(tmp_path / "impact.nc") as ds:
        np.testing.assert_array_equal(ds["velocity_nominal"].values,
                                      result.to_xarray()["velocity_nominal"].values)
    with pytest.raises(GprmInputError, match=r"\.nc"):
        write_impact(result, tmp_path / "impact.nc")


def test_notes_and_multi_are_carried(telemetry):
    opts = ImpactOptions(AnalysisOptions(n_samples=20, n_times=151, seed=3), multi=True,
                         scenarios=None)
    res = run_impact("paper", telemetry[0], opts, notes=["best fit only"])
    doc = res.to_json()
    assert doc["notes"] == ["best fit only"]
    assert [r["id"] for r in doc["multiple_impacts"]["releases"]] == \
        [r["id"] for r in doc["releases"]]
    assert list(doc)[-2:] == ["multiple_impacts", "notes"]


@pytest.mark.parametrize("args, flag", [
    (["impact", "paper", "{tel}", "--out", "{tmp}/o.json", "--samples", "1"], "--samples"),
    (["impact", "paper", "{tel}", "--out", "{tmp}/o.json", "--impact-model", "2d"],
     "--impact-model"),
    (["impact", "paper", "{tel}", "--out", "{tmp}/o.nc"], "--out"),
    (["synth", "telemetry", "paper", "--out", "{tmp}/t.nc", "--z-from", "xy"], "--z-from"),
    (["synth", "telemetry", "paper", "--out", "{tmp}/t.nc", "--truth-model", "2d"],
     "--truth-model"),
    (["synth", "telemetry", "paper", "--out", "{tmp}/t.nc", "--scenario", "xy"], "--scenario"),
    (["impact", "paper", "{tel}", "--out", "{tmp}/o.json", "--scenario-draws", "5"],
     "--scenario-draws"),
    (["impact", "paper", "{tel}", "--out", "{tmp}/o.json", "--impact-model", "auto",
      "--scenario-draws", "0"], "--impact-model"),
])
def test_commands_name_a_bad_option_by_its_flag(telemetry, tmp_path, args, flag):
    """The options' own checks, reached through the commands: one line naming the flag as
    typed, exit code 2, nothing written."""
    from typer.testing import CliRunner

    from gprm.cli import app

    argv = [a.format(tel=telemetry[0], tmp=tmp_path) for a in args]
    res = CliRunner().invoke(app, argv)
    assert res.exit_code == 2
    err = res.stderr if hasattr(res, "stderr") else res.output
    lines = [x for x in err.strip().splitlines() if x]
    assert len(lines) == 1 and lines[0].startswith(f"gprm: error: {flag}"), lines
    assert list(tmp_path.iterdir()) == []
