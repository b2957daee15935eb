"""The structural argument of docs/fitting.md ("Identifiability"), checked on the generated
matrices: two springs at b1 and b1 + b2 enter the stiffness matrix only through their sum and
their first and second moments, so the dampers alone separate (k_Cy, k_Dy, b1, b2); and the
sample of a fit never hands a later stage a set it cannot simulate."""

from __future__ import annotations

import numpy as np
import pytest

from gprm.fit.files import FittedModel
from gprm.model.linear import admissible, generated
from gprm.params import batch, paper


def moments(kc, kd, b1, b2):
    return kc + kd, kc * b1 + kd * (b1 + b2), kc * b1 ** 2 + kd * (b1 + b2) ** 2


def same_moments(kc, kd, b1, b2, b1_new):
    """(k_C, k_D, b2) with b1 = b1_new and the same K0, K1, K2."""
    K0, K1, K2 = moments(kc, kd, b1, b2)
    A = K1 - K0 * b1_new                      # k_D b2
    B = K2 - K0 * b1_new ** 2 - 2 * b1_new * A  # k_D b2^2
    b2n = B / A
    kdn = A / b2n
    return K0 - kdn, kdn, b2n


@pytest.mark.parametrize("piezo", [1, 2])
def test_stiffness_sees_the_y_springs_only_through_three_moments(piezo):
    p = paper()
    kc, kd, b2n = same_moments(p["k_Cy"], p["k_Dy"], p["b1"], p["b2"], 0.95 * p["b1"])
    assert kc > 0 and kd > 0 and b2n > 0
    q = p.with_values(k_Cy=kc, k_Dy=kd, b1=0.95 * p["b1"], b2=b2n)
    M1, C1, K1 = generated(piezo).linear_matrices(batch([p]))
    M2, C2, K2 = generated(piezo).linear_matrices(batch([q]))
    np.testing.assert_allclose(K2, K1, rtol=1e-12, atol=1e-9 * np.abs(K1).max())
    np.testing.assert_array_equal(M2, M1)
    # the dampers at the moved points are what changes: C differs
    assert np.max(np.abs(C2 - C1)) > 1e-6 * np.abs(C1).max()
    # and the same holds in the x plane (k_Ax at d1, k_Bx at d1 + d2)
    ka, kb, d2n = same_moments(p["k_Ax"], p["k_Bx"], p["d1"], p["d2"], 0.99 * p["d1"])
    r = p.with_values(k_Ax=ka, k_Bx=kb, d1=0.99 * p["d1"], d2=d2n)
    _, _, K3 = generated(piezo).linear_matrices(batch([r]))
    np.testing.assert_allclose(K3, K1, rtol=1e-12, atol=1e-9 * np.abs(K1).max())


def test_admissible_rejects_a_missing_spring_and_sample_never_returns_one():
    p = paper()
    ok = admissible(batch([p, p.with_values(k_Dy=0.0), p.with_values(k_Ax=0.0, k_Bx=0.0)]), 2)
    assert ok.tolist() == [True, False, False]
    # a covariance so wide that most normal draws put a spring at or below zero
    names = p.fitted
    se = 2.0 * np.abs(p.vector(names))
    fm = FittedModel(p, np.diag(se ** 2))
    pb = fm.sample(64, seed=1)
    assert admissible(pb, 2).all()
    assert all(np.all(pb[n] > 0) for n in ("k_Cy", "k_Dy", "k_Ax", "m2"))
    # no uncertainty at all: the best fit, repeated, said so
    none = FittedModel(p, None)
    assert not none.has_uncertainty and "best fit only" in none.uncertainty_note
    pb0 = none.sample(3)
    assert np.all(pb0["k_Cy"] == p["k_Cy"])
