"""Prediction results as frozen dataclasses: the what-if table and the mass table, with
to_json (the JSON written, as before) / from_json round trips and to_xarray views."""

import dataclasses
import json

import numpy as np
import pytest

from gprm.errors import GprmInputError
from gprm.predict.masses import MassTable, mass_arrays, mass_table
from gprm.predict.whatif import HEADLINE, WhatIf, whatif


@pytest.fixture(scope="module")
def wi(fm):
    return whatif(fm, samples=8, seed=2)


def test_whatif_is_frozen_and_round_trips(wi):
    assert isinstance(wi, WhatIf)
    with pytest.raises(dataclasses.FrozenInstanceError):
        wi.seed = 3
    doc = wi.to_json()
    back = WhatIf.from_json(json.loads(json.dumps(doc, allow_nan=False)))
    assert back == wi and back.to_json() == doc
    assert list(doc) == ["definition", "window_s", "rate_hz", "points", "axes", "unit",
                         "source", "samples", "seed", "scenarios", "ratios"]
    doc["scenarios"][0]["name"] = "changed"             # a copy: the result is unchanged
    assert wi.scenarios[0]["name"] == "piezo2"
    bad = wi.to_json()
    del bad["ratios"]
    with pytest.raises(GprmInputError) as e:
        WhatIf.from_json(bad)
    assert e.value.field == "ratios"
    with pytest.raises(GprmInputError):
        WhatIf.from_json(["not", "a", "table"])


def test_whatif_xarray_holds_the_same_numbers(wi):
    ds = wi.to_xarray()
    assert list(ds["scenario"].values) == [s["name"] for s in wi.scenarios]
    for i, s in enumerate(wi.scenarios):
        for p in wi.points:
            for a in wi.axes:
                assert ds["overshoot"].isel(scenario=i).sel(point=p, axis=a) == \
                    s["overshoot"][p][a]
                assert ds["overshoot_p97_5"].isel(scenario=i).sel(point=p, axis=a) == \
                    s["overshoot_p97_5"][p][a]
    # ratios are the baseline's overshoot over the scenario's
    np.testing.assert_allclose(ds["ratio"].values,
                               ds["overshoot"].values[:1] / ds["overshoot"].values,
                               rtol=1e-12)
    for i, r in enumerate(wi.ratios):
        for a, v in r["headline"].items():
            assert ds["headline"].isel(scenario=i).sel(axis=a) == v
            assert v == ds["ratio"].isel(scenario=i).sel(point=HEADLINE[a], axis=a)
    assert wi.headline("piezo1") == wi.ratios[1]["headline"]
    with pytest.raises(GprmInputError):
        wi.headline("piezo3")


def test_whatif_without_samples_has_no_ranges(fm):
    ds = whatif(fm, samples=0).to_xarray()
    assert np.all(np.isnan(ds["overshoot_p2_5"].values))
    assert np.all(np.isfinite(ds["overshoot"].values))


def test_mass_table(fm):
    t = mass_table(fm)
    assert isinstance(t, MassTable) and len(t) == 4
    rows = t.to_json()
    assert [r["name"] for r in rows] == ["m1", "m2", "m3", "m4"]
    assert list(rows[0]) == ["name", "body", "unit", "fitted", "stderr", "nominal",
                             "paper_3d", "paper_3d_stderr", "z_vs_nominal", "source"]
    assert MassTable.from_json(json.loads(json.dumps(rows))) == t
    assert t["m2"].fitted == fm.params["m2"]
    with pytest.raises(KeyError):
        t["m9"]
    a, b = mass_arrays(t), mass_arrays(rows)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    ds = t.to_xarray()
    np.testing.assert_array_equal(ds["fitted"].values, [r["fitted"] for r in rows])
    assert np.isnan(ds["nominal"].sel(body="m1")) and rows[0]["nominal"] is None
    m2 = t["m2"]
    if m2.z_vs_nominal is not None:
        assert m2.z_vs_nominal == pytest.approx((m2.fitted - m2.nominal) / m2.stderr)
    with pytest.raises(GprmInputError):
        MassTable.from_json([{"name": "m1"}])


def test_prediction_to_xarray_is_its_file_and_to_json_its_headline(fm, tmp_path):
    """Prediction: to_xarray() is exactly what predict.nc holds; to_json() carries the
    overshoots of that file (point x axis) and is JSON-able."""
    import xarray as xr

    from gprm.predict.api import PredictOptions, run_predict
    from gprm.predict.files import write_prediction

    pred = run_predict(fm, PredictOptions(samples=4, seed=2, t_start=1e-3, t_end=1.02e-3))
    with pytest.raises(dataclasses.FrozenInstanceError):
        pred.seed = 3
    write_prediction(pred, tmp_path / "p.nc")
    with xr.open_dataset(tmp_path / "p.nc") as ds:
        ds = ds.load()
    mine = pred.to_xarray()
    np.testing.assert_array_equal(ds["overshoot"].values, mine["overshoot"].values)
    doc = json.loads(json.dumps(pred.to_json(), allow_nan=False))
    for i, point in enumerate(ds["point"].values.astype(str)):
        for j, axis in enumerate("xyz"):
            assert doc["overshoot_m"][point][axis] == float(ds["overshoot"].values[i, j])
    assert doc["scenario"] == pred.scenario.to_json() and doc["seed"] == 2
