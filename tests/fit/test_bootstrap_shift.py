"""The parametric bootstrap compares refits with the best fit in the same time base.

Preprocessing aligns each mean signal at its threshold crossing, which moves a synthetic
campaign's signal p by ``truth_shift[p]`` (aligned(t) = original(t - s)). The model's lags
then absorb the move; ``time_base_shift`` must name the lag changes that reproduce it.
Checked here against the simulator itself, not against the formula.
"""
from __future__ import annotations

import numpy as np
import xarray as xr

from gprm.fit.bootstrap import time_base_shift
from gprm.params import LAG_PARAMETERS, paper
from gprm.simulate.core import simulate

SIGNALS = ["x_base", "x_head", "y_base", "y_head", "z_bk"]


def _means(shift):
    return xr.Dataset({"truth_shift": (("signal",), np.asarray(shift, float))},
                      coords={"signal": SIGNALS})


def test_shift_in_lags_reproduces_the_aligned_signals():
    p = paper()
    names = list(p.values)
    for extra in ("dt_x_head", "dt_y_base", "dt_y_head"):
        if extra not in names:
            names.append(extra)
    base = {n: np.array([float(p.values.get(n, 0.0))]) for n in names}
    shift = np.array([1.3e-6, -0.7e-6, 2.1e-6, 0.4e-6, -1.1e-6])
    moved = time_base_shift(_means(shift), names)
    # exactly the registry's lags move (the parametric bootstrap widens the same set)
    assert {n for n, m in zip(names, moved) if m != 0} == set(LAG_PARAMETERS)

    t = np.linspace(0.95e-3, 1.2e-3, 201)  # the retraction starts at t_c + t0
    shifted = {n: base[n] + moved[i] for i, n in enumerate(names)}
    for s, signal in zip(shift, SIGNALS):
        want = simulate(base, time=t - s).outputs[signal][0]       # original(t - s)
        got = simulate(shifted, time=t).outputs[signal][0]
        scale = np.max(np.abs(want))
        assert np.max(np.abs(got - want)) < 1e-9 * scale, signal
        # and the shift matters at this size (the check above could not pass by accident)
        plain = simulate(base, time=t).outputs[signal][0]
        assert np.max(np.abs(plain - want)) > 1e-4 * scale, signal


def test_no_shift_known_means_no_correction():
    names = ["t0", "t1", "k_Ax", "dt_x_head"]
    assert np.all(time_base_shift(xr.Dataset(coords={"signal": SIGNALS}), names) == 0)
    nan_shift = _means([np.nan, 0.5e-6, 0.0, 0.0, 0.0])
    out = time_base_shift(nan_shift, names)
    assert np.all(np.isfinite(out)) and out[2] == 0.0
