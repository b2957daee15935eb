"""Impact time per release and axis: first crossing of the measured release velocity with the
predicted velocity-vs-impact-time curve (Section 4.1, Fig. 11b-c).

Error bar (linear propagation at the crossing t*): the measured velocity's standard error s_m
and the curve's band σ_c(t*) are independent, and both move the crossing by their size over
the local slope of the curve, so σ_t = sqrt(s_m² + σ_c(t*)²) / |dv/dt(t*)|.
A release/axis without a crossing gets ``value = None`` with a reason.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ImpactTime:
    value: float | None
    stderr: float | None
    slope: float | None = None
    sigma_curve: float | None = None
    reason: str | None = None

    def to_json(self) -> dict:
        d = {"value": self.value, "stderr": self.stderr}
        if self.value is not None:
            d["slope"] = self.slope
            d["sigma_curve"] = self.sigma_curve
        if self.reason is not None:
            d["reason"] = self.reason
        return d


def first_crossing(time, curve, sigma, v_meas: float, s_meas: float) -> ImpactTime:
    """First time the curve (T,) crosses the measured velocity ``v_meas`` (± ``s_meas``).

    The crossing is searched between consecutive grid points where the curve is defined
    (an exact touch of a grid point counts); t* by linear interpolation, slope from the
    bracketing points, σ_c interpolated (NaN σ_c counts as 0 and is flagged by the reason
    field staying empty only when finite).
    """
    t = np.asarray(time, float)
    c = np.asarray(curve, float)
    s = np.asarray(sigma, float)
    fin = np.isfinite(c)
    if not fin.any():
        return ImpactTime(None, None, reason="no impact possible in the window (the contact "
                                             "point never approaches the indent face)")
    d = c - v_meas
    ok = fin[:-1] & fin[1:]
    touch = fin & (d == 0)
    cross = ok & (np.sign(d[:-1]) * np.sign(d[1:]) < 0)
    cand = np.flatnonzero(cross | touch[:-1])
    if touch[-1]:
        cand = np.append(cand, t.size - 1)
    if cand.size == 0:
        lo, hi = float(np.nanmin(c)), float(np.nanmax(c))
        where = "above" if v_meas > hi else ("below" if v_meas < lo else "between pieces of")
        return ImpactTime(None, None, reason=f"no crossing: measured {v_meas:.6g} is {where} "
                                             f"the predicted range [{lo:.6g}, {hi:.6g}]")
    i = int(cand[0])
    if touch[i] and (i == t.size - 1 or not ok[i]):
        j0, j1 = (i - 1, i) if i > 0 and fin[i - 1] else (i, i + 1)
        ts = t[i]
    else:
        j0, j1 = i, i + 1
        ts = t[i] + d[i] / (d[i] - d[i + 1]) * (t[i + 1] - t[i]) if d[i] != 0 else t[i]
    if j1 >= t.size or not (fin[j0] and fin[j1]):
        return ImpactTime(float(ts), None, reason="crossing at an isolated point: slope unknown")
    slope = (c[j1] - c[j0]) / (t[j1] - t[j0])
    w = 0.0 if t[j1] == t[j0] else (ts - t[j0]) / (t[j1] - t[j0])
    sc = (1 - w) * s[j0] + w * s[j1]
    sc = 0.0 if not np.isfinite(sc) else float(sc)
    if slope == 0:
        return ImpactTime(float(ts), None, 0.0, sc, reason="zero slope at the crossing")
    st = float(np.sqrt(s_meas ** 2 + sc ** 2) / abs(slope))
    return ImpactTime(float(ts), st, float(slope), sc)
