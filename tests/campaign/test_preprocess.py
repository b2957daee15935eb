"""Preprocessing (Sec. 2): synchronisation, noise, mean vs truth, alignment, Table 1."""

import json

import numpy as np
import pytest
from scipy.interpolate import CubicSpline
from scipy.optimize import minimize_scalar

from gprm.campaign.data import MODEL_POSITIONS, POSITIONS
from gprm.campaign.files import read_tables
from gprm.campaign.preprocess import first_crossing, noise_std, sync_timing_sd, synchronise
from gprm.campaign.files import read_truth, read_truth_alignment

GOOD_SNR = MODEL_POSITIONS + ("x_lr", "y_lr", "z_fl")
WINDOW = (0.97e-3, 1.2e-3)


def _relative_shifts(campaign, means, pos):
    i = POSITIONS.index(pos)
    dt = 1.0 / campaign.attrs["sample_rate"]
    off = campaign["trigger_offset"].sel(position=pos).values
    injected = (off - off[means.reference_run[i]]) / dt
    return injected, means.sync_shift[i] / dt


@pytest.mark.parametrize("pos", GOOD_SNR)
def test_trigger_offsets_recovered_to_a_tenth_of_a_sample(amp_campaign, amp_means, pos):
    injected, recovered = _relative_shifts(amp_campaign, amp_means, pos)
    assert np.ptp(injected) > 3.0                       # offsets of several samples injected
    assert np.max(np.abs(recovered - injected)) < 0.1


def test_trigger_offsets_with_full_variability(full_campaign, full_means):
    """With shape variability (tau_v, stiffness, damping per run) the RMS-optimal shift is no
    longer the trigger offset exactly; it stays within a quarter sample for the model points."""
    errs = [np.max(np.abs(np.subtract(*_relative_shifts(full_campaign, full_means, p))))
            for p in MODEL_POSITIONS]
    assert max(errs) < 0.25


def test_synchronise_band_limited_signal():
    """Independent check: a smooth decaying sine, shifted by known sub-sample amounts."""
    i = np.arange(300.0)

    def f(x):
        return np.exp(-((x - 150) / 40) ** 2) * np.sin(2 * np.pi * x / 17.0)

    true = np.array([0.0, 0.37, -1.61, 2.25, -3.9])
    Y = np.stack([f(i - s) for s in true])   # run r delayed by true[r] samples
    shifts, _ = synchronise(Y, 0, np.arange(60, 240), 8)
    assert np.max(np.abs(shifts - true)) < 0.01


def test_sync_timing_sd_is_the_time_shift_the_runs_spread_loses():
    """The mechanism behind ``sync_timing_sd``, by Monte Carlo on a smooth onset with white
    noise and step 0's baseline line (400 replicates of 10 runs): the synchronised runs'
    mean differs from the truth at the runs' average shift by a time shift (its projection
    on the slope) whose spread is the sd ``sync_timing_sd`` reports, while the runs'
    deviations from their mean have almost none of it (so a covariance from the runs'
    spread misses it). The sd of 400 draws' sd is 3.5 % of it: 12 % is about three and a
    half of those; the runs' share is bounded at a tenth of the variance (to first order it
    is zero)."""
    from gprm.campaign.preprocess import _detrend

    rng = np.random.default_rng(11)
    T, R, dt, n_base = 300, 10, 5e-6, 100
    i = np.arange(T, dtype=float)
    time = i * dt

    def f(x):
        return 200.0 * (1.0 + np.tanh((x - 150.0) / 12.0))

    win = np.arange(120, 200)
    slope = np.gradient(f(i))[win]
    g = slope / (slope @ slope)
    mean_proj, run_proj, reported = [], [], []
    for _ in range(400):
        Y = _detrend(f(i)[None, :] + rng.standard_normal((R, T)), time, n_base)
        shifts, splines = synchronise(Y, 0, win, 4)
        aligned = np.stack([splines[r](win + shifts[r]) for r in range(R)])
        M = aligned.mean(axis=0)
        # the truth where the data's axis puts it: at the runs' average shift
        mean_proj.append(float(g @ (M - f(win + shifts.mean()))))
        run_proj.append(float(np.mean(((aligned - M) @ g) ** 2)))
        reported.append(sync_timing_sd(splines, shifts, win, 1.0, time, n_base) / dt)
    sd_mean = float(np.std(mean_proj))
    assert abs(sd_mean / float(np.mean(reported)) - 1.0) < 0.12, (sd_mean, np.mean(reported))
    # what the runs' spread says about the mean's shift: their variance over R
    runs_var = float(np.mean(run_proj)) * R / (R - 1) / R
    assert runs_var < 0.1 * sd_mean ** 2, (runs_var, sd_mean ** 2)


