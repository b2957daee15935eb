"""Synthetic telemetry with known impact times (truth: the one-contact 3D corner impact with
friction of issue 14, ``truth_model="3d"``, drawn within the model's uncertainty; the
scenario truths of issue 23 are tested in test_scenario.py): the estimated times are found on all six axes and
recover the truth within their error bars; the joint estimate's interval covers the truth;
the paper's planar analysis shows its systematic error on the same data; the CLI end to
end."""

import json

import numpy as np
import pytest

from gprm.fit.files import paper_model
from gprm.flight.analysis import AnalysisOptions, analyze
from gprm.flight.synth import SynthOptions, synth_telemetry
from gprm.flight.files import read_truth, telemetry_from_dataset
from gprm.flight.telemetry import AXES

SCORED = ("vx", "vz_xz", "wy", "vy", "vz_yz", "wx")


@pytest.fixture(scope="module")
def run():
    m = paper_model()
    ds = synth_telemetry(m, SynthOptions(n_releases=40, seed=5, truth_model="3d"))
    tel = telemetry_from_dataset(ds, source="synthetic")
    res = analyze(m, tel, AnalysisOptions(seed=1))
    return ds, tel, res.to_json(), res.curves


def test_truth_recovered_at_expected_rate(run):
    ds, tel, doc, _ = run
    tt = tel.truth_impact_time
    z = []
    for i, r in enumerate(doc["releases"]):
        for a in SCORED:
            it = r["impact_time"][a]
            if it["value"] is not None and it["stderr"] is not None:
                z.append((it["value"] - tt[i]) / it["stderr"])
    z = np.abs(np.array(z))
    n = z.size
    assert n >= 0.95 * 40 * len(SCORED), n      # issue 14: >= 95 % of the times found
    f1, f2 = np.mean(z < 1), np.mean(z < 2)
    # the error bar is the rms of the model draws' crossings about the estimate; the six
    # axes of a release share one truth draw, so the effective sample is ~40 releases.
    assert 0.46 < f1 < 0.97, f1
    assert f2 >= 0.90, f2


def test_joint_estimate_covers_truth(run):
    _, tel, doc, _ = run
    tt = tel.truth_impact_time
    inside = [r["joint"]["ci95"][0] <= tt[i] <= r["joint"]["ci95"][1]
              for i, r in enumerate(doc["releases"]) if r["joint"]["value"] is not None]
    assert len(inside) >= 38
    # 95 % interval, 40 releases: P(coverage < 0.8) < 0.5 % for a calibrated interval, while
    # an interval of half the width (±1 sigma for 95 %) covers ~68 % (seeds 0-9 of 40
    # releases: 35-40, 373 of 400 in all; this seed, 5, is one of the two lowest)
    assert 0.8 <= np.mean(inside) <= 1.0, np.mean(inside)
    s = doc["truth"]["summary"]
    assert s["joint_truth_in_ci95"] == sum(inside)
    # both v_z axes observe the one v_z with the one curve: used once in the joint fit
    r0 = doc["releases"][0]
    assert "vz_yz" not in r0["joint"]["axes"] and "vz_xz" in r0["joint"]["axes"]
    assert abs(sum(r0["joint"]["weights"]) - 1) < 1e-12
    assert min(r0["joint"]["weights"]) >= 0


def test_planar_analysis_systematic_error_is_measured(run):
    """The paper's two-plane planar analysis on the same 3D truth: it finds crossings, but
    they are biased (the one-contact impulse is smaller than either plane's), so far fewer lie
    within 2 sigma (seed 5: 70 % against 92 % for the 3D analysis)."""
    m = paper_model()
    ds, tel, doc3, _ = run
    docp = analyze(m, tel, AnalysisOptions(seed=1, impact_model="planar")).to_json()
    s3, sp = doc3["truth"]["summary"], docp["truth"]["summary"]
    assert docp["impact_model"] == "planar" and doc3["impact_model"] == "3d"
    assert sp["within_2sigma"] / sp["found"] < s3["within_2sigma"] / s3["found"] - 0.1
    assert sp["within_2sigma"] / sp["found"] < 0.85


def test_missing_crossings_reported_not_dropped(run):
    _, tel, doc, _ = run
    n_null = sum(1 for r in doc["releases"] for a in r["impact_time"].values()
                 if a["value"] is None)
    assert n_null == len(doc["missing"])
    for m in doc["missing"]:
        assert m["reason"]
    # the Tukey counts are the non-null ones
    counts = doc["tukey"]["counts"]
    for a, c in counts.items():
        assert c == sum(1 for r in doc["releases"] if r["impact_time"][a]["value"] is not None)


def test_release_velocities_match_truth(run):
    ds, tel, doc, _ = run
    truth = read_truth(ds)["tm_velocity"]
    comp = {"vx": "vx", "vy": "vy", "wy": "wy", "wx": "wx", "vz_xz": "vz", "vz_yz": "vz"}
    zs = []
    for i, r in enumerate(doc["releases"]):
        for a, c in comp.items():
            v = r["velocity"][a]
            zs.append((v["value"] - truth[c][i]) / v["stderr"])
    zs = np.abs(zs)
    assert np.mean(zs < 2) > 0.85 and zs.max() < 6


