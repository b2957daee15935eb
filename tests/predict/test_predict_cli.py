"""``gprm predict``: the NetCDF it writes, and one-line errors for bad input."""

import json

import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

from gprm.cli import app
from gprm.params import REGISTRY, paper

from predict_means_synth import synthetic_means


def fit_json(path, model="gprm-3d", version=1):
    ps = paper()
    names = list(ps.fitted)
    doc = {"model": model, "format_version": version, "piezo": 2,
           "parameters": {n: {"value": ps[n], "unit": "SI", "fitted": n in names,
                              "stderr": REGISTRY[n].paper_stderr if n in names else None}
                          for n in REGISTRY},
           "correlation": {"names": names, "matrix": np.eye(len(names)).tolist()}}
    path.write_text(json.dumps(doc))
    return path


def run(*args):
    return CliRunner().invoke(app, ["predict", *map(str, args)])


def test_predict_writes_documented_dataset(tmp_path):
    means = tmp_path / "means.nc"
    synthetic_means(paper(), seed=1).to_netcdf(means)
    out = tmp_path / "p.nc"
    wi = tmp_path / "whatif.json"
    r = run(fit_json(tmp_path / "fit.json"), "--out", out, "--samples", 40, "--seed", 3,
            "--means", means, "--gap", "2um", "--gap-std", "0.5 um", "--whatif", wi,
            "--set", "h2=31 mm", "--t-end", 1.15e-3)
    assert r.exit_code == 0, r.output
    ds = xr.open_dataset(out)
    assert list(ds["point"].values) == ["com", "M_xz", "M_yz", "tip_edge"]
    assert ds["pos"].dims == ("point", "axis", "time")
    assert np.isclose(float(ds["time"][-1]), 1.15e-3)
    from gprm.predict.files import read_parameters

    values, fitted = read_parameters(ds)                 # variables along `parameter`
    assert values["h2"] == pytest.approx(0.031) and "h2" not in fitted
    assert ds["parameter_units"].sel(parameter="h2").item() == "m"
    assert "parameters_json" not in ds.attrs and "masses_json" not in ds.attrs
    for v in ("pos_p2_5", "pos_p97_5", "pos_std_linear", "vel", "overshoot", "hist_measured",
              "hist_model_point", "mass_nominal", "clearance", "p_cross"):
        assert v in ds and "units" in ds[v].attrs, v
    from gprm.predict.files import read_energy_window

    span = np.diff(read_energy_window(ds))[0]
    for h in ("hist_model_point", "hist_measured", "hist_model_total"):
        assert float(ds[h].sum()) == pytest.approx(span, rel=1e-12)
    assert ds.attrs["samples_ok"] == 40 and ds.attrs["model"] == "gprm-3d"
    w = json.loads(wi.read_text())
    assert [s["name"] for s in w["scenarios"]] == ["piezo2", "piezo1", "piezo1_ecc_div10"]
    # issue 22: the ratios are printed, not only written (the rows of the report's table)
    from gprm.predict.whatif import ratio_rows

    assert "what-if overshoot ratios, baseline (piezo2) / strategy" in r.stdout
    for row in ratio_rows(w, missing="-"):
        line = next(ln for ln in r.stdout.splitlines() if ln.split()[:1] == [row[0]])
        assert line.split() == " ".join(row).split(), (line, row)
    p1 = w["ratios"][1]["headline"]
    assert f"{p1['x']:.3g} [" in r.stdout and "4, 6.4, 3.8" in r.stdout
    # same seed -> same file content
    out2 = tmp_path / "p2.nc"
    run(fit_json(tmp_path / "fit.json"), "--out", out2, "--samples", 40, "--seed", 3,
        "--means", means, "--gap", "2um", "--gap-std", "0.5 um", "--set", "h2=31 mm",
        "--t-end", 1.15e-3)
    xr.testing.assert_identical(ds.drop_attrs(), xr.open_dataset(out2).drop_attrs())


@pytest.mark.parametrize("args,needle", [
    (["--scale-eccentricity", "0"], "scale-eccentricity"),
    (["--scale-eccentricity", "-2"], "scale-eccentricity"),
    (["--t-start", "-1e-3"], "'--t-start': must be >= 0 s"),
    (["--t-start", "1.2e-3", "--t-end", "1.0e-3"], "must be after"),
    (["--t-end", "10", "--rate", "1e6"], "samples"),
    (["--set", "nope=3"], "unknown parameter"),
    (["--set", "h2=3 kg"], "dimension"),
    (["--piezo", "3"], "--piezo"),
    (["--gap", "-1um"], "gap"),
])
def test_bad_options(tmp_path, args, needle):
    r = run("paper", "--out", tmp_path / "x.nc", "--samples", 0, *args)
    assert r.exit_code == 2
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], r.output
    assert not (tmp_path / "x.nc").exists()


