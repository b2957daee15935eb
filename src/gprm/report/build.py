"""Build the report from a run directory (the files ``gprm run`` / ``gprm demo`` write, or
any run laid out the same way). Each section appears with its figures when its input files are present, and
says "not run" otherwise.

Run directory layout::

    campaign.nc       synthetic or imported campaign             (gprm synth campaign)
    means.nc          mean signals with sigma                    (gprm preprocess)
    fit.json, fit.nc  identification and its sidecar             (gprm fit)
    predict.nc        trajectories and energy, Piezo 2           (gprm predict)
    predict_piezo1.nc what-if: Piezo 1                           (gprm predict --piezo 1)
    predict_ecc10.nc  what-if: Piezo 1, eccentricities / 10      (gprm predict ...)
    whatif.json       what-if overshoot ratios                   (gprm predict --whatif)
    telemetry.nc      in-flight releases                         (gprm synth telemetry)
    impact.json       release velocities, impact times, Tukey    (gprm impact)
    run.json          command, seed, versions, per-stage timings (gprm run)

Figures carry stable HTML ids (:data:`FIGURE_IDS`) so that tests and links can find them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gprm import __version__
from gprm._io import open_netcdf, read_json, write_text_atomic
from gprm.campaign.files import load_campaign, read_means, read_tables
from gprm.errors import GprmInputError
from gprm.fit.files import read_fit_document, read_fit_sidecar
from gprm.fit.sandwich import COVERAGE_HEADLINE
from gprm.flight.files import read_impact, read_impact_curves, read_telemetry
from gprm.params import REGISTRY, from_si
from gprm.predict.files import read_prediction, read_whatif
from gprm.fit.report_text import draws_label, pretty_unit, weights_label
from gprm.report import figures as F
from gprm.report.html import (Card, Section, fig_to_img, not_run, num, paragraph, pm, render,
                              table)
from gprm.report.scenarios import scenario_section, voltage_section
from gprm.report.summary import (current_file, earlier_outputs, impact_times_found,
                                 summarise, truth_for_fit, truth_from_means)

# Figure id -> the paper's figure it mirrors.
FIGURE_IDS = {
    "fig-campaign": "Fig. 3", "fig-fit": "Fig. 6", "fig-residuals": "residuals of Fig. 6",
    "fig-waterfall": "waterfall of starts",
    "fig-masses": "Fig. 7", "fig-energy": "Fig. 8", "fig-trajectories": "Fig. 10",
    "fig-release-fit": "Fig. 11a", "fig-velocity-impact": "Fig. 11b",
    "fig-impact-times": "Fig. 12",
    "fig-whatif-piezo1": "Fig. 13", "fig-whatif-eccentricity": "Fig. 14",
    "fig-voltage": "Fig. 5 right",
}
TABLE_IDS = ("table-1", "table-3", "table-whatif", "table-tukey", "table-provenance",
             "table-timings", "table-observations", "table-scenarios")

_PAPER_T1 = {"x_head/x_lr": 3, "x_head/x_fl": 17, "y_head/y_lr": 3, "y_head/y_fl": 21,
             "z_bk/z_fl": 26}


def _reader(name: str):
    """The reader of a run directory's file in its format's home (None: read it plainly)."""
    if name.startswith("predict") and name.endswith(".nc"):
        return read_prediction
    return {"campaign.nc": load_campaign, "means.nc": read_means, "telemetry.nc": read_telemetry,
            "impact.nc": read_impact_curves, "impact.json": read_impact,
            "whatif.json": read_whatif}.get(name)


def _load_nc(run: Path, name: str, what: str):
    p = current_file(run, name)
    if p is None:
        return None
    read = _reader(name)
    return read(p) if read is not None else open_netcdf(p, what=what)


def _load_json(run: Path, name: str, what: str):
    p = current_file(run, name)
    if p is None:
        return None
    read = _reader(name)
    return read(p) if read is not None else read_json(p, what=what)


def _missing(run: Path, name: str, why: str) -> str:
    """Why ``name`` is not shown: ``why`` (missing), or that the last run did not make it."""
    stale = earlier_outputs(run).get(name)
    if stale is None:
        return why
    return (f"{name} was not made by the last run and is not shown: {stale} there "
            "(run.json), and gprm left the file as it was.")


def _not_run(s: Section, what: str, why: str) -> Section:
    """``s`` marked as not run (greyed in the navigation), with a note saying why."""
    s.ran = False
    s.blocks.append(not_run(what, why))
    return s


# ----------------------------------------------------------------------------- campaign

def _table1(means) -> list:

    stored = read_tables(means)[0]
    sig = [str(s) for s in means["signal"].values]
    rows = []
    for key, paper_v in _PAPER_T1.items():
        a, b = key.split("/")
        v = stored.get(key, stored.get(f"max({a})/max({b})"))
        if isinstance(v, dict):
            v = v.get("value")
        if v is None and a in sig and b in sig:
            v = float(np.abs(means["mean"].sel(signal=a)).max()
                      / np.abs(means["mean"].sel(signal=b)).max())
        if v is None:
            continue
        rows.append((f"max({a}) / max({b})", f"{float(v):.3g}", paper_v))
    return rows


def campaign_section(run: Path) -> Section:
    s = Section("Ground-test campaign", "campaign")
    means = _load_nc(run, "means.nc", "mean-signals file")
    if means is None:
        return _not_run(s, "Campaign and preprocessing", _missing(
            run, "means.nc", "means.nc is missing (gprm synth campaign + gprm preprocess)."))
    camp = _load_nc(run, "campaign.nc", "campaign file")
    n_runs = means["n_runs"].values if "n_runs" in means else None
    align = float(means.attrs.get("align_time", 1e-3))
    txt = ("Mean signals of the ten laser positions after synchronisation, averaging and "
           f"alignment (each signal's 2σ crossing within half a sample of {align * 1e3:g} ms, "
           "the shifts being whole samples; the retraction "
           "command is at 1 ms, Section 2), with the across-run standard deviation σ(t).")
    if n_runs is not None:
        lo, hi = int(np.min(n_runs)), int(np.max(n_runs))
        txt += (f" Runs averaged per position: {lo}." if lo == hi else
                f" Runs averaged per position: {lo} to {hi}.")
    if camp is not None and "seed" in camp.attrs:
        txt += f" Synthetic campaign, seed {camp.attrs['seed']}."
    s.blocks.append(paragraph(txt))
    s.blocks.append(fig_to_img(F.fig_mean_signals(means),
                               "Campaign mean signals from 0.9 ms (the retraction "
                               "command is at 1 ms): x_base with ±σ(t), σ(t) itself on the "
                               "right axis in nm, about a thousandth of the signal (a); the "
                               "synchronised mean signals of the x (b), y (c) and z (d) "
                               "positions (cf. Fig. 3)", "fig-campaign"))
    rows = _table1(means)
    if rows:
        s.blocks.append(table(["ratio", "this campaign", "paper"], rows,
                              "Table 1: ratios of the maxima of the mean signals", "table-1",
                              note="Dimensionless. The fit uses x_base, x_head, y_base, "
                                   "y_head and z_bk; the others serve the hypotheses of Sec. 2. "
                                   "Why the ratios are not the paper's: a synthetic campaign's "
                                   "flange and linear-runner motions come from supports tuned "
                                   "once so that the noise-free ratios are near the paper's; "
                                   "the ratios here are of the noisy, synchronised means and "
                                   "move by a few per cent with the seed and the drawn truth "
                                   "(a small y motion divided by a small one moves most). On "
                                   "measured data they are the campaign's own."))

    dropped = read_tables(means)[1]
    if dropped:
        rows = []
        entries = dropped.items() if isinstance(dropped, dict) else \
            [(d.get("position", "?"), d) for d in dropped]
        for pos, d in entries:
            if isinstance(d, dict):
                v, thr = d.get("value"), d.get("support_threshold")
                rows.append((pos, d.get("hypothesis", ""), d.get("ratio", ""),
                             "—" if v is None else f"{v:.3g}",
                             "—" if thr is None else f"> {thr:g}",
                             "yes" if d.get("supported") else "no"))
            else:
                rows.append((pos, str(d), "", "", "", ""))
        s.blocks.append(table(["position", "hypothesis (Sec. 2)", "ratio", "value",
                               "needed", "supported"], rows,
                              "Positions the hypotheses of Sec. 2 drop from the fit",
                              "table-dropped"))
    return s


# ----------------------------------------------------------------------------- fit

def truth_of(run: Path, fit: dict) -> dict | None:
    truth = truth_from_means(run)
    return None if truth is None else truth_for_fit(truth, fit)


def table3_rows(fit: dict, truth: dict | None) -> list:
    """Table 3: best fit, its 95 % interval from the fit's uncertainty method and whether the
    data determine it, the synthetic truth (and whether the interval holds it), the paper's
    value ± its error, the initial value and the CAD nominal, in the paper's display units."""

    rows = []
    for name, p in fit["parameters"].items():
        if not p.get("fitted") or name not in REGISTRY:
            continue
        spec = REGISTRY[name]
        unit_scale = from_si(1.0, name)
        unit = spec.unit.replace("us", "µs")
        if unit == "s":             # every lag in µs: t0, t1 as the offsets dt_* (issue 22)
            unit_scale, unit = 1e6, "µs"
        iv = p.get("interval") or {}
        lo, hi = iv.get("lower"), iv.get("upper")
        ident = p.get("identified")
        row = [name, pretty_unit(unit), num(p["value"] * unit_scale),
               "—" if lo is None or hi is None else
               f"[{num(lo * unit_scale)}, {num(hi * unit_scale)}]",
               "—" if ident is None else ("yes" if ident else "leans on the prior"
                                          if p.get("leans_on_prior") else "not determined")]
        if truth is not None:
            t = truth.get(name)
            row.append("—" if t is None else num(t * unit_scale))
            row.append("—" if (t is None or lo is None or hi is None)
                       else ("yes" if lo <= t <= hi else "no"))
        row.append(pm(spec.default, spec.paper_stderr, unit_scale)
                   if spec.group == "fitted" else "— (not in the paper)")
        row.append("—" if spec.initial is None else num(spec.initial * unit_scale))
        row.append("—" if spec.nominal is None else num(spec.nominal * unit_scale))
        rows.append(row)
    return rows


