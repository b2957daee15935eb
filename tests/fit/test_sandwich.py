"""The default uncertainty (gprm.fit.sandwich) and the adequacy checks (gprm.fit.adequacy)
against independent references: the HAC sum against statsmodels, the Ljung-Box test against
statsmodels, the coverage of the run-based and residual-based covariances on a linear model
with correlated errors whose answer is known, the gain-error estimate's mean and its
noise without gain errors, the stated
systematics read from a parameter file, and the structure: a default fit loads neither the
synthetic generator nor the opt-in method that needs it."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.stats import binom

from gprm.errors import GprmInputError
from gprm.fit.adequacy import ljung_box
from gprm.fit.sandwich import (Systematics, gain_moments, gain_variance, hac_meat,
                               statistical_covariance, stretch_draws, stretch_whitened)
from gprm.params.files import read_systematics


def _binomial_range(p: float, n: int, level: float = 0.9999) -> tuple[float, float]:
    """The central range a coverage fraction lies in with probability ``level``."""
    lo, hi = binom.interval(level, n, p)
    return lo / n, hi / n


def test_hac_meat_matches_statsmodels():
    from statsmodels.stats.sandwich_covariance import S_hac_simple

    rng = np.random.default_rng(1)
    E = rng.standard_normal((60, 3))
    E[1:] += 0.6 * E[:-1]
    for lags in (1, 4, 12):
        np.testing.assert_allclose(hac_meat(E, lags), S_hac_simple(E, nlags=lags),
                                   rtol=1e-12)


def test_parzen_meat_is_the_weighted_double_sum_and_never_negative():
    """The Parzen-weighted meat equals sum_t sum_t' w(|t - t'|) e_t e_t'^T written out with
    Parzen's weights (1 - 6x^2 + 6x^3 to x = 1/2, 2 (1 - x)^3 to 1, x = lag / (L + 1)), is
    positive semi-definite, and leaks less of an oscillation several samples long into the
    zero-frequency estimate than Bartlett's window of the same length."""
    rng = np.random.default_rng(3)
    T, L = 47, 11
    E = rng.standard_normal((T, 3))
    E[1:] += 0.5 * E[:-1]
    lag = np.abs(np.subtract.outer(np.arange(T), np.arange(T))) / (L + 1.0)
    W = np.where(lag <= 0.5, 1 - 6 * lag ** 2 + 6 * lag ** 3,
                 np.where(lag <= 1, 2 * (1 - lag) ** 3, 0.0))
    np.testing.assert_allclose(hac_meat(E, L, "parzen"), E.T @ W @ E, rtol=1e-12)
    for _ in range(20):
        F = rng.standard_normal((T, 4))
        assert np.linalg.eigvalsh(hac_meat(F, L, "parzen")).min() > -1e-10
    osc = np.sin(2 * np.pi * np.arange(T) / 7.0)[:, None]        # period 7 samples
    assert hac_meat(osc, L, "parzen")[0, 0] < hac_meat(osc, L, "bartlett")[0, 0]


def _ar2(rng, T, a1, a2, burn=200):
    e = rng.standard_normal(T + burn)
    r = np.zeros_like(e)
    for i in range(2, e.size):
        r[i] = a1 * r[i - 1] + a2 * r[i - 2] + e[i]
    return r[burn:]


def test_prewhitened_scores_keep_the_sum_and_estimate_its_variance():
    """The prewhitened scores sum exactly to sum_t B_t r_t; and over Monte Carlo series
    (white, an oscillation 7 samples long, low-pass AR(1) and AR(2)) the Parzen HAC of
    them averages to the actual variance of that sum within 20 %, where the HAC of the
    plain scores is off by 25-45 % on the correlated ones."""
    from gprm.fit.sandwich import prewhitened_scores

    rng = np.random.default_rng(11)
    T, L = 47, 11
    t = np.linspace(0.0, 1.0, T)
    B = np.stack([np.sin(2.5 * t) + t, np.exp(-2 * t)])
    r = _ar2(rng, T, 1.2, -0.3)
    np.testing.assert_allclose(prewhitened_scores(B, r, 2).sum(axis=0), B @ r, rtol=1e-10)
    np.testing.assert_allclose(prewhitened_scores(B, r, 0), (B * r).T)
    cases = {"white": (0.0, 0.0), "oscillation": (1.8 * np.cos(2 * np.pi / 7), -0.81),
             "low-pass": (0.7, 0.0), "low-pass 2": (1.2, -0.3)}
    for name, (a1, a2) in cases.items():
        sums, pw, plain = [], [], []
        for _ in range(1500):
            r = _ar2(rng, T, a1, a2)
            sums.append(B @ r)
            pw.append(np.diag(hac_meat(prewhitened_scores(B, r, 2), L, "parzen")))
            plain.append(np.diag(hac_meat((B * r).T, L, "parzen")))
        true = np.var(np.array(sums), axis=0)
        ratio = np.mean(pw, axis=0) / true
        assert np.all((ratio > 0.8) & (ratio < 1.2)), (name, ratio)
        if name != "white":
            off = np.abs(np.mean(plain, axis=0) / true - 1.0)
            assert np.all(off > 0.2), (name, off)


