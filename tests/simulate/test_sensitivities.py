"""Exact sensitivities against central finite differences of the solver itself, for the 23
fitted parameters and the output-map distances (and V0, h2), default profile and a measured
trace, both piezos."""

import numpy as np
import pytest

from gprm.params import FITTED_DEFAULT, batch, paper
from gprm.simulate import VoltageTrace, observe
from gprm.simulate.core import OUTPUTS
from sens_fd import compare_with_central_differences

EXTRA = ("d_x_base", "d_x_head", "d_y_base", "d_y_head", "h2", "k3", "T_em")
NAMES = OUTPUTS + ("mu4", "eta", "q")
TIMES = np.arange(0.97e-3, 1.2e-3 + 1e-12, 5e-6)


def _fd_check(ps, piezo, sens, trace=None, rel=1e-4, tol=1e-5):
    """Central differences with step ``rel * |p|``: their truncation error (~rel^2) and
    rounding error (the solver's ~1e-13 relative accuracy divided by the step) both stay near
    2e-6 of a parameter's effect at rel = 1e-4 (measured: 1e-3 gives 2e-4, 1e-5 gives 2e-5),
    so 1e-5 is the tolerance; a wrong or missing sensitivity term gives O(1) errors."""
    exact, plain, worst, _ = compare_with_central_differences(
        ps, sens, NAMES, TIMES, step=lambda n, v: rel * abs(v), piezo=piezo, trace=trace)
    np.testing.assert_allclose(exact.y[0], plain.y[0], rtol=0, atol=1e-12 * np.abs(plain.y[0]).max())
    for n in sens:
        assert worst[n] < tol, (n, worst[n])
    return worst


@pytest.mark.parametrize("piezo", [1, 2])
def test_default_profile_random_set(piezo, random_sets):
    ps = random_sets(1, seed=40 + piezo)[0]
    _fd_check(ps, piezo, FITTED_DEFAULT + EXTRA + ("V0",))


def test_measured_trace():
    t = np.arange(0.95e-3, 1.2e-3, 4e-6)
    v = 120 * np.exp(-np.clip(t - 1e-3, 0, None) / 9e-6) + 0.5 * np.cos(7e4 * t)
    ps = paper().with_values(t0=3.3e-6, t1=6.1e-6)
    _fd_check(ps, 2, FITTED_DEFAULT + EXTRA, trace=VoltageTrace(t, v))


def test_sensitivity_order_and_shape():
    ps = paper()
    names = ("t1", "m2", "d_x_head")
    o = observe(batch([ps, ps]), TIMES, OUTPUTS, sensitivities=names)
    assert o.dy.shape == (2, len(OUTPUTS), TIMES.size, 3)
    assert o.sens_names == names
    # t1 only acts on the lagged z_bk; d_x_head only on x_head
    assert np.all(o.dy[:, :4, :, 0] == 0) and np.any(o.dy[:, 4, :, 0] != 0)
    assert np.all(o.dy[:, [0, 2, 3, 4], :, 2] == 0) and np.any(o.dy[:, 1, :, 2] != 0)


def test_failed_sets_are_masked_without_disturbing_the_others(random_sets):
    """A batch with a singular set (no lateral x stiffness: a free mode) in the middle: that
    set comes back NaN with ok False and a reason; the others equal their single-set runs."""
    good = random_sets(2, seed=9)
    bad = paper().with_values(k_Ax=0.0, k_Bx=0.0)
    names = FITTED_DEFAULT[:5] + ("t1", "d_x_head")
    o = observe(batch([good[0], bad, good[1]]), TIMES, NAMES, sensitivities=names)
    assert o.ok.tolist() == [True, False, True]
    assert o.reason[1] and np.all(np.isnan(o.y[1])) and np.all(np.isnan(o.dy[1]))
    for k, ps in ((0, good[0]), (2, good[1])):
        single = observe(batch([ps]), TIMES, NAMES, sensitivities=names)
        np.testing.assert_allclose(o.y[k], single.y[0], rtol=1e-12, atol=1e-24)
        np.testing.assert_allclose(o.dy[k], single.dy[0], rtol=1e-9,
                                   atol=1e-12 * np.abs(single.dy[0]).max())


def test_unstable_and_singular_sets_are_flagged():
    """Negative damping (rejected by parameter validation, so built here directly) gives an
    unstable mode; zero rotational stiffness about x (b1 = b2 = 0) a free mode."""
    base = batch([paper()])
    unstable = dict(base, c_Cy=np.array([-50.0]), c_Dy=np.array([-50.0]))
    free = dict(base, b1=np.array([0.0]), b2=np.array([0.0]))
    o = observe({k: np.concatenate([unstable[k], free[k], base[k]]) for k in base}, TIMES)
    assert o.ok.tolist() == [False, False, True]
    assert "unstable" in o.reason[0] and "free" in o.reason[1]


def test_only_lagged_or_only_unlagged_rows():
    ps = paper()
    names = ("m2", "t0", "t1", "k_Az")
    full = observe(batch([ps]), TIMES, ("x_head", "z_bk"), sensitivities=names)
    for k, row in enumerate(("x_head", "z_bk")):
        part = observe(batch([ps]), TIMES, (row,), sensitivities=names)
        np.testing.assert_allclose(part.y[0, 0], full.y[0, k], rtol=1e-13,
                                   atol=1e-14 * np.abs(full.y[0, k]).max())
        np.testing.assert_allclose(part.dy[0, 0], full.dy[0, k], rtol=1e-12,
                                   atol=1e-15 * np.abs(full.dy).max())


def test_the_profiles_time_constant_has_no_exact_sensitivity_and_says_so():
    """tau_v acts on the input profile, not on the equations of motion: the EOM path would
    return zeros for it while the outputs move (central differences below), so asking for
    it is an error that says what to do instead."""
    pb = batch([paper()])
    with pytest.raises(KeyError, match="tau_v acts on the input profile"):
        observe(pb, TIMES, OUTPUTS, sensitivities=("tau_v",))
    v = paper().values["tau_v"]
    up, dn = (observe(batch([paper().with_values(tau_v=v * f)]), TIMES, OUTPUTS).y
              for f in (1 + 1e-5, 1 - 1e-5))
    assert np.abs(up - dn).max() > 1e-6 * np.abs(up).max()      # it does move the outputs
