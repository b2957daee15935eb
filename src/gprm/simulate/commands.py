"""CLI: ``gprm simulate``."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from gprm.console import one_line_errors
from gprm.options import Int, Quantity


def register(app: typer.Typer, synth_app: typer.Typer) -> None:
    @app.command("simulate")
    @one_line_errors
    def simulate_cmd(
        out: Path = typer.Option(..., "--out", help="output NetCDF file"),
        params: Optional[Path] = typer.Option(None, "--params", help="TOML parameter file"),
        piezo: int = typer.Option(2, "--piezo", parser=Int(1, 2),
                                  help="driven piezo: 1 (nominal) or 2"),
        voltage: Optional[Path] = typer.Option(None, "--voltage",
                                               help="measured trace CSV (time s, voltage V)"),
        t_end: float = typer.Option(1.2e-3, "--t-end", parser=Quantity("s", 0, min_open=True),
                                    metavar="TIME", help="record length, e.g. 1.2ms (bare: s)"),
        rate: float = typer.Option(200e3, "--rate", parser=Quantity("Hz", 0, min_open=True),
                                   metavar="RATE", help="sample rate, e.g. 200kHz (bare: Hz)"),
        z_bk_absolute: bool = typer.Option(False, "--z-bk-absolute",
                                           help="z_bk as z_lr + z_A (laser on the plunger "
                                                "back sees both) instead of Eq. 3's z_A"),
    ):
        """Simulate the tip retraction (exact linear model) and write NetCDF."""
        from gprm.params import load_params
        from gprm.simulate import read_voltage_csv, simulate
        from gprm.simulate.files import simulation_dataset, write_simulation

        from gprm._io import check_outputs
        from gprm.model.piezo import check_piezo
        from gprm.resources import check_memory

        check_piezo(piezo, field="--piezo")
        check_outputs({out: "--out"}, inputs=[params, voltage])
        # about 1.6 kB per sample (the simulated states, their rates and outputs, the dataset;
        # measured with tracemalloc, docs/README.md) plus a fixed 50 MB
        check_memory(t_end * rate + 1, 2000.0, fixed=50e6, field="--rate", unit="Hz",
                     what=f"{t_end * rate + 1:.4g} samples", unit_scale=t_end)
        ps = load_params(params)
        trace = read_voltage_csv(voltage) if voltage is not None else None
        res = simulate(ps, piezo=piezo, t_end=t_end, rate=rate, voltage=trace,
                       z_bk_absolute=z_bk_absolute)
        ds = simulation_dataset(res, ps, source=str(voltage) if voltage else "",
                                z_bk_absolute=z_bk_absolute)
        write_simulation(ds, out)
        peak = {k: float(abs(ds[k]).max()) for k in ("x_head", "y_head", "z_bk")}
        typer.echo(f"wrote {out}: {ds.sizes['time']} samples, piezo {piezo}; peaks "
                   + ", ".join(f"{k} {v * 1e6:.3f} um" for k, v in peak.items()))