def test_whitening_filter_is_the_autoregression_impulse_response():
    """The filter matrix of :func:`whitening` applies h_k to B_{s+k} with h the impulse
    response of the fitted AR(2) (h_0 = 1, h_t = a_1 h_{t-1} + a_2 h_{t-2}), and the
    innovations u rebuild r through it; a whitening passed in gives the scores computed
    from r."""
    from gprm.fit.sandwich import ar_coefficients, prewhitened_scores, whitening

    rng = np.random.default_rng(5)
    T = 40
    r = _ar2(rng, T, 1.2, -0.3)
    B = rng.standard_normal((3, T))
    a = ar_coefficients(r, 2)
    w = whitening(r, 2)
    h = np.zeros(T)
    h[0] = 1.0
    h[1] = a[0]
    for t in range(2, T):
        h[t] = a[0] * h[t - 1] + a[1] * h[t - 2]
    filtered = np.stack([[sum(h[k] * B[p, s + k] for k in range(T - s)) for s in range(T)]
                         for p in range(3)])
    np.testing.assert_allclose(B @ w.H, filtered, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.convolve(h, w.u)[:T], r, rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(prewhitened_scores(B, r, 2, w), prewhitened_scores(B, r, 2))
    assert whitening(r, 0) is None


def test_ljung_box_matches_statsmodels():
    from statsmodels.stats.diagnostic import acorr_ljungbox

    rng = np.random.default_rng(2)
    x = rng.standard_normal(47)
    x[1:] += 0.4 * x[:-1]
    for lags in (1, 5, 9):
        q, p = ljung_box(x, lags)
        ref = acorr_ljungbox(x, lags=[lags])
        assert q == pytest.approx(float(ref["lb_stat"].iloc[0]), rel=1e-10)
        assert p == pytest.approx(float(ref["lb_pvalue"].iloc[0]), rel=1e-8)


def _ar1(rng, shape, phi):
    e = rng.standard_normal(shape)
    for t in range(1, shape[-1]):
        e[..., t] = phi * e[..., t - 1] + np.sqrt(1 - phi ** 2) * e[..., t]
    return e


def _linear_problem(rng, S=3, T=40, P=4):
    t = np.linspace(0, 1, T)
    X = np.stack([np.stack([np.sin((k + 1) * (s + 1) * t) + 0.3 * k for k in range(P)], 1)
                  for s in range(S)])                          # (S, T, P)
    return X, X.reshape(S * T, P)


def test_run_based_covariance_gives_the_exact_t_pivot_with_correlated_run_errors():
    """Each 'campaign': R = 10 runs per signal, each the truth plus AR(1) errors (phi 0.8,
    correlated in time), the mean fitted with known weights. The run-based sandwich is then
    the unbiased sample covariance of the estimate, so (est - truth) / sd follows Student's t
    with R - 1 degrees of freedom: its coverage of the normal 95 % / 68 % quantiles is
    P(|t_9| < z), checked to the binomial range. Eq. 7 with white residuals is far off."""
    from scipy.stats import t as student

    rng = np.random.default_rng(3)
    X, _ = _linear_problem(rng)
    S, T, P = X.shape
    theta = np.array([1.0, -0.5, 0.3, 2.0])
    n_rep, R = 500, 10
    zs = {0.95: 1.959964, 0.68: 0.994458}
    hits = {L: 0 for L in zs}
    hits_eq7 = 0
    sig = 0.1 / np.sqrt(R)                                  # the mean's error sd per sample
    Jw = (X / sig).reshape(S * T, P)
    H = Jw.T @ Jw
    Bs = np.linalg.solve(H, Jw.T).reshape(P, S, T)
    for _ in range(n_rep):
        runs = (X @ theta)[:, None, :] + 0.1 * _ar1(rng, (S, R, T), 0.8)
        mean = runs.mean(axis=1)
        est = np.linalg.solve(H, Jw.T @ (mean / sig).reshape(-1))
        r = (mean / sig) - (X @ est) / sig
        dev = (runs - mean[:, None, :]) / sig
        V_runs, V_res, V = statistical_covariance(Bs, r, dev, T // 4, float(P))
        sd = np.sqrt(np.diag(V_runs))
        for L, z in zs.items():
            hits[L] += int(np.sum(np.abs(est - theta) <= z * sd))
        hits_eq7 += int(np.sum(np.abs(est - theta) <= 1.959964 * np.sqrt(np.diag(
            np.linalg.inv(H)) * float(np.sum(r * r)) / (S * T - P))))
        # the combined estimate is at least as large as each of its parts
        assert np.all(np.linalg.eigvalsh(V - V_runs) > -1e-9 * np.abs(V).max())
        assert np.all(np.linalg.eigvalsh(V - V_res) > -1e-9 * np.abs(V).max())
    n = n_rep * P
    for L, z in zs.items():
        expected = 1 - 2 * student.sf(z, R - 1)
        lo, hi = _binomial_range(expected, n)
        assert lo <= hits[L] / n <= hi, (L, hits[L] / n, expected)
    assert hits_eq7 / n < 0.85          # white-residual Eq. 7 under-covers here


def test_residual_hac_matches_statsmodels_for_one_signal():
    """Without runs and without a prior, the residual part is the Newey-West covariance with
    the small-sample factor N / (N - P): statsmodels' HAC with use_correction."""
    import statsmodels.api as sm

    rng = np.random.default_rng(4)
    T = 80
    X = np.column_stack([np.ones(T), np.linspace(0, 1, T), np.sin(np.linspace(0, 6, T))])
    y = X @ [1.0, 2.0, 3.0] + _ar1(rng, (T,), 0.5)
    ols = sm.OLS(y, X).fit()
    Bs = np.linalg.solve(X.T @ X, X.T).reshape(3, 1, T)
    for lags in (2, 5, 20):
        runs_part, V_res, V = statistical_covariance(Bs, ols.resid.reshape(1, T), None, lags,
                                                     3.0, kernel="bartlett", prewhiten=0)
        ref = ols.get_robustcov_results("HAC", maxlags=lags, use_correction=True)
        assert runs_part is None and V is V_res
        np.testing.assert_allclose(V_res, ref.cov_params(), rtol=1e-10)


def test_gain_error_estimate_is_unbiased_in_the_variance():
    """Data = signals with independent gain errors of sd 2 % plus white noise, part of the
    signals' shapes shared with the parameters: the method-of-moments variance estimate
    (before its clip at 0) averages to the true variance, and to 0 without gain errors."""
    rng = np.random.default_rng(5)
    S, T = 5, 50
    t = np.linspace(0, 1, T)
    y = np.stack([np.sin(2 * np.pi * (s + 1) * t) * (3 + s) + 10 * t for s in range(S)])
    Ju = np.zeros((S * T, 2))
    Ju[:, 0] = 10 * np.tile(t, S)                 # a common ramp the model fits
    Ju[:, 1] = np.concatenate([np.sin(2 * np.pi * t)] + [np.zeros(T)] * (S - 1))
    Hinv = np.linalg.inv(Ju.T @ Ju)
    sigma = np.ones((S, T))
    for g_true in (0.02, 0.0):
        v = []
        for _ in range(400):
            g = g_true * rng.standard_normal(S)
            data = y * (1 + g[:, None]) + rng.standard_normal((S, T))
            r = data.reshape(-1) - y.reshape(-1)
            r = r - Ju @ (Hinv @ (Ju.T @ r))
            v.append(gain_variance(Ju, Hinv, r.reshape(S, T), y, sigma, None))
            # the sd the sandwich uses: the square root of the estimate clipped at 0
            assert gain_moments(Ju, Hinv, r.reshape(S, T), y, sigma, None).sd == \
                pytest.approx(np.sqrt(max(v[-1], 0.0)))
        # the mean of 400 estimates within four of its standard errors of the truth
        se = float(np.std(v)) / np.sqrt(len(v))
        assert abs(float(np.mean(v)) - g_true ** 2) < 4 * se, (np.mean(v), g_true ** 2, se)


def test_gain_estimate_null_sd_is_its_spread_without_gain_errors():
    """gain_moments' null_sd against a Monte Carlo: without gain errors the estimate's
    spread over 400 replicates is the null sd it reports (from the runs' spread, and from
    the exact unit weights without runs), so z is about N(0, 1); with gain errors of sd 10 %
    (a gain projection about 4 times its noise here) z is large. The sd of 400 draws' sd is 3.5 % of it: 15 % is four of those."""
    rng = np.random.default_rng(6)
    S, T, n_runs = 5, 50, 10
    t = np.linspace(0, 1, T)
    y = np.stack([np.sin(2 * np.pi * (s + 1) * t) * (3 + s) + 10 * t for s in range(S)])
    Ju = np.zeros((S * T, 2))
    Ju[:, 0] = 10 * np.tile(t, S)
    Ju[:, 1] = np.concatenate([np.sin(2 * np.pi * t)] + [np.zeros(T)] * (S - 1))
    Hinv = np.linalg.inv(Ju.T @ Ju)
    for with_runs in (True, False):
        for g_true in (0.0, 0.1):
            v, null, z = [], [], []
            for _ in range(400):
                g = g_true * rng.standard_normal(S)
                if with_runs:
                    runs = y[:, None, :] * (1 + g[:, None, None]) + \
                        np.sqrt(n_runs) * rng.standard_normal((S, n_runs, T))
                    data, sigma = runs.mean(axis=1), np.ones((S, T))
                else:
                    runs, data, sigma = None, y * (1 + g[:, None]) + \
                        rng.standard_normal((S, T)), np.ones((S, T))
                r = data.reshape(-1) - y.reshape(-1)
                r = r - Ju @ (Hinv @ (Ju.T @ r))
                gm = gain_moments(Ju, Hinv, r.reshape(S, T), y, sigma, runs)
                assert gm.variance == pytest.approx(
                    gain_variance(Ju, Hinv, r.reshape(S, T), y, sigma, runs))
                v.append(gm.variance)
                null.append(gm.null_sd)
                z.append(gm.z)
            if g_true == 0.0:
                ratio = float(np.std(v)) / float(np.mean(null))
                assert abs(ratio - 1.0) < 0.15, (with_runs, ratio)
                assert abs(float(np.mean(z))) < 4 * float(np.std(z)) / 20
            else:
                assert float(np.median(z)) > 4.0, (with_runs, np.median(z))


def test_systematics_are_read_from_the_parameter_file(tmp_path):
    p = tmp_path / "p.toml"
    p.write_text('[parameters]\n[systematics]\ngain = "0.5 %"\ntiming = "0.2 us"\n'
                 '[systematics.z_bk]\ngain = 0.01\n')
    d = read_systematics(p)
    assert d["gain_sd"] == pytest.approx(0.005) and d["timing_sd"] == pytest.approx(2e-7)
    assert d["per_signal"] == {"z_bk": (0.01, None)}
    from gprm.fit.api import FitOptions

    s = FitOptions().systematics(d)
    assert s.for_signal("z_bk") == pytest.approx((0.01, 2e-7))
    assert s.for_signal("x_base") == pytest.approx((0.005, 2e-7))
    # an option given on the command line wins over the file
    assert FitOptions(gain_sd=0.002).systematics(d).for_signal("x_head")[0] == 0.002


@pytest.mark.parametrize("text, field", [
    ('[systematics]\ngian = "1 %"\n', "systematics.gian"),
    ('[systematics]\ngain = "1 mm"\n', "systematics.gain"),
    ('[systematics]\ntiming = "-1 us"\n', "systematics.timing"),
    ('[systematics.x_base]\noffset = 1\n', "systematics.x_base"),
])
def test_bad_systematics_name_the_field(tmp_path, text, field):
    p = tmp_path / "p.toml"
    p.write_text("[parameters]\n" + text)
    with pytest.raises(GprmInputError) as exc:
        read_systematics(p)
    assert exc.value.field == field and exc.value.source == str(p)
    if "gian" in text:
        assert "did you mean 'gain'" in str(exc.value)


def test_systematics_refuse_negative_values():
    with pytest.raises(GprmInputError):
        Systematics(gain_sd=-0.1)


def test_a_default_fit_never_loads_the_synthetic_generator(tmp_path):
    """The structure of issue 21: the default fit path imports neither gprm.campaign.synth
    nor the opt-in method that uses it (checked in a fresh interpreter)."""
    from gprm.params import paper
    sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
    from means_factory import make_means

    ds = make_means(paper(), seed=1, rel=0.0)
    ds.attrs.pop("truth_json")
    path = tmp_path / "means.nc"
    ds.to_netcdf(path)
    code = (
        "import sys\n"
        "from gprm.fit.api import FitOptions, run_fit\n"
        f"res = run_fit({str(path)!r}, FitOptions(starts=2, max_iter=3, band_samples=0))\n"
        "assert res.uncertainty.method == 'sandwich'\n"
        "bad = [m for m in ('gprm.campaign.synth', 'gprm.fit.bootstrap', "
        "'gprm.fit.calibration') if m in sys.modules]\n"
        "print('loaded:', bad)\n"
        "sys.exit(1 if bad else 0)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr


class _Quartic:
    """A stand-in objective in physical = normalised coordinates: phi = a x0^2 + b x1^2 +
    c x0^4 (quadratic for c = 0, steeper with c > 0, flatter with c < 0 near the edges)."""

    def __init__(self, a, b, c):
        self.a, self.b, self.c = a, b, c

    def bounds(self):
        return np.array([-np.inf, -np.inf]), np.array([np.inf, np.inf])

    def to_normalised(self, X):
        return np.asarray(X, float)

    def chi2(self, X):
        X = np.atleast_2d(X)
        return self.a * X[:, 0] ** 2 + self.b * X[:, 1] ** 2 + self.c * X[:, 0] ** 4


def _flat_prior():
    from gprm.fit.prior import Prior

    return Prior(("p", "q"), np.zeros(2), np.array([1e6, 1e6]), np.array([False, False]), 0.0)


def test_shape_factors_leave_a_quadratic_objective_alone_and_widen_a_flat_one():
    from gprm.fit.sandwich import shape_factors

    prior = _flat_prior()
    Ju = np.diag([np.sqrt(4.0), np.sqrt(9.0)])            # H = J^T J = diag(4, 9)
    Cu = np.linalg.inv(Ju.T @ Ju)
    lo, hi = shape_factors(_Quartic(4.0, 9.0, 0.0), np.zeros(2), Cu, Ju, prior)
    np.testing.assert_allclose(lo, 1.0, atol=1e-9)
    np.testing.assert_allclose(hi, 1.0, atol=1e-9)
    # steeper than quadratic: never narrowed
    lo, hi = shape_factors(_Quartic(4.0, 9.0, 5.0), np.zeros(2), Cu, Ju, prior)
    np.testing.assert_allclose([lo, hi], 1.0, atol=1e-9)
    # flatter: phi = 4 x^2 - x^4 / 4 rises to the quadratic's 2-sd value (4 H sd^2 = 4) at
    # the x where 4 x^2 - x^4 / 4 = 4, i.e. x^2 = 8 - sqrt(48); sd = 1/2, so the factor is
    # x / (2 sd) = x; interpolated between the sampled steps it is close to that
    lo, hi = shape_factors(_Quartic(4.0, 9.0, -0.25), np.zeros(2), Cu, Ju, prior)
    expected = np.sqrt(8 - np.sqrt(48))
    assert lo[0] == pytest.approx(expected, rel=0.05) and hi[0] == pytest.approx(expected, rel=0.05)
    assert lo[1] == pytest.approx(1.0) and hi[1] == pytest.approx(1.0)


class _Squared:
    """A stand-in objective with one signal y(t) = theta^2 g(t) (weights 1): the data's
    sensitivity to theta, 2 theta g, grows with theta, so the estimator's spread at a value
    theta is sd0 theta^ / theta (sd0 its spread at the best fit theta^)."""

    def __init__(self, T=40):
        from types import SimpleNamespace
        t = np.linspace(0.0, 1.0, T)
        self.g = np.sin(3 * t) + t
        self.data = SimpleNamespace(values=np.zeros((1, T)), sigma=np.ones((1, T)), time=t,
                                    signals=("s",), interpolation_error=None, runs=None)

    def bounds(self):
        return np.array([1e-9]), np.array([np.inf])

    def model(self, X, *, jacobian=False):
        from types import SimpleNamespace
        th = np.atleast_2d(X)[:, 0]
        y = (th[:, None] ** 2 * self.g[None])[:, None, :]
        dy = (2 * th[:, None] * self.g[None])[:, None, :, None]
        return SimpleNamespace(y=y, dy=dy if jacobian else None)


class _Linear(_Squared):
    """y(t) = theta g(t): the sensitivity g does not depend on theta."""

    def model(self, X, *, jacobian=False):
        from types import SimpleNamespace
        th = np.atleast_2d(X)[:, 0]
        y = (th[:, None] * self.g[None])[:, None, :]
        dy = np.broadcast_to(self.g[None, None, :, None], (th.size, 1, self.g.size, 1))
        return SimpleNamespace(y=y, dy=dy if jacobian else None)


def test_variance_factors_solve_the_score_interval_where_sensitivity_changes():
    """On y = theta^2 g with unit white error the value theta below theta^ is compatible when
    theta^ - theta = z sd0 theta^ / theta: alpha = (theta^ - sqrt(theta^2 - 4 sd0 z theta^)) /
    (2 sd0) in units of sd0. The upper side, where the spread shrinks, is not narrowed."""
    from gprm.fit.prior import Prior
    from gprm.fit.sandwich import ErrorModel, propagate, variance_factors

    obj = _Squared()
    T = obj.data.time.size
    prior = Prior(("theta",), np.zeros(1), np.array([1e9]), np.array([False]), 0.0)
    dev = np.sqrt(T * (T - 1.0)) * np.eye(T)[None]            # runs whose covariance is I
    err = ErrorModel(np.zeros((1, T)), dev, np.zeros(1), np.zeros(1), np.zeros(1), 0.0, 1.0,
                     4)
    th = 2.0
    x = np.array([th])
    J = -obj.model(x, jacobian=True).dy[0].reshape(T, 1)
    Cu = propagate(obj, x, J, prior, err).total
    sd0 = float(np.sqrt(Cu[0, 0]))
    assert sd0 == pytest.approx(1.0 / (2 * th * np.linalg.norm(obj.g)), rel=1e-9)
    obj.g = obj.g / (np.linalg.norm(obj.g) * 2 * th * 0.1 * th)   # sd0 = theta^ / 10
    J = -obj.model(x, jacobian=True).dy[0].reshape(T, 1)
    Cu = propagate(obj, x, J, prior, err).total
    sd0 = float(np.sqrt(Cu[0, 0]))
    assert sd0 == pytest.approx(0.1 * th, rel=1e-9)
    for z in (1.0, 1.96):
        lo, hi = variance_factors(obj, x, Cu, prior, err, z, iterations=50, tol=1e-9)
        alpha = (th - np.sqrt(th ** 2 - 4 * sd0 * z * th)) / (2 * sd0)
        assert lo[0] * z == pytest.approx(alpha, rel=1e-3)
        assert hi[0] == 1.0
    # with constant sensitivity (y = theta g) nothing is stretched
    lin = _Linear()
    J = -lin.model(x, jacobian=True).dy[0].reshape(T, 1)
    Cu = propagate(lin, x, J, prior, err).total
    lo, hi = variance_factors(lin, x, Cu, prior, err, 1.96)
    assert lo[0] == pytest.approx(1.0) and hi[0] == pytest.approx(1.0)


def test_crossing_offsets_find_a_model_onset_moved_from_the_datas():
    """Data aligned so that their 2-sigma crossing is at align_time; a model whose crossing
    comes delta later gives the offset -delta (the shift the alignment rule would give it),
    on a 200 kHz grid and to well under a sample; zero for the model that crosses there."""
    from types import SimpleNamespace

    from gprm.fit.sandwich import crossing_offsets

    rate, t_a, noise = 200e3, 1.01e-3, 5e-10
    t = np.arange(194, 241) / rate
    thr = 2.0 * noise
    amp, width = 1e-7, 20e-6                               # a smooth onset (4 samples wide)

    def onset_ramp(t_cross):
        t_mid = t_cross - width * np.arctanh(2 * thr / amp - 1)
        return amp * (1 + np.tanh((t - t_mid) / width)) / 2

    data = SimpleNamespace(signals=("a", "b"), time=t, noise_std=np.array([noise, noise]),
                           attrs={"align_time": t_a, "threshold_factor": 2.0, "hold": 1})
    obj = SimpleNamespace(data=data)
    for delta in (0.0, 1.3e-6, -2.2e-6):
        y = np.stack([onset_ramp(t_a + delta), onset_ramp(t_a)])
        off = crossing_offsets(obj, y)
        assert off[0] == pytest.approx(-delta, abs=0.02 / rate)
        assert off[1] == pytest.approx(0.0, abs=0.02 / rate)
    # data moved by whole samples put their crossing at crossing_time, off align_time by a
    # fraction of a sample: a model crossing there has no offset, one at align_time has
    # the difference
    data.crossing_time = np.array([t_a + 2.1e-6, t_a - 1.7e-6])
    y = np.stack([onset_ramp(t_a + 2.1e-6), onset_ramp(t_a)])
    off = crossing_offsets(obj, y)
    assert off[0] == pytest.approx(0.0, abs=0.02 / rate)
    assert off[1] == pytest.approx(-1.7e-6, abs=0.02 / rate)
    # without the rule's attributes nothing is claimed
    data.attrs = {}
    np.testing.assert_array_equal(crossing_offsets(obj, y), 0.0)


def test_stretched_draws_reproduce_both_levels_intervals():
    """The draws behind the prediction bands: each parameter's empirical 16/84 and 2.5/97.5 %
    points land on the reported 68 % and 95 % interval ends, each side and level with its
    own stretch (a single 95 % stretch would put the 84th percentile at z68 f95 instead),
    the map keeps every draw's rank, and draws that need no stretch are left alone."""
    from scipy.special import ndtri

    rng = np.random.default_rng(3)
    n, P = 200_000, 4
    A = rng.standard_normal((P, P))
    C = A @ A.T + P * np.eye(P)
    sd = np.sqrt(np.diag(C))
    Z = rng.multivariate_normal(np.zeros(P), C, size=n)
    z68, z95 = ndtri(0.84), ndtri(0.975)
    f68 = (np.array([1.0, 1.3, 1.0, 2.5]), np.array([1.0, 1.1, 1.6, 1.0]))
    f95 = (np.array([1.0, 1.8, 1.2, 1.2]), np.array([1.0, 1.1, 1.4, 1.2]))
    assert z95 * f95[0][3] < z68 * f68[0][3]       # the 4th lower side exercises the raise
    W = stretch_draws(Z, sd, f68, f95, (z68, z95))
    q = np.quantile(W, [0.025, 0.16, 0.84, 0.975], axis=0) / sd
    # binomial error of a quantile of 200000 draws: about 0.01 sd at these levels
    np.testing.assert_allclose(q[1], -z68 * f68[0], atol=0.02)
    np.testing.assert_allclose(q[2], z68 * f68[1], atol=0.02)
    # the 95 % knot is raised to the 68 % one where it would fall below it (4th, lower)
    np.testing.assert_allclose(q[0], -np.maximum(z95 * f95[0], z68 * f68[0]), atol=0.03)
    np.testing.assert_allclose(q[3], z95 * f95[1], atol=0.03)
    for k in range(P):
        assert np.all(np.diff(W[np.argsort(Z[:, k]), k]) >= 0)
    np.testing.assert_allclose(W[:, 0], Z[:, 0], rtol=1e-12, atol=0)


def test_whitened_stretch_keeps_tight_combinations_tight():
    """The draws stretched through the correlation's symmetric root (Systematics.draws_stretch
    "whitened"): with every factor 1 they are the Gaussian's; with one factor per parameter
    (the same at both levels, so the map is linear) their covariance is S R^(1/2) F^2
    R^(1/2) S, between f_min^2 and f_max^2 times the Gaussian's for every combination of the
    parameters; an uncorrelated parameter keeps its interval exactly. The per-coordinate
    map stretches a combination that two correlated parameters hold tight by far more than
    any factor: the failure this stretch exists to avoid."""
    from scipy.special import ndtri

    from gprm.fit.covariance import symmetric_root

    rng = np.random.default_rng(11)
    n, P = 200_000, 4
    sd = np.array([2.0, 1e-3, 5.0, 0.3])
    R = np.eye(P)
    R[0, 1] = R[1, 0] = 0.999           # parameters 0 and 1 the data hold in a tight pair
    R[0, 2] = R[2, 0] = -0.4
    R[1, 2] = R[2, 1] = -0.4            # parameter 3 uncorrelated
    C = R * np.outer(sd, sd)
    s, Rh = symmetric_root(C)
    np.testing.assert_allclose(s, sd, rtol=1e-12)
    np.testing.assert_allclose(Rh @ Rh, R, atol=1e-10)
    np.testing.assert_allclose(Rh, Rh.T, atol=1e-12)
    z = (ndtri(0.84), ndtri(0.975))
    E = rng.standard_normal((n, P))
    one = (np.ones(P), np.ones(P))
    W1 = stretch_whitened(E, sd, Rh, one, one, z)
    np.testing.assert_allclose(np.cov(W1.T) / np.outer(sd, sd), R, atol=0.01)
    f = np.array([1.0, 2.0, 1.3, 1.7])
    ff = (f, f)
    W = stretch_whitened(E, sd, Rh, ff, ff, z)
    C_w = (Rh * f ** 2) @ Rh * np.outer(sd, sd)
    np.testing.assert_allclose(np.cov(W.T) / np.outer(sd, sd), C_w / np.outer(sd, sd),
                               atol=0.02)
    # every combination between the smallest and the largest factor (in the matrix sense)
    Ci = np.linalg.inv(np.linalg.cholesky(C))
    ev = np.linalg.eigvalsh(Ci @ C_w @ Ci.T)
    assert ev.min() >= f.min() ** 2 * (1 - 1e-9) and ev.max() <= f.max() ** 2 * (1 + 1e-9)
    # the uncorrelated parameter's quantiles are its interval's ends
    q = np.quantile(W[:, 3], [0.16, 0.84]) / sd[3]
    np.testing.assert_allclose(q, [-z[0] * f[3], z[0] * f[3]], atol=0.02)
    # the tight pair's combination: the coordinates' map loosens it, the whitened one not
    a = np.array([1 / sd[0], -1 / sd[1], 0.0, 0.0])
    v0 = a @ C @ a
    W_coord = stretch_draws(E @ np.linalg.cholesky(C).T, sd, ff, ff, z)
    assert np.var(W_coord @ a) > 10 * f.max() ** 2 * v0
    assert f.min() ** 2 * v0 * 0.95 <= np.var(W @ a) <= f.max() ** 2 * v0 * 1.05
    # whitened for some parameters only: the others are the plain draw mapped coordinate by
    # coordinate, and their factors (here a large one) stay out of the whitened ones
    big = (np.array([1.0, 2.0, 6.0, 1.7]),) * 2
    mask = np.array([True, True, False, True])
    Wm = stretch_whitened(E, sd, Rh, big, big, z, whiten=mask)
    plain = E @ Rh.T * sd
    np.testing.assert_allclose(Wm[:, 2], stretch_draws(plain, sd, big, big, z)[:, 2],
                               rtol=1e-12)
    Wf = stretch_whitened(E, sd, Rh, (np.where(mask, big[0], 1.0),) * 2,
                          (np.where(mask, big[0], 1.0),) * 2, z)
    np.testing.assert_allclose(Wm[:, mask], Wf[:, mask], rtol=1e-12)


def test_timing_error_moves_only_the_lags_it_is_absorbed_by():
    """Every signal is the response at t - t0, so a timing error of a signal is exactly a
    change of its fitted lag: propagated through the estimator it must land on the lags and
    nowhere else. The sandwich's time derivative is the model's own (equal to a central
    difference in t0, with or without t0 fitted); a finite difference on the data's grid is
    visibly short of it, and with it a stated timing error would reach the physical
    parameters."""
    from gprm.fit.prior import default_prior
    from gprm.fit.sandwich import error_model, propagate, time_derivative
    from gprm.fit.objective import Objective, fit_data_from_means
    from gprm.params import ALIGNMENT_OFFSETS, LAG_PARAMETERS, paper
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).parent))
    from means_factory import make_means

    p = paper()
    p = p.with_fitted(tuple(p.fitted) + tuple(ALIGNMENT_OFFSETS.values()))   # gprm fit's set
    data = fit_data_from_means(make_means(p, seed=3), source="synthetic")
    obj = Objective.create(data, p)
    names = list(obj.names)
    assert "t0" in names
    x = p.vector(obj.names)
    k = names.index("t0")
    J = -obj.model(x[None], jacobian=True).dy[0].reshape(-1, x.size) / data.sigma.reshape(-1, 1)
    dydt = time_derivative(obj, x, J, None)
    h = 1e-10

    def shifted(dt):
        xx = x.copy()
        xx[k] += dt
        return obj.model(xx[None]).y[0]

    central = (shifted(-h) - shifted(h)) / (2 * h)
    scale = np.abs(central).max()
    assert np.abs(dydt - central).max() < 1e-5 * scale
    y = obj.model(x[None]).y[0]
    assert np.abs(np.gradient(y, data.time, axis=1) - central).max() > 1e-2 * scale
    # t0 held fixed: the model is asked for it
    rest = [n for n in names if n != "t0"]
    obj2 = Objective.create(data, p, rest)
    x2 = p.vector(obj2.names)
    J2 = np.delete(J, k, axis=1)
    assert np.abs(time_derivative(obj2, x2, J2, None) - central).max() < 1e-5 * scale

    prior = default_prior(p, obj.names)
    r = ((data.values - y) / data.sigma).reshape(-1)
    stated = error_model(obj, x, J, r, prior, Systematics(timing_sd=1e-6, estimate_gain=False))
    V = propagate(obj, x, J, prior, stated)
    lags = np.array([n in LAG_PARAMETERS for n in names])
    sd_time = np.sqrt(np.diag(V.timing))
    sd_stat = np.sqrt(np.diag(V.statistical))
    # 1 us of timing error on every channel, ~100 times the statistical sd of the lags: the
    # lags move by that much, a physical parameter by nothing its interval would notice
    assert np.all(sd_time[lags] > 10 * sd_stat[lags])
    assert np.all(sd_time[~lags] < 1e-2 * sd_stat[~lags])


