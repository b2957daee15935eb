"""What-ifs (Sec. 4.2): overshoot definition, scenario transforms, the paper's ratios."""

import dataclasses
import json
from dataclasses import replace

import numpy as np
import pytest

from gprm.errors import GprmInputError
from gprm.simulate.kinematics import body_motion, named_points, point_motion
from gprm.report.figures import fig_sweep
from gprm.predict.scenarios import ECCENTRICITIES, Scenario, apply_scenario
from gprm.predict.whatif import (PAPER_RATIOS, RatioSensitivity, overshoot, ratio_sensitivity,
                                 sweep, whatif, window_times)


@pytest.fixture(scope="module")
def table(fm):
    return whatif(fm, samples=30, seed=4).to_json()


def test_overshoot_definition():
    t = np.linspace(0, 1, 1001)
    d = np.stack([0.1 + 2 * np.sin(6 * t) * t, 0.1 - 3 * t ** 2, np.full_like(t, 0.1)])
    os_ = overshoot(d)
    np.testing.assert_allclose(os_[1], 3.0)
    assert os_[2] == 0.0
    assert np.isclose(os_[0], np.max(np.abs(2 * np.sin(6 * t) * t)))


def test_apply_scenario(fm):
    sc = Scenario("s", 1, 0.1, {"h2": 0.035, "m2": 0.013})
    fs = apply_scenario(fm, sc)
    for n in ECCENTRICITIES:
        assert np.isclose(fs.params[n], 0.1 * fm.params[n])
    assert fs.params["h2"] == 0.035 and fs.params["m2"] == 0.013
    i, j = fm.names.index("v2"), fm.names.index("m2")
    assert np.isclose(fs.covariance[i, i], 0.01 * fm.covariance[i, i])
    assert fs.covariance[j, j] == 0.0
    k = fm.names.index("k_Ax")
    assert fs.covariance[k, k] == fm.covariance[k, k]


@pytest.mark.parametrize("f", [0.0, -1.0, float("nan")])
def test_bad_scale(fm, f):
    with pytest.raises(GprmInputError, match="scale_eccentricity"):
        apply_scenario(fm, Scenario("bad", 2, f))


def test_bad_override_and_piezo(fm):
    with pytest.raises(GprmInputError):
        apply_scenario(fm, Scenario("bad", 2, 1.0, {"nope": 1.0}))
    with pytest.raises(GprmInputError):
        apply_scenario(fm, Scenario("bad", 3))
    with pytest.raises(GprmInputError):
        apply_scenario(fm, Scenario("bad", 2, 1.0, {"m2": -1.0}))


def test_ratios_against_independent_simulation(fm, table):
    """Piezo 2 / Piezo 1 overshoot ratios recomputed directly from the kinematics API."""
    t = window_times()
    os_ = {}
    for pz in (1, 2):
        m = body_motion(fm, t, piezo=pz)
        pts = named_points(fm)
        os_[pz] = {p: np.max(np.abs(point_motion(m, pts[p], relative=True)[0][0]), axis=-1)
                   for p in ("M_xz", "M_yz")}
    r = table["ratios"][1]
    assert r["name"] == "piezo1"
    assert np.isclose(r["headline"]["x"], os_[2]["M_xz"][0] / os_[1]["M_xz"][0], rtol=1e-12)
    assert np.isclose(r["headline"]["y"], os_[2]["M_yz"][1] / os_[1]["M_yz"][1], rtol=1e-12)
    assert np.isclose(r["headline"]["z"], os_[2]["M_xz"][2] / os_[1]["M_xz"][2], rtol=1e-12)


