"""The summary's truth recovery on hand-made fit results (independent numbers)."""

from __future__ import annotations

import math

from gprm.report.summary import truth_for_fit, truth_recovery


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
