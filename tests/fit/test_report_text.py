"""The text fit report (``gprm show`` and the end of ``gprm fit``) and the starts progress."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from gprm.cli import app
from gprm.fit.report_text import correlations_above, fit_report
from gprm.params import paper

sys.path.insert(0, str(Path(__file__).parent))
from means_factory import make_means  # noqa: E402


def _new_format() -> dict:
    """A fit dictionary with the fields of the newer format (issue #12)."""
    return {
        "model": "m", "piezo": 2, "sigma": "sem", "chi2": 12.5, "dof": 10, "reduced_chi2": 1.25,
        "window": [0.97e-3, 1.2e-3],
        "uncertainty": {"method": "covariance", "note": "J^T W J"},
        "starts": {"requested": 60, "converged": 50, "pruned": 8, "failed": 2, "n_at_best": 7},
        "parameters": {
            "v2": {"value": 2.0e-3, "stderr": 1.0e-4, "unit": "m", "display_unit": "mm",
                   "display_value": 2.0, "fitted": True, "initial": 2.5e-3, "at_bound": None,
                   "identified": True,
                   "interval": {"level": 0.95, "lower": 1.8e-3, "upper": 2.2e-3}},
            "g2": {"value": -4.0e-4, "stderr": None, "unit": "m", "display_unit": "mm",
                   "display_value": -0.4, "fitted": True, "initial": -3.0e-4,
                   "at_bound": "upper", "identified": False,
                   "interval": {"level": 0.95, "lower": -6e-4, "upper": None}},
            "kz": {"value": 3.0, "stderr": 0.3, "unit": "N/m", "fitted": True},
            "m": {"value": 1.0, "stderr": None, "unit": "kg", "fitted": False},
        },
        "correlation": {"names": ["v2", "g2", "kz"],
                        "matrix": [[1, -0.95, 0.2], [-0.95, 1, 0.91], [0.2, 0.91, 1]]},
    }


def _row(text: str, name: str) -> str:
    return next(ln for ln in text.splitlines() if ln.strip().startswith(f"{name} ="))


def test_report_rows_show_value_error_relative_initial_bound_identified_interval():
    text = fit_report(_new_format())
    v2 = _row(text, "v2")
    assert "2 +/- 0.1" in v2 and "(5.00%)" in v2 and "mm" in v2      # display units, 0.1/2
    assert "init = 2.5" in v2 and "[1.8, 2.2]" in v2 and "bound" not in v2
    g2 = _row(text, "g2")
    assert "n/a" in g2 and "* at upper bound" in g2 and "not identified" in g2
    assert "[-0.6, +inf]" in g2 and "init = -0.3" in g2
    kz = _row(text, "kz")                     # no display unit: SI, (0.3/3 = 10 %)
    assert "N/m" in kz and "(10.00%)" in kz and "init" not in kz
    assert "m =" not in text.split("[[Parameters]]")[1].split("fixed")[0]   # fixed: not a row
    assert "fixed: 1 parameters (m)" in text
    assert "uncertainty: covariance (J^T W J)" in text and "95 % interval" in text


def test_correlations_above_threshold_strongest_first_each_pair_once():
    corr = _new_format()["correlation"]
    assert correlations_above(corr, 0.9) == [("v2", "g2", -0.95), ("g2", "kz", 0.91)]
    assert correlations_above(corr, 0.93) == [("v2", "g2", -0.95)]
    assert len(correlations_above(corr, 0.0)) == 3
    text = fit_report(_new_format(), min_correl=0.93)
    assert "C(v2, g2) = -0.9500" in text and "C(g2, kz)" not in text


def test_report_of_an_old_file_degrades_gracefully():
    """Files without the newer fields (and without covariance) still print."""
    d = _new_format()
    for p in d["parameters"].values():
        for k in ("initial", "at_bound", "identified", "interval"):
            p.pop(k, None)
    d.pop("uncertainty")
    d["parameters_at_bounds"] = ["kz"]
    d["correlation"] = {"names": ["v2", "g2", "kz"], "matrix": None}
    d["covariance_message"] = "singular"
    text = fit_report(d)
    rows = [_row(text, n) for n in ("v2", "g2", "kz")]
    assert not any("init" in r or "identified" in r or "[" in r for r in rows)
    assert "* at a bound" in _row(text, "kz")
    assert "(no covariance: singular)" in text and "[[Correlations]]" not in text


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    d = tmp_path_factory.mktemp("show")
    means = d / "means.nc"
    make_means(paper(), seed=4).to_netcdf(means)
    out = d / "fit.json"
    r = CliRunner().invoke(app, ["fit", str(means), "--out", str(out), "--starts", "4",
                                 "--chunk", "2", "--max-iter", "8", "--band-samples", "0",
                                 "--seed", "3", "--workers", "0"])
    assert r.exit_code == 0, r.output
    return out, r.output


def test_gprm_fit_ends_with_the_text_gprm_show_prints(fitted):
    out, fit_output = fitted
    before = out.read_bytes()
    r = CliRunner().invoke(app, ["show", str(out)])
    assert r.exit_code == 0, r.output
    assert r.output.strip() in fit_output
    assert "[[Parameters]]" in r.output and "starts: 4" in r.output
    d = json.loads(before)
    # the default method's systematics and the adequacy verdict are shown, each as fit.json
    # holds them
    syst = d["uncertainty"]["details"]["systematics"]
    flat = " ".join(r.output.split())            # the console may wrap the long line
    assert "systematics marginalised" in flat
    assert all(f"{s}: gain {100 * v['gain_sd']:.3g} %" in flat for s, v in syst.items())
    assert all(f"crossing offset {1e9 * v['crossing_offset_s']:+.3g} ns" in flat
               for v in syst.values())
    assert "time origin" not in flat                # the crossing offset is not on t0
    # this means file predates the synchronisation's timing sd: said, not shown as 0
    assert all(v["sync_timing_sd_s"] is None for v in syst.values())
    assert flat.count("synchronisation not in the means file") == len(syst)
    det = d["uncertainty"]["details"]
    assert (f"gain error the residuals show: {100 * det['gain_estimated']:.3g} % "
            f"({det['gain_estimated_z']:.1f} sd of its noise without one") in flat
    # the prediction draws were projected onto the data (gprm.fit.draws): counts as held
    dr = det["draws"]
    assert 0 < dr["kept"] <= 400 and dr["proposed"] >= dr["kept"]
    assert f"prediction draws: {dr['kept']} kept of {dr['proposed']} proposals" in flat
    adq = d["uncertainty"]["adequacy"]
    assert f"[[Adequacy]] {adq['verdict']}" in flat and adq["text"].split(":")[0] in flat
    assert sum(1 for p in d["parameters"].values() if p["fitted"]) == \
        sum(1 for ln in r.output.splitlines() if " = " in ln and "+/-" in ln)
    assert out.read_bytes() == before                      # input not modified


@pytest.mark.parametrize("content, text", [
    (None, "does not exist"), ("{not json", "not valid JSON"),
    ('{"chi2": 1}', "field 'model'"),
    ('{"model": "gprm-3d", "chi2": 1}', "field 'parameters'"),
    ('{"model": "gprm-3d", "parameters": {"m2": {"value": "x"}}}', "field 'parameters.m2.value'")])
def test_gprm_show_bad_files(tmp_path, content, text):
    f = tmp_path / "f.json"
    if content is not None:
        f.write_text(content)
    r = CliRunner().invoke(app, ["show", str(f)])
    assert r.exit_code == 2 and text in r.output and "Traceback" not in r.output


def test_progress_counts_starts_and_reports_best_chi2():
    """run_multistart reports starts (not chunks) and the running minimum of chi-square."""
    from gprm.fit.engine import run_multistart
    from gprm.fit.objective import Objective, fit_data_from_means
    from gprm.fit.starts import LMOptions, MultiStartOptions

    data = fit_data_from_means(make_means(paper(), seed=4))
    obj = Objective.create(data, paper(), piezo=2)
    opts = MultiStartOptions(n_starts=5, seed=1, chunk_size=2, lm=LMOptions(max_iter=3))
    calls, plain = [], []
    out = run_multistart(obj, opts, progress=lambda d, t, best_chi2: calls.append((d, t,
                                                                                   best_chi2)))
    run_multistart(obj, opts, progress=lambda d, t: plain.append((d, t)))
    assert [c[:2] for c in calls] == [(0, 5), (2, 5), (4, 5), (5, 5)] == plain
    assert math.isnan(calls[0][2])
    bests = [c[2] for c in calls[1:]]
    assert bests == sorted(bests, reverse=True)            # a running minimum
    assert bests[-1] == pytest.approx(np.nanmin(out.chi2))
    assert bests[0] == pytest.approx(np.nanmin(out.chi2[:2]))


def test_starts_line_names_raced_starts_only_when_there_are_some():
    d = _new_format()
    line = next(ln for ln in fit_report(d).splitlines() if "starts:" in ln)
    assert "raced" not in line and "pruned 8, failed 2" in line
    d["starts"] = {**d["starts"], "raced": 40, "race": [[3, 25], [6, 5]]}
    line = next(ln for ln in fit_report(d).splitlines() if "starts:" in ln)
    assert "pruned 8, raced 40, failed 2, at best (dchi2<=1) 7" in line


def test_report_names_other_minima_and_the_parameters_they_widen_most():
    """The uncertainty block says how many other minima fit as well as the best and which
    parameters' intervals they widened by more than half (factors indexed like the
    correlation's names, not the parameter table, which also lists fixed parameters)."""
    d = _new_format()
    d["uncertainty"] = {"method": "sandwich", "details": {
        "statistical_from": "runs and residuals",
        "alternative_minima": {"within_95": 2, "within_68": 1, "distinct": 5,
                               "factors": {"lower": [1.0, 3.0, 1.0],
                                           "upper": [1.2, 1.0, 1.6]}}}}
    line = next(ln for ln in fit_report(d).splitlines() if "other minima" in ln)
    assert "2 of 5" in line and "widened most: g2, kz" in line and "v2" not in line
    d["uncertainty"]["details"]["alternative_minima"]["within_95"] = 0
    assert "other minima" not in fit_report(d)


def test_report_names_the_sides_the_profile_lengthened():
    """The uncertainty block names each parameter whose 95 % side the profile check stretched
    by more than half, with the side and the factor (indexed like the correlation's names);
    none such, no line."""
    d = _new_format()
    d["uncertainty"] = {"method": "sandwich", "details": {
        "statistical_from": "runs and residuals",
        "profile_factors": {"lower": [1.0, 4.08, 1.2], "upper": [1.0, 1.0, 2.5],
                            "lower_68": [1.0, 5.0, 1.0], "upper_68": [1.0, 1.0, 2.0]}}}
    line = next(ln for ln in fit_report(d).splitlines() if "profile longer" in ln)
    assert "g2 lower x4.08" in line and "kz upper x2.5" in line and "v2" not in line
    d["uncertainty"]["details"]["profile_factors"] = {"lower": [1.0, 1.4, 1.0],
                                                      "upper": [1.0, 1.0, 1.1]}
    assert "profile longer" not in fit_report(d)


def test_report_names_the_parameters_whose_intervals_left_the_residuals_excess_out():
    """The excess test (item 9 of docs/fitting.md's default): the uncertainty block names the
    parameters whose intervals the residuals' excess did not reach (indexed like the
    correlation's names) and says whether the draws keep it; every one reached, or a file
    from before the test (no field), no line; the lags, which the excess reaches only when
    stated, are not named as the test's."""
    d = _new_format()
    d["uncertainty"] = {"method": "sandwich", "details": {
        "excess_reaches": [True, False, False], "draws_excess": "untested"}}
    line = next(ln for ln in fit_report(d).splitlines() if "excess" in ln)
    assert line.endswith("the draws keep it): g2, kz") and "v2" not in line
    d["uncertainty"]["details"]["draws_excess"] = "tested"
    line = next(ln for ln in fit_report(d).splitlines() if "excess" in ln)
    assert "the draws leave it out too): g2, kz" in line
    for reach in ([True, True, True], None):
        d["uncertainty"]["details"]["excess_reaches"] = reach
        assert "excess" not in fit_report(d)
    # a lag the excess never reaches (Systematics.excess_on_lags off) is not listed as left
    # out by the test; with the excess stated on the lags it is
    d["correlation"]["names"] = ["v2", "g2", "t0"]
    d["uncertainty"]["details"]["excess_reaches"] = [True, False, False]
    line = next(ln for ln in fit_report(d).splitlines() if "excess" in ln)
    assert line.endswith("): g2")
    d["uncertainty"]["details"]["stated"] = {"excess_on_lags": True}
    line = next(ln for ln in fit_report(d).splitlines() if "excess" in ln)
    assert line.endswith("): g2, t0")


def test_report_lists_the_parameters_whose_variance_has_few_degrees_of_freedom():
    """Student's t: the uncertainty block lists, fewest first, each parameter whose variance
    has fewer than STUDENT_SHOWN degrees of freedom with the part they came from (indexed
    like the correlation's names); none such, no line."""
    d = _new_format()
    d["uncertainty"] = {"method": "sandwich", "details": {
        "degrees_of_freedom": [12.0, None, 5.5],
        "degrees_of_freedom_from": ["runs", None, "residuals"]}}
    line = next(ln for ln in fit_report(d).splitlines() if "Student" in ln)
    assert line.endswith("kz 5.5 (residuals), v2 12 (runs)") and "g2" not in line
    d["uncertainty"]["details"]["degrees_of_freedom"] = [40.0, None, None]
    assert "Student" not in fit_report(d)


def test_report_says_the_runs_were_moved_through_the_model():
    """A fit whose runs carried a sub-sample remainder says so, with the largest remainder
    and change of the mean (fit.json ``polish.subsample``); a fit without one says nothing."""
    d = _new_format()
    assert "sub-sample" not in fit_report(d)
    d["polish"] = {"subsample": {
        "x_base": {"max_remainder_s": 2.4e-6, "max_mean_change_m": 3.0e-9,
                   "max_run_change_m": 9e-9},
        "z_bk": {"max_remainder_s": 1.2e-6, "max_mean_change_m": 9.2e-8,
                 "max_run_change_m": 4e-7}}}
    line = next(ln for ln in fit_report(d).splitlines() if "sub-sample" in ln)
    assert "2.4 us" in line and "92 nm" in line


def test_report_shows_the_synchronisations_timing_sd_per_signal():
    """fit.json's per-signal ``sync_timing_sd_s`` (stop 43) is printed in ns beside the
    alignment noise."""
    d = _new_format()
    d["uncertainty"] = {"method": "sandwich", "details": {"systematics": {
        "x_base": {"gain_sd": 0.001, "timing_sd_s": 6e-9, "alignment_sd_s": 2e-9,
                   "sync_timing_sd_s": 5.6e-9, "crossing_offset_s": 1e-7}}}}
    flat = " ".join(fit_report(d).split())
    assert "alignment 2 ns, synchronisation 5.6 ns, crossing offset +100 ns" in flat


def test_report_says_how_the_draws_were_put_back_on_the_data():
    """fit.json's ``details.draws`` (stop 44) in words; a file without it says nothing."""
    d = _new_format()
    d["uncertainty"] = {"method": "sandwich", "details": {
        "draws": {"kept": 400, "proposed": 588, "acceptance": 0.73, "threshold": 330.0,
                  "scale": 7.2, "misfit_median": 5.3}}}
    flat = " ".join(fit_report(d).split())
    assert "prediction draws: 400 kept of 588 proposals (73 % reproduce" in flat
    d["uncertainty"]["details"].pop("draws")
    assert "prediction draws" not in fit_report(d)


def test_first_line_says_the_weights_and_their_pooling():
    """fit.json's sigma and sigma_pool on the report's first line; an older file without
    sigma_pool (sample-by-sample weights) says nothing of pooling."""
    d = _new_format()
    d["sigma"], d["sigma_pool"] = "sem", 3
    assert fit_report(d).splitlines()[0].endswith("sigma=sem pooled over +-3 samples")
    d.pop("sigma_pool")
    assert fit_report(d).splitlines()[0].endswith("sigma=sem")
