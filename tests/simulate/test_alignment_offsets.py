"""Per-signal alignment offsets (dt_x_head, dt_y_base, dt_y_head) and signed lags t0, t1
(docs/model.md, "Per-signal alignment offsets").

A point with offset dt must read the same model output at t - dt: checked against the model
with zero offsets evaluated on separately shifted time grids, against the solve_ivp reference
(which reads each row from its own integrated state) and the nonlinear reference; the exact
sensitivities against central differences; the registry and TOML accept negative lags and the
new names, fitted only on request.
"""

import math

import numpy as np
import pytest

from gprm.errors import GprmInputError
from gprm.params import (ALIGNMENT_OFFSETS, FITTED_DEFAULT, REGISTRY, batch, load_params,
                         paper, save_params)
from gprm.simulate import VoltageTrace, observe, simulate
from gprm.simulate.core import COORDS, OUTPUTS
from gprm.simulate.reference import reference_linear
from sens_fd import compare_with_central_differences

TIMES = np.arange(0.97e-3, 1.2e-3 + 1e-12, 5e-6)
DT = {"dt_x_head": 2.3e-6, "dt_y_base": -1.7e-6, "dt_y_head": 3.9e-6}
DT_NAMES = tuple(DT)
OWN_LAG = {"x_base": 0.0, "x_head": DT["dt_x_head"], "y_base": DT["dt_y_base"],
           "y_head": DT["dt_y_head"]}


def _trace():
    t = np.arange(0.95e-3, 1.2e-3, 4e-6)
    v = 120 * np.exp(-np.clip(t - 1e-3, 0, None) / 9e-6) + 0.5 * np.cos(7e4 * t)
    return VoltageTrace(t, v)


def _peak(y):
    return np.abs(y).max(axis=-1)


@pytest.mark.parametrize("trace", [None, "trace"])
def test_offsets_are_time_shifts_of_each_point(trace):
    tr = _trace() if trace else None
    base = paper().with_values(t0=-6.1e-6, t1=4.6e-6)            # signed lags as after alignment
    shifted = base.with_values(**DT)
    names = OUTPUTS + COORDS
    got = observe(batch([shifted]), TIMES, names, voltage=tr)
    assert got.ok[0]
    for k, name in enumerate(names):
        lag = OWN_LAG.get(name, 0.0)
        if name == "z_bk":
            lag = 0.0                                               # t1 is in both sets
        # the same model without offsets, evaluated on its own shifted grid
        ref = observe(batch([base]), TIMES - lag, (name,), voltage=tr).y[0, 0]
        scale = _peak(ref)
        assert scale > 0
        np.testing.assert_allclose(got.y[0, k], ref, rtol=0, atol=1e-10 * scale, err_msg=name)
    # and the offsets matter: a 2-4 us shift of these steep signals is a large change
    plain = observe(batch([base]), TIMES, OUTPUTS, voltage=tr).y[0]
    for k, name in enumerate(OUTPUTS):
        diff = np.abs(got.y[0, k] - plain[k]).max() / _peak(plain[k])
        if OWN_LAG.get(name, 0.0) != 0.0:
            assert diff > 0.05, (name, diff)
        else:
            assert diff < 1e-12, (name, diff)


def test_negative_t0_is_an_earlier_command():
    # default profile: t0 and t_c enter only as t_c + t0
    a = observe(batch([paper().with_values(t0=-6e-6)]), TIMES, OUTPUTS)
    b = observe(batch([paper().with_values(t0=0.0, t_c=0.994e-3)]), TIMES, OUTPUTS)
    np.testing.assert_allclose(a.y, b.y, rtol=0, atol=1e-12 * np.abs(b.y).max())
    # the record starts moving before t_c = 1 ms
    sim = simulate(paper().with_values(t0=-6e-6), time=np.array([0.9e-3, 0.995e-3, 0.999e-3]))
    assert sim.outputs["x_head"][0, 0] == 0.0
    assert abs(sim.outputs["x_head"][0, 2]) > 0
    assert sim.voltage[0, 2] < sim.voltage[0, 0]


def test_batch_with_different_offsets_per_set():
    sets = [paper().with_values(**DT), paper(), paper().with_values(dt_x_head=-4e-6)]
    got = observe(batch(sets), TIMES, OUTPUTS)
    for b, ps in enumerate(sets):
        one = observe(batch([ps]), TIMES, OUTPUTS)
        np.testing.assert_allclose(got.y[b], one.y[0], rtol=0,
                                   atol=1e-12 * np.abs(one.y).max())