def _at_paper(data, names):
    """(obj, x, y, J, r, prior) of the paper set on ``data``: the objective over ``names``,
    the model there, the weighted residuals' Jacobian and values, the default prior."""
    from gprm.fit.objective import Objective
    from gprm.fit.prior import default_prior
    from gprm.params import paper

    p = paper()
    obj = Objective.create(data, p, names)
    x = p.vector(obj.names)
    y = obj.model(x[None]).y[0]
    J = -obj.model(x[None], jacobian=True).dy[0].reshape(-1, x.size) / \
        data.sigma.reshape(-1, 1)
    r = ((data.values - y) / data.sigma).reshape(-1)
    return obj, x, y, J, r, default_prior(p, obj.names)


def test_alignment_noise_joins_only_the_signals_whose_own_lag_is_held_fixed():
    """A fitted lag absorbs its signal's alignment noise exactly (the data and its place in
    the aligned axis move together), so by default ("fixed-lags") a signal's timing error is
    the stated one alone where its own lag is fitted, and the stated one combined with its
    alignment noise (the mean's noise at the alignment time over its slope) where it is held
    fixed; "all" (stop 39's default) adds it everywhere, "none" nowhere."""
    from dataclasses import replace

    from gprm.fit.api import FitOptions
    from gprm.fit.objective import fit_data_from_means
    from gprm.fit.sandwich import error_model, own_lag, propagate
    from gprm.params import paper
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).parent))
    from means_factory import make_means

    p = paper()
    data = fit_data_from_means(make_means(p, seed=3), source="synthetic")
    data = replace(data, attrs={**data.attrs, "align_time": 1.01e-3})
    assert [own_lag(s) for s in data.signals] == ["t0", "dt_x_head", "dt_y_base",
                                                   "dt_y_head", "t1"]
    stated = 2e-8

    def parts(names, mode):
        obj, x, y, J, r, prior = _at_paper(data, names)
        err = error_model(obj, x, J, r, prior, Systematics(timing_sd=stated,
                                                           estimate_gain=False,
                                                           alignment_noise=mode))
        return obj, err, propagate(obj, x, J, prior, err, y)

    every = tuple(FitOptions().parameters(p).fitted)       # the CLI's: the offsets fitted
    assert {"t0", "t1", "dt_x_head", "dt_y_base", "dt_y_head"} <= set(every)
    _, on, _ = parts(every, "fixed-lags")
    assert np.all(on.alignment_sd > 0)
    np.testing.assert_array_equal(on.timing_sd, stated)
    _, al, _ = parts(every, "all")
    np.testing.assert_allclose(al.timing_sd, np.hypot(stated, al.alignment_sd))
    _, no, _ = parts(every, "none")
    np.testing.assert_array_equal(no.timing_sd, stated)
    np.testing.assert_array_equal(no.alignment_sd, on.alignment_sd)
    # dt_x_head held fixed: x_head's alignment noise joins its timing error, no other's
    held = tuple(n for n in every if n != "dt_x_head")
    obj, fx, V = parts(held, "fixed-lags")
    k = list(data.signals).index("x_head")
    want = np.full(len(data.signals), float(stated))
    want[k] = np.hypot(stated, fx.alignment_sd[k])
    np.testing.assert_allclose(fx.timing_sd, want)
    # and it widens t0, now x_head's only lag
    _, _, V0 = parts(held, "none")
    i0 = list(obj.names).index("t0")
    assert V.timing[i0, i0] > 1.5 * V0.timing[i0, i0]
    with pytest.raises(GprmInputError, match="alignment_noise"):
        Systematics(alignment_noise="yes")


