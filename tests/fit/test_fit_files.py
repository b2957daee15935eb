"""The fit file's one home (gprm.fit.files): the writer and the reader side by side, the
validation inside the reader, and the one resolver of 'paper or a path' (load_model)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from gprm.errors import GprmInputError
from gprm.fit.api import FitOptions, run_fit
from gprm.fit.files import (FittedModel, load_fit, load_model, paper_model, read_fit_document,
                            read_fit_sidecar, write_fit)
from gprm.params import paper

sys.path.insert(0, str(Path(__file__).parent))
from means_factory import make_means  # noqa: E402


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    d = tmp_path_factory.mktemp("fitfile")
    res = run_fit(make_means(paper(), seed=5), FitOptions(starts=3, chunk=3, max_iter=6,
                                                          band_samples=5, seed=2,
                                                          uncertainty="laplace-prior"))
    side = write_fit(res, d / "fit.json")
    return res, d / "fit.json", side


def test_writer_and_reader_round_trip(saved):
    res, path, side = saved
    assert side == path.with_suffix(".nc") and side.is_file()
    doc = read_fit_document(path)
    side_rec = doc.pop("sidecar")                   # the writer binds the sidecar (issue 22)
    assert side_rec["name"] == "fit.nc" and len(side_rec["sha256"]) == 64
    assert doc == json.loads(json.dumps(res.to_json_dict()))        # what was written
    fm = load_fit(path)
    np.testing.assert_allclose(fm.params.vector(res.names), res.x, rtol=1e-15)
    assert fm.names == tuple(n for n in paper().values if n in res.names)
    assert fm.covariance_message == res.covariance_message
    ds = read_fit_sidecar(path)                      # the JSON's name gives the sidecar
    np.testing.assert_array_equal(ds["chi2"].values, res.starts.chi2)
    assert ds["data_mean"].attrs["units"] == "m"


def test_load_model_resolves_paper_a_file_a_run_folder_and_a_model(saved):
    _, path, _ = saved
    assert load_model("paper").source == "paper" and load_model("paper").piezo == 2
    assert load_model("paper", piezo=1).piezo == 1
    by_file, by_folder = load_model(path), load_model(path.parent)
    assert by_file.source == by_folder.source == str(path)
    assert load_model(by_file) is by_file
    other = load_model(path, piezo=1)
    assert other.piezo == 1 and other.params == by_file.params
    with pytest.raises(GprmInputError) as e:
        load_model(path, piezo=3)
    assert e.value.field == "piezo"
    assert isinstance(paper_model(), FittedModel)


@pytest.mark.parametrize("change, field", [
    (lambda d: d.update(model="other"), "model"),
    (lambda d: d.update(format_version=7), "format_version"),
    (lambda d: d.update(piezo=3), "piezo"),
    (lambda d: d.pop("parameters"), "parameters"),
    (lambda d: d["parameters"].update(zz={"value": 1.0}), "parameters.zz"),
    (lambda d: d["parameters"]["m2"].update(value=float("nan")), "parameters.m2.value"),
    # a field of the wrong JSON type: named, not met later as an AttributeError in a reader
    (lambda d: d.update(correlation=5), "correlation"),
    (lambda d: d.update(polish="x"), "polish"),
    (lambda d: d.update(identified={"v2": 1}), "identified"),
    (lambda d: d.update(dof=True), "dof"),
    (lambda d: d.update(window=[0.97e-3]), "window"),
    (lambda d: d.update(window=["x", 1.2e-3]), "window[0]"),
])
def test_every_reader_validates_the_fit_file(saved, tmp_path, change, field):
    _, path, _ = saved
    doc = json.loads(path.read_text())
    change(doc)
    bad = tmp_path / "fit.json"
    bad.write_text(json.dumps(doc))
    for read in (read_fit_document, load_fit, load_model):
        with pytest.raises(GprmInputError) as e:
            read(bad)
        assert e.value.field == field and str(bad) in str(e.value)


def test_the_sidecar_is_checked_by_its_reader(saved, tmp_path):
    _, _, side = saved
    ds = read_fit_sidecar(side)
    ds.drop_vars("data_mean").to_netcdf(tmp_path / "fit.nc")
    with pytest.raises(GprmInputError) as e:
        read_fit_sidecar(tmp_path / "fit.nc")
    assert e.value.field == "data_mean"
    ds2 = ds.copy()
    ds2["data_sigma"] = ds2["data_sigma"] * 0.0
    ds2.to_netcdf(tmp_path / "fit2.nc")
    with pytest.raises(GprmInputError) as e:
        read_fit_sidecar(tmp_path / "fit2.nc")
    assert e.value.field == "data_sigma"
