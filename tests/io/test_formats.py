"""One home per file format (issue 16): each reader gives back what its writer was given, and
reads the files gprm wrote before the metadata became variables (``tests/io/legacy``, written
by the earlier version: JSON strings in attributes, velocities along one mixed-unit axis)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

from gprm.campaign.files import (has_truth, load_campaign, read_generator, read_means,
                                 read_no_crossing, read_preprocess_settings, read_tables,
                                 read_truth, read_truth_alignment, write_campaign, write_means)
from gprm.campaign.preprocess import PreprocessConfig, preprocess
from gprm.campaign.synth import SynthConfig, synth_campaign
from gprm.cli import app
from gprm.fit.objective import fit_data_from_means
from gprm.flight import files as ff
from gprm.predict import files as pf
from gprm.simulate import files as sf

LEGACY = Path(__file__).parent / "legacy"


def _attrs(path) -> dict:
    with xr.open_dataset(path) as ds:
        return dict(ds.attrs)


def _run(*args):
    r = CliRunner().invoke(app, [str(a) for a in args])
    assert r.exit_code == 0, r.output


def _lists(d: dict) -> dict:
    """A generator JSON as read_generator gives it (a support as [k, f, zeta])."""
    return {k: (list(v.values()) if isinstance(v, dict) else v) for k, v in d.items()}


# ----------------------------------------------------------------------------- legacy files

def test_legacy_files_hold_json_attributes():
    """The legacy files are what they claim: the earlier layout (so the tests below do test
    the fallback)."""
    for name, key in (("campaign_v1.nc", "truth_json"), ("means_v1.nc", "preprocess_json"),
                      ("sim_v1.nc", "parameters_json"), ("predict_v1.nc", "scenario_json"),
                      ("telemetry_v1.nc", "options_json")):
        assert _attrs(LEGACY / name)[key].startswith("{"), name
    with xr.open_dataset(LEGACY / "impact_v1.nc") as ds:
        assert "axis" in ds.dims and "velocity_nominal" not in ds


def test_legacy_campaign_reads():
    a = _attrs(LEGACY / "campaign_v1.nc")
    ds = load_campaign(LEGACY / "campaign_v1.nc")
    assert read_truth(ds) == json.loads(a["truth_json"])
    assert read_generator(ds.attrs) == _lists(json.loads(a["generator_json"]))
    assert has_truth(ds.attrs)


def test_legacy_means_read():
    a = _attrs(LEGACY / "means_v1.nc")
    ds = read_means(LEGACY / "means_v1.nc")
    assert read_truth(ds) == json.loads(a["truth_json"])
    assert read_truth_alignment(ds) == json.loads(a["truth_alignment_json"])
    assert read_preprocess_settings(ds.attrs) == json.loads(a["preprocess_json"])
    assert read_generator(ds.attrs) == _lists(json.loads(a["generator_json"]))
    assert read_no_crossing(ds) == json.loads(a["no_crossing_json"])
    assert read_tables(ds)[0]                                   # Table 1 (variables already)


def test_legacy_simulation_and_prediction_read():
    a = _attrs(LEGACY / "sim_v1.nc")
    sim = sf.read_simulation(LEGACY / "sim_v1.nc")
    assert sf.read_parameters(sim) == json.loads(a["parameters_json"])
    a = _attrs(LEGACY / "predict_v1.nc")
    with xr.open_dataset(LEGACY / "predict_v1.nc") as raw:
        assert raw["vel"].attrs["units"] == "m/s"
    pred = pf.read_prediction(LEGACY / "predict_v1.nc")        # read in UDUNITS SI
    assert pred["vel"].attrs["units"] == "m s-1"
    np.testing.assert_array_equal(pred["vel"].values, raw["vel"].values)
    assert pf.read_scenario(pred) == json.loads(a["scenario_json"])
    assert pf.read_energy_window(pred) == tuple(json.loads(a["energy_window_s"]))
    assert pf.read_impact_risk(pred) == json.loads(a["impact_risk_json"])
    values, fitted = pf.read_parameters(pred)
    assert values["m2"] > 0 and "m2" in fitted


def test_legacy_telemetry_and_impact_curves_read():
    a = _attrs(LEGACY / "telemetry_v1.nc")
    tel = ff.load_telemetry(LEGACY / "telemetry_v1.nc")
    with xr.open_dataset(LEGACY / "telemetry_v1.nc") as ds:
        assert ff.read_truth(ds) == json.loads(a["truth_json"])
        assert ff.read_synth_options(ds.attrs) == json.loads(a["options_json"])
        np.testing.assert_array_equal(
            tel.truth_velocity, ds["truth_velocity"].transpose("release", "axis").values)
    cur = ff.read_impact_curves(LEGACY / "impact_v1.nc")
    assert cur["nominal"].dims == ("axis", "time") and cur["lo"].sizes["axis"] == 6


# ----------------------------------------------------------------------------- same numbers

#: the libraries the legacy files were written with (requirements/lock.txt at 5a2516a):
#: bit-identical numbers can be asked of the same libraries only (numpy 2.0 and scipy 1.13,
#: the lower bounds, move the flange signals' noise-free crossing by about 1 ns)
LEGACY_LIBRARIES = {"numpy": "2.4.6", "scipy": "1.17.1"}


def _libraries_differ() -> str:
    import importlib.metadata as md

    other = {k: md.version(k) for k, v in LEGACY_LIBRARIES.items() if md.version(k) != v}
    return ", ".join(f"{k} {v}" for k, v in other.items())


@pytest.mark.skipif(bool(_libraries_differ()),
                    reason=f"the legacy files were written with numpy "
                    f"{LEGACY_LIBRARIES['numpy']} and scipy {LEGACY_LIBRARIES['scipy']}; "
                    f"this environment has {_libraries_differ()} (bit-identity across "
                    f"library versions is not claimed; the readers' legacy paths are "
                    f"tested version-independently above)")
def test_new_writers_give_the_numbers_the_old_ones_did(tmp_path):
    """The campaign, its mean signals and a synthetic telemetry made again with the options of
    the legacy files: same data, same truth, same settings, read through the new layout."""
    old_c = load_campaign(LEGACY / "campaign_v1.nc")
    cfg = SynthConfig(n_runs=2, n_noise=1, nonlinear=False)
    write_campaign(synth_campaign(seed=1, config=cfg), tmp_path / "c.nc")
    new_c = load_campaign(tmp_path / "c.nc")
    assert "truth_json" not in new_c.attrs and "truth_value" in new_c
    assert read_truth(new_c) == read_truth(old_c)
    # the legacy file predates the generator's piezo setting; it was made with Piezo 2
    assert read_generator(new_c.attrs) == {**read_generator(old_c.attrs), "piezo": 2}
    np.testing.assert_array_equal(new_c["displacement"].values[..., :40],
                                  old_c["displacement"].values)

    ms = preprocess(new_c)
    write_means(ms, tmp_path / "m.nc")
    new_m, old_m = read_means(tmp_path / "m.nc"), read_means(LEGACY / "means_v1.nc")
    drift = float(np.max(np.abs(new_m["noise_std"].values / old_m["noise_std"].values - 1)))
    if drift != 0.0:
        # the same libraries on another processor: the noise std (a least-squares fit, BLAS)
        # differs in its last bit, and the alignment's threshold rule can then pick a
        # neighbouring crossing (measured: y_head's shift moved by 1.6 us on a 2-run campaign
        # while every other number agreed to 1e-17), so bit-identity is not claimed here
        pytest.skip(f"this processor's floating-point kernels differ from those that wrote "
                    f"the legacy files (noise std differs by {drift:.1e} relative); the "
                    "means are compared bit for bit only where they agree")
    assert read_truth_alignment(new_m) == ms.truth_alignment
    assert read_preprocess_settings(new_m.attrs) == read_preprocess_settings(old_m.attrs)
    assert read_generator(new_m.attrs) == {**read_generator(old_m.attrs), "piezo": 2}
    assert read_no_crossing(new_m) == read_no_crossing(old_m) == list(ms.no_crossing)
    # the legacy means were aligned by the exact sub-sample shift; since stop 34 the shift is
    # that one rounded to whole samples (docs/data-formats.md, step 3), and the truth's
    # alignment moves with the rounding: so the new file's numbers follow from the old ones
    dt = 1.0 / float(new_c.attrs["sample_rate"])
    old_shift, new_shift = old_m["shift"].values, new_m["shift"].values
    np.testing.assert_allclose(new_shift, dt * np.round(old_shift / dt), rtol=0, atol=1e-15)
    # the legacy truth_shift was the alignment rule applied to the noise-free truth; since
    # stop 40 it is where the data's axis puts the truth's time (the runs' average of trigger
    # offset less synchronisation shift, plus the data's shift), within half a sample of the
    # rule's
    off = new_c["trigger_offset"].sel(position=list(new_m["signal"].values)).values
    exact = new_shift + np.mean(off - new_m["sync_shift"].values, axis=1)
    np.testing.assert_allclose(new_m["truth_shift"].values, exact, rtol=0, atol=1e-15)
    rule = old_m["truth_shift"].values + new_shift - old_shift
    model = [list(new_m["signal"].values).index(p) for p in ("x_base", "x_head", "y_base",
                                                              "y_head", "z_bk")]
    assert np.max(np.abs(new_m["truth_shift"].values - rule)[model]) < 0.5 * dt
    # the synchronisation is unchanged (the file's runs are moved by its whole samples)
    np.testing.assert_allclose(new_m["sync_shift"].values, old_m["sync_shift"].values,
                               rtol=0, atol=1e-15)

    # the legacy telemetry predates the impact scenarios (issue 23): its truth is the 3d
    # model, which is no longer the default
    _run("synth", "telemetry", "paper", "--out", tmp_path / "t.nc", "--releases", 2,
         "--no-spread", "--post", "2s", "--truth-model", "3d")
    new_t = ff.load_telemetry(tmp_path / "t.nc")
    old_t = ff.load_telemetry(LEGACY / "telemetry_v1.nc")
    np.testing.assert_array_equal(new_t.truth_velocity, old_t.truth_velocity)
    for r_new, r_old in zip(new_t.releases, old_t.releases):
        np.testing.assert_array_equal(r_new.data["x"], r_old.data["x"])
    with xr.open_dataset(tmp_path / "t.nc") as a, \
            xr.open_dataset(LEGACY / "telemetry_v1.nc") as b:
        assert ff.read_truth(a) == ff.read_truth(b)
        new_o, old_o = ff.read_synth_options(a.attrs), ff.read_synth_options(b.attrs)
        # options added since (the scenario truth's, unused by the 3d truth) are the only
        # difference
        assert {k: new_o[k] for k in old_o} == old_o
        assert set(new_o) - set(old_o) <= {"scenario", "tm_offset"}


# ----------------------------------------------------------------------------- round trips

def test_means_metadata_round_trip(tmp_path):
    camp = synth_campaign(seed=3, config=SynthConfig(n_runs=3, n_noise=2, nonlinear=False))
    cfg = PreprocessConfig(align_time=1.02e-3, max_lag=10)
    ms = preprocess(camp, cfg)
    write_means(ms, tmp_path / "m.nc")
    ds = read_means(tmp_path / "m.nc")
    assert read_truth(ds) == ms.truth == read_truth(camp)
    assert read_truth_alignment(ds) == ms.truth_alignment
    assert PreprocessConfig(**read_preprocess_settings(ds.attrs)) == cfg
    # every setting is recorded (the file's list of fields follows PreprocessConfig's)
    assert set(read_preprocess_settings(ds.attrs)) == \
        {f.name for f in dataclasses.fields(PreprocessConfig)}
    gen = read_generator(ds.attrs)
    assert gen == _lists(dataclasses.asdict(SynthConfig(n_runs=3, n_noise=2, nonlinear=False)))
    assert ds["truth_value"].dims == ("parameter",)
    assert ds["parameter_units"].sel(parameter="m2").item() == "kg"
    assert has_truth(ds.attrs) and not has_truth({"title": "lab campaign"})
    # where each crossing was put (whole-sample alignment) reaches the fit
    np.testing.assert_array_equal(ds["crossing_time"].values, ms.crossing_time)
    fd = fit_data_from_means(ds, window=(0.97e-3, 1.2e-3))
    names = [str(x) for x in ds["signal"].values]
    np.testing.assert_array_equal(fd.crossing_time,
                                  [ms.crossing_time[names.index(x)] for x in fd.signals])
    assert np.all(np.abs(fd.crossing_time - 1.02e-3) <= 0.5 / 200e3 + 1e-12)


def test_prediction_metadata_round_trip(tmp_path):
    from gprm.predict.api import PredictOptions, run_predict
    from gprm.fit.files import load_model

    pred = run_predict(load_model("paper"),
                       PredictOptions(piezo=1, scale_eccentricity=0.5, name="half",
                                      overrides={"h2": 0.031}, samples=4, seed=2, gap=2e-6,
                                      t_start=1e-3, t_end=1.02e-3))
    pf.write_prediction(pred, tmp_path / "p.nc")
    ds = pf.read_prediction(tmp_path / "p.nc")
    assert pf.read_scenario(ds) == pred.scenario.to_json()
    assert pf.read_energy_window(ds) == tuple(float(x) for x in pred.energy.window)
    assert pf.read_impact_risk(ds) == pred.risk.to_json()
    assert ds["vel"].attrs["units"] == "m s-1"


def test_simulation_parameters_round_trip(tmp_path):
    from gprm.params import paper
    from gprm.simulate import simulate

    ps = paper().with_values(m2=0.123)
    sf.write_simulation(sf.simulation_dataset(simulate(ps, piezo=2, t_end=1.05e-3), ps),
                        tmp_path / "s.nc")
    assert sf.read_parameters(sf.read_simulation(tmp_path / "s.nc")) == dict(ps.values)


def test_telemetry_truth_round_trip(tmp_path):
    from gprm.fit.files import paper_model
    from gprm.flight.synth import SynthOptions, synth_telemetry

    opts = SynthOptions(n_releases=3, seed=4, truth_spread=False, truth_model="planar",
                        z_from="xz")
    ds = synth_telemetry(paper_model(), opts)
    ff.write_telemetry(ds, tmp_path / "t.nc")
    with xr.open_dataset(tmp_path / "t.nc") as back:
        truth = ff.read_truth(back)
        assert truth == ff.read_truth(ds)
        assert truth["z_from"] == "xz" and truth["truth_model"] == "planar"
        assert truth["impact_time"] == [float(x) for x in ds["truth_impact_time"].values]
        assert ff.read_synth_options(back.attrs) == dataclasses.asdict(opts)
        assert back["truth_velocity"].attrs["units"] == "m s-1"
        assert back["truth_angular_velocity"].attrs["units"] == "rad s-1"
    tel = ff.load_telemetry(tmp_path / "t.nc")
    np.testing.assert_array_equal(tel.truth_velocity[:, 0], truth["tm_velocity"]["vx"])


def test_whatif_table_round_trip_and_refusal(tmp_path):
    from gprm.errors import GprmInputError

    table = {"scenarios": [{"name": "piezo2"}], "ratios": [{"name": "piezo2"}]}
    pf.write_whatif(table, tmp_path / "w.json")
    assert pf.read_whatif(tmp_path / "w.json") == table
    (tmp_path / "x.json").write_text('{"ratios": 3}')
    with pytest.raises(GprmInputError, match="scenarios"):
        pf.read_whatif(tmp_path / "x.json")


def test_readers_refuse_a_broken_legacy_attribute(tmp_path):
    from gprm.errors import GprmInputError

    ds = xr.open_dataset(LEGACY / "means_v1.nc").load()
    ds.attrs["truth_json"] = "{not json"
    with pytest.raises(GprmInputError, match="truth_json"):
        read_truth(ds)
    bad = xr.Dataset(attrs={"format": "something-else"})
    bad.to_netcdf(tmp_path / "c.nc")
    with pytest.raises(GprmInputError, match="format"):
        ff.read_impact_curves(tmp_path / "c.nc")


def test_legacy_json_attributes_are_read_by_one_helper():
    """Older files' JSON attributes: absent -> default; valid -> the document; invalid ->
    an input error naming the attribute (or the default, for optional settings)."""
    from gprm.errors import GprmInputError
    from gprm.validate import legacy_json_attr

    attrs = {"truth_json": '{"m2": 0.0124}', "options_json": "{not json"}
    assert legacy_json_attr(attrs, "truth_json", source="f.nc") == {"m2": 0.0124}
    assert legacy_json_attr(attrs, "absent_json", source="f.nc", default=[]) == []
    assert legacy_json_attr(attrs, "options_json", source="f.nc", strict=False) is None
    with pytest.raises(GprmInputError) as e:
        legacy_json_attr(attrs, "options_json", source="f.nc")
    assert e.value.field == "options_json" and e.value.source == "f.nc"
