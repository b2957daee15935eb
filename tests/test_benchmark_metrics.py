"""The coverage benchmark's own statistics (benchmarks/bench_coverage.py): the randomised PIT
it scores the kinetic-energy histogram with is calibrated where a bin's occupancy has an atom
at zero, and the closed percentile band over the bins the truth occupies is not (here it
under-covers; with rarer empty bins it over-covers)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import binom

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_coverage import pit_cover  # noqa: E402


def _binomial_range(p: float, n: int) -> tuple[float, float]:
    """The central 99.99 % range of a binomial proportion (the test fails by chance 1e-4)."""
    lo, hi = binom.interval(0.9999, n, p)
    return lo / n, hi / n


def test_pit_coverage_is_nominal_with_and_without_atoms_and_the_band_is_not():
    rng = np.random.default_rng(5)
    n_sets, k, b = 300, 40, 400
    hits = {"pit95": 0, "pit68": 0, "band68": 0}
    n_pit = n_band = 0
    for _ in range(n_sets):
        mu = rng.uniform(-1.5, 1.0, k)                   # bins empty with probability 16-93 %
        draws = np.maximum(0.0, mu + rng.standard_normal((b, k)))
        truth = np.maximum(0.0, mu + rng.standard_normal(k))   # same distribution as draws
        r = pit_cover(draws, truth, rng)
        hits["pit95"] += r["in95"]
        hits["pit68"] += r["in68"]
        n_pit += k
        used = truth > 0                                  # the bins the truth occupies
        q16, q84 = np.percentile(draws, [16, 84], axis=0)
        hits["band68"] += int(np.sum(used & (q16 <= truth) & (truth <= q84)))
        n_band += int(used.sum())
    # with finitely many draws the PIT is nominal up to O(1/b); the range allows for it
    lo, hi = _binomial_range(0.95, n_pit)
    assert lo - 0.005 <= hits["pit95"] / n_pit <= hi + 0.005
    lo, hi = _binomial_range(0.68, n_pit)
    assert lo - 0.005 <= hits["pit68"] / n_pit <= hi + 0.005
    # scoring the closed band over the bins the truth occupies is off nominal at the atom
    lo, hi = _binomial_range(0.68, n_band)
    assert not lo <= hits["band68"] / n_band <= hi


def test_likelihood_study_mixture_weights_against_the_gaussian_and_scipy():
    """bench_scenarios' exact mixture over parameter sets (the likelihood study of
    docs/flight.md §11): with every set identical it is the method's Gaussian with C_k = 0
    (gprm.flight.inference.posterior_weights); with distinct sets, the mean of the sets'
    normal densities (scipy), renormalised; draws with < 75 % impacts get no weight."""
    from bench_scenarios import _mixture_weights
    from scipy.stats import multivariate_normal

    from gprm.flight.inference import InferenceOptions, PriorPredictive, posterior_weights
    from gprm.flight.scenario import PARAMS

    rng = np.random.default_rng(3)
    K, M = 300, 5
    mean = rng.normal(0, 2e-5, (K, 6))
    y = mean[17] + rng.normal(0, 3e-7, 6)
    sig = np.full(6, 1e-7)
    use = np.array([True] * 5 + [False])
    opts = InferenceOptions(n_draws=K)
    pp = PriorPredictive("xz", {k: rng.uniform(size=K) for k in PARAMS}, mean,
                         np.zeros((K, 6, 6)), np.zeros(K), np.zeros((K, 6)), np.zeros(K),
                         np.ones(K, bool))
    same = np.broadcast_to(mean, (M, K, 6))
    ok = np.ones((M, K), bool)
    w_mix = _mixture_weights(same, ok, y, sig, use, opts.floor, opts.rel_floor)
    np.testing.assert_allclose(w_mix, posterior_weights(pp, y, sig, use, opts),
                               rtol=1e-9, atol=1e-300)
    # distinct sets; set 0 without an impact at draw 5; draw 9 with 3 of 5 sets only
    Y = mean[None] * (1 + rng.normal(0, 0.03, (M, K, 1)))
    ok[0, 5] = False
    ok[:2, 9] = False
    w = _mixture_weights(Y, ok, y, sig, use, opts.floor, opts.rel_floor)
    fl = np.array([opts.floor[0]] * 3 + [opts.floor[1]] * 3)
    want = np.zeros(K)
    for k in range(K):
        if ok[:, k].mean() < 0.75:
            continue
        dens = [multivariate_normal(Y[m, k, use], np.diag(
            (sig ** 2 + fl ** 2 + (opts.rel_floor * Y[m, k]) ** 2)[use])).pdf(y[use])
            for m in range(M) if ok[m, k]]
        want[k] = np.mean(dens)
    assert w[9] == 0 and want[9] == 0
    np.testing.assert_allclose(w, want / want.sum(), rtol=1e-8, atol=1e-300)


def test_impact_time_totals_count_each_campaign_once():
    """bench_flight.add_analysis (shared by bench_flight and bench_scenarios): the truth
    summary's counts add up, a joint chi-square test counts where a release has a p-value and
    rejects below 0.01, and a campaign where Tukey rejects counts once."""
    from bench_flight import COUNTS, add_analysis, new_totals

    def doc(ps, compatible):
        return {"truth": {"summary": {k: i + 1 for i, k in enumerate(COUNTS)}},
                "releases": [{"joint": {"p": p}} for p in ps],
                "tukey": {"all_compatible": compatible}}

    tot = new_totals()
    add_analysis(tot, doc([0.5, 0.001, None], True))
    add_analysis(tot, doc([0.009, None], False))
    assert tot["campaigns"] == 2
    assert [tot[k] for k in COUNTS] == [2 * (i + 1) for i in range(len(COUNTS))]
    assert (tot["chi2_tests"], tot["chi2_rejects"]) == (3, 2)
    assert tot["tukey_rejecting_campaigns"] == 1


def test_oracle_study_counts_every_truth_once_per_likelihood():
    """bench_scenarios --oracle-study (docs/flight.md §11, the per-release ceiling): every
    truth of each compared scenario is classified once per likelihood, the confusion adds
    up to the truths, and the right count is its diagonal."""
    from bench_scenarios import oracle_study

    from gprm.fit.files import paper_model
    from gprm.flight.scenario import COMPARED

    out = oracle_study(paper_model(), seed=4000, truths=1, draws=400)
    assert len(out["sigma"]) == 6 and all(s > 0 for s in out["sigma"][:5])
    for r in out["variants"].values():
        assert r["n"] == len(COMPARED)
        assert sum(r["confusion"].values()) == r["n"]
        assert r["right"] == sum(c for k, c in r["confusion"].items()
                                 if k.split("->")[0] == k.split("->")[1])
        assert all(k.split("->")[0] in COMPARED and k.split("->")[1] in COMPARED
                   for k in r["confusion"])


def test_per_set_predictives_are_the_methods_when_every_set_is_the_best_fit():
    """bench_scenarios --geometry-study: with a model that has only its best fit (every
    parameter set the same, so each set's own geometry is the best fit's), the per-set prior
    predictives are the method's (gprm.flight.inference.prior_predictives), draw by draw."""
    from dataclasses import replace

    from bench_scenarios import per_set_predictives

    from gprm.fit.files import paper_model
    from gprm.flight.inference import InferenceOptions, prior_predictives
    from gprm.flight.scenario import ScenarioPrior

    fm = replace(paper_model(), covariance=None, draws=None)
    opts = InferenceOptions(n_draws=40, n_model=8, scenarios=("xz", "two"))
    prior = ScenarioPrior()
    ref = prior_predictives(fm, opts, prior)
    new = per_set_predictives(fm, opts, prior)
    for kind in opts.scenarios:
        np.testing.assert_array_equal(new[kind].valid, ref[kind].valid)
        assert new[kind].valid.any()
        v = ref[kind].valid
        np.testing.assert_allclose(new[kind].mean[v], ref[kind].mean[v], rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(new[kind].t_mean[v], ref[kind].t_mean[v], rtol=1e-12)


def test_mixture_choice_study_agrees_with_the_method_and_counts_each_release_once():
    """bench_scenarios --mixture-choice (docs/flight.md §11): its Gaussian variant is the
    method's choice (infer_scenarios on the same prior predictives, equal prior odds), every
    variant classifies every release once, and the right count is the confusion's diagonal."""
    from bench_scenarios import mixture_choice_study, scenario_campaigns

    from gprm.fit.files import paper_model
    from gprm.flight.inference import InferenceOptions, infer_scenarios, prior_predictives
    from gprm.flight.scenario import COMPARED, ScenarioPrior

    fm = paper_model()
    out = mixture_choice_study(fm, [3000], 2, draws=300, n_model=8)
    assert out["n_model"] == 8
    for r in out["variants"].values():
        assert r["n"] == 2 * len(COMPARED) == sum(r["confusion"].values())
        assert r["right"] == sum(c for k, c in r["confusion"].items()
                                 if k.split("->")[0] == k.split("->")[1])
    opts = InferenceOptions(n_draws=300, n_model=8)
    pps = prior_predictives(fm, opts, ScenarioPrior(tm_offset=0.0))
    confusion: dict = {}
    for _s, kind, _ds, tel, y, sig in scenario_campaigns(fm, [3000], 2, tm_offset=0.0):
        res = infer_scenarios(fm, [r.id for r in tel.releases], y, sig, opts, predictive=pps)
        for c in res.chosen_alone:
            confusion[f"{kind}->{c}"] = confusion.get(f"{kind}->{c}", 0) + 1
    assert out["variants"]["Gaussian C_k, floor + 2 % (the method)"]["confusion"] == confusion


def test_likelihood_study_scores_each_release_under_its_own_scenario(monkeypatch):
    """bench_scenarios --likelihood-study: every release's posterior is taken under the prior
    predictive of the scenario that made it (a renamed loop variable once made it use the
    last scenario's for all), and each release is counted once per likelihood."""
    import bench_scenarios as bsc

    from gprm.fit.files import paper_model
    from gprm.flight import inference
    from gprm.flight.scenario import COMPARED

    current, seen = [], []
    campaigns = bsc.scenario_campaigns

    def recording_campaigns(*a, **k):
        for item in campaigns(*a, **k):
            current.append(item[1])
            yield item

    weights = inference.posterior_weights

    def recording_weights(pp, *a, **k):
        seen.append((current[-1], pp.scenario))
        return weights(pp, *a, **k)

    monkeypatch.setattr(bsc, "scenario_campaigns", recording_campaigns)
    monkeypatch.setattr(inference, "posterior_weights", recording_weights)
    res = bsc.likelihood_study(paper_model(), [3000], 2, draws=300)
    assert current == list(COMPARED)
    assert seen and all(truth == used for truth, used in seen)
    assert all(r["n"] == 2 * len(COMPARED) for r in res.values())


def test_band_width_ratio_of_the_projection_study():
    """bench_draws.py --convergence compares prediction bands by |ln(width ratio)| at 68 % and
    95 %; a band twice as wide reads ln 2, the same band 0, a band of zero width is left out
    (its ratio is undefined)."""
    from bench_draws import _log_width_ratio

    rng = np.random.default_rng(3)
    B = np.sort(rng.normal(size=(5, 12)), axis=0)          # 2.5, 16, 50, 84, 97.5 % points
    A = B[2] + 2.0 * (B - B[2])                            # every band twice as wide
    r68, r95 = _log_width_ratio(A, B)
    assert np.allclose(r68, np.log(2.0)) and np.allclose(r95, np.log(2.0))
    r68, r95 = _log_width_ratio(B, B)
    assert r68.size == 12 and np.all(r68 == 0.0) and np.all(r95 == 0.0)
    C = B.copy()
    C[:, 4] = 1.0                                          # one band of zero width
    assert _log_width_ratio(C, B)[0].size == 11


def test_t0_shape_tells_a_heavy_tail_from_a_wrong_width():
    """bench_sources.py's pooled t0 line: errors over their 68 % half-widths read a normal's
    quantiles when the intervals are right; a unit-rms Student t with 4 degrees of freedom
    (a sound variance, heavy tails) has its 68 % point well under 1 and its 95 % point at a
    normal's; an interval 1.3 times too wide moves every quantile down by 1.3."""
    from scipy.stats import norm

    from bench_sources import shape_of

    rng = np.random.default_rng(11)
    h = norm.ppf(0.84)                                     # a normal's 68 % half-width
    q_norm, rms = shape_of(rng.standard_normal(40000) / h)
    assert np.allclose(q_norm, norm.ppf([0.75, 0.84, 0.95, 0.975]) / h, rtol=0.03)
    assert abs(rms - 1 / h) < 0.02
    q_t, _ = shape_of(rng.standard_t(4, 40000) / np.sqrt(2) / h)
    assert q_t[1] < 0.85 and abs(q_t[3] - q_norm[3]) < 0.08
    q_wide, _ = shape_of(rng.standard_normal(40000) / (1.3 * h))
    assert np.allclose(q_wide * 1.3, q_norm, rtol=0.03)


def test_hac_lag_argument_reads_the_systematics_values_and_refuses_others():
    """bench_sources.py / bench_residual_dof.py --hac-lag: ``default`` is None (a quarter of
    the window's samples), ``auto`` the plug-in, a count of samples an int; what
    ``Systematics.hac_lag`` refuses is refused at the command line."""
    import argparse

    from bench_sources import hac_lag_arg

    assert hac_lag_arg("default") is None
    assert hac_lag_arg("auto") == "auto"
    assert hac_lag_arg("5") == 5 and hac_lag_arg("0") == 0
    for bad in ("-1", "x", "2.5"):
        with pytest.raises(argparse.ArgumentTypeError):
            hac_lag_arg(bad)


def test_excess_test_argument_reads_a_quantile_and_refuses_others():
    """bench_sources.py's ``--excess-test``: a quantile strictly inside (0, 1), or ``none``
    (untested, stops 1-50), else refused."""
    import argparse

    from bench_sources import excess_test_arg

    assert excess_test_arg("0.5") == 0.5 and excess_test_arg("0.9") == 0.9
    assert excess_test_arg("none") is None
    for bad in ("0", "1", "-0.1", "None", "x"):
        with pytest.raises(argparse.ArgumentTypeError):
            excess_test_arg(bad)


def test_method_label_names_each_development_check_and_nothing_for_the_default():
    """bench_sources.py's rows are grouped by their method label: the default is the method's
    name alone; each Systematics field changed from the default adds its words, in a fixed
    order (the labels of the JSON files written before the labels were derived this way)."""
    from bench_sources import method_label
    from gprm.fit.sandwich import Systematics

    assert method_label("sandwich", Systematics()) == "sandwich"
    assert method_label("sandwich", Systematics(profile_check=False)) == \
        "sandwich, profile check off"
    assert method_label("sandwich", Systematics(hac_lag=5, residual_dof=False,
                                                alignment_noise="all")) == \
        "sandwich, alignment noise all, residuals' t off, residuals' lag window 5"
    assert method_label("sandwich", Systematics(sync_timing=False, project_draws=False)) == \
        "sandwich, synchronisation's timing off, draws as drawn"
    assert method_label("sandwich", Systematics(excess_test=0.5)) == "sandwich"
    assert method_label("sandwich", Systematics(excess_test=None)) == \
        "sandwich, residuals' excess untested"
    assert method_label("sandwich", Systematics(excess_test=0.9, excess_test_draws=True)) == \
        "sandwich, residuals' excess where above F_0.9, draws' excess tested"


def test_support_table_pools_the_x_plane_support_per_source_and_method():
    """bench_sources.py's x-plane B support table: per source and method, the identified
    cases of k_Bx, c_Bx and d2 pooled (a campaign that did not identify one contributes no
    case for it), other parameters ignored; a source with none says so."""
    from bench_sources import support_table

    rows = [{"source": "a", "method": "m", "inside": {"k_Bx": [1, 0], "d2": [1, 1],
                                                        "m3": [0, 0]}},
            {"source": "a", "method": "m", "inside": {"c_Bx": [0, 0]}},
            {"source": "a", "method": "n", "inside": {"k_Bx": [1, 1]}},
            {"source": "b", "method": "m", "inside": {"m1": [1, 1]}}]
    lines = [[c.strip() for c in ln.split("|")[1:-1]]
             for ln in support_table(rows).splitlines()[2:]]
    assert lines == [["a", "m", "3", "66.7", "33.3"], ["a", "n", "1", "100.0", "100.0"],
                     ["b", "m", "0", "-", "-"]]


def test_prior_share_table_counts_narrow_and_leaning_parameters():
    """bench_prior_share's table: narrow = contraction below CONTRACTION; leaning = narrow and
    the prior's share at least PRIOR_SHARE (gprm.fit.uncertainty.determined); the leaning ones'
    coverage counted over themselves only."""
    from bench_prior_share import table

    def r(name, c, s, in95=True, in68=True):
        return {"name": name, "contraction": c, "share": s, "in95": in95, "in68": in68}
    rows = [r("b1", 0.05, 0.8), r("b1", 0.05, 0.5, in68=False), r("b1", 0.05, 0.49),
            r("b1", 0.5, 0.9, in95=False), r("m2", 0.01, 0.0), r("k_Cy", 0.9, 0.99)]
    lines = {ln.split("|")[1].strip(): [c.strip() for c in ln.split("|")[1:-1]]
             for ln in table(rows).splitlines()[2:]}
    assert set(lines) == {"b1", "m2"}                       # k_Cy never narrow
    assert lines["b1"][1:3] == ["3", "2"]
    assert lines["b1"][4] == "2 / 2, 1 / 2"
    assert lines["m2"][1:3] == ["1", "0"] and lines["m2"][4] == "-"


def test_truth_polish_finds_the_fits_own_minimum_and_scores_errors_in_half_widths():
    """bench_truth_polish.from_truth on a real small fit: with the truth at the fit's own
    point the polish stays (no lower minimum, zero errors); with k_Bx's truth 5 % above it,
    the polish comes back to the same minimum and k_Bx's error is ln(1/1.05) over its 68 %
    half-width in u."""
    from types import SimpleNamespace

    from bench_truth_polish import from_truth
    from gprm.campaign.preprocess import PreprocessConfig, preprocess
    from gprm.campaign.synth import SynthConfig, synth_campaign
    from gprm.fit.api import FitOptions, run_fit
    from sources import PHYSICAL

    camp = synth_campaign(seed=4, config=SynthConfig(nonlinear=False))
    fit = run_fit(preprocess(camp, PreprocessConfig()).to_dataset(),
                  FitOptions(starts=8, seed=1))
    u = fit.uncertainty
    at_fit = {n: float(v) for n, v in zip(fit.names, fit.x) if n in PHYSICAL}
    r = from_truth(SimpleNamespace(fit=fit, truth=at_fit), ["k_Bx", "m2"])
    assert r["truth"] == pytest.approx(r["fit"], rel=1e-6)
    assert all(abs(v[0]) < 1e-12 for v in r["z"].values()) and "m2" in r["z"]
    moved = {**at_fit, "k_Bx": at_fit["k_Bx"] * 1.05}
    r = from_truth(SimpleNamespace(fit=fit, truth=moved), ["k_Bx"])
    k = fit.names.index("k_Bx")
    half = np.log(u.upper68[k] / u.lower68[k]) / 2
    assert r["z"]["k_Bx"][0] == pytest.approx(np.log(1 / 1.05) / half, rel=1e-9)
    assert r["truth"] == pytest.approx(r["fit"], rel=1e-4)


def test_design_replicates_geometric_mean_and_ceiling_match_a_simulation(capsys):
    """bench_design.py --replicates: a design's replicate rows give each parameter's geometric
    mean ratio and the sample variance of its logs; the printed ceiling (a perfect
    prediction's share within +-25 % of one campaign) agrees with the share simulated from
    the same log-normal spread, and a prediction off by a factor 2 is never within."""
    import bench_design

    rng = np.random.default_rng(3)
    sd_ln, k, rows = 0.3, 3, []
    for seed in range(200):
        for j in range(k):
            ratios = {"a": float(np.exp(sd_ln * rng.standard_normal())),
                      "b": float(2.0 * np.exp(0.01 * rng.standard_normal()))}
            if j == 1 and seed == 0:
                ratios.pop("b")                         # not compared in every replicate
            rows.append({"seed": seed, "rank": 1, "name": "d", "ratios": ratios,
                         "replicate": j})
    reps = bench_design.replicate_means(rows)
    first = [r for r in reps if r["seed"] == 0]
    assert [r["param"] for r in first] == ["a"]         # only parameters in every replicate
    a0 = [x["ratios"]["a"] for x in rows if x["seed"] == 0]
    assert first[0]["gm"] == pytest.approx(float(np.exp(np.mean(np.log(a0)))), rel=1e-12)
    assert first[0]["var"] == pytest.approx(float(np.var(np.log(a0), ddof=1)), rel=1e-12)
    bench_design.replicate_tables(rows, [("all", lambda r: True),
                                         ("a only", lambda r: r["param"] == "a")])
    out = capsys.readouterr().out.splitlines()
    cells = {x.split("|")[1].split("(")[0].strip(): [c.strip() for c in x.strip("|").split("|")]
             for x in out if x.startswith("| a") or x.startswith("| all")}
    z = sd_ln * rng.standard_normal(200_000)
    simulated = np.mean(np.abs(np.exp(z) - 1) <= 0.25)
    assert float(cells["a only"][4].rstrip("%")) == pytest.approx(100 * simulated, abs=3)
    # against the replicates' mean the spread is sd / sqrt(k)
    z_k = z / np.sqrt(k)
    assert float(cells["a only"][5].rstrip("%")) == pytest.approx(
        100 * np.mean(np.abs(np.exp(z_k) - 1) <= 0.25), abs=3)
    # half the comparisons are b's, off by 2: the share within is at most a's half
    assert float(cells["all"][3].rstrip("%")) <= 0.5 * float(cells["a only"][3].rstrip("%")) + 1
    gm_b = np.array([r["gm"] for r in reps if r["param"] == "b"])
    assert np.all(np.abs(gm_b - 1) > 0.25)


def test_aligned_likelihood_is_a_density_of_the_measured_components():
    """bench_scenarios --aligned-study (docs/flight.md §11): the Jacobian term of the
    velocity-aligned coordinates, 1 / (|v|^(3 + A) cos^3), against the determinant of their
    numerical Jacobian (A = 3 and 2 angular components); each draw's frame is the sets' mean
    direction and its moments numpy's mean and covariance of the sets there (a set with no
    impact left out); and the log-likelihood of a release against scipy's normal density in
    those coordinates plus that term, so that its evidence compares with the method's (a
    density of the measured components), with the allowance per component and as a common
    scale."""
    from bench_scenarios import (_aligned_frames, aligned_coordinates,
                                 aligned_log_likelihood, aligned_moments)
    from scipy.stats import multivariate_normal

    rng = np.random.default_rng(11)
    e = rng.normal(size=(1, 3))
    e /= np.linalg.norm(e)
    a, b = _aligned_frames(e)
    assert np.allclose(np.cross(a, b), e) and abs(float(np.sum(a * e))) < 1e-15
    for n_ang in (3, 2):
        y = np.concatenate([60e-6 * (e[0] + rng.normal(0, 0.3, 3)), rng.normal(0, 2e-4, 3)])
        idx = list(range(3 + n_ang))
        Jn = np.zeros((len(idx), len(idx)))
        for j, col in enumerate(idx):
            h = 1e-7 * abs(y[col])
            p, q = y.copy(), y.copy()
            p[col] += h
            q[col] -= h
            Jn[:, j] = ((aligned_coordinates(p[None], e, a, b)[0][0]
                         - aligned_coordinates(q[None], e, a, b)[0][0])[idx] / (2 * h))
        _, c, r = aligned_coordinates(y[None], e, a, b)
        expect = -(3 + n_ang) * np.log(r[0]) - 3 * np.log(c[0])
        assert abs(np.log(abs(np.linalg.det(Jn))) - expect) < 1e-5
    # the likelihood: 40 sets scattered about one velocity, 3 draws
    M, K = 40, 3
    base = np.array([50e-6, 5e-6, 30e-6, 2e-4, -1e-4, 3e-5])
    Y = base * (1 + rng.normal(0, 0.03, (M, K, 6)))
    ok = np.ones((M, K), bool)
    ok[3, 1] = False                                    # a set without an impact at draw 1
    am = aligned_moments(Y, ok)
    for k in range(K):
        Yk = Y[ok[:, k], k]
        n = Yk[:, :3] / np.linalg.norm(Yk[:, :3], axis=1)[:, None]
        e_k = n.mean(0) / np.linalg.norm(n.mean(0))
        np.testing.assert_allclose(am["e"][k], e_k, rtol=1e-12)
        U = aligned_coordinates(Yk[:, None], am["e"][k:k + 1], am["a"][k:k + 1],
                                am["b"][k:k + 1])[0][:, 0]
        np.testing.assert_allclose(am["m"][k], U.mean(0), rtol=1e-10, atol=1e-15)
        np.testing.assert_allclose(am["S"][k], np.cov(U, rowvar=False), rtol=1e-8,
                                   atol=1e-12 * np.abs(np.cov(U, rowvar=False)).max())
        np.testing.assert_allclose(am["mu"][k], Yk.mean(0), rtol=1e-12)
    y = base * (1 + rng.normal(0, 0.03, 6))
    sig = np.full(6, 1e-8)
    use = np.array([True] * 5 + [False])
    floor, rel = (0.2e-6, 10e-6), 0.02
    fl = np.array([floor[0]] * 3 + [floor[1]] * 3)
    for scale_only in (False, True):
        ll = aligned_log_likelihood(am, y, sig, use, floor, rel, scale_only)
        for k in range(K):
            u, c, r = aligned_coordinates(y[None], am["e"][k:k + 1], am["a"][k:k + 1],
                                          am["b"][k:k + 1])
            extra = 0.0 if scale_only else (rel * am["mu"][k]) ** 2
            D = np.diag(np.where(use, sig ** 2 + fl ** 2 + extra, 0.0))
            C = am["S"][k] + am["G"][k] @ D @ am["G"][k].T
            if scale_only:
                C[0, 0] += rel ** 2                     # on ln |v| alone
            ui = [0, 1, 2, 3, 4]
            ref = (multivariate_normal(am["m"][k][ui], C[np.ix_(ui, ui)]).logpdf(u[0][ui])
                   - 5 * np.log(r[0]) - 3 * np.log(c[0]))
            assert abs(ll[k] - ref) < 1e-9 * abs(ref)


def test_composite_files_counts_majority_and_minority_releases():
    """bench_scenarios.composite_files: per seed and ordered pair of scenario files, the
    first m releases of A replaced by B's; each release scored on its own evidence and given
    the file. With decisive evidences both are right everywhere; with a minority whose own
    evidence barely favours its scenario, the file's majority takes it along, and the tally
    says so."""
    from bench_scenarios import composite_files

    sc = ["xz", "yz", "two"]

    def file_of(k, n=6, margin=20.0):
        L = np.zeros((n, 3))
        L[:, sc.index(k)] = margin
        return L

    files = [(1, k, file_of(k)) for k in sc]
    out = composite_files(files, sc, minority=(1, 2))
    for m, t in out.items():
        assert t["files"] == 6 and t["same"] == 0
        assert t["majority"] == [6 * (6 - m)] * 3 and t["minority"] == [6 * m] * 3
    # two files whose releases barely tell xz from two: one odd release follows its file
    weak = [(2, "xz", np.tile([0.3, -50.0, 0.0], (6, 1))),
            (2, "two", np.tile([0.0, -50.0, 0.3], (6, 1)))]
    t = composite_files(weak, sc, minority=(1,))[1]
    assert t["files"] == 2 and t["same"] == 2
    assert t["minority"] == [2, 0, 2] and t["majority"] == [10, 10, 10]