def strong_correlations(fit: dict, threshold: float = 0.99) -> list:
    """Pairs of fitted parameters with |correlation| above ``threshold``, strongest first."""
    corr = fit.get("correlation") or {}
    names, R = corr.get("names") or [], corr.get("matrix")
    if R is None:
        return []
    R = np.asarray(R, float)
    out = [(names[i], names[j], R[i, j]) for i in range(len(names))
           for j in range(i + 1, len(names)) if abs(R[i, j]) > threshold]
    return [[a, b, f"{r:+.5f}"] for a, b, r in sorted(out, key=lambda t: -abs(t[2]))]


def combination_rows(fit: dict) -> list:

    rows = []
    for c in fit.get("identifiable_combinations") or []:
        terms = c["terms"]
        if c.get("form") == "product of powers":
            expr = " · ".join(f"{k}^{v:g}" if v != 1 else k for k, v in terms.items())
            unit = " · ".join(f"({REGISTRY[k].unit})^{v:g}" for k, v in terms.items()
                              if k in REGISTRY)
        else:
            expr = " + ".join(f"{v:g} {k}" for k, v in terms.items())
            unit = "SI"
        rows.append([expr, num(c["value"]), f"[{num(c['lower'])}, {num(c['upper'])}]",
                     f"{c['spread_vs_prior']:.2f}", f"SI ({unit})"])
    return rows


