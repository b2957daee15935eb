"""gprm.design (issue 25): the Fisher information against independent computations, the
channel geometry against the model's own outputs, the selection, the files and the CLI."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from gprm.design.config import (MODEL_CHANNELS, Block, Channel, default_candidates,
                                read_design_config)
from gprm.design.core import _calibrate, _posterior, run_design
from gprm.design.information import (NoiseModel, block_information, block_signals,
                                     estimate_noise)
from gprm.errors import GprmInputError
from gprm.fit.api import FitOptions
from gprm.fit.prior import default_prior
from gprm.params import batch_from_vectors, paper
from gprm.simulate import observe


@pytest.fixture(scope="module")
def setup():
    ps = FitOptions().parameters(paper())
    names = ps.fitted
    prior = default_prior(ps, names)
    x = ps.vector(names)
    return ps, names, prior, x


FIVE = tuple(Channel(n) for n in MODEL_CHANNELS)
WHITE = NoiseModel(white=5e-10, variability=0.0)


def _fd_jacobian(ps, names, prior, x, fun, h=1e-5):
    """Central differences in u (step h times the prior's sd) of fun(pb) -> (B, N)."""
    P = len(names)
    X = np.repeat(x[None], 2 * P + 1, 0)
    step = h * prior.sd
    for j in range(P):
        for s, row in ((1, 1 + 2 * j), (-1, 2 + 2 * j)):
            X[row, j] = x[j] * np.exp(s * step[j]) if prior.log[j] else x[j] + s * step[j]
    y = fun(batch_from_vectors(ps, names, X))
    return y[0], np.stack([(y[1 + 2 * j] - y[2 + 2 * j]) / (2 * step[j]) for j in range(P)], 1)


def test_fisher_of_white_noise_is_that_of_finite_differences(setup):
    """With white noise only (no systematics, no mismatch, every channel's lag fitted), the
    block's information is J^T J / sigma^2 with J the signals' derivatives in u: checked
    against central differences of plain simulations (no sensitivities)."""
    ps, names, prior, x = setup
    block = Block(FIVE, runs=10)
    dxdu = np.where(prior.log, x, 1.0)[None]
    F = block_information(ps, names, x[None], dxdu, block, WHITE, gain_sd=0.0, timing_sd=0.0,
                          lag_sd=0.0, fitted_lag_channels=("x_head", "y_base", "y_head"))[0]
    from gprm.design.information import window_times

    t = window_times(block)

    def fun(pb):
        return observe(pb, t, MODEL_CHANNELS).y.reshape(len(pb["t0"]), -1)

    _, J = _fd_jacobian(ps, names, prior, x, fun)
    F_fd = J.T @ J / (WHITE.white ** 2 / block.runs)
    scale = np.sqrt(np.outer(np.diag(F_fd), np.diag(F_fd)))
    seen = scale > 1e-12 * scale.max()
    assert np.max(np.abs(F - F_fd)[seen] / scale[seen]) < 1e-4


@pytest.mark.parametrize("component", ["all", "runs", "floor"])
def test_nuisances_are_marginalised_exactly(setup, component):
    """Gain, timing and mismatch terms: the Woodbury form equals J^T Sigma^-1 J with the
    dense covariance Sigma = diag(var_w) + var_a y y^T + var_t y' y'^T of each channel; for
    the two parts of the carry-over, Sigma holds only the error that averages down over the
    block's runs (white noise, amplitude spread, alignment, synchronisation) or only the
    error that does not (mismatch, gain, stated timing); the own-lag nuisance is in both."""
    ps, names, prior, x = setup
    runs, floor = component in ("all", "runs"), component in ("all", "floor")
    block = Block((Channel("x_head"), Channel("tip_x", "tip", point="tip_edge", axis="x")),
                  runs=7)
    noise = NoiseModel(4e-10, 0.02, kappa=1.7, mismatch=3.0, base_runs=10,
                       gain=(("x_head", 0.004),), align=(("x_head", 2e-7),),
                       sync=(("x_head", 5e-8), ("x_base", 3e-8)))
    dxdu = np.where(prior.log, x, 1.0)[None]
    F = block_information(ps, names, x[None], dxdu, block, noise, gain_sd=0.003,
                          timing_sd=1e-7, lag_sd=1e-5,
                          fitted_lag_channels=("x_head", "y_base", "y_head"),
                          component=component)[0]
    Y, D, Yd = block_signals(ps, names, x[None], block, 2)
    k = noise.kappa
    F_dense = np.zeros_like(F)
    for c, ch in enumerate(block.channels):
        y = Y[0, c]
        sem2 = (noise.white ** 2 + noise.variability ** 2 * y ** 2) / noise.base_runs
        var_w = k * (runs * noise.white ** 2 / block.runs + floor * noise.mismatch * sem2)
        var_a = k * (floor * (0.003 ** 2 + noise.gain_of(ch.name) ** 2)
                     + runs * 0.02 ** 2 / block.runs)
        own = 0.0 if ch.name == "x_head" else 1e-5 ** 2
        # the synchronisation's timing: the fit's where it had the channel, else the
        # median of the fit's (tip_x: 4e-8)
        sync = 5e-8 if ch.name == "x_head" else 4e-8
        assert noise.sync_of(ch.name) == pytest.approx(sync)
        var_t = k * (floor * 1e-7 ** 2
                     + runs * (noise.align_of(ch.name) ** 2 + sync ** 2) * 10 / block.runs
                     + own)
        S = np.diag(var_w) + var_a * np.outer(y, y) + var_t * np.outer(Yd[0, c], Yd[0, c])
        J = D[0, c] * dxdu[0]
        F_dense += J.T @ np.linalg.solve(S, J)
    scale = np.sqrt(np.outer(np.diag(F_dense), np.diag(F_dense)))
    seen = scale > 0
    assert np.max(np.abs(F - F_dense)[seen] / scale[seen]) < 1e-6
    assert np.all(F[~seen] == 0)


def test_a_plunger_point_where_a_laser_is_gives_that_laser(setup):
    """A custom plunger point at (0, 0, d_x_base) along x is the model's x_base (Eq. 3), and
    at (0, 0, d_y_head) along y its y_head (apart from y_head's alignment offset, zero
    here): same signals and same sensitivities, although built from the states."""
    ps, names, prior, x = setup
    dxb, dyh = ps["d_x_base"], ps["d_y_head"]
    names_ = tuple(n for n in names if n not in ("d_x_base", "d_y_head"))
    x_ = ps.vector(names_)
    block = Block((Channel("x_base"), Channel("y_head"),
                   Channel("px", "plunger", at=(0.0, 0.0, dxb), axis="x"),
                   Channel("py", "plunger", at=(0.0, 0.0, dyh), axis="y")))
    Y, D, _ = block_signals(ps.with_values(dt_y_head=0.0), names_, x_[None], block, 2)
    assert np.allclose(Y[0, 2], Y[0, 0], rtol=0, atol=1e-12 * np.abs(Y[0, 0]).max())
    assert np.allclose(Y[0, 3], Y[0, 1], rtol=0, atol=1e-12 * np.abs(Y[0, 1]).max())
    keep = [i for i, n in enumerate(names_) if n != "dt_y_head"]
    for a, b in ((2, 0), (3, 1)):
        ref = D[0, b][:, keep]
        assert np.allclose(D[0, a][:, keep], ref, rtol=0,
                           atol=1e-9 * np.abs(ref).max())


def test_tip_point_sensitivities_include_the_actuation_axis(setup):
    """A tip point along x sees the retraction projected by gamma: its derivative in gamma
    and rho (through the axis u, the point held where it is at the best fit) matches central
    differences of the same channel."""
    ps, names, prior, x = setup
    ch = Channel("tip_x", "tip", point="tip_edge", axis="x")
    block = Block((ch, Channel("tip_y", "tip", point="tip_edge", axis="y")))
    Y, D, _ = block_signals(ps, names, x[None], block, 2)
    for n in ("gamma", "rho", "k_Ax", "m4"):
        j = names.index(n)
        h = 1e-4 * max(abs(x[j]), 1e-3)
        X = np.repeat(x[None], 3, 0)
        X[1, j] += h
        X[2, j] -= h
        Yh, _, _ = block_signals(ps, names, X, block, 2)
        fd = (Yh[1] - Yh[2]) / (2 * h)
        # central differences: the solver's rounding over h and h^2 leave ~1e-6 here (the
            # model's own x_base shows the same against its exact sensitivities)
        err = np.max(np.abs(D[0][..., j] - fd)) / np.abs(fd).max()
        assert err < 1e-5, (n, err)
        if n == "gamma":              # the projected retraction: large, and only through u
            assert np.abs(fd[0]).max() > 0.1 * np.abs(Y[0, 0]).max()


def test_information_is_positive_semidefinite_and_adds(setup):
    ps, names, prior, x = setup
    dxdu = np.where(prior.log, x, 1.0)[None]
    P0 = np.diag(1 / prior.sd ** 2)
    noise = NoiseModel(4e-10, 0.02, mismatch=2.0, gain=(("x_base", 0.005),))
    Fs = [block_information(ps, names, x[None], dxdu, c.block, noise, gain_sd=0.0,
                            timing_sd=0.0, lag_sd=1.25e-5)[0] for c in default_candidates()]
    for F in Fs:
        ev = np.linalg.eigvalsh(F / np.abs(F).max())
        assert ev.min() > -1e-8
    # more information never widens the posterior of any parameter
    sd1 = np.sqrt(np.diag(np.linalg.inv(P0 + Fs[0])))
    sd2 = np.sqrt(np.diag(np.linalg.inv(P0 + Fs[0] + Fs[1])))
    assert np.all(sd2 <= sd1 * (1 + 1e-9))


def test_estimate_noise_recovers_its_model():
    rng = np.random.default_rng(3)
    y = rng.normal(size=(5, 40)) * 1e-6
    sem = np.sqrt((5e-10 ** 2 + 0.02 ** 2 * y ** 2) / 10)
    n0, v = estimate_noise(sem, y, 10)
    assert n0 == pytest.approx(5e-10, rel=1e-6) and v == pytest.approx(0.02, rel=1e-6)


def test_calibration_matches_the_median_ratio():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(2, 6, 6))
    F = np.einsum("bij,bkj->bik", A, A) * 100
    P0 = np.eye(6)
    fit_sd = np.full(6, 0.05)
    mask = np.ones(6, bool)
    k = _calibrate(P0, F, fit_sd, mask)
    sd = np.sqrt(np.mean(np.diagonal(_posterior(P0, F, k), axis1=1, axis2=2), 0))
    assert np.median(sd / fit_sd) == pytest.approx(1.0, rel=1e-6)


