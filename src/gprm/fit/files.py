"""Reading fit results back: the one object later stages (predict, flight, report) use.

A :class:`FittedModel` is a parameter set plus the covariance of its fitted parameters. It
comes either from a fit result JSON (``gprm fit``, INTERFACES.md) or from the paper's Table 3
(best-fit values and their uncertainties as a diagonal reference covariance, MODEL.md), so
every later stage runs with or without a fit of its own.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace

import numpy as np

from gprm._io import read_json
from gprm.errors import GprmInputError
from gprm.params import REGISTRY, ParameterSet, batch_from_vectors, paper

MODEL_NAME = "gprm-3d"
FORMAT_VERSION = 1


@dataclass(frozen=True)
class FittedModel:
    """Best-fit parameters with the covariance (SI) of the fitted ones.

    Attributes
    ----------
    params: every parameter, SI; ``params.fitted`` are the fitted names, in the order of
        ``covariance``.
    covariance: (P, P) covariance of the fitted parameters, SI (Eq. 7).
    piezo: the piezo driven in the campaign the model was fitted to.
    source: a fit JSON path or ``paper``.
    """

    params: ParameterSet
    covariance: np.ndarray
    piezo: int = 2
    source: str = "paper"
    z_bk_absolute: bool = False

    @property
    def names(self) -> tuple[str, ...]:
        return self.params.fitted

    @property
    def stderr(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))

    def sample(self, n: int, seed: int = 0) -> dict[str, np.ndarray]:
        """``n`` parameter sets drawn from N(best, covariance), as a batch ``{name: (n,)}``.

        Draws that leave a parameter's physical range are redrawn (a truncated normal), so
        every set can be simulated.
        """
        x = self.params.vector()
        rng = np.random.default_rng(seed)
        lo = np.array([REGISTRY[k].lower for k in self.names])
        hi = np.array([REGISTRY[k].upper for k in self.names])
        from gprm.fit.covariance import sample_normal

        X = sample_normal(x, self.covariance, n, rng)
        for _ in range(100):
            bad = np.any((X <= lo) | (X >= hi), axis=1)
            if not bad.any():
                break
            X[bad] = sample_normal(x, self.covariance, int(bad.sum()), rng)
        else:
            X = np.clip(X, np.nextafter(lo, np.inf), np.nextafter(hi, -np.inf))
        return batch_from_vectors(self.params, self.names, X)


def paper_model(piezo: int = 2) -> FittedModel:
    """The paper's Table 3 best fit with its uncertainties as a diagonal covariance."""
    ps = paper()
    se = ps.paper_stderr()
    return FittedModel(ps, np.diag(se ** 2), piezo=piezo, source="paper")


def load_fit(path: str | os.PathLike) -> FittedModel:
    """Read a fit result JSON (INTERFACES.md) into a :class:`FittedModel`.

    The covariance is rebuilt from the standard errors and the correlation matrix. A file of
    another model or format version, or one without a covariance, is an input error.
    """
    src = str(path)
    doc = read_json(path, what="fit result")
    if not isinstance(doc, dict):
        raise GprmInputError("is not a fit result (expected a JSON object)", source=src)
    model = doc.get("model")
    if model != MODEL_NAME:
        raise GprmInputError(f"fit of model {model!r}, this gprm reads {MODEL_NAME!r}",
                             source=src, field="model")
    fv = doc.get("format_version", FORMAT_VERSION)
    if fv != FORMAT_VERSION:
        raise GprmInputError(f"format version {fv}, this gprm reads {FORMAT_VERSION}",
                             source=src, field="format_version")
    table = doc.get("parameters")
    if not isinstance(table, dict) or not table:
        raise GprmInputError("missing parameter table", source=src, field="parameters")
    values = dict(paper().values)
    for name, entry in table.items():
        if name not in REGISTRY:
            raise GprmInputError("unknown parameter (fit from another model version?)",
                                 source=src, field=f"parameters.{name}")
        try:
            values[name] = float(entry["value"])
        except (KeyError, TypeError, ValueError):
            raise GprmInputError("missing or non-numeric value", source=src,
                                 field=f"parameters.{name}") from None
    corr = doc.get("correlation") or {}
    names = tuple(corr.get("names") or ())
    matrix = corr.get("matrix")
    if not names or matrix is None:
        raise GprmInputError("no covariance in this fit (" + str(
            doc.get("covariance_message", "not estimated")) + ")", source=src,
            field="correlation")
    se = []
    for n in names:
        e = (table.get(n) or {}).get("stderr")
        if e is None or not np.isfinite(e):
            raise GprmInputError("fitted parameter without a standard error", source=src,
                                 field=f"parameters.{n}.stderr")
        se.append(float(e))
    se = np.asarray(se)
    R = np.asarray(matrix, float)
    if R.shape != (len(names), len(names)):
        raise GprmInputError(f"correlation matrix has shape {R.shape}, expected "
                             f"{(len(names), len(names))}", source=src, field="correlation")
    ps = ParameterSet(values, source=src).with_fitted(names)
    # with_fitted keeps registry order; reorder the covariance to match
    order = [names.index(n) for n in ps.fitted]
    cov = (R * np.outer(se, se))[np.ix_(order, order)]
    return FittedModel(ps, cov, piezo=int(doc.get("piezo", 2)), source=src,
                       z_bk_absolute=bool(doc.get("z_bk_absolute", False)))


def well_determined(fm: FittedModel, max_rel: float = 0.5) -> tuple[FittedModel, list]:
    """``fm`` with the covariance restricted to its well-determined parameters: a parameter
    whose standard error exceeds ``max_rel`` of its value (a direction the data barely
    constrain) is held at its best fit (its rows and columns set to zero). Returns the model
    and the names held."""
    se = np.sqrt(np.clip(np.diag(fm.covariance), 0.0, None))
    x = np.array([fm.params.values[n] for n in fm.names])
    keep = np.isfinite(se) & (se < max_rel * np.abs(x))
    held = [n for n, k in zip(fm.names, keep) if not k]
    cov = np.where(np.outer(keep, keep), fm.covariance, 0.0)
    return replace(fm, covariance=cov), held


def with_covariance_fallbacks(call, fm: FittedModel, notes: list, what: str):
    """``call(fm)``; if drawing parameter sets from the fit covariance gives a degenerate set
    (numpy LinAlgError: e.g. a stiffness drawn at its bound of zero), retry with the
    covariance of the well-determined parameters only, then without a covariance. Each
    fallback adds a note (once) to ``notes``. Used by ``gprm demo`` for every stage that
    draws from the fit covariance; a notebook can wrap its own calls the same way."""
    try:
        return call(fm)
    except np.linalg.LinAlgError as exc:
        first = exc
    fm2, held = well_determined(fm)
    try:
        out = call(fm2)
        note = (f"degenerate draws from the fit covariance ({first}): {what} use the "
                f"well-determined parameters' uncertainty only ({', '.join(held)} held at "
                "the best fit, standard error over 50 % of the value)")
    except np.linalg.LinAlgError:
        out = call(replace(fm, covariance=np.zeros_like(fm.covariance)))
        note = (f"degenerate draws from the fit covariance ({first}): {what} without "
                "parameter uncertainty")
    if note not in notes:
        notes.append(note)
    return out
