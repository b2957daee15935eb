"""Figures of the report, one function per figure of the paper it mirrors. Each takes the
stage's output (xarray Dataset or dict) and returns a matplotlib Figure; nothing is read
from disk here. Displacements are shown in micrometres, times in milliseconds.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

# One colour per quantity, used in every figure.
COLORS = {
    "x_base": "#1f77b4", "x_head": "#0b3d91", "y_base": "#d62728", "y_head": "#8c1a1a",
    "z_bk": "#2ca02c", "x_lr": "#9ecae1", "x_fl": "#c6dbef", "y_lr": "#fc9272",
    "y_fl": "#fcbba1", "z_fl": "#a1d99b", "data": "#1f4e79", "model": "#e6550d",
    "band": "#fdae6b", "measured": "#3182bd", "predicted": "#fd8d3c", "nominal": "#31a354",
    "vx": "#1f77b4", "vz_xz": "#17becf", "wy": "#9467bd", "vy": "#d62728", "vz_yz": "#ff7f0e",
    "wx": "#8c564b", "truth": "#111111", "piezo2": "#9aa3ad",
    "M_xz": "#1f77b4", "M_yz": "#d62728", "tip": "#2ca02c",
}
# the six flight axes, in the order of INTERFACES.md
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
    fig, axes = plt.subplots(len(signals), 1, figsize=(7.5, 1.9 * len(signals)), sharex=True)
    t = side["time"].values * MS
    for ax, s in zip(np.atleast_1d(axes), signals):
        d = side["data_mean"].sel(signal=s).values * UM
        e = side["data_sigma"].sel(signal=s).values * UM
        ax.fill_between(t, d - e, d + e, color=COLORS["data"], alpha=0.18, lw=0,
                        label="data ±σ")
        ax.plot(t, d, ".", ms=2.5, color=COLORS["data"], label="mean signal")
        if "model_best" in side:
            m = side["model_best"].sel(signal=s).values * UM
            lo = side["band_sample_lo"].sel(signal=s).values * UM
            hi = side["band_sample_hi"].sel(signal=s).values * UM
            if np.all(np.isfinite(lo)):
                ax.fill_between(t, lo, hi, color=COLORS["band"], alpha=0.5, lw=0,
                                label="model 95 % band")
            ax.plot(t, m, "-", lw=1.2, color=COLORS["model"], label="best fit")
        ax.set_ylabel(f"{s} [µm]")
    np.atleast_1d(axes)[0].legend(ncol=4, loc="upper left")
    np.atleast_1d(axes)[-1].set_xlabel("time [ms]")
    fig.suptitle("Best fit of the five signals (cf. Fig. 6)")
    fig.tight_layout()
    return fig


def fig_waterfall(side):
    """Sorted final chi-square of every start: how many reach the best."""
    chi = np.sort(side["chi2"].values[np.isfinite(side["chi2"].values)])
    fig, ax = plt.subplots(figsize=(7.5, 3.0))
    best = chi[0]
    ax.semilogy(np.arange(1, chi.size + 1), chi - best + 1.0, ".", ms=3,
                color=COLORS["model"])
    ax.axhline(2.0, color="k", lw=0.8, ls="--", label="Δχ² = 1 from the best")
    n_best = int(np.sum(chi <= best + 1))
    ax.set_xlabel("start (sorted by final χ²)")
    ax.set_ylabel("χ² − χ²_best + 1")
    ax.set_title(f"Waterfall of {chi.size} starts: {n_best} within Δχ² ≤ 1 of the best "
                 f"(χ²_best = {best:.4g})")
    ax.legend(loc="lower right")
    fig.tight_layout()
    return fig


def fig_masses(fit: dict, truth: dict | None = None):
    """Fig. 7: fitted masses (± 1 sigma) against the CAD nominal, the initial value, the
    paper's 3D fit and, for synthetic data, the truth."""
    from gprm.params import REGISTRY

    names = [n for n in ("m1", "m2", "m3", "m4") if n in fit["parameters"]]
    fig, axes = plt.subplots(1, len(names), figsize=(8.6, 2.9))
    for ax, n in zip(np.atleast_1d(axes), names):
        p = fit["parameters"][n]
        spec = REGISTRY[n]
        cols = [("fit", p["value"], p.get("stderr"), "o", COLORS["model"])]
        cols.append(("paper", spec.default, spec.paper_stderr, "D", "#7f7f7f"))
        if spec.nominal is not None:
            cols.append(("CAD", spec.nominal, None, "s", COLORS["nominal"]))
        if truth and n in truth:
            cols.append(("truth", truth[n], None, "*", COLORS["truth"]))
        for i, (lab, v, e, mk, c) in enumerate(cols):
            ax.errorbar([i], [v * 1e3], yerr=None if e is None else [e * 1e3], fmt=mk,
                        color=c, ms=7 if mk == "*" else 5, capsize=4, label=lab)
        ax.set_xticks(range(len(cols)), [c[0] for c in cols])
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
    ax.legend()
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
        ax.set_xlabel("time [ms]")
        ax.set_ylabel("displacement [µm]")
    fig.suptitle("Campaign mean signals (cf. Fig. 3)")
    fig.tight_layout()
    return fig


