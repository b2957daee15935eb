"""Parameters: registry contents against the paper's tables, TOML round trip, pint units, bare
numbers in SI, fit flags and bounds, and bad input (library and `gprm params`)."""

import math
import warnings

import numpy as np
import pytest
from typer.testing import CliRunner

from gprm.cli import app
from gprm.errors import GprmInputError
from gprm.params import (FITTED_DEFAULT, REGISTRY, batch, batch_from_vectors, load_params,
                         paper, params_to_toml, save_params, to_si)

# The paper's Table 3 (best fit, initial, unit) and Table 2 constants, typed in independently.
TABLE3 = {
    "v2": (2.7, 2.8, 1e-3), "g2": (-0.4, -0.4, 1e-3), "gamma": (-7, 5, 1e-3),
    "rho": (37, 37, 1e-3), "k_lr": (164e4, 166e4, 1), "k_Ax": (1104e5, 1123e5, 1),
    "k_Bx": (223e3, 232e3, 1), "c_Ax": (1.07, 0.099, 1), "c_Bx": (21.6, 23, 1),
    "k_Cy": (7e6, 6e6, 1), "k_Dy": (50e5, 54e5, 1), "c_Cy": (1.50, 1.57, 1),
    "c_Dy": (1.61, 1.72, 1), "m1": (0.4, 0.4, 1e-3), "m2": (12.4, 12.7, 1e-3),
    "m3": (1.7, 1.9, 1e-3), "m4": (0.5, 0.3, 1e-3), "d1": (2, 2, 1e-3), "d2": (40, 45, 1e-3),
    "b1": (42, 39, 1e-3), "b2": (4, 4, 1e-3), "t0": (4e-6, 5e-6, 1), "t1": (5e-6, 4e-6, 1),
}
TABLE2 = {"h3": 0.0421, "h4": 0.0192, "J2": 2.7e-6, "k_Az": 2.1e6, "k3": 2.0e7, "k4": 9.8e4,
          "c1": 1.3, "c3": 1.4, "T_em": 2.6, "C_a": 5.0e-7, "R": 19.06}
ASSUMED = {"h2": 0.030, "d_x_base": 0.025, "d_y_base": 0.025, "d_x_head": 0.058,
           "d_y_head": 0.058, "dist_x": 0.004, "dist_y": 0.004, "dist_z": 0.029, "V0": 120.0,
           "t_c": 1.0e-3, "tau_v": 10e-6}


def test_paper_set_matches_the_papers_tables():
    ps = paper()
    assert ps.fitted == tuple(TABLE3) == FITTED_DEFAULT
    for n, (best, init, scale) in TABLE3.items():
        assert math.isclose(ps[n], best * scale, rel_tol=1e-12), n
        assert math.isclose(REGISTRY[n].initial, init * scale, rel_tol=1e-12), n
        assert REGISTRY[n].paper_stderr > 0
    for n, v in {**TABLE2, **ASSUMED}.items():
        assert math.isclose(ps[n], v, rel_tol=1e-12), n
    assert math.isclose(REGISTRY["m2"].paper_stderr, 0.9e-3)


def test_toml_round_trip_with_fit_flags_and_bounds(tmp_path):
    p = tmp_path / "in.toml"
    p.write_text('[parameters]\nv2 = "2.9 mm"\nk_Ax = 1.2e8\n'
                 'm2 = { value = "12.1 g", fit = true, lower = "5 g", upper = "20 g" }\n'
                 'h2 = { value = "3.1 cm", fit = true }\n'
                 't1 = { value = "6 us", fit = false }\n', encoding="utf-8")
    ps = load_params(p)
    assert math.isclose(ps["v2"], 2.9e-3) and ps["k_Ax"] == 1.2e8          # pint; bare SI
    assert math.isclose(ps["m2"], 12.1e-3) and math.isclose(ps["h2"], 0.031)
    assert math.isclose(ps["t1"], 6e-6)
    assert "h2" in ps.fitted and "t1" not in ps.fitted and "m2" in ps.fitted
    assert np.allclose(ps.bounds["m2"], (5e-3, 20e-3))
    assert ps["k3"] == paper()["k3"]                                       # rest from paper
    out = tmp_path / "out.toml"
    save_params(ps, out)
    back = load_params(out)
    assert back.fitted == ps.fitted
    for n in REGISTRY:
        assert math.isclose(back[n], ps[n], rel_tol=1e-9, abs_tol=0), n
    for n in ps.fitted:
        assert np.allclose(back.bounds[n], ps.bounds[n], rtol=1e-9)
    # the default set round-trips through text too
    q = tmp_path / "paper.toml"
    q.write_text(params_to_toml(paper()), encoding="utf-8")
    assert all(math.isclose(load_params(q)[n], paper()[n], rel_tol=1e-9) for n in REGISTRY)


