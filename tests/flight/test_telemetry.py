"""Telemetry format, release-velocity line fit, bad input (library and CLI)."""

import numpy as np
import pytest

from gprm.errors import GprmInputError
from gprm.flight.files import load_telemetry, telemetry_dataset, telemetry_from_dataset
from gprm.flight.telemetry import AXES, fit_release_velocity, release_velocities


def _tel(R=3, S=60, rate=10.0, seed=0, v=None):
    rng = np.random.default_rng(seed)
    t_rel = 100.0 * (1 + np.arange(R))
    time = t_rel[:, None] - 1.0 + np.arange(S)[None] / rate
    v = v if v is not None else {c: rng.normal(0, 1e-5, R)
                                 for c in ("x", "y", "z", "theta", "eta", "phi")}
    dt = np.clip(time - t_rel[:, None], 0, None)
    data = {c: 1e-6 + v[c][:, None] * dt + rng.normal(0, 2e-9, (R, S)) for c in v}
    ds = telemetry_dataset([f"R{i + 1:02d}" for i in range(R)], time, t_rel, data,
                           noise_std={c: 2e-9 for c in v})
    return ds, v


def test_weighted_line_fit_against_statsmodels_wls():
    import statsmodels.api as sm

    rng = np.random.default_rng(1)
    t = np.sort(rng.uniform(0.1, 5, 40))
    sig = rng.uniform(1e-9, 5e-9, 40)
    y = 3e-7 + 2.5e-5 * t + sig * rng.standard_normal(40)
    f = fit_release_velocity(t, y, sig)
    res = sm.WLS(y, sm.add_constant(t), weights=1 / sig ** 2).fit(cov_type="fixed scale")
    assert f.value == pytest.approx(res.params[1], rel=1e-9)
    assert f.stderr == pytest.approx(res.bse[1], rel=1e-9)
    # without sigma: ordinary least squares, residual-scaled stderr
    g = fit_release_velocity(t, y)
    r2 = sm.OLS(y, sm.add_constant(t)).fit()
    assert g.value == pytest.approx(r2.params[1], rel=1e-9)
    assert g.stderr == pytest.approx(r2.bse[1], rel=1e-9)


def test_release_velocity_recovers_slope_and_roundtrip(tmp_path):
    from gprm._io import write_netcdf_atomic

    ds, v = _tel(R=4, S=80)
    p = tmp_path / "tel.nc"
    write_netcdf_atomic(ds, p)
    tel = load_telemetry(p)
    assert [r.id for r in tel.releases] == ["R01", "R02", "R03", "R04"]
    vel = release_velocities(tel)
    ch = {"vx": "x", "vz_xz": "z", "wy": "eta", "vy": "y", "vz_yz": "z", "wx": "theta"}
    for i, r in enumerate(tel.releases):
        for a in AXES:
            f = vel[r.id][a]
            assert f.weighted and f.n == int(np.sum(r.time > r.release_time))
            assert abs(f.value - v[ch[a]][i]) < 5 * f.stderr


def _bad(ds, tmp_path, name="bad.nc"):
    from gprm._io import write_netcdf_atomic
    p = tmp_path / name
    write_netcdf_atomic(ds, p)
    return p


def test_bad_inputs_library(tmp_path):
    ds, _ = _tel(R=2, S=30)
    # too few samples after the release
    short = ds.copy(deep=True)
    short["time"].values[:, :] = short["time"].values - 2.8  # only ~1 sample after release
    with pytest.raises(GprmInputError, match="samples after the release"):
        release_velocities(telemetry_from_dataset(short))
    # missing axis channel
    with pytest.raises(GprmInputError, match="eta"):
        telemetry_from_dataset(ds.drop_vars("eta"))
    # non-monotonic time
    nm = ds.copy(deep=True)
    nm["time"].values[1, 5] = nm["time"].values[1, 3]
    with pytest.raises(GprmInputError, match="strictly increasing"):
        telemetry_from_dataset(nm)
    # NaN in a data channel
    nn = ds.copy(deep=True)
    nn["x"].values[0, 12] = np.nan
    with pytest.raises(GprmInputError, match="non-finite"):
        telemetry_from_dataset(nn)
    # NaN padding at the end of a shorter release is allowed
    pad = ds.copy(deep=True)
    for v in ("time", "x", "y", "z", "theta", "eta", "phi"):
        pad[v].values[1, -3:] = np.nan
    tel = telemetry_from_dataset(pad)
    assert tel.releases[1].time.size == 27 and tel.releases[0].time.size == 30


