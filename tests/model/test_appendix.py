"""The derived linear equations against the paper's Appendix A, term by term.

Appendix A (Eqs. A.1-A.9, Piezo 2) is transcribed here by hand from the paper, as SymPy
expressions, *literally*; the garbles docs/spec.md lists are then applied as explicit corrections
(literal term -> corrected term). The tests check that

* the corrected linear parts equal the derived linear equations M0 x'' + C0 x' + K0 x - F V
  exactly (A.9 is the derived charge equation times C_a: see docs/model.md),
* every correction is needed (the literal reading differs from the derivation),
* docs/spec.md's claims about the literal reading hold (indefinite K, unstable mode),
* the appendix's products of small quantities (eta*z_lr'' ...) equal the first-order terms of
  the derived mass matrix M(x), except the one sign docs/spec.md names,
* Piezo 1: force on mu4 with its reaction on mu3, everything else as for Piezo 2,
* the generated code (what is simulated) equals the corrected appendix numerically.
"""

import numpy as np
import pytest
import sympy as sp

from gprm.model.definition import COORDINATES
from gprm.model.linear import generated
from gprm.params import paper

# ------------------------------------------------------------------ symbols (own, by name)
R_ = dict(real=True)
X = {c: sp.Symbol(c, **R_) for c in COORDINATES}
XD = {c: sp.Symbol(f"{c}_d", **R_) for c in COORDINATES}
XDD = {c: sp.Symbol(f"{c}_dd", **R_) for c in COORDINATES}
V = sp.Symbol("V", **R_)
(v2, g2, h2, gamma, rho, k_lr, k_Az, k_Ax, k_Bx, c_Ax, c_Bx, k_Cy, k_Dy, c_Cy, c_Dy, m1, m2,
 m3, m4, J2, d1, d2, b1, b2, h3, h4, k3, k4, c1, c3, T_em, C_a, R) = sp.symbols(
    "v2 g2 h2 gamma rho k_lr k_Az k_Ax k_Bx c_Ax c_Bx k_Cy k_Dy c_Cy c_Dy m1 m2 m3 m4 J2 "
    "d1 d2 b1 b2 h3 h4 k3 k4 c1 c3 T_em C_a R", **R_)
sg, cg, sr, cr = sp.sin(gamma), sp.cos(gamma), sp.sin(rho), sp.cos(rho)
Q = sp.Rational(1, 4)
half = sp.Rational(1, 2)

zlr, zA, xA, yA, eta, th, mu3, mu4, q = (X[c] for c in COORDINATES)
zlr_d, zA_d, xA_d, yA_d, eta_d, th_d, mu3_d, mu4_d, q_d = (XD[c] for c in COORDINATES)
zlr_dd, zA_dd, xA_dd, yA_dd, eta_dd, th_dd, mu3_dd, mu4_dd, q_dd = (XDD[c] for c in COORDINATES)

# a_1, a_2 of A.4 and A.6 are b_1, b_2 (docs/spec.md): substituted in the transcription itself,
# since they are only names.
a1, a2 = b1, b2

