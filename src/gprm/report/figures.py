"""The figures of gprm, one function per figure of the paper it mirrors, used by the report
and by library users alike (the one home of the drawing code: the stages before the report
draw nothing). Each takes a stage's output (xarray Dataset, result or dict) and returns a
matplotlib Figure (Agg backend; save it with ``fig.savefig``); nothing is read from disk here.
Displacements are shown in micrometres, times in milliseconds.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from gprm.flight.telemetry import fit_release_velocity  # noqa: E402
from gprm.params import REGISTRY, from_si  # noqa: E402

if TYPE_CHECKING:
    from gprm.predict.whatif import Sweep

# One colour per quantity, used in every figure.
COLORS = {
    "x_base": "#1f77b4", "x_head": "#0b3d91", "y_base": "#d62728", "y_head": "#8c1a1a",
    "z_bk": "#2ca02c", "x_lr": "#9ecae1", "x_fl": "#c6dbef", "y_lr": "#fc9272",
    "y_fl": "#fcbba1", "z_fl": "#a1d99b", "data": "#1f4e79", "model": "#e6550d",
    "band": "#fdae6b", "measured": "#3182bd", "predicted": "#fd8d3c", "nominal": "#31a354",
    "vx": "#1f77b4", "vz_xz": "#17becf", "wy": "#9467bd", "vy": "#d62728", "vz_yz": "#ff7f0e",
    "wx": "#8c564b", "truth": "#111111", "piezo2": "#9aa3ad",
    "M_xz": "#1f77b4", "M_yz": "#d62728", "tip_edge": "#2ca02c", "com": "#7f7f7f",
}
# the six flight axes, in the order of docs/spec.md
AXES = ("vx", "vz_xz", "wy", "vy", "vz_yz", "wx")
AXIS_LABEL = {"vx": "v_x [µm/s]", "vz_xz": "v_z (x–z) [µm/s]", "wy": "ω_y [µrad/s]",
              "vy": "v_y [µm/s]", "vz_yz": "v_z (y–z) [µm/s]", "wx": "ω_x [µrad/s]"}
UM = 1e6
MS = 1e3

plt.rcParams.update({"figure.dpi": 110, "axes.grid": True, "grid.alpha": 0.3,
                     "axes.spines.top": False, "axes.spines.right": False,
                     "font.size": 9, "legend.fontsize": 8, "legend.frameon": False})


def _color(name: str, fallback: str = "#555555") -> str:
    return COLORS.get(name, fallback)


def fig_fit(side, signals=("x_base", "x_head", "y_base", "y_head", "z_bk")):
    """Fig. 6: mean signals with sigma, best fit and uncertainty bands (fit sidecar)."""
    fig, axes = plt.subplots(3, 2, figsize=(10.0, 7.2), sharex=True)
    flat = axes.ravel()
    t = side["time"].values * MS
    for ax, s in zip(flat, signals):
        d = side["data_mean"].sel(signal=s).values * UM
        e = side["data_sigma"].sel(signal=s).values * UM
        ax.fill_between(t, d - e, d + e, color=_color(s), alpha=0.18, lw=0, label="data ±σ")
        ax.plot(t, d, "o", ms=2.5, color=_color(s), label="mean signal")
        if "model_best" in side:
            m = side["model_best"].sel(signal=s).values * UM
            lo = hi = None
            label = "model 95 % band"
            if "band_sample_lo" in side:
                lo = side["band_sample_lo"].sel(signal=s).values * UM
                hi = side["band_sample_hi"].sel(signal=s).values * UM
            if (lo is None or not np.all(np.isfinite(lo))) and "band_linear_std" in side:
                # no usable covariance draws: the linear propagation J C J^T instead
                sd = side["band_linear_std"].sel(signal=s).values * UM
                lo, hi, label = m - 1.96 * sd, m + 1.96 * sd, "model 95 % band (linear)"
            if lo is not None and np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)):
                ax.fill_between(t, lo, hi, color=COLORS["band"], alpha=0.55, lw=0,
                                label=label)
            ax.plot(t, m, "-", lw=1.3, color=COLORS["model"], label="best fit")
            if "resonance_fitted" in side:
                ax.plot(t, m + side["resonance_fitted"].sel(signal=s).values * UM, "--",
                        lw=1.0, color=COLORS["model"],
                        label="best fit + resonance (marginalised)")
        ax.set_title(s)
        ax.set_ylabel("displacement [µm]")
    handles, labels = flat[0].get_legend_handles_labels()
    flat[-1].axis("off")
    flat[-1].legend(handles, labels, loc="center", fontsize=10)
    for ax in axes[-1]:
        ax.set_xlabel("time [ms]")
    axes[1, 1].xaxis.set_tick_params(labelbottom=True)
    axes[1, 1].set_xlabel("time [ms]")
    fig.suptitle("Best fit of the five signals (cf. Fig. 6)")
    fig.tight_layout()
    return fig


def waterfall(chi2, *, ax=None, tol: float = 1.0, title: str | None = None):
    """Waterfall plot of a multi-start fit: the final chi-square of every start, sorted
    ascending (log scale), the best start marked, and the number of starts within
    ``tol`` (Delta chi2 <= 1 by default) of the best -- the plateau at the left shows how
    reliably the starts find the best minimum.

    chi2: (n_starts,) final chi-square (NaN for failed starts, counted but not drawn), e.g.
        ``FitResult.starts.chi2`` or the ``chi2`` variable of the fit's NetCDF sidecar.
    ax: a matplotlib Axes to draw in; None makes a new figure.
    Returns the matplotlib Figure.
    """
    c = np.asarray(chi2, float).ravel()
    finite = np.sort(c[np.isfinite(c)])
    counts = waterfall_counts(c, tol)
    n_failed = counts["n_failed"]
    if ax is None:
        fig, ax = plt.subplots(figsize=(6.0, 3.6), constrained_layout=True)
    else:
        fig = ax.figure
    if finite.size == 0:
        ax.text(0.5, 0.5, f"no start produced a finite chi-square ({c.size} failed)",
                ha="center", va="center", transform=ax.transAxes)
        return fig
    best, n_best = counts["best"], counts["n_at_best"]
    rank = np.arange(1, finite.size + 1)
    ax.plot(rank, finite, ".", ms=3, color="0.35", label="starts (sorted)")
    ax.plot(rank[:n_best], finite[:n_best], ".", ms=4, color="tab:orange",
            label=f"within Δχ² ≤ {tol:g} of the best: {n_best}")
    ax.plot([1], [best], "*", ms=12, color="tab:red", label=f"best χ² = {best:.6g}")
    if np.all(finite > 0):
        ax.set_yscale("log")
    ax.set_xlabel("start (sorted by final χ²)")
    ax.set_ylabel("final χ²")
    t = title or f"{c.size} starts" + (f", {n_failed} failed" if n_failed else "")
    ax.set_title(t)
    ax.legend(loc="upper left", fontsize=8, frameon=False)
    return fig


def waterfall_counts(chi2, tol: float = 1.0) -> dict:
    """The numbers the waterfall shows: starts, failed, best chi-square, and how many are
    within ``tol`` of it."""
    c = np.asarray(chi2, float).ravel()
    f = c[np.isfinite(c)]
    if f.size == 0:
        return {"n_starts": int(c.size), "n_failed": int(c.size), "best": None, "n_at_best": 0}
    return {"n_starts": int(c.size), "n_failed": int(c.size - f.size), "best": float(f.min()),
            "n_at_best": int(np.sum(f <= f.min() + tol))}


def fig_waterfall(side):
    """Waterfall of the starts: sorted final chi-square of every start (:func:`waterfall`
    on the ``chi2`` of the fit's NetCDF sidecar)."""
    fig, ax = plt.subplots(figsize=(8.0, 3.2))
    waterfall(side["chi2"].values, ax=ax,
              title=f"Waterfall of {side.sizes.get('start', side['chi2'].size)} starts")
    fig.tight_layout()
    return fig


def fig_masses(fit: dict, truth: dict | None = None):
    """Fig. 7: fitted masses (± 1 sigma) against the CAD nominal, the initial value, the
    paper's 3D fit and, for synthetic data, the truth."""

    names = [n for n in ("m1", "m2", "m3", "m4") if n in fit["parameters"]]
    fig, axes = plt.subplots(1, len(names), figsize=(10.0, 3.0))
    for ax, n in zip(np.atleast_1d(axes), names):
        p = fit["parameters"][n]
        spec = REGISTRY[n]
        cols = [("fit", p["value"], p.get("stderr"), "o", COLORS["model"])]
        init = p.get("initial", spec.initial)
        if init is not None:
            cols.append(("initial", init, None, "^", "#9467bd"))
        cols.append(("paper", spec.default, spec.paper_stderr, "D", "#7f7f7f"))
        if spec.nominal is not None:
            cols.append(("CAD", spec.nominal, None, "s", COLORS["nominal"]))
        if truth and n in truth:
            cols.append(("truth", truth[n], None, "*", COLORS["truth"]))
        for i, (lab, v, e, mk, c) in enumerate(cols):
            ax.errorbar([i], [v * 1e3], yerr=None if e is None else [e * 1e3], fmt=mk,
                        color=c, ms=7 if mk == "*" else 5, capsize=4, label=lab)
        ax.set_xticks(range(len(cols)), [c[0] for c in cols], fontsize=8)
        ax.set_xlim(-0.6, len(cols) - 0.4)
        ax.set_title(f"{n} ({spec.description})")
        ax.set_ylabel("mass [g]")
    fig.suptitle("Masses: fit vs nominal (cf. Fig. 7)")
    fig.tight_layout()
    return fig


def fig_mean_signals(means):
    """Fig. 3: one mean signal with its sigma, and the aligned mean signals per axis."""
    fig, axes = plt.subplots(2, 2, figsize=(7.5, 5.2))
    t = means["time"].values * MS
    sig = [str(s) for s in means["signal"].values]
    ax = axes[0, 0]
    s0 = "x_base" if "x_base" in sig else sig[0]
    m = means["mean"].sel(signal=s0).values * UM
    sd = means["std"].sel(signal=s0).values * UM if "std" in means else 0 * m
    ax.fill_between(t, m - sd, m + sd, color=_color(s0), alpha=0.25, lw=0, label="±σ(t)")
    ax.plot(t, m, color=_color(s0), lw=1, label=f"mean {s0}")
    ax.set_title(f"(a) {s0} with σ(t)")
    # sigma is ~1e-3 of the signal: a band around the mean cannot show it, so it also gets
    # its own axis (right, nm)
    ax2 = ax.twinx()
    ax2.plot(t, sd * 1e3, color="#444444", lw=0.9, ls="--", label="σ(t) (right axis)")
    ax2.set_ylabel("σ(t) [nm]")
    ax2.set_ylim(0, max(float(np.nanmax(sd * 1e3)) * 1.15, 1e-9))
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, fontsize=8)
    for ax, (axis, title) in zip([axes[0, 1], axes[1, 0], axes[1, 1]],
                                 [("x", "(b) x signals"), ("y", "(c) y signals"),
                                  ("z", "(d) z signals")]):
        for s in sig:
            if s.startswith(axis):
                ax.plot(t, means["mean"].sel(signal=s).values * UM, lw=1, color=_color(s),
                        label=s)
        ax.set_title(title)
        ax.legend(ncol=2)
    for ax in axes.ravel():
        ax.set_xlim(0.9, t[-1])       # from just before the retraction command (1 ms) on
        ax.set_xlabel("time [ms]")
        ax.set_ylabel("displacement [µm]")
    fig.suptitle("Campaign mean signals (cf. Fig. 3)")
    fig.tight_layout()
    return fig