@pytest.mark.parametrize("case,needle", [
    ("few", "samples after the release"), ("missing", "eta"),
    ("nonmono", "strictly increasing"), ("nan", "non-finite"),
    ("absent", "none.nc: telemetry file does not exist (a NetCDF or CSV file)"),
    ("absent_csv", "none.csv: telemetry file does not exist (a NetCDF or CSV file)")])
def test_bad_inputs_cli(tmp_path, case, needle):
    from typer.testing import CliRunner
    from gprm.cli import app

    ds, _ = _tel(R=2, S=30)
    if case == "few":
        ds["time"].values[:, :] = ds["time"].values - 2.8
    elif case == "missing":
        ds = ds.drop_vars("eta")
    elif case == "nonmono":
        ds["time"].values[0, 7] = ds["time"].values[0, 2]
    elif case == "nan":
        ds["theta"].values[1, 20] = np.nan
    p = (_bad(ds, tmp_path) if not case.startswith("absent")
         else tmp_path / ("none.csv" if case == "absent_csv" else "none.nc"))
    res = CliRunner().invoke(app, ["impact", "paper", str(p), "--out",
                                   str(tmp_path / "o.json"), "--samples", "4"])
    assert res.exit_code == 2
    err = res.stderr if hasattr(res, "stderr") else res.output
    lines = [x for x in err.strip().splitlines() if x]
    assert len(lines) == 1 and needle in lines[0] and lines[0].startswith("gprm: error:")
    assert not (tmp_path / "o.json").exists()


# ---------------------------------------------------------------- real telemetry: units, CSV
SCALE = {"x": ("mm", 1e3), "y": ("um", 1e6), "z": ("µm", 1e6), "theta": ("µrad", 1e6),
         "eta": ("mrad", 1e3), "phi": ("deg", 180 / np.pi)}


def _to_csv(ds, path, *, with_std=False):
    """The telemetry as a user would export it: one row per sample, units in the header."""
    import pandas as pd

    rows = []
    R, S = ds.sizes["release"], ds.sizes["sample"]
    for i in range(R):
        for k in range(S):
            row = {"release": str(ds["release"].values[i]),
                   "time [ms]": ds["time"].values[i, k] * 1e3,
                   "release_time [ms]": ds["release_time"].values[i] * 1e3}
            for c, (u, f) in SCALE.items():
                row[f"{c} [{u}]"] = ds[c].values[i, k] * f
                if with_std:
                    row[f"{c}_std ({u})"] = ds[c].attrs["noise_std"] * f
            rows.append(row)
    pd.DataFrame(rows).to_csv(path, index=False)
    return path


def _si_velocities(tel):
    return {r: {a: f.value for a, f in d.items()} for r, d in release_velocities(tel).items()}


def test_units_are_converted_netcdf(tmp_path):
    from gprm._io import write_netcdf_atomic

    ds, _ = _tel(R=3, S=50)
    ref = _si_velocities(telemetry_from_dataset(ds))
    alt = ds.copy(deep=True)
    for c, (u, f) in SCALE.items():
        alt[c] = alt[c] * f
        alt[c].attrs = {"units": u, "noise_std": ds[c].attrs["noise_std"] * f}
    alt["time"] = alt["time"] * 1e3
    alt["time"].attrs = {"units": "ms"}
    alt["release_time"] = alt["release_time"] * 1e3
    alt["release_time"].attrs = {"units": "ms"}
    p = tmp_path / "units.nc"
    write_netcdf_atomic(alt, p)
    tel = load_telemetry(p)
    got = _si_velocities(tel)
    for r in ref:
        for a in AXES:
            assert got[r][a] == pytest.approx(ref[r][a], rel=1e-9)
    assert tel.releases[0].sigma["x"][0] == pytest.approx(2e-9, rel=1e-12)


@pytest.mark.parametrize("with_std", [False, True])
def test_csv_import_equals_netcdf(tmp_path, with_std):
    ds, _ = _tel(R=3, S=50)
    if not with_std:
        for c in SCALE:
            ds[c].attrs.pop("noise_std")
    ref = release_velocities(telemetry_from_dataset(ds))
    tel = load_telemetry(_to_csv(ds, tmp_path / "tel.csv", with_std=with_std))
    assert [r.id for r in tel.releases] == ["R01", "R02", "R03"]
    got = release_velocities(tel)
    for r in ref:
        for a in AXES:
            assert got[r][a].value == pytest.approx(ref[r][a].value, rel=1e-7)
            assert got[r][a].weighted == with_std