def test_bad_fit_files(tmp_path):
    r = run(fit_json(tmp_path / "f.json", model="gprm-2d"), "--out", tmp_path / "x.nc")
    assert r.exit_code == 2 and "gprm-2d" in r.output
    r = run(fit_json(tmp_path / "g.json", version=7), "--out", tmp_path / "x.nc")
    assert r.exit_code == 2 and "format version" in r.output
    r = run(tmp_path / "missing.json", "--out", tmp_path / "x.nc")
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1


def test_means_too_short(tmp_path):
    means = tmp_path / "short.nc"
    synthetic_means(paper(), t_end=1.1e-3).to_netcdf(means)
    r = run("paper", "--out", tmp_path / "x.nc", "--samples", 0, "--means", means)
    assert r.exit_code == 2 and "short.nc" in r.output and "not inside" in r.output


def test_span_beyond_voltage_trace(tmp_path):
    csv = tmp_path / "v.csv"
    csv.write_text("time,voltage\n0,120\n0.001,120\n0.00103,10\n0.00105,0\n0.00115,0\n")
    r = run("paper", "--out", tmp_path / "x.nc", "--samples", 0, "--voltage", csv)
    assert r.exit_code == 2 and "after the end of the simulated input" in r.output
    r = run("paper", "--out", tmp_path / "x.nc", "--samples", 5, "--voltage", csv,
            "--t-end", 1.14e-3, "--t-start", 0.9e-3)
    # the energy window (to 1.2 ms) is also beyond the trace
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1
    r = run("paper", "--out", tmp_path / "x.nc", "--samples", 5, "--voltage", csv,
            "--t-end", 1.14e-3, "--t-start", 0.9e-3, "--ke-end", 1.14e-3)
    assert r.exit_code == 0, r.output


def test_fit_without_covariance_predicts_with_its_best_fit(tmp_path):
    """A fit `gprm fit` wrote without a covariance (matrix null) still predicts: best fit
    only, no bands, and the file says so (issue 12: propagation never breaks)."""
    path = fit_json(tmp_path / "f.json")
    doc = json.loads(path.read_text())
    doc["correlation"]["matrix"] = None
    for e in doc["parameters"].values():
        e["stderr"] = None
    path.write_text(json.dumps(doc))
    out = tmp_path / "p.nc"
    r = run(path, "--out", out, "--samples", "5")
    assert r.exit_code == 0, r.output
    with xr.open_dataset(out) as ds:
        assert "best fit only" in ds.attrs["uncertainty"]
        assert np.all(np.isfinite(ds["pos"].values))


def test_singular_correlation_draws_are_simulable(tmp_path):
    """A fit with a rank-one correlation block and huge errors on the y springs (the
    situation that raised LinAlgError 'Singular matrix' before) predicts with bands."""
    path = fit_json(tmp_path / "f.json")
    doc = json.loads(path.read_text())
    names = doc["correlation"]["names"]
    R = np.eye(len(names))
    i, j = names.index("k_Cy"), names.index("k_Dy")
    R[i, j] = R[j, i] = -1.0
    doc["correlation"]["matrix"] = R.tolist()
    doc["parameters"]["k_Cy"]["stderr"] = 3 * doc["parameters"]["k_Cy"]["value"]
    doc["parameters"]["k_Dy"]["stderr"] = 3 * doc["parameters"]["k_Dy"]["value"]
    path.write_text(json.dumps(doc))
    out = tmp_path / "p.nc"
    r = run(path, "--out", out, "--samples", "8")
    assert r.exit_code == 0, r.output
    with xr.open_dataset(out) as ds:
        assert int(ds.attrs["samples_ok"]) == 8


def test_read_parameters_of_new_and_older_prediction_files():
    """The parameter set is variables since issue 15; files with the older JSON attributes
    read to the same values and fitted names."""
    from gprm.predict.files import parameters_dataset, read_parameters

    values, fitted = {"m2": 0.0124, "h2": 0.031, "k_lr": 1.64e6}, ("m2", "k_lr")
    ds = parameters_dataset(values, fitted)
    assert read_parameters(ds) == (values, ["m2", "k_lr"])
    assert list(ds["parameter_units"].values) == ["kg", "m", "kg/s**2"]
    old = xr.Dataset(attrs={"parameters_json": json.dumps(values),
                            "fitted_json": json.dumps(list(fitted))})
    assert read_parameters(old) == (values, ["m2", "k_lr"])
