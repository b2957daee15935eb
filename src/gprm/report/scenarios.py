"""Report sections of issue 23: the retraction voltage (Fig. 5 right) and the impact
scenarios read from the telemetry (the paper's three observations checked on the measured
velocities, the scenario chosen per release with its evidence, jointly over the releases, and
the synthetic truth only where the telemetry has one). Self-contained: each section reads its
run file and returns a :class:`~gprm.report.html.Section`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gprm.flight.inference import probability_text
from gprm.report.html import Section, fig_to_img, not_run, paragraph, table

MS = 1e3
SCENARIO_TEXT = {"xz": "one contact in x–z", "yz": "one contact in y–z",
                 "two": "two contacts (x–z and y–z)"}


def fig_voltage(camp):
    """Fig. 5 right: the mean piezo voltage of the campaign's voltage runs with its spread
    (±σ across runs, and the runs' 2.5–97.5 % range), against time."""
    import matplotlib.pyplot as plt

    v = np.asarray(camp["voltage"].values, float)            # (vrun, vtime)
    t = np.asarray(camp["vtime"].values, float) * MS
    m = np.nanmean(v, 0)
    sd = np.nanstd(v, 0, ddof=1) if v.shape[0] > 1 else np.zeros_like(m)
    lo, hi = np.nanpercentile(v, [2.5, 97.5], axis=0)
    fig, ax = plt.subplots(figsize=(6.0, 3.4))
    ax.fill_between(t, lo, hi, color="#c6dbef", lw=0, label="2.5–97.5 % of the runs")
    ax.fill_between(t, m - sd, m + sd, color="#6baed6", alpha=0.6, lw=0, label="mean ± σ")
    ax.plot(t, m, color="#08306b", lw=1.2, label=f"mean of {v.shape[0]} runs")
    ax.set_xlabel("time from the start of the voltage record [ms]")
    ax.set_ylabel("piezo voltage [V]")
    ax.set_title("Retraction voltage (cf. Fig. 5 right)")
    ax.legend()
    fig.tight_layout()
    return fig


def voltage_section(run: Path) -> Section | None:
    """Fig. 5 right from ``campaign.nc`` (None when the run has no campaign file of its
    last run, :func:`gprm.report.summary.current_file`; a not-run note when the campaign has
    no voltage runs). The file is read as every NetCDF input is (:func:`gprm._io.open_netcdf`:
    one that is not NetCDF is an input error naming it, not a crash)."""
    from gprm._io import open_netcdf
    from gprm.report.summary import current_file

    path = current_file(run, "campaign.nc")
    if path is None or not path.is_file():
        return None
    s = Section("Retraction voltage", "voltage")
    camp = open_netcdf(path, what="campaign file")
    if "voltage" not in camp.variables or "vtime" not in camp.variables:
        s.blocks.append(not_run("Fig. 5 right", "the campaign has no voltage runs"))
        return s
    v = np.asarray(camp["voltage"].values, float)
    m = np.nanmean(v, 0)
    sd = np.nanstd(v, 0, ddof=1) if v.shape[0] > 1 else np.zeros_like(m)
    s.blocks.append(paragraph(
        f"{v.shape[0]} voltage runs of the campaign: the mean voltage falls from "
        f"{m[0]:.1f} V to {m[-1]:.1f} V; the spread across runs (σ) is at most "
        f"{np.nanmax(sd):.2f} V."))
    s.blocks.append(fig_to_img(fig_voltage(camp), "Mean piezo voltage of the campaign's "
                               "voltage runs with its spread: ±σ across runs (dark band) and "
                               "the runs' 2.5–97.5 % range (light band) (cf. Fig. 5 right)",
                               "fig-voltage"))
    return s


def _um(x):
    return "—" if x is None or not np.isfinite(x) else f"{x * 1e6:.1f}"


def observation_rows(imp: dict) -> list:
    """One row per release: |v_x|, |v_y|, |v_z| (µm/s), z not the largest, the x–z share,
    the compliant components; then the counts."""
    sc = imp["scenarios"]
    ob = sc["observations"]
    vel = {r["id"]: r["velocity"] for r in imp.get("releases", [])}
    rows = []
    for r in ob["releases"]:
        v = vel.get(r["id"], {})
        def val(a, v=v):
            return abs(v[a]["value"]) if a in v and v[a]["value"] is not None else None

        comp = r["components"]
        bad = [c for c, k in comp.items() if k != "non-compliant"]
        rows.append((r["id"], _um(val("vx")), _um(val("vy")), _um(val("vz_xz")),
                     "yes" if r["z_not_largest"] else "no",
                     "—" if r["xz_share"] is None else f"{r['xz_share']:.3f}",
                     "all" if not bad else "all but " + ", ".join(
                         f"{c} ({comp[c]})" for c in bad)))
    n = ob["n"]
    rows.append(("all releases", "", "", "", f"{ob['z_not_largest']}/{n}",
                 f"median {ob['xz_share_median']:.3f}; ≥ {ob['xz_share_threshold']:g} in "
                 f"{ob['xz_almost_all']}/{n}",
                 f"{', '.join(ob.get('checked', []))} all non-compliant in "
                 f"{ob['all_non_compliant']}/{n}"))
    return rows


def _ci(fit: dict, p: str, scale: float, fmt: str) -> str:
    q = (fit or {}).get("params", {}).get(p)
    if not q or q["median"] is None:
        return "—"
    lo, hi = q["ci95"]
    return f"{q['median'] * scale:{fmt}} [{lo * scale:{fmt}}, {hi * scale:{fmt}}]"


def scenario_rows(imp: dict) -> list:
    """Per release: the chosen scenario, its posterior probability and the odds against the
    runner-up, the impact time, friction and azimuth with their 95 % intervals under it;
    with a synthetic truth, the true scenario."""
    sc = imp["scenarios"]
    rows = []
    for r in sc["releases"]:
        c = r["chosen"]
        pr = r["probability"]
        ca = r.get("chosen_alone", c)          # impact.json files before the file rule
        pa = r.get("probability_alone", pr)
        le = {k: f["log_evidence"] for k, f in r["fits"].items()}
        ranked = sorted((v, k) for k, v in le.items() if v is not None)
        bf = (f"{ranked[-1][0] - ranked[-2][0]:.1f}" if len(ranked) >= 2 else "—")
        fit = r["fits"].get(c)
        row = [r["id"], "—" if c is None else SCENARIO_TEXT.get(c, c),
               "—" if pr.get(c) is None else probability_text(pr[c]),
               ("the same" if ca == c else SCENARIO_TEXT.get(ca, ca))
               + ("" if pa.get(ca) is None else f" ({probability_text(pa[ca])})"), bf,
               _ci(fit, "t", MS, ".4f"), _ci(fit, "mu", 1, ".2f"),
               _ci(fit, "phi", 180 / np.pi, ".0f"),
               "—" if not fit or fit.get("ess") is None else f"{fit['ess']:.0f}"]
        if "truth" in r:
            t = r["truth"]
            row.append(f"{t['scenario']} ({'right' if t['chosen_right'] else 'wrong'})")
        rows.append(row)
    return rows


def scenario_section(imp: dict | None) -> Section | None:
    """The impact scenarios of impact.json (None when it has none)."""
    if not imp or not imp.get("scenarios"):
        return None
    sc = imp["scenarios"]
    s = Section("Flight: impact scenarios", "scenarios")
    truth = "truth_summary" in sc
    ob = sc["observations"]
    s.blocks.append(paragraph(
        "The paper (Sec. 1) reports three observations of the in-flight releases: all TM "
        "velocity components non-compliant (> 5 µm/s, > 100 µrad/s), the z component not the "
        "predominant one, and the linear momentum almost totally in the x–z plane. Checked "
        f"here on the measured release velocities of this telemetry ({ob['n']} releases; "
        f"components {', '.join(ob['components'])}; 'almost totally' read as a share "
        f"(v_x² + v_z²)/|v|² ≥ {ob['xz_share_threshold']:g}, our threshold)."))
    s.blocks.append(table(["release", "|v_x| [µm/s]", "|v_y| [µm/s]", "|v_z| [µm/s]",
                           "z not the largest", "x–z share", "non-compliant components"],
                          observation_rows(imp), "The paper's three observations on this "
                          "telemetry", "table-observations",
                          note="'uncertain': the limit lies within 2 standard errors of the "
                               "measured value."))
    j = sc["joint"]
    jp = j.get("probability") or {}
    s.blocks.append(paragraph(
        "Impact scenario read from the telemetry (docs/flight.md §11): for each release, the "
        "posterior of the contact's unknowns (impact time, contact height and azimuth on the "
        "head, friction, restitution) under each scenario, given the measured velocity "
        "components and their standard errors and the fitted model with its uncertainty; "
        "the evidence compares the scenarios (equal prior odds). Jointly over the releases "
        f"(one scenario for all): {SCENARIO_TEXT.get(j.get('chosen'), j.get('chosen'))}"
        + (f", probability {jp[j['chosen']]:.3f}." if jp.get(j.get("chosen")) is not None
           else ".")
        + (" Each release's scenario is chosen given the whole file: either its releases "
           "share one scenario or each has its own (prior odds "
           f"{j['p_same_prior']:g} : {1 - j['p_same_prior']:g}); here the probability that "
           f"they share one is {probability_text(j['p_same'])}, and the table gives each release's choice "
           "on its own evidence beside it." if j.get("p_same") is not None else "")
        + (f" Synthetic telemetry: the chosen scenario is the true one in "
           f"{sc['truth_summary']['chosen_right']}/{sc['truth_summary']['releases']} releases"
           + (f" ({sc['truth_summary']['chosen_alone_right']} on each release's own "
              "evidence)." if "chosen_alone_right" in sc["truth_summary"] else ".")
           if truth else "")))
    head = ["release", "chosen scenario", "probability", "on its own evidence",
            "ln Bayes factor vs runner-up",
            "impact time [ms] (95 %)", "friction μ (95 %)", "azimuth φ [°] (95 %)",
            "effective draws"]
    if truth:
        head.append("true scenario")
    s.blocks.append(table(head, scenario_rows(imp), "The scenario behind each release",
                          "table-scenarios",
                          note="Medians with 95 % intervals under the chosen scenario; "
                               "effective draws: the importance sample's effective size "
                               "(intervals from a few tens of draws are rough). "
                               + ("The true scenario is shown because this telemetry is "
                                  "synthetic." if truth else
                                  "Measured telemetry: no truth exists to compare with.")))
    return s