def test_the_synchronisations_timing_joins_every_signals_timing_error():
    """FitData.sync_timing_sd (the time shift the synchronisation takes out of the runs'
    spread but leaves in their mean, gprm.campaign.preprocess.sync_timing_sd) adds to each
    signal's timing error in quadrature, whether its lag is fitted or not; it widens the
    lags and leaves the physical parameters' variance as it was; Systematics(sync_timing=
    False) and files without it leave the timing error the stated one."""
    from dataclasses import replace

    from gprm.fit.api import FitOptions
    from gprm.fit.objective import Objective, fit_data_from_means
    from gprm.fit.sandwich import error_model, propagate
    from gprm.params import LAG_PARAMETERS, paper
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).parent))
    from means_factory import make_means

    p = paper()
    data = fit_data_from_means(make_means(p, seed=3), source="synthetic")
    data = replace(data, attrs={**data.attrs, "align_time": 1.01e-3})
    assert data.sync_timing_sd is None
    sync = np.array([6e-9, 5e-9, 12e-9, 7e-9, 2e-10])
    stated = 2e-9
    names = tuple(FitOptions().parameters(p).fitted)
    obj, x, y, J, r, prior = _at_paper(replace(data, sync_timing_sd=sync), names)

    def err(**kw):
        return error_model(obj, x, J, r, prior, Systematics(timing_sd=stated,
                                                            estimate_gain=False, **kw))

    on, off = err(), err(sync_timing=False)
    np.testing.assert_allclose(on.timing_sd, np.hypot(stated, sync))
    np.testing.assert_array_equal(off.timing_sd, stated)
    V_on, V_off = (propagate(obj, x, J, prior, e, y) for e in (on, off))
    lags = np.array([n in LAG_PARAMETERS for n in obj.names])
    t_on, t_off = np.diag(V_on.timing), np.diag(V_off.timing)
    assert np.all(t_on[lags] > 4 * t_off[lags])
    stat = np.diag(V_on.statistical)
    assert np.all(t_on[~lags] < 1e-3 * stat[~lags])
    # a file without it: the stated timing only
    obj0 = Objective.create(data, p, names)
    e0 = error_model(obj0, x, J, r, prior, Systematics(timing_sd=stated, estimate_gain=False))
    np.testing.assert_array_equal(e0.timing_sd, stated)


def test_fisher_g_test_is_exact_on_white_noise_and_finds_an_oscillation():
    """Fisher's g of 47 white Gaussian samples (23 ordinates): the exact p-value's
    distribution is uniform (the fraction below 0.01, 0.05 and 0.5 within the binomial
    range of 20000 series), and a sinusoid of the noise's amplitude at a Fourier frequency
    gives p < 1e-4 with g its bin. An adequacy record written before the field reads back
    with it NaN."""
    from gprm.fit.adequacy import Adequacy, fisher_g

    rng = np.random.default_rng(8)
    n, trials = 47, 20000
    p = np.array([fisher_g(rng.standard_normal(n))[1] for _ in range(trials)])
    assert fisher_g(rng.standard_normal(n))[2] == 23
    for level in (0.01, 0.05, 0.5):
        lo, hi = _binomial_range(level, trials)
        assert lo <= np.mean(p < level) <= hi, (level, np.mean(p < level))
    t = np.arange(n)
    x = rng.standard_normal(n) + np.sqrt(2) * np.sin(2 * np.pi * 7 * t / n)
    g, pv, _ = fisher_g(x)
    assert pv < 1e-4
    ordinates = np.abs(np.fft.rfft(x - x.mean())[1:24]) ** 2
    assert np.argmax(ordinates) == 6 and g == pytest.approx(ordinates[6] / ordinates.sum())
    old = {"chi2": 50.0, "dof": 40.0, "p_value": 0.1, "verdict": "adequate", "reasons": [],
           "signals": [{"signal": "x_base", "chi2_per_sample": 1.0, "ljung_box_q": 3.0,
                        "ljung_box_p": 0.5, "lags": 9, "lag1_autocorrelation": 0.1,
                        "peak_frequency_hz": 5e3, "peak_share": 0.1, "loso_ratio": 1.1}]}
    a = Adequacy.from_json(old)
    assert np.isnan(a.signals[0].peak_p)
    assert "peak_p_fisher_g" in a.to_json()["signals"][0]


def test_alternative_minima_that_fit_as_well_widen_only_their_side():
    """Another minimum whose objective lies within the level's likelihood-ratio threshold of
    the best makes that level's interval the union of the best's and the same width around
    the other minimum, side by side; one above the threshold, or none, changes nothing."""
    from gprm.fit.sandwich import LR_THRESHOLD, alternative_factors

    u = np.array([0.0, 1.0, -2.0])
    sd = np.array([0.1, 0.2, 0.5])
    z = 1.96
    # the other minimum: parameter 0 three z-sds above, parameter 1 inside, parameter 2 below
    U = np.array([[3 * z * 0.1, 1.0 + 0.1, -2.0 - 2 * z * 0.5]])
    lo, hi = alternative_factors(u, sd, U, np.array([2.0]), z, LR_THRESHOLD[0.95])
    np.testing.assert_allclose(hi, [4.0, 1.0 + 0.1 / (z * 0.2), 1.0])
    np.testing.assert_allclose(lo, [1.0, 1.0, 3.0])
    # the same point at 68 %: D = 2 is above that level's threshold (0.99)
    lo, hi = alternative_factors(u, sd, U, np.array([2.0]), 1.0, LR_THRESHOLD[0.68])
    np.testing.assert_array_equal(np.concatenate([lo, hi]), 1.0)
    # none, or one that fits clearly worse
    for D in (np.zeros(0), np.array([50.0])):
        lo, hi = alternative_factors(u, sd, U[:D.size], D, z, LR_THRESHOLD[0.95])
        np.testing.assert_array_equal(np.concatenate([lo, hi]), 1.0)
    from scipy.stats import chi2
    # the levels' z^2: chi-square quantiles of 1 dof (68 % is the interval's z = ndtri(0.84))
    assert LR_THRESHOLD[0.95] == pytest.approx(chi2.ppf(0.95, 1))
    assert LR_THRESHOLD[0.68] == pytest.approx(chi2.ppf(0.68, 1), rel=1e-4)


def test_minima_apart_along_a_lag_are_told_apart_at_the_lags_scale():
    """The distinct minima's Mahalanobis distance is scale-free: two minima 3 ALT_SAME of a
    lag's sd apart along it (its variance ~1e-15 s^2 beside O(1) ones, as in the prior's
    coordinates) are distinct, and 0.5 ALT_SAME apart the same; the whitening of Cu itself
    (until stop 51) floored the lag's eigenvalue at 1e-14 of the largest and took them for
    one."""
    from gprm.fit.sandwich import ALT_SAME, _distinct_minima

    sd = np.array([1.0, 0.3, 3e-8])
    Rm = np.array([[1.0, 0.4, 0.2], [0.4, 1.0, -0.3], [0.2, -0.3, 1.0]])
    Cu = Rm * np.outer(sd, sd)
    u0 = np.array([0.5, -1.0, 4e-6])
    # an offset along the lag alone, of Mahalanobis length 1
    lag = np.array([0.0, 0.0, 1.0])
    step = lag / np.sqrt(lag @ np.linalg.solve(Cu, lag))
    for k, expect in ((3.0, [0]), (0.5, [])):
        U = (u0 + k * ALT_SAME * step)[None]
        np.testing.assert_array_equal(_distinct_minima(U, np.zeros(1), u0, Cu), expect)
    # Cu's own eigen-whitening with the floor: the 3 ALT_SAME offset shrinks about fourfold,
    # under ALT_SAME (docs/fitting.md, "The draws' factor")
    w, V = np.linalg.eigh(Cu)
    w = np.clip(w, np.max(np.abs(w)) * 1e-14, None)
    old = np.linalg.norm((3.0 * ALT_SAME * step) @ V / np.sqrt(w))
    assert 0.2 < old / (3.0 * ALT_SAME) < 0.3


