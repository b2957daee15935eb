"""CLI: ``gprm predict`` (a thin layer over :mod:`gprm.predict.core`)."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from gprm.console import one_line_errors
from gprm.options import Int, Number, Quantity


def parse_overrides(items) -> dict:
    """``NAME=VALUE_WITH_UNIT`` strings -> {name: SI value} (bare numbers are SI)."""
    from gprm.errors import GprmInputError
    from gprm.params import REGISTRY
    from gprm.params.files import to_si

    out = {}
    for item in items or ():
        if "=" not in item:
            raise GprmInputError(f"expected NAME=VALUE, got {item!r}", field="--set")
        name, value = (s.strip() for s in item.split("=", 1))
        if name not in REGISTRY:
            raise GprmInputError(f"unknown parameter {name!r}", field="--set")
        out[name] = to_si(value, name, source="--set")
    return out


def parse_length(text: str, field: str) -> float:
    """A length such as ``2um`` or ``2e-6`` (bare numbers are metres) -> m."""
    import pint

    from gprm.errors import GprmInputError
    from gprm.units import ureg

    try:
        q: pint.Quantity | float = ureg().Quantity(text)
    except Exception as exc:
        raise GprmInputError(f"cannot parse length {text!r} ({exc})", field=field) from None
    if not isinstance(q, pint.Quantity):    # a bare number
        return float(q)
    if q.dimensionless:
        return float(q.magnitude)
    if q.dimensionality != ureg().Quantity(1, "m").dimensionality:
        raise GprmInputError(f"{text!r} is not a length", field=field)
    return float(q.to("m").magnitude)


#: PredictOptions field -> the flag that sets it (for error messages)
_FLAGS = {"piezo": "--piezo", "scale_eccentricity": "--scale-eccentricity",
          "overrides": "--set", "t_start": "--t-start", "t_end": "--t-end", "rate": "--rate",
          "samples": "--samples", "seed": "--seed", "bins": "--bins",
          "ke_window": "--ke-start/--ke-end", "gap": "--gap", "gap_std": "--gap-std"}


def register(app: typer.Typer, synth_app: typer.Typer) -> None:
    @app.command("predict")
    @one_line_errors
    def predict_cmd(
        fit: str = typer.Argument(..., help="fit result JSON, or 'paper' for Table 3"),
        out: Path = typer.Option(..., "--out", help="output NetCDF file"),
        piezo: int = typer.Option(2, "--piezo", parser=Int(1, 2),
                                  help="driven piezo: 1 (nominal) or 2"),
        scale_eccentricity: float = typer.Option(1.0, "--scale-eccentricity",
                                                 parser=Number(0, min_open=True),
                                                 help="factor on v2, g2, gamma, rho (> 0)"),
        set_: Optional[List[str]] = typer.Option(None, "--set",
                                                 help="override NAME=VALUE_WITH_UNIT"),
        t_start: float = typer.Option(0.95e-3, "--t-start", parser=Quantity("s", 0),
                                      metavar="TIME", help="span start, e.g. 0.95ms (bare: s)"),
        t_end: float = typer.Option(1.2e-3, "--t-end", parser=Quantity("s", 0, min_open=True),
                                    metavar="TIME", help="span end, e.g. 1.2ms (bare: s)"),
        rate: float = typer.Option(1e6, "--rate", parser=Quantity("Hz", 0, min_open=True),
                                   metavar="RATE", help="prediction sample rate, e.g. 1MHz "
                                                        "(bare: Hz)"),
        samples: int = typer.Option(200, "--samples", parser=Int(min=0, max=1_000_000),
                                    help="parameter sets drawn"),
        seed: int = typer.Option(0, "--seed", parser=Int(min=0), help="random seed"),
        means: Optional[Path] = typer.Option(None, "--means", help="mean-signals NetCDF "
                                             "(measured kinetic energy, Fig. 8)"),
        bins: int = typer.Option(20, "--bins", parser=Int(1, 100_000),
                                 help="kinetic-energy bins"),
        ke_start: float = typer.Option(0.97e-3, "--ke-start", parser=Quantity("s", 0),
                                       metavar="TIME", help="energy window start, e.g. 0.97ms "
                                                            "(bare: s)"),
        ke_end: float = typer.Option(1.2e-3, "--ke-end", parser=Quantity("s", 0,
                                     min_open=True), metavar="TIME",
                                     help="energy window end, e.g. 1.2ms (bare: s)"),
        gap: Optional[float] = typer.Option(None, "--gap", parser=Quantity("m", 0,
                                            min_open=True), metavar="LENGTH",
                                            help="available plunger-TM gap along the indent "
                                                 "normal, e.g. 2um (bare: m)"),
        gap_std: float = typer.Option("0", "--gap-std", parser=Quantity("m", 0),
                                      metavar="LENGTH",
                                      help="its standard deviation, e.g. 0.2um (bare: m)"),
        voltage: Optional[Path] = typer.Option(None, "--voltage", help="measured drive trace "
                                               "CSV (time s, voltage V)"),
        whatif_out: Optional[Path] = typer.Option(None, "--whatif",
                                                  help="also write the standard what-if "
                                                       "table (JSON)"),
        ignore_sidecar: bool = typer.Option(False, "--ignore-sidecar",
                                            help="use the fit without its .nc sidecar where "
                                                 "that is missing, damaged or not the fit's "
                                                 "own (its draws are then not used: bands "
                                                 "from the covariance, narrower); said in "
                                                 "the output"),
    ):
        """Predict trajectories, kinetic energy, masses, overshoot and impact risk."""
        from gprm.errors import GprmInputError
        from gprm.predict.api import PredictOptions, run_predict, run_whatif
        from gprm.fit.files import load_model, model_inputs
        from gprm.predict.files import write_prediction

        from gprm._io import check_outputs
        from gprm.resources import check_memory

        check_outputs([(out, "--out"), (whatif_out, "--whatif")],
                      inputs=[*model_inputs(fit), means, voltage])
        # about 1.95 kB per drawn set and time (measured with tracemalloc at 20 and 80 sets
        # over the default 251 times; docs/README.md) plus a fixed 50 MB
        n_times = (t_end - t_start) * rate + 1
        if n_times > 0:
            check_memory(max(samples, 1) * n_times, 2500.0, fixed=50e6, field="--samples",
                         what=f"{samples} sets x {n_times:.4g} times", unit_scale=n_times,
                         integer=True)
        if means is not None:
            from gprm.campaign.files import read_means

            read_means(means)         # refuse a bad file before the prediction runs
        try:
            opts = PredictOptions(piezo=piezo, scale_eccentricity=scale_eccentricity,
                                  overrides=parse_overrides(set_), name="cli", t_start=t_start,
                                  t_end=t_end, rate=rate, samples=samples, seed=seed,
                                  means=means, bins=bins, ke_window=(ke_start, ke_end), gap=gap,
                                  gap_std=gap_std, voltage=voltage)
        except GprmInputError as exc:
            flag = None if exc.field is None else _FLAGS.get(exc.field, exc.field)
            raise GprmInputError(exc.problem, source=exc.source, field=flag) from None
        fm = load_model(fit, ignore_sidecar=ignore_sidecar)
        if fm.sidecar_note:
            typer.echo(f"note: --ignore-sidecar: {fm.sidecar_note}")
        if not fm.has_uncertainty:
            typer.echo(f"note: {fm.uncertainty_note}")
        pred = run_predict(fm, opts)
        table = None if whatif_out is None else run_whatif(fm, opts)
        write_prediction(pred, out, table, whatif_out)
        os_, tr = pred.overshoot, pred.trajectories
        pts = list(tr.points)
        msg = (f"wrote {out}: {tr.time.size} times, {tr.n_ok}/{samples} samples, "
               f"piezo {piezo}; overshoot M_xz x {os_[pts.index('M_xz'), 0] * 1e6:.3f} um, "
               f"M_yz y {os_[pts.index('M_yz'), 1] * 1e6:.3f} um, "
               f"M_xz z {os_[pts.index('M_xz'), 2] * 1e6:.3f} um")
        if pred.risk is not None:
            msg += "; P(cross) " + ", ".join(f"{p} {v:.3f}" for p, v in
                                             zip(pred.risk.planes, pred.risk.p_cross))
        typer.echo(msg)
        if whatif_out is not None and table is not None:
            from gprm.predict.whatif import ratio_table_text

            typer.echo(ratio_table_text(table.to_json()))
            typer.echo(f"wrote {whatif_out}")