def test_sync_timing_sd_is_written_and_read(full_means, tmp_path):
    """The file carries it per signal, in s, positive on a campaign with motion; the fit's
    data read it, and a negative value is an error naming the field."""
    from gprm.errors import GprmInputError
    from gprm.fit.objective import fit_data_from_means

    ds = full_means.to_dataset()
    v = ds["sync_timing_sd"]
    assert v.dims == ("signal",) and v.attrs["units"] == "s"
    model = [list(POSITIONS).index(p) for p in MODEL_POSITIONS]
    assert np.all(np.isfinite(v.values)) and np.all(v.values[model] > 0)
    fd = fit_data_from_means(ds)
    want = [float(v.sel(signal=s)) for s in fd.signals]
    np.testing.assert_array_equal(fd.sync_timing_sd, want)
    assert fit_data_from_means(ds.drop_vars("sync_timing_sd")).sync_timing_sd is None
    bad = ds.copy()
    bad["sync_timing_sd"] = bad["sync_timing_sd"] * -1.0
    with pytest.raises(GprmInputError, match="sync_timing_sd"):
        fit_data_from_means(bad)


def test_detrended_noise_factor_is_the_projection_of_step_0s_operator():
    """Step 0 (``_detrend``) is linear in the run: its matrix D (each unit sample through
    it) gives a white-noise run's variance along weights w over a window exactly as
    |D w|^2 (noise sd 1). detrended_noise_factor must equal it, for a window right after
    the baseline and one far from it, and exceed |w|^2 (the line's noise adds along w)."""
    from gprm.campaign.preprocess import _detrend, detrended_noise_factor

    T, n_base = 400, 120
    time = 1e-6 * np.arange(T) + 3e-4
    D = _detrend(np.eye(T), time, n_base)         # row k: unit sample k after step 0
    rng = np.random.default_rng(4)
    for win in (np.arange(130, 200), np.arange(300, 390)):
        w = rng.normal(size=win.size) + np.linspace(0, 3, win.size)
        full = np.zeros(T)
        full[win] = w
        exact = float(np.sum((D @ full) ** 2))
        got = detrended_noise_factor(w, time[win], time[:n_base])
        assert got == pytest.approx(exact, rel=1e-10)
        assert got > 1.01 * float(w @ w)
    # no baseline given: the run's own noise only
    assert detrended_noise_factor(w, time[win], time[:0]) == pytest.approx(float(w @ w))


def test_noise_autocovariance_models_the_noise_runs_correlation():
    """An AR(3) fitted to the noise runs by Yule-Walker: lag 0 is noise_std^2 exactly; on
    white noise the other lags are near 0; on an AR(1) process (phi 0.5, 400 runs of 300
    samples) the function is the process's phi^h / (1 - phi^2) within 5 % of lag 0 at every
    lag (the runs' own lines take a little of the low-frequency power); it obeys the fitted
    recursion beyond lag 3, and its Toeplitz matrix is positive definite."""
    from scipy.linalg import toeplitz

    from gprm.campaign.preprocess import noise_autocovariance

    T = 300
    time = 5e-6 * np.arange(T)
    rng = np.random.default_rng(8)
    white = rng.normal(0, 2e-10, (5, T))
    ac = noise_autocovariance(white, time)
    assert ac.shape == (T,)
    assert ac[0] == pytest.approx(noise_std(white, time) ** 2, rel=1e-12)
    assert np.all(np.abs(ac[1:]) < 0.1 * ac[0])
    phi = 0.5
    e = rng.normal(size=(400, T + 100))
    x = np.zeros_like(e)
    for t in range(1, e.shape[1]):
        x[:, t] = phi * x[:, t - 1] + e[:, t]
    ac = noise_autocovariance(x[:, 100:], time)
    theory = phi ** np.arange(T) / (1 - phi ** 2)
    np.testing.assert_allclose(ac, theory, atol=0.05 * theory[0])
    A = toeplitz(ac[:3])
    coef = np.linalg.solve(A, ac[1:4])
    np.testing.assert_allclose(ac[4:40], [coef @ ac[h - 1::-1][:3] for h in range(4, 40)],
                               rtol=1e-9, atol=1e-15)
    assert np.linalg.eigvalsh(toeplitz(ac[:120])).min() > 0