def _calibration_sentence(unc: dict) -> str:
    """The mismatch calibration factors an opt-in generator-bootstrap applied, in words ('' if
    none)."""
    factors = (unc.get("calibration") or {}).get("factors") or {}
    if not factors:
        return ""
    listed = ", ".join(f"{n} ×{f:.2f}" for n, f in factors.items())
    return (f" Intervals widened by the mismatch calibration measured on gprm's synthetic "
            f"generator (gprm.fit.calibration): {listed}.")


def systematics_rows(unc: dict) -> list:
    """Per signal: the gain and timing standard deviations the default uncertainty
    marginalised (stated, estimated from the residuals, the alignment's own)."""
    det = unc.get("details") or {}
    syst = det.get("systematics") or {}
    stated = (det.get("stated") or {})
    est = det.get("gain_estimated")
    rows = []
    for sig, v in syst.items():
        if not isinstance(v, dict):
            continue
        rows.append([sig, f"{100 * v.get('gain_sd', float('nan')):.3g} %",
                     f"{100 * stated.get('gain_sd', 0.0):.3g} %" if stated else "–",
                     (f"{100 * est:.3g} %" + (f" (z {det['gain_estimated_z']:.1f})"
                                              if isinstance(det.get("gain_estimated_z"),
                                                            (int, float)) else ""))
                     if isinstance(est, (int, float)) else "–",
                     f"{1e9 * v.get('timing_sd_s', float('nan')):.3g} ns",
                     f"{1e9 * v.get('alignment_sd_s', float('nan')):.3g} ns",
                     (f"{1e9 * v['sync_timing_sd_s']:.3g} ns"
                      if isinstance(v.get("sync_timing_sd_s"), (int, float)) else "–"),
                     (f"{1e9 * v['drive_timing_sd_s']:.3g} ns"
                      if isinstance(v.get("drive_timing_sd_s"), (int, float)) else "–"),
                     f"{1e9 * v.get('crossing_offset_s', float('nan')):+.3g} ns"])
    return rows


def adequacy_rows(adq: dict) -> list:
    rows = []
    for sc in adq.get("signals") or []:
        if isinstance(sc, dict):
            rows.append([sc.get("signal", "?"), f"{sc.get('chi2_per_sample', float('nan')):.3g}",
                         f"{sc.get('ljung_box_p', float('nan')):.2g}",
                         f"{sc.get('lag1_autocorrelation', float('nan')):.2f}",
                         f"{sc.get('peak_frequency_hz', float('nan')) / 1e3:.3g} kHz"
                         + (f" (p {sc['peak_p_fisher_g']:.2g})"
                            if isinstance(sc.get('peak_p_fisher_g'), (int, float))
                            and np.isfinite(sc['peak_p_fisher_g']) else ""),
                         f"{sc.get('loso_ratio', float('nan')):.3g}"])
    return rows