def test_minima_nearer_than_alt_same_are_one_and_could_not_move_an_interval():
    """Two polished minima count as one where their Mahalanobis distance under the fit's
    covariance is at most ALT_SAME; kept or not, such a neighbour of the best moves no side
    of an interval by more than ALT_SAME / z, so dropping it loses nothing reported."""
    from gprm.fit.sandwich import (ALT_SAME, LR_THRESHOLD, _distinct_minima,
                                   alternative_factors)

    rng = np.random.default_rng(7)
    P = 5
    A = rng.standard_normal((P, P))
    Cu = A @ A.T + 0.1 * np.eye(P)
    L = np.linalg.cholesky(Cu)
    u0 = rng.standard_normal(P)

    def at(dist, base=u0):
        v = rng.standard_normal(P)
        return base + L @ (dist * v / np.linalg.norm(v))       # Mahalanobis ``dist`` away

    far = at(3.0)
    U = np.array([at(0.5 * ALT_SAME),          # the best's own basin: dropped
                  far,                         # another minimum: kept
                  at(0.5 * ALT_SAME, far),     # the same other minimum, higher: dropped
                  at(1.5)])                    # a third: kept
    D = np.array([0.0, 0.5, 0.6, 2.0])
    np.testing.assert_array_equal(_distinct_minima(U, D, u0, Cu), [1, 3])
    # the order is the rises', not the rows': the lower of the pair stands for it
    np.testing.assert_array_equal(_distinct_minima(U, np.array([0.0, 0.7, 0.6, 2.0]), u0, Cu),
                                  [2, 3])
    sd = np.sqrt(np.diag(Cu))
    for z, level in ((1.96, 0.95), (1.0, 0.68)):
        for _ in range(50):
            lo, hi = alternative_factors(u0, sd, at(ALT_SAME)[None], np.zeros(1), z,
                                         LR_THRESHOLD[level])
            assert max(lo.max(), hi.max()) <= 1.0 + ALT_SAME / z + 1e-12


def test_student_intervals_from_few_runs_hold_their_level():
    """A linear estimator from the mean of R = 3 runs of five signals with unequal noise:
    the runs' variance estimate has the Satterthwaite degrees of freedom (between R - 1 and
    S (R - 1)), and the interval with Student's quantile at those degrees holds the truth at
    its level where the normal quantile does not (Monte Carlo, 20 000 campaigns); the factor
    is SciPy's t over the normal quantile, 1 at infinite degrees."""
    from scipy.stats import t as student

    from gprm.fit.sandwich import satterthwaite, student_factors

    rng = np.random.default_rng(7)
    S, T, R, n = 5, 20, 3, 20000
    A = rng.standard_normal((S, T))
    B = A / np.sum(A * A)                            # the one-parameter least-squares row
    noise = np.array([3.0, 1.0, 0.5, 0.3, 0.2])      # unequal: fewer effective degrees
    runs = noise[None, :, None, None] * rng.standard_normal((n, S, R, T))
    est = np.einsum("st,nst->n", B, runs.mean(axis=2))
    dev = runs - runs.mean(axis=2, keepdims=True)
    v = np.einsum("st,nsrt->nsr", B, dev) ** 2
    v = v.sum(axis=2) / (R * (R - 1))                # (n, S): each signal's runs variance
    sd = np.sqrt(v.sum(axis=1))
    nu = np.array([satterthwaite(vi[:, None], R)[0] for vi in v[:2000]])
    assert np.all((nu >= R - 1 - 1e-9) & (nu <= S * (R - 1) + 1e-9))
    nu_all = np.concatenate([nu, [satterthwaite(vi[:, None], R)[0] for vi in v[2000:]]])
    lo, hi = _binomial_range(0.95, n)
    normal = np.mean(np.abs(est) <= 1.959964 * sd)
    t_cov = np.mean(np.abs(est) <= 1.959964 * student_factors(nu_all, 0.95) * sd)
    print(f"3 runs: normal quantile {100 * normal:.1f} %, Student's {100 * t_cov:.1f} %")
    assert normal < lo                               # the normal quantile under-covers
    assert lo - 0.01 <= t_cov <= hi + 0.01           # Student's holds its level
    np.testing.assert_allclose(student_factors(np.array([4.0, np.inf]), 0.95),
                               [student.ppf(0.975, 4) / 1.959964, 1.0], rtol=1e-6)
    # equal contributions: S (R - 1); one signal alone: R - 1
    np.testing.assert_allclose(satterthwaite(np.ones((S, 1)), R), [S * (R - 1)])
    np.testing.assert_allclose(satterthwaite(np.array([[1.0], [0], [0], [0], [0]]), R),
                               [R - 1])


@pytest.mark.parametrize("prewhiten,projected", [(False, False), (True, False), (True, True)])
def test_residual_dof_matches_the_kernel_estimates_moments(prewhiten, projected):
    """The residual kernel estimate of a linear fit of five signals (47 samples each, a
    weak prior) is a quadratic form in the data's error: its mean and variance under
    independent Gaussian errors are exact (residual_dof), so Satterthwaite's degrees of
    freedom 2 E^2 / Var must match those of the estimates computed by
    statistical_covariance on simulated errors (the same prewhitening filter held fixed;
    4000 draws: the sampled nu within 12 % of the formula's and the sampled mean within 5 %
    of residual_moments' mean, for every parameter; the target within 4.5 sampling sd of
    the sampled variance of the estimator's error); also with the residuals projected off
    orthonormal nuisance columns (an unmodelled resonance's, two per signal)."""
    from gprm.fit.sandwich import (Whitening, residual_dof, residual_moments,
                                   statistical_covariance, whitening)

    rng = np.random.default_rng(11)
    S, T, P = 5, 47, 6
    N = S * T
    Ju = rng.standard_normal((N, P)) * np.repeat(rng.uniform(0.3, 2.0, S), T)[:, None]
    Ju[: 2 * T, 0] *= 4.0                               # one parameter led by two signals
    Qp = None
    if projected:                           # two nuisance columns per signal, orthonormal
        t = np.arange(T)
        cols = []
        for s in range(S):
            for f in (np.sin, np.cos):
                c = np.zeros(N)
                c[s * T:(s + 1) * T] = np.exp(-t / 20.0) * f(2 * np.pi * t / 7.0)
                cols.append(c)
        Qp = np.linalg.qr(np.stack(cols, 1))[0]
        Ju = Ju - Qp @ (Qp.T @ Ju)            # the projected objective's Jacobian
    Hinv = np.linalg.inv(Ju.T @ Ju + np.diag(np.full(P, 0.5)))
    B = Hinv @ Ju.T
    Bs = B.reshape(P, S, T)
    M = np.eye(N) - Ju @ B - (0.0 if Qp is None else Qp @ Qp.T)
    sig = np.repeat(rng.uniform(0.5, 2.0, S), T)
    max_lag = T // 4
    p_eff = float(np.trace(Ju @ B)) + (0 if Qp is None else Qp.shape[1])
    if prewhiten:
        ar = rng.standard_normal(T + 2)                 # a fixed AR(2) filter per signal
        w = tuple(whitening(np.convolve(ar, [1.0, 0.6], "same")[:T] + 0.1 * s, 2)
                  for s in range(S))
        assert all(x is not None for x in w)
    else:
        w = (None,) * S
    # the working model's scale is each signal's residual mean square: hand it sigma
    nu = residual_dof(Ju, Hinv, sig.reshape(S, T), max_lag, p_eff, whitenings=w,
                      projection=Qp)
    Q = np.empty((4000, P))
    G = np.random.default_rng(12).standard_normal((3, P))   # three combinations of them
    QG = np.empty((4000, G.shape[0]))
    est = np.empty((4000, P))                           # the estimator's own error, B e
    for i in range(Q.shape[0]):
        e = sig * rng.standard_normal(N)
        est[i] = B @ e
        r = (M @ e).reshape(S, T)
        wi = None if not prewhiten else tuple(
            Whitening(np.linalg.solve(w[s].H, r[s]), w[s].H) for s in range(S))
        V = statistical_covariance(Bs, r, None, max_lag, p_eff, whitenings=wi,
                                   prewhiten=2 if prewhiten else 0)[1]
        Q[i] = np.diag(V)
        QG[i] = np.einsum("qi,ij,qj->q", G, V, G)
    nu_mc = 2 * Q.mean(0) ** 2 / Q.var(0)
    E, _, target = residual_moments(Ju, Hinv, sig.reshape(S, T), max_lag, p_eff,
                                    whitenings=w, projection=Qp)
    print("nu formula", np.round(nu, 2), "sampled", np.round(nu_mc, 2),
          "mean / target", np.round(E / target, 3))
    np.testing.assert_allclose(nu_mc, nu, rtol=0.12)
    np.testing.assert_allclose(Q.mean(0), E, rtol=0.05)
    # the target is the estimator's actual variance: a sample variance of n Gaussian draws
    # has relative sd sqrt(2 / n); 4.5 of them for 18 comparisons (3 cases x 6 parameters)
    np.testing.assert_allclose(target, est.var(0), rtol=4.5 * np.sqrt(2 / est.shape[0]))
    assert np.all(nu > 1.0) and np.all(nu < 5 * N)
    # along combinations g of the parameters (rows): the estimate of g^T V g, same checks
    nu_g = residual_dof(Ju, Hinv, sig.reshape(S, T), max_lag, p_eff, whitenings=w,
                        projection=Qp, rows=G)
    E_g, _, target_g = residual_moments(Ju, Hinv, sig.reshape(S, T), max_lag, p_eff,
                                        whitenings=w, projection=Qp, rows=G)
    np.testing.assert_allclose(2 * QG.mean(0) ** 2 / QG.var(0), nu_g, rtol=0.12)
    np.testing.assert_allclose(QG.mean(0), E_g, rtol=0.05)
    np.testing.assert_allclose(target_g, (est @ G.T).var(0),
                               rtol=4.5 * np.sqrt(2 / est.shape[0]))
    # the identity's rows are the parameters themselves
    np.testing.assert_allclose(residual_dof(Ju, Hinv, sig.reshape(S, T), max_lag, p_eff,
                                            whitenings=w, projection=Qp, rows=np.eye(P)),
                               nu, rtol=1e-12)


def _paper_setup(seed=3):
    """(obj, x, y, J, r, prior, data, dy) at the paper set on make_means' signals (no runs;
    each signal's noise_std 0), dy the model signals' time derivative there."""
    from dataclasses import replace

    from gprm.fit.api import FitOptions
    from gprm.fit.objective import fit_data_from_means
    from gprm.fit.sandwich import time_derivative
    from gprm.params import paper
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).parent))
    from means_factory import make_means

    p = paper()
    data = fit_data_from_means(make_means(p, seed=seed), source="synthetic")
    data = replace(data, attrs={**data.attrs, "align_time": 1.01e-3},
                   noise_std=np.zeros(len(data.signals)))
    obj, x, y, J, r, prior = _at_paper(data, tuple(FitOptions().parameters(p).fitted))
    return obj, x, y, J, r, prior, data, time_derivative(obj, x, J, y)


def _drive_sensitivities(data, x, names):
    """(S_V0, S_tau) (S, T): the paper model's signals' derivatives in the drive's V0 and
    tau_v, by central differences on gprm.simulate.observe (relative step 1e-5)."""
    from gprm.params import batch_from_vectors, paper
    from gprm.simulate import observe

    out = []
    for c in ("V0", "tau_v"):
        pb = batch_from_vectors(paper(), names, np.repeat(x[None], 2, 0))
        v = float(pb[c][0])
        pb[c] = np.array([v * (1 + 1e-5), v * (1 - 1e-5)])
        y = observe(pb, data.time, data.signals, piezo=2).y
        out.append((y[0] - y[1]) / (2e-5 * v))
    return out