# ----------------------------------------------------------------------------- prediction

def _find(ds, *names):
    """The first of ``names`` that ``ds`` holds (variables of the prediction files)."""
    for n in names:
        if n in ds.variables:
            return ds[n]
    return None


def _trace(ds, point: str, comp: str):
    """Displacement (m) of a body point along one axis, relative to its initial position:
    the best-fit trace and, if present, the sample spread (lo, hi)."""
    v = _find(ds, f"{point}_{comp}", f"{point}.{comp}", f"{comp}_{point}")
    if v is None and "point" in ds.dims:
        base = _find(ds, comp, f"r_{comp}", f"pos_{comp}")
        if base is not None and point in [str(p) for p in ds["point"].values]:
            v = base.sel(point=point)
    if v is None:
        return None
    arr = np.asarray(v.values, float)
    if arr.ndim == 2:        # (sample, time): the first sample is the best fit
        best, samples = arr[0], arr
    else:
        best, samples = arr, None
    best = best - best[0]
    lo = hi = None
    if samples is not None and samples.shape[0] > 2:
        rel = samples - samples[:, :1]
        lo, hi = np.percentile(rel, [2.5, 97.5], axis=0)
    return best, lo, hi


_PLANES = (("M_xz", "x", "z", "M_xz in the x–z plane"), ("M_yz", "y", "z", "M_yz in the y–z plane"),
           ("tip", "x", "y", "tip edge in the x–y plane"))


def fig_trajectories(ds, title: str, ref=None):
    """Figs. 10, 13, 14: the contact middle points and the tip edge, projected on the planes.
    Start (blue star) and end (red star) as in the paper; ``ref`` (grey) for comparison."""
    fig, axes = plt.subplots(1, 3, figsize=(9.6, 3.3))
    for ax, (pt, a, b, lab) in zip(axes, _PLANES):
        for src, colour, lw, name in ((ref, COLORS["piezo2"], 0.9, "Piezo 2 (as built)"),
                                      (ds, COLORS[pt], 1.3, "prediction")):
            if src is None:
                continue
            ta, tb = _trace(src, pt, a), _trace(src, pt, b)
            if ta is None or tb is None:
                continue
            ax.plot(ta[0] * UM, tb[0] * UM, "-", color=colour, lw=lw, label=name)
            if src is ds:
                ax.plot(ta[0][0] * UM, tb[0][0] * UM, "*", color="#1f4eb4", ms=9,
                        label="start")
                ax.plot(ta[0][-1] * UM, tb[0][-1] * UM, "*", color="#c62828", ms=9,
                        label="end (1.2 ms)")
        ax.set_xlabel(f"{a} [µm]")
        ax.set_ylabel(f"{b} [µm]")
        ax.set_title(lab)
    axes[0].legend(loc="best")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def fig_energy(pred, run=None):
    """Fig. 8: kinetic energy, predicted (3D model) against measured."""
    pe = _find(pred, "kinetic_energy_predicted", "energy_predicted", "kinetic_energy")
    me = _find(pred, "kinetic_energy_measured", "energy_measured")
    if pe is None:
        return None
    fig, ax = plt.subplots(figsize=(7.5, 3.0))
    vals = np.atleast_1d(np.asarray(pe.values, float)).ravel()
    if me is not None:
        mv = np.atleast_1d(np.asarray(me.values, float)).ravel()
        both = np.concatenate([vals, mv])
        bins = np.linspace(both.min(), both.max(), 30) if both.ptp() > 0 else 10
        ax.hist(mv * 1e9, bins=bins if np.isscalar(bins) else bins * 1e9,
                color=COLORS["measured"], alpha=0.6, label="measured")
    else:
        bins = 30
    ax.hist(vals * 1e9, bins=bins if np.isscalar(bins) else bins * 1e9,
            color=COLORS["predicted"], alpha=0.6, label="3D model")
    ax.set_xlabel("kinetic energy [nJ]")
    ax.set_ylabel("count")
    ax.legend()
    ax.set_title("Kinetic energy at the tip retraction (cf. Fig. 8)")
    fig.tight_layout()
    return fig


