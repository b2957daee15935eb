"""Tukey's range test across the six axes (Section 4.1, Eq. 9).

Each velocity component is a treatment, each release's estimated impact time an observation.
With equal group sizes n the statistic is Eq. 9, q_ab = |μ_a − μ_b| / sqrt(mse / n); with
unequal sizes (axes without a crossing) the Tukey–Kramer form
q_ab = |μ_a − μ_b| / sqrt(mse/2 · (1/n_a + 1/n_b)) is used, which equals Eq. 9 when
n_a = n_b = n. mse is the pooled within-treatment variance with df = N − k degrees of freedom
(k = 6, df = 60 for 11 complete releases). p-values and the critical value come from the
studentized range distribution (``scipy.stats.studentized_range``).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations
from typing import Mapping, Sequence

import numpy as np
from scipy.stats import studentized_range

from gprm.errors import GprmInputError


@dataclass(frozen=True)
class TukeyPair:
    a: str
    b: str
    mean_a: float
    mean_b: float
    n_a: int
    n_b: int
    q: float
    p: float
    reject: bool


@dataclass(frozen=True)
class TukeyResult:
    alpha: float
    k: int
    df: int
    mse: float
    q_critical: float
    means: dict
    counts: dict
    pairs: tuple[TukeyPair, ...]
    method: str  # "tukey" (equal n, Eq. 9) or "tukey-kramer"

    def to_json(self) -> dict:
        """JSON-ready dict (a non-finite q, from a zero within-treatment variance, is null)."""
        fin = lambda x: float(x) if np.isfinite(x) else None  # noqa: E731
        return {"alpha": self.alpha, "k": self.k, "df": self.df, "mse": self.mse,
                "q_critical": self.q_critical, "method": self.method,
                "means": self.means, "counts": self.counts,
                "pairs": [{"a": p.a, "b": p.b, "mean_a": p.mean_a, "mean_b": p.mean_b,
                           "n_a": p.n_a, "n_b": p.n_b, "q": fin(p.q), "p": p.p,
                           "reject": p.reject} for p in self.pairs]}


def tukey_range_test(groups: Mapping[str, Sequence[float]], alpha: float = 0.01,
                     *, source: str = "impact times") -> TukeyResult:
    """Tukey (Tukey–Kramer for unequal n) test of all pairs of treatments.

    ``groups`` maps a treatment name to its observations (non-finite values are an error:
    drop missing crossings before calling). Needs k >= 2 treatments, each with at least one
    observation, and N − k >= 1 residual degrees of freedom.
    """

    if not (0.0 < alpha < 1.0):
        raise GprmInputError(f"alpha must be in (0, 1), got {alpha}", field="alpha")
    names = list(groups)
    data = {k: np.asarray(groups[k], float).ravel() for k in names}
    for name, v in data.items():
        if not np.all(np.isfinite(v)):
            raise GprmInputError("non-finite observation", source=source, field=name)
    names = [k for k in names if data[k].size > 0]
    k = len(names)
    N = sum(data[n].size for n in names)
    df = N - k
    if k < 2 or df < 1:
        raise GprmInputError(f"Tukey test needs >= 2 treatments and N - k >= 1 "
                             f"(have k={k}, N={N})", source=source)
    means = {n: float(np.mean(data[n])) for n in names}
    counts = {n: int(data[n].size) for n in names}
    ss = sum(float(np.sum((data[n] - means[n]) ** 2)) for n in names)
    mse = ss / df
    qcrit = float(studentized_range.ppf(1.0 - alpha, k, df))
    equal = len(set(counts.values())) == 1
    pairs = []
    for a, b in combinations(names, 2):
        se = np.sqrt(mse / 2.0 * (1.0 / counts[a] + 1.0 / counts[b]))
        diff = abs(means[a] - means[b])
        q = float(diff / se) if se > 0 else (np.inf if diff > 0 else 0.0)
        p = float(studentized_range.sf(q, k, df)) if np.isfinite(q) else 0.0
        pairs.append(TukeyPair(a, b, means[a], means[b], counts[a], counts[b], q,
                               min(max(p, 0.0), 1.0), bool(q > qcrit)))
    return TukeyResult(float(alpha), k, int(df), float(mse), qcrit, means, counts,
                       tuple(pairs), "tukey" if equal else "tukey-kramer")
