"""Parameter covariance of a least-squares fit (Eq. 7) and checks that make it meaningless.

Eq. 7: ``C = (e_x^T e_x / (m - p)) (J_x^T J_x)^{-1}`` with ``e_x = D e`` the weighted residuals
at the best fit and ``J_x`` their Jacobian; ``m - p`` the degrees of freedom. The factor in
front is the reduced chi-square, so C does not depend on an overall scale error of sigma
(``--sigma sem`` and ``--sigma std`` give the same C).
"""

from __future__ import annotations

import numpy as np


class CovarianceError(ValueError):
    """The covariance cannot be estimated; the message says why."""


def covariance(J: np.ndarray, r: np.ndarray, dof: int, *, rcond: float = 1e-12,
               names=None) -> np.ndarray:
    """Eq. 7 covariance (P, P) from the weighted residuals r (N,) and Jacobian J (N, P).

    The inverse of J^T J is computed from the SVD of J with the columns scaled to unit norm
    (so that parameters of very different magnitude do not make a well-posed problem look
    singular). Raises :class:`CovarianceError` when dof <= 0, when J or r is not finite,
    when a parameter has no effect on the residuals (zero column), or when J^T J is singular
    (scaled condition number of J above 1/rcond, i.e. of J^T J above 1/rcond^2), naming the
    parameter combination responsible.
    """
    J = np.asarray(J, float)
    r = np.asarray(r, float)
    N, P = J.shape
    label = (lambda k: str(names[k])) if names is not None else (lambda k: f"#{k}")
    if dof <= 0:
        raise CovarianceError(f"no degrees of freedom left ({N} observations, {P} parameters)")
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(r))):
        raise CovarianceError("Jacobian or residuals not finite at the best fit")
    norms = np.linalg.norm(J, axis=0)
    zero = np.nonzero(norms == 0)[0]
    if zero.size:
        raise CovarianceError("singular J^T J: parameter(s) with no effect on the fitted "
                              "signals: " + ", ".join(label(k) for k in zero))
    Js = J / norms
    U, s, Vt = np.linalg.svd(Js, full_matrices=False)
    if s[-1] <= rcond * s[0]:
        v = Vt[-1]
        top = np.argsort(-np.abs(v))[:3]
        combo = " + ".join(f"{v[k]:+.2f} {label(k)}" for k in top)
        raise CovarianceError(f"singular J^T J (condition number of the scaled Jacobian "
                              f"{s[0] / max(s[-1], 1e-300):.2e} > {1 / rcond:.0e}); the "
                              f"direction not determined by the data is about {combo}")
    inv_scaled = (Vt.T / s ** 2) @ Vt
    s2 = float(r @ r) / dof
    C = s2 * inv_scaled / np.outer(norms, norms)
    return 0.5 * (C + C.T)


def parameters_at_bounds(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, *,
                         rtol: float = 1e-6) -> np.ndarray:
    """Boolean mask of parameters within ``rtol`` of a bound, for ``x`` in normalised (O(1))
    coordinates: relative to the width of the box where it is finite, else to
    max(1, |bound|). Their standard errors are not reliable (the minimum is constrained, not
    stationary)."""
    x = np.asarray(x, float)
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    with np.errstate(invalid="ignore"):
        width = hi - lo
        tol_lo = rtol * np.where(np.isfinite(width), width, np.maximum(1.0, np.abs(lo)))
        tol_hi = rtol * np.where(np.isfinite(width), width, np.maximum(1.0, np.abs(hi)))
        return (np.isfinite(lo) & (x - lo <= tol_lo)) | (np.isfinite(hi) & (hi - x <= tol_hi))


def sample_normal(x: np.ndarray, cov: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` draws (n, P) from N(x, cov), computed in standardised coordinates.

    The fitted parameters span ~14 orders of magnitude in SI (stiffness ~1e8, times ~1e-6),
    so their covariance spans ~28: factorising it directly (as ``rng.multivariate_normal``
    does) loses the small variances to round-off. Here cov = S R S with S = diag(stderr) and
    the correlation R (O(1) entries) is factorised by its eigen-decomposition (negative
    round-off eigenvalues set to 0).
    """
    x = np.asarray(x, float)
    z = rng.standard_normal((int(n), x.size)) @ normal_factor(cov).T
    return x[None] + z


def normal_factor(cov: np.ndarray) -> np.ndarray:
    """L (P, P) with L L^T = ``cov`` (a covariance, positive semi-definite up to round-off):
    standard normal vectors z give draws L z of N(0, cov) whose every marginal variance is
    ``cov``'s diagonal to round-off, whatever the scales.

    cov = S R S with S = diag(sd) and the correlation R factorised by its symmetric eigen-
    decomposition (negative round-off eigenvalues set to 0). Factorising cov itself loses
    the small variances: in the prior's coordinates the lags' variances are ~1e-15 s^2
    beside O(1) ones, below the eigen-solver's absolute error, and their draws came out with
    sds several per cent off theirs (tests/fit/test_covariance.py)."""
    s, B, _ = _correlation_eigen(cov)
    return s[:, None] * B


def symmetric_root(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sd (P,), R^(1/2) (P, P)): ``cov`` = S R S with S = diag(sd), and the symmetric
    positive semi-definite square root of the correlation R, the root nearest the identity
    (the eigen-decomposition of :func:`normal_factor`; gprm.fit.sandwich.stretch_whitened)."""
    s, B, V = _correlation_eigen(cov)
    return s, B @ V.T


def _correlation_eigen(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sd, V sqrt(w), V): ``cov``'s sds and its correlation's eigenvectors V scaled by the
    square roots of the eigenvalues w (negative round-off ones set to 0)."""
    s, R = standardised(cov)
    w, V = np.linalg.eigh(R)
    return s, V * np.sqrt(np.clip(w, 0, None)), V


def standardised(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sd (P,), R (P, P)): ``cov``'s standard deviations and its correlation matrix
    (symmetrised; a zero variance leaves its row and column of R zero), the O(1) form in
    which a covariance whose scales span many orders of magnitude is factorised or whitened
    without losing the small ones to round-off (:func:`normal_factor`)."""
    cov = np.asarray(cov, float)
    s = np.sqrt(np.clip(np.diag(cov), 0, None))
    safe = np.where(s > 0, s, 1.0)
    R = cov / np.outer(safe, safe)
    return s, 0.5 * (R + R.T)
