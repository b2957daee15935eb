"""`gprm simulate` on good and bad input: a NetCDF of docs/spec.md, or one line on stderr that
names the file and the field, a non-zero exit code and no output file."""

import warnings
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

from gprm.cli import app

runner = CliRunner()


def _run(args):
    """Invoke in-process; a Python warning (which would print a second stderr line) fails."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return runner.invoke(app, [str(a) for a in args])


def _assert_error(res, out, *words):
    assert res.exit_code != 0
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    for w in words:
        assert str(w) in lines[0], (w, lines[0])
    assert not out.exists()
    assert not [p for p in out.parent.iterdir() if p.name.startswith(f".{out.name}")]


def test_simulate_writes_the_netcdf_of_the_spec(tmp_path):
    out = tmp_path / "sim.nc"
    res = _run(["simulate", "--out", out, "--piezo", "1", "--t-end", "1.1e-3"])
    assert res.exit_code == 0, res.stderr
    with xr.open_dataset(out) as ds:
        assert ds["time"].size == 221 and ds["time"].attrs["units"] == "s"
        for v, u in [("z_lr", "m"), ("eta", "rad"), ("q", "C"), ("z_bk", "m"), ("voltage", "V")]:
            assert ds[v].attrs["units"] == u
        assert ds.attrs["piezo"] == 1
        assert float(ds["voltage"][0]) == 120.0
        assert np.all(ds["x_head"].values[:190] == 0)       # rest until t_c + t0 = 1.004 ms
        assert np.abs(ds["mu4"]).max() > 1e-6
        # the drive is named by where it is defined, a page of this repository
        assert ds.attrs["input"] == "default profile (docs/spec.md)"
    spec = Path(__file__).resolve().parents[2] / "docs" / "spec.md"
    assert "default profile" in spec.read_text()


def _params(tmp_path, body):
    p = tmp_path / "bad.toml"
    p.write_text("[parameters]\n" + body + "\n", encoding="utf-8")
    return p


@pytest.mark.parametrize("body, field", [
    ('m9 = "1 g"', "m9"),                                  # unknown name
    ('m2 = "3 mm"', "m2"),                                 # wrong dimension
    ('m2 = "-12 g"', "m2"),                                # negative mass
    ("k_Ax = -1.0e8", "k_Ax"),                             # negative stiffness
    ('C_a = "-0.5 uF"', "C_a"),                            # negative capacitance
    ('k_Ax = 0\nk_Bx = 0', "parameters"),                  # free lateral mode: singular K
    ("c_Dy = -3.0", "c_Dy"),                               # negative damping (would be unstable)
    ('b1 = "0 mm"\nb2 = "0 mm"', "parameters"),            # no rotational stiffness about x
])
def test_bad_parameter_file(tmp_path, body, field):
    p = _params(tmp_path, body)
    out = tmp_path / "sim.nc"
    res = _run(["simulate", "--params", p, "--out", out])
    _assert_error(res, out, p, field)


def _csv(tmp_path, rows, header=True):
    p = tmp_path / "trace.csv"
    text = ("time,voltage\n" if header else "") + "".join(f"{a},{b}\n" for a, b in rows)
    p.write_text(text, encoding="utf-8")
    return p


@pytest.mark.parametrize("rows, field", [
    ([], "voltage"),                                                   # empty
    ([(0.0, 120), (1e-3, 120), (0.9e-3, 60), (1.2e-3, 0)], "time"),    # non-monotonic time
    ([(0.0, 120), (1e-3, "nan"), (1.2e-3, 0)], "voltage"),             # NaN voltage
    ([(0.0, 120), ("nan", 60), (1.2e-3, 0)], "time"),                  # NaN time
])
def test_bad_voltage_csv(tmp_path, rows, field):
    p = _csv(tmp_path, rows)
    out = tmp_path / "sim.nc"
    res = _run(["simulate", "--voltage", p, "--out", out])
    _assert_error(res, out, p, field)


def test_bad_options(tmp_path):
    out = tmp_path / "sim.nc"
    _assert_error(_run(["simulate", "--piezo", "3", "--out", out]), out, "--piezo")
    _assert_error(_run(["simulate", "--rate", "-5", "--out", out]), out, "rate")


def test_existing_output_survives_a_failed_run(tmp_path):
    out = tmp_path / "sim.nc"
    out.write_bytes(b"old")
    p = _params(tmp_path, 'm2 = "3 mm"')
    res = _run(["simulate", "--params", p, "--out", out])
    assert res.exit_code != 0 and out.read_bytes() == b"old"


def test_simulate_with_a_voltage_trace(tmp_path):
    t = np.arange(0.9e-3, 1.2e-3, 2e-6)
    v = 120 * np.exp(-np.clip(t - 1e-3, 0, None) / 8e-6)
    p = _csv(tmp_path, list(zip(t, v)))
    out = tmp_path / "sim.nc"
    res = _run(["simulate", "--voltage", p, "--out", out, "--piezo", "2"])
    assert res.exit_code == 0, res.stderr
    with xr.open_dataset(out) as ds:
        t0 = 4e-6                                            # paper set
        expect = np.interp(ds["time"].values - t0, t, v)
        np.testing.assert_allclose(ds["voltage"].values, expect, rtol=1e-12)
        assert str(p) in ds.attrs["input"]
        # the response starts when the trace starts to change (1.0 ms + t0)
        moving = np.flatnonzero(np.abs(ds["mu4"].values) > 0)
        assert abs(ds["time"].values[moving[0]] - (1.0e-3 + t0)) <= 5e-6