# ------------------------------------------------------------------ Appendix A, literally
# Linear terms, in the order printed. Products of two small quantities go to PRODUCTS below.
LITERAL = {
    "A.1": (g2 * m2 * th_dd - h4 * m4 * sg * eta_dd + h4 * m4 * cg * sr * th_dd + k_lr * zlr
            + m1 * zlr_dd - m2 * v2 * eta_dd + m2 * zA_dd + m2 * zlr_dd + m3 * cg * cr * mu3_dd
            + m3 * zA_dd + m3 * zlr_dd + m4 * cg * cr * mu4_dd + m4 * zA_dd + m4 * zlr_dd),
    "A.2": (g2 * m2 * th_dd - h4 * m4 * sg * eta_dd + h4 * m4 * cg * sr * th_dd + k_Az * zA
            - m2 * v2 * eta_dd + m2 * zA_dd + m2 * zlr_dd + m3 * cg * cr * mu3_dd + m3 * zA_dd
            + m3 * zlr_dd + m4 * cg * cr * mu4_dd + m4 * zA_dd + m4 * zlr_dd),
    # A.3 as printed stops after "m2 x_A''"; its last line is printed as the first line of A.4.
    "A.3": (c_Ax * d1 * eta_d + c_Ax * xA_d + c_Bx * d1 * eta_d + c_Bx * d2 * eta_d + c_Bx * xA_d
            + d1 * k_Ax * eta + d1 * k_Bx * eta + d2 * k_Bx * eta + h2 * m2 * eta_dd
            + h3 * m3 * eta_dd + h3 * m4 * eta_dd + h4 * m4 * cg * cr * eta_dd + k_Ax * xA
            + k_Bx * xA + m2 * xA_dd),
    "A.4": (m3 * sg * mu3_dd + m3 * xA_dd + m4 * sg * mu4_dd + m4 * xA_dd
            - a1 * c_Cy * th_d - a1 * c_Dy * th_d - a1 * k_Cy * th - a1 * k_Dy * th
            - a2 * c_Dy * th_d - a2 * k_Dy * th + c_Cy * yA_d + c_Dy * yA_d - h2 * m2 * th_dd
            - h3 * m3 * th_dd - h3 * m4 * th_dd - h4 * m4 * cg * cr * th_dd + k_Cy * yA
            + k_Dy * yA + m2 * yA_dd + m3 * cg * sr * mu3_dd + m3 * yA_dd
            + m4 * cg * sr * mu4_dd + m4 * yA_dd),
    "A.5": (half * (2 * c_Ax * d1 * (d1 * eta_d + xA_d)
                    + 2 * c_Bx * (d1 + d2) * ((d1 + d2) * eta_d + xA_d))
            - m2 * v2 * zA_dd + d1**2 * k_Bx * eta + 2 * d1 * d2 * k_Bx * eta + d1 * k_Ax * xA
            + d1 * k_Bx * xA + d2**2 * k_Bx * eta + d2 * k_Bx * xA - g2 * m2 * v2 * th_dd
            + h2**2 * m2 * eta_dd + h2 * m2 * xA_dd + h2**2 * m3 * eta_dd - m2 * v2 * zlr_dd
            + h2**2 * m4 * eta_dd + 2 * h3 * h4 * m4 * cg * cr * eta_dd + h3 * m3 * sg * mu3_dd
            + h3 * m3 * xA_dd + h3 * m4 * sg * mu4_dd + h3 * m4 * xA_dd + m2 * v2**2 * eta_dd
            + Q * h4**2 * m4 * cg**2 * cr**2 * eta_dd - Q * h4**2 * m4 * sg**2 * cr**2 * eta_dd
            - Q * h4**2 * m4 * cg**2 * sr**2 * eta_dd + Q * h4**2 * m4 * sg**2 * eta_dd
            - Q * h4**2 * m4 * cg**2 * eta_dd - h4**2 * m4 * sg * cg * sr * th_dd
            + Q * h4**2 * m4 * sr**2 * eta_dd + Q * h4**2 * m4 * cr**2 * eta_dd
            + 3 * Q * h4**2 * m4 * eta_dd + h4 * m4 * cg * cr * xA_dd - h4 * m4 * sg * zA_dd
            - h4 * m4 * sg * zlr_dd + J2 * eta_dd + Q * h4**2 * m4 * sg**2 * sr**2 * eta_dd),
    # A.6: the stray "1/2 + ..." and "-(...)" as printed: 1/2 times minus the bracket.
    "A.6": (a1**2 * k_Cy * th + a1**2 * k_Dy * th + 2 * a1 * a2 * k_Dy * th - a1 * k_Cy * yA
            - a1 * k_Dy * yA
            + half * -(2 * c_Dy * (a1 + a2) * (yA_d - (a1 + a2) * th_d)
                       - 2 * a1 * c_Cy * (yA_d - a1 * th_d))
            + a2**2 * k_Dy * th - a2 * k_Dy * yA + g2**2 * m2 * th_dd - g2 * m2 * v2 * eta_dd
            + g2 * m2 * zA_dd + g2 * m2 * zlr_dd + h2**2 * m2 * th_dd - h2 * m2 * yA_dd
            + h2**2 * m3 * th_dd + h2**2 * m4 * th_dd + 2 * h3 * h4 * m4 * cg * cr * th_dd
            - h3 * m3 * cg * sr * mu3_dd - h3 * m3 * yA_dd - h3 * m4 * cg * sr * mu4_dd
            - h3 * m4 * yA_dd - h4**2 * m4 * sg * cg * sr * eta_dd
            - half * h4**2 * m4 * sg**2 * th_dd + half * h4**2 * m4 * cg**2 * th_dd
            + half * h4**2 * m4 * th_dd - h4 * m4 * cg * cr * yA_dd + h4 * m4 * cg * sr * zA_dd
            + h4 * m4 * cg * sr * zlr_dd + J2 * th_dd),
    "A.7": ((c1 * C_a * mu3_d + c3 * C_a * mu3_d - c3 * C_a * mu4_d + T_em**2 * mu3) / C_a
            - T_em * q / C_a + h3 * m3 * sg * eta_dd - h3 * m3 * cg * sr * th_dd + 2 * k3 * mu3
            - k3 * mu4 + m3 * mu3_d + m3 * sg * xA_dd + m3 * cg * sr * yA_dd
            + m3 * cg * cr * zA_dd + m3 * cg * cr * zlr_dd),
    "A.8": (c3 * (mu4_d - mu3_d) + h3 * m4 * sg * eta_dd - h3 * m4 * cg * sr * th_dd - k3 * mu3
            + k3 * mu4 + k4 * mu4 + m4 * mu4_d + m4 * sg * xA_dd + m4 * cg * sr * yA_dd
            + m4 * cg * cr * zA_dd + m4 * cg * cr * zlr_dd),
    "A.9": R * C_a * q_d + q - T_em * mu3 - C_a * V,
}

