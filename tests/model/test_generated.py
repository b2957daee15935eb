"""The committed generated code is current and consistent.

The full Lagrange derivation takes ~25 s per piezo, so currency is checked by (1) the source
fingerprint the generator stamps into the files and (2) a fresh, independent linearisation
(Hessians of the energies, conftest.py) evaluated at random parameter sets; the derivative
functions are checked against finite differences and the nonlinear M(x), f(x, x') against the
linear matrices and against the energy balance of the Lagrangian.
"""

import re

import numpy as np
import pytest
import sympy as sp

from gprm.model.definition import COORDINATES, DEFINITIONS, EOM_PARAMETERS, make_symbols
from gprm.model.derive import definition_fingerprint, generated_path
from gprm.model.linear import generated
from gprm.params import paper


def _as_batch(sets):
    return {k: np.array([s[k] for s in sets], float) for k in sets[0]}


@pytest.mark.parametrize("piezo", [1, 2])
def test_fingerprint_is_current(piezo):
    """The generator stamps the hash of definition.py + derive.py; editing either without
    regenerating (``python -m gprm.model.derive``) fails here."""
    text = generated_path(piezo).read_text(encoding="utf-8")
    m = re.search(r"# fingerprint: ([0-9a-f]+)", text)
    assert m and m.group(1) == definition_fingerprint()


@pytest.mark.parametrize("piezo", [1, 2])
def test_linear_matrices_equal_fresh_linearisation(piezo, linearised, random_sets):
    s, M0, C0, K0, F = linearised[piezo]
    syms = [s.p[n] for n in EOM_PARAMETERS]
    f = sp.lambdify(syms, (M0, C0, K0), "numpy")
    sets = [dict(ps.values) for ps in [paper()] + random_sets(4, seed=piezo)]
    M, C, K = generated(piezo).linear_matrices(_as_batch(sets))
    for b, vals in enumerate(sets):
        for got, want in zip((M[b], C[b], K[b]), f(*[vals[n] for n in EOM_PARAMETERS])):
            want = np.array(want, float)
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-13 * np.abs(want).max())
    assert np.array_equal(np.asarray(generated(piezo).INPUT, float),
                          np.array(F, float).ravel())


@pytest.mark.parametrize("piezo", [1, 2])
def test_parameter_derivatives_match_finite_differences(piezo, random_sets):
    g = generated(piezo)
    vals = dict(random_sets(1, seed=5 + piezo)[0].values)
    assert set(g.DERIVATIVES) == set(g.PARAMETERS)
    for name, fn in g.DERIVATIVES.items():
        h = 1e-6 * abs(vals[name])
        up, dn = dict(vals), dict(vals)
        up[name] += h
        dn[name] -= h
        mats_up = g.linear_matrices(_as_batch([up]))
        mats_dn = g.linear_matrices(_as_batch([dn]))
        exact = fn(_as_batch([vals]))
        for a, b, d in zip(mats_up, mats_dn, exact):
            fd = (a[0] - b[0]) / (2 * h)
            scale = max(np.abs(fd).max(), np.abs(d[0]).max(), 1e-300)
            assert np.abs(fd - d[0]).max() <= 1e-6 * scale, name


@pytest.mark.parametrize("piezo", [1, 2])
def test_nonlinear_terms_reduce_to_linear_at_rest(piezo):
    """M(0) = M0; df/dx(0, 0) = K0; df/dx'(0, 0) = C0 (central differences)."""
    g = generated(piezo)
    p = dict(paper().values)
    M, C, K = (a[0] for a in g.linear_matrices(_as_batch([p])))
    z = np.zeros(9)
    Mnl, f0 = g.nonlinear(z, z, p)
    np.testing.assert_allclose(Mnl, M, rtol=1e-13, atol=1e-18)
    np.testing.assert_allclose(f0, 0.0, atol=1e-18)
    scales = np.array([1e-6, 1e-6, 1e-7, 1e-7, 1e-5, 1e-5, 1e-5, 1e-5, 1e-4])
    for j in range(9):
        e = np.zeros(9)
        e[j] = scales[j] * 1e-3
        dfx = (g.nonlinear(e, z, p)[1] - g.nonlinear(-e, z, p)[1]) / (2 * e[j])
        dfv = (g.nonlinear(z, e, p)[1] - g.nonlinear(z, -e, p)[1]) / (2 * e[j])
        np.testing.assert_allclose(dfx, K[:, j], rtol=1e-6, atol=1e-6 * np.abs(K).max())
        np.testing.assert_allclose(dfv, C[:, j], rtol=1e-6, atol=1e-6 * np.abs(C).max())


def test_nonlinear_equations_conserve_energy_up_to_dissipation():
    """Along the full nonlinear equations, d(T + U)/dt = V q' - 2 D (Rayleigh dissipation is
    quadratic). Evaluated at random (large) states with T, U, D lambdified from the definition:
    an independent check of the generated f(x, x') including its Coriolis terms."""
    piezo = 2
    g = generated(piezo)
    s = make_symbols()
    en = DEFINITIONS[piezo].build(s)
    x = [s.x[c] for c in COORDINATES]
    xd = [s.xd[c] for c in COORDINATES]
    psyms = [s.p[n] for n in EOM_PARAMETERS]
    E = en.T + en.U
    grad_x = sp.lambdify([x, xd, psyms], [sp.diff(E, v) for v in x], "numpy")
    grad_xd = sp.lambdify([x, xd, psyms], [sp.diff(en.T, v) for v in xd], "numpy")
    Dfun = sp.lambdify([x, xd, psyms], en.D, "numpy")
    p = dict(paper().values)
    pv = [p[n] for n in EOM_PARAMETERS]
    rng = np.random.default_rng(3)
    Q = np.asarray(g.INPUT)
    for _ in range(5):
        xs = rng.normal(size=9) * np.array([1e-5, 1e-5, 1e-5, 1e-5, 0.05, 0.05, 1e-4, 1e-4, 1e-4])
        vs = rng.normal(size=9) * np.array([1, 1, 1, 1, 100, 100, 1, 1, 0])
        Vin = 120 * rng.uniform()
        # q has no inertia: its equation f_q(x, x') = V fixes q' (f_q is affine in q')
        f_a = g.nonlinear(xs, vs, p)[1][8]
        v2 = vs.copy()
        v2[8] = 1.0
        f_b = g.nonlinear(xs, v2, p)[1][8]
        vs[8] = (Vin - f_a) / (f_b - f_a)
        M, f = g.nonlinear(xs, vs, p)
        acc = np.zeros(9)
        acc[:8] = np.linalg.solve(M[:8, :8], (Q * Vin - f)[:8])
        dEdt = (np.dot(grad_x(xs, vs, pv), vs) + np.dot(grad_xd(xs, vs, pv), acc))
        power = Vin * vs[8] - 2 * Dfun(xs, vs, pv)
        scale = abs(Vin * vs[8]) + 2 * abs(Dfun(xs, vs, pv))
        assert abs(dEdt - power) <= 1e-9 * scale