@pytest.mark.parametrize("text, name, si", [
    ("2.7 mm", "v2", 2.7e-3), ("-7 mrad", "gamma", -7e-3), ("0.4 g", "m1", 4e-4),
    ("2.7e-6 kg*m^2", "J2", 2.7e-6), ("10 us", "tau_v", 1e-5), ("0.5 uF", "C_a", 5e-7),
    ("2.6 C/m", "T_em", 2.6), ("1.5 N*s/m", "c_Cy", 1.5), ("45 deg", "indent_angle", math.pi / 4),
    (1.2e8, "k_Ax", 1.2e8), ("19.06 ohm", "R", 19.06), ("1.64 kN/mm", "k_lr", 1.64e6),
])
def test_units(text, name, si):
    assert math.isclose(to_si(text, name), si, rel_tol=1e-12)


@pytest.mark.parametrize("body, field", [
    ('m9 = "1 g"', "m9"),
    ('m2 = "3 mm"', "m2"),
    ('k_Ax = "5 N"', "k_Ax"),
    ('m2 = "-12 g"', "m2"),
    ("k_Bx = -2e5", "k_Bx"),
    ("c_Cy = -1.5", "c_Cy"),
    ('C_a = "-0.5 uF"', "C_a"),
    ('R = "0 ohm"', "R"),
    ('m2 = { value = "12 g", lower = "20 g", upper = "5 g" }', "m2"),
    ('m2 = { fit = true }', "m2"),
    ('m2 = { value = "12 g", fit = "yes" }', "m2"),
    ('m2 = "twelve grams"', "m2"),
    ('tau_v = { value = "10 us", fit = true }', "tau_v"),   # no exact sensitivity
])
def test_bad_values_name_file_and_field(tmp_path, body, field):
    p = tmp_path / "bad.toml"
    p.write_text("[parameters]\n" + body + "\n", encoding="utf-8")
    with pytest.raises(GprmInputError) as exc:
        load_params(p)
    assert exc.value.field == field and exc.value.source == str(p)
    out = tmp_path / "resolved.toml"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = CliRunner().invoke(app, ["params", "--params", str(p), "--out", str(out)])
    assert res.exit_code != 0
    line = res.stderr.strip()
    assert "\n" not in line and str(p) in line and field in line
    assert not out.exists()


def test_params_command_prints_the_table_and_writes_toml(tmp_path):
    out = tmp_path / "resolved.toml"
    res = CliRunner().invoke(app, ["params", "--out", str(out)])
    assert res.exit_code == 0
    assert "k_Ax" in res.stdout and "N/m" in res.stdout and "fitted" in res.stdout
    assert math.isclose(load_params(out)["k_Ax"], 1104e5)


def test_batches():
    ps = paper()
    b = batch([ps, ps.with_values(m2=0.013)])
    assert b["m2"].shape == (2,) and b["m2"][1] == 0.013 and b["k3"][0] == ps["k3"]
    X = np.array([ps.vector(), ps.vector() * 1.1])
    bb = batch_from_vectors(ps, ps.fitted, X)
    assert np.allclose(bb["d2"], [0.040, 0.044]) and np.all(bb["h2"] == ps["h2"])
    with pytest.raises(GprmInputError):
        ps.with_values(m2=-1.0)


def test_a_parameter_added_to_the_fitted_set_keeps_its_start_as_initial_value():
    """Issue 22: ``gprm show`` gave each alignment offset an initial value equal to its fit.
    A parameter the paper gives no initial value for starts where it was when it joined the
    fitted set; new values (a fit's best) do not move that, and it survives pickling (the
    sets travel to Dask workers)."""
    import pickle

    dt = ("dt_x_head", "dt_y_base", "dt_y_head")
    fitted = paper().with_fitted(FITTED_DEFAULT + dt + ("h2",))
    best = fitted.with_values(dt_x_head=4.8e-6, dt_y_base=1.8e-6, dt_y_head=-2.8e-6, h2=0.032,
                              v2=2.75e-3)
    np.testing.assert_array_equal(best.initial_vector(dt), 0.0)
    assert best.initial_vector(("h2",))[0] == pytest.approx(0.030)
    assert best.initial_vector(("v2",))[0] == pytest.approx(2.8e-3)       # the paper's
    assert pickle.loads(pickle.dumps(best)).initial_vector(dt + ("h2",)).tolist() == \
        best.initial_vector(dt + ("h2",)).tolist()
    # dropped from the fitted set and added again: it starts from where it is then
    again = best.with_fitted(FITTED_DEFAULT).with_fitted(FITTED_DEFAULT + ("h2",))
    assert again.initial_vector(("h2",))[0] == pytest.approx(0.032)
