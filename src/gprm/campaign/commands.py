"""CLI: ``gprm synth campaign`` and ``gprm preprocess``."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from gprm.console import one_line_errors
from gprm.options import Int, Quantity


def register(app: typer.Typer, synth_app: typer.Typer) -> None:
    @synth_app.command("campaign")
    @one_line_errors
    def synth_campaign_cmd(
        out: Path = typer.Option(..., "--out", help="output campaign NetCDF"),
        truth: Optional[Path] = typer.Option(None, "--truth",
                                             help="TOML parameter file of the true set "
                                                  "(default: drawn around the paper set)"),
        seed: int = typer.Option(0, "--seed", parser=Int(min=0),
                                 help="random seed (same seed, same file)"),
        runs: int = typer.Option(10, "--runs", parser=Int(min=2, max=10000),
                                 help="actuated runs per position"),
        noise_runs: int = typer.Option(5, "--noise-runs", parser=Int(min=1, max=10000),
                                       help="noise runs per position"),
        t_end: float = typer.Option(1.5e-3, "--t-end", parser=Quantity("s", 1.2e-3, 0.1,
                                    min_open=True), metavar="TIME",
                                    help="record length in (1.2 ms, 100 ms], e.g. 1.5ms "
                                         "(bare: s)"),
        no_nonlinear: bool = typer.Option(False, "--no-nonlinear",
                                          help="skip the nonlinear correction (faster)"),
        piezo: int = typer.Option(2, "--piezo", parser=Int(1, 2),
                                  help="driven piezo: 1 (nominal) or 2 (as the paper's "
                                       "campaign)"),
    ):
        """Synthetic ground-test campaign with known truth (richer model than the fit's)."""
        from gprm.campaign.files import write_campaign
        from gprm.campaign.synth import SynthConfig, synth_campaign
        from gprm._io import check_outputs
        from gprm.params import load_params

        check_outputs({out: "--out"}, inputs=[truth])
        from gprm.resources import check_memory

        # 1.5 kB per recorded sample of each run and position (tracemalloc peak: 1.12 kB
        # between 4+2 and 16+8 runs of 301 samples; docs/README.md) plus a fixed 50 MB
        from gprm.campaign.data import POSITIONS

        per_run = len(POSITIONS) * (t_end * SynthConfig().rate + 1)
        check_memory(runs * per_run, 1500.0, fixed=50e6 + 1500.0 * per_run * noise_runs,
                     field="--runs", what=f"{runs} + {noise_runs} runs", unit_scale=per_run,
                     integer=True)
        ps = load_params(truth) if truth is not None else None
        cfg = SynthConfig(n_runs=runs, n_noise=noise_runs, t_end=t_end,
                          nonlinear=not no_nonlinear, piezo=piezo)
        ds = synth_campaign(ps, seed=seed, config=cfg)
        write_campaign(ds, out)
        typer.echo(f"wrote {out}: {ds.sizes['position']} positions x {ds.sizes['run']} "
                   f"actuated + {ds.sizes['noise_run']} noise runs x {ds.sizes['time']} "
                   f"samples at {ds.attrs['sample_rate'] / 1e3:g} kHz; seed {seed}")

    @app.command("preprocess")
    @one_line_errors
    def preprocess_cmd(
        campaign: Path = typer.Argument(..., help="campaign NetCDF file or CSV directory"),
        out: Path = typer.Option(..., "--out", help="output mean-signals NetCDF"),
        align_time: float = typer.Option(1.01e-3, "--align-time",
                                         parser=Quantity("s", 0, min_open=True),
                                         metavar="TIME",
                                         help="time at which each mean signal reaches the "
                                              "threshold, e.g. 1ms (bare: s)"),
    ):
        """Synchronise, average and align a campaign (Sec. 2); prints Table 1."""
        from gprm._io import check_outputs
        from gprm.campaign.api import PreprocessOptions, preprocess_campaign
        from gprm.campaign.files import campaign_inputs, write_means

        check_outputs({out: "--out"}, inputs=campaign_inputs(campaign))
        ms = preprocess_campaign(campaign, PreprocessOptions(align_time=align_time))
        write_means(ms, out)
        typer.echo(f"wrote {out}: {len(ms.signals)} mean signals x {ms.time.size} samples "
                   f"({ms.time[0] * 1e3:.3f}..{ms.time[-1] * 1e3:.3f} ms)")
        typer.echo(format_summary(ms))


def format_summary(ms) -> str:
    lines = ["Table 1 (ratios of mean-signal maxima):",
             f"  {'ratio':26s} {'data':>7s} {'paper':>6s}"]
    for k, v in ms.table1.items():
        lines.append(f"  {k:26s} {v['value']:7.2f} {v['paper']:6.0f}")
    lines.append("Dropped positions (Sec. 2 hypotheses):")
    for n, d in ms.dropped.items():
        flag = "supported" if d["supported"] else "NOT supported by the data"
        lines.append(f"  {n:6s} {d['hypothesis']}; {d['ratio']} = {d['value']:.2f} ({flag})")
    lines.append("Per signal: noise std, alignment shift, peak/std (Fig. 3a):")
    for i, n in enumerate(ms.signals):
        lines.append(f"  {n:7s} noise {ms.noise_std[i] * 1e6:.2e} um  shift "
                     f"{ms.shift[i] * 1e6:+8.2f} us  peak/std {ms.snr[n]['peak_over_std']:6.1f}")
    if ms.truth_alignment is not None:
        ta = ms.truth_alignment
        lines.append(f"Truth after alignment: t0 equivalent {ta['t0_expected_s'] * 1e6:.2f} us,"
                     f" t1 equivalent {ta['t1_expected_s'] * 1e6:.2f} us")
    return "\n".join(lines)
