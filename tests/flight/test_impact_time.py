"""First crossing of measured velocity and predicted curve, with its error bar."""

import numpy as np
import pytest

from gprm.flight.impact_time import first_crossing


def test_linear_curve_exact():
    t = np.linspace(1.0e-3, 1.1e-3, 101)
    a, b = -30.0, 0.04                      # v = a + b t  (m/s, m/s^2)
    v = a + b * t * 1e3                     # slope 40 m/s^2 per ms -> 4e4 m/s^2
    slope = b * 1e3
    vm = a + slope * 1.0437e-3
    r = first_crossing(t, v, np.full_like(t, 3e-6), vm, 4e-6)
    assert r.value == pytest.approx(1.0437e-3, rel=1e-12)
    assert r.slope == pytest.approx(slope, rel=1e-9)
    assert r.stderr == pytest.approx(np.hypot(3e-6, 4e-6) / slope, rel=1e-9)


def test_first_of_several_and_gaps():
    t = np.linspace(0, 1, 201)
    v = np.sin(2 * np.pi * 2 * t)           # crosses 0.5 four times
    v[5:15] = np.nan                        # the first crossing (t = 1/24) lies in a gap
    r = first_crossing(t, v, np.zeros_like(t), 0.5, 0.01)
    # next crossing: falling branch at t = 5/24
    assert r.value == pytest.approx(5 / 24, abs=2e-4)
    assert r.slope < 0


def test_no_crossing_reasons():
    t = np.linspace(0, 1, 11)
    r = first_crossing(t, t.copy(), np.zeros(11), 2.0, 0.1)
    assert r.value is None and "above" in r.reason
    r = first_crossing(t, np.full(11, np.nan), np.zeros(11), 0.5, 0.1)
    assert r.value is None and "no impact possible" in r.reason
    js = r.to_json()
    assert js["value"] is None and js["stderr"] is None and js["reason"]


def test_touch_at_grid_point():
    t = np.linspace(0, 1, 11)
    r = first_crossing(t, 2 * t, np.zeros(11), 0.6, 0.0)
    assert r.value == pytest.approx(0.3) and r.slope == pytest.approx(2.0)
