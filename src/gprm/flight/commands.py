"""CLI: ``gprm synth telemetry`` and ``gprm impact``."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from gprm.console import cli_options, one_line_errors
from gprm.options import Int, Number, Quantity, Window


#: option fields -> the flags that set them, where the names differ
_SYNTH_FLAGS = {"n_releases": "--releases", "truth_spread": "--no-spread"}
_IMPACT_FLAGS = {"n_samples": "--samples"}


def register(app: typer.Typer, synth_app: typer.Typer) -> None:
    @synth_app.command("telemetry")
    @one_line_errors
    def synth_telemetry_cmd(
        fit: str = typer.Argument(..., help="fit result JSON, or 'paper' (Table 3)"),
        out: Path = typer.Option(..., "--out", help="output telemetry NetCDF"),
        releases: int = typer.Option(11, "--releases", parser=Int(1, 10_000),
                                     help="number of releases"),
        seed: int = typer.Option(0, "--seed", parser=Int(min=0), help="random seed"),
        piezo: Optional[int] = typer.Option(None, "--piezo", parser=Int(1, 2),
                                            help="driven piezo: 1 or 2 (default: fit's)"),
        rate: float = typer.Option(10.0, "--rate", parser=Quantity("Hz", 0, 1e6,
                                   min_open=True), metavar="RATE",
                                   help="GRS sample rate, e.g. 10Hz (bare: Hz)"),
        post: float = typer.Option(5.0, "--post", parser=Quantity("s", 0, 1e5, min_open=True),
                                   metavar="TIME",
                                   help="record after the release, e.g. 5s (bare: s)"),
        pos_noise: float = typer.Option(2e-9, "--pos-noise", parser=Quantity("m", 0,
                                        min_open=True), metavar="LENGTH",
                                        help="position noise std, e.g. 2nm (bare: m)"),
        att_noise: float = typer.Option(1e-6, "--att-noise", parser=Quantity("rad", 0,
                                        min_open=True), metavar="ANGLE",
                                        help="attitude noise std, e.g. 1urad (bare: rad)"),
        no_spread: bool = typer.Option(False, "--no-spread",
                                       help="truth from the best fit and nominal geometry"),
        z_from: str = typer.Option("sum", "--z-from",
                                   help="TM v_z with --truth-model planar: sum, xz or yz"),
        truth_model: str = typer.Option("scenario", "--truth-model",
                                        help="impact of the truth: scenario (see "
                                             "--scenario), 3d (one corner contact, issue 14) "
                                             "or planar (paper)"),
        scenario: str = typer.Option("two", "--scenario",
                                     help="contact scenario of the truth (--truth-model "
                                          "scenario): xz, yz, two (rim contacts), xz-face, "
                                          "yz-face, two-face, corner, or mixed (each release "
                                          "one of xz, yz, two)"),
        tm_offset: Optional[float] = typer.Option(None, "--tm-offset",
                                        parser=Quantity("m", 0, 0.01), metavar="LENGTH",
                                        help="largest lateral offset of the TM from the head "
                                             "axis, in x and y (scenario truths), e.g. 1mm "
                                             "(bare: m; default 1mm, docs/flight.md §10)"),
    ):
        """Synthetic in-flight releases with known impact times (telemetry NetCDF)."""
        from gprm._io import check_outputs
        from gprm.fit.files import load_model, model_inputs
        from gprm.flight.api import TelemetryOptions, run_synth_telemetry
        from gprm.flight.files import write_telemetry
        from gprm.flight.synth import SynthOptions
        from gprm.resources import check_memory

        opts = cli_options(TelemetryOptions, piezo=piezo, synth=cli_options(
            SynthOptions, _SYNTH_FLAGS, n_releases=releases, seed=seed, rate=rate, post=post,
            pos_noise=pos_noise, att_noise=att_noise, truth_spread=not no_spread,
            z_from=z_from, truth_model=truth_model, scenario=scenario,
            **({} if tm_offset is None else {"tm_offset": tm_offset})))
        check_outputs({out: "--out"}, inputs=model_inputs(fit))
        # 150 B per record sample (tracemalloc peak: 96 B per sample between 2 x 1e4 and
        # 2 x 4e4 samples; docs/README.md) plus a fixed 50 MB
        check_memory(releases * (post * rate + 1), 150.0, fixed=50e6, field="--rate",
                     unit="Hz", what=f"{releases} records of {post * rate + 1:.4g} samples",
                     unit_scale=releases * post)
        m = load_model(fit, piezo=piezo)
        ds = run_synth_telemetry(m, opts)
        write_telemetry(ds, out)
        tt = ds["truth_impact_time"].values * 1e3
        note = ("" if getattr(m, "has_uncertainty", True) or no_spread else
                "; the fit has no usable covariance: truth parameters are the best fit "
                "(geometry still drawn)")
        kind = truth_model if truth_model != "scenario" else f"scenario {scenario}"
        typer.echo(f"wrote {out}: {releases} releases, impact times {tt.min():.4f}-"
                   f"{tt.max():.4f} ms ({kind} impact truth){note}")

    @app.command("impact")
    @one_line_errors
    def impact_cmd(
        fit: str = typer.Argument(..., help="fit result JSON, or 'paper' (Table 3)"),
        telemetry: Path = typer.Argument(..., help="telemetry file: NetCDF or CSV (.csv)"),
        out: Path = typer.Option(..., "--out", help="output JSON (sidecar <name>.nc: curves)"),
        alpha: float = typer.Option(0.01, "--alpha", parser=Number(0, 1, min_open=True,
                                    max_open=True), help="Tukey test level (0 < alpha < 1)"),
        samples: int = typer.Option(200, "--samples", parser=Int(min=0, max=1_000_000),
                                    help="draws per uncertainty band"),
        seed: int = typer.Option(0, "--seed", parser=Int(min=0), help="seed of the band draws"),
        window: Optional[str] = typer.Option(None, "--window", parser=Window("s"),
                                             metavar="START,END",
                                             help="impact-time window, e.g. '1.0ms,1.2ms' "
                                                  "(bare numbers: s; default t_c .. t_c + "
                                                  "0.2 ms)"),
        fit_window: Optional[float] = typer.Option(None, "--fit-window",
                                                   parser=Quantity("s", 0, min_open=True),
                                                   metavar="TIME",
                                                   help="line fit over this long after the "
                                                        "release, e.g. 2s (bare: s; default: "
                                                        "all)"),
        piezo: Optional[int] = typer.Option(None, "--piezo", parser=Int(1, 2),
                                            help="driven piezo: 1 or 2 (default: fit's)"),
        impact_model: str = typer.Option("3d", "--impact-model",
                                         help="curves of the impact times: 3d (one corner "
                                              "contact), planar (the paper's two planes), xz, "
                                              "yz, two (rim-contact scenarios), or auto (the "
                                              "scenario chosen jointly over the releases)"),
        multi: bool = typer.Option(False, "--multi",
                                   help="also integrate plunger and TM with contact detection "
                                        "at each estimated impact (second impacts)"),
        scenario_draws: int = typer.Option(20000, "--scenario-draws",
                                           parser=Int(min=0, max=1_000_000),
                                           help="prior draws per scenario of the impact-"
                                                "scenario posterior (0: not computed)"),
    ):
        """Release velocities, impact times and Tukey's test from telemetry (JSON)."""
        from gprm._io import check_outputs
        from gprm.errors import GprmInputError
        from gprm.flight.analysis import AnalysisOptions
        from gprm.fit.files import load_model, model_inputs
        from gprm.flight.api import ImpactOptions, run_impact, write_impact
        from gprm.flight.files import impact_sidecar
        from gprm.flight.inference import InferenceOptions, probability_text

        from gprm.resources import check_memory

        # the band draws' curves: 554 kB per sample (maximum resident size 311 MB at 200,
        # 1308 MB at 2000 and 4472 MB at 8000 samples, with 3 and with 11 releases alike;
        # docs/README.md), counted as 600 kB plus a fixed 250 MB
        check_memory(samples, 600e3, fixed=250e6, field="--samples",
                     what=f"{samples} band samples", integer=True)
        opts = cli_options(ImpactOptions, piezo=piezo, multi=multi, analysis=cli_options(
            AnalysisOptions, _IMPACT_FLAGS, alpha=alpha, n_samples=samples, seed=seed,
            window=window, fit_window=fit_window, impact_model=impact_model),
            scenarios=(None if scenario_draws == 0 else cli_options(
                InferenceOptions, {"n_draws": "--scenario-draws"}, n_draws=scenario_draws,
                seed=seed)))
        try:
            side = impact_sidecar(out)
        except GprmInputError as exc:
            raise GprmInputError(exc.problem, source=exc.source, field="--out") from None
        check_outputs({out: "--out", side: "--out (its .nc sidecar)"},
                      inputs=[*model_inputs(fit), telemetry], sidecars=[(side, out)])
        m = load_model(fit, piezo=piezo)
        doc = write_impact(run_impact(m, telemetry, opts), out).to_json()
        n_ok = sum(1 for r in doc["releases"] for a in r["impact_time"].values()
                   if a["value"] is not None)
        tk = doc["tukey"]
        verdict = ("no Tukey test" if tk.get("q_critical") is None else
                   "all pairs compatible" if tk.get("all_compatible")
                   else f"{sum(p['reject'] for p in tk['pairs'])} pair(s) rejected")
        js = doc["joint"]
        jv = ("joint chi2: no test" if js["all_consistent"] is None else
              "joint chi2: all consistent" if js["all_consistent"]
              else f"joint chi2 rejects {', '.join(js['rejected'])}")
        typer.echo(f"wrote {out} (+ {side.name}): {len(doc['releases'])} releases, "
                   f"{n_ok} impact times, {len(doc['missing'])} missing; Tukey: {verdict}; "
                   f"{jv} (alpha={alpha}; {doc['impact_model']} impact model)")
        if not getattr(m, "has_uncertainty", True):
            typer.echo("note: the fit has no usable covariance: best fit only; error bars "
                       "carry the impact geometry's uncertainty and the telemetry's only")
        sc = doc.get("scenarios")
        if sc:
            ob = sc["observations"]
            jc = sc["joint"]["chosen"]
            ps = sc["joint"].get("p_same")
            typer.echo(f"scenarios: chosen per release {', '.join(str(r['chosen']) for r in sc['releases'])}"
                       + ("" if ps is None else
                          f" (given the file: one scenario for all with probability "
                             f"{probability_text(ps)})")
                       + f"; jointly {jc}; paper's observations: z not the largest in "
                       f"{ob['z_not_largest']}/{ob['n']}, momentum almost all in x-z in "
                       f"{ob['xz_almost_all']}/{ob['n']}, every component non-compliant in "
                       f"{ob['all_non_compliant']}/{ob['n']}")
            if "truth_summary" in sc:
                ts = sc["truth_summary"]
                typer.echo(f"truth (synthetic): scenario chosen right in "
                           f"{ts['chosen_right']}/{ts['releases']}"
                           + (f" ({ts['chosen_alone_right']} on each release's own evidence)"
                              if "chosen_alone_right" in ts else ""))
        if "truth" in doc:
            s = doc["truth"]["summary"]
            typer.echo(f"truth (synthetic): {s['found']}/{s['impact_times']} found, "
                       f"{s['within_2sigma']} within 2 sigma; joint 95 % interval contains "
                       f"the truth in {s['joint_truth_in_ci95']}/{s['joint_releases']}")
