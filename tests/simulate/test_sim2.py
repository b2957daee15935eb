"""benchmarks/sim2.py, the second, independent campaign simulator (validation data).

(a) Its noise-free solve_ivp outputs agree with gprm's exact modal solver (two independent
    implementations of docs/model.md: energies -> numerical Hessians -> LSODA, versus SymPy
    derivation -> generated matrices -> closed-form modal convolutions).
(b) Same seed, byte-identical campaign (through the API and the CLI).
(c) gprm's campaign reader and preprocessing take the campaign without complaint.

Tolerance of (a): sim2 integrates with rtol 1e-9 and absolute tolerances 1e-11 of each
state's peak, so its global error is ~1e-8 of a signal's peak (measured: <= 1e-9 on the
cases below); gprm's solver is exact to ~1e-11 (docs/model.md section 7). We assert 1e-6 of
each signal's peak over the fit window: a 100x margin over the expected integration error,
and still ~3000x below the noise-to-peak ratio (~3e-3 for y_head), so any disagreement in the
model itself (a sign, a missing term, a wrong lag: all >= 1e-3 of the peak) fails.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"
sys.path.insert(0, str(BENCH))
import sim2  # noqa: E402

from gprm.params import FITTED_DEFAULT, paper  # noqa: E402

TOL = 1e-6
WINDOW = np.arange(970, 1201) * 1e-6            # 0.97..1.2 ms at 1 MHz (sub-sample detail)


def _gprm_outputs(values: dict, times, piezo=2, **override):
    from gprm.simulate import simulate

    ps = paper().with_values(**{**values, **override})
    res = simulate(ps, piezo=piezo, time=times)
    return {k: res.outputs[k][0] for k in sim2.MODEL_OUTPUTS}


CASES = {
    "paper": (dict(paper().values), 2, {}),
    "random truth": (sim2.draw_truth(np.random.default_rng(11), 0.1), 2, {}),
    # a jittered, off-nominal retraction (sub-sample shift of the command, V0 and tau_v moved)
    # with non-zero alignment offsets: the lags of every row
    "drive, jitter, offsets": (dict(paper().values, dt_x_head=2.3e-6, dt_y_base=-1.7e-6,
                                    dt_y_head=0.9e-6),
                               2, {"V0": 117.3, "tau_v": 10.6e-6, "shift": 1.37e-6}),
    "piezo 1": (dict(paper().values), 1, {}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_noise_free_outputs_agree_with_gprms_exact_solver(case):
    values, piezo, drive = CASES[case]
    shift = drive.get("shift", 0.0)
    mine = sim2.simulate_signals(values, WINDOW, piezo=piezo, V0=drive.get("V0"),
                                 tau_v=drive.get("tau_v"), shift=shift)
    over = {k: v for k, v in drive.items() if k != "shift"}
    theirs = _gprm_outputs(values, WINDOW, piezo, t_c=values["t_c"] + shift, **over)
    for name in sim2.MODEL_OUTPUTS:
        peak = np.abs(theirs[name]).max()
        assert peak > 1e-8, name                     # the signal moves in the window
        err = np.abs(mine[name] - theirs[name]).max() / peak
        assert err < TOL, f"{case}: {name} differs by {err:.2e} of its peak"


def test_campaign_files_hold_the_model_for_each_runs_drive_and_jitter(tmp_path):
    """A campaign with everything but jitter and drive off (noise 1e-16 m) read back from its
    CSV files: every actuated run of the five model positions equals gprm's solver for that
    run's truth, V0, tau_v and command time t_c + jitter (batched, chunked integration and
    the file format included)."""
    from gprm.params import batch
    from gprm.simulate import simulate

    imp = sim2.Imperfections(gain=0.0, resonance=0.0, noise=0.0, noise_floor=1e-16)
    truth = sim2.make_campaign(tmp_path / "c", seed=9, imperfections=imp)
    real = truth["realisation"]
    values = dict(paper().values, **truth["parameters"])
    sets, runs, names = [], [], []
    for name in sim2.MODEL_OUTPUTS:
        i = sim2.POSITIONS.index(name)
        for r in range(10):
            run = {"V0": values["V0"] * real["V0_factor"][i][r],
                   "tau_v": values["tau_v"] * real["tau_v_factor"][i][r],
                   "t_c": values["t_c"] + real["trigger_jitter_s"][i][r]}
            sets.append(paper().with_values(**{**values, **run}))
            t, y = np.loadtxt(tmp_path / "c" / name / f"run{r + 1:02d}.csv", delimiter=",",
                              skiprows=1, unpack=True)
            runs.append(y * 1e-6)
            names.append(name)
    assert np.ptp(real["trigger_jitter_s"]) > 1e-6 and np.ptp(real["tau_v_factor"]) > 0.02
    ref = simulate(batch(sets), time=t).outputs
    for b, (name, y) in enumerate(zip(names, runs)):
        g = ref[name][b]
        err = np.abs(y - g).max() / np.abs(g).max()
        assert err < TOL, f"{name} run {b % 10 + 1}: differs by {err:.2e} of its peak"


def test_static_tip_extension_from_own_matrices():
    """docs/model.md section 6: K0^-1 F 120 V gives the tip 15.45 um, mu3 15.52 um (Piezo 2)
    and -0.076 um (Piezo 1); M0, K0 symmetric, mechanical K0 positive definite."""
    p = dict(paper().values)
    for piezo, mu3 in ((2, 15.52e-6), (1, -0.076e-6)):
        M, C, K, F = sim2.linear_matrices(p, piezo)
        x = np.linalg.solve(K, 120.0 * F)
        assert x[sim2.COORDS.index("mu4")] == pytest.approx(15.45e-6, abs=0.01e-6)
        assert x[sim2.COORDS.index("mu3")] == pytest.approx(mu3, abs=0.01e-6)
        for A in (M, C, K):
            assert np.allclose(A, A.T, rtol=0, atol=1e-12 * np.abs(A).max())
        assert np.linalg.eigvalsh(K[:8, :8]).min() > 0


def test_independent_of_gprms_model_code():
    code = ("import sys; sys.path.insert(0, %r); import numpy as np; import sim2; "
            "sim2.simulate_signals(dict(sim2.paper().values), np.arange(1000, 1010) * 1e-6); "
            "print(sorted(m for m in sys.modules if m.startswith('gprm')))" % str(BENCH))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    for banned in ("gprm.model", "gprm.simulate", "gprm.campaign", "gprm.fit"):
        assert banned not in out, out


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    d = tmp_path_factory.mktemp("sim2") / "c"
    truth = sim2.make_campaign(d, seed=5)
    return d, truth


def _files(root: Path) -> dict:
    return {str(f.relative_to(root)): f.read_bytes() for f in sorted(root.rglob("*"))
            if f.is_file()}


def test_same_seed_gives_byte_identical_files(campaign, tmp_path):
    d, _ = campaign
    d2 = tmp_path / "again"
    assert sim2.main(["--seed", "5", "--out", str(d2)]) == 0      # the CLI, default preset
    a, b = _files(d), _files(d2)
    assert len(a) == 1 + 1 + 10 * 15 + 10                        # manifest, truth, runs, volts
    assert a.keys() == b.keys()
    assert all(a[k] == b[k] for k in a)


def test_campaign_reads_and_preprocesses(campaign):
    from gprm.campaign.api import run_preprocess
    from gprm.campaign.data import POSITIONS
    from gprm.campaign.files import read_campaign_dir, read_tables

    d, truth = campaign
    ds = read_campaign_dir(d)
    assert tuple(ds["position"].values) == POSITIONS == sim2.POSITIONS
    assert ds["displacement"].shape == (10, 10, 301)
    assert ds["noise"].shape == (10, 5, 301)
    assert ds["voltage"].shape == (10, 1501)
    assert float(ds.attrs["sample_rate"]) == pytest.approx(200e3)
    # values in um on file, SI after reading: z_bk peaks near its noiseless 2-3 um
    zbk = np.abs(ds["displacement"].sel(position="z_bk").values).max()
    assert 1e-6 < zbk < 4e-6
    noise = ds["noise"].values
    resid = noise - noise.mean(axis=-1, keepdims=True)
    assert 3e-10 < resid.std() < 8e-10

    means = run_preprocess(d)
    for name in sim2.MODEL_OUTPUTS:
        m = means["mean"].sel(signal=name).values
        assert np.all(np.isfinite(m)) and np.abs(m).max() > 20 * float(means["noise_std"]
                                                                        .sel(signal=name))
    _, dropped, _ = read_tables(means)
    assert all(row["supported"] for row in dropped.values()), dropped

    on_disk = json.loads((d / "truth.json").read_text())
    assert on_disk == truth
    assert on_disk["generator"] == "sim2" and on_disk["seed"] == 5
    assert set(on_disk["parameters"]) == set(FITTED_DEFAULT)
    for name, v in on_disk["parameters"].items():
        ratio = v / paper()[name]
        assert (ratio == 1.0) if name in ("t0", "t1") else (0.9 <= ratio <= 1.1), name


def test_white_preset_is_white_noise_only(monkeypatch):
    imp = sim2.PRESETS["white"]
    assert imp == sim2.Imperfections(jitter=0, drive=0, gain=0, resonance=0, noise=0,
                                     nonlinear=0)
    rng = np.random.default_rng(0)
    h = sim2._pink_filter(sim2._PINK_LEN)
    x = np.stack([sim2._noise(rng, 301, imp, h) for _ in range(400)])
    assert x.std() == pytest.approx(5e-10, rel=0.02)
    assert abs(x.mean()) < 1e-11                                  # no offsets
    # default strength: the white + pink part has std 5e-10 m (offsets and drift off here)
    monkeypatch.setattr(sim2, "OFFSET_SD", 0.0)
    monkeypatch.setattr(sim2, "DRIFT_SD", 0.0)
    y = np.stack([sim2._noise(rng, 301, sim2.Imperfections(), h) for _ in range(400)])
    assert np.sqrt(np.mean(y ** 2)) == pytest.approx(5e-10, rel=0.1)


def test_the_sources_that_switch_on_one_sim2_imperfection_at_a_time():
    """benchmarks/sources.py's sim2-<name> sources (each of sim2's imperfections alone, the
    others off, its white floor kept) and the named presets: each source gets the strengths
    its name says."""
    import sources

    fields = ("jitter", "drive", "gain", "resonance", "noise")
    assert sources.SIM2_ALONE == tuple(f"sim2-{f}" for f in fields)
    for f in fields:
        imp = sources.sim2_imperfections(f"sim2-{f}")
        assert {g: getattr(imp, g) for g in fields} == {g: float(g == f) for g in fields}
        assert imp.nonlinear == 0.0 and imp.noise_floor == sim2.Imperfections().noise_floor
    assert sources.sim2_imperfections("sim2") == sim2.PRESETS["default"]
    assert sources.sim2_imperfections("sim2-white") == sim2.PRESETS["white"]
    twice = sources.sim2_imperfections("probe-sim2-2x")
    assert all(getattr(twice, f) == 2.0 for f in fields)
    with pytest.raises(ValueError, match="not a sim2 source"):
        sources.sim2_imperfections("generator")
