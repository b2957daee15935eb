"""Residual-covariance estimators of the default uncertainty on Monte Carlo series (issue 21,
docs/fitting.md "Where the over-coverage comes from"): for each kind of residual series, the
mean of each estimator of Var(sum_t B_t r_t) over the actual variance of that sum, per
sensitivity (min-max over four sensitivities), on a window of 47 samples like the fit's.

    .venv/bin/python benchmarks/bench_residual_covariance.py [--series 3000] [--seed 1]

Series: white; AR(1) 0.8 (low-pass); 1/f (pink); a random-phase 28 kHz oscillation at
200 kHz sampling plus white noise; white noise with a variance peak; white noise plus a
per-realisation offset and ramp. Sensitivities: damped oscillations at 3, 7 and 12 kHz and a
ramp. Estimators: the default (AR(2)-prewhitened scores, Parzen window of T/4 lags), its
variants, and the stationary (Toeplitz) covariance of the residuals over all lags, with and
without a local variance envelope.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.linalg import toeplitz
from scipy.ndimage import gaussian_filter1d

from gprm.fit import sandwich as sw

T = 47
t = np.arange(T)
B = np.stack([np.exp(-t / 30) * np.sin(2 * np.pi * f * t / 200) for f in (3, 7, 12)] + [t / T])
KINDS = ("white", "low-pass", "1/f", "oscillation", "variance peak", "offset")


def series(kind: str, n: int, rng) -> np.ndarray:
    if kind == "white":
        return rng.standard_normal((n, T))
    if kind == "low-pass":
        e = rng.standard_normal((n, T + 200))
        x = np.zeros_like(e)
        for i in range(1, e.shape[1]):
            x[:, i] = 0.8 * x[:, i - 1] + e[:, i]
        return x[:, 200:]
    if kind == "1/f":
        f = np.fft.rfftfreq(4 * T)
        amp = np.where(f > 0, 1 / np.sqrt(np.maximum(f, 1e-9)), 0)
        Z = (rng.standard_normal((n, f.size)) + 1j * rng.standard_normal((n, f.size))) * amp
        return np.fft.irfft(Z, 4 * T, axis=1)[:, :T]
    if kind == "oscillation":
        ph = rng.uniform(0, 2 * np.pi, (n, 1))
        return 3 * np.sin(2 * np.pi * 28 * t / 200 + ph) + rng.standard_normal((n, T))
    if kind == "variance peak":
        return rng.standard_normal((n, T)) * (0.3 + 2 * np.exp(-((t - 15) / 6.0) ** 2))
    return (rng.standard_normal((n, T)) + 1.5 * rng.standard_normal((n, 1))
            + 1.5 * rng.standard_normal((n, 1)) * t / T)


def hac(order: int, lags: int, kernel: str = "parzen"):
    return lambda r: sw.hac_meat(sw.prewhitened_scores(B, r, order), lags, kernel)


def toeplitz_cov(envelope: float | None = None):
    def est(r):
        s = np.sqrt(gaussian_filter1d(r ** 2, envelope, mode="nearest")) if envelope else \
            np.ones(T)
        z = r / s
        g = np.array([z[:T - lag] @ z[lag:] / T for lag in range(T)])
        return B @ (toeplitz(g) * np.outer(s, s)) @ B.T
    return est


ESTIMATORS = {
    "default: AR(2), Parzen T/4": hac(2, T // 4),
    "AR(2), no window": hac(2, 0),
    "AR(2), Parzen 5": hac(2, 5),
    "AR(4), Parzen T/4": hac(4, T // 4),
    "no prewhitening, Parzen T/4": hac(0, T // 4),
    "no prewhitening, Parzen T/2": hac(0, T // 2),
    "no prewhitening, Bartlett T/4": hac(0, T // 4, "bartlett"),
    "Toeplitz, all lags": toeplitz_cov(),
    "Toeplitz, variance envelope 4": toeplitz_cov(4.0),
}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--series", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args(argv)
    rng = np.random.default_rng(a.seed)
    data = {k: series(k, a.series, rng) for k in KINDS}
    true = {k: np.var(data[k] @ B.T, axis=0) for k in KINDS}
    n_est = max(1, a.series // 5)
    print(f"mean estimate / actual variance, min-max over the sensitivities ({a.series} series "
          f"per kind for the variance, {n_est} for the estimators' mean; seed {a.seed})\n")
    print("| estimator | " + " | ".join(KINDS) + " |")
    print("|---" * (len(KINDS) + 1) + "|")
    for name, est in ESTIMATORS.items():
        cells = []
        for k in KINDS:
            m = np.mean([np.diag(est(r)) for r in data[k][:n_est]], axis=0) / true[k]
            cells.append(f"{m.min():.2f}-{m.max():.2f}")
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