def test_missing_offsets_count_as_zero():
    pb = batch([paper()])
    reduced = {k: v for k, v in pb.items() if k not in DT}
    a = observe(reduced, TIMES, OUTPUTS, sensitivities=("t0",) + DT_NAMES)
    b = observe(pb, TIMES, OUTPUTS, sensitivities=("t0",) + DT_NAMES)
    np.testing.assert_array_equal(a.y, b.y)
    np.testing.assert_array_equal(a.dy, b.dy)


def _fd(ps, sens, names, trace=None, tol=1e-5):
    """Central differences: relative step 1e-4 (absolute 10 ns for lags, which may be 0)."""
    exact, _, err, big = compare_with_central_differences(
        ps, sens, names, TIMES, trace=trace,
        step=lambda n, v: 1e-8 if n in DT or n in ("t0", "t1") else 1e-4 * abs(v))
    for j, n in enumerate(sens):
        assert big[n] > 0, n
        assert err[n] < tol, (n, err[n])
        # an offset acts on its own point only
        if n in DT:
            own = [k for k, o in enumerate(names) if ALIGNMENT_OFFSETS.get(o) == n]
            others = [k for k in range(len(names)) if k not in own]
            assert own and np.all(exact.dy[0, ..., j][others] == 0)
    return exact


@pytest.mark.parametrize("offsets", ["zero", "nonzero"])
@pytest.mark.parametrize("trace", [None, "trace"])
def test_sensitivities_against_finite_differences(offsets, trace):
    ps = paper().with_values(t0=-5.3e-6, t1=-1.1e-6)
    if offsets == "nonzero":
        ps = ps.with_values(**DT)
    sens = ("t0", "t1") + DT_NAMES + ("m2", "k_Ax", "c_Cy", "rho", "d_x_head", "d_y_base")
    names = OUTPUTS + ("eta", "mu4")
    exact = _fd(ps, sens, names, _trace() if trace else None)
    # dy/d dt = dy/d t1 pattern: minus the rate of that row, and d/dt0 of the same row too
    k = names.index("x_head")
    np.testing.assert_allclose(exact.dy[0, k, :, sens.index("dt_x_head")],
                               exact.dy[0, k, :, sens.index("t0")], rtol=1e-12,
                               atol=1e-12 * np.abs(exact.dy[0, k, :, 0]).max())


def test_sensitivities_with_all_23_and_offsets_equal_separate_calls():
    # the fitter's call with the offsets added: the 23 columns are unchanged by asking for more
    ps = paper().with_values(**DT)
    pb = batch([ps, paper()])
    a = observe(pb, TIMES, OUTPUTS, sensitivities=FITTED_DEFAULT + DT_NAMES)
    b = observe(pb, TIMES, OUTPUTS, sensitivities=FITTED_DEFAULT)
    np.testing.assert_array_equal(a.y, b.y)
    np.testing.assert_allclose(a.dy[..., :23], b.dy, rtol=0,
                               atol=1e-12 * np.abs(b.dy).max())


def test_reference_integrator_with_offsets_and_negative_lags():
    ps = paper().with_values(t0=-6.3e-6, t1=-2.2e-6, **DT)
    names = OUTPUTS + ("eta", "theta")
    times = np.arange(0.98e-3, 1.12e-3 + 1e-12, 5e-6)
    ref = reference_linear(ps, times, names=names)
    obs = observe(batch([ps]), times, names)
    peak = np.abs(ref).max(axis=1)
    assert np.all(peak > 0)
    err = np.abs(obs.y[0] - ref).max(axis=1) / peak
    assert np.all(err < 1e-6), dict(zip(names, err))
    # the reference does see the offsets (not just the same code path twice)
    ref0 = reference_linear(ps.with_values(**{n: 0.0 for n in DT}), times, names=names)
    moved = np.abs(ref - ref0).max(axis=1) / peak
    assert np.all(moved[1:4] > 0.05) and moved[0] < 1e-8 and moved[4] < 1e-8


