"""``gprm fit`` end to end on a small synthetic mean-signals file, and its input errors."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
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
                                 "--seed", "2", "--workers", "0"])
    assert r.exit_code == 0, r.output
    d = json.loads(out.read_text())
    assert d["starts"]["requested"] == 3 and d["seed"] == 2
    assert out.with_suffix(".nc").exists()
    assert not Path(str(out) + ".ckpt").exists()        # checkpoints removed after success
    fm = load_fit(out) if d["correlation"]["matrix"] is not None else None
    if fm is not None:
        assert len(fm.names) == 23


@pytest.mark.parametrize("args, text", [
    (["--starts", "0"], "at least 1"),
    (["--sigma", "var"], "sem or std"),
    (["--window", "0.5", "0.6"], "outside the data"),
])
def test_gprm_fit_bad_options(means_file, tmp_path, args, text):
    r = CliRunner().invoke(app, ["fit", str(means_file), "--out", str(tmp_path / "f.json"),
                                 *args])
    assert r.exit_code == 2
    assert text in r.output
    assert not (tmp_path / "f.json").exists()


def test_gprm_fit_file_without_sigma(tmp_path):
    path = tmp_path / "nosigma.nc"
    make_means(paper(), seed=4).drop_vars(["sem", "std"]).to_netcdf(path)
    r = CliRunner().invoke(app, ["fit", str(path), "--out", str(tmp_path / "f.json")])
    assert r.exit_code == 2
    assert "sem" in r.output and str(path) in r.output