# ----------------------------------------------------------------------------- prediction
# Prediction NetCDF (docs/prediction.md): pos(point, axis, time) m, change from the initial
# equilibrium; pos_p2_5/pos_p97_5 bands; pos_samples(sample, point, axis, time); energy
# histograms over ke_edges (J) as time per bin (s).

_PLANES = (("M_xz", "x", "z", "M_xz, x–z plane"), ("M_yz", "y", "z", "M_yz, y–z plane"),
           ("tip_edge", "x", "y", "tip edge, x–y plane"))


def _pt(ds, var, point, axis):
    return np.asarray(ds[var].sel(point=point, axis=axis).values, float)


def fig_trajectories(ds, title: str, ref=None):
    """Figs. 10, 13, 14: the contact middle points and the tip edge projected on the planes,
    axes centred on the initial position. Start (blue star) and end at 1.2 ms (red star) as in
    the paper; thin lines: trajectories of parameter sets drawn from the covariance; grey:
    ``ref`` (Piezo 2 as built) for comparison."""
    fig, axes = plt.subplots(1, 3, figsize=(10.0, 3.5))
    for ax, (pt, a, b, lab) in zip(axes, _PLANES):
        c = COLORS.get(pt, COLORS["model"])
        if ref is not None:
            ax.plot(_pt(ref, "pos", pt, a) * UM, _pt(ref, "pos", pt, b) * UM, "-",
                    color=COLORS["piezo2"], lw=1.0, label="Piezo 2 (as built)")
        if "pos_samples" in ds:
            S = ds["pos_samples"].sel(point=pt)
            for k in range(min(S.sizes["sample"], 20)):
                ax.plot(S.isel(sample=k).sel(axis=a).values * UM,
                        S.isel(sample=k).sel(axis=b).values * UM, "-", color=c, lw=0.4,
                        alpha=0.25, label="covariance samples" if k == 0 else None)
        xa, xb = _pt(ds, "pos", pt, a) * UM, _pt(ds, "pos", pt, b) * UM
        ax.plot(xa, xb, "-", color=c, lw=1.5, label="best fit")
        ax.plot(xa[0], xb[0], "*", color="#1f4eb4", ms=10, label="start", zorder=5)
        ax.plot(xa[-1], xb[-1], "*", color="#c62828", ms=10, label="end (1.2 ms)", zorder=5)
        ax.set_xlabel(f"{a} [µm]")
        ax.set_ylabel(f"{b} [µm]")
        ax.set_title(lab)
    handles, labels = [], []
    for ax in axes:
        for h, l in zip(*ax.get_legend_handles_labels()):
            if l not in labels:
                handles.append(h)
                labels.append(l)
    fig.legend(handles, labels, loc="lower center", ncol=len(labels),
               bbox_to_anchor=(0.5, -0.04))
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    return fig