def test_the_drives_hidden_time_shift_is_read_from_the_runs_shapes():
    """Runs whose drive differs (V0 by 2 %, tau_v by 3 % per run) and whose synchronisation
    moved them by arbitrary shifts: drive_shift_sd recovers the time shift the
    synchronisation takes for each run's shape, <g, S d_r> with g = y' / |y'|^2, exactly
    (noise-free; computed here without the regression), and its sd over the runs over
    sqrt(R). On runs that differ by white noise alone its noise correction leaves about
    nothing: it is 0 on most seeds and a fraction of what the noise would give uncorrected.
    The timing error it joins widens the lags and not the physical parameters; no runs, or
    Systematics(drive_timing=False): nothing is added."""
    from dataclasses import replace

    from gprm.fit.objective import Objective
    from gprm.fit.sandwich import drive_shift_sd, error_model, propagate
    from gprm.params import LAG_PARAMETERS, paper

    rng = np.random.default_rng(11)
    R = 10
    a, b, c = rng.normal(0, 0.02, R), rng.normal(0, 0.03, R), rng.normal(0, 3e-8, R)
    obj, x, y, J, r, prior, data, dy = _paper_setup()
    SV, ST = _drive_sensitivities(data, x, obj.names)
    V0, tau = float(paper().values["V0"]), float(paper().values["tau_v"])
    shape = (a[None, :, None] * V0 * SV[:, None, :] + b[None, :, None] * tau * ST[:, None, :])
    runs = y[:, None, :] + shape + c[None, :, None] * dy[:, None, :]
    obj = Objective.create(replace(data, runs=runs), paper(), obj.names)
    got = drive_shift_sd(obj, x, dy)
    g = dy / np.sum(dy ** 2, axis=1, keepdims=True)
    h = np.einsum("srt,st->sr", shape, g)
    want = np.sqrt(np.var(h, axis=1, ddof=1) / R)
    np.testing.assert_allclose(got, want, rtol=1e-3)
    assert np.all(want > 0)
    # white noise only: the correction takes out what the noise gives
    n0 = 2e-10
    est, raw = [], []
    for seed in range(30):
        noise = np.random.default_rng(seed).normal(0, n0, (len(data.signals), R, y.shape[1]))
        dn = replace(data, runs=y[:, None, :] + noise,
                     noise_std=np.full(len(data.signals), n0))
        on = Objective.create(dn, paper(), obj.names)
        est.append(drive_shift_sd(on, x, dy))
        raw.append(drive_shift_sd(Objective.create(replace(dn, noise_std=np.zeros(
            len(data.signals))), paper(), obj.names), x, dy))
    est, raw = np.array(est), np.array(raw)
    assert np.mean(est == 0) > 0.3
    assert np.all(np.mean(est, axis=0) < 0.5 * np.mean(raw, axis=0))
    # in the error model: joins every signal's timing in quadrature; widens only the lags
    e_on = error_model(obj, x, J, r, prior, Systematics(estimate_gain=False))
    e_off = error_model(obj, x, J, r, prior, Systematics(estimate_gain=False,
                                                          drive_timing=False))
    np.testing.assert_allclose(e_on.drive_timing_sd, got, rtol=1e-9)
    assert e_off.drive_timing_sd is None
    np.testing.assert_allclose(e_on.timing_sd ** 2 - e_off.timing_sd ** 2, got ** 2,
                               rtol=1e-6, atol=1e-30)
    V_on, V_off = (propagate(obj, x, J, prior, e, y) for e in (e_on, e_off))
    lags = np.array([n in LAG_PARAMETERS for n in obj.names])
    t_on, t_off = np.diag(V_on.timing), np.diag(V_off.timing)
    assert np.all(t_on[lags] > t_off[lags])
    stat = np.diag(V_on.statistical)
    assert np.all(t_on[~lags] - t_off[~lags] < 1e-3 * stat[~lags])
    # a file without runs: nothing to read it from
    no_runs = Objective.create(replace(data, runs=None), paper(), obj.names)
    assert drive_shift_sd(no_runs, x, dy) is None


def _warped_synchronised_runs(seed, R, at_crossing=False):
    """The paper setup with runs whose amplitude (V0, 2 %) and time scale ((t - t_x) y', 1 %)
    differ, synchronised: each run's shape slope part h taken out, a trigger shift c left in.
    Returns (obj, x, y, J, r, prior, data, dy, runs, shape, h, c, warp); t_x each mean's
    crossing time where ``at_crossing`` and the data give one, else 1.01 ms."""
    from gprm.params import paper

    rng = np.random.default_rng(seed)
    a, e, c = rng.normal(0, 0.02, R), rng.normal(0, 0.01, R), rng.normal(0, 3e-8, R)
    obj, x, y, J, r, prior, data, dy = _paper_setup()
    SV, _ = _drive_sensitivities(data, x, obj.names)
    V0 = float(paper().values["V0"])
    t_x = (np.asarray(data.crossing_time, float) if at_crossing and data.crossing_time is not None
           else np.full(len(data.signals), 1.01e-3))
    warp = (data.time[None, :] - t_x[:, None]) * dy                  # (S, T)
    shape = a[None, :, None] * V0 * SV[:, None, :] + e[None, :, None] * warp[:, None, :]
    g = dy / np.sum(dy ** 2, axis=1, keepdims=True)
    h = np.einsum("srt,st->sr", shape, g)
    runs = y[:, None, :] + shape - (h - c[None, :])[:, :, None] * dy[:, None, :]
    return obj, x, y, J, r, prior, data, dy, runs, shape, h, c, warp


def test_drive_shift_weights_count_an_extra_columns_shift_with_the_drives():
    """drive_shift_weights: w . (run - mean) is each run's slope component the
    synchronisation took, <g, shape_r>, exactly for noise-free shapes in the span of the
    drive's sensitivities and the ``extra`` columns (here a time warp (t - t_x) y', a
    stiffness change to first order), whatever trigger shift the run also has; without the
    extra column a warped run's shift is not recovered."""
    from dataclasses import replace

    from gprm.fit.objective import Objective
    from gprm.fit.sandwich import drive_shift_weights
    from gprm.params import paper

    obj, x, y, J, r, prior, data, dy, runs, shape, h, c, warp = _warped_synchronised_runs(5, 8)
    obj = Objective.create(replace(data, runs=runs), paper(), obj.names)
    dev = runs - runs.mean(axis=1, keepdims=True)
    W = drive_shift_weights(obj, x, dy, extra=warp[:, :, None])
    got = np.einsum("srt,st->sr", dev, W)
    want = h - h.mean(axis=1, keepdims=True)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6 * np.abs(want).max())
    W0 = drive_shift_weights(obj, x, dy)
    off = np.einsum("srt,st->sr", dev, W0) - want
    assert np.abs(off).max() > 0.1 * np.abs(want).max()
    assert drive_shift_weights(Objective.create(replace(data, runs=None), paper(), obj.names),
                               x, dy) is None


def test_the_drive_put_back_restores_each_runs_slope_part():
    """Systematics(drive_put_back=True), a development check: runs whose amplitude and time
    scale differ, synchronised (their shape's slope part taken out, a trigger shift left
    in), nearly noise-free: the error model's run deviations are the runs' whole shape
    deviations again (the slope part put back, the trigger shift not), the drive term is not
    added, and the runs' part is positive semi-definite. On runs of white noise alone the
    runs' F test puts back on few signals, and the runs' part's lag variances stay within
    a factor of the plain runs' part."""
    from dataclasses import replace

    from gprm.fit.objective import Objective
    from gprm.fit.sandwich import error_model, propagate
    from gprm.params import LAG_PARAMETERS, paper

    obj, x, y, J, r, prior, data, dy, runs, shape, h, c, warp = _warped_synchronised_runs(
        7, 10, at_crossing=True)
    tiny = np.full(len(data.signals), 1e-16)
    d1 = replace(data, runs=runs, noise_std=tiny)
    o1 = Objective.create(d1, paper(), obj.names)
    on = error_model(o1, x, J, r, prior, Systematics(estimate_gain=False, drive_put_back=True))
    full = y[:, None, :] + shape + c[None, :, None] * dy[:, None, :]
    want = (full - full.mean(axis=1, keepdims=True)) / data.sigma[:, None, :]
    np.testing.assert_allclose(on.dev, want, rtol=1e-6, atol=1e-6 * np.abs(want).max())
    assert on.drive_timing_sd is None and on.put_back_noise is not None
    parts = propagate(o1, x, J, prior, on, y)
    assert np.linalg.eigvalsh(parts.runs).min() >= -1e-12 * np.abs(parts.runs).max()
    # white noise alone: the test puts back on few signals; the lags' runs' part stays near
    n0 = 2e-10
    lags = np.array([n in LAG_PARAMETERS for n in obj.names])
    put, ratio = [], []
    for seed in range(12):
        noise = np.random.default_rng(100 + seed).normal(0, n0, runs.shape)
        dn = replace(data, runs=y[:, None, :] + noise, noise_std=np.full(len(data.signals), n0))
        o = Objective.create(dn, paper(), obj.names)
        e_on = error_model(o, x, J, r, prior, Systematics(estimate_gain=False,
                                                          drive_put_back=True))
        e_off = error_model(o, x, J, r, prior, Systematics(estimate_gain=False))
        put.append(np.mean(np.any(e_on.dev != e_off.dev, axis=(1, 2))))
        v_on = np.diag(propagate(o, x, J, prior, e_on, y).runs)[lags]
        v_off = np.diag(propagate(o, x, J, prior, e_off, y).runs)[lags]
        ratio.append(v_on / v_off)
    assert np.mean(put) < 0.25
    assert 0.5 < np.median(ratio) < 1.5


def test_the_drive_terms_noise_correction_counts_step_0s_baseline_line():
    """Runs of white noise that went through step 0 (a straight line fitted to 150 baseline
    samples before the window and subtracted): their variance along the drive term's
    projection w is n0^2 (|w|^2 + the line's extrapolated part), which is what the term's
    noise correction now subtracts where the data give the baseline. Measured over 40 seeds
    x 5 signals (R = 10 runs), the runs' variance over that prediction is 1 within 4 Monte
    Carlo sds, and clearly above 1 over the old |w|^2 alone (the line's part 20-150 % here);
    the corrected term is then 0 on most seeds, and the uncorrected estimate's excess over
    the corrected one is what the line adds. With the noise's autocovariance in the data
    (stop 56) a white one reproduces the white model, a correlated one subtracts more."""
    from dataclasses import replace

    from gprm.campaign.preprocess import detrended_noise_factor
    from gprm.fit.objective import Objective
    from gprm.fit.sandwich import drive_shift_sd
    from gprm.params import paper

    obj, x, y, J, r, prior, data, dy = _paper_setup()
    SV, ST = _drive_sensitivities(data, x, obj.names)
    t = data.time
    dt, T, S, R, n0 = t[1] - t[0], t.size, len(data.signals), 10, 2e-10
    nb, gap = 150, 20
    tb = t[0] - dt * (gap + nb) + dt * np.arange(nb)
    # w, the drive part of the regression on [y', S_V0, S_tau] projected on g = y'/|y'|^2
    ws = []
    for i in range(S):
        A = np.stack([dy[i], SV[i], ST[i]], axis=1)
        ws.append(np.linalg.pinv(A)[1:].T @ (A[:, 1:].T @ (dy[i] / (dy[i] @ dy[i]))))
    f_line = np.array([detrended_noise_factor(w, t, tb) for w in ws])
    f_own = np.array([w @ w for w in ws])
    base = np.stack([np.full(S, tb[0]), np.full(S, tb[-1])], axis=1)
    X = np.stack([np.ones(nb), (tb - tb.mean()) / np.ptp(tb)], axis=1)
    Xf = np.stack([np.ones(T), (t - tb.mean()) / np.ptp(tb)], axis=1)
    ratio_line, ratio_own, zero = [], [], []
    for seed in range(40):
        e = np.random.default_rng(seed).normal(0, n0, (S, R, nb + gap + T))
        coef = np.linalg.lstsq(X, e[..., :nb].reshape(-1, nb).T, rcond=None)[0]
        runs = y[:, None, :] + e[..., -T:] - (Xf @ coef).T.reshape(S, R, T)
        dn = replace(data, runs=runs, noise_std=np.zeros(S), baseline=base)
        v = R * drive_shift_sd(Objective.create(dn, paper(), obj.names), x, dy) ** 2
        ratio_line.append(v / (n0 ** 2 * f_line))
        ratio_own.append(v / (n0 ** 2 * f_own))
        on = replace(dn, noise_std=np.full(S, n0))
        zero.append(drive_shift_sd(Objective.create(on, paper(), obj.names), x, dy) == 0)
    ratio_line, ratio_own = np.ravel(ratio_line), np.ravel(ratio_own)
    mc = np.std(ratio_line) / np.sqrt(ratio_line.size)
    assert abs(np.mean(ratio_line) - 1) < 4 * mc, (np.mean(ratio_line), mc)
    assert np.mean(ratio_own) > 1 + 8 * mc
    assert np.all(f_line > 1.1 * f_own)
    assert np.mean(zero) > 0.4
    # without the baseline in the data: the old correction (the run's own noise only)
    old = drive_shift_sd(Objective.create(replace(on, baseline=None), paper(), obj.names),
                         x, dy)
    new = drive_shift_sd(Objective.create(on, paper(), obj.names), x, dy)
    assert np.all(old >= new) and np.any(old > new)
    # the noise's autocovariance where the data give it: a white one (a delta of n0^2) is
    # the white model to round-off; a correlated one subtracts more, never less
    L = nb + gap + T
    delta = np.zeros((S, L))
    delta[:, 0] = n0 ** 2
    same = drive_shift_sd(Objective.create(replace(on, noise_acov=delta), paper(),
                                           obj.names), x, dy)
    np.testing.assert_allclose(same, new, rtol=1e-9, atol=1e-18)
    red = np.tile(n0 ** 2 * 0.7 ** np.arange(L), (S, 1))
    less = drive_shift_sd(Objective.create(replace(on, noise_acov=red), paper(), obj.names),
                          x, dy)
    assert np.all(less <= new) and np.any(less < new)


