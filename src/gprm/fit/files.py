"""Reading fit results back: the one object later stages (predict, flight, report) use.

A :class:`FittedModel` is a parameter set plus the covariance of its fitted parameters. It
comes either from a fit result JSON (``gprm fit``, INTERFACES.md) or from the paper's Table 3
(best-fit values and their uncertainties as a diagonal reference covariance, MODEL.md), so
every later stage runs with or without a fit of its own.
"""

from __future__ import annotations

import os
from pathlib import Path
from dataclasses import dataclass

import numpy as np

from gprm._io import read_json
from gprm.errors import GprmInputError
from gprm.fit.covariance import sample_normal
from gprm.params import REGISTRY, ParameterSet, batch_from_vectors, paper

MODEL_NAME = "gprm-3d"
FORMAT_VERSION = 1


@dataclass(frozen=True)
class FittedModel:
    """Best-fit parameters with the uncertainty of the fitted ones: the one object every later
    stage (predict, flight, report) consumes.

    Attributes
    ----------
    params: every parameter, SI; ``params.fitted`` are the fitted names, in the order of
        ``covariance`` and of the columns of ``draws``.
    covariance: (P, P) covariance of the fitted parameters, SI, from the fit's uncertainty
        method (linearised); ``None`` where the fit could not estimate one.
    draws: (n, P) parameter sets from the fit's uncertainty method (posterior draws or
        bootstrap refits), SI, or ``None``. Where present, :meth:`sample` resamples them
        instead of drawing from N(best, covariance): they carry the non-Gaussian shape
        (positive parameters, bounded directions) that a covariance cannot.
    identified: names the data determine (issue 12); ``None`` where not assessed.
    uncertainty: the method's name (``eq7``, ``laplace-prior``, ``none`` ...).
    piezo: the piezo driven in the campaign the model was fitted to.
    source: a fit JSON path or ``paper``.
    """

    params: ParameterSet
    covariance: np.ndarray | None
    piezo: int = 2
    source: str = "paper"
    z_bk_absolute: bool = False
    draws: np.ndarray | None = None
    identified: tuple[str, ...] | None = None
    uncertainty: str = "covariance"

    @property
    def names(self) -> tuple[str, ...]:
        return self.params.fitted

    @property
    def stderr(self) -> np.ndarray:
        if self.covariance is None:
            return np.full(len(self.names), np.nan)
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def has_uncertainty(self) -> bool:
        """False where only the best fit is known: :meth:`sample` then repeats it."""
        if self.draws is not None and len(self.draws) >= 2:
            return True
        if self.covariance is None:
            return False
        d = np.diag(self.covariance)
        return bool(np.all(np.isfinite(self.covariance)) and np.any(d > 0))

    @property
    def uncertainty_note(self) -> str:
        """One line for consoles, files and the report."""
        if self.has_uncertainty:
            return f"parameter uncertainty from the fit ({self.uncertainty})"
        return ("best fit only: this fit has no usable parameter uncertainty, so no bands "
                "or intervals are drawn from it")

    def sample(self, n: int, seed: int = 0) -> dict[str, np.ndarray]:
        """``n`` parameter sets as a batch ``{name: (n,)}`` that can all be simulated.

        From ``draws`` (resampled with replacement, seeded) where present, else from
        N(best, covariance) with draws outside a parameter's physical range redrawn. Sets
        with a singular mass or stiffness matrix (:func:`gprm.model.linear.admissible`) are
        redrawn too; where none can be had (or no uncertainty exists) the best fit is
        repeated. Never raises on a degenerate covariance.
        """
        from gprm.model.linear import admissible

        n = int(n)
        x = self.params.vector()
        rng = np.random.default_rng(seed)
        if n <= 0:
            return batch_from_vectors(self.params, self.names, np.zeros((0, x.size)))
        if not self.has_uncertainty:
            return batch_from_vectors(self.params, self.names, np.repeat(x[None], n, 0))
        lo, hi = self._bounds()

        def draw(k):
            if self.draws is not None and len(self.draws) >= 2:
                return np.asarray(self.draws, float)[rng.integers(0, len(self.draws), k)]
            return sample_normal(x, np.nan_to_num(self.covariance), k, rng)

        def good(X):
            inside = np.all((X > lo) & (X < hi) & np.isfinite(X), axis=1)
            ok = inside.copy()
            if inside.any():
                pb = batch_from_vectors(self.params, self.names, X[inside])
                ok[inside] = admissible(pb, self.piezo)
            return ok

        X = draw(n)
        ok = good(X)
        for _ in range(50):
            if ok.all():
                break
            bad = ~ok
            X[bad] = draw(int(bad.sum()))
            ok[bad] = good(X[bad])
        if not ok.all():
            keep = X[ok] if ok.any() else x[None]
            X[~ok] = keep[rng.integers(0, len(keep), int((~ok).sum()))]
        return batch_from_vectors(self.params, self.names, X)

    def _bounds(self) -> tuple[np.ndarray, np.ndarray]:
        b = [self.params.bounds.get(k, (REGISTRY[k].lower, REGISTRY[k].upper))
             for k in self.names]
        return np.array([v[0] for v in b], float), np.array([v[1] for v in b], float)


def paper_model(piezo: int = 2) -> FittedModel:
    """The paper's Table 3 best fit with its uncertainties as a diagonal covariance."""
    ps = paper()
    se = ps.paper_stderr()
    return FittedModel(ps, np.diag(se ** 2), piezo=piezo, source="paper")


def _number(x, src: str, field: str, *, allow_none: bool = False):
    """A finite JSON number (bool is not one), or an input error naming the field."""
    if x is None and allow_none:
        return None
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not np.isfinite(x):
        raise GprmInputError(f"expected a finite number, got {x!r}", source=src, field=field)
    return float(x)