def fit_section(run: Path) -> tuple[Section, dict | None]:
    s = Section("Identification", "fit")
    if current_file(run, "fit.json") is None:
        return _not_run(s, "Fit", _missing(run, "fit.json",
                                           "fit.json is missing (gprm fit).")), None
    fit = read_fit_document(run / "fit.json")
    side = read_fit_sidecar(run / "fit.nc") if current_file(run, "fit.nc") else None
    st = fit.get("starts", {})
    s.blocks.append(paragraph(
        f"Weighted multi-signal Levenberg–Marquardt (Algorithm 1) from {st.get('requested')} "
        f"random starts within ±{100 * st.get('spread', 0.2):.0f} % of the paper's initial "
        f"values; {st.get('converged')} converged, {st.get('n_at_best', '?')} reached the best "
        f"χ² within Δχ² ≤ 1"
        + (f" ({st['raced']} stopped early by racing, schedule "
           f"{', '.join(f'{r}:{q}' for r, q in st.get('race') or [])}; the counts are of "
           f"the starts that ran on)" if st.get("raced") else "")
        + f". χ² = {fit['chi2']:.5g} for {fit['dof']} degrees of freedom "
        f"(reduced χ² = {fit['reduced_chi2']:.4g}; weights: "
        f"{weights_label(fit.get('sigma', 'sem'), fit.get('sigma_pool'), '±')}). "
        f"Covariance (Eq. 7): {fit.get('covariance_message', 'ok')}."))
    unc = fit.get("uncertainty") or {}
    phys = [n for n, p in fit["parameters"].items() if p.get("fitted") and n not in
            ("t0", "t1") and not n.startswith("dt_")]
    ident = [n for n in phys if fit["parameters"][n].get("identified")]
    leans = [n for n in phys if fit["parameters"][n].get("leans_on_prior")]
    if unc:
        headline = (f"{COVERAGE_HEADLINE} (docs/fitting.md, benchmarks/bench_sources.py)."
                    if unc.get("method") == "sandwich" else
                    "This method's coverage is compared with the default's in "
                    "docs/fitting.md.")
        s.blocks.append(paragraph(
            f"Uncertainty: {unc.get('method')} — {unc.get('note', '')}. The data determine "
            f"{len(ident)} of the {len(phys)} physical parameters ({', '.join(ident)}); "
            + (f"{', '.join(leans)} {'has' if len(leans) == 1 else 'have'} a narrow interval "
               "that is mostly the weak prior's (the data tie "
               f"{'it' if len(leans) == 1 else 'them'} to parameters they do not see): "
               "leaning on the prior, not identified; " if leans else "")
            + "the others are reported as not determined, with the interval the posterior "
            "gives (close to the weak prior's), never with a small error. " + headline
            + _calibration_sentence(unc)
            + (f" Bands and predictions, {drawn} (docs/fitting.md, 'The draws put back on "
               "the data')." if (drawn := draws_label(unc.get("details"))) else "")))
        adq = unc.get("adequacy") or {}
        if adq.get("text"):
            s.blocks.append(paragraph(f"Model adequacy: {adq['text']}"))
            s.blocks.append(table(["signal", "χ² per sample", "Ljung–Box p", "lag-1 autocorr.",
                                   "residual peak", "leave-out error ×"], adequacy_rows(adq),
                                  "Does the model describe the data?", "table-adequacy",
                                  note="Per signal: the residuals' size, their whiteness "
                                  "(Ljung–Box test, p below 0.001/5 flags structure), the "
                                  "frequency holding most residual power (p: Fisher's exact "
                                  "test of that peak against white residuals; small p, an "
                                  "unmodelled oscillation or coloured residuals), and the "
                                  "error of the signal's prediction by the fit without it "
                                  "over its in-fit error (docs/fitting.md, 'Model "
                                  "adequacy')."))
        srows = systematics_rows(unc)
        if srows:
            s.blocks.append(table(["signal", "gain sd used", "gain sd stated",
                                   "gain sd from residuals", "timing sd used",
                                   "alignment noise", "synchronisation",
                                   "the drive's shift", "model crossing offset"], srows,
                                  "Instrument systematics marginalised", "table-systematics",
                                  note="Per-channel gain (calibration) and timing errors the "
                                  "intervals include: the stated prior (parameter file "
                                  "[systematics], --gain-sd, --timing-sd) or, where larger, "
                                  "the gain errors' size the residuals show (z: that "
                                  "estimate's variance in sd of its noise without gain "
                                  "errors; below about 2 it cannot be told from none, and "
                                  "is used all the same, on the safe side); the timing adds "
                                  "the alignment's noise, estimated from the data, where the "
                                  "signal's own lag is held fixed (a fitted lag absorbs it "
                                  "exactly), and for every signal the time shift the "
                                  "synchronisation of the runs took out of their spread but "
                                  "left in their mean (from the noise and the slope; it "
                                  "widens the lags and what is read on the fit's time axis), "
                                  "and the same shift from the drive varying between runs "
                                  "(read from the runs' shapes through the model's "
                                  "sensitivities to the drive's amplitude and retraction "
                                  "time). "
                                  "The model "
                                  "crossing offset is where the fitted model crosses the "
                                  "alignment threshold against the data: a diagnostic of "
                                  "what the model lacks at the onset, not an error of the "
                                  "lags, which live in the data's aligned time axis "
                                  "(docs/fitting.md)."))
    if side is not None:
        res = "resonance_fitted" in side
        s.blocks.append(fig_to_img(F.fig_fit(side), "Best fit over the mean signals with "
                                   "±σ and the 95 % model band from the parameter covariance "
                                   "(cf. Fig. 6)" + ("; dashed: the best fit plus the "
                                   "unmodelled resonance the fit found and marginalised "
                                   "(its nuisance columns' part of the residuals)" if res
                                   else ""), "fig-fit"))
        fig = F.fig_residuals(side)
        if fig is not None:
            s.blocks.append(fig_to_img(fig, (
                "Normalised residuals (mean signal − best fit − the marginalised resonance)/σ "
                "per signal, what the fit minimised (thin: before the resonance is taken "
                "off)" if res else "Normalised residuals (mean signal − best fit)/σ per "
                "signal") + ": systematic structure shows what the model leaves out",
                "fig-residuals"))
        s.blocks.append(fig_to_img(F.fig_waterfall(side), "Waterfall of the starts: final χ² "
                                   "of every start, sorted; starts within Δχ² ≤ 1 of the best "
                                   "found the same minimum", "fig-waterfall"))
    else:
        s.blocks.append(not_run("Fit figures", "fit.nc (the sidecar) is missing."))
    truth = truth_of(run, fit)
    head = ["parameter", "unit", "best fit", "95 % interval", "identified"]
    if truth is not None:
        head += ["synthetic truth", "in interval"]
    head += ["paper ± 1σ", "initial", "nominal (CAD)"]
    s.blocks.append(table(head, table3_rows(fit, truth), "Table 3: best-fit parameters",
                          "table-3", note="Intervals come from the fit's uncertainty method "
                          f"({unc.get('method', 'Eq. 7')}); 'not determined' means the data "
                          "shrink the weak prior by less than the identification threshold; "
                          "'leans on the prior' that the interval is narrow but at least half "
                          "of its variance is the prior's (docs/fitting.md). The paper column "
                          "is the published Table 3; the "
                          "initial values are the centre of the random starts and of the "
                          "prior. Lags (t0, t1, the alignment offsets dt_*) in µs."
                          + ("" if truth is None else
                             " The synthetic truth of the lags is the one expected in the "
                             "aligned time base of the means (docs/data-formats.md, "
                             "docs/model.md).")))
    combos = combination_rows(fit)
    if combos:
        s.blocks.append(table(["combination", "best fit", "95 % interval",
                               "spread / prior's", "unit"], combos,
                              "What the data determine among the undetermined parameters",
                              "table-combinations", note="Directions of the posterior, "
                              "restricted to the not-determined parameters, along which the "
                              "data shrink the prior at least as much as for an identified "
                              "parameter (e.g. the y springs' stiffness moments)."))
    strong = strong_correlations(fit)
    s.blocks.append(table(["parameter", "parameter", "correlation"], strong,
                          "Correlations above 0.99", "table-correlations",
                          note="From the fit's covariance." if strong else
                          "None above 0.99."))
    fig = F.fig_profiles(fit)
    if fig is not None:
        s.blocks.append(fig_to_img(fig, "Profile likelihoods of the fitted parameters "
                                   "(gprm fit --profile): a profile that stays below the "
                                   "dashed line on one side leaves the parameter unbounded "
                                   "there", "fig-profiles"))
    s.blocks.append(fig_to_img(F.fig_masses(fit, truth), "Masses: fitted value ± 1σ against "
                               "the CAD nominal, the initial value and the paper's 3D fit "
                               "(cf. Fig. 7)", "fig-masses"))
    return s, fit