# ----------------------------------------------------------------------------- design runs
@pytest.fixture(scope="module")
def paper_design():
    return run_design("paper")


def test_paper_design_ranks_every_candidate_and_keeps_the_budget(paper_design):
    r = paper_design
    assert set(r.ranking) == {c.name for c in default_candidates()}
    gains = [r.evaluation(n).gain["release"] for n in r.ranking]
    assert all(g >= 1 - 1e-9 for g in gains)          # information never hurts
    assert r.recommended.hours <= r.config.cost.budget
    assert len(r.recommended.additions) <= r.config.cost.max_additions
    # the exhaustive choice is at least as good as any single candidate that fits
    fits = [r.evaluation(n).gain["release"] for n in r.ranking
            if r.evaluation(n).hours <= r.config.cost.budget]
    assert r.recommended.gain["release"] >= max(fits) - 1e-12
    assert r.noise.kappa == 1.0                          # no fit to calibrate against


def test_no_candidate_separates_the_y_springs_and_the_reason_is_given(paper_design):
    y = paper_design.y_springs
    assert y["determined_by"] == []
    assert "K0 = k_Cy + k_Dy" in y["text"]


def test_a_tight_budget_is_kept(setup):
    cfg = read_design_config(None)
    cfg = replace(cfg, cost=replace(cfg.cost, budget=4.0))
    r = run_design("paper", cfg)
    assert r.recommended.hours <= 4.0
    hours = {c.name: e.hours for c, e in zip(cfg.candidates, r.candidates)}
    assert all(hours[a] <= 4.0 for a in r.recommended.additions)


