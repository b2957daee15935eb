"""Campaign files: NetCDF and the CSV directory layout, bad input, the two commands."""

import csv
import hashlib
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

from gprm.campaign.files import read_campaign_dir, write_campaign_dir
from gprm.campaign.data import POSITIONS
from gprm.campaign.files import load_campaign, write_campaign
from gprm.cli import app
from gprm.errors import GprmInputError
from gprm.campaign.files import read_truth


def _hash_tree(path: Path) -> str:
    h = hashlib.sha256()
    files = sorted(p for p in Path(path).rglob("*") if p.is_file()) if Path(path).is_dir() \
        else [Path(path)]
    for p in files:
        h.update(str(p.relative_to(path if Path(path).is_dir() else p.parent)).encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def write_lab_dir(ds: xr.Dataset, root: Path, *, unit_um: bool = True) -> None:
    """Write a campaign the way a lab would, by hand (not with the library's exporter):
    displacement files in micrometres with a header, runs numbered from 1, voltage in V."""
    root.mkdir()
    t = ds["time"].values
    rows = [["# exported by a test", "", "", "", ""], ["position", "kind", "run", "file", "unit"]]
    scale = 1e6 if unit_um else 1.0
    for p in POSITIONS:
        for kind, var, dim in (("actuated", "displacement", "run"),
                               ("noise", "noise", "noise_run")):
            for j in range(ds.sizes[dim]):
                name = f"{p}_{kind[0]}{j + 1}.csv"
                y = ds[var].sel(position=p).isel({dim: j}).values * scale
                with (root / name).open("w") as fh:
                    fh.write("time [s],displacement\n")
                    for a, b in zip(t, y):
                        fh.write(f"{float(a):.17g},{float(b):.17g}\n")
                rows.append([p, kind, str(j + 1), name, "um" if unit_um else ""])
    if "voltage" in ds.variables:
        vt = ds["vtime"].values
        for j in range(ds.sizes["vrun"]):
            name = f"volt_{j}.csv"
            np.savetxt(root / name, np.column_stack([vt, ds["voltage"].isel(vrun=j).values]),
                       delimiter=",", fmt="%.17g")
            rows.append(["", "voltage", str(j), name, ""])
    with (root / "manifest.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        for r in rows:
            if r[0].startswith("#"):
                fh.write(r[0] + "\n")
            else:
                w.writerow(r)


def test_netcdf_roundtrip(small_campaign, tmp_path):
    f = tmp_path / "c.nc"
    write_campaign(small_campaign, f)
    back = load_campaign(f)
    for v in ("displacement", "noise", "voltage", "trigger_offset", "truth_displacement"):
        np.testing.assert_array_equal(back[v].values, small_campaign[v].values)
    assert back.attrs["seed"] == 3 and back.attrs["sample_rate"] == 200e3
    assert read_truth(back) == read_truth(small_campaign) and read_truth(back)
    assert back.attrs["campaign_sha256"] == hashlib.sha256(f.read_bytes()).hexdigest()


def test_lab_csv_directory_imports_to_the_same_structure(small_campaign, tmp_path):
    write_lab_dir(small_campaign, tmp_path / "lab")
    ds = load_campaign(tmp_path / "lab")
    assert ds["displacement"].dims == ("position", "run", "time")
    assert [str(p) for p in ds["position"].values] == list(POSITIONS)
    assert ds.attrs["sample_rate"] == pytest.approx(200e3, rel=1e-9)
    for v in ("displacement", "noise"):
        np.testing.assert_allclose(ds[v].values, small_campaign[v].values, rtol=1e-12,
                                   atol=1e-24)
    np.testing.assert_allclose(ds["voltage"].values, small_campaign["voltage"].values,
                               rtol=1e-15)
    assert ds["displacement"].attrs["units"] == "m"


def test_exporter_roundtrip_and_preprocess_equal(small_campaign, tmp_path):
    from gprm.campaign.preprocess import preprocess

    write_campaign_dir(small_campaign, tmp_path / "exp", unit="nm")
    ds = read_campaign_dir(tmp_path / "exp")
    np.testing.assert_allclose(ds["displacement"].values, small_campaign["displacement"].values,
                               rtol=1e-12, atol=1e-24)
    a = preprocess(ds)
    b = preprocess(small_campaign)
    np.testing.assert_allclose(a.mean, b.mean, rtol=1e-6, atol=1e-15)
    np.testing.assert_allclose(a.shift, b.shift, atol=1e-12)


def test_same_seed_same_file(tmp_path):
    from gprm.campaign.synth import SynthConfig, synth_campaign

    cfg = SynthConfig(n_runs=3, n_noise=1, nonlinear=False)
    a, b = synth_campaign(seed=5, config=cfg), synth_campaign(seed=5, config=cfg)
    xr.testing.assert_identical(a, b)
    write_campaign(a, tmp_path / "a.nc")
    write_campaign(b, tmp_path / "b.nc")
    assert (tmp_path / "a.nc").read_bytes() == (tmp_path / "b.nc").read_bytes()
    c = synth_campaign(seed=6, config=cfg)
    assert not np.array_equal(a["displacement"].values, c["displacement"].values)


# --- bad input ----------------------------------------------------------------------------

def _nc_variant(ds, tmp_path, kind):
    ds = ds.copy(deep=True)
    if kind == "missing position":
        ds = ds.drop_sel(position="x_fl")
    elif kind == "sample rate":
        ds.attrs["sample_rate"] = 100e3
    elif kind == "nan":
        ds["displacement"][2, 1, 50] = np.nan
    elif kind == "inf":
        ds["noise"][4, 0, 7] = np.inf
    elif kind == "flat":
        ds["displacement"][3, 2, :] = 1e-6
    elif kind == "empty noise":
        ds = ds.isel(noise_run=slice(0, 0))
    path = tmp_path / f"bad_{kind.replace(' ', '_')}.nc"
    ds.to_netcdf(path)
    return path


NC_CASES = {"missing position": "position", "sample rate": "sample_rate", "nan": "displacement",
            "inf": "noise", "flat": "displacement", "empty noise": "noise"}


def _one_line_load_error(path) -> str:
    """The message of the input error ``load_campaign(path)`` raises (checked one line)."""
    with pytest.raises(GprmInputError) as exc:
        load_campaign(path)
    msg = str(exc.value)
    assert "\n" not in msg, msg
    return msg


@pytest.mark.parametrize("kind", list(NC_CASES))
def test_bad_netcdf(small_campaign, tmp_path, kind):
    path = _nc_variant(small_campaign, tmp_path, kind)
    msg = _one_line_load_error(path)
    assert str(path) in msg and f"'{NC_CASES[kind]}'" in msg, msg


def test_corrupted_netcdf(small_campaign, tmp_path):
    good = tmp_path / "c.nc"
    write_campaign(small_campaign, good)
    bad = tmp_path / "corrupt.nc"
    data = good.read_bytes()
    bad.write_bytes(data[:200] + b"\x00garbage" * 50 + data[600:1000])
    with pytest.raises(GprmInputError, match="corrupt.nc"):
        load_campaign(bad)


def _csv_variant(ds, tmp_path, kind):
    root = tmp_path / f"lab_{kind.replace(' ', '_')}"
    write_lab_dir(ds, root)
    man = (root / "manifest.csv").read_text().splitlines()
    victim = root / "x_head_a2.csv"
    if kind == "missing position":
        man = [ln for ln in man if not ln.startswith("z_fl,")]
    elif kind == "unequal length":
        lines = victim.read_text().splitlines()
        victim.write_text("\n".join(lines[:-10]) + "\n")
    elif kind == "sample rate":
        lines = victim.read_text().splitlines()
        out = [lines[0]] + [f"{2 * float(ln.split(',')[0]):.17g},{ln.split(',')[1]}"
                            for ln in lines[1:]]
        victim.write_text("\n".join(out) + "\n")
    elif kind in ("nan", "inf"):
        lines = victim.read_text().splitlines()
        t = lines[40].split(",")[0]
        lines[40] = f"{t},{kind}"
        victim.write_text("\n".join(lines) + "\n")
    elif kind == "flat":
        lines = victim.read_text().splitlines()
        victim.write_text("\n".join([lines[0]] + [ln.split(",")[0] + ",0.25" for ln in
                                                   lines[1:]]) + "\n")
    elif kind == "empty noise":
        man = [ln for ln in man if not ln.startswith("y_lr,noise")]
    (root / "manifest.csv").write_text("\n".join(man) + "\n")
    return root


CSV_CASES = {"missing position": ("manifest.csv", "position"),
             "unequal length": ("x_head_a2.csv", "time"),
             "sample rate": ("x_head_a2.csv", "time"),
             "nan": ("x_head_a2.csv", "value"), "inf": ("x_head_a2.csv", "value"),
             "flat": ("x_head_a2.csv", "value"),
             "empty noise": ("manifest.csv", "noise")}


@pytest.mark.parametrize("kind", list(CSV_CASES))
def test_bad_csv_directory(small_campaign, tmp_path, kind):
    root = _csv_variant(small_campaign, tmp_path, kind)
    msg = _one_line_load_error(root)
    fname, field = CSV_CASES[kind]
    assert fname in msg and f"'{field}'" in msg, msg


# --- the commands ---------------------------------------------------------------------------

def test_cli_bad_inputs_write_nothing_and_change_nothing(small_campaign, tmp_path):
    runner = CliRunner()
    inputs = [_nc_variant(small_campaign, tmp_path, k) for k in NC_CASES]
    inputs += [_csv_variant(small_campaign, tmp_path, k) for k in ("unequal length", "nan")]
    corrupt = tmp_path / "corrupt.nc"
    corrupt.write_bytes(b"CDF\x01 not really")
    inputs.append(corrupt)
    for src in inputs:
        before = _hash_tree(src)
        out = tmp_path / "out" / "m.nc"
        res = runner.invoke(app, ["preprocess", str(src), "--out", str(out)])
        assert res.exit_code == 2, (src, res.output)
        err = res.stderr.strip()
        assert err.startswith("gprm: error:") and "\n" not in err and src.name in err
        assert not out.exists()
        assert not out.parent.exists() or not any(out.parent.iterdir())
        assert _hash_tree(src) == before


def test_cli_synth_and_preprocess(tmp_path):
    runner = CliRunner()
    c = tmp_path / "c.nc"
    res = runner.invoke(app, ["synth", "campaign", "--seed", "2", "--runs", "4",
                              "--noise-runs", "2", "--no-nonlinear", "--out", str(c)])
    assert res.exit_code == 0, res.output
    before = _hash_tree(c)
    m = tmp_path / "m.nc"
    res = runner.invoke(app, ["preprocess", str(c), "--out", str(m)])
    assert res.exit_code == 0, res.output
    assert "max(x_head)/max(x_lr)" in res.stdout and "x_fl" in res.stdout
    assert _hash_tree(c) == before
    ds = xr.open_dataset(m)
    try:
        assert int(ds["n_runs"].values[0]) == 4
        assert read_truth(ds)["m2"] > 0
        assert ds.attrs["campaign_sha256"] == hashlib.sha256(c.read_bytes()).hexdigest()
    finally:
        ds.close()
    # bad option values: one line, nothing written
    bad = tmp_path / "bad.nc"
    res = runner.invoke(app, ["synth", "campaign", "--runs", "1", "--out", str(bad)])
    assert res.exit_code == 2 and "--runs" in res.stderr and not bad.exists()


def test_units_converted_on_read(small_campaign, tmp_path):
    ds = small_campaign.copy(deep=True)
    ds["displacement"] = ds["displacement"] * 1e6
    ds["displacement"].attrs["units"] = "um"
    ds.to_netcdf(tmp_path / "um.nc")
    back = load_campaign(tmp_path / "um.nc")
    assert back["displacement"].attrs["units"] == "m"
    np.testing.assert_allclose(back["displacement"].values,
                               small_campaign["displacement"].values, rtol=1e-12)
    ds["displacement"].attrs["units"] = "furlongs per volt"
    ds.to_netcdf(tmp_path / "bad_unit.nc")
    with pytest.raises(GprmInputError, match="bad_unit.nc.*'displacement'"):
        load_campaign(tmp_path / "bad_unit.nc")


def test_cli_truth_file(tmp_path):
    toml = tmp_path / "truth.toml"
    toml.write_text('[parameters]\nm2 = "13.1 g"\nk_Ax = 1.0e8\n')
    out = tmp_path / "c.nc"
    res = CliRunner().invoke(app, ["synth", "campaign", "--truth", str(toml), "--runs", "2",
                                   "--noise-runs", "1", "--no-nonlinear", "--out", str(out)])
    assert res.exit_code == 0, res.output
    ds = load_campaign(out)
    truth = read_truth(ds)
    assert truth["m2"] == pytest.approx(0.0131) and truth["k_Ax"] == 1.0e8
