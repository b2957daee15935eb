"""NIST StRD nonlinear-regression problems: reader of the ``.dat`` files and, per problem, the
model function with its analytic Jacobian (written from the model formula in each file).

Residuals are ``f(x; b) - y`` (for Nelson, ``f - log y``, as its model is stated for log y),
so their sum of squares is the certified residual sum of squares at the certified b.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

# All 27 problems ship with the tests (a clone needs nothing outside the repository): the 19 of
# lower and average difficulty in nist_strd/, the 8 of higher difficulty in nist_strd_extra/
# (each folder's README says where the files come from).
DATA_DIR = Path(__file__).resolve().parent / "nist_strd"
EXTRA_DIR = Path(__file__).resolve().parent / "nist_strd_extra"
LOWER = ("Misra1a", "Chwirut2", "Chwirut1", "Lanczos3", "Gauss1", "Gauss2", "DanWood", "Misra1b",
         "Kirby2", "Hahn1", "Nelson", "MGH17", "Lanczos1", "Lanczos2", "Gauss3", "Misra1c",
         "Misra1d", "Roszman1", "ENSO")
HIGHER = ("MGH09", "Thurber", "BoxBOD", "Rat42", "MGH10", "Eckerle4", "Rat43", "Bennett5")

_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


@dataclass(frozen=True)
class Problem:
    name: str
    x: np.ndarray                 # (n,) or (n, 2) for Nelson
    y: np.ndarray
    starts: tuple[np.ndarray, np.ndarray]
    certified: np.ndarray
    certified_sd: np.ndarray
    rss: float
    model: Callable
    jac: Callable

    def residuals(self, b):
        return self.model(np.asarray(b, float), self.x) - self._target

    def jacobian(self, b):
        return self.jac(np.asarray(b, float), self.x)

    @property
    def _target(self):
        return np.log(self.y) if self.name == "Nelson" else self.y


def read(path: Path) -> dict:
    """Starting values, certified values, residual sum of squares and data of one file."""
    lines = path.read_text().splitlines()
    starts1, starts2, cert, sd = [], [], [], []
    rss = None
    data_start = None
    for i, line in enumerate(lines):
        m = re.match(rf"\s*b\d+\s*=\s*({_NUM})\s+({_NUM})\s+({_NUM})\s+({_NUM})\s*$", line)
        if m:
            a, b, c, d = map(float, m.groups())
            starts1.append(a), starts2.append(b), cert.append(c), sd.append(d)
        if line.strip().startswith("Residual Sum of Squares:"):
            rss = float(line.split(":")[1])
        if line.startswith("Data:") and re.search(r"\by\b", line) and "Observations" not in line \
                and "Variable" not in line:
            data_start = i + 1
    rows = [list(map(float, ln.split())) for ln in lines[data_start:] if ln.strip()]
    arr = np.array(rows)
    return {"start1": np.array(starts1), "start2": np.array(starts2),
            "certified": np.array(cert), "sd": np.array(sd), "rss": rss,
            "y": arr[:, 0], "x": arr[:, 1] if arr.shape[1] == 2 else arr[:, 1:]}


# ----------------------------------------------------------------------------- models

def _chwirut(b, x):
    return np.exp(-b[0] * x) / (b[1] + b[2] * x)


def _chwirut_j(b, x):
    e = np.exp(-b[0] * x)
    d = b[1] + b[2] * x
    return np.stack([-x * e / d, -e / d ** 2, -x * e / d ** 2], axis=1)


def _danwood(b, x):
    return b[0] * x ** b[1]


def _danwood_j(b, x):
    return np.stack([x ** b[1], b[0] * x ** b[1] * np.log(x)], axis=1)


def _enso(b, x):
    w = 2 * np.pi * x
    return (b[0] + b[1] * np.cos(w / 12) + b[2] * np.sin(w / 12)
            + b[4] * np.cos(w / b[3]) + b[5] * np.sin(w / b[3])
            + b[7] * np.cos(w / b[6]) + b[8] * np.sin(w / b[6]))


def _enso_j(b, x):
    w = 2 * np.pi * x
    c4, s4 = np.cos(w / b[3]), np.sin(w / b[3])
    c7, s7 = np.cos(w / b[6]), np.sin(w / b[6])
    # d/db of cos(w/b) = sin(w/b) * w / b^2 ; of sin(w/b) = -cos(w/b) * w / b^2
    d4 = (b[4] * s4 - b[5] * c4) * w / b[3] ** 2
    d7 = (b[7] * s7 - b[8] * c7) * w / b[6] ** 2
    return np.stack([np.ones_like(x), np.cos(w / 12), np.sin(w / 12), d4, c4, s4, d7, c7, s7],
                    axis=1)


def _gauss(b, x):
    return (b[0] * np.exp(-b[1] * x) + b[2] * np.exp(-(x - b[3]) ** 2 / b[4] ** 2)
            + b[5] * np.exp(-(x - b[6]) ** 2 / b[7] ** 2))


def _gauss_j(b, x):
    e1 = np.exp(-b[1] * x)
    g1 = np.exp(-(x - b[3]) ** 2 / b[4] ** 2)
    g2 = np.exp(-(x - b[6]) ** 2 / b[7] ** 2)
    return np.stack([
        e1, -b[0] * x * e1,
        g1, b[2] * g1 * 2 * (x - b[3]) / b[4] ** 2, b[2] * g1 * 2 * (x - b[3]) ** 2 / b[4] ** 3,
        g2, b[5] * g2 * 2 * (x - b[6]) / b[7] ** 2, b[5] * g2 * 2 * (x - b[6]) ** 2 / b[7] ** 3,
    ], axis=1)


def _rational(nnum):
    """(sum_{i<nnum} b_i x^i) / (1 + sum_j b_{nnum+j} x^(j+1))"""

    def f(b, x):
        num = sum(b[i] * x ** i for i in range(nnum))
        den = 1 + sum(b[nnum + j] * x ** (j + 1) for j in range(len(b) - nnum))
        return num / den

    def j(b, x):
        num = sum(b[i] * x ** i for i in range(nnum))
        den = 1 + sum(b[nnum + j] * x ** (j + 1) for j in range(len(b) - nnum))
        cols = [x ** i / den for i in range(nnum)]
        cols += [-num * x ** (jj + 1) / den ** 2 for jj in range(len(b) - nnum)]
        return np.stack(cols, axis=1)

    return f, j


def _lanczos(b, x):
    return b[0] * np.exp(-b[1] * x) + b[2] * np.exp(-b[3] * x) + b[4] * np.exp(-b[5] * x)


def _lanczos_j(b, x):
    cols = []
    for k in range(3):
        e = np.exp(-b[2 * k + 1] * x)
        cols += [e, -b[2 * k] * x * e]
    return np.stack(cols, axis=1)


def _mgh17(b, x):
    return b[0] + b[1] * np.exp(-x * b[3]) + b[2] * np.exp(-x * b[4])


def _mgh17_j(b, x):
    e4, e5 = np.exp(-x * b[3]), np.exp(-x * b[4])
    return np.stack([np.ones_like(x), e4, e5, -x * b[1] * e4, -x * b[2] * e5], axis=1)


def _misra1a(b, x):
    return b[0] * (1 - np.exp(-b[1] * x))


def _misra1a_j(b, x):
    e = np.exp(-b[1] * x)
    return np.stack([1 - e, b[0] * x * e], axis=1)


def _misra1b(b, x):
    return b[0] * (1 - (1 + b[1] * x / 2) ** -2)


def _misra1b_j(b, x):
    u = 1 + b[1] * x / 2
    return np.stack([1 - u ** -2, b[0] * x * u ** -3], axis=1)


def _misra1c(b, x):
    return b[0] * (1 - (1 + 2 * b[1] * x) ** -0.5)


def _misra1c_j(b, x):
    u = 1 + 2 * b[1] * x
    return np.stack([1 - u ** -0.5, b[0] * x * u ** -1.5], axis=1)


def _misra1d(b, x):
    return b[0] * b[1] * x / (1 + b[1] * x)


def _misra1d_j(b, x):
    u = 1 + b[1] * x
    return np.stack([b[1] * x / u, b[0] * x / u ** 2], axis=1)


def _nelson(b, x):
    return b[0] - b[1] * x[:, 0] * np.exp(-b[2] * x[:, 1])


def _nelson_j(b, x):
    e = np.exp(-b[2] * x[:, 1])
    return np.stack([np.ones(len(x)), -x[:, 0] * e, b[1] * x[:, 0] * x[:, 1] * e], axis=1)


def _roszman(b, x):
    return b[0] - b[1] * x - np.arctan(b[2] / (x - b[3])) / np.pi


def _roszman_j(b, x):
    u = x - b[3]
    den = np.pi * (u ** 2 + b[2] ** 2)
    return np.stack([np.ones_like(x), -x, -u / den, -b[2] / den], axis=1)


def _mgh09(b, x):
    return b[0] * (x ** 2 + x * b[1]) / (x ** 2 + x * b[2] + b[3])


def _mgh09_j(b, x):
    num = x ** 2 + x * b[1]
    den = x ** 2 + x * b[2] + b[3]
    return np.stack([num / den, b[0] * x / den, -b[0] * num * x / den ** 2,
                     -b[0] * num / den ** 2], axis=1)


def _boxbod(b, x):                      # the same model as Misra1a
    return _misra1a(b, x)


def _rat42(b, x):
    return b[0] / (1 + np.exp(b[1] - b[2] * x))


def _rat42_j(b, x):
    e = np.exp(b[1] - b[2] * x)
    u = 1 + e
    return np.stack([1 / u, -b[0] * e / u ** 2, b[0] * x * e / u ** 2], axis=1)


def _mgh10(b, x):
    return b[0] * np.exp(b[1] / (x + b[2]))


def _mgh10_j(b, x):
    u = x + b[2]
    e = np.exp(b[1] / u)
    return np.stack([e, b[0] * e / u, -b[0] * b[1] * e / u ** 2], axis=1)


def _eckerle4(b, x):
    return b[0] / b[1] * np.exp(-0.5 * ((x - b[2]) / b[1]) ** 2)


def _eckerle4_j(b, x):
    z = (x - b[2]) / b[1]
    f = b[0] / b[1] * np.exp(-0.5 * z ** 2)
    return np.stack([f / b[0], f * (z ** 2 - 1) / b[1], f * z / b[1]], axis=1)


def _rat43(b, x):
    return b[0] / (1 + np.exp(b[1] - b[2] * x)) ** (1 / b[3])


def _rat43_j(b, x):
    e = np.exp(b[1] - b[2] * x)
    u = 1 + e
    f = b[0] * u ** (-1 / b[3])
    dfu = -f / (b[3] * u)                                    # d f / d u
    return np.stack([f / b[0], dfu * e, -dfu * e * x, f * np.log(u) / b[3] ** 2], axis=1)


def _bennett5(b, x):
    return b[0] * (b[1] + x) ** (-1 / b[2])


def _bennett5_j(b, x):
    u = b[1] + x
    f = b[0] * u ** (-1 / b[2])
    return np.stack([f / b[0], -f / (b[2] * u), f * np.log(u) / b[2] ** 2], axis=1)


_hahn = _rational(4)
_kirby = _rational(3)
_thurber = _rational(4)

MODELS: dict[str, tuple[Callable, Callable]] = {
    "Chwirut1": (_chwirut, _chwirut_j), "Chwirut2": (_chwirut, _chwirut_j),
    "DanWood": (_danwood, _danwood_j), "ENSO": (_enso, _enso_j),
    "Gauss1": (_gauss, _gauss_j), "Gauss2": (_gauss, _gauss_j), "Gauss3": (_gauss, _gauss_j),
    "Hahn1": _hahn, "Kirby2": _kirby,
    "Lanczos1": (_lanczos, _lanczos_j), "Lanczos2": (_lanczos, _lanczos_j),
    "Lanczos3": (_lanczos, _lanczos_j), "MGH17": (_mgh17, _mgh17_j),
    "Misra1a": (_misra1a, _misra1a_j), "Misra1b": (_misra1b, _misra1b_j),
    "Misra1c": (_misra1c, _misra1c_j), "Misra1d": (_misra1d, _misra1d_j),
    "Nelson": (_nelson, _nelson_j), "Roszman1": (_roszman, _roszman_j),
    # higher difficulty
    "MGH09": (_mgh09, _mgh09_j), "Thurber": _thurber, "BoxBOD": (_boxbod, _misra1a_j),
    "Rat42": (_rat42, _rat42_j), "MGH10": (_mgh10, _mgh10_j),
    "Eckerle4": (_eckerle4, _eckerle4_j), "Rat43": (_rat43, _rat43_j),
    "Bennett5": (_bennett5, _bennett5_j),
}


def path(name: str) -> Path:
    return (EXTRA_DIR if name in HIGHER else DATA_DIR) / f"{name}.dat"


def load(name: str) -> Problem:
    d = read(path(name))
    f, j = MODELS[name]
    return Problem(name, d["x"], d["y"], (d["start1"], d["start2"]), d["certified"], d["sd"],
                   d["rss"], f, j)


def names() -> list[str]:
    """The 19 lower/average-difficulty problems and the 8 higher-difficulty ones."""
    return sorted(LOWER + HIGHER)


def digits(b: np.ndarray, certified: np.ndarray) -> float:
    """Log relative error (LRE): the number of significant digits of b that agree with the
    certified values, the minimum over the parameters (capped at 11)."""
    b = np.asarray(b, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.abs(b - certified) / np.abs(certified)
        lre = -np.log10(rel)
    lre = np.where(np.isfinite(lre), lre, np.where(rel == 0, 11.0, 0.0))
    return float(np.clip(np.min(lre), 0.0, 11.0))
