"""Shared fixtures for the model tests: an independent symbolic linearisation of the model
definition's energies (Hessians at rest), which is cheap (seconds) compared with the full
Lagrange derivation of ``gprm.model.derive`` (about 25 s per piezo)."""

import functools

import pytest
import sympy as sp

from gprm.model.definition import COORDINATES, DEFINITIONS, make_symbols


@functools.lru_cache(maxsize=None)
def hessian_linearisation(piezo: int):
    """M0 = d2T/dx'2, C0 = d2D/dx'2, K0 = d2U/dx2 at x = x' = 0 and the input vector.

    At rest (x = x' = 0) the Lagrange terms d/dt(dT/dx') - dT/dx are, to first order, exactly
    M0 x'' (T is quadratic in x'); this is the same linear model as derive.py's but reached by
    a different route."""
    s = make_symbols()
    en = DEFINITIONS[piezo].build(s)
    x = [s.x[c] for c in COORDINATES]
    xd = [s.xd[c] for c in COORDINATES]
    zero = {v: 0 for v in x + xd}
    at_rest = {v: 0 for v in x}
    n = len(COORDINATES)
    dT = [sp.diff(en.T, v).subs(at_rest) for v in xd]         # T is quadratic in x'
    M0 = sp.Matrix(n, n, lambda i, j: sp.diff(dT[i], xd[j]))
    dD = [sp.diff(en.D, v).subs(at_rest) for v in xd]
    C0 = sp.Matrix(n, n, lambda i, j: sp.diff(dD[i], xd[j]))
    dU = [sp.diff(en.U, v) for v in x]
    K0 = sp.Matrix(n, n, lambda i, j: sp.diff(dU[i], x[j]).subs(zero))
    F = sp.Matrix([en.input_force.get(c, 0) for c in COORDINATES])
    return s, M0, C0, K0, F


@pytest.fixture(scope="session")
def linearised():
    return {pz: hessian_linearisation(pz) for pz in (1, 2)}