def load_fit(path: str | os.PathLike) -> FittedModel:
    """Read a fit result JSON (INTERFACES.md) into a :class:`FittedModel`.

    Every fit ``gprm fit`` writes loads, with or without a covariance: where there is none
    (``correlation.matrix`` null), the model is the best fit alone (``has_uncertainty``
    False) and later stages say so. The covariance is rebuilt from the standard errors and the
    correlation matrix; the uncertainty method's parameter draws are read from the NetCDF
    sidecar (same name, ``.nc``) where it holds them. A file of another model or format
    version, a value that is not a finite number, a matrix of the wrong shape, or a best fit
    that cannot be simulated (a zero spring or mass) is an input error naming the field.
    """
    from gprm.model.linear import admissible
    from gprm.params import validate_values

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
    piezo = doc.get("piezo", 2)
    if piezo not in (1, 2) or isinstance(piezo, bool):
        raise GprmInputError(f"must be 1 or 2, got {piezo!r}", source=src, field="piezo")
    table = doc.get("parameters")
    if not isinstance(table, dict) or not table:
        raise GprmInputError("missing parameter table", source=src, field="parameters")
    values = dict(paper().values)
    for name, entry in table.items():
        if name not in REGISTRY:
            raise GprmInputError("unknown parameter (fit from another model version?)",
                                 source=src, field=f"parameters.{name}")
        if not isinstance(entry, dict) or "value" not in entry:
            raise GprmInputError("missing value", source=src, field=f"parameters.{name}")
        values[name] = _number(entry["value"], src, f"parameters.{name}.value")
    validate_values(values, source=src)
    corr = doc.get("correlation") or {}
    if not isinstance(corr, dict):
        raise GprmInputError("expected an object with names and matrix", source=src,
                             field="correlation")
    names = corr.get("names") or [n for n, e in table.items()
                                  if isinstance(e, dict) and e.get("fitted")]
    if not isinstance(names, list) or not all(isinstance(n, str) and n in REGISTRY
                                              for n in names):
        raise GprmInputError("expected a list of parameter names", source=src,
                             field="correlation.names")
    names = tuple(names)
    if not names:
        raise GprmInputError("no fitted parameters", source=src, field="correlation.names")
    ps = ParameterSet(values, source=src).with_fitted(names)
    if not admissible(batch_from_vectors(ps, (), np.zeros((1, 0))), int(piezo))[0]:
        zero = [n for n in REGISTRY if values[n] == 0.0 and REGISTRY[n].lower == 0.0]
        raise GprmInputError("the best fit cannot be simulated (singular mass or stiffness "
                             "matrix" + (f"; zero: {', '.join(zero)}" if zero else "") + ")",
                             source=src, field="parameters" + (f".{zero[0]}" if zero else ""))
    order = [names.index(n) for n in ps.fitted]      # with_fitted keeps registry order
    cov = None
    matrix = corr.get("matrix")
    if matrix is not None:
        try:
            R = np.asarray(matrix, float)
        except (TypeError, ValueError):
            raise GprmInputError("not a numeric matrix", source=src,
                                 field="correlation.matrix") from None
        if R.shape != (len(names), len(names)) or not np.all(np.isfinite(R)):
            raise GprmInputError(f"expected a finite {len(names)} x {len(names)} matrix, got "
                                 f"shape {R.shape}", source=src, field="correlation.matrix")
        if not np.allclose(R, R.T, atol=1e-9) or np.any(np.abs(np.diag(R) - 1) > 1e-9):
            raise GprmInputError("not a correlation matrix (symmetric, unit diagonal)",
                                 source=src, field="correlation.matrix")
        if np.linalg.eigvalsh(R)[0] < -1e-6:
            raise GprmInputError("not positive semi-definite", source=src,
                                 field="correlation.matrix")
        se = np.array([_number((table.get(n) or {}).get("stderr"), src,
                               f"parameters.{n}.stderr") for n in names])
        if np.any(se < 0):
            k = int(np.argmax(se < 0))
            raise GprmInputError(f"negative standard error {se[k]:g}", source=src,
                                 field=f"parameters.{names[k]}.stderr")
        cov = (R * np.outer(se, se))[np.ix_(order, order)]
    unc = doc.get("uncertainty") if isinstance(doc.get("uncertainty"), dict) else {}
    ident = doc.get("identified")
    ident = tuple(n for n in ident if n in names) if isinstance(ident, list) else None
    draws = _read_draws(Path(src).with_suffix(".nc"), ps.fitted)
    return FittedModel(ps, cov, piezo=int(piezo), source=src,
                       z_bk_absolute=bool(doc.get("z_bk_absolute", False)), draws=draws,
                       identified=ident,
                       uncertainty=str(unc.get("method", "eq7" if cov is not None else "none")))


def _read_draws(side: Path, names: tuple[str, ...]) -> np.ndarray | None:
    """The uncertainty method's parameter draws from a fit's sidecar, or None (no sidecar, or
    none stored). A sidecar that is there but unreadable is ignored: the JSON alone is the
    documented result, and the covariance then stands in."""
    if not side.is_file():
        return None
    import xarray as xr

    try:
        with xr.open_dataset(side) as ds:
            if "posterior_draws" not in ds:
                return None
            da = ds["posterior_draws"]
            have = [str(v) for v in da["param"].values]
            if not set(names) <= set(have):
                return None
            X = np.asarray(da.sel(param=list(names)).transpose("draw", "param").values, float)
    except Exception:  # noqa: BLE001 - optional extra; see the docstring
        return None
    return X if X.ndim == 2 and len(X) >= 2 and np.all(np.isfinite(X)) else None
