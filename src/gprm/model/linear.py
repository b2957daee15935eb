"""The linear model in first-order (state-space) form, batched, with parameter derivatives.

State z = [xi_s, xi_s', xi_f] where xi_s are the 8 mechanical coordinates (second order) and
xi_f = q (first order, no inertia). From Eq. 2, M xi'' + C xi' + K xi = F V:

    E z' = A z + B V,   E = [[I, 0, 0], [0, M_ss, C_sf], [0, 0, C_ff]],
                        A = [[0, I, 0], [-K_ss, -C_ss, -K_sf], [-K_fs, -C_fs, -K_ff]].

so z' = A_s z + b V with A_s = E^-1 A, b = E^-1 B.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from types import ModuleType

import numpy as np

from gprm.errors import GprmInputError
from gprm.model.definition import COORDINATES

MECH = 8
NSTATE = 17
STATE_NAMES: tuple[str, ...] = (COORDINATES[:8] + tuple(f"{c}_dot" for c in COORDINATES[:8])
                                + ("q",))


def generated(piezo: int) -> ModuleType:
    """The generated code for a piezo (1 or 2)."""
    if piezo not in (1, 2):
        raise GprmInputError(f"piezo must be 1 or 2, got {piezo}", field="piezo")
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


def raw_derivatives(pb: dict, piezo: int, names):
    """Rows 8..16 of dA (unsolved) and dE for each name: arrays (B, P, 9, 17), (B, P, 9, 9).

    Only these rows of the descriptor depend on parameters (the first 8 rows are the
    kinematic identity q' = v). Parameters that do not enter the equations get zeros.
    """
    g = generated(piezo)
    Bsh = np.broadcast_shapes(*(np.shape(pb[k]) for k in g.PARAMETERS))
    dA = np.zeros(Bsh + (len(names), 9, NSTATE))
    dE = np.zeros(Bsh + (len(names), 9, 9))
    F = np.zeros(9)
    for k, name in enumerate(names):
        fn = g.DERIVATIVES.get(name)
        if fn is None:
            continue
        dM, dC, dK = fn(pb)
        dEf, dAf, _ = _assemble(dM, dC, dK, F)
        dA[..., k, :, :] = dAf[..., 8:, :]
        dE[..., k, :, :] = dEf[..., 8:, 8:]
    return dA, dE


def state_space_derivatives(pb: dict, piezo: int, names, ss: StateSpace):
    """dA_s/dp and db/dp for each name (arrays (B, P, 17, 17) and (B, P, 17)).

    d(E^-1 A) = E^-1 (dA - dE A_s);  d(E^-1 B) = -E^-1 dE b. (Reference form; the solver
    uses the same identities restricted to the rows that change.)
    """
    dAr, dEr = raw_derivatives(pb, piezo, names)
    Einv = np.linalg.inv(ss.E[..., 8:, 8:])[:, None]
    rhs = dAr - dEr @ ss.A[:, None, 8:, :]
    dA = np.zeros(dAr.shape[:2] + (NSTATE, NSTATE))
    dA[..., 8:, :] = Einv @ rhs
    db = np.zeros(dAr.shape[:2] + (NSTATE,))
    db[..., 8:] = -(Einv @ (dEr @ ss.b[:, None, 8:, None]))[..., 0]
    return dA, db



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
        dM, dC, dK = fn(pb)
        for mat, d in enumerate((dK, dC, dM)):
            d = d.reshape((-1, 9, 9))
            rows, cols = np.nonzero(np.any(d != 0, axis=0))
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