def test_detrended_noise_variance_is_the_quadratic_form_through_step_0():
    """Var<w, e> after step 0 for noise of a given autocovariance: the exact quadratic form
    (D w)^T C (D w) with D step 0's matrix and C the Toeplitz covariance; for white noise
    (a delta) it is sd^2 times detrended_noise_factor; along a smooth template, correlated
    noise gives well over the white model's."""
    from scipy.linalg import toeplitz

    from gprm.campaign.preprocess import (_detrend, detrended_noise_factor,
                                          detrended_noise_variance)

    T, n_base, dt = 300, 180, 5e-6
    time = dt * np.arange(T) + 1e-4
    rng = np.random.default_rng(2)
    w = rng.normal(size=60) + 1.0
    win = np.arange(200, 260)
    acov = 0.8 ** np.arange(T) / (1 - 0.64)
    D = _detrend(np.eye(T), time, n_base)
    full = np.zeros(T)
    full[win] = w
    v = D @ full
    got = detrended_noise_variance(w, time[win], time[:n_base], acov, dt)
    assert got == pytest.approx(float(v @ toeplitz(acov) @ v), rel=1e-10)
    delta = np.zeros(T)
    delta[0] = 4.0
    assert detrended_noise_variance(w, time[win], time[:n_base], delta, dt) == pytest.approx(
        4.0 * detrended_noise_factor(w, time[win], time[:n_base]), rel=1e-12)
    # correlated noise along a smooth template: more than the white model gives
    assert got > 1.5 * acov[0] * detrended_noise_factor(w, time[win], time[:n_base])


def test_detrended_noise_cross_is_the_covariance_through_step_0():
    """Cov(e'(t_i), <w, e'>) after step 0: exactly (D^T C D w_full)_i over the window's
    samples i, D the identity's rows through step 0, C the Toeplitz covariance; its inner
    product with w is
    detrended_noise_variance, with another weight vector the two projections' covariance."""
    from scipy.linalg import toeplitz

    from gprm.campaign.preprocess import (_detrend, detrended_noise_cross,
                                          detrended_noise_variance)

    T, n_base, dt = 300, 180, 5e-6
    time = dt * np.arange(T) + 1e-4
    rng = np.random.default_rng(4)
    w, u = rng.normal(size=60) + 1.0, rng.normal(size=60)
    win = np.arange(200, 260)
    acov = 0.7 ** np.arange(T) / (1 - 0.49)
    D = _detrend(np.eye(T), time, n_base)
    full = np.zeros(T)
    full[win] = w
    want = (D.T @ toeplitz(acov) @ D @ full)[win]
    got = detrended_noise_cross(w, time[win], time[:n_base], acov, dt)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())
    assert float(w @ got) == pytest.approx(
        detrended_noise_variance(w, time[win], time[:n_base], acov, dt), rel=1e-10)
    q = [detrended_noise_variance(u + s * w, time[win], time[:n_base], acov, dt)
         for s in (1, -1)]
    assert float(u @ got) == pytest.approx((q[0] - q[1]) / 4, rel=1e-9)