# ----------------------------------------------------------------------------- predict

def predict_section(run: Path) -> Section:
    s = Section("Prediction", "predict")
    pred = _load_nc(run, "predict.nc", "prediction file")
    if pred is None:
        return _not_run(s, "Prediction", _missing(run, "predict.nc",
                                                  "predict.nc is missing (gprm predict)."))
    s.blocks.append(paragraph(
        "Trajectories of the contact middle points M_xz and M_yz and of the tip edge from the "
        "best fit (Eq. 8), with trajectories of parameter sets drawn from the fit covariance, "
        "and the kinetic energy at the tip retraction, Piezo 2 " + (
            f"({int(pred.attrs.get('samples_ok', 0))} of {int(pred.attrs.get('samples', 0))} "
            "parameter samples valid)." if int(pred.attrs.get("samples", 0)) else
            "(best fit only: no usable draws from the covariance, see the provenance "
            "notes).")))
    fig = F.fig_energy(pred, run)
    if fig is not None:
        s.blocks.append(fig_to_img(fig, "Kinetic energy E₅ of the five measured points: time "
                                   "spent in each energy bin within the fit window, 3D model "
                                   "(orange) against the measured mean signals (blue), with "
                                   "errors from the parameter samples and the signals' sem "
                                   "(cf. Fig. 8)", "fig-energy"))
    else:
        s.blocks.append(not_run("Energy histogram", "predict.nc holds no kinetic energy."))
    s.blocks.append(fig_to_img(F.fig_trajectories(pred, "Trajectories, Piezo 2 (cf. Fig. 10)"),
                               "Trajectory of M_xz in the x–z plane, of M_yz in the y–z plane "
                               "and of the tip edge in the x–y plane, Piezo 2, from the "
                               "initial position (blue star) to 1.2 ms (red star) "
                               "(cf. Fig. 10)", "fig-trajectories"))
    if "overshoot" in pred:
        rows = []
        for pt in [str(p) for p in pred["point"].values]:
            rows.append((pt, *(f"{float(pred['overshoot'].sel(point=pt, axis=a)) * 1e6:.3g}"
                               for a in ("x", "y", "z"))))
        s.blocks.append(table(["point", "x [µm]", "y [µm]", "z [µm]"], rows,
                              "Overshoot (largest excursion from rest), Piezo 2",
                              "table-overshoot"))
    return s


def whatif_section(run: Path) -> Section:
    s = Section("What-ifs: risk reduction", "whatif")
    wi = _load_json(run, "whatif.json", "what-if table")
    p1 = _load_nc(run, "predict_piezo1.nc", "what-if prediction")
    e10 = _load_nc(run, "predict_ecc10.nc", "what-if prediction")
    base = _load_nc(run, "predict.nc", "prediction file")
    if wi is None and p1 is None and e10 is None:
        return _not_run(s, "What-ifs", _missing(
            run, "whatif.json", "whatif.json and the what-if predictions are missing "
            "(gprm predict --piezo 1, --scale-eccentricity 0.1)."))
    s.blocks.append(paragraph(
        "Two strategies of Sec. 4.2: driving Piezo 1 instead of Piezo 2, and Piezo 1 with the "
        "eccentricities v2, g2, ρ and γ divided by ten. The ratios are the overshoot with "
        "Piezo 2 (as built) over the overshoot of the strategy, per axis (paper: 4.0, 6.4, "
        "3.8 for Piezo 1; 40.0, 64.6 lateral for the eccentricities)."))
    if wi is not None:
        rows = F.whatif_rows(wi)
        if rows:
            s.blocks.append(table(["strategy", "x (M_xz)", "y (M_yz)", "z (M_xz)",
                                   "paper (x, y, z)"], rows,
                                  "Overshoot ratios: Piezo 2 (as built) / strategy",
                                  "table-whatif",
                                  note="Dimensionless. In brackets: 2.5–97.5 % range over "
                                       "parameter sets drawn from the fit covariance. "
                                       + str(wi.get("definition", ""))))
    if p1 is not None:
        s.blocks.append(fig_to_img(F.fig_trajectories(p1, "Piezo 1 (cf. Fig. 13)", ref=base),
                                   "Trajectories with Piezo 1 (grey: Piezo 2 as built) "
                                   "(cf. Fig. 13)", "fig-whatif-piezo1"))
    if e10 is not None:
        s.blocks.append(fig_to_img(F.fig_trajectories(e10, "Piezo 1, eccentricities ÷ 10 "
                                                           "(cf. Fig. 14)", ref=base),
                                   "Trajectories with Piezo 1 and the eccentricities divided "
                                   "by ten (grey: Piezo 2 as built) (cf. Fig. 14)",
                                   "fig-whatif-eccentricity"))
    return s


