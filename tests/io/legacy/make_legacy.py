"""How the files in this folder were made: one NetCDF file of each kind gprm wrote before its
metadata became variables (JSON strings in attributes, velocities along one mixed-unit
``axis``), written by gprm at commit 5a2516a and trimmed to keep them small. The readers'
legacy fallback is tested on them (tests/io/test_formats.py). Not run by the tests:
``python make_legacy.py OUT_DIR`` with that version of gprm installed."""
import shutil
import sys
from pathlib import Path

import xarray as xr
from typer.testing import CliRunner

from gprm.cli import app

RUNNER = CliRunner()


def run(*args):
    res = RUNNER.invoke(app, [str(x) for x in args])
    assert res.exit_code == 0, (args, res.output)


def main(d: Path) -> None:
    d.mkdir(exist_ok=True, parents=True)
    tmp = d / "tmp"
    tmp.mkdir(exist_ok=True)
    run("synth", "campaign", "--out", tmp / "campaign.nc", "--runs", 2, "--noise-runs", 1,
        "--no-nonlinear", "--seed", 1)
    run("preprocess", tmp / "campaign.nc", "--out", tmp / "means.nc")
    run("simulate", "--out", tmp / "sim.nc", "--t-end", "1.1e-3")
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "predict"))
    from test_predict_cli import fit_json

    fit_json(tmp / "fit.json")
    run("predict", tmp / "fit.json", "--out", tmp / "predict.nc", "--samples", 4, "--means",
        tmp / "means.nc", "--gap", "2um", "--t-start", "1e-3", "--t-end", "1.02e-3")
    run("synth", "telemetry", "paper", "--out", tmp / "telemetry.nc", "--releases", 2,
        "--no-spread", "--post", "2s")
    run("impact", "paper", tmp / "telemetry.nc", "--out", tmp / "impact.json", "--samples", 4)
    with xr.open_dataset(tmp / "campaign.nc") as c:
        c = c.load().drop_vars(["voltage", "vtime", "vrun", "truth_displacement",
                                "truth_time"]).isel(time=slice(0, 40))
        c.to_netcdf(d / "campaign_v1.nc")
    with xr.open_dataset(tmp / "means.nc") as m:
        m = m.load().isel(time=slice(150, 170))
        m.to_netcdf(d / "means_v1.nc")
    for name in ("sim", "predict", "telemetry", "impact"):
        with xr.open_dataset(tmp / f"{name}.nc") as x:
            x = x.load()
            if name in ("impact", "sim"):
                x = x.isel(time=slice(0, None, 10))
            if name == "predict":
                x = x.drop_vars(["pos_samples"])
            x.to_netcdf(d / f"{name}_v1.nc")
    shutil.rmtree(tmp)
    for p in sorted(d.iterdir()):
        print(p.name, p.stat().st_size)


if __name__ == "__main__":
    main(Path(sys.argv[1]))