def test_noise_acov_is_written_and_read(full_means):
    """The means file carries the noise's autocovariance per signal over the record's lags,
    lag 0 the noise_std squared; the fit's data read it; an older file without it gives
    None; a lag larger than lag 0 is refused naming the field."""
    from gprm.errors import GprmInputError
    from gprm.fit.objective import fit_data_from_means

    ds = full_means.to_dataset()
    v = ds["noise_acov"]
    assert v.dims == ("signal", "lag") and v.attrs["units"] == "m2"
    np.testing.assert_allclose(v.values[:, 0], ds["noise_std"].values ** 2, rtol=1e-12)
    fd = fit_data_from_means(ds)
    np.testing.assert_array_equal(fd.noise_acov[0], v.sel(signal=fd.signals[0]).values)
    assert fit_data_from_means(ds.drop_vars("noise_acov")).noise_acov is None
    bad = ds.copy()
    vals = bad["noise_acov"].values.copy()
    vals[:, 1] = 2 * vals[:, 0]
    bad["noise_acov"] = (("signal", "lag"), vals)
    with pytest.raises(GprmInputError, match="noise_acov"):
        fit_data_from_means(bad)


def test_baseline_is_written_and_read(full_means):
    """The means file carries step 0's baseline per signal (first and last sample on the
    aligned axis, in s): before the motion's onset, as long as the samples step 0 used; the
    fit's data read it, an older file without it gives None, and a stop before its start is
    an error naming the field."""
    from gprm.errors import GprmInputError
    from gprm.fit.objective import fit_data_from_means

    ds = full_means.to_dataset()
    for end in ("start", "stop"):
        assert ds[f"baseline_{end}"].dims == ("signal",)
        assert ds[f"baseline_{end}"].attrs["units"] == "s"
    start, stop = ds["baseline_start"].values, ds["baseline_stop"].values
    dt = float(ds["time"][1] - ds["time"][0])
    n = np.rint((stop - start) / dt) + 1
    assert np.all(n >= 10) and np.allclose((stop - start) / dt + 1, n)
    # the baseline lies before every fitted signal's crossing into the motion (a position
    # that barely moves finds its onset late, and its baseline may run past the crossing)
    model = [list(POSITIONS).index(p) for p in MODEL_POSITIONS]
    assert np.all(stop[model] < ds["crossing_time"].values[model])
    fd = fit_data_from_means(ds)
    want = [[float(ds[f"baseline_{e}"].sel(signal=s)) for e in ("start", "stop")]
            for s in fd.signals]
    np.testing.assert_array_equal(fd.baseline, want)
    assert fit_data_from_means(ds.drop_vars(["baseline_start", "baseline_stop"])).baseline \
        is None
    bad = ds.copy()
    bad["baseline_stop"] = bad["baseline_start"] - dt
    with pytest.raises(GprmInputError, match="baseline_start"):
        fit_data_from_means(bad)


def test_fit_data_subset_selects_every_per_signal_field(full_means):
    """FitData.subset (the adequacy check's leave-one-signal-out) selects every field that
    is indexed by signal first, and PER_SIGNAL_FIELDS names every such field of a fit's
    data read from a full means file (a field added later cannot be left unselected)."""
    from dataclasses import fields

    from gprm.fit.objective import PER_SIGNAL_FIELDS, fit_data_from_means

    fd = fit_data_from_means(full_means.to_dataset())
    S = len(fd.signals)
    per_signal = {f.name for f in fields(fd) if isinstance(getattr(fd, f.name), np.ndarray)
                  and f.name != "time" and getattr(fd, f.name).shape[0] == S}
    assert per_signal == set(PER_SIGNAL_FIELDS)
    keep = [4, 1]
    sub = fd.subset(keep)
    assert sub.signals == (fd.signals[4], fd.signals[1])
    for name in PER_SIGNAL_FIELDS:
        np.testing.assert_array_equal(getattr(sub, name), getattr(fd, name)[keep])
    np.testing.assert_array_equal(sub.time, fd.time)
    assert sub.sigma_pool == fd.sigma_pool and sub.window == fd.window