def test_paper_ratios_reported(table):
    """Piezo 1 shrinks every overshoot; eccentricities / 10 shrink the lateral ones ten-fold
    more and leave the axial one as with Piezo 1 (the paper's statements). With the docs/spec.md
    geometry the x and z ratios come within 10 % of the paper's 4.0 and 3.8; y does not (see
    docs/prediction.md)."""
    p1, e10 = table["ratios"][1]["headline"], table["ratios"][2]["headline"]
    assert all(v > 1 for v in p1.values())
    for a in ("x", "y"):
        assert np.isclose(e10[a], 10 * p1[a], rtol=0.03)
    assert np.isclose(e10["z"], p1["z"], rtol=0.02)
    assert abs(p1["x"] / PAPER_RATIOS["piezo1"]["x"] - 1) < 0.1
    assert abs(p1["z"] / PAPER_RATIOS["piezo1"]["z"] - 1) < 0.1
    assert table["ratios"][1]["paper"] == PAPER_RATIOS["piezo1"]
    # sampled ranges bracket the best-fit value
    lo, hi = table["ratios"][1]["ratio_p2_5"]["M_xz"]["x"], table["ratios"][1]["ratio_p97_5"][
        "M_xz"]["x"]
    assert lo <= p1["x"] <= hi


def test_table_is_json(table):

    s = json.dumps(table, allow_nan=False)
    assert "definition" in json.loads(s)
    assert [x["name"] for x in table["scenarios"]] == ["piezo2", "piezo1", "piezo1_ecc_div10"]


def test_sweep_and_plot(fm, table, tmp_path):
    res = sweep(fm, "h2", [0.025, fm.params["h2"], 0.035])
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.parameter = "m2"
    sw = json.loads(json.dumps(res.to_json(), allow_nan=False))
    ds = res.to_xarray()
    np.testing.assert_array_equal(ds["overshoot"].sel(point=sw["points"][0]).values[:, 0],
                                  sw["overshoot"][sw["points"][0]][sw["axes"][0]])
    base = table["scenarios"][0]["overshoot"]
    for p in sw["points"]:
        for a in sw["axes"]:
            assert np.isclose(sw["overshoot"][p][a][1], base[p][a], rtol=1e-12)
    assert sw["display_values"][1] == pytest.approx(30.0)
    fig = fig_sweep(res)
    drawn = fig.axes[0].lines[0].get_ydata()      # first axis, first point, in um
    np.testing.assert_allclose(drawn, np.asarray(sw["overshoot"][sw["points"][0]][
        sw["axes"][0]]) * 1e6)
    fig.savefig(tmp_path / "sweep.png")
    assert (tmp_path / "sweep.png").stat().st_size > 1000
    with pytest.raises(GprmInputError):
        sweep(fm, "m2", [0.01, -0.01])


def test_scenario_of_a_changed_model(fm):
    """A model with a different geometry gives different overshoots (the plumbing uses it)."""
    a = whatif(fm, samples=0).scenarios[0]["overshoot"]["M_yz"]["y"]
    f2 = replace(fm, params=fm.params.with_values(h2=0.02))
    b = whatif(f2, samples=0).scenarios[0]["overshoot"]["M_yz"]["y"]
    assert a != b


def test_ratio_sensitivity_is_a_frozen_table(fm):
    """Nominal headlines equal whatif's; each changed geometry value gives its own table."""
    rs = ratio_sensitivity(fm, ("h2",), rel=0.25)
    assert isinstance(rs, RatioSensitivity)
    nominal = whatif(fm, samples=0)
    assert rs.nominal == {r["name"]: r["headline"] for r in nominal.ratios[1:]}
    doc = json.loads(json.dumps(rs.to_json(), allow_nan=False))
    assert set(doc) == {"rel_change", "nominal", "h2"} and set(doc["h2"]) == {"x0.75", "x1.25"}
    ds = rs.to_xarray()
    assert list(ds["case"].values) == ["nominal", "h2 x0.75", "h2 x1.25"]
    s0, a0 = str(ds["scenario"].values[0]), str(ds["axis"].values[0])
    assert float(ds["ratio"].sel(case="h2 x1.25", scenario=s0, axis=a0)) == \
        doc["h2"]["x1.25"][s0][a0]
    assert doc["h2"]["x0.75"] != doc["nominal"]          # h2 matters (docs/prediction.md)
