"""Figures of the identification (matplotlib, Agg backend; no display needed)."""

from __future__ import annotations

import numpy as np


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
    import matplotlib

    if ax is None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    c = np.asarray(chi2, float).ravel()
    finite = np.sort(c[np.isfinite(c)])
    n_failed = int(c.size - finite.size)
    if ax is None:
        fig, ax = plt.subplots(figsize=(6.0, 3.6), constrained_layout=True)
    else:
        fig = ax.figure
    if finite.size == 0:
        ax.text(0.5, 0.5, f"no start produced a finite chi-square ({c.size} failed)",
                ha="center", va="center", transform=ax.transAxes)
        return fig
    best = finite[0]
    n_best = int(np.sum(finite <= best + tol))
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