def test_bad_real_inputs(tmp_path):
    import pandas as pd

    ds, _ = _tel(R=2, S=30)
    bad = ds.copy(deep=True)
    for u in ("kelvin", "xyzzy", "m/s"):
        bad["x"].attrs["units"] = u
        with pytest.raises(GprmInputError, match="not a length unit") as e:
            telemetry_from_dataset(bad, source="f.nc")
        assert e.value.field == "x" and e.value.source == "f.nc"
    bad = ds.copy(deep=True)
    bad["theta"].attrs["units"] = "mm"
    with pytest.raises(GprmInputError, match="not an angle unit"):
        telemetry_from_dataset(bad)
    with pytest.raises(GprmInputError, match=">= 2"):
        telemetry_from_dataset(ds.isel(release=[0]))
    bad = ds.copy(deep=True)
    bad["y"].values[1, :] = 0.0
    with pytest.raises(GprmInputError, match="constant") as e:
        telemetry_from_dataset(bad)
    assert e.value.field == "y" and "R02" in str(e.value)
    bad = ds.copy(deep=True)
    bad["z"] = bad["z"].astype(str)
    with pytest.raises(GprmInputError, match="real numbers"):
        telemetry_from_dataset(bad)
    bad = ds.copy(deep=True)
    bad["release_time"] = bad["x"]
    with pytest.raises(GprmInputError, match="dims"):
        telemetry_from_dataset(bad)
    # CSV: missing column, a non-number (row named), scattered rows of a release
    p = _to_csv(ds, tmp_path / "t.csv")
    df = pd.read_csv(p)
    df.drop(columns=["eta [mrad]"]).to_csv(tmp_path / "m.csv", index=False)
    with pytest.raises(GprmInputError, match="missing column") as e:
        load_telemetry(tmp_path / "m.csv")
    assert e.value.field == "eta"
    d2 = df.astype({"x [mm]": object})
    d2.loc[7, "x [mm]"] = "n/a"
    d2.to_csv(tmp_path / "n.csv", index=False)
    with pytest.raises(GprmInputError, match="line 9"):
        load_telemetry(tmp_path / "n.csv")
    df.iloc[[0, 40, 1] + list(range(2, 40)) + list(range(41, 60))].to_csv(
        tmp_path / "s.csv", index=False)
    with pytest.raises(GprmInputError, match="not contiguous"):
        load_telemetry(tmp_path / "s.csv")
    (tmp_path / "e.csv").write_bytes(b"")
    with pytest.raises(GprmInputError, match="cannot be read as CSV"):
        load_telemetry(tmp_path / "e.csv")
    (tmp_path / "b.csv").write_bytes(b"release,time\n\xff\xfe,1\n")
    with pytest.raises(GprmInputError, match="cannot be read as CSV"):
        load_telemetry(tmp_path / "b.csv")
    (tmp_path / "r.csv").write_text("# measured\n" + p.read_text().replace("\n", ",1\n", 3))
    with pytest.raises(GprmInputError, match="fields"):
        load_telemetry(tmp_path / "r.csv")


def test_cli_reads_csv(tmp_path):
    from typer.testing import CliRunner
    from gprm.cli import app
    from gprm.flight.synth import SynthOptions, synth_telemetry
    from gprm.fit.files import paper_model

    ds = synth_telemetry(paper_model(), SynthOptions(n_releases=3, seed=1))
    p = _to_csv(ds, tmp_path / "rel.csv", with_std=True)
    before = p.read_bytes()
    res = CliRunner().invoke(app, ["impact", "paper", str(p), "--out",
                                   str(tmp_path / "o.json"), "--samples", "40",
                                   "--scenario-draws", "500"])
    assert res.exit_code == 0, res.output
    import json
    doc = json.loads((tmp_path / "o.json").read_text())
    assert "truth" not in doc and len(doc["releases"]) == 3
    # the same scenario analysis as a synthetic file, and no truth claimed (issue 23, item 5)
    sc = doc["scenarios"]
    assert len(sc["releases"]) == 3 and sc["joint"]["chosen"] in ("xz", "yz", "two")
    assert "truth_summary" not in sc and not any("truth" in r for r in sc["releases"])
    assert "truth (synthetic)" not in res.output and "scenarios: chosen" in res.output
    assert sum(v["value"] is not None for r in doc["releases"]
               for v in r["impact_time"].values()) >= 15
    assert p.read_bytes() == before                       # input never modified
