"""Symbolic derivation of the equations of motion (Lagrange with Rayleigh dissipation) and
generation of NumPy code from them.

For a model definition with kinetic energy T(x, x'), potential U(x), dissipation D(x, x') and
generalised input forces Q·V, the equations are

    d/dt dT/dx'_i - dT/dx_i + dU/dx_i + dD/dx'_i - Q_i V = 0,

written as ``M(x) x'' + f(x, x') - Q V = 0``. Linearised about x = x' = 0 (paper Eq. 2):
``M0 x'' + C0 x' + K0 x = F V`` with M0 = d2T/dx'2, C0 = d2D/dx'2, K0 = d2U/dx2 at 0.

Derivation takes tens of seconds; it runs only in :func:`generate` (a developer command,
``python -m gprm.model.derive``), which writes ``gprm/model/_generated_piezo{1,2}.py``. A test
re-derives and checks that the committed files are current. Importing or simulating never
re-derives.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import sys
from dataclasses import dataclass
from pathlib import Path

import sympy as sp

from gprm.model.definition import (DEFINITIONS, EOM_PARAMETERS, ModelDefinition, Symbols,
                                   make_symbols)

GENERATED_DIR = Path(__file__).parent


@dataclass(frozen=True)
class DerivedModel:
    """Symbolic results for one model definition."""

    definition: ModelDefinition
    symbols: Symbols
    M: sp.Matrix       # full nonlinear mass matrix M(x)
    f: sp.Matrix       # M(x) x'' + f(x, x') - Q V = 0
    Q: sp.Matrix       # input vector
    M0: sp.Matrix      # linearised matrices (Eq. 2)
    C0: sp.Matrix
    K0: sp.Matrix
    equations: sp.Matrix  # full equations with x'' symbols (for term-by-term comparison)
    xdd: dict


def derive(defn: ModelDefinition) -> DerivedModel:
    s = make_symbols(defn.coordinates)
    en = defn.build(s)
    coords = defn.coordinates
    xv = [s.x[c] for c in coords]
    xdv = [s.xd[c] for c in coords]
    xdd = {c: sp.Symbol(f"{c}_dd", real=True) for c in coords}
    n = len(coords)
    M = sp.zeros(n, n)
    f = sp.zeros(n, 1)
    Q = sp.zeros(n, 1)
    dT_dxd = [sp.diff(en.T, v) for v in xdv]
    for i in range(n):
        for j in range(n):
            M[i, j] = sp.diff(dT_dxd[i], xdv[j])
        f[i] = (sum(sp.diff(dT_dxd[i], xv[j]) * xdv[j] for j in range(n))
                - sp.diff(en.T, xv[i]) + sp.diff(en.U, xv[i]) + sp.diff(en.D, xdv[i]))
        Q[i] = en.input_force.get(coords[i], 0)
    zero = {v: 0 for v in xv + xdv}
    M0 = M.subs(zero).applyfunc(sp.simplify)
    C0 = sp.Matrix(n, n, lambda i, j: sp.diff(f[i], xdv[j]).subs(zero)).applyfunc(sp.simplify)
    K0 = sp.Matrix(n, n, lambda i, j: sp.diff(f[i], xv[j]).subs(zero)).applyfunc(sp.simplify)
    eqs = M * sp.Matrix([xdd[c] for c in coords]) + f - Q * sp.Symbol("V")
    return DerivedModel(defn, s, M, f, Q, M0, C0, K0, eqs, xdd)


@functools.lru_cache(maxsize=None)
def derived(piezo: int) -> DerivedModel:
    """Derive (once per process) the model for a piezo. Slow: tests and generation only."""
    return derive(DEFINITIONS[piezo])


# ----------------------------------------------------------------------------- code generation

def _emit_block(exprs: list[sp.Expr], targets: list[str], indent: str = "    ") -> list[str]:
    printer = sp.printing.numpy.NumPyPrinter({"fully_qualified_modules": False,
                                               "allow_unknown_functions": False})
    repl, reduced = sp.cse(exprs, symbols=sp.numbered_symbols("_c"), optimizations="basic")
    lines = [f"{indent}{printer.doprint(sym)} = {printer.doprint(e)}" for sym, e in repl]
    lines += [f"{indent}{t} = {printer.doprint(e)}" for t, e in zip(targets, reduced)]
    return lines


def _param_unpack(names, indent="    ", source="p") -> list[str]:
    return [f"{indent}{n} = {source}['{n}']" for n in names]


def _used(exprs) -> list[str]:
    syms = set()
    for e in exprs:
        syms |= {str(x) for x in sp.sympify(e).free_symbols}
    return [n for n in EOM_PARAMETERS if n in syms]


def _matrix_fn(name, doc, mats: dict[str, sp.Matrix], shape_expr: str) -> list[str]:
    """Emit a function building batched matrices (B, n, n) from a parameter dict."""
    exprs, targets = [], []
    for key, mat in mats.items():
        for (i, j), e in _nonzero(mat):
            exprs.append(e)
            targets.append(f"{key}[..., {i}, {j}]")
    used = _used(exprs)
    lines = [f"def {name}(p):", f'    """{doc}"""']
    lines += _param_unpack(used)
    lines.append(f"    shape = {shape_expr}")
    for key, mat in mats.items():
        lines.append(f"    {key} = np.zeros(shape + {mat.shape})")
    lines += _emit_block(exprs, targets)
    lines.append(f"    return {', '.join(mats)}")
    return lines


def _nonzero(mat: sp.Matrix):
    return [((i, j), mat[i, j]) for i in range(mat.rows) for j in range(mat.cols)
            if mat[i, j] != 0]


def generate_source(dm: DerivedModel) -> str:
    defn = dm.definition
    coords = defn.coordinates
    n = len(coords)
    used = _used(list(dm.M0) + list(dm.C0) + list(dm.K0))
    out = [
        f'"""Generated by gprm.model.derive from the definition {defn.name!r}, piezo {defn.piezo}.',
        "",
        "Do not edit: run `python -m gprm.model.derive` to regenerate. A test checks that this",
        'file matches a fresh derivation."""',
        "# flake8: noqa",
        "import numpy as np",
        "from numpy import sin, cos",
        "",
        f"MODEL = {defn.name!r}",
        f"PIEZO = {defn.piezo}",
        f"COORDINATES = {tuple(coords)!r}",
        f"FIRST_ORDER = {tuple(defn.first_order)!r}",
        f"PARAMETERS = {tuple(used)!r}",
        f"INPUT = {tuple(float(v) for v in dm.Q)!r}",
        "",
        "",
        "def _shape(p):",
        "    shapes = {np.shape(p[k]) for k in PARAMETERS}",
        "    return shapes.pop() if len(shapes) == 1 else np.broadcast_shapes(*shapes)",
        "",
        "",
    ]
    out += _matrix_fn("linear_matrices",
                      "Linearised M, C, K (Eq. 2), each (..., n, n), from p: name -> array (...).",
                      {"M": dm.M0, "C": dm.C0, "K": dm.K0}, "_shape(p)")
    out += ["", ""]
    # Derivatives of M, C, K with respect to every parameter that appears.
    derivs = []
    for pname in used:
        sym = dm.symbols.p[pname]
        mats = {"dM": dm.M0.diff(sym), "dC": dm.C0.diff(sym), "dK": dm.K0.diff(sym)}
        fname = f"_d_{pname}"
        derivs.append((pname, fname))
        out += _matrix_fn(fname, f"d(M, C, K)/d{pname}.", mats, "_shape(p)")
        out += ["", ""]
    out.append("DERIVATIVES = {" + ", ".join(f"{p!r}: {f}" for p, f in derivs) + "}")
    out += ["", ""]
    # Nonlinear reference: mass matrix M(x) and f(x, x') for one parameter set.
    lines = ["def nonlinear(x, xd, p):",
             '    """Full nonlinear M(x) and f(x, x\') (M x\'\' + f - Q V = 0), one set."""']
    lines += _param_unpack(_used(list(dm.M) + list(dm.f)))
    lines += [f"    {c} = x[{i}]" for i, c in enumerate(coords)]
    lines += [f"    {c}_d = xd[{i}]" for i, c in enumerate(coords)]
    lines += [f"    M = np.zeros(({n}, {n}))", f"    f = np.zeros({n})"]
    exprs, targets = [], []
    for (i, j), e in _nonzero(dm.M):
        exprs.append(e)
        targets.append(f"M[{i}, {j}]")
    for i in range(n):
        if dm.f[i] != 0:
            exprs.append(dm.f[i])
            targets.append(f"f[{i}]")
    lines += _emit_block(exprs, targets)
    lines.append("    return M, f")
    out += lines
    return "\n".join(out) + "\n"


def definition_fingerprint() -> str:
    """Hash of the source that determines the derivation (to detect stale generated code)."""
    from gprm.model import coordinates, definition

    src = (inspect.getsource(coordinates) + inspect.getsource(definition)
           + inspect.getsource(sys.modules[__name__]))
    return hashlib.sha256(src.encode()).hexdigest()[:16]


def generated_path(piezo: int) -> Path:
    return GENERATED_DIR / f"_generated_piezo{piezo}.py"


def generate(piezos=(1, 2)) -> None:
    for pz in piezos:
        src = generate_source(derived(pz))
        src = src.replace("# flake8: noqa", f"# flake8: noqa\n# fingerprint: {definition_fingerprint()}")
        generated_path(pz).write_text(src, encoding="utf-8")
        print(f"wrote {generated_path(pz)}")


if __name__ == "__main__":
    generate()
