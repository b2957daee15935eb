"""Tukey range test against statsmodels and scipy."""

import numpy as np
import pytest

from gprm.errors import GprmInputError
from gprm.flight.telemetry import AXES
from gprm.flight.tukey import tukey_range_test


def _groups(rng, sizes, shift=None):
    shift = shift or {}
    return {a: 1.02e-3 + shift.get(a, 0.0) + 3e-6 * rng.standard_normal(n)
            for a, n in zip(AXES, sizes)}


def _statsmodels(groups, alpha):
    from statsmodels.stats.multicomp import pairwise_tukeyhsd

    y = np.concatenate([groups[a] for a in groups])
    lab = np.concatenate([[a] * len(groups[a]) for a in groups])
    res = pairwise_tukeyhsd(y, lab, alpha=alpha)
    out = {}
    for row in res.summary().data[1:]:
        a, b, md, p, lo, hi, rej = row
        out[frozenset((a, b))] = (float(p), bool(rej))
    return out


@pytest.mark.parametrize("sizes,shift", [
    ((11,) * 6, None),                                   # the paper's case: k = 6, df = 60
    ((11,) * 6, {"wx": 8e-6}),                           # one treatment off
    ((11, 9, 11, 7, 10, 11), {"vy": 6e-6}),              # missing crossings: Tukey-Kramer
])
def test_against_statsmodels(sizes, shift):
    rng = np.random.default_rng(sum(sizes))
    g = _groups(rng, sizes, shift)
    res = tukey_range_test(g, alpha=0.01)
    assert res.k == 6 and res.df == sum(sizes) - 6
    ref = _statsmodels(g, 0.01)
    for p in res.pairs:
        pr, rej = ref[frozenset((p.a, p.b))]
        # statsmodels rounds its p-values to 4 decimals in the summary
        assert abs(p.p - pr) < 1e-4 + 1e-6
        assert p.reject == rej
    if shift:
        assert any(p.reject for p in res.pairs)


def test_paper_case_critical_value_and_scipy_tukey_hsd():
    from scipy.stats import studentized_range, tukey_hsd

    rng = np.random.default_rng(11)
    g = _groups(rng, (11,) * 6, {"vz_xz": 5e-6})
    res = tukey_range_test(g, alpha=0.01)
    assert (res.k, res.df) == (6, 60)
    assert res.method == "tukey"
    # tabulated upper 1 % point of the studentized range, k = 6, df = 60: 4.99
    assert abs(res.q_critical - 4.99) < 0.01
    assert res.q_critical == pytest.approx(studentized_range.ppf(0.99, 6, 60))
    ref = tukey_hsd(*[g[a] for a in AXES])
    for p in res.pairs:
        i, j = AXES.index(p.a), AXES.index(p.b)
        assert p.p == pytest.approx(ref.pvalue[i, j], rel=1e-6, abs=1e-10)
        # Eq. 9 with n = 11
        mse = np.mean([np.var(g[a], ddof=1) for a in AXES])
        q9 = abs(np.mean(g[p.a]) - np.mean(g[p.b])) / np.sqrt(mse / 11)
        assert p.q == pytest.approx(q9, rel=1e-12)


def test_bad_input():
    with pytest.raises(GprmInputError):
        tukey_range_test({"vx": [1.0, np.nan], "vy": [1.0, 2.0]})
    with pytest.raises(GprmInputError):
        tukey_range_test({"vx": [1.0]})
    with pytest.raises(GprmInputError):
        tukey_range_test({"vx": [1.0], "vy": [2.0]})          # df = 0
    with pytest.raises(GprmInputError):
        tukey_range_test({"vx": [1.0, 2], "vy": [2.0, 3]}, alpha=1.5)
