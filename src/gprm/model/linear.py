"""The linear model in first-order (state-space) form, batched, with parameter derivatives.

State z = [xi_s, xi_s', xi_f] where xi_s are the 8 mechanical coordinates (second order) and
xi_f = q (first order, no inertia). From Eq. 2, M xi'' + C xi' + K xi = F V:

    E z' = A z + B V,   E = [[I, 0, 0], [0, M_ss, C_sf], [0, 0, C_ff]],
                        A = [[0, I, 0], [-K_ss, -C_ss, -K_sf], [-K_fs, -C_fs, -K_ff]].

so z' = A_s z + b V with A_s = E^-1 A, b = E^-1 B.
"""

from __future__ import annotations

import functools
import importlib
from dataclasses import dataclass
from types import ModuleType

import numpy as np

from gprm.model.coordinates import MECHANICAL
from gprm.model.piezo import check_piezo

#: the eight mechanical coordinates (``MECHANICAL``, the model's COORDINATES without the
#: charge q, defined once in model.definition) and the state size
MECH = len(MECHANICAL)
NSTATE = 17
STATE_NAMES: tuple[str, ...] = (MECHANICAL + tuple(f"{c}_dot" for c in MECHANICAL)
                                + ("q",))


def generated(piezo: int) -> ModuleType:
    """The generated code for a piezo (1 or 2)."""
    check_piezo(piezo)
    return importlib.import_module(f"gprm.model._generated_piezo{piezo}")


@dataclass(frozen=True)
class StateSpace:
    """Batched state-space matrices: A (B,17,17), b (B,17), E (B,17,17)."""

    A: np.ndarray
    b: np.ndarray
    E: np.ndarray


def _assemble(M, C, K, F):
    shape = M.shape[:-2]
    E = np.zeros(shape + (NSTATE, NSTATE))
    A = np.zeros(shape + (NSTATE, NSTATE))
    s, v, f = slice(0, 8), slice(8, 16), slice(16, 17)
    E[..., s, s] = np.eye(8)
    E[..., v, v] = M[..., :8, :8]
    E[..., v, f] = C[..., :8, 8:]
    E[..., f, f] = C[..., 8:, 8:]
    A[..., s, v] = np.eye(8)
    A[..., v, s] = -K[..., :8, :8]
    A[..., v, v] = -C[..., :8, :8]
    A[..., v, f] = -K[..., :8, 8:]
    A[..., f, s] = -K[..., 8:, :8]
    A[..., f, v] = -C[..., 8:, :8]
    A[..., f, f] = -K[..., 8:, 8:]
    B = np.zeros(shape + (NSTATE,))
    B[..., 8:16] = F[:8]
    B[..., 16] = F[8]
    return E, A, B


def descriptor(pb: dict, piezo: int):
    """E, A, B (unsolved) for a parameter batch."""
    g = generated(piezo)
    M, C, K = g.linear_matrices(pb)
    return _assemble(M, C, K, np.asarray(g.INPUT))


def state_space(pb: dict, piezo: int, desc=None) -> StateSpace:
    """A_s = E^-1 A, b = E^-1 B. The first 8 rows of E are the identity, so only the 9 x 9
    block of the equations (rows 8..16) is solved."""
    E, A, B = descriptor(pb, piezo) if desc is None else desc
    rhs = np.concatenate([A[..., 8:, :], B[..., 8:, None]], axis=-1)
    sol = np.linalg.solve(E[..., 8:, 8:], rhs)
    As = A.copy()
    As[..., 8:, :] = sol[..., :NSTATE]
    b = B.copy()
    b[..., 8:] = sol[..., NSTATE]
    return StateSpace(As, b, E)


@dataclass(frozen=True)
class SparseDerivatives:
    """Non-zero entries of d(K, C, M)/dp for several parameters, over a batch.

    Entry k is d(K, C, M)_mat[k][a[k], c[k]] / d names[p[k]] with values ``vals[:, k]`` (B,);
    ``e = 9 mat + c`` indexes the stacked columns [K | C | M]. Only entries that are non-zero
    for some set of the batch are kept (a few percent of 3 x 81 x P).
    """

    e: np.ndarray
    a: np.ndarray
    p: np.ndarray
    vals: np.ndarray
    n_params: int


@functools.lru_cache(maxsize=None)
def _derivative_pattern(piezo: int, name: str) -> tuple:
    """The entries of dK, dC, dM (in that order) that the generated derivative of ``name``
    assigns: ((rows, cols), ...) of its structural non-zeros. Found once by evaluating it with
    every parameter NaN: an assigned entry is then NaN or a non-zero constant, an untouched
    one stays 0."""
    g = generated(piezo)
    nan = {k: np.full(1, np.nan) for k in g.PARAMETERS}
    dM, dC, dK = g.DERIVATIVES[name](nan)
    with np.errstate(all="ignore"):
        return tuple(np.nonzero(d.reshape(9, 9) != 0) for d in (dK, dC, dM))


def coordinate_derivatives(pb: dict, piezo: int, names) -> SparseDerivatives:
    """Parameter derivatives of K, C and M for the modal sensitivities (sparse form).

    With Xi the coordinate rows of the eigenvectors, the descriptor derivative in the
    eigenbasis is  -(dK Xi + dC Xi Lambda + dM Xi Lambda^2)  (simulate/modal.py). Parameters
    that do not enter the equations of motion have no entries.
    """
    g = generated(piezo)
    e, a, p, vals = [], [], [], []
    for k, name in enumerate(names):
        fn = g.DERIVATIVES.get(name)
        if fn is None:
            continue
        mats = fn(pb)
        for mat, (rows, cols) in enumerate(_derivative_pattern(piezo, name)):
            d = mats[2 - mat].reshape((-1, 9, 9))                   # dK, dC, dM
            e.append(9 * mat + cols)
            a.append(rows)
            p.append(np.full(rows.size, k))
            vals.append(d[:, rows, cols])
    if not e:
        Bn = np.broadcast_shapes(*(np.shape(pb[k]) for k in g.PARAMETERS))
        return SparseDerivatives(np.zeros(0, int), np.zeros(0, int), np.zeros(0, int),
                                 np.zeros(Bn + (0,)), len(names))
    return SparseDerivatives(np.concatenate(e), np.concatenate(a), np.concatenate(p),
                             np.concatenate(vals, axis=-1), len(names))


def admissible(pb: dict, piezo: int, *, rtol: float = 1e-9) -> np.ndarray:
    """Boolean mask (B,) of parameter sets the exact solver can simulate: the mechanical mass
    and stiffness blocks M_ss and K_ss (8 x 8, symmetric) positive definite, smallest
    eigenvalue above ``rtol`` times the largest. A stiffness drawn at zero (a spring removed)
    makes K_ss singular and the static equilibrium undefined; such sets are never simulated
    (issue 12: propagation never breaks)."""
    M, _, K = generated(piezo).linear_matrices(pb)
    ok = np.ones(np.shape(M)[:-2], bool)
    for A in (M[..., :8, :8], K[..., :8, :8]):
        with np.errstate(all="ignore"):
            w = np.linalg.eigvalsh(0.5 * (A + np.swapaxes(A, -1, -2)))
        ok &= np.all(np.isfinite(w), axis=-1) & (w[..., 0] > rtol * np.abs(w[..., -1]))
    return ok