def _mismatch_case(seed=5, R=10, amplitude=0.05):
    """(obj, x, yy, J, r, prior) at the paper set on means that carry an unmodelled 23 kHz
    oscillation after 1 ms (``amplitude`` of each signal's peak; 0: none) and R runs of
    white noise about them."""
    from dataclasses import replace

    from gprm.fit.objective import Objective
    from gprm.params import paper

    rng = np.random.default_rng(seed)
    obj, x, y, J, r, prior, data, _ = _paper_setup()
    t = data.time
    bump = amplitude * np.max(np.abs(y), axis=1, keepdims=True) * np.sin(2 * np.pi * 23e3 * t)
    values = data.values + bump * (t > 1.0e-3)
    runs = values[:, None, :] + data.sigma[:, None, :] * np.sqrt(R) * \
        rng.standard_normal((len(data.signals), R, t.size))
    runs = runs - runs.mean(axis=1, keepdims=True) + values[:, None, :]
    d2 = replace(data, values=values, runs=runs)
    obj = Objective.create(d2, paper(), obj.names)
    yy = obj.model(x[None]).y[0]
    J2 = -obj.model(x[None], jacobian=True).dy[0].reshape(-1, x.size) / d2.sigma.reshape(-1, 1)
    r2 = ((d2.values - yy) / d2.sigma).reshape(-1)
    return obj, x, yy, J2, r2, prior


def test_the_residuals_excess_stays_off_the_lags():
    """Where the residuals show more than the runs' spread (a mismatch added to the means),
    the statistical part's excess over the runs' covariance reaches the lags' rows and
    columns only with Systematics(excess_on_lags=True) (stops 1-44); by default those are
    the runs' part's, and every other entry is the same as with it."""
    from gprm.fit.sandwich import error_model, propagate
    from gprm.params import LAG_PARAMETERS

    obj, x, yy, J2, r2, prior = _mismatch_case()

    def parts(on):
        e = error_model(obj, x, J2, r2, prior, Systematics(excess_on_lags=on,
                                                           drive_timing=False))
        return propagate(obj, x, J2, prior, e, yy)

    off, on = parts(False), parts(True)
    lags = np.array([n in LAG_PARAMETERS for n in obj.names])
    E_off, E_on = off.statistical - off.runs, on.statistical - on.runs
    assert np.abs(E_on[np.ix_(lags, lags)]).max() > 0           # the leak reaches them
    np.testing.assert_array_equal(E_off[lags, :], 0.0)
    np.testing.assert_array_equal(E_off[:, lags], 0.0)
    keep = ~lags
    np.testing.assert_allclose(off.statistical[np.ix_(keep, keep)],
                               on.statistical[np.ix_(keep, keep)], rtol=1e-12)
    assert np.linalg.eigvalsh(off.statistical).min() >= -1e-12 * np.abs(off.statistical).max()


def test_the_residuals_excess_is_tested_per_parameter():
    """``Systematics.excess_test`` = q: the residuals' excess over the runs' covariance
    reaches parameter k only where V_res,kk / V_runs,kk exceeds the q quantile of F(nu_res,
    nu_runs) (:func:`excess_mask`); the statistical part is then V_runs plus the excess's
    block on those parameters (still positive semi-definite), the runs' part elsewhere. A
    mismatch the residuals show keeps the excess where it shows; a higher q drops more; a
    file without runs has nothing to test; an out-of-range q is refused."""
    from dataclasses import replace

    from scipy.stats import f as f_dist

    from gprm.errors import GprmInputError
    from gprm.fit.objective import Objective
    from gprm.fit.sandwich import (_estimator, error_model, excess_mask, propagate,
                                   residual_dof, satterthwaite, with_excess_mask)

    syst = Systematics(drive_timing=False)

    def case(amplitude):
        """The mismatch case's error model, its parts and the residuals' dof."""
        obj, x, yy, J, r, prior = _mismatch_case(amplitude=amplitude)
        err = error_model(obj, x, J, r, prior, syst)
        Ju, Hinv = _estimator(x, J, prior)
        nu = residual_dof(Ju, Hinv, err.R, err.max_lag, err.p_eff, whitenings=err.whitenings)
        return (obj, x, yy, J, r, prior), err, propagate(obj, x, J, prior, err, yy), nu

    # the exact model and white runs: dropped on most parameters; a mismatch twice the
    # runs' noise or more (1 % of the peak): kept on every one
    assert excess_mask(*case(0.0)[2:], 0.5).mean() < 0.5
    assert excess_mask(*case(0.01)[2:], 0.5).all()
    (obj, x, yy, J, r, prior), err, parts, nu_res = case(0.002)
    ratio = np.diag(parts.residuals) / np.diag(parts.runs)
    nu_runs = satterthwaite(parts.runs_by_signal, parts.n_runs)
    assert np.all(np.isfinite(nu_res)) and np.all(nu_runs >= 9 - 1e-9)
    masks = {q: excess_mask(parts, nu_res, q) for q in (0.5, 0.9, 0.99)}
    for q, m in masks.items():
        np.testing.assert_array_equal(m, ratio > f_dist.ppf(q, nu_res, nu_runs))
    assert masks[0.5].any() and not masks[0.5].all()
    assert np.all(masks[0.99] <= masks[0.9]) and np.all(masks[0.9] <= masks[0.5])
    # in the propagation: the excess's principal block on the tested parameters
    m = masks[0.5]
    tested = propagate(obj, x, J, prior, replace(err, excess_mask=m), yy)
    # the method restricts the parts it has instead of propagating again: the same arrays
    short = with_excess_mask(parts, m)
    np.testing.assert_array_equal(short.statistical, tested.statistical)
    np.testing.assert_array_equal(short.total, tested.total)
    E, E_t = parts.statistical - parts.runs, tested.statistical - tested.runs
    np.testing.assert_allclose(E_t[np.ix_(m, m)], E[np.ix_(m, m)], rtol=1e-12)
    np.testing.assert_array_equal(E_t[~m, :], 0.0)
    np.testing.assert_array_equal(E_t[:, ~m], 0.0)
    np.testing.assert_allclose(tested.runs, parts.runs, rtol=1e-12)
    np.testing.assert_allclose(tested.total - tested.statistical,
                               parts.total - parts.statistical, rtol=1e-9, atol=1e-30)
    assert np.linalg.eigvalsh(tested.statistical).min() >= \
        -1e-12 * np.abs(tested.statistical).max()
    # no runs: the residuals are the statistical part, nothing to test against
    no_runs = Objective.create(replace(obj.data, runs=None), obj.base, obj.names)
    e0 = error_model(no_runs, x, J, r, prior, syst)
    assert excess_mask(propagate(no_runs, x, J, prior, e0, yy), nu_res, 0.5) is None
    for bad in (0.0, 1.0, 1, True, -0.5):
        with pytest.raises(GprmInputError, match="excess_test"):
            Systematics(excess_test=bad)


def test_the_excess_test_through_the_method_changes_only_the_dropped_parameters_variance():
    """Through the method: fit.json records the test (``details.excess_reaches``, the stated
    ``excess_test``; None untested, stops 1-50; 0.5 the default). A parameter the excess
    still reaches keeps its variance, so its degrees of freedom are those without the test;
    one whose excess is dropped loses variance that was not the runs', so its statistical
    part is a larger share and its degrees of freedom (Student's t) fall."""
    from gprm.fit.methods import FitState, compute

    obj, x, yy, J, r, prior = _mismatch_case(amplitude=0.002)

    def method(syst):
        return compute("sandwich", FitState(obj, x, J, r, prior, n_draws=0, systematics=syst))

    base = method(Systematics(drive_timing=False, excess_test=None))     # untested
    test = method(Systematics(drive_timing=False))                       # the default
    assert base.details["excess_reaches"] is None
    assert base.details["stated"]["excess_test"] is None
    reach = np.array(test.details["excess_reaches"], bool)
    assert reach.any() and not reach.all()
    assert test.details["stated"]["excess_test"] == 0.5
    nu_b = np.array(base.details["degrees_of_freedom"], float)
    nu_t = np.array(test.details["degrees_of_freedom"], float)
    np.testing.assert_allclose(nu_t[reach], nu_b[reach], rtol=1e-9)
    assert np.all(nu_t[~reach] <= nu_b[~reach] * (1 + 1e-9))
    assert np.any(nu_t[~reach] < 0.9 * nu_b[~reach])


def test_the_draws_keep_the_excess_the_parameters_tests_leave_out():
    """The excess test narrows the parameters' intervals only: by default the posterior
    draws (every prediction's uncertainty) come from the covariance with the whole excess,
    so a parameter whose excess was dropped spreads its draws wider than its interval by
    sqrt(V_untested,kk / V_tested,kk), a kept one by nothing; with
    ``excess_test_draws`` (stop 50's check) they follow the tested covariance. The intervals
    are the same either way, and fit.json says which (``details.draws_excess``)."""
    from gprm.fit.methods import FitState, compute
    from gprm.fit.sandwich import error_model, propagate

    obj, x, yy, J, r, prior = _mismatch_case(amplitude=0.002)
    n = 20000

    def method(syst):
        return compute("sandwich", FitState(obj, x, J, r, prior, n_draws=n, seed=3,
                                            systematics=syst))

    common = dict(drive_timing=False, project_draws=False)
    kept = method(Systematics(**common))
    thin = method(Systematics(excess_test_draws=True, **common))
    assert kept.details["draws_excess"] == "untested"
    assert thin.details["draws_excess"] == "tested"
    np.testing.assert_array_equal(kept.lower95, thin.lower95)
    np.testing.assert_array_equal(kept.upper68, thin.upper68)
    reach = np.array(kept.details["excess_reaches"], bool)
    assert reach.any() and not reach.all()
    # the two covariances the draws come from, before the intervals' stretch
    err = error_model(obj, x, J, r, prior, Systematics(**common))
    whole = propagate(obj, x, J, prior, err, yy).total
    from dataclasses import replace
    tested = propagate(obj, x, J, prior, replace(err, excess_mask=reach), yy).total
    expect = np.sqrt(np.diag(whole) / np.diag(tested))
    assert np.any(expect[~reach] > 1.1)                  # the case drops real variance
    u_kept, u_thin = prior.to_u(kept.draws), prior.to_u(thin.draws)

    def width(u):
        """The draws' central 68 % range per parameter (scale-equivariant; the sd would
        follow the lags' long stretched tails)."""
        lo, hi = np.percentile(u, [16, 84], axis=0)
        return hi - lo

    # the same stretch maps both, so each marginal is the other's scaled by the
    # covariances' sd ratio (Monte Carlo sd of the ranges' ratio from 20000 draws each:
    # about 1.3 %)
    np.testing.assert_allclose(width(u_kept) / width(u_thin), expect, rtol=0.05)