# ----------------------------------------------------------------------------- files, CLI
def test_candidates_file(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text('include_defaults = false\n[cost]\nbudget = 10\n[[candidate]]\n'
                 'name = "tip"\nchannels = [{body = "tip", point = "tip_edge", axis = "x"}]\n'
                 'runs = 20\nwindow = ["0.97 ms", "1.3 ms"]\nrecord = "1.5 ms"\n'
                 'voltage = "50 %"\ndrive = ["piezo1", "piezo2"]\n')
    cfg = read_design_config(f)
    (c,) = cfg.candidates
    assert c.block.runs == 20 and c.block.drives == (1, 2)
    assert c.block.window == pytest.approx((0.97e-3, 1.3e-3))
    assert c.block.voltage == pytest.approx(0.5) and cfg.cost.budget == 10


@pytest.mark.parametrize("text, field", [
    ('[[candidate]]\nname = "a"\nchannels = ["x_lr"]\n', "candidate[0].channels[0]"),
    ('[[candidate]]\nname = "a"\nwindow = ["1.3 ms", "1.2 ms"]\n', "candidate[0].window"),
    ('[[candidate]]\nname = "a"\nrunz = 3\n', "candidate[0]"),
    ('[cost]\nbudget = "a lot"\n', "cost.budget"),
    ('[[candidate]]\nname = "a"\nchannels = [{body = "runner", at = [0, 0, 0], axis = "x"}]\n',
     "candidate[0].channels[0].axis"),
    # more samples in the window than a design evaluates: refused, not a MemoryError
    ('[[candidate]]\nname = "a"\nrate = "1e15 Hz"\n', "candidate[0].rate"),
])
def test_bad_candidates_are_refused_naming_the_field(tmp_path, text, field):
    f = tmp_path / "c.toml"
    f.write_text(text)
    with pytest.raises(GprmInputError) as e:
        read_design_config(f)
    assert e.value.field == field


def test_cli_paper_and_one_line_errors(tmp_path):
    from gprm.cli import app

    out = tmp_path / "design.json"
    r = CliRunner().invoke(app, ["design", "paper", "--out", str(out)])
    assert r.exit_code == 0, r.output
    doc = json.loads(out.read_text())
    assert doc["format"] == "gprm-design" and doc["ranking"]
    assert "recommended within" in r.output
    bad = tmp_path / "bad.toml"
    bad.write_text("[[candidate]]\nname = 3\n")
    before = bad.read_text()
    r = CliRunner().invoke(app, ["design", "paper", "--candidates", str(bad), "--out",
                                 str(tmp_path / "d2.json")])
    assert r.exit_code == 2
    assert "candidate[0].name" in r.output and "Traceback" not in r.output
    assert len(r.output.strip().splitlines()) == 1
    assert bad.read_text() == before and not (tmp_path / "d2.json").exists()


@pytest.fixture(scope="module")
def synthetic_fit(tmp_path_factory):
    """A real fit file (a small one: a generated campaign without the nonlinear correction,
    8 starts, the default uncertainty)."""
    from gprm.campaign.preprocess import PreprocessConfig, preprocess
    from gprm.campaign.synth import SynthConfig, synth_campaign
    from gprm.fit.api import run_fit

    camp = synth_campaign(seed=4, config=SynthConfig(nonlinear=False))
    means = preprocess(camp, PreprocessConfig()).to_dataset()
    fit = run_fit(means, FitOptions(starts=8, seed=1))
    path = tmp_path_factory.mktemp("fit") / "fit.json"
    fit.write(path)
    return path


def _parts_document(names, shares, rr, origin=0.0, stated_timing=0.0):
    return {"uncertainty": {"details": {
        "variance_shares": {n: dict(shares) for n in names},
        "residual_over_runs": list(rr), "time_origin_sd_s": origin,
        "stated": {"timing_sd_s": stated_timing}}}}


def test_variance_parts_split_what_averages_down_from_what_does_not():
    """The runs' share of the statistical variance is 1 / rho (rho = the residuals' over the
    runs' variance), the rest and the gain share do not average down; the timing share is
    the alignment's unless a timing error is stated; t0's time origin is moved out of the
    timing share; nothing is lost; where the excess test left a parameter's excess out, its
    statistical share is all the runs'; no shares, no split."""
    from gprm.design.core import variance_parts

    names = ("m1", "t0")
    shares = {"statistical": 0.6, "gain": 0.2, "timing": 0.15, "interpolation": 0.01,
              "prior": 0.04}
    var = np.array([4.0, 9.0])
    x = np.array([0.1, 1.0e-3])
    log = np.array([True, True])
    rr = np.sqrt([3.0, 0.5])                  # rho 3 (mismatch) and 0.5 (runs dominate)
    A, B = variance_parts(_parts_document(names, shares, rr), names, var, x, log)
    np.testing.assert_allclose(A + B, var, rtol=1e-12)
    np.testing.assert_allclose(A[0], var[0] * (0.6 / 3 + 0.15 + 0.05), rtol=1e-12)
    np.testing.assert_allclose(B[1], var[1] * 0.2, rtol=1e-12)     # rho < 1: all runs'
    # t0's time origin: (origin / t0)^2 of variance in u moves from A (alignment) to B
    origin = 1.0e-3 * np.sqrt(0.1 * 9.0)
    A2, B2 = variance_parts(_parts_document(names, shares, rr, origin), names, var, x, log)
    np.testing.assert_allclose(B2[1] - B[1], 0.1 * 9.0, rtol=1e-9)
    np.testing.assert_allclose(A2 + B2, var, rtol=1e-12)
    # a stated timing error does not average down
    A3, B3 = variance_parts(_parts_document(names, shares, rr, stated_timing=1e-7), names,
                            var, x, log)
    np.testing.assert_allclose(B3 - B, var * 0.15, rtol=1e-12)
    assert variance_parts({"uncertainty": {}}, names, var, x, log) is None
    # the excess test left m1's excess out of its variance: its statistical share is the
    # runs', all of it averages down
    tested = _parts_document(names, shares, rr)
    tested["uncertainty"]["details"]["excess_reaches"] = [False, True]
    A4, B4 = variance_parts(tested, names, var, x, log)
    np.testing.assert_allclose(A4[0], var[0] * (0.6 + 0.15 + 0.05), rtol=1e-12)
    np.testing.assert_allclose(A4 + B4, var, rtol=1e-12)
    np.testing.assert_allclose(B4[1], B[1], rtol=1e-12)
    no_runs = _parts_document(names, shares, rr)
    no_runs["uncertainty"]["details"]["residual_over_runs"] = None
    assert variance_parts(no_runs, names, var, x, log) is None


def test_more_runs_shrink_only_the_part_that_averages_down(synthetic_fit):
    """On a real fit (default uncertainty): the carry-over has two parts; the base design
    reproduces the fit's sd; a campaign of the same design with a million runs keeps the
    part that does not average down (its information does not depend on the runs), never
    more than the fit's variance, and loses the other wherever runs can determine the
    parameter (not where it trades off with the y-plane springs, which no number of runs
    separates: b1 on some fits)."""
    from gprm.design.core import read_fit_document, variance_parts

    cfg = replace(read_design_config(None), candidates=())
    base = run_design(synthetic_fit, cfg)
    assert [p.component for p in base.parts] == ["runs", "floor"]
    many = replace(base.base_block, runs=10 ** 6)
    res = run_design(synthetic_fit, cfg, alone=(base.base_block, many))
    same, big = res.alone
    fit_sd = res.fit_sd_u
    below_prior = fit_sd < res.prior_sd
    np.testing.assert_allclose(same["sd_u"][below_prior], fit_sd[below_prior], rtol=1e-6)
    log = np.asarray(res.log, bool)
    A, B = variance_parts(read_fit_document(synthetic_fit), res.names, fit_sd ** 2, res.best,
                          log)
    v = big["sd_u"] ** 2
    m = below_prior
    assert np.all(v[m] >= B[m] * (1 - 1e-6))
    assert np.all(v[m] <= (A + B)[m] * (1 + 1e-9))
    ident = res.base.identified
    at_floor = np.abs(v - B) <= 0.02 * B
    assert at_floor[ident].sum() >= 0.75 * ident.sum()


def test_run_to_run_variation_averages_over_runs_not_over_the_window(synthetic_fit):
    """The runs' part beyond what the noise model explains (the mechanism and its drive
    varying from run to run) shrinks with the runs of the same measurement as 1/runs and
    not with a longer window; where the noise model explains all of a parameter's runs'
    part, the part scales with the information as before. Checked on the parts themselves
    (each design's variance is the sum of its parts' contributions)."""
    from gprm.design.core import same_measurement

    cfg = replace(read_design_config(None), candidates=())
    res = run_design(synthetic_fit, cfg)
    runs = res.parts[0]
    assert runs.component == "runs" and runs.kappa == 1.0 and runs.runs == 10
    V = runs.per_run_variance(10)
    np.testing.assert_allclose(runs.per_run_variance(40), V / 4, rtol=1e-12)
    np.testing.assert_allclose(V, V.T, rtol=0, atol=1e-15 * np.abs(V).max())
    assert np.linalg.eigvalsh(V).min() >= -1e-9 * np.abs(V).max()    # a covariance
    with pytest.raises(ValueError):
        runs.per_run_variance(0)
    # a synthetic campaign has run-to-run variation (the generator varies its drive and
    # mechanism between runs), so the excess is not empty
    ident = res.base.identified
    assert np.all(np.diag(V) >= 0) and np.median(np.diag(V)[ident]) > 0
    base = res.base_block
    longer = replace(base, window=(base.window[0], 1.6e-3), record=2e-3)
    more = replace(base, runs=40)
    other = replace(base, drives=(1,))
    assert same_measurement(longer, base) and same_measurement(more, base)
    assert not same_measurement(other, base)
    out = run_design(synthetic_fit, cfg, alone=(base, longer, more, other))
    same, long_, many, piezo1 = (a["sd_u"] ** 2 for a in out.alone)
    d = np.diag(V)
    below = out.fit_sd_u < out.prior_sd
    # the share the runs' amplitude and timing errors explain (through the fit's
    # estimator, at the base) is a share; with the base's own leak nothing changes
    ex = runs.explained
    assert ex is not None and np.all((ex >= 0) & (ex <= 1)) and ex[ident].max() > 0
    np.testing.assert_allclose(runs.per_run_variance(10, runs.leak_base), V, rtol=1e-12)
    unexplained = d * (1 - ex)
    # a longer window cannot take the variance below the unexplained run-to-run part of
    # the same runs (only more runs average it)
    assert np.all(long_[below] >= unexplained[below] * (1 - 1e-9))
    # four times the runs: the run-to-run part about a quarter (the rest also shrinks)
    assert np.all(many[below] <= same[below] * (1 + 1e-9))
    assert np.all(many[below] >= unexplained[below] / 4 * (1 - 1e-9))
    # another drive is not a repeat: its runs do not average the base's variation
    assert np.all(piezo1[below] >= np.minimum(unexplained[below], out.prior_sd[below] ** 2)
                  * (1 - 1e-9))
    # a zero leak leaves the unexplained part; the part between follows the leak linearly
    V0 = runs.per_run_variance(10, np.zeros_like(d))
    np.testing.assert_allclose(np.diag(V0), unexplained, rtol=1e-12, atol=1e-300)
    half = runs.per_run_variance(10, 0.5 * runs.leak_base)
    np.testing.assert_allclose(np.diag(half), unexplained + 0.5 * d * ex, rtol=1e-12,
                               atol=1e-300)


def test_run_error_leak_scales_with_runs_and_vanishes_under_a_tight_prior(synthetic_fit):
    """gprm.design.information.run_error_leak: the runs' amplitude and timing errors reach
    the estimate as 1 / runs (exactly, with the prior's precision scaled alike: the
    estimator is the same, its errors average), ten runs and twenty as two blocks as
    thirty in one (each block's mean errs independently), and not at all under a prior far
    tighter than the data."""
    from gprm.design.core import draws_of, load_model
    from gprm.design.information import run_error_leak, run_error_pieces

    cfg = replace(read_design_config(None), candidates=())
    res = run_design(synthetic_fit, cfg)
    fm = load_model(synthetic_fit)
    X = draws_of(fm, 8, 0)
    dx_du = np.where(np.asarray(res.log, bool)[None], X, 1.0)
    base, noise = res.base_block, res.noise
    P0 = np.diag(1.0 / res.prior_sd ** 2)

    def pieces(runs):
        return run_error_pieces(fm.params, fm.names, X, dx_du, replace(base, runs=runs), noise)

    L10 = run_error_leak([pieces(10)], P0)
    assert np.all(L10 >= 0) and L10.max() > 0
    np.testing.assert_allclose(run_error_leak([pieces(40)], 4 * P0), L10 / 4, rtol=1e-8)
    one = run_error_leak([pieces(30)], 3 * P0)
    np.testing.assert_allclose(run_error_leak([pieces(10), pieces(20)], 3 * P0), one,
                               rtol=1e-8)
    np.testing.assert_allclose(one, L10 / 3, rtol=1e-8)
    # the data's errors cannot move a parameter the prior pins
    assert np.all(run_error_leak([pieces(10)], P0 * 1e30) <= 1e-12 * L10)


def test_a_fit_without_the_split_is_carried_over_in_one_part(tmp_path, synthetic_fit):
    """A fit whose uncertainty does not record how its variance splits (another method, an
    older file): one part, which still reproduces the fit's sd at the base design."""
    import shutil

    doc = json.loads(synthetic_fit.read_text())
    del doc["uncertainty"]["details"]["variance_shares"]
    path = tmp_path / "fit.json"
    path.write_text(json.dumps(doc))
    shutil.copy(synthetic_fit.with_suffix(".nc"), tmp_path / "fit.nc")
    res = run_design(path, replace(read_design_config(None), candidates=()))
    assert [p.component for p in res.parts] == ["all"]
    assert res.noise.kappa == res.parts[0].kappa != 1.0
    below = res.fit_sd_u < res.prior_sd
    np.testing.assert_allclose(res.base.sd_u[below], res.fit_sd_u[below], rtol=1e-6)


def test_cli_on_a_fit_of_a_synthetic_campaign(tmp_path, synthetic_fit):
    """The command on a real fit file: its noise model comes from the fit, calibrated in
    two parts."""
    from gprm.cli import app

    out = tmp_path / "design.json"
    r = CliRunner().invoke(app, ["design", str(synthetic_fit), "--out", str(out)])
    assert r.exit_code == 0, r.output
    doc = json.loads(out.read_text())
    assert [p["component"] for p in doc["carry_over"]] == ["runs", "floor"]
    runs, floor = doc["carry_over"]
    # the floor is calibrated; the runs' part takes the noise model at face value and
    # carries the excess as run-to-run variation, recorded per parameter
    assert floor["kappa"] > 0 and floor["kappa"] != 1.0 and "run_to_run_sd_u" not in floor
    assert runs["kappa"] == 1.0 and runs["base_runs"] == 10
    assert set(runs["run_to_run_sd_u"]) == set(doc["base"]["parameters"])
    assert max(runs["run_to_run_sd_u"].values()) > 0
    ex = runs["run_to_run_explained"]
    assert set(ex) == set(doc["base"]["parameters"]) and "run_to_run_explained" not in floor
    assert all(0.0 <= v <= 1.0 for v in ex.values()) and max(ex.values()) > 0
    assert all(0.0 <= v <= 1.0 for v in runs["scale"].values())
    assert doc["noise"]["white_m"] > 0
    assert doc["base"]["fit_sd_u"] is not None
    # the carry-over: the base design reproduces the fit's own sd (or the prior's, where
    # the fit reports more than the prior)
    for n, e in doc["base"]["parameters"].items():
        prior_sd = e["sd_u"] / e["contraction"]
        assert e["sd_u"] == pytest.approx(min(doc["base"]["fit_sd_u"][n], prior_sd), rel=1e-9)
    # narrow and mostly the prior's: leaning, never identified (the fit's rule)
    for n, e in doc["base"]["parameters"].items():
        narrow = e["contraction"] < doc["identified_threshold"]
        assert e["identified"] == (narrow and e["prior_share"] < 0.5), n
        assert e["leans_on_prior"] == (narrow and e["prior_share"] >= 0.5), n
    # and every candidate only adds information
    for c in doc["candidates"]:
        assert all(v <= 1 + 1e-9 for v in c["width_ratio"].values()), c["name"]


def test_report_section_only_where_a_design_is(tmp_path, paper_design):
    from gprm.design.files import write_design
    from gprm.report.design_section import design_section

    assert design_section(tmp_path) is None
    write_design(paper_design, tmp_path / "design.json")
    s = design_section(tmp_path)
    html = "".join(s.blocks)
    assert 'id="fig-design"' in html and 'id="table-design"' in html
    for name in paper_design.ranking:
        assert name in html
    # the candidates that excite the mechanism otherwise carry the validation's caveat
    from gprm.report.design_section import other_excitation

    doc = json.loads((tmp_path / "design.json").read_text())
    other = other_excitation(doc)
    assert set(other) == {"piezo1", "slow-retraction", "fast-retraction", "half-voltage"}
    assert "Caveat for " + ", ".join(other) in html
    # and those fitted over another window carry the window's caveat
    from gprm.report.design_section import other_window

    base = doc["base"]["block"]
    longer = other_window(doc)
    expected = {c["name"] for c in doc["candidates"]
                if c["block"]["window_ms"] != base["window_ms"]}
    assert longer and set(longer) == expected
    assert not set(longer) & {"more-runs", "piezo1", "fast-sampling"}
    assert "Caveat for " + ", ".join(longer) + ": these are fitted over" in html


def _spring_null_direction(ps):
    """The direction of (k_Cy, k_Dy, b1, b2) that keeps K0, K1, K2 (docs/fitting.md) fixed."""
    kC, kD, b1, b2 = (ps[n] for n in ("k_Cy", "k_Dy", "b1", "b2"))
    A = np.array([[1, 1, 0, 0], [b1, b1 + b2, kC + kD, kD],
                  [b1 ** 2, (b1 + b2) ** 2, 2 * kC * b1 + 2 * kD * (b1 + b2),
                   2 * kD * (b1 + b2)]])
    s = np.array([kC, kD, b1, b2])
    return np.linalg.svd(A * s)[2][-1] * s


@pytest.mark.parametrize("dampers", [0.0, None])
def test_no_candidate_sees_the_y_spring_direction_but_through_the_dampers(setup, dampers):
    """The structural argument extended to every candidate: along the direction that keeps
    K0, K1, K2 fixed, no channel of any default candidate (new points on plunger, tip and
    runner, Piezo 1, other voltage profiles, longer record, faster sampling) changes at all
    when the y dampers are zero; with them, only through them (a small fraction of what
    k_Cy alone does)."""
    ps, names, prior, x = setup
    if dampers is not None:
        ps = ps.with_values(c_Cy=dampers, c_Dy=dampers)
        x = ps.vector(names)
    v = _spring_null_direction(ps)
    idx = [names.index(n) for n in ("k_Cy", "k_Dy", "b1", "b2")]
    worst = 0.0
    for c in default_candidates():
        for d in c.block.drives:
            _, D, _ = block_signals(ps, names, x[None], c.block, d)
            along = np.einsum("bctp,p->bct", D[..., idx], v)
            alone = D[..., idx[0]] * v[0]
            worst = max(worst, np.abs(along).max() / np.abs(alone).max())
    if dampers == 0.0:
        assert worst < 1e-12
    else:
        assert 1e-12 < worst < 0.05


def test_overshoot_gradients_match_the_exact_point_jacobians():
    """The release predictions' central-difference gradients (Piezo 2 scenario) against the
    exact displacement Jacobians of gprm.predict (sensitivities + complex step) at the
    time of the largest |displacement|."""
    from gprm.design.core import prior_of
    from gprm.design.predictions import release_predictions
    from gprm.fit.files import paper_model
    from gprm.predict.trajectories import (TRAJECTORY_POINTS, default_times,
                                           linear_point_jacobians, sampled_points)

    fm = paper_model()
    prior = prior_of(fm)
    pr = release_predictions(fm, prior.sd, prior.log)
    t = default_times()
    Jd, _ = linear_point_jacobians(fm, t, TRAJECTORY_POINTS, piezo=2)    # (P, pt, 3, T)
    pos, _, _ = sampled_points({k: np.atleast_1d(v) for k, v in fm.params.values.items()},
                               t, TRAJECTORY_POINTS, piezo=2)
    x = fm.params.vector(fm.names)
    dxdu = np.where(prior.log, x, 1.0)
    checked = 0
    for k, lab in enumerate(pr.label):
        sc, point, axis = lab.split()
        if sc != "piezo2":
            continue
        i, a = TRAJECTORY_POINTS.index(point), "xyz".index(axis)
        j = int(np.argmax(np.abs(pos[0, i, a])))
        exact = np.sign(pos[0, i, a, j]) * Jd[:, i, a, j] * dxdu
        err = np.max(np.abs(pr.gradient[k] - exact)) / np.max(np.abs(exact))
        assert err < 1e-3, (lab, err)
        checked += 1
    assert checked >= 6
    assert {"overshoot", "velocity"} <= set(pr.group)


@pytest.mark.parametrize("piezo", [1, 2])
def test_the_generator_drives_the_piezo_it_is_told(piezo):
    """gprm synth campaign --piezo (for validating a Piezo 1 design): the campaign's
    noise-free truth at the model positions is the model driven by that piezo (without the
    nonlinear correction and the unmodelled mode, which are added on top)."""
    from gprm.campaign.synth import SynthConfig, synth_campaign

    truth = paper()
    ds = synth_campaign(truth, seed=1, config=SynthConfig(nonlinear=False, mode_rel=0.0,
                                                          piezo=piezo))
    t = np.asarray(ds["truth_time"].values)
    from gprm.params import batch

    ref = observe(batch([truth]), t, MODEL_CHANNELS, piezo=piezo).y[0]
    other = observe(batch([truth]), t, MODEL_CHANNELS, piezo=3 - piezo).y[0]
    pos = [str(p) for p in ds["position"].values]
    got = np.stack([np.asarray(ds["truth_displacement"].values)[pos.index(n)]
                    for n in MODEL_CHANNELS])
    assert np.allclose(got, ref, rtol=0, atol=1e-9 * np.abs(ref).max())
    assert not np.allclose(got, other, rtol=0, atol=1e-3 * np.abs(ref).max())
    assert int(ds.attrs["generator_piezo"]) == piezo


def test_greedy_selection_keeps_the_budget_and_never_beats_the_exhaustive(paper_design):
    cfg = replace(read_design_config(None), exhaustive_limit=0)
    r = run_design("paper", cfg)
    assert r.selection.startswith("greedy")
    assert 0 < len(r.recommended.additions) <= cfg.cost.max_additions
    assert r.recommended.hours <= cfg.cost.budget
    # the two searches reach a subset's gain through sums in different orders: equal to
    # rounding, 3e-9 relative with the lower-bound NumPy (1e-8 allows three times that)
    assert 1.0 < r.recommended.gain["release"] <= \
        paper_design.recommended.gain["release"] * (1 + 1e-8)


def test_a_marginalised_resonance_is_projected_off_each_channel(setup):
    """Where the fit found a resonance (fit.json's adequacy.resonance), each channel's
    information is that of its signal projected off the resonance's two columns (written out
    here with the fit's own basis, gprm.fit.resonance.response): free amplitude and phase,
    no prior. It never adds information, and a resonance whose onset lies after the window
    takes none."""
    from gprm.design.information import window_times
    from gprm.fit.resonance import response
    from gprm.simulate.core import ROW_LAGS

    ps, names, prior, x = setup
    block = Block(FIVE, runs=10)
    dxdu = np.where(prior.log, x, 1.0)[None]
    lags = ("x_head", "y_base", "y_head")
    res = (31e3, 0.015, 0.0)
    kw = dict(gain_sd=0.0, timing_sd=0.0, lag_sd=0.0, fitted_lag_channels=lags)
    F0 = block_information(ps, names, x[None], dxdu, block, WHITE, **kw)[0]
    F1 = block_information(ps, names, x[None], dxdu, block, replace(WHITE, resonance=res),
                           **kw)[0]
    t = window_times(block)
    Y, D, _ = block_signals(ps, names, x[None], block, 2)
    var = WHITE.white ** 2 / block.runs
    F_ref = np.zeros_like(F0)
    for ci, ch in enumerate(MODEL_CHANNELS):
        on = ps["t_c"] + ps["t0"] + sum(ps[n] for n in ROW_LAGS.get(ch, ()))
        g = response(t, on, ps["tau_v"], res[0], res[1])
        Q, _ = np.linalg.qr(np.stack([g.real, g.imag], 1))
        J = D[0, ci] * dxdu[0][None, :]
        J = J - Q @ (Q.T @ J)
        F_ref += J.T @ J / var
    scale = np.sqrt(np.outer(np.diag(F_ref), np.diag(F_ref)))
    seen = scale > 1e-10 * scale.max()
    assert np.max(np.abs(F1 - F_ref)[seen] / scale[seen]) < 1e-6
    assert np.linalg.eigvalsh(F0 - F1).min() > -1e-9 * np.abs(F0).max()
    assert np.trace(F1) < np.trace(F0)
    late = replace(WHITE, resonance=(31e3, 0.015, 1.0))          # onset 1 s after the window
    F2 = block_information(ps, names, x[None], dxdu, block, late, **kw)[0]
    np.testing.assert_allclose(F2, F0, rtol=1e-9, atol=1e-12 * np.abs(F0).max())


def test_design_counts_the_alignment_noise_the_fit_counted():
    """The design's noise model takes a channel's alignment timing noise from the fit only
    where the fit counted it: its recorded timing sd beyond the stated one (combined in
    quadrature), which since stop 40 is nothing for a signal whose own lag was fitted and
    the alignment sd for one held fixed; older files without the timing sd: the
    alignment sd. The synchronisation's timing sd the fit also adds is not counted."""
    from gprm.design.core import _alignment_counted

    a, st = 3e-7, 1e-7
    stated = {"timing_sd_s": st, "per_signal": {"y_head": {"gain_sd": 0.0,
                                                           "timing_sd_s": 0.0}}}
    assert _alignment_counted({"alignment_sd_s": a, "timing_sd_s": st}, stated,
                              "x_head") == 0.0
    assert _alignment_counted({"alignment_sd_s": a, "timing_sd_s": float(np.hypot(st, a))},
                              stated, "x_head") == pytest.approx(a, rel=1e-12)
    # a per-signal statement overrides the global one
    assert _alignment_counted({"alignment_sd_s": a, "timing_sd_s": a}, stated,
                              "y_head") == pytest.approx(a, rel=1e-12)
    assert _alignment_counted({"alignment_sd_s": a}, stated, "x_head") == a
    # the synchronisation's timing (stop 43, every signal) is not alignment noise
    sync = 8e-9
    assert _alignment_counted({"alignment_sd_s": a, "timing_sd_s": float(np.hypot(st, sync)),
                               "sync_timing_sd_s": sync}, stated,
                              "x_head") == pytest.approx(0.0, abs=1e-12)   # 1 ps: rounding
    both = float(np.sqrt(st ** 2 + a ** 2 + sync ** 2))
    assert _alignment_counted({"alignment_sd_s": a, "timing_sd_s": both,
                               "sync_timing_sd_s": sync}, stated,
                              "x_head") == pytest.approx(a, rel=1e-9)


def test_a_design_counts_identified_as_a_fit_does():
    """The design's identified mask is the fit's rule (gprm.fit.uncertainty.determined): narrow
    and less than half of the variance the prior's. The prior's part diag(C P0 C) and the
    data's diag(C F C) / kappa add up to the posterior variance, draw by draw."""
    from gprm.design.core import _identified, _prior_variance

    rng = np.random.default_rng(5)
    A = rng.normal(size=(3, 5, 5)) * np.array([100.0, 30.0, 10.0, 1.0, 0.01])[:, None]
    F = np.einsum("bij,bkj->bik", A, A)
    P0 = np.diag(1 / np.array([1.0, 2.0, 0.5, 1.0, 1.5]) ** 2)
    kappa = 2.0
    C = _posterior(P0, F, kappa)
    data = np.mean(np.einsum("dip,dpq,dqi->di", C, F / kappa, C), 0)
    var = np.mean(np.diagonal(C, axis1=1, axis2=2), 0)
    prior_var = _prior_variance(C, P0)
    np.testing.assert_allclose(prior_var + data, var, rtol=1e-9)
    sd0 = 1 / np.sqrt(np.diag(P0))
    ident = _identified(np.sqrt(var), sd0, prior_var / var, 0.3)
    # the rule written out: narrow, and less than half of the variance the prior's
    expect = (np.sqrt(var) / sd0 < 0.3) & (prior_var / var < 0.5)
    assert ident.tolist() == expect.tolist() and 0 < ident.sum() < 5