def test_noise_std_matches_injected(full_campaign, full_means):
    inj = full_campaign.attrs["noise_std_injected"]
    assert inj == pytest.approx(5e-10, rel=1e-6)
    assert np.all(np.abs(full_means.noise_std / inj - 1) < 0.10)


def test_sigma_before_motion_is_the_noise(full_campaign, full_means):
    """sigma(t) across runs before the motion is the interferometer noise. There each run's
    baseline line was fitted to the same samples, which removes part of the low-frequency
    (coloured) noise: about 2 of ~25 effective degrees of freedom, so sigma is expected a few
    per cent low, never high."""
    inj = full_campaign.attrs["noise_std_injected"]
    pre = full_means.time < 0.9e-3
    rms_sigma = np.sqrt(np.mean(full_means.std[:, pre] ** 2, axis=1))
    ratio = rms_sigma / inj
    assert np.all(ratio > 0.85) and np.all(ratio < 1.05), ratio


def test_noise_std_estimator_on_white_noise():
    rng = np.random.default_rng(0)
    t = np.arange(2000) / 2e5
    x = 3e-10 * rng.standard_normal((5, t.size)) + 1e-9 * t[None] / t[-1] + 4e-9
    assert noise_std(x, t) == pytest.approx(3e-10, rel=0.03)


@pytest.mark.parametrize("which", ["full", "amp"])
def test_aligned_means_match_truth_within_sigma(request, which):
    """Mean signals vs the noise-free truth put on the aligned axis as the data were
    (truth_mean): within sigma (RMS over the fit window <= 1), and the time offset that
    matches them best is a small part of a sample: at most 0.03 here, the mean's own noise.
    (With the reference run's trigger offset for the truth's time, as at stop 39, it is 0.087
    on y_head of the full campaign: the reference run's own timing noise, which the
    synchronisation passes to every run; docs/data-formats.md.)"""
    ms = request.getfixturevalue(f"{which}_means")
    t = ms.time
    sel = (t >= WINDOW[0]) & (t <= WINDOW[1])
    dt = t[1] - t[0]
    for p in MODEL_POSITIONS:
        i = POSITIONS.index(p)
        cs = CubicSpline(t, ms.mean[i])
        S, tr = ms.std[i, sel], ms.truth_mean[i, sel]

        def chi(d):  # minimised in this iteration, so the loop variables are current
            return np.mean(((cs(t[sel] + d * dt) - tr) / S) ** 2)  # noqa: B023

        r = minimize_scalar(chi, bounds=(-2.0, 2.0), method="bounded")
        assert abs(r.x) < 0.05, (p, r.x)
        assert np.sqrt(r.fun) <= 1.0, (p, np.sqrt(r.fun))
        # and without any correction the mean is the truth to a few per cent of its peak
        assert np.max(np.abs(ms.mean[i, sel] - tr)) < 0.1 * np.max(np.abs(tr))


def test_alignment_rule_at_align_time(full_means):
    """The alignment moves each mean by whole samples so that its first sustained crossing of
    2x its noise std (``crossing_time``) lies within half a sample of the default align time
    (1.01 ms): the mean is below the threshold at the sample before it and at or above it at
    the sample after, and before that it never stays above it for two consecutive samples."""
    from gprm.campaign.preprocess import PreprocessConfig

    ta = PreprocessConfig().align_time
    assert ta == 1.01e-3
    t = full_means.time
    dt = t[1] - t[0]
    tc = full_means.crossing_time
    assert np.all(np.abs(tc - ta) <= 0.5 * dt + 1e-12)
    np.testing.assert_allclose(full_means.shift / dt, np.round(full_means.shift / dt),
                               atol=1e-9)
    thr = 2 * full_means.noise_std
    for i in range(len(full_means.signals)):
        k = int(np.searchsorted(t, tc[i]))            # the first sample at or after it
        assert abs(full_means.mean[i, k]) >= thr[i] * (1 - 1e-9)
        assert abs(full_means.mean[i, k - 1]) <= thr[i] * (1 + 1e-9)
        above = np.abs(full_means.mean[i, :k - 1]) >= thr[i]
        assert not np.any(above[1:] & above[:-1])


