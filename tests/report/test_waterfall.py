"""The waterfall plot draws every start and counts those at the best chi-square."""

from __future__ import annotations

import numpy as np

from gprm.report.figures import waterfall, waterfall_counts


def test_waterfall_counts_and_draws(tmp_path):
    chi2 = np.array([10.2, 10.0, 10.9, 11.5, 250.0, np.nan, 3000.0])
    c = waterfall_counts(chi2)
    assert c == {"n_starts": 7, "n_failed": 1, "best": 10.0, "n_at_best": 3}
    fig = waterfall(chi2)
    ax = fig.axes[0]
    drawn = np.concatenate([ln.get_ydata() for ln in ax.lines[:1]])
    np.testing.assert_array_equal(drawn, np.sort(chi2[np.isfinite(chi2)]))
    assert "3" in ax.get_legend().get_texts()[1].get_text()
    fig.savefig(tmp_path / "w.png")
    assert (tmp_path / "w.png").stat().st_size > 1000


def test_waterfall_with_no_finite_start():
    fig = waterfall([np.nan, np.nan])
    assert fig.axes[0].texts