def fig_energy(pred, run=None):
    """Fig. 8: histogram of the kinetic energy E_5 (time spent per energy bin in the fit
    window), model (orange) against measured (blue), with their errors."""
    need = ("ke_edges", "hist_model_point")
    if any(n not in pred for n in need):
        return None
    edges = np.asarray(pred["ke_edges"].values, float) * 1e6          # J -> µJ
    centres, width = 0.5 * (edges[1:] + edges[:-1]), np.diff(edges)
    fig, ax = plt.subplots(figsize=(8.0, 3.2))
    series = [("hist_measured", "measured", COLORS["measured"], -0.2),
              ("hist_model_point", "3D model", COLORS["predicted"], 0.2)]
    for var, lab, col, off in series:
        if var not in pred:
            continue
        h = np.asarray(pred[var].values, float) * 1e6                    # s -> µs
        if not np.any(np.isfinite(h)):
            continue
        err = pred[var + "_err"].values * 1e6 if var + "_err" in pred else None
        if err is not None:
            err = np.where(h > 0, err, np.nan)
        ax.bar(centres + off * width, h, width=0.4 * width, color=col, alpha=0.85, label=lab,
               yerr=err, error_kw={"elinewidth": 0.8, "capsize": 1.5, "ecolor": "#333333"})
    last = int(np.max(np.nonzero(np.nan_to_num(pred["hist_model_point"].values) > 0)[0],
                      initial=0))
    if "hist_measured" in pred:
        hm = np.nan_to_num(pred["hist_measured"].values)
        if np.any(hm > 0):
            last = max(last, int(np.max(np.nonzero(hm > 0)[0])))
    ax.set_xlim(edges[0], edges[min(last + 2, len(edges) - 1)])
    ax.set_xlabel("kinetic energy E₅ [µJ]")
    ax.set_ylabel("time in bin [µs]")
    ax.legend()
    ax.set_title("Kinetic energy at the tip retraction, fit window (cf. Fig. 8)")
    fig.tight_layout()
    return fig