def test_reference_run_is_not_interpolated(full_campaign, full_means):
    """The alignment shift is whole samples and the reference run's synchronisation shift is
    zero, so each reference run on the output grid is its own record samples less the
    step-0 baseline (a straight line): no interpolation across the motion's onset, where a
    cubic spline errs (docs/data-formats.md, step 3)."""
    t_rec = full_campaign["time"].values
    dt = t_rec[1] - t_rec[0]
    for i, p in enumerate(full_means.signals):
        r = int(full_means.reference_run[i])
        rec = full_campaign["displacement"].sel(position=p).values[r]
        j = np.rint((full_means.time - full_means.shift[i] - t_rec[0]) / dt).astype(int)
        diff = full_means.runs[i, r] - rec[j]
        # the baseline line: second differences vanish to rounding
        scale = np.max(np.abs(rec))
        assert np.max(np.abs(np.diff(diff, 2))) < 1e-9 * scale, p


def test_runs_are_measured_samples(full_campaign, full_means):
    """Every run in ``runs``, not only the reference, is its own record samples less the
    step-0 baseline, moved by its synchronisation shift rounded to whole samples; the rest of
    the shift is ``sync_remainder`` (within half a sample, zero for the reference run), and
    the sub-sample shift the synchronisation estimated is their sum
    (docs/data-formats.md, step 1)."""
    t_rec = full_campaign["time"].values
    dt = t_rec[1] - t_rec[0]
    rem = full_means.sync_remainder
    assert np.all(np.abs(rem) <= 0.5 * dt + 1e-15)
    whole = (full_means.sync_shift - rem) / dt
    np.testing.assert_allclose(whole, np.rint(whole), atol=1e-9)
    moved = 0
    for i, p in enumerate(full_means.signals):
        ref = int(full_means.reference_run[i])
        assert rem[i, ref] == 0.0
        for r in range(full_means.runs.shape[1]):
            rec = full_campaign["displacement"].sel(position=p).values[r]
            j = np.rint((full_means.time - full_means.shift[i] - t_rec[0]) / dt
                        + whole[i, r]).astype(int)
            diff = full_means.runs[i, r] - rec[j]
            scale = np.max(np.abs(rec))
            assert np.max(np.abs(np.diff(diff, 2))) < 1e-9 * scale, (p, r)
            moved += int(abs(rem[i, r]) > 0.05 * dt)
    # the campaign has trigger offsets: most runs had a sub-sample rest to leave
    assert moved > full_means.runs.shape[1]


def test_truth_shift_is_where_the_datas_axis_puts_the_truths_time(full_campaign, full_means):
    """The truth sits on the aligned axis as the data were put there: truth_shift is the
    runs' average of (trigger offset - synchronisation shift), the time of the average of the
    synchronised runs, plus the data's alignment shift. The alignment rule
    applied to the noise-free truth itself (sampled at the reference run's phase) gives
    nearly the same shift: the noise and the sampling move the data's crossing by less than
    half a sample (the difference is what the fit's lags would be scored against if the
    rule's own shift were taken for the truth's, as until stop 39)."""
    from scipy.interpolate import CubicSpline

    from gprm.campaign.preprocess import PreprocessConfig, _sampled_crossing

    cfg = PreprocessConfig()
    dt = 1.0 / full_campaign.attrs["sample_rate"]
    off = full_campaign["trigger_offset"].values
    tt = full_campaign["truth_time"].values
    time = full_campaign["time"].values
    err = []
    for p in MODEL_POSITIONS:
        i = POSITIONS.index(p)
        ref = full_means.reference_run[i]
        assert full_means.truth_shift[i] == pytest.approx(
            full_means.shift[i] + np.mean(off[i] - full_means.sync_shift[i]), rel=0, abs=1e-15)
        cs = CubicSpline(tt, full_campaign["truth_displacement"].sel(position=p).values)
        tx = _sampled_crossing(cs, time, off[i, ref], cfg.threshold_factor *
                               full_means.noise_std[i], cfg.hold)
        rule = full_means.crossing_time[i] - tx
        err.append(abs(full_means.truth_shift[i] - rule) / dt)
    assert max(err) < 0.5, err


