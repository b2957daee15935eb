"""The summary's truth recovery on hand-made fit results (independent numbers)."""

from __future__ import annotations

import math

from gprm.report.summary import truth_for_fit, truth_recovery, truth_recovery_text


def _fit(**params):
    return {"parameters": {k: {"value": v, "stderr": e, "fitted": True}
                           for k, (v, e) in params.items()}}


def test_z_scores_and_counts():
    fit = _fit(m2=(12.0e-3, 0.5e-3), k_lr=(1.7e6, 0.1e6), v2=(2.0e-3, 0.2e-3))
    truth = {"m2": 12.4e-3, "k_lr": 1.64e6, "v2": 2.7e-3}
    tr = truth_recovery(fit, truth)
    assert tr["n"] == 3
    assert math.isclose(tr["z"]["m2"], -0.8, rel_tol=1e-9)
    assert math.isclose(tr["z"]["k_lr"], 0.6, rel_tol=1e-9)
    assert math.isclose(tr["z"]["v2"], -3.5, rel_tol=1e-9)
    assert (tr["within_1sigma"], tr["within_2sigma"], tr["within_3sigma"]) == (2, 2, 2)
    assert math.isclose(tr["max_abs_z"], 3.5)
    assert math.isclose(tr["mass_max_relative_error"], 0.4 / 12.4)


def test_without_standard_errors_only_relative_errors():
    tr = truth_recovery(_fit(m2=(12.0e-3, None)), {"m2": 12.5e-3})
    assert tr["n"] == 0 and math.isnan(tr["max_abs_z"])
    assert math.isclose(tr["relative_error"]["m2"], -0.04)


def test_lag_truth_follows_the_fitted_offsets():
    truth = {"t0": 4e-6, "t1": 5e-6, "t0_with_offsets": 1e-6, "t1_with_offsets": 7e-6,
             "dt_x_head": 4.8e-6, "m2": 1.0}
    plain = truth_for_fit(truth, _fit(t0=(0, 1), t1=(0, 1)))
    assert plain["t0"] == 4e-6 and plain["t1"] == 5e-6 and "dt_x_head" not in plain
    off = truth_for_fit(truth, _fit(t0=(0, 1), t1=(0, 1), dt_x_head=(0, 1)))
    assert off["t0"] == 1e-6 and off["t1"] == 7e-6 and off["dt_x_head"] == 4.8e-6
    assert not any(k.endswith("_with_offsets") for k in off)


def test_undetermined_parameters_get_no_z_and_intervals_are_counted():
    """A parameter the data do not determine has a meaningless standard error: it is counted
    apart, by whether its (wide) interval holds the truth; identified ones by theirs."""
    def p(value, stderr, lo95, hi95, lo68, hi68, identified):
        return {"value": value, "stderr": stderr, "fitted": True, "identified": identified,
                "interval": {"lower": lo95, "upper": hi95},
                "interval68": {"lower": lo68, "upper": hi68}}
    fit = {"parameters": {
        "m2": p(12.0e-3, 0.5e-3, 11e-3, 13e-3, 11.5e-3, 12.5e-3, True),    # in 68 and 95
        "k_lr": p(1.7e6, 0.1e6, 1.5e6, 1.9e6, 1.65e6, 1.75e6, True),       # in 95 only
        "c_Ax": p(0.1, 0.15, 0.01, 1.4, 0.05, 0.5, False),                 # z would be 6.6
        "c_Bx": p(20.0, 1.0, 15.0, 25.0, 18.0, 22.0, False)}}              # outside
    truth = {"m2": 12.4e-3, "k_lr": 1.6e6, "c_Ax": 1.09, "c_Bx": 30.0}
    tr = truth_recovery(fit, truth)
    assert set(tr["z"]) == {"m2", "k_lr"} and tr["n"] == 2
    assert (tr["n_interval"], tr["in95"], tr["in68"]) == (2, 2, 1)
    assert (tr["undetermined"], tr["undetermined_in95"]) == (2, 1)
    assert math.isclose(tr["max_abs_z"], 1.0)
    line = truth_recovery_text(tr)
    assert "2/2 identified" in line and "1/2 inside 68 %" in line
    assert "2 not determined" in line and "1 with the truth inside" in line


def test_parameters_leaning_on_the_prior_are_counted_apart_from_the_undetermined():
    """A narrow interval that is mostly the prior's (fit.json ``leans_on_prior``) is neither
    identified (no z, not in the identified coverage) nor 'not determined': its own count."""
    def p(value, lo95, hi95, identified, leans=False):
        d = {"value": value, "stderr": 0.1 * value, "fitted": True, "identified": identified,
             "interval": {"lower": lo95, "upper": hi95},
             "interval68": {"lower": lo95, "upper": hi95}}
        return {**d, "leans_on_prior": True} if leans else d
    fit = {"parameters": {
        "m2": p(12.0e-3, 11e-3, 13e-3, True),
        "b1": p(42e-3, 41e-3, 43e-3, False, leans=True),      # truth outside
        "k_Cy": p(7e6, 1e6, 5e7, False)}}
    tr = truth_recovery(fit, {"m2": 12.4e-3, "b1": 45e-3, "k_Cy": 8e6})
    assert set(tr["z"]) == {"m2"} and tr["n_interval"] == 1
    assert (tr["leans_on_prior"], tr["leans_in95"]) == (1, 0)
    assert (tr["undetermined"], tr["undetermined_in95"]) == (1, 1)
    line = truth_recovery_text(tr)
    assert "1 not determined" in line and "1 leaning on the prior (0 with the truth" in line