def whatif_rows(wi: dict) -> list:
    """Rows of the what-if table: the headline ratio per axis with its 2.5-97.5 % range,
    and the paper's values (:func:`gprm.predict.whatif.ratio_rows`, which ``gprm predict
    --whatif`` prints too)."""
    from gprm.predict.whatif import ratio_rows

    return ratio_rows(wi)


# ----------------------------------------------------------------------------- flight
# impact.json (docs/spec.md + docs/flight.md) and its sidecar impact.nc:
# nominal/lo/hi(axis, time) = predicted TM velocity as a function of the impact time.

def _vt(rel: dict, axis: str, what: str):
    d = (rel.get(what) or {}).get(axis) or {}
    v, e = d.get("value"), d.get("stderr")
    return (np.nan if v is None else float(v)), (np.nan if e is None else float(e))


_PANEL = {"vx": "v_x (x–z plane)", "vz_xz": "v_z (x–z plane)", "wy": "ω_y (x–z plane)",
          "vy": "v_y (y–z plane)", "vz_yz": "v_z (y–z plane)", "wx": "ω_x (y–z plane)"}


def _joint(rel: dict):
    j = rel.get("joint") or {}
    v, ci = j.get("value"), j.get("ci95")
    if v is None or not ci:
        return None
    return float(v), float(ci[0]), float(ci[1]), j.get("chi2"), j.get("df"), j.get("p")