# ----------------------------------------------------------------------------- flight

def _has_truth(imp: dict) -> bool:
    """Whether an impact result comes from telemetry with a truth (synthetic releases)."""
    return bool((imp.get("truth") or {}).get("impact_time")) or any(
        "truth_impact_time" in r for r in imp.get("releases", []))


def flight_section(run: Path) -> Section:
    s = Section("Flight: impact analysis", "flight")
    imp = _load_json(run, "impact.json", "impact result")
    if imp is None:
        return _not_run(s, "Flight analysis", _missing(
            run, "impact.json", "impact.json is missing (gprm synth telemetry + gprm impact)."))
    curves = _load_nc(run, "impact.nc", "impact curves")
    n = len(imp.get("releases", []))
    n_ok = impact_times_found(imp)
    s.blocks.append(paragraph(
        f"{n} releases: the release velocity per axis from the telemetry, and the impact time "
        "at which the impact model ("
        + {"3d": "one contact of the plunger tip on the indent face in 3D, with restitution "
                 "and friction", "planar": "the planar impacts of Appendix B",
           "xz": "scenario: one rim contact in x–z, with restitution and friction",
           "yz": "scenario: one rim contact in y–z, with restitution and friction",
           "two": "scenario: two rim contacts, x–z and y–z, with restitution and friction"
           }.get(imp.get("impact_model"), str(imp.get("impact_model")))
        + ") applied to the predicted plunger state gives that velocity (crossing on the "
        f"rising branch of the curve): {n_ok} of {6 * n} impact times found; each error bar "
        "combines the telemetry's error and the model band (parameter and geometry draws). "
        "Tukey's range test asks whether the six axes' impact times share one mean (Eq. 9); "
        "the joint estimate combines the axes into one impact time per release (weighted "
        "least squares with the model's covariance between the axes), and its χ² is a second "
        "consistency check. The two v_z axes are one measurement read through two planes: "
        "the measured v_z is compared with the x–z plane's curve (vz_xz) and with the y–z "
        "plane's (vz_yz), each the test mass's full v_z (docs/flight.md, Section 2)."
        + ("" if not imp.get("missing") else
           " Missing impact times, each with its reason: " + "; ".join(
               f"{m.get('release')} {m.get('axis')}: {m.get('reason')}"
               for m in imp["missing"][:12])
           + (f"; … ({len(imp['missing'])} in all, listed in impact.json)"
              if len(imp["missing"]) > 12 else "") + ".")))
    tele = _load_nc(run, "telemetry.nc", "telemetry file")
    fig = F.fig_release_fit(tele, imp)
    if fig is not None:
        s.blocks.append(fig_to_img(fig, "Telemetry of the first release: the test mass's x "
                                   "displacement and the line whose slope is the release "
                                   "velocity (cf. Fig. 11a)", "fig-release-fit"))
    truth = _has_truth(imp)
    fig = F.fig_velocity_impact(imp, curves)
    if fig is not None:
        s.blocks.append(fig_to_img(fig, "Release velocity against the impact time, first "
                                   "release: velocity the impact model gives as a function of "
                                   "the impact time with its band, the measured velocity, "
                                   "each axis' impact time (±1σ) and the joint estimate with "
                                   "its 95 % interval (grey)"
                                   + (", and the true impact time of the synthetic release "
                                      "(dotted)" if truth else "") + " (cf. Fig. 11)",
                                   "fig-velocity-impact"))
    else:
        s.blocks.append(not_run("Velocity vs impact time", "impact.nc (the curves) is "
                                "missing."))
    s.blocks.append(fig_to_img(F.fig_impact_times(imp), "All estimated impact times per "
                               "release and axis with 1σ errors; open diamonds: the joint "
                               "estimate per release with its 95 % interval"
                               + ("; black bars: the true impact times of the synthetic "
                                  "releases" if truth else "") + " (cf. Fig. 12)",
                               "fig-impact-times"))
    jc = imp.get("joint") or {}
    if jc.get("all_consistent") is not None:
        rej = [str(r) for r in jc.get("rejected") or ()]
        s.blocks.append(paragraph(
            f"Joint χ² check (α = {jc.get('alpha')}, {jc.get('n')} releases): "
            + ("every release's axes agree on one impact time." if not rej else
               f"the axes of release(s) {', '.join(rej)} do not agree on one impact time "
               "(their joint χ² test rejects); their joint estimates are not to be "
               "trusted.")))
    tk = imp.get("tukey")
    if tk and tk.get("pairs"):
        rows = []
        for p in tk["pairs"]:
            ma, mb = p.get("mean_a"), p.get("mean_b")
            rows.append((f"{p['a']} – {p['b']}",
                         "—" if ma is None else f"{ma * 1e3:.4f}",
                         "—" if mb is None else f"{mb * 1e3:.4f}",
                         f"{p['q']:.3f}", f"{p['p']:.3g}",
                         "rejected" if p.get("reject") else "not rejected"))
        qc = tk.get("q_critical")
        s.blocks.append(table(["pair of axes", "mean a [ms]", "mean b [ms]", "q", "p",
                               "H0 (equal means)"], rows,
                              f"Tukey's range test ({tk.get('method', 'tukey')}): k = "
                              f"{tk.get('k')}, df = {tk.get('df')}, α = {tk.get('alpha')}, "
                              f"q_crit = {'—' if qc is None else f'{qc:.3f}'}",
                              "table-tukey", note="q and p are dimensionless; means are "
                                                  "impact times from the record start."))
    elif tk:
        s.blocks.append(not_run("Tukey test", str(tk.get("note", "too few impact times"))))
    return s