def test_cli_end_to_end(tmp_path):
    from typer.testing import CliRunner
    from gprm.cli import app

    tel = tmp_path / "telemetry.nc"
    out = tmp_path / "impact.json"
    r = CliRunner().invoke(app, ["synth", "telemetry", "paper", "--releases", "11", "--seed",
                                 "2", "--out", str(tel)])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(app, ["impact", "paper", str(tel), "--out", str(out),
                                 "--samples", "30", "--alpha", "0.01", "--scenario-draws", "0"])
    assert r.exit_code == 0, r.output
    assert "truth (synthetic):" in r.output and "3d impact model" in r.output
    doc = json.loads(out.read_text())
    assert len(doc["releases"]) == 11
    assert doc["impact_model"] == "3d" and doc["joint"]["n"] >= 1
    assert all("ci95" in rel["joint"] for rel in doc["releases"])
    assert set(doc["releases"][0]["velocity"]) == {"vx", "vz_xz", "wy", "vy", "vz_yz", "wx"}
    tk = doc["tukey"]
    assert tk["alpha"] == 0.01 and tk["k"] == 6 and len(tk["pairs"]) == 15
    assert tk["df"] == sum(tk["counts"].values()) - 6
    side = tmp_path / doc["curves"]["sidecar"]
    import xarray as xr
    with xr.open_dataset(side) as c:             # one unit per variable (CF)
        assert c["velocity_nominal"].dims == ("velocity_axis", "time")
        assert c["velocity_nominal"].attrs["units"] == "m s-1"
        assert c["angular_velocity_nominal"].attrs["units"] == "rad s-1"
        assert list(c["velocity_axis"].values) == ["vx", "vz_xz", "vy", "vz_yz"]
        assert list(c["angular_axis"].values) == ["wy", "wx"]
    from gprm.flight.files import read_impact_curves

    c = read_impact_curves(side)                  # the reader gives the six axes together
    assert c["nominal"].dims == ("axis", "time")
    assert list(c["axis"].values) == ["vx", "vz_xz", "wy", "vy", "vz_yz", "wx"]
    with xr.open_dataset(side) as raw:
        np.testing.assert_array_equal(c["nominal"].sel(axis="wx").values,
                                      raw["angular_velocity_nominal"].sel(angular_axis="wx"))
    # same seed -> same file content
    tel2 = tmp_path / "t2.nc"
    CliRunner().invoke(app, ["synth", "telemetry", "paper", "--releases", "11", "--seed", "2",
                             "--out", str(tel2)])
    with xr.open_dataset(tel) as a, xr.open_dataset(tel2) as b:
        np.testing.assert_array_equal(a["x"].values, b["x"].values)


class _BestFitOnly:
    """A fitted model without usable uncertainty, as ``gprm fit`` may write it (issue 12's
    contract): ``has_uncertainty`` False and ``sample`` the best fit repeated."""

    def __init__(self, fm):
        self._fm = fm
        self.params, self.piezo, self.source = fm.params, fm.piezo, "fit-without-covariance"
        self.has_uncertainty = False

    def sample(self, n, seed=0):
        from gprm.params import batch
        return {k: np.repeat(v, n) for k, v in batch([self.params]).items()}


def test_chain_runs_on_a_fit_without_uncertainty():
    m = _BestFitOnly(paper_model())
    ds = synth_telemetry(m, SynthOptions(n_releases=6, seed=3, truth_model="3d"))
    tel = telemetry_from_dataset(ds, source="synthetic")
    res = analyze(m, tel, AnalysisOptions(n_samples=60, n_times=301))
    doc, curves = res.to_json(), res.curves
    assert "best fit only" in doc["model_uncertainty"]
    # no fit spread (round-off of identical batched runs only)
    assert np.nanmax(curves.sigma_fit["vx"]) < 1e-9 * np.nanmax(np.abs(curves.nominal["vx"]))
    s = doc["truth"]["summary"]
    assert s["found"] >= 0.9 * s["impact_times"]
    for r in doc["releases"]:                                        # geometry still spreads
        assert all(v["stderr"] > 0 for v in r["impact_time"].values() if v["value"])
    json.dumps(doc)


def test_synthetic_truth_is_the_3d_impact():
    """The issue-14 truth (``truth_model="3d"``) is the one-contact 3D impact: one v_z (both
    v_z axes hold it, the
    TM's vz equals it), a spin about z from the off-axis impulse, and the truth velocities are
    the model's at the true impact time for the drawn parameters (checked here without spread:
    the best fit and the nominal geometry)."""
    from gprm.flight.predicted import tm_velocity_vs_time
    from gprm.params import batch
    from gprm.simulate.kinematics import body_motion

    m = paper_model()
    ds = synth_telemetry(m, SynthOptions(n_releases=5, seed=8, truth_spread=False,
                                         truth_model="3d"))
    truth = read_truth(ds)
    assert truth["truth_model"] == "3d" and truth["z_from"] is None
    tv = telemetry_from_dataset(ds).truth_velocity
    ax = list(AXES)
    np.testing.assert_array_equal(tv[:, ax.index("vz_xz")], tv[:, ax.index("vz_yz")])
    np.testing.assert_array_equal(truth["tm_velocity"]["vz"], tv[:, ax.index("vz_xz")])
    assert np.all(np.abs(truth["tm_velocity"]["wz"]) > 0)
    t = ds["truth_impact_time"].values
    ref = tm_velocity_vs_time(body_motion(batch([m.params]), np.sort(t), piezo=m.piezo))
    o = np.argsort(t)
    for a in ("vx", "vy", "vz_xz", "wx", "wy"):
        np.testing.assert_allclose(tv[o, ax.index(a)], ref[a][0], rtol=1e-9)
    planar = synth_telemetry(m, SynthOptions(n_releases=5, seed=8, truth_spread=False,
                                             truth_model="planar"))
    tp = read_truth(planar)["tm_velocity"]
    pv = telemetry_from_dataset(planar).truth_velocity
    np.testing.assert_allclose(tp["vz"], pv[:, ax.index("vz_xz")] + pv[:, ax.index("vz_yz")])
