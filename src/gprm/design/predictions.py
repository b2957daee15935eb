"""The release predictions a design is judged by, and their gradients in u.

- overshoots: the largest |displacement| over 0.95-1.2 ms of the four trajectory points on
  three axes in the three scenarios of Sec. 4.2 (as ``benchmarks/bench_coverage.py`` scores
  them), where the best fit's overshoot is at least 1 % of its scenario's largest;
- velocity curves: the test mass's post-impact velocity on the six axes if the impact
  happened at t, at 21 times over t_c .. t_c + 0.2 ms (nominal geometry, Fig. 11), where
  finite.

Gradients are central differences in u (step 1e-4; one batch of 2P + 1 simulations): the
overshoot is a maximum over time, whose derivative is that of the displacement at the
maximising time, which central differences follow.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gprm.fit.files import FittedModel
from gprm.flight.predicted import tm_velocity_vs_time
from gprm.params import batch_from_vectors
from gprm.predict.scenarios import standard_scenarios
from gprm.predict.trajectories import TRAJECTORY_POINTS, default_times, sampled_points
from gprm.predict.whatif import transform_batch
from gprm.simulate.kinematics import body_motion

STEP = 1e-4


@dataclass(frozen=True)
class ReleasePredictions:
    """Values (K,) at the best fit, gradients G (K, P) in u, and each row's group
    (``overshoot`` or ``velocity``) and label."""

    value: np.ndarray
    gradient: np.ndarray
    group: tuple[str, ...]
    label: tuple[str, ...]


def _evaluate(pb: dict, piezo: int) -> tuple[np.ndarray, list[str], list[str]]:
    vals, groups, labels = [], [], []
    times = default_times()
    for sc in standard_scenarios():
        pos, _, ok = sampled_points(transform_batch(pb, sc), times, TRAJECTORY_POINTS,
                                    piezo=sc.piezo)
        os_ = np.max(np.abs(pos), axis=-1)                    # (B, point, 3)
        os_ = np.where(ok[:, None, None], os_, np.nan)
        for i, p in enumerate(TRAJECTORY_POINTS):
            for k, a in enumerate("xyz"):
                vals.append(os_[:, i, k])
                groups.append("overshoot")
                labels.append(f"{sc.name} {p} {a}")
    t = float(pb["t_c"][0]) + np.linspace(0.0, 0.2e-3, 21)
    v = tm_velocity_vs_time(body_motion(pb, t, piezo=piezo))
    from gprm.flight.telemetry import AXES

    for a in AXES:
        for j, tj in enumerate(t):
            vals.append(np.asarray(v[a], float)[:, j])
            groups.append("velocity")
            labels.append(f"{a} at t_c+{(tj - t[0]) * 1e6:.0f}us")
    return np.stack(vals, 1), groups, labels


def release_predictions(fm: FittedModel, sd_u: np.ndarray, log: np.ndarray
                        ) -> ReleasePredictions:
    """The predictions at the best fit and their central-difference gradients in u (step
    ``STEP`` times each parameter's prior sd ``sd_u``)."""
    names = fm.names
    x = fm.params.vector(names)
    P = len(names)
    X = np.repeat(x[None], 2 * P + 1, 0)
    h = STEP * np.asarray(sd_u, float)
    for j in range(P):
        for s, row in ((1, 1 + 2 * j), (-1, 2 + 2 * j)):
            X[row, j] = x[j] * np.exp(s * h[j]) if log[j] else x[j] + s * h[j]
    with np.errstate(invalid="ignore"):
        vals, groups, labels = _evaluate(batch_from_vectors(fm.params, names, X), 2)
    v0 = vals[0]
    G = np.stack([(vals[1 + 2 * j] - vals[2 + 2 * j]) / (2 * h[j]) for j in range(P)], 1)
    groups_a = np.array(groups)
    keep = np.isfinite(v0) & np.all(np.isfinite(G), axis=1)
    # overshoots: the moving point-axes only (1 % of their scenario's largest)
    for sc in standard_scenarios():
        rows = np.array([g == "overshoot" and lab.split()[0] == sc.name
                         for lab, g in zip(labels, groups)])
        big = np.nanmax(np.abs(v0[rows]))
        keep &= ~rows | (np.abs(v0) > 0.01 * big)
    idx = np.flatnonzero(keep)
    return ReleasePredictions(v0[idx], G[idx], tuple(groups_a[idx]),
                              tuple(labels[i] for i in idx))