# Products of two small quantities the appendix prints (all of them: coordinate * z_lr'').
PRODUCTS = {
    "A.5": [-h2 * m2 * eta * zlr_dd, -h3 * m3 * eta * zlr_dd, -h3 * m4 * eta * zlr_dd,
            h4 * m4 * cg * cr * eta * zlr_dd, -m3 * sg * mu3 * zlr_dd, -m4 * sg * mu4 * zlr_dd],
    "A.6": [-h2 * m2 * th * zlr_dd, -h3 * m3 * th * zlr_dd, -h3 * m4 * th * zlr_dd,
            -h4 * m4 * cg * cr * th * zlr_dd, m3 * cg * sr * mu3 * zlr_dd,
            m4 * cg * sr * mu4 * zlr_dd],
    "A.7": [-m3 * sg * eta * zlr_dd, m3 * cg * sr * th * zlr_dd],
    "A.8": [-m4 * sg * eta * zlr_dd, m4 * cg * sr * th * zlr_dd],
}

# ------------------------------------------------------------------ the garbles (docs/spec.md)
# (equation, literal term as printed, corrected term)
A3_LAST_LINE = m3 * sg * mu3_dd + m3 * xA_dd + m4 * sg * mu4_dd + m4 * xA_dd
CORRECTIONS = [
    ("A.3", sp.Integer(0), A3_LAST_LINE),                            # the line split
    ("A.4", A3_LAST_LINE, sp.Integer(0)),
    ("A.5", h2**2 * m3 * eta_dd, h3**2 * m3 * eta_dd),
    ("A.5", h2**2 * m4 * eta_dd, h3**2 * m4 * eta_dd),
    ("A.5", Q * h4**2 * m4 * sr**2 * eta_dd, -Q * h4**2 * m4 * sr**2 * eta_dd),
    ("A.5", sp.Integer(0), d1**2 * k_Ax * eta),                       # missing stiffness term
    ("A.6", h2**2 * m3 * th_dd, h3**2 * m3 * th_dd),
    ("A.6", h2**2 * m4 * th_dd, h3**2 * m4 * th_dd),
    ("A.6", half * -(2 * c_Dy * (a1 + a2) * (yA_d - (a1 + a2) * th_d)
                     - 2 * a1 * c_Cy * (yA_d - a1 * th_d)),
     half * (-2 * c_Dy * (a1 + a2) * (yA_d - (a1 + a2) * th_d)
             - 2 * a1 * c_Cy * (yA_d - a1 * th_d))),
    ("A.7", m3 * mu3_d, m3 * mu3_dd),
    ("A.8", m4 * mu4_d, m4 * mu4_dd),
]
EQS = [f"A.{i}" for i in range(1, 10)]


def corrected():
    out = dict(LITERAL)
    for eq, lit, cor in CORRECTIONS:
        out[eq] = out[eq] - lit + cor
    return out


def derived_equations(lin):
    s, M0, C0, K0, F = lin
    xdd = sp.Matrix([XDD[c] for c in COORDINATES])
    xd = sp.Matrix([XD[c] for c in COORDINATES])
    x = sp.Matrix([X[c] for c in COORDINATES])
    return M0 * xdd + C0 * xd + K0 * x - F * V


