"""Structural and practical identifiability of the Table 3 parameters from the five signals
(issue 12): rank and null space of the sensitivity matrix over many points of the +-20 % box.

At each of N parameter sets drawn uniformly within +-20 % of Table 3 the relative sensitivity
matrix S = d y / d ln x (the five signals over the fit window at 200 kHz, each signal divided
by its rms so that all five count alike; exact sensitivities of the solver) is decomposed,
columns scaled to unit norm. Printed: the singular values s_i / s_1 (median and range over the
points) and, for the weakest directions, their largest components. A ratio near round-off
(< 1e-10) would be a structural non-identifiability; one far below the noise-to-signal ratio
of a campaign (about 1e-3 here) a practical one.

    .venv/bin/python benchmarks/bench_identifiability.py [--points 50] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from gprm.fit.objective import DEFAULT_WINDOW
from gprm.params import FITTED_DEFAULT, batch_from_vectors, paper
from gprm.simulate import OUTPUTS, observe

PHYSICAL = tuple(n for n in FITTED_DEFAULT if n not in ("t0", "t1"))


def spectra(points: int, seed: int, spread: float = 0.2):
    base = paper()
    names = PHYSICAL
    rng = np.random.default_rng(seed)
    x0 = base.vector(names)
    X = x0[None] * rng.uniform(1 - spread, 1 + spread, (points, len(names)))
    t = np.arange(DEFAULT_WINDOW[0], DEFAULT_WINDOW[1] + 1e-12, 5e-6)
    obs = observe(batch_from_vectors(base, names, X), t, OUTPUTS, piezo=2, sensitivities=names)
    y, dy = obs.y, obs.dy                                 # (B, S, T), (B, S, T, P)
    rms = np.sqrt(np.mean(y ** 2, axis=2))                # (B, S)
    S = dy * X[:, None, None, :] / rms[:, :, None, None]  # d y / d ln x, per-signal scaled
    S = S.reshape(points, -1, len(names))
    norms = np.linalg.norm(S, axis=1)
    S = S / norms[:, None, :]
    U, s, Vt = np.linalg.svd(S, full_matrices=False)
    return names, s / s[:, :1], Vt, norms / norms.max(axis=1, keepdims=True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    names, s, Vt, rel = spectra(a.points, a.seed)
    print(f"{a.points} points of the +-20 % box around Table 3, {len(names)} parameters "
          f"({time.perf_counter() - t0:.1f} s)")
    print("| i | s_i/s_1 median | min | max | largest components of direction i (median |v|) |")
    print("|---|---|---|---|---|")
    for i in range(len(names)):
        v = np.median(np.abs(Vt[:, i, :]), axis=0)
        top = np.argsort(-v)[:4]
        comp = ", ".join(f"{names[k]} {v[k]:.2f}" for k in top)
        print(f"| {i + 1} | {np.median(s[:, i]):.2e} | {s[:, i].min():.2e} | "
              f"{s[:, i].max():.2e} | {comp if i >= len(names) - 8 else ''} |")
    order = np.argsort(np.median(rel, axis=0))
    print("\nrelative sensitivity |d y / d ln x| / largest (median over the points): " +
          ", ".join(f"{names[k]} {np.median(rel[:, k]):.1e}" for k in order))
    print(f"numerical rank (s_i/s_1 > 1e-10): {int(np.min(np.sum(s > 1e-10, axis=1)))} to "
          f"{int(np.max(np.sum(s > 1e-10, axis=1)))} of {len(names)}; above 1e-3: "
          f"{int(np.median(np.sum(s > 1e-3, axis=1)))} (median)")


if __name__ == "__main__":
    main()
