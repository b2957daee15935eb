"""The Moré-Garbow-Hillstrom test problems for unconstrained least squares (J. J. Moré,
B. S. Garbow, K. E. Hillstrom, "Testing unconstrained optimization software", ACM TOMS 7(1),
1981): all 35 problems, each written here from its definition in that paper (residuals
``f_i(x)``, the standard starting point ``x0``, the minima the paper lists).

Dimensions where the paper leaves them free (fixed here, the same for every solver compared):
Gulf research m = 10; Box three-dimensional m = 10; Watson n = 6; extended Rosenbrock n = 10;
extended Powell singular n = 12; penalty I and II n = 10; variably dimensioned n = 10;
trigonometric, Brown almost-linear, discrete boundary value, discrete integral equation,
Broyden tridiagonal and banded n = 10; the three linear functions n = 5, m = 10; Chebyquad
n = m = 8.

The exact Jacobian is computed by the complex-step derivative (``Im f(x + i h e_j) / h`` with
h = 1e-100): no subtraction, hence exact to rounding for residuals analytic in x (the
functions below are written so that they are: ``|d|`` of Gulf research as ``d sign(Re d)``,
the branch of the helical valley's angle chosen on the real part). The same Jacobian is given
to every solver. ``tests/fit/test_lm_mgh.py`` checks it against central differences and each
listed minimum against the residuals at its known point where the paper gives one.

The runs are the paper's: each problem from ``x0``, ``10 x0`` and ``100 x0`` (a start that is
zero in every coordinate, Watson's, is replaced by ``factor`` in every coordinate, as the
MINPACK test drivers do), 105 runs. A run is *solved* when its final sum of squares is within
``1e-4`` relative (plus ``1e-10`` absolute) of a minimum the paper lists for that problem at a
finite point (the global one, or a listed local one: a least-squares solver is a local method).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

H_CS = 1e-100


@dataclass(frozen=True)
class Problem:
    number: int
    name: str
    n: int
    m: int
    x0: np.ndarray
    minima: tuple[float, ...]          # sums of squares of listed minima at finite points
    f: Callable                        # f(x) -> (m,), complex-safe

    def residuals(self, x):
        return np.real(self.f(np.asarray(x, float)))

    def jacobian(self, x):
        x = np.asarray(x, float)
        J = np.empty((self.m, self.n))
        for j in range(self.n):
            xc = x.astype(complex)
            xc[j] += 1j * H_CS
            J[:, j] = np.imag(self.f(xc)) / H_CS
        return J

    def start(self, factor: float) -> np.ndarray:
        if factor != 1.0 and not np.any(self.x0):
            return np.full(self.n, float(factor))
        return float(factor) * self.x0

    def solved(self, ssq: float) -> bool:
        return bool(np.isfinite(ssq)) and any(ssq <= f * (1 + 1e-4) + 1e-10 for f in self.minima)


def _c(x):
    """Array of the same kind as x (complex for the complex step)."""
    return np.asarray(x)


# ----------------------------------------------------------------------------- 1-18

def rosenbrock(x):
    return np.array([10 * (x[1] - x[0] ** 2), 1 - x[0]])


def freudenstein_roth(x):
    return np.array([-13 + x[0] + ((5 - x[1]) * x[1] - 2) * x[1],
                     -29 + x[0] + ((x[1] + 1) * x[1] - 14) * x[1]])


def powell_badly_scaled(x):
    return np.array([1e4 * x[0] * x[1] - 1, np.exp(-x[0]) + np.exp(-x[1]) - 1.0001])


def brown_badly_scaled(x):
    return np.array([x[0] - 1e6, x[1] - 2e-6, x[0] * x[1] - 2])


def beale(x):
    y = np.array([1.5, 2.25, 2.625])
    i = np.arange(1, 4)
    return y - x[0] * (1 - x[1] ** i)


def jennrich_sampson(x):
    i = np.arange(1, 11)
    return 2 + 2 * i - (np.exp(i * x[0]) + np.exp(i * x[1]))


def helical_valley(x):
    x1r = np.real(x[0])
    if x1r > 0:
        theta = np.arctan(x[1] / x[0]) / (2 * np.pi)
    elif x1r < 0:
        theta = np.arctan(x[1] / x[0]) / (2 * np.pi) + 0.5
    else:
        theta = 0.25 * np.sign(np.real(x[1])) + 0 * x[1]
    return np.array([10 * (x[2] - 10 * theta), 10 * (np.sqrt(x[0] ** 2 + x[1] ** 2) - 1), x[2]])


BARD_Y = np.array([0.14, 0.18, 0.22, 0.25, 0.29, 0.32, 0.35, 0.39, 0.37, 0.58, 0.73, 0.96, 1.34,
                   2.10, 4.39])


def bard(x):
    u = np.arange(1, 16.0)
    v = 16 - u
    w = np.minimum(u, v)
    return BARD_Y - (x[0] + u / (v * x[1] + w * x[2]))


GAUSS_Y = np.array([0.0009, 0.0044, 0.0175, 0.0540, 0.1295, 0.2420, 0.3521, 0.3989, 0.3521,
                    0.2420, 0.1295, 0.0540, 0.0175, 0.0044, 0.0009])


def gaussian(x):
    t = (8 - np.arange(1, 16)) / 2
    return x[0] * np.exp(-x[1] * (t - x[2]) ** 2 / 2) - GAUSS_Y


MEYER_Y = np.array([34780, 28610, 23650, 19630, 16370, 13720, 11540, 9744, 8261, 7030, 6005,
                    5147, 4427, 3820, 3307, 2872], float)


def meyer(x):
    t = 45 + 5 * np.arange(1, 17)
    return x[0] * np.exp(x[1] / (t + x[2])) - MEYER_Y


def gulf(x, m=10):
    t = np.arange(1, m + 1) / 100
    y = 25 + (-50 * np.log(t)) ** (2 / 3)
    d = y - x[1]
    a = d * np.sign(np.real(d))                          # |d|, complex-step safe
    return np.exp(-(a ** x[2]) / x[0]) - t


def box3(x, m=10):
    t = 0.1 * np.arange(1, m + 1)
    return np.exp(-t * x[0]) - np.exp(-t * x[1]) - x[2] * (np.exp(-t) - np.exp(-10 * t))


def powell_singular(x):
    return np.array([x[0] + 10 * x[1], np.sqrt(5) * (x[2] - x[3]), (x[1] - 2 * x[2]) ** 2,
                     np.sqrt(10) * (x[0] - x[3]) ** 2])


def wood(x):
    return np.array([10 * (x[1] - x[0] ** 2), 1 - x[0], np.sqrt(90) * (x[3] - x[2] ** 2),
                     1 - x[2], np.sqrt(10) * (x[1] + x[3] - 2), (x[1] - x[3]) / np.sqrt(10)])


KO_Y = np.array([0.1957, 0.1947, 0.1735, 0.1600, 0.0844, 0.0627, 0.0456, 0.0342, 0.0323,
                 0.0235, 0.0246])
KO_U = np.array([4, 2, 1, 0.5, 0.25, 0.167, 0.125, 0.1, 0.0833, 0.0714, 0.0625])


def kowalik_osborne(x):
    u = KO_U
    return KO_Y - x[0] * (u ** 2 + u * x[1]) / (u ** 2 + u * x[2] + x[3])


def brown_dennis(x):
    t = np.arange(1, 21) / 5
    return ((x[0] + t * x[1] - np.exp(t)) ** 2 + (x[2] + x[3] * np.sin(t) - np.cos(t)) ** 2)


OSB1_Y = np.array([0.844, 0.908, 0.932, 0.936, 0.925, 0.908, 0.881, 0.850, 0.818, 0.784, 0.751,
                   0.718, 0.685, 0.658, 0.628, 0.603, 0.580, 0.558, 0.538, 0.522, 0.506, 0.490,
                   0.478, 0.467, 0.457, 0.448, 0.438, 0.431, 0.424, 0.420, 0.414, 0.411, 0.406])


def osborne1(x):
    t = 10.0 * np.arange(33)
    return OSB1_Y - (x[0] + x[1] * np.exp(-t * x[3]) + x[2] * np.exp(-t * x[4]))


def biggs_exp6(x, m=13):
    t = 0.1 * np.arange(1, m + 1)
    y = np.exp(-t) - 5 * np.exp(-10 * t) + 3 * np.exp(-4 * t)
    return (x[2] * np.exp(-t * x[0]) - x[3] * np.exp(-t * x[1]) + x[5] * np.exp(-t * x[4]) - y)


# ----------------------------------------------------------------------------- 19-35

OSB2_Y = np.array([1.366, 1.191, 1.112, 1.013, 0.991, 0.885, 0.831, 0.847, 0.786, 0.725, 0.746,
                   0.679, 0.608, 0.655, 0.616, 0.606, 0.602, 0.626, 0.651, 0.724, 0.649, 0.649,
                   0.694, 0.644, 0.624, 0.661, 0.612, 0.558, 0.533, 0.495, 0.500, 0.423, 0.395,
                   0.375, 0.372, 0.391, 0.396, 0.405, 0.428, 0.429, 0.523, 0.562, 0.607, 0.653,
                   0.672, 0.708, 0.633, 0.668, 0.645, 0.632, 0.591, 0.559, 0.597, 0.625, 0.739,
                   0.710, 0.729, 0.720, 0.636, 0.581, 0.428, 0.292, 0.162, 0.098, 0.054])


def osborne2(x):
    t = np.arange(65) / 10
    return OSB2_Y - (x[0] * np.exp(-t * x[4]) + x[1] * np.exp(-(t - x[8]) ** 2 * x[5])
                     + x[2] * np.exp(-(t - x[9]) ** 2 * x[6])
                     + x[3] * np.exp(-(t - x[10]) ** 2 * x[7]))


def watson(x):
    n = x.size
    t = np.arange(1, 30) / 29
    j = np.arange(1, n + 1)
    s1 = sum((jj - 1) * x[jj - 1] * t ** (jj - 2) for jj in j[1:])
    s2 = sum(x[jj - 1] * t ** (jj - 1) for jj in j)
    return np.concatenate([s1 - s2 ** 2 - 1, [x[0], x[1] - x[0] ** 2 - 1]])


def ext_rosenbrock(x):
    out = [None] * x.size
    for i in range(0, x.size, 2):
        out[i] = 10 * (x[i + 1] - x[i] ** 2)
        out[i + 1] = 1 - x[i]
    return np.array(out)


def ext_powell(x):
    out = []
    for i in range(0, x.size, 4):
        out += list(powell_singular(x[i:i + 4]))
    return np.array(out)


def penalty1(x):
    return np.concatenate([np.sqrt(1e-5) * (x - 1), [np.sum(x * x) - 0.25]])


def penalty2(x):
    n = x.size
    a = np.sqrt(1e-5)
    i = np.arange(2, n + 1)
    y = np.exp(i / 10) + np.exp((i - 1) / 10)
    mid = a * (np.exp(x[1:] / 10) + np.exp(x[:-1] / 10) - y)
    tail = a * (np.exp(x[1:] / 10) - np.exp(-0.1))
    last = np.sum((n - np.arange(n)) * x * x) - 1
    return np.concatenate([[x[0] - 0.2], mid, tail, [last]])


def variably_dimensioned(x):
    j = np.arange(1, x.size + 1)
    s = np.sum(j * (x - 1))
    return np.concatenate([x - 1, [s, s * s]])


def trigonometric(x):
    n = x.size
    i = np.arange(1, n + 1)
    return n - np.sum(np.cos(x)) + i * (1 - np.cos(x)) - np.sin(x)


def brown_almost_linear(x):
    n = x.size
    return np.concatenate([x[:-1] + np.sum(x) - (n + 1), [np.prod(x) - 1]])


def discrete_boundary(x):
    n = x.size
    h = 1 / (n + 1)
    t = h * np.arange(1, n + 1)
    xp = np.concatenate([[0 * x[0]], x, [0 * x[0]]])
    return 2 * x - xp[:-2] - xp[2:] + h ** 2 * (x + t + 1) ** 3 / 2


def discrete_integral(x):
    n = x.size
    h = 1 / (n + 1)
    t = h * np.arange(1, n + 1)
    c = (x + t + 1) ** 3
    out = []
    for i in range(n):
        s1 = np.sum(t[:i + 1] * c[:i + 1])
        s2 = np.sum((1 - t[i + 1:]) * c[i + 1:])
        out.append(x[i] + h * ((1 - t[i]) * s1 + t[i] * s2) / 2)
    return np.array(out)


def broyden_tridiagonal(x):
    xp = np.concatenate([[0 * x[0]], x, [0 * x[0]]])
    return (3 - 2 * x) * x - xp[:-2] - 2 * xp[2:] + 1


def broyden_banded(x, ml=5, mu=1):
    n = x.size
    out = []
    for i in range(n):
        js = [j for j in range(max(0, i - ml), min(n - 1, i + mu) + 1) if j != i]
        out.append(x[i] * (2 + 5 * x[i] ** 2) + 1 - sum(x[j] * (1 + x[j]) for j in js))
    return np.array(out)


def linear_full_rank(x, m=10):
    n = x.size
    s = np.sum(x)
    return np.concatenate([x - 2 * s / m - 1, np.full(m - n, 1.0) * (-2 * s / m - 1)])


def linear_rank1(x, m=10):
    j = np.arange(1, x.size + 1)
    return np.arange(1, m + 1) * np.sum(j * x) - 1


def linear_rank1_zero(x, m=10):
    n = x.size
    j = np.arange(2, n)
    s = np.sum(j * x[1:n - 1])
    return np.concatenate([[-1 + 0 * s], np.arange(1, m - 1) * s - 1, [-1 + 0 * s]])


def chebyquad(x, m=8):
    n = x.size
    y = 2 * x - 1
    T = [np.ones_like(y), y]
    for _ in range(2, m + 1):
        T.append(2 * y * T[-1] - T[-2])
    out = []
    for i in range(1, m + 1):
        integral = -1.0 / (i * i - 1) if i % 2 == 0 else 0.0
        out.append(np.sum(T[i]) / n - integral)
    return np.array(out)


def _p(num, name, x0, minima, f, m):
    x0 = np.asarray(x0, float)
    return Problem(num, name, x0.size, m, x0, tuple(float(v) for v in minima), f)


def problems() -> list[Problem]:
    """The 35 problems in the paper's order."""
    n10 = 10
    h = 1 / (n10 + 1)
    t10 = h * np.arange(1, n10 + 1)
    return [
        _p(1, "Rosenbrock", [-1.2, 1], [0], rosenbrock, 2),
        _p(2, "Freudenstein and Roth", [0.5, -2], [0, 48.9842], freudenstein_roth, 2),
        _p(3, "Powell badly scaled", [0, 1], [0], powell_badly_scaled, 2),
        _p(4, "Brown badly scaled", [1, 1], [0], brown_badly_scaled, 3),
        _p(5, "Beale", [1, 1], [0], beale, 3),
        _p(6, "Jennrich and Sampson", [0.3, 0.4], [124.362], jennrich_sampson, 10),
        _p(7, "Helical valley", [-1, 0, 0], [0], helical_valley, 3),
        _p(8, "Bard", [1, 1, 1], [8.21487e-3], bard, 15),
        _p(9, "Gaussian", [0.4, 1, 0], [1.12793e-8], gaussian, 15),
        _p(10, "Meyer", [0.02, 4000, 250], [87.9458], meyer, 16),
        _p(11, "Gulf research and development", [5, 2.5, 0.15], [0], gulf, 10),
        _p(12, "Box three-dimensional", [0, 10, 20], [0], box3, 10),
        _p(13, "Powell singular", [3, -1, 0, 1], [0], powell_singular, 4),
        _p(14, "Wood", [-3, -1, -3, -1], [0], wood, 6),
        _p(15, "Kowalik and Osborne", [0.25, 0.39, 0.415, 0.39], [3.07505e-4, 1.02734e-3],
           kowalik_osborne, 11),
        _p(16, "Brown and Dennis", [25, 5, -5, -1], [85822.2], brown_dennis, 20),
        _p(17, "Osborne 1", [0.5, 1.5, -1, 0.01, 0.02], [5.46489e-5], osborne1, 33),
        _p(18, "Biggs EXP6", [1, 2, 1, 1, 1, 1], [0, 5.65565e-3], biggs_exp6, 13),
        _p(19, "Osborne 2", [1.3, 0.65, 0.65, 0.7, 0.6, 3, 5, 7, 2, 4.5, 5.5], [4.01377e-2],
           osborne2, 65),
        _p(20, "Watson", np.zeros(6), [2.28767e-3], watson, 31),
        _p(21, "Extended Rosenbrock", np.tile([-1.2, 1], 5), [0], ext_rosenbrock, 10),
        _p(22, "Extended Powell singular", np.tile([3, -1, 0, 1], 3), [0], ext_powell, 12),
        _p(23, "Penalty I", np.arange(1, 11), [7.08765e-5], penalty1, 11),
        _p(24, "Penalty II", np.full(10, 0.5), [2.93660e-4], penalty2, 20),
        _p(25, "Variably dimensioned", 1 - np.arange(1, 11) / 10, [0], variably_dimensioned,
           12),
        _p(26, "Trigonometric", np.full(10, 0.1), [0, 2.79506e-5], trigonometric, 10),
        _p(27, "Brown almost-linear", np.full(10, 0.5), [0, 1], brown_almost_linear, 10),
        _p(28, "Discrete boundary value", t10 * (t10 - 1), [0], discrete_boundary, 10),
        _p(29, "Discrete integral equation", t10 * (t10 - 1), [0], discrete_integral, 10),
        _p(30, "Broyden tridiagonal", np.full(10, -1.0), [0], broyden_tridiagonal, 10),
        _p(31, "Broyden banded", np.full(10, -1.0), [0], broyden_banded, 10),
        _p(32, "Linear full rank", np.ones(5), [5], linear_full_rank, 10),
        _p(33, "Linear rank 1", np.ones(5), [10 * 9 / (2 * 21)], linear_rank1, 10),
        _p(34, "Linear rank 1 with zero columns and rows", np.ones(5),
           [(100 + 30 - 6) / (2 * 17)], linear_rank1_zero, 10),
        _p(35, "Chebyquad", np.arange(1, 9) / 9, [3.51687e-3], chebyquad, 8),
    ]


FACTORS = (1.0, 10.0, 100.0)


def runs():
    """The 105 runs: (problem, factor, start)."""
    return [(p, f, p.start(f)) for p in problems() for f in FACTORS]
