"""Issue 15's report items: readable units and values, Fig. 3 panels, Fig. 7's initial value,
the runs count, provenance notes once and the git commit."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import xarray as xr

sys.path.insert(0, str(Path(__file__).parent))
import report_runfactory as runfactory  # noqa: E402

from gprm.report import figures as F  # noqa: E402
from gprm.report.build import (build_report, campaign_section, flight_section,  # noqa: E402
                               git_commit, provenance_section, summary_cards, table3_rows)
from gprm.report.html import num, pm  # noqa: E402
from gprm.report.summary import summarise  # noqa: E402


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    run = tmp_path_factory.mktemp("items")
    runfactory.make_means(run / "means.nc")
    runfactory.make_fit(run, starts=6)
    return run


def test_pm_keeps_the_value_when_the_error_exceeds_it():
    assert pm(1.03e7, 5.2e8) == "1.03 × 10⁷ ± 5.2 × 10⁸"       # was "(0.1 ± 5.2) × 10⁸"
    assert pm(9.9e-11, 3.5) == "9.90 × 10⁻¹¹ ± 3.5"             # was "0.0 ± 3.5"
    assert pm(2.752, 0.045) == "2.752 ± 0.045"                  # unchanged otherwise


def test_table3_damping_unit_is_typeset(run):
    fit = json.loads((run / "fit.json").read_text())
    units = {r[0]: r[1] for r in table3_rows(fit, None)}
    assert units["c_Ax"] == "N·s/m" and not any("*" in u for u in units.values())


def test_runs_averaged_says_one_number_when_all_positions_agree(run):
    text = "".join(map(str, campaign_section(run).blocks))
    assert "Runs averaged per position: 10." in text and "10–10" not in text


def _texts(fig):
    return [t.get_text() for ax in fig.axes for t in ax.get_xticklabels()]


def test_fig3_panels_start_near_the_trigger_and_sigma_has_its_own_axis(run):
    with xr.open_dataset(run / "means.nc") as means:
        fig = F.fig_mean_signals(means)
        t_end = float(means["time"].values[-1]) * 1e3
        sd_max = float(means["std"].sel(signal="x_base").max()) * 1e9
    main = [ax for ax in fig.axes if ax.get_title()]
    assert len(main) == 4
    for ax in main:
        lo, hi = ax.get_xlim()
        assert lo == pytest.approx(0.9) and hi == pytest.approx(t_end)
        assert (1.0 - lo) / (hi - lo) < 0.3                 # before the trigger: < 30 %
    twin = [ax for ax in fig.axes if ax.get_ylabel() == "σ(t) [nm]"]
    assert len(twin) == 1
    assert twin[0].get_ylim()[1] == pytest.approx(1.15 * sd_max)   # σ fills its axis


def test_fig7_plots_the_initial_value_its_caption_names(run):
    fit = json.loads((run / "fit.json").read_text())
    fig = F.fig_masses(fit)
    labels = _texts(fig)
    assert labels.count("initial") == 4 and labels.count("fit") == 4


def test_provenance_lists_a_repeated_note_once_with_its_stages_and_the_commit(run):
    note = "degenerate draws from the fit covariance"
    prov = {"stages": {s: {"info": {"notes": [note]}} for s in ("predict", "telemetry",
                                                              "impact")},
            "git": "abc123"}
    text = "".join(map(str, provenance_section(run, prov).blocks))
    assert text.count(note) == 1 and "note (predict, telemetry, impact)" in text
    assert "abc123" in text and "git commit (report)" in text


def test_git_commit_of_a_checkout_and_outside_one(tmp_path):
    here = git_commit()
    head = subprocess.run(["git", "-C", str(Path(__file__).parent), "rev-parse", "HEAD"],
                          capture_output=True, text=True)
    if head.returncode == 0:
        assert re.fullmatch(r"[0-9a-f]{40}(\+dirty)?", here)
        assert here.startswith(head.stdout.strip())
    assert git_commit(tmp_path) == "not a git checkout"


# ------------------------------------------------------------------ issue 22, item 15

def test_provenance_omits_options_not_given_and_shows_times_with_units(run):
    prov = {"options": {"campaign": None, "telemetry": None, "seed": 0,
                        "preprocess": {"align_time": 0.00101, "threshold_factor": 2.0},
                        "fit": {"window": [0.00097, 0.0012], "gain_sd": None,
                                "timing_sd": 2e-7, "starts": 50}}}
    text = "".join(map(str, provenance_section(run, prov).blocks))
    assert "option campaign" not in text and "None" not in text
    assert "1.01 ms" in text and "0.00101" not in text
    assert "0.97, 1.2 ms" in text and "200 ns" in text
    assert "option fit.starts" in text


def test_table3_gives_every_lag_in_microseconds(run):
    fit = json.loads((run / "fit.json").read_text())
    rows = {r[0]: r for r in table3_rows(fit, {"t0": 4.2e-6})}
    lags = [n for n in rows if n in ("t0", "t1") or n.startswith("dt_")]
    assert "t0" in lags and "t1" in lags
    for n in lags:
        assert rows[n][1] == "µs", rows[n]
        assert "10⁻" not in " ".join(rows[n][2:4]), rows[n]
    t0 = fit["parameters"]["t0"]["value"]
    assert rows["t0"][2] == num(t0 * 1e6) and rows["t0"][5] == "4.2"


def test_the_stages_card_counts_the_stages_the_terminal_lists(run):
    stages = {k: {"status": "ran", "seconds": 1.0} for k in
              ("campaign", "preprocess", "fit", "predict", "telemetry", "impact")}
    cards = {c.label: c for c in summary_cards(run, None, {"stages": stages})}
    assert cards["stages"].value == "7 / 7 done"          # the report is the terminal's 7th
    stages["fit"] = {"status": "failed"}
    cards = {c.label: c for c in summary_cards(run, None, {"stages": stages})}
    assert cards["stages"].value == "6 / 7 done" and "fit (failed)" in cards["stages"].note


def test_real_telemetry_report_names_rejected_releases_and_claims_no_truth(tmp_path):
    run = tmp_path / "real"
    run.mkdir()
    runfactory.make_means(run / "means.nc")
    runfactory.make_fit(run, starts=6)
    runfactory.make_impact(run / "impact.json", releases=4, truth=False,
                           joint_rejected=("R03",))
    cards = {c.label: c for c in summary_cards(run, None, {})}
    assert cards["joint impact time"].value == "rejected: R03"
    assert cards["joint impact time"].tone == "bad"
    assert "R03" in summarise(run)["joint"]["verdict"]
    html = build_report(run)
    assert "R03" in html and "joint χ² test rejects" in html
    flight = re.sub(r"base64,[A-Za-z0-9+/=]+", "",          # the text, not the images
                    "".join(map(str, flight_section(run).blocks)))   # (telemetry: no truth)
    assert "R03" in flight and "true impact time" not in flight
    assert "synthetic" not in flight and "truth" not in flight


def test_synthetic_telemetry_keeps_its_truth_captions(tmp_path):
    run = tmp_path / "synth"
    run.mkdir()
    runfactory.make_impact(run / "impact.json", releases=3, joint_rejected=())
    html = build_report(run)
    assert "true impact times of the synthetic releases" in html
    cards = {c.label: c for c in summary_cards(run, None, {})}
    assert cards["joint impact time"].value == "every release consistent"


@pytest.mark.slow
def test_a_run_on_csv_telemetry_without_truth_claims_no_truth(tmp_path):
    """``gprm run`` with measured (CSV) telemetry: the report's flight captions and summary
    claim no true impact time, and the closing table counts the report among the stages."""
    import csv

    from typer.testing import CliRunner

    from gprm.campaign.synth import SynthConfig, synth_campaign
    from gprm.cli import app
    from gprm.fit.files import paper_model
    from gprm.flight.synth import SynthOptions, synth_telemetry

    synth_campaign(seed=1, config=SynthConfig(n_runs=3, n_noise=2, nonlinear=False)
                   ).to_netcdf(tmp_path / "c.nc")
    tel = synth_telemetry(paper_model(2), SynthOptions(n_releases=3))
    with (tmp_path / "tel.csv").open("w", newline="") as fh:    # the channels alone
        w = csv.writer(fh)
        chans = [c for c in ("x", "y", "z", "theta", "eta", "phi") if c in tel]
        w.writerow(["release", "time [s]", "release_time [s]"]
                   + [f"{c} [{tel[c].attrs['units']}]" for c in chans])
        for i, rid in enumerate(tel["release"].values):
            for k in range(tel.sizes["sample"]):
                t = float(tel["time"].values[i, k])
                if t == t:
                    w.writerow([str(rid), repr(t), repr(float(tel["release_time"].values[i]))]
                               + [repr(float(tel[c].values[i, k])) for c in chans])
    r = CliRunner().invoke(app, ["run", str(tmp_path / "c.nc"), "--telemetry",
                                 str(tmp_path / "tel.csv"), "--out", str(tmp_path / "run"),
                                 "--quick", "--starts", "4", "--workers", "0"])
    assert r.exit_code == 0, r.output
    html = re.sub(r"base64,[A-Za-z0-9+/=]+", "", (tmp_path / "run" / "report.html").read_text())
    flight = html[html.index('id="flight"'):html.index('id="provenance"')]
    assert "true impact time" not in flight and "synthetic releases" not in flight
    assert ">None<" not in html                   # options not given are left out
    assert "7 / 7 done" in html


def test_fit_paragraph_says_when_racing_stopped_starts(tmp_path):
    from gprm.report.build import fit_section

    run = tmp_path / "r"
    run.mkdir()
    runfactory.make_means(run / "means.nc")
    runfactory.make_fit(run, starts=6)
    text = "".join(map(str, fit_section(run)[0].blocks))
    assert "racing" not in text
    doc = json.loads((run / "fit.json").read_text())
    doc["starts"].update(raced=4, race=[[3, 25], [6, 5]])
    (run / "fit.json").write_text(json.dumps(doc))
    text = "".join(map(str, fit_section(run)[0].blocks))
    assert "(4 stopped early by racing, schedule 3:25, 6:5; the counts are of the starts " \
           "that ran on)" in text