_PAPER_WHATIF = {"piezo1": "4.0, 6.4, 3.8", "ecc10": "40.0, 64.6, —"}


def whatif_rows(wi: dict) -> list:
    rows = []
    for name, r in (wi.get("ratios") or {}).items():
        if not isinstance(r, dict):
            continue
        rows.append((name, *(f"{r[k]:.3g}" if isinstance(r.get(k), (int, float)) else "—"
                             for k in ("x", "y", "z")), _PAPER_WHATIF.get(name, "—")))
    return rows


# ----------------------------------------------------------------------------- flight

def _vt(rel: dict, axis: str, what: str):
    d = (rel.get(what) or {}).get(axis) or {}
    v, e = d.get("value"), d.get("stderr")
    return (np.nan if v is None else float(v)), (np.nan if e is None else float(e))


def _unit_scale(axis: str) -> float:
    return 1e6


def fig_velocity_impact(imp: dict, tele=None):
    """Fig. 11: predicted release velocity as a function of the impact time (with its band),
    the measured velocity and the estimated impact time, for the first release; without
    stored curves, the measured velocity of every release against its impact time."""
    releases = imp.get("releases") or []
    if not releases:
        return None
    fig, axes = plt.subplots(2, 3, figsize=(9.6, 5.0), sharex=True)
    curves = imp.get("curves") or {}
    rel0 = releases[0]
    for ax, axis in zip(axes.ravel(), AXES):
        c = COLORS[axis]
        sc = _unit_scale(axis)
        cv = curves.get(axis) if isinstance(curves, dict) else None
        if cv and "time" in cv and "velocity" in cv:
            t = np.asarray(cv["time"], float) * MS
            ax.plot(t, np.asarray(cv["velocity"], float) * sc, color=c, lw=1.2,
                    label="model v(t_impact)")
            if "lo" in cv and "hi" in cv:
                ax.fill_between(t, np.asarray(cv["lo"]) * sc, np.asarray(cv["hi"]) * sc,
                                color=c, alpha=0.2, lw=0, label="band")
            v, ev = _vt(rel0, axis, "velocity")
            ax.axhline(v * sc, color="#c62828", lw=1, label="measured")
            ti, ei = _vt(rel0, axis, "impact_time")
            if np.isfinite(ti):
                ax.errorbar([ti * MS], [v * sc], xerr=[ei * MS], fmt="o", color="k", ms=3,
                            capsize=3, label="impact time")
        else:
            vs = np.array([_vt(r, axis, "velocity") for r in releases])
            ts = np.array([_vt(r, axis, "impact_time") for r in releases])
            ax.errorbar(ts[:, 0] * MS, vs[:, 0] * sc, xerr=ts[:, 1] * MS, yerr=vs[:, 1] * sc,
                        fmt="o", color=c, ms=4, capsize=2, label="releases")
        ax.set_title(axis)
        ax.set_ylabel(AXIS_LABEL[axis])
    for ax in axes[-1]:
        ax.set_xlabel("impact time [ms]")
    axes[0, 0].legend(loc="best")
    fig.suptitle("Release velocity vs impact time (cf. Fig. 11)")
    fig.tight_layout()
    return fig


def fig_impact_times(imp: dict, tele=None):
    """Fig. 12: every estimated impact time (release x axis) with its 1-sigma error."""
    releases = imp.get("releases") or []
    fig, ax = plt.subplots(figsize=(8.6, 3.4))
    n = len(releases)
    width = 0.7
    for k, axis in enumerate(AXES):
        off = (k - (len(AXES) - 1) / 2) * width / len(AXES)
        ts = np.array([_vt(r, axis, "impact_time") for r in releases]).reshape(-1, 2)
        ax.errorbar(np.arange(n) + off, ts[:, 0] * MS, yerr=ts[:, 1] * MS, fmt="o", ms=3.5,
                    color=COLORS[axis], capsize=2, label=axis)
    ax.set_xticks(range(n), [str(r.get("id", i + 1)) for i, r in enumerate(releases)])
    ax.set_xlabel("release")
    ax.set_ylabel("impact time [ms]")
    ax.legend(ncol=6, loc="upper center", bbox_to_anchor=(0.5, -0.22))
    ax.set_title(f"All {sum(np.isfinite(_vt(r, a, 'impact_time')[0]) for r in releases for a in AXES)}"
                 " estimated impact times (cf. Fig. 12)")
    fig.tight_layout()
    return fig
