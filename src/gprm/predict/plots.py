"""Plots of the prediction products (matplotlib, Agg backend; each function writes one file
and returns its path). The report stage may draw its own; these are for notebooks and checks.
"""

from __future__ import annotations

import os

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(plt, fig, path) -> str:
    """Lay out, write ``path`` (120 dpi), close ``fig``; the path as a string."""
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return str(path)


def plot_trajectories(ds, path: str | os.PathLike) -> str:
    """Fig. 10 layout from a prediction dataset: M_xz on x-z, M_yz on y-z, tip edge on x-y
    (displacements in um, axes centred on the initial position; sampled trajectories thin)."""
    plt = _plt()
    fig, axs = plt.subplots(1, 3, figsize=(12, 4))
    spec = (("M_xz", "x", "z"), ("M_yz", "y", "z"), ("tip_edge", "x", "y"))
    for ax, (pt, a, b) in zip(axs, spec):
        p = ds["pos"].sel(point=pt)
        if "sample" in ds["pos_samples"].dims and ds.sizes.get("sample", 0):
            s = ds["pos_samples"].sel(point=pt)
            for k in range(s.sizes["sample"]):
                ax.plot(s.sel(axis=a)[k] * 1e6, s.sel(axis=b)[k] * 1e6, color="0.8", lw=0.5)
        ax.plot(p.sel(axis=a) * 1e6, p.sel(axis=b) * 1e6, color="C0", lw=1.2)
        ax.plot(p.sel(axis=a)[0] * 1e6, p.sel(axis=b)[0] * 1e6, "b*", ms=10, label="start")
        ax.plot(p.sel(axis=a)[-1] * 1e6, p.sel(axis=b)[-1] * 1e6, "r*", ms=10, label="end")
        ax.set_xlabel(f"{a} (um)")
        ax.set_ylabel(f"{b} (um)")
        ax.set_title(f"{pt}: {a}-{b}")
    axs[0].legend(loc="best", fontsize=8)
    return _save(plt, fig, path)


def plot_energy_histogram(ds, path: str | os.PathLike) -> str:
    """Fig. 8 layout: time per energy bin, model E_5 (with parameter error bars) beside the
    measured E_5 (with noise error bars) where present."""
    plt = _plt()
    e = np.asarray(ds["ke_edges"]) * 1e6
    c = 0.5 * (e[1:] + e[:-1])
    w = np.diff(e)
    fig, ax = plt.subplots(figsize=(7, 4))
    hm = np.asarray(ds["hist_model_point"]) * 1e6
    ax.bar(c - w / 4, hm, width=w / 2, color="gold", label="model")
    ax.errorbar(c - w / 4, hm, yerr=np.asarray(ds["hist_model_point_err"]) * 1e6, fmt="none",
                ecolor="darkorange")
    meas = np.asarray(ds["hist_measured"])
    if np.all(np.isfinite(meas)):
        ax.bar(c + w / 4, meas * 1e6, width=w / 2, color="C0", label="measured")
        ax.errorbar(c + w / 4, meas * 1e6, yerr=np.asarray(ds["hist_measured_err"]) * 1e6,
                    fmt="none", ecolor="navy")
    ax.set_xlabel("kinetic energy E_5 (uJ)")
    ax.set_ylabel("time in bin (us)")
    ax.legend()
    return _save(plt, fig, path)


def plot_masses(rows: list[dict], path: str | os.PathLike) -> str:
    """Fig. 7 layout: fitted masses with 1-sigma bars beside the nominal ones (g)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4))
    x = np.arange(len(rows))
    f = np.array([r["fitted"] for r in rows]) * 1e3
    s = np.array([np.nan if r["stderr"] is None else r["stderr"] for r in rows]) * 1e3
    n = np.array([np.nan if r["nominal"] is None else r["nominal"] for r in rows]) * 1e3
    ax.errorbar(x - 0.1, f, yerr=s, fmt="o", color="C1", label="fitted")
    ax.plot(x + 0.1, n, "s", color="C2", label="nominal (CAD)")
    ax.set_xticks(x, [f"{r['name']} ({r['body']})" for r in rows])
    ax.set_ylabel("mass (g)")
    ax.legend()
    return _save(plt, fig, path)


def plot_sweep(sw: dict, path: str | os.PathLike) -> str:
    """Overshoot against the swept parameter (one panel per axis, a line per point)."""
    plt = _plt()
    x = np.asarray(sw["display_values"])
    fig, axs = plt.subplots(1, len(sw["axes"]), figsize=(12, 3.8))
    for ax, a in zip(axs, sw["axes"]):
        for p in sw["points"]:
            ax.plot(x, np.asarray(sw["overshoot"][p][a]) * 1e6, "o-", label=p)
        ax.set_xlabel(f"{sw['parameter']} ({sw['display_unit']})")
        ax.set_ylabel(f"overshoot {a} (um)")
    axs[0].legend(fontsize=8)
    return _save(plt, fig, path)