def test_the_draws_stretch_changes_the_draws_only():
    """``Systematics.draws_stretch`` (stop 57's development checks) acts on the posterior
    draws alone: every map gives the same intervals; "identified" leaves the identified
    parameters' draws exactly the default's and maps the others by nothing (the same
    Gaussian draw, so the same ranks and no wider); an unknown map is refused."""
    from gprm.fit.methods import FitState, compute

    obj, x, yy, J, r, prior = _mismatch_case(amplitude=0.002)

    def method(syst):
        return compute("sandwich", FitState(obj, x, J, r, prior, n_draws=4000, seed=5,
                                            systematics=syst))

    common = dict(drive_timing=False, project_draws=False)
    base = method(Systematics(**common))
    for mode in ("whitened", "whitened-all", "identified"):
        other = method(Systematics(draws_stretch=mode, **common))
        np.testing.assert_array_equal(base.lower95, other.lower95)
        np.testing.assert_array_equal(base.upper68, other.upper68)
        assert other.details["stated"]["draws_stretch"] == mode
        assert other.draws.shape == base.draws.shape
        assert np.all(np.isfinite(other.draws))
        if mode == "identified":
            ident = np.asarray(base.identified, bool)
            assert ident.any() and not ident.all()       # the case has both kinds
            u0, u1 = prior.to_u(base.draws), prior.to_u(other.draws)
            np.testing.assert_allclose(u1[:, ident], u0[:, ident], rtol=1e-12, atol=1e-15)
            # the others: the same Gaussian draw unstretched, so the same ranks, no wider,
            # and narrower wherever their factors exceed 1 (here at least one does)
            for k in np.nonzero(~ident)[0]:
                assert np.array_equal(np.argsort(u0[:, k]), np.argsort(u1[:, k]))
                assert np.ptp(u1[:, k]) <= np.ptp(u0[:, k]) * (1 + 1e-12)
            assert np.ptp(u1[:, ~ident], axis=0).sum() < 0.99 * np.ptp(u0[:, ~ident],
                                                                      axis=0).sum()
    with pytest.raises(GprmInputError, match="draws_stretch"):
        Systematics(draws_stretch="diagonal")


def test_the_residuals_lag_window_is_a_stated_systematics_field():
    """``Systematics.hac_lag`` sets the residuals' kernel estimate's lag window (None: a
    quarter of the window's samples, :func:`default_max_lag`): the error model carries it,
    and the residual part is the Parzen sum over the prewhitened scores with that window,
    computed here from the module's pieces; a window that is not a count is refused."""
    from gprm.fit.sandwich import (DEFAULT_KERNEL, _linearised, default_max_lag, error_model,
                                   prewhitened_scores, propagate)

    obj, x, y, J, r, prior, data, _ = _paper_setup()
    S, T = data.values.shape
    assert error_model(obj, x, J, r, prior, Systematics()).max_lag == default_max_lag(T)
    res = {}
    for L in (0, 3):
        e = error_model(obj, x, J, r, prior, Systematics(hac_lag=L, estimate_gain=False))
        assert e.max_lag == L
        res[L] = propagate(obj, x, J, prior, e, y).residuals
        Ju, Hinv, B, _, _ = _linearised(obj, x, J, prior)
        Bs = B.reshape(x.size, S, T)
        want = sum(hac_meat(prewhitened_scores(Bs[:, s, :], e.R[s], 2, e.whitenings[s]), L,
                            DEFAULT_KERNEL) for s in range(S))
        want *= S * T / max(S * T - e.p_eff, 1.0)
        np.testing.assert_allclose(res[L], want, rtol=1e-9, atol=1e-12 * np.abs(want).max())
    assert not np.allclose(res[0], res[3])
    for bad in (-1, 2.5, True, "3", "Auto"):
        with pytest.raises(GprmInputError) as exc:
            Systematics(hac_lag=bad)
        assert exc.value.field == "systematics.hac_lag"


def test_plugin_lag_is_andrews_parzen_bandwidth():
    """:func:`plugin_lag` is Andrews' (1991) plug-in for Parzen's kernel from AR(1) fits to
    each series (written out here for two series), round(S_T) - 1 clipped to [0, a quarter
    of the samples]: uncorrelated series give a short window, strongly correlated ones the
    cap, and an "auto" window in the error model is the plug-in on the signals'
    prewhitened residuals."""
    from gprm.fit.sandwich import default_max_lag, error_model, plugin_lag

    rng = np.random.default_rng(8)
    T = 47
    a = _ar2(rng, T, 0.5, 0.0)
    b = 3.0 * _ar2(rng, T, -0.2, 0.0)
    num = den = 0.0
    for u in (a, b):
        rho = np.sum(u[1:] * u[:-1]) / np.sum(u[:-1] ** 2)
        s4 = np.mean((u[1:] - rho * u[:-1]) ** 2) ** 2
        num += 4 * rho ** 2 * s4 / (1 - rho) ** 8
        den += s4 / (1 - rho) ** 4
    S_T = 2.6614 * (num / den * T) ** 0.2
    assert plugin_lag([a, b]) == min(max(round(S_T) - 1, 0), default_max_lag(T))
    white = [rng.standard_normal(T) for _ in range(5)]
    slow = [_ar2(rng, T, 0.95, 0.0) for _ in range(5)]
    assert plugin_lag(white) <= 3
    assert plugin_lag(slow) == default_max_lag(T)
    assert plugin_lag([]) == 0
    obj, x, y, J, r, prior, data, _ = _paper_setup()
    e = error_model(obj, x, J, r, prior, Systematics(hac_lag="auto"))
    S, Tn = data.values.shape
    assert e.max_lag == plugin_lag([e.R[s] if w is None else w.u
                                    for s, w in enumerate(e.whitenings)])
    assert 0 <= e.max_lag <= default_max_lag(Tn)


class _Valley:
    """A stand-in objective (physical = normalised coordinates) with a valley: residuals
    G(x0 / s) and (x1 - x0) / eps, so that x1 follows x0 and the objective re-minimised over
    x1 at fixed x0 (the profile of x0) is G(x0 / s)^2. G'(0) = 1, so the Gauss-Newton
    variance of x0 at the minimum (0, 0) is s^2 and the profile statistic in it is G(o)^2 at
    o standard deviations."""

    def __init__(self, G, s=0.1, eps=0.01, lower=-np.inf):
        self.G, self.s, self.eps, self.lower = G, s, eps, lower

    def bounds(self):
        return np.array([self.lower, -np.inf]), np.array([np.inf, np.inf])

    def bounds_normalised(self):
        return self.bounds()

    def to_normalised(self, X):
        return np.asarray(X, float)

    def to_physical(self, X):
        return np.asarray(X, float)

    def residuals(self, X):
        X = np.atleast_2d(X)
        return np.stack([self.G(X[:, 0] / self.s), (X[:, 1] - X[:, 0]) / self.eps], axis=1)

    def __call__(self, X):
        X = np.atleast_2d(X)
        h = 1e-7
        dG = (self.G(X[:, 0] / self.s + h) - self.G(X[:, 0] / self.s - h)) / (2 * h * self.s)
        J = np.zeros((X.shape[0], 2, 2))
        J[:, 0, 0] = dG
        J[:, 1, 0], J[:, 1, 1] = -1.0 / self.eps, 1.0 / self.eps
        return self.residuals(X), J

    def chi2(self, X):
        r = self.residuals(X)
        return np.sum(r * r, axis=1)

    def hinv(self):
        J = self(np.zeros((1, 2)))[1][0]
        return np.linalg.inv(J.T @ J)


def test_profile_crossing_interpolates_the_root_of_the_statistic():
    from gprm.fit.sandwich import profile_crossing

    offs = np.array([1.0, 2.0, 4.0, 8.0])
    # quadratic: D = o^2, so sqrt(D) reaches z at o = z wherever the points are
    for z in (1.0, 1.96, 3.0):
        assert profile_crossing(offs, offs ** 2, z) == pytest.approx(z)
    # never reaching z: the side ends at its last point; a point not evaluated (beyond a
    # bound) ends it at the point before
    assert profile_crossing(offs, np.full(4, 0.25), 1.0) == 8.0
    assert profile_crossing(offs, np.array([0.25, 0.5, np.inf, 100.0]), 1.96) == 2.0
    assert profile_crossing(offs, np.array([np.nan, 1.0, 4.0, 9.0]), 1.0) == 0.0
    # a point below the best fit's objective counts as D = 0
    assert profile_crossing(offs, np.array([-0.5, 9.0, 9.0, 9.0]), 1.0) == pytest.approx(
        1.0 + 1.0 / 3.0)


def test_profile_factors_follow_the_valley_that_a_straight_line_leaves():
    """On the valley G(o) = 2 o / (2 + o) (flatter than quadratic above the minimum, steeper
    below) the profile of x0 reaches sqrt(D) = 1 at o = 2 exactly and never reaches 1.96 (it
    saturates at 2) within the points, so the upper side's factors are 2 at z = 1 and 8 / 1.96
    at 1.96; the lower side is never narrowed. A quadratic valley (G(o) = o) keeps the
    sandwich's interval. The x1 column follows x0 along the valley: without re-minimising
    it the objective would rise at once (a straight line in x0 alone)."""
    from gprm.fit.prior import Prior
    from gprm.fit.sandwich import profile_factors
    from gprm.fit.starts import LMOptions

    prior = Prior(("p", "q"), np.zeros(2), np.array([1e3, 1e3]), np.array([False, False]), 0.0)
    x = np.zeros(2)
    quad = _Valley(lambda o: o)
    Hinv = quad.hinv()
    assert Hinv[0, 0] == pytest.approx(0.1 ** 2, rel=1e-6)
    (lo95, hi95), (lo68, hi68) = profile_factors(quad, x, Hinv, Hinv, prior, LMOptions(),
                                                 (1.96, 1.0))
    np.testing.assert_allclose([lo95[0], hi95[0], lo68[0], hi68[0]], 1.0, atol=1e-4)
    valley = _Valley(lambda o: 2 * o / (2 + o), lower=-0.19)
    Hinv = valley.hinv()
    (lo95, hi95), (lo68, hi68) = profile_factors(valley, x, Hinv, Hinv, prior, LMOptions(),
                                                 (1.96, 1.0))
    assert hi68[0] == pytest.approx(2.0, rel=1e-3)
    assert hi95[0] == pytest.approx(8.0 / 1.96, rel=1e-9)
    assert lo68[0] == 1.0 and lo95[0] == 1.0
    # in the sandwich's variance: with a covariance twice the noise's the points lie at
    # o sqrt(2) noise sds and the statistic is G^2 / 2; sqrt(D) reaches 1 between o = 2 and 4
    (_, hi95b), (_, hi68b) = profile_factors(valley, x, 2 * Hinv, Hinv, prior, LMOptions(),
                                             (1.96, 1.0))
    o_s = np.sqrt(2) * np.array([2.0, 4.0])
    root = 2 * o_s / (2 + o_s) / np.sqrt(2)
    assert hi68b[0] == pytest.approx(2 + (1 - root[0]) * 2 / (root[1] - root[0]), rel=1e-3)
    assert hi95b[0] == pytest.approx(8.0 / 1.96, rel=1e-9)