# ----------------------------------------------------------------------------- provenance

def git_commit(where: Path | None = None) -> str:
    """The commit of the gprm source that builds the report (``+dirty`` with uncommitted
    changes), or why there is none (an installed wheel has no git checkout)."""
    import subprocess

    where = Path(__file__).parent if where is None else where
    try:
        rev = subprocess.run(["git", "-C", str(where), "rev-parse", "HEAD"], capture_output=True,
                             text=True, timeout=10)
        if rev.returncode != 0:
            return "not a git checkout"
        dirty = subprocess.run(["git", "-C", str(where), "status", "--porcelain",
                                "--untracked-files=no"], capture_output=True, text=True,
                               timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "git not available"
    return rev.stdout.strip() + ("+dirty" if dirty else "")


#: options that are times (SI seconds in run.json), shown with a unit in the provenance
TIME_OPTIONS = frozenset({"align_time", "window", "timing_sd", "t_start", "t_end",
                          "ke_window", "sync_window", "t_c"})


def time_text(*seconds: float) -> str:
    """Times with a readable unit, the one of the largest: ``1.01 ms``, ``4.2 µs``,
    ``0.97, 1.2 ms``."""
    a = max(abs(x) for x in seconds)
    scale, unit = next(((sc, u) for sc, u in ((1.0, "s"), (1e-3, "ms"), (1e-6, "µs"))
                        if a >= sc), (1e-9, "ns") if a else (1.0, "s"))
    return ", ".join(f"{x / scale:.4g}" for x in seconds) + f" {unit}"


def option_text(name: str, value):
    """An option's value for the provenance table: times with their unit."""
    if name in TIME_OPTIONS:
        xs = value if isinstance(value, (list, tuple)) else [value]
        if xs and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in xs):
            return time_text(*(float(x) for x in xs))
    return value


def provenance_section(run: Path, prov: dict) -> Section:
    """``prov``: the run record (run.json; empty where there is none)."""
    s = Section("Provenance", "provenance")
    rows = []
    for key in ("command", "seed", "started", "finished"):
        if key in prov:
            rows.append((key, prov[key]))
    for k, v in (prov.get("options") or {}).items():
        if isinstance(v, dict):          # a stage's options (gprm run: preprocess, fit)
            rows.extend((f"option {k}.{k2}", option_text(k2, v2)) for k2, v2 in v.items()
                        if v2 is not None)
        elif v is not None:              # an option not given (no campaign, no telemetry)
            rows.append((f"option {k}", option_text(k, v)))
    for k, v in (prov.get("versions") or {}).items():
        rows.append((f"version {k}", v))
    if prov.get("git"):
        rows.append(("git commit (run)", prov["git"]))
    rows.append(("git commit (report)", git_commit()))
    files = sorted(f.name for f in run.iterdir() if f.is_file() and not f.name.startswith("."))
    rows.append(("files", ", ".join(files)))
    notes: dict[str, list[str]] = {}          # one row per distinct note, naming its stages
    for name, rec in (prov.get("stages") or {}).items():
        for fname, sha in (rec.get("inputs") or {}).items():
            rows.append((f"{name} input {fname}", f"sha256 {sha[:16]}…"))
        for note in (rec.get("info") or {}).get("notes", []):
            notes.setdefault(str(note), []).append(name)
        if rec.get("status") in ("not available", "blocked", "failed"):
            rows.append((f"{name} status", f"{rec['status']}: {rec.get('detail', '')}"))
    for note, stages in notes.items():
        rows.append((f"note ({', '.join(stages)})", note))
    s.blocks.append(table(["item", "value"], rows, "Inputs, seed, versions",
                          "table-provenance"))
    tim = prov.get("stages") or {}
    if tim:
        trows = [(k, v.get("status", ""), "—" if v.get("seconds") is None else
                  f"{v['seconds']:.1f}") for k, v in tim.items()]
        s.blocks.append(table(["stage", "status", "time [s]"], trows, "Timings",
                              "table-timings", note="Skipped stages were up to date: their "
                              "time is the one recorded when they ran."))
    return s


# ----------------------------------------------------------------------------- assembly