def test_first_crossing_analytic():
    """y = a (t - ts)^3 after ts: |y| = thr at ts + (thr/a)^(1/3)."""
    a, ts, thr = 2e6, 1.0e-3, 1e-9

    def f(t):
        s = np.clip(np.asarray(t) - ts, 0, None)
        return -a * s ** 3

    tx = first_crossing(f, 0.0, 1.5e-3, 5e-6 / 8, thr)
    assert tx == pytest.approx(ts + (thr / a) ** (1 / 3), abs=1e-12)
    assert first_crossing(f, 0.0, 0.9e-3, 5e-6, thr) is None


def test_signal_to_noise_like_fig3a(full_means):
    """Peak over std across runs about 50 (Fig. 3a) for the fitted signals."""
    snr = [full_means.snr[p]["peak_over_std"] for p in MODEL_POSITIONS]
    assert 30 < np.median(snr) < 90


def test_table1_from_data(full_campaign, full_means):
    """Table 1 ratios come out of the noisy data as they do from the noise-free truth, and
    near the paper's values."""
    clean = {p: np.max(np.abs(full_campaign["truth_displacement"].sel(position=p).values))
             for p in POSITIONS}
    paper = {"max(x_head)/max(x_lr)": 3, "max(x_head)/max(x_fl)": 17,
             "max(y_head)/max(y_lr)": 3, "max(y_head)/max(y_fl)": 21,
             "max(z_bk)/max(z_fl)": 26}
    for key, v in full_means.table1.items():
        num, den = key[4:].split(")/max(")
        den = den.rstrip(")")
        assert v["value"] == pytest.approx(clean[num] / clean[den], rel=0.1), key
        assert 0.7 < v["value"] / paper[key] < 1.4, key
    print("\nTable 1 from the synthetic campaign (seed 7):")
    for key, v in full_means.table1.items():
        print(f"  {key:24s} {v['value']:6.2f}   paper {paper[key]}")


def test_dropped_positions(full_means):
    ds = full_means.to_dataset()
    table, dropped, _ = read_tables(ds)
    assert set(dropped) == {"x_fl", "y_fl", "z_fl", "x_lr", "y_lr"}
    assert all(d["supported"] for d in dropped.values())
    assert dropped["x_lr"]["value"] == table["max(x_head)/max(x_lr)"]["value"]


def test_tables_are_variables_and_round_trip_through_the_file(full_means, tmp_path):
    """Table 1, the dropped positions and the SNR summary are variables along their own
    dimension (CF; no JSON strings) and read back to exactly the dicts MeanSignals holds;
    files of the older layout (JSON attributes) read the same."""
    from gprm._io import open_netcdf, write_netcdf_atomic

    ds = full_means.to_dataset()
    assert not [a for a in ds.attrs if a in ("table1_json", "dropped_json", "snr_json")]
    assert ds["table1_value"].dims == ("ratio",) and ds["snr_peak"].attrs["units"] == "m"
    write_netcdf_atomic(ds, tmp_path / "m.nc")
    want = (full_means.table1, full_means.dropped, full_means.snr)
    assert read_tables(open_netcdf(tmp_path / "m.nc")) == want
    legacy = ds.drop_vars([v for v in ds.variables if v.startswith(("table1_", "dropped_",
                                                                      "snr_"))]
                          + ["ratio", "dropped_position", "snr_position"])
    legacy.attrs.update({"table1_json": json.dumps(want[0]), "dropped_json": json.dumps(want[1]),
                         "snr_json": json.dumps(want[2])})
    assert read_tables(legacy) == want