def fig_velocity_impact(imp: dict, curves=None, release: int = 0):
    """Fig. 11: the TM velocity the impact model predicts as a function of the impact time
    (line, band from the parameter and geometry uncertainties), the measured release velocity
    (red line), the estimated impact time of each axis (black, with its error bar), the joint
    estimate of the release (grey band: its 95 % interval) and, for synthetic telemetry, the
    true impact time, for each of the six axes of one release."""
    releases = imp.get("releases") or []
    if not releases or curves is None:
        return None
    rel = releases[release]
    truth = (imp.get("truth") or {}).get("impact_time")
    joint = _joint(rel)
    fig, axes = plt.subplots(2, 3, figsize=(10.0, 5.6), sharex=True)
    t = curves["time"].values * MS
    for ax, axis in zip(axes.ravel(), AXES):
        c = COLORS[axis]
        sc = 1e6
        nom = curves["nominal"].sel(axis=axis).values * sc
        ax.fill_between(t, curves["lo"].sel(axis=axis).values * sc,
                        curves["hi"].sel(axis=axis).values * sc, color=c, alpha=0.2, lw=0,
                        label="model band (95 %)")
        ax.plot(t, nom, color=c, lw=1.3, label="model: velocity vs impact time")
        v, ev = _vt(rel, axis, "velocity")
        ax.axhline(v * sc, color="#c62828", lw=1.0, label="measured release velocity")
        if joint is not None:
            ax.axvspan(joint[1] * MS, joint[2] * MS, color="#777777", alpha=0.18, lw=0,
                       label="joint estimate, 95 % interval")
            ax.axvline(joint[0] * MS, color="#555555", lw=1.0, label="joint estimate")
        ti, ei = _vt(rel, axis, "impact_time")
        if np.isfinite(ti):
            ax.errorbar([ti * MS], [v * sc], xerr=[0 if not np.isfinite(ei) else ei * MS],
                        fmt="o", color="k", ms=4, capsize=3,
                        label="impact time of the axis (±1σ)")
        else:
            ax.text(0.03, 0.92, "no impact time (see impact.json)", transform=ax.transAxes,
                    fontsize=7, color="#c62828")
        if truth is not None:
            ax.axvline(truth[release] * MS, color="k", ls=":", lw=0.9,
                       label="true impact time (synthetic)")
        ax.set_title(_PANEL[axis])
        ax.set_ylabel(AXIS_LABEL[axis])
    for ax in axes[-1]:
        ax.set_xlabel("impact time [ms]")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, bbox_to_anchor=(0.5, -0.07))
    model = {"3d": "one-contact 3D impact", "planar": "planar impacts (Appendix B)"}.get(
        imp.get("impact_model", "planar"), "impact model")
    head = f"Release {rel.get('id', release + 1)}: velocity vs impact time, {model}"
    if joint is not None:
        head += (f"; joint estimate {joint[0] * MS:.4f} ms "
                 f"[{joint[1] * MS:.4f}, {joint[2] * MS:.4f}]")
        if joint[5] is not None:
            head += f", χ² = {joint[3]:.2f} (df {joint[4]}, p = {joint[5]:.2g})"
    fig.suptitle(head, fontsize=9)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    return fig