def summary_cards(run: Path, fit: dict | None, prov: dict) -> list[Card]:
    s = summarise(run)
    cards = []
    if "fit" in s:
        f = s["fit"]
        cards.append(Card("reduced χ²", f"{f['reduced_chi2']:.3g}",
                          f"χ² {f['chi2']:.4g} / {f['dof']} dof",
                          "ok" if f["reduced_chi2"] < 2 else "warn"))
        cards.append(Card("starts at the best", f"{f.get('n_at_best')} / {f.get('starts')}",
                          "within Δχ² ≤ 1"))
    adq = ((fit or {}).get("uncertainty") or {}).get("adequacy") or {}
    if adq.get("verdict"):
        ok = adq["verdict"] == "adequate"
        cards.append(Card("model adequacy", "describes the data" if ok else "does not "
                          "describe the data", f"reduced χ² {adq.get('reduced_chi2', 0):.3g}; "
                          + ("residuals white" if ok else f"{len(adq.get('reasons', []))} "
                             "check(s) fail; intervals include the residuals' structure"),
                          "ok" if ok else "warn"))
    if fit is not None and "m2" in fit["parameters"]:
        m2 = fit["parameters"]["m2"]
        cards.append(Card("plunger mass m₂", pm(m2["value"], m2.get("stderr"), 1e3) + " g",
                          "nominal 12.3 g, paper 12.4 ± 0.9 g"))
    if "truth_recovery" in s:
        tr = s["truth_recovery"]
        mrel = tr.get("mass_max_relative_error")
        mtxt = "" if mrel is None else f"masses within {100 * mrel:.1f} % of the truth"
        if tr.get("n_interval"):
            tone = "ok" if tr["in95"] >= 0.9 * tr["n_interval"] else "warn"
            und = ("" if not tr.get("undetermined") else
                   f"{tr['undetermined']} not determined "
                   f"({tr['undetermined_in95']} inside their wide interval); ")
            if tr.get("leans_on_prior"):
                und += (f"{tr['leans_on_prior']} leaning on the prior "
                        f"({tr['leans_in95']} inside their 95 % interval); ")
            cards.append(Card("truth recovered",
                              f"{tr['in95']} / {tr['n_interval']} in their 95 % interval",
                              f"identified parameters ({tr['in68']} / {tr['n_interval']} in "
                              f"68 %); " + und + mtxt, tone))
        elif tr["n"]:
            tone = "ok" if tr["within_3sigma"] == tr["n"] else "warn"
            cards.append(Card("truth recovered", f"{tr['within_2sigma']} / {tr['n']} within 2σ",
                              f"{tr['within_3sigma']} / {tr['n']} within 3σ; " + mtxt, tone))
        elif mrel is not None:
            cards.append(Card("truth recovered", f"masses ±{100 * mrel:.1f} %",
                              "no standard errors: the fit has no covariance",
                              "ok" if mrel < 0.1 else "warn"))
    p1 = (s.get("whatif") or {}).get("piezo1")
    if isinstance(p1, dict) and p1:
        cards.append(Card("Piezo 2 / Piezo 1 overshoot", " / ".join(
            f"{p1[a]:.2g}" for a in ("x", "y", "z") if a in p1), "x / y / z (paper 4.0 / 6.4 "
            "/ 3.8)"))
    if "tukey" in s:
        tk = s["tukey"]
        ok = not tk["rejected"]
        cards.append(Card("Tukey test", "compatible" if ok else f"{len(tk['rejected'])} "
                          "pairs differ", f"{s.get('releases')} releases, α = {tk['alpha']}",
                          "ok" if ok else "bad"))
    if "joint" in s:
        jt = s["joint"]
        cards.append(Card("joint impact time", "every release consistent" if not
                          jt["rejected"] else "rejected: " + ", ".join(jt["rejected"]),
                          f"joint χ² test per release, α = {jt['alpha']}",
                          "bad" if jt["rejected"] else "ok"))
    stages = {k: v for k, v in (prov.get("stages") or {}).items() if k != "report"}
    if stages:
        # the stages the terminal lists, the report included (this file: it ran)
        listed = {**stages, "report": {"status": "ran"}}
        done = [k for k, v in listed.items() if v.get("status") in ("ran", "skipped")]
        bad = [k for k in listed if k not in done]
        cards.append(Card("stages", f"{len(done)} / {len(listed)} done",
                          ("not done: " + ", ".join(f"{k} ({listed[k].get('status')})"
                                                    for k in bad)) if bad else
                          "every stage ran or was up to date", "bad" if bad else "ok"))
    total = sum(v.get("seconds", 0.0) or 0.0 for v in stages.values())
    if total:
        cards.append(Card("run time", f"{total:.0f} s", "all stages (report excluded)"))
    return cards


def build_report(run_dir: str | Path) -> str:
    run = Path(run_dir)
    if not run.is_dir():
        raise GprmInputError("run directory does not exist", source=str(run))
    known = ("means.nc", "fit.json", "predict.nc", "impact.json", "whatif.json", "run.json")
    if not any((run / k).exists() for k in known):
        raise GprmInputError("holds none of the stage outputs (" + ", ".join(known) + ")",
                             source=str(run))
    fit_s, fit = fit_section(run)
    sections = [campaign_section(run), fit_s, predict_section(run), whatif_section(run),
                flight_section(run)]
    from gprm.report.design_section import design_section   # only where design.json is

    design = design_section(run)
    if design is not None:
        sections.append(design)
    sections += [x for x in (voltage_section(run),
                             scenario_section(_load_json(run, "impact.json",
                                                         "impact result")))
                 if x is not None]
    prov = _load_json(run, "run.json", "run record") or {}
    sections.append(provenance_section(run, prov))
    sub = f"gprm {__version__} · run directory {run.resolve().name}"
    if "seed" in prov:
        sub += f" · seed {prov['seed']}"
    if prov.get("started"):
        sub += f" · run started {prov['started']}"
    return render("GPRM tip retraction: identification, prediction and flight analysis", sub,
                  summary_cards(run, fit, prov), sections,
                  footer="Self-contained report: figures are embedded PNG images; nothing is "
                         "fetched over the network.")


def write_report(run_dir: str | Path, out: str | Path) -> Path:
    text = build_report(run_dir)
    write_text_atomic(out, text)
    return Path(out)

