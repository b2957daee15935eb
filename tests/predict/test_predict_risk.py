"""Impact risk against a gap: clearance and crossing probability from sampled parameters."""

import numpy as np
import pytest

from gprm.errors import GprmInputError
from gprm.predict.risk import closing_direction, impact_risk
from gprm.predict.trajectories import default_times, sampled_points


def test_probability_matches_direct_count(fm):
    t = default_times(0.95e-3, 1.2e-3, 5e5)
    r = impact_risk(fm, 1.5e-6, 0.0, times=t, samples=150, seed=3)
    sp, _, ok = sampled_points(fm.sample(150, 3), t, ("M_xz", "M_yz"), piezo=2)
    ang = fm.params["indent_angle"]
    n_xz = np.array([np.sin(ang), 0, np.cos(ang)])
    n_yz = np.array([0, np.sin(ang), np.cos(ang)])
    peak_xz = np.einsum("a,sat->st", n_xz, sp[ok][:, 0]).max(-1)
    peak_yz = np.einsum("a,sat->st", n_yz, sp[ok][:, 1]).max(-1)
    assert r.p_cross[0] == pytest.approx(np.mean(peak_xz > 1.5e-6))
    assert r.p_cross[1] == pytest.approx(np.mean(peak_yz > 1.5e-6))
    assert 0 < r.p_cross[0] < 1   # the gap was chosen inside the spread


def test_clearance_and_monotonic(fm):
    t = default_times(0.95e-3, 1.2e-3, 5e5)
    gaps = [0.2e-6, 1.5e-6, 3e-6, 50e-6]
    rs = [impact_risk(fm, g, 0.3e-6, times=t, samples=100, seed=1) for g in gaps]
    p = np.array([r.p_cross for r in rs])
    assert np.all(np.diff(p, axis=0) <= 1e-12)
    assert np.all(p[0] > 0.9) and np.all(p[-1] < 1e-6)
    r = rs[1]
    sp, _, _ = sampled_points({k: np.atleast_1d(v) for k, v in fm.params.values.items()}, t,
                              ("M_xz",), piezo=2)
    n = closing_direction("xz", fm.params["indent_angle"])
    np.testing.assert_allclose(r.clearance[0], 1.5e-6 - n @ sp[0, 0], atol=1e-18)
    assert r.min_clearance[0] == r.clearance[0].min()
    if np.isfinite(r.t_first_cross[0]):
        k = np.searchsorted(t, r.t_first_cross[0])
        assert r.clearance[0, k] < 0 and np.all(r.clearance[0, :k] >= 0)
    assert np.all(r.min_clearance_lo <= r.min_clearance_hi)
    js = r.to_json()
    assert set(js["planes"]) == {"xz", "yz"}


@pytest.mark.parametrize("gap,std", [(0.0, 0.0), (-1e-6, 0.0), (1e-6, -1e-7)])
def test_bad_gap(fm, gap, std):
    with pytest.raises(GprmInputError):
        impact_risk(fm, gap, std, samples=0)
