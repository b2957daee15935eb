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
from gprm.report.build import (campaign_section, git_commit, provenance_section,  # noqa: E402
                               table3_rows)
from gprm.report.html import pm  # noqa: E402


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
