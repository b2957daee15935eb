"""The exact modal solver against a general stiff integrator of the same linear equations
(scipy solve_ivp, tight tolerances): to 1e-6 of each signal's peak amplitude.

Radau at rtol 1e-10 (absolute tolerances 1e-12 of each group's scale, reference.py) for the
paper set, random sets and a measured trace; BDF once as a second integrator. Lags t0 and t1
are set off the 5 us sample grid so that the sub-sample handling is exercised.
"""

import numpy as np
import pytest

from gprm.params import batch, paper
from gprm.simulate import observe, read_voltage_csv, record_times
from gprm.simulate.core import COORDS, OUTPUTS
from gprm.simulate.reference import reference_linear

NAMES = OUTPUTS + COORDS + ("eta_dot", "mu4_dot")
TOL = 1e-6


def _compare(ps, piezo, trace=None, method="Radau", rtol=1e-10, times=None):
    times = record_times() if times is None else times
    ref = reference_linear(ps, times, piezo=piezo, voltage=trace, names=NAMES, method=method,
                           rtol=rtol)
    obs = observe(batch([ps]), times, NAMES, piezo=piezo, voltage=trace)
    assert obs.ok[0]
    peak = np.abs(ref).max(axis=1)
    assert np.all(peak > 0)
    err = np.abs(obs.y[0] - ref).max(axis=1) / peak
    assert np.all(err < TOL), dict(zip(NAMES, err))
    return err


@pytest.mark.parametrize("piezo", [1, 2])
def test_paper_set_radau_subsample_lags(piezo):
    ps = paper().with_values(t0=3.3e-6, t1=6.7e-6)
    _compare(ps, piezo)
    if piezo == 2:
        _compare(ps, piezo, method="BDF")


@pytest.mark.parametrize("piezo", [1, 2])
def test_random_sets_within_20_percent(piezo, random_sets):
    for ps in random_sets(2, seed=100 + piezo):
        _compare(ps, piezo)


def _write_trace(path, seed=0):
    """An oscilloscope-like trace: 250 kHz from 0.9 ms, 120 V then a drop with a small
    ringing, plus 0.3 V rms noise (so even the 'flat' part moves the system)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.9e-3, 1.2e-3 + 1e-12, 4e-6)
    s = np.clip(t - 1.0e-3, 0, None)
    v = 120 * np.exp(-s / 12e-6) + 3 * np.sin(2 * np.pi * 40e3 * s) * np.exp(-s / 30e-6)
    v += rng.normal(0, 0.3, t.size)
    with open(path, "w") as fh:
        fh.write("time_s,voltage_V\n")
        for a, b in zip(t, v):
            fh.write(f"{a:.9e},{b:.6f}\n")
    return path


def test_measured_trace_input(tmp_path):
    trace = read_voltage_csv(_write_trace(tmp_path / "scope.csv"))
    ps = paper().with_values(t0=2.7e-6, t1=3.1e-6)
    times = np.arange(0.95e-3, 1.2e-3, 5e-6)
    _compare(ps, 2, trace=trace, times=times)


def test_starts_in_equilibrium_and_settles_to_the_static_response():
    """Zero change before the input moves; at t = 40 s (slowest mode ~0.8 s) the state is the
    static response to the full drop: the tip retracted by its 120 V extension (K^-1 F V0)."""
    from gprm.model.linear import generated

    ps = paper()
    times = np.array([0.0, 0.5e-3, 1.0e-3 + ps["t0"] - 1e-9, 40.0])
    obs = observe(batch([ps]), times, COORDS, piezo=2)
    assert np.all(obs.y[0, :, :3] == 0)
    M, C, K = generated(2).linear_matrices(batch([ps]))
    static = np.linalg.solve(K[0], np.asarray(generated(2).INPUT) * (0 - ps["V0"]))
    np.testing.assert_allclose(obs.y[0, :, 3], static, rtol=1e-7,
                               atol=1e-9 * np.abs(static).max())