def fig_impact_times(imp: dict):
    """Fig. 12: every estimated impact time (release x axis) with its 1-sigma error, the joint
    estimate of each release with its 95 % interval, and the true impact time of synthetic
    releases; the title gives Tukey's verdict and the joint χ² check."""
    releases = imp.get("releases") or []
    truth = (imp.get("truth") or {}).get("impact_time")
    fig, ax = plt.subplots(figsize=(10.0, 3.9))
    n = len(releases)
    width = 0.7
    count = 0
    for k, axis in enumerate(AXES):
        off = (k - (len(AXES) - 1) / 2) * width / len(AXES)
        ts = np.array([_vt(r, axis, "impact_time") for r in releases]).reshape(-1, 2)
        count += int(np.sum(np.isfinite(ts[:, 0])))
        ax.errorbar(np.arange(n) + off, ts[:, 0] * MS, yerr=ts[:, 1] * MS, fmt="o", ms=3.5,
                    color=COLORS[axis], capsize=2, label=_PANEL[axis])
    js = [_joint(r) for r in releases]
    xs = [i + width / 2 + 0.08 for i, j in enumerate(js) if j is not None]
    if xs:
        jv = np.array([j for j in js if j is not None])
        ax.errorbar(xs, jv[:, 0] * MS, yerr=[(jv[:, 0] - jv[:, 1]) * MS,
                                             (jv[:, 2] - jv[:, 0]) * MS],
                    fmt="D", ms=4.5, color="#444444", mfc="white", capsize=3,
                    label="joint estimate (95 %)")
    if truth is not None:
        ax.plot(np.arange(n) + 0.04, np.asarray(truth, float) * MS, "_", color="k", ms=26,
                mew=1.5, label="truth (synthetic)")
    ax.set_xticks(range(n), [str(r.get("id", i + 1)) for i, r in enumerate(releases)])
    ax.set_xlabel("release")
    ax.set_ylabel("impact time [ms]")
    ax.legend(ncol=4, loc="upper center", bbox_to_anchor=(0.5, -0.2))
    tk = imp.get("tukey") or {}
    verdict = ("" if tk.get("q_critical") is None else
               f"; Tukey (α = {tk.get('alpha')}, df = {tk.get('df')}): "
               + ("all compatible" if tk.get("all_compatible") else
                  f"{sum(p['reject'] for p in tk.get('pairs', []))} pair(s) rejected"))
    jc = imp.get("joint") or {}
    if jc.get("all_consistent") is not None:
        verdict += ("; joint χ²: all consistent" if jc["all_consistent"] else
                    f"; joint χ² rejects {len(jc.get('rejected', []))}")
    ax.set_title(f"{count} of {6 * n} impact times, {n} releases × 6 axes{verdict} "
                 "(cf. Fig. 12)", fontsize=9)
    fig.tight_layout()
    return fig


def fig_release_fit(tele, imp: dict, release: int = 0):
    """Fig. 11a: the test mass's x displacement around the release (telemetry) and the line
    whose slope is the release velocity v_x (fitted after the release)."""

    if tele is None or "x" not in tele or "release_time" not in tele:
        return None
    t = np.asarray(tele["time"].isel(release=release).values, float)
    x = np.asarray(tele["x"].isel(release=release).values, float)
    t_rel = float(tele["release_time"].values[release])
    ok = np.isfinite(t) & np.isfinite(x)
    t, x = t[ok] - t_rel, x[ok]
    after = t >= 0
    if after.sum() < 3:
        return None
    line = fit_release_velocity(t[after], x[after])
    rel = (imp.get("releases") or [{}])[release]
    rid = rel.get("id", release + 1)
    v = (rel.get("velocity") or {}).get("vx", {})
    fig, ax = plt.subplots(figsize=(8.0, 3.0))
    ax.plot(t, x * UM, "o", ms=3, color=COLORS["vx"], label="telemetry x (test mass)")
    tt = np.linspace(0, t.max(), 50)
    ax.plot(tt, (line.intercept + line.value * tt) * UM, "-", color="#c62828", lw=1.2,
            label=f"line fit after the release: v_x = {line.value * 1e6:.2f} µm/s")
    ax.axvline(0, color="k", lw=0.8, ls=":", label="release")
    ax.set_xlabel("time from the release [s]")
    ax.set_ylabel("x [µm]")
    ttl = f"Release {rid}: x displacement and release velocity (cf. Fig. 11a)"
    if v.get("value") is not None:
        ttl += f"; impact.json v_x = {v['value'] * 1e6:.2f} µm/s"
    ax.set_title(ttl)
    ax.legend(loc="upper left")
    fig.tight_layout()
    return fig