def test_nonlinear_reference_honours_offsets():
    from gprm.simulate.nonlinear import simulate_nonlinear

    ps = paper().with_values(**DT)
    times = np.arange(0.995e-3, 1.04e-3 + 1e-12, 5e-6)
    grid = np.unique(np.concatenate([times - lag for lag in OWN_LAG.values()]))
    nl0 = simulate_nonlinear(ps.with_values(**{n: 0.0 for n in DT}), time=grid)
    nl = simulate_nonlinear(ps, time=times)
    for name, lag in OWN_LAG.items():
        ref = np.interp(times - lag, grid, nl0.outputs[name][0])   # exact: grid holds t - lag
        np.testing.assert_allclose(nl.outputs[name][0], ref, rtol=0,
                                   atol=1e-6 * np.abs(ref).max(), err_msg=name)
        assert np.abs(ref).max() > 0


# ----------------------------------------------------------------------- registry and TOML

def test_registry_signed_lags_and_offsets():
    for n in ("t0", "t1"):
        spec = REGISTRY[n]
        assert spec.lower == -1e-3 and spec.upper == 1e-3
        assert "may be negative" in spec.description
    assert (REGISTRY["t0"].default, REGISTRY["t0"].initial, REGISTRY["t0"].paper_stderr) == \
        (4e-6, 5e-6, 3e-6)
    assert (REGISTRY["t1"].default, REGISTRY["t1"].initial, REGISTRY["t1"].paper_stderr) == \
        (5e-6, 4e-6, 3e-6)
    assert set(ALIGNMENT_OFFSETS.values()) == set(DT)
    for n in DT:
        spec = REGISTRY[n]
        assert spec.group == "alignment" and spec.default == 0.0
        assert spec.initial is None and spec.paper_stderr is None
        assert math.isclose(spec.lower, -50e-6) and math.isclose(spec.upper, 50e-6)
        assert n not in FITTED_DEFAULT
    assert len(FITTED_DEFAULT) == 23 and "t0" in FITTED_DEFAULT and "t1" in FITTED_DEFAULT
    ps = paper().with_values(t0=-6e-6, t1=-1e-6, dt_y_head=-3e-6)
    assert ps["t0"] == -6e-6 and ps["dt_y_head"] == -3e-6
    with pytest.raises(GprmInputError):
        paper().with_values(dt_x_head=60e-6)
    with pytest.raises(GprmInputError):
        paper().with_values(t0=-2e-3)
    fitted = paper().with_fitted(FITTED_DEFAULT + DT_NAMES)
    assert fitted.fitted == FITTED_DEFAULT + DT_NAMES
    assert all(np.isnan(fitted.paper_stderr(DT_NAMES)))
    np.testing.assert_array_equal(fitted.initial_vector(DT_NAMES), 0.0)


def test_toml_negative_t0_and_fitted_offsets(tmp_path):
    f = tmp_path / "p.toml"
    f.write_text('[parameters]\n'
                 't0 = "-6.2 us"\n'
                 't1 = { value = "-1 us", fit = true }\n'
                 'dt_x_head = { value = "1.5 us", fit = true }\n'
                 'dt_y_base = { value = 0, fit = true, lower = "-10 us", upper = "10 us" }\n'
                 'dt_y_head = "-2e-6 s"\n')
    ps = load_params(f)
    assert math.isclose(ps["t0"], -6.2e-6) and math.isclose(ps["t1"], -1e-6)
    assert math.isclose(ps["dt_x_head"], 1.5e-6) and math.isclose(ps["dt_y_head"], -2e-6)
    assert "dt_x_head" in ps.fitted and "dt_y_base" in ps.fitted
    assert "dt_y_head" not in ps.fitted
    assert np.allclose(ps.bounds["dt_y_base"], (-1e-5, 1e-5))
    assert np.allclose(ps.bounds["dt_x_head"], (-50e-6, 50e-6))
    out = tmp_path / "back.toml"
    save_params(ps, out)
    back = load_params(out)
    assert back.fitted == ps.fitted
    for n in ("t0", "t1") + DT_NAMES:
        assert math.isclose(back[n], ps[n], rel_tol=1e-9, abs_tol=1e-18), n
    assert np.allclose(back.bounds["dt_y_base"], ps.bounds["dt_y_base"])
    bad = tmp_path / "bad.toml"
    bad.write_text('[parameters]\ndt_y_head = "80 us"\n')
    with pytest.raises(GprmInputError) as e:
        load_params(bad)
    assert "dt_y_head" in str(e.value)
    bad.write_text('[parameters]\ndt_x_head = "1 mm"\n')
    with pytest.raises(GprmInputError):
        load_params(bad)