def test_mean_signals_contract(full_campaign, full_means):
    ds = full_means.to_dataset()
    assert [str(s) for s in ds["signal"].values] == list(POSITIONS)
    for v, u in (("mean", "m"), ("std", "m"), ("sem", "m"), ("noise_std", "m"),
                 ("shift", "s"), ("n_runs", "1")):
        assert ds[v].attrs["units"] == u
    assert ds["time"].attrs["units"] == "s"
    assert np.all(np.isfinite(ds["sem"])) and np.all(ds["sem"] > 0)
    assert np.all(np.isfinite(ds["std"])) and np.all(ds["std"] > 0)
    np.testing.assert_allclose(ds["sem"], ds["std"] / np.sqrt(10))
    assert np.all(ds["n_runs"] == 10)
    t = ds["time"].values
    assert t[0] <= WINDOW[0] and t[-1] >= WINDOW[1]
    np.testing.assert_allclose(np.diff(t), 5e-6, rtol=1e-9)
    for a in ("source", "sample_rate", "campaign_sha256", "truth_source", "seed",
              "align_time", "threshold_factor", "max_lag", "hold", "generator_rate"):
        assert a in ds.attrs, a
    for v in ("table1_value", "table1_paper", "dropped_supported", "snr_peak_over_std"):
        assert v in ds and "units" in ds[v].attrs, v
    assert read_truth(ds) == read_truth(full_campaign) and read_truth(ds)
    assert ds.attrs["seed"] == 7
    ta = read_truth_alignment(ds)
    assert set(ta) >= {"t0_expected_s", "t1_expected_s", "truth_shift_s"}


def test_alignment_shift_of_a_sampled_signal():
    """The step-3 rule applied to a sampled analytic onset -a (t - ts)^3."""
    from gprm.campaign.preprocess import alignment_shift

    a, ts, thr = 2e6, 1.0037e-3, 1e-9
    t = np.arange(301) / 2e5
    y = -a * np.clip(t - ts, 0, None) ** 3
    sh = alignment_shift(t, y, thr)
    # the spline of the samples of a cubic onset is exact away from the kink; allow 0.05 sample
    assert sh == pytest.approx(1e-3 - (ts + (thr / a) ** (1 / 3)), abs=0.05 * 5e-6)
    assert alignment_shift(t, y, 1.0) is None


@pytest.mark.parametrize("position, accepted", [("y_fl", True), ("y_base", False)])
def test_a_still_position_fails_only_if_the_model_fits_it(small_campaign, position, accepted):
    """A flange that barely moves (seen on a campaign drawn within +-10 % of Table 3, seed 1008
    of benchmarks/bench_coverage.py) is averaged with the fitted positions' onset; a fitted
    position without motion cannot be aligned and stays an input error."""
    from gprm.campaign.preprocess import preprocess
    from gprm.errors import GprmInputError

    ds = small_campaign.copy(deep=True)
    i = list(ds["position"].values).index(position)
    ds["displacement"].values[i] = ds["noise"].values[i, :1].repeat(ds.sizes["run"], axis=0)[
        :, :ds.sizes["time"]]
    if accepted:
        means = preprocess(ds)
        assert np.all(np.isfinite(means.to_dataset()["mean"].values))
    else:
        with pytest.raises(GprmInputError, match=position):
            preprocess(ds)


def test_alignment_starts_after_a_baseline_excursion(amp_campaign, amp_means):
    """A mean that is above the threshold at the record's start (a slow baseline excursion
    that a few runs do not average out and the straight-line baseline does not remove) is
    aligned at the crossing that leads into the motion, where the clean campaign is (the
    first-crossing rule alone finds none there: it was an input error)."""
    from gprm.campaign.preprocess import preprocess
    camp = amp_campaign.copy(deep=True)
    i = POSITIONS.index("z_bk")
    t = camp["time"].values
    bump = 6 * float(amp_means.noise_std[i]) * np.exp(-t / 30e-6)   # gone well before 1 ms
    disp = camp["displacement"].values.copy()
    disp[i] += bump[None, :]
    camp["displacement"] = (camp["displacement"].dims, disp)
    means = preprocess(camp)
    dt = t[1] - t[0]
    assert abs(means.shift[i] - amp_means.shift[i]) < 0.05 * dt
    # every other position is untouched
    others = [k for k in range(len(POSITIONS)) if k != i]
    assert np.array_equal(means.shift[others], amp_means.shift[others])