def fig_residuals(side, signals=("x_base", "x_head", "y_base", "y_head", "z_bk")):
    """Normalised residuals (mean signal - best fit) / sigma of the fitted signals: where the
    model departs from the data (the paper discusses these deviations after Fig. 6). Where
    the fit marginalised an unmodelled resonance (sidecar ``resonance_fitted``), the lines
    are what the fit minimised, (data - fit - resonance) / sigma, and the residuals before
    taking the resonance off are drawn thin beneath them."""
    if "model_best" not in side:
        return None
    t = side["time"].values * MS
    fig, ax = plt.subplots(figsize=(8.0, 3.0))
    res = "resonance_fitted" in side
    for s in signals:
        r = (side["data_mean"].sel(signal=s).values - side["model_best"].sel(signal=s).values) \
            / side["data_sigma"].sel(signal=s).values
        if res:
            ax.plot(t, r, "-", lw=0.6, alpha=0.35, color=_color(s))
            r = r - side["resonance_fitted"].sel(signal=s).values \
                / side["data_sigma"].sel(signal=s).values
        ax.plot(t, r, "-", lw=1.0, color=_color(s), label=s)
    ax.axhspan(-2, 2, color="#dddddd", alpha=0.5, lw=0, label="±2")
    ax.set_xlabel("time [ms]")
    ax.set_ylabel("(data − fit − resonance) / σ" if res else "(data − fit) / σ")
    ax.legend(ncol=6, loc="upper center", bbox_to_anchor=(0.5, -0.25))
    ax.set_title("Normalised residuals of the best fit" + (
        ", the marginalised resonance taken off (thin: with it)" if res else ""))
    fig.tight_layout()
    return fig


def fig_profiles(fit: dict):
    """Profile likelihoods (``gprm fit --profile``): the statistic D against each parameter,
    with the 68 % and 95 % thresholds; None where the fit has no profiles."""

    profs = [p for p in fit.get("profiles") or [] if p.get("grid")]
    if not profs:
        return None
    n = len(profs)
    cols = min(6, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(1.9 * cols, 1.7 * rows), squeeze=False)
    for ax, p in zip(axes.flat, profs):
        name = p["name"]
        g = np.array([from_si(v, name) for v in p["grid"]])
        d = np.array([np.nan if v is None else v for v in p["chi2"]], float)
        ident = fit["parameters"].get(name, {}).get("identified")
        ax.plot(g, d, "o-", ms=2.5, lw=1, color=COLORS["model"] if ident else "#999999")
        for lev, ls in ((1.0, ":"), (3.84, "--")):
            ax.axhline(lev, color="k", lw=0.6, ls=ls)
        ax.set_ylim(0, 8)
        lean = fit["parameters"].get(name, {}).get("leans_on_prior")
        ax.set_title(f"{name} [{REGISTRY[name].unit}]"
                     + ("" if ident else " (prior)" if lean else " (n.d.)"),
                     fontsize=7)
        ax.tick_params(labelsize=6)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.suptitle("Profile likelihoods: D = (Φ − Φ_min)/s² (dotted 68 %, dashed 95 %); grey: "
                 "not determined (n.d.) or leaning on the prior (prior)", fontsize=8)
    fig.tight_layout()
    return fig


def fig_sweep(sw: Sweep):
    """Best-fit overshoot against a swept parameter (the :class:`~gprm.predict.whatif.Sweep`
    of :func:`gprm.predict.whatif.sweep`): one panel per axis, a line per point."""
    x = np.asarray(sw.display_values, float)
    fig, axes = plt.subplots(1, len(sw.axes), figsize=(10.0, 3.4))
    for j, (ax, a) in enumerate(zip(np.atleast_1d(axes), sw.axes)):
        for i, p in enumerate(sw.points):
            ax.plot(x, sw.overshoot[:, i, j] * UM, "o-",
                    color=COLORS.get(p, COLORS["model"]), label=p)
        ax.set_xlabel(f"{sw.parameter} [{sw.display_unit}]")
        ax.set_ylabel(f"overshoot {a} [µm]")
    np.atleast_1d(axes)[0].legend()
    fig.suptitle(f"Overshoot against {sw.parameter}")
    fig.tight_layout()
    return fig