def is_zero(e) -> bool:
    """Exact symbolic zero test: expand, then eliminate sin^2 = 1 - cos^2."""
    e = sp.expand(sp.expand_trig(e))
    if e == 0:
        return True
    e = e.replace(lambda a: a.is_Pow and isinstance(a.base, sp.sin) and a.exp.is_even,
                  lambda a: (1 - sp.cos(a.base.args[0]) ** 2) ** (a.exp // 2))
    return sp.expand(e) == 0


def test_symbols_match_the_model_definition(linearised):
    s = linearised[2][0]
    assert all(s.x[c] == X[c] and s.xd[c] == XD[c] for c in COORDINATES)
    assert s.p["k_Ax"] == k_Ax and s.p["T_em"] == T_em


def test_corrected_appendix_equals_derived_linear_equations(linearised):
    eqs = derived_equations(linearised[2])
    cor = corrected()
    for i, name in enumerate(EQS[:8]):
        assert is_zero(cor[name] - eqs[i]), (name, sp.simplify(cor[name] - eqs[i]))
    # A.9 is Kirchhoff's law in volts times C_a; the Lagrange (energy) form is volts, so the
    # derived charge equation is A.9 / C_a (which keeps K symmetric).
    assert is_zero(cor["A.9"] - C_a * eqs[8])


@pytest.mark.parametrize("k", range(len(CORRECTIONS)))
def test_every_correction_is_needed(linearised, k):
    """Undo one correction: the equation then differs from the derivation."""
    eqs = derived_equations(linearised[2])
    eq, lit, cor = CORRECTIONS[k]
    i = EQS.index(eq)
    assert not is_zero(corrected()[eq] - cor + lit - eqs[i])


def _matrices(exprs, coord_syms):
    """Coefficient matrix of a set of linear expressions with respect to symbols."""
    return sp.Matrix(len(exprs), len(coord_syms),
                     lambda i, j: sp.diff(exprs[i], coord_syms[j]))


def _appendix_matrices(eqs):
    rows = [eqs[n] for n in EQS[:8]] + [eqs["A.9"] / C_a]
    Mx = _matrices(rows, [XDD[c] for c in COORDINATES])
    Cx = _matrices(rows, [XD[c] for c in COORDINATES])
    Kx = _matrices(rows, [X[c] for c in COORDINATES])
    return Mx, Cx, Kx


def _numeric(mat, values):
    syms = sorted(mat.free_symbols, key=str)
    f = sp.lambdify(syms, mat, "numpy")
    return np.array(f(*[values[str(s)] for s in syms]), float)


def test_literal_appendix_is_unphysical_as_model_md_says():
    """docs/spec.md: without d1^2 k_Ax eta the stiffness matrix is indefinite; with the literal
    A.6 damping the damping matrix is not symmetric and a mode is unstable."""
    vals = dict(paper().values)
    lit = corrected()
    lit["A.5"] = lit["A.5"] - d1**2 * k_Ax * eta
    _, _, Kl = _appendix_matrices(lit)
    Kn = _numeric(Kl, vals)
    assert np.allclose(Kn, Kn.T, rtol=0, atol=1e-9 * np.abs(Kn).max())
    assert np.linalg.eigvalsh(Kn).min() < 0
    lit = corrected()
    eq, literal_damp, cor = next(c for c in CORRECTIONS if c[0] == "A.6" and c[2].has(c_Cy))
    lit["A.6"] = lit["A.6"] - cor + literal_damp
    Mx, Cx, Kx = _appendix_matrices(lit)
    Mn, Cn, Kn = (_numeric(m, vals) for m in (Mx, Cx, Kx))
    assert not np.allclose(Cn, Cn.T)
    assert _max_real_eig(Mn, Cn, Kn) > 0
    # and the corrected appendix is stable
    Mx, Cx, Kx = _appendix_matrices(corrected())
    assert _max_real_eig(*(_numeric(m, vals) for m in (Mx, Cx, Kx))) < 0


def _max_real_eig(M, C, K):
    """Largest real part of the eigenvalues of M x'' + C x' + K x = 0, written as the pencil
    E z' = A z with z = [x_mech (8), x_mech' (8), q] (q is first order: no inertia)."""
    import scipy.linalg as sl
    I8, Z = np.eye(8), np.zeros
    E = np.block([[I8, Z((8, 8)), Z((8, 1))],
                  [Z((8, 8)), M[:8, :8], C[:8, 8:]],
                  [Z((1, 8)), M[8:, :8], C[8:, 8:]]])
    A = np.block([[Z((8, 8)), I8, Z((8, 1))],
                  [-K[:8, :8], -C[:8, :8], -K[:8, 8:]],
                  [-K[8:, :8], -C[8:, :8], -K[8:, 8:]]])
    w = sl.eigvals(A, E)
    return w[np.isfinite(w)].real.max()


def test_products_of_small_quantities_match_the_mass_matrix_expansion(linearised):
    """Each appendix product c * x_k * z_lr'' in the equation of coordinate i is the
    first-order term d M_{i,z_lr}/d x_k of the derived M(x); A.5's h4 m4 cos(g) cos(r)
    eta z_lr'' has the wrong sign (docs/spec.md)."""
    from gprm.model.definition import DEFINITIONS, make_symbols

    s = make_symbols()
    T = DEFINITIONS[2].build(s).T
    zero = {v: 0 for v in list(s.x.values()) + list(s.xd.values())}
    dT_dzlr = sp.diff(T, s.xd["z_lr"])
    wrong_sign = h4 * m4 * cg * cr * eta * zlr_dd
    for eq, terms in PRODUCTS.items():
        i = EQS.index(eq)
        Mi0 = sp.diff(dT_dzlr, s.xd[COORDINATES[i]])               # M_{i, z_lr}(x)
        total = sum(terms)
        if eq == "A.5":
            total = total - 2 * wrong_sign                         # read with the other sign
        for c in ("eta", "theta", "mu3", "mu4"):
            printed = sp.diff(total, X[c], zlr_dd)
            expected = sp.diff(Mi0, s.x[c]).subs(zero)
            assert is_zero(printed - expected), (eq, c, printed, expected)
    # the sign really is wrong as printed
    Mi0 = sp.diff(dT_dzlr, s.xd["eta"])
    printed = sp.diff(sum(PRODUCTS["A.5"]), eta, zlr_dd)
    assert not is_zero(printed - sp.diff(Mi0, s.x["eta"]).subs(zero))


def test_piezo1_force_on_mu4_with_reaction_on_mu3(linearised):
    """Piezo 1 (Eq. 1, F_p1 with mu4 - mu3): same M and C; K differs from Piezo 2 only by the
    piezo terms written here by hand; the force T_em q / C_a acts on mu4 and -T_em q / C_a on
    mu3, and the circuit sees T_em (mu4 - mu3)."""
    _, M1, C1, K1, F1 = linearised[1]
    _, M2, C2, K2, F2 = linearised[2]
    assert (M1 - M2).applyfunc(sp.simplify) == sp.zeros(9, 9)
    assert (C1 - C2).applyfunc(sp.simplify) == sp.zeros(9, 9)
    assert F1 == F2 == sp.Matrix([0] * 8 + [1])
    x = sp.Matrix([X[c] for c in COORDINATES])
    # generalised piezo forces (minus the gradient of the piezo energy) written from Eq. 1
    Fp1 = T_em * q / C_a - T_em**2 * (mu4 - mu3) / C_a
    Fp2 = T_em * q / C_a - T_em**2 * mu3 / C_a
    gen1 = sp.Matrix([0] * 6 + [-Fp1, Fp1, 0])              # on mu4, reaction on mu3
    gen2 = sp.Matrix([0] * 6 + [Fp2, 0, 0])                  # on mu3 (reaction on plunger: in mu3)
    circuit1 = sp.Matrix([0] * 8 + [(q - T_em * (mu4 - mu3)) / C_a])
    circuit2 = sp.Matrix([0] * 8 + [(q - T_em * mu3) / C_a])
    mech = K2 * x + gen2 - circuit2                         # Piezo 2's K without its piezo
    assert ((K1 * x) - (mech - gen1 + circuit1)).applyfunc(sp.expand) == sp.zeros(9, 1)


@pytest.mark.parametrize("piezo", [1, 2])
def test_generated_code_equals_corrected_appendix_numerically(piezo, random_sets):
    """What the solver uses (the generated code) equals the corrected appendix (Piezo 2) or
    the appendix with Piezo 1's terms (Piezo 1), at the paper set and random sets."""
    Mx, Cx, Kx = _appendix_matrices(corrected())
    if piezo == 1:
        Kx = Kx.copy()
        # piezo energy (q - T_em (mu4 - mu3))^2 / 2C_a instead of (q - T_em mu3)^2 / 2C_a
        Kx[7, 7] = Kx[7, 7] + T_em**2 / C_a
        Kx[6, 7] = Kx[7, 6] = Kx[6, 7] - T_em**2 / C_a
        Kx[6, 8] = Kx[8, 6] = T_em / C_a
        Kx[7, 8] = Kx[8, 7] = -T_em / C_a
    g = generated(piezo)
    for ps in [paper()] + random_sets(3, seed=11 + piezo):
        vals = dict(ps.values)
        M, C, K = (a[0] for a in g.linear_matrices({k: np.array([v]) for k, v in vals.items()}))
        for got, want in ((M, Mx), (C, Cx), (K, Kx)):
            ref = _numeric(want, vals)
            np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
