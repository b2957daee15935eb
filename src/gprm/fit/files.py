"""The fit file: its writer and its reader side by side, and :class:`FittedModel`, the object
every later stage (predict, flight, report, run) consumes.

The fit file is a JSON document (docs/spec.md, docs/fitting.md) with a NetCDF sidecar of the
same name (``.nc``: every start, the data, the bands, the covariance, the uncertainty
method's draws).

- writing: :func:`write_fit` (:func:`fit_document`, :func:`fit_sidecar`, both from a
  :class:`gprm.fit.result.FitResult`);
- reading: :func:`read_fit_document` (the JSON, validated: model, format version, parameter
  table), :func:`read_fit_sidecar`, :func:`load_fit` (a :class:`FittedModel`) and
  :func:`load_model`, which resolves what a command accepts as a model: the word ``paper``
  (the paper's Table 3 with its uncertainties as a diagonal reference covariance,
  docs/spec.md), a fit JSON, or a run folder holding ``fit.json``.
"""

from __future__ import annotations

import hashlib
import os
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import xarray as xr

import gprm
from gprm._io import (atomic_paths, json_text, write_text_to, open_netcdf, read_json, write_netcdf_to)
from gprm.campaign.files import has_truth
from gprm.errors import GprmInputError
from gprm.fit.covariance import sample_normal
from gprm.model.linear import admissible
from gprm.model.piezo import check_piezo
from gprm.params import (REGISTRY, ParameterSet, batch_from_vectors, from_si, paper,
                         validate_values)
from gprm.params.files import si_unit_strings
from gprm.validate import Schema, Var, check_dataset

if TYPE_CHECKING:
    from gprm.fit.objective import FitData
    # what the writer reads of a gprm.fit.result.FitResult (which imports this module to
    # write itself: naming its class here would close an import circle)
    from gprm.fit.record import FitRecord as FitResult
    from gprm.fit.starts import StartsOutcome

MODEL_NAME = "gprm-3d"
FORMAT_VERSION = 1

#: the fit's NetCDF sidecar as its reader checks it (docs/fitting.md, "Files"): required are
#: what its readers use (the starts' final chi-square, the data and their sigma); the rest is
#: checked where present. The starts' values may be NaN (a failed start), the bands too (no
#: covariance)
FIT_SIDECAR = Schema("fit sidecar NetCDF", (
    Var("time", ("time",), "s", increasing=True),
    Var("signal", ("signal",), numeric=False, unique=True),
    Var("chi2", ("start",), finite=False, min=0.0),
    Var("data_mean", ("signal", "time"), "m"),
    Var("data_sigma", ("signal", "time"), "m", min=0.0, min_open=True),
    Var("param", ("param",), numeric=False, unique=True, required=False),
    Var("x0", ("start", "param"), required=False, finite=False),
    Var("x", ("start", "param"), required=False, finite=False),
    Var("chi2_0", ("start",), required=False, finite=False, min=0.0),
    Var("status", ("start",), numeric=False, required=False),
    *(Var(v, ("signal", "time"), "m", required=False, finite=False)
      for v in ("model_best", "band_linear_std", "band_sample_std", "band_sample_lo",
                "band_sample_hi", "resonance_fitted")),
    Var("covariance", ("param", "param2"), required=False, finite=False),
    Var("posterior_draws", ("draw", "param"), required=False, finite=False),
))


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
    covariance_message: the fit's note on its covariance (why there is none, parameters at a
        bound), ``""`` where not given.
    sidecar_note: ``""``, or why the fit's sidecar was ignored (``load_fit(...,
        ignore_sidecar=True)`` on a sidecar that is missing, unreadable or not the fit's own):
        the draws it holds are then not used, and :attr:`uncertainty_note` says so.
    """

    params: ParameterSet
    covariance: np.ndarray | None
    piezo: int = 2
    source: str = "paper"
    z_bk_absolute: bool = False
    draws: np.ndarray | None = None
    identified: tuple[str, ...] | None = None
    uncertainty: str = "covariance"
    covariance_message: str = ""
    sidecar_note: str = ""

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
        extra = f"; {self.sidecar_note}" if self.sidecar_note else ""
        if self.has_uncertainty:
            return f"parameter uncertainty from the fit ({self.uncertainty}){extra}"
        return ("best fit only: this fit has no usable parameter uncertainty, so no bands "
                "or intervals are drawn from it" + extra)

    def sample(self, n: int, seed: int = 0) -> dict[str, np.ndarray]:
        """``n`` parameter sets as a batch ``{name: (n,)}`` that can all be simulated.

        From ``draws`` (resampled with replacement, seeded) where present, else from
        N(best, covariance) with draws outside a parameter's physical range redrawn. Sets
        with a singular mass or stiffness matrix (:func:`gprm.model.linear.admissible`) are
        redrawn too; where none can be had (or no uncertainty exists) the best fit is
        repeated. Never raises on a degenerate covariance.
        """
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


def read_fit_document(path: str | os.PathLike) -> dict:
    """The JSON of a fit file, validated: a JSON object of this model (``model``) and format
    version with a non-empty parameter table of known parameters, each with a finite value.
    A missing or unreadable file, or any of these problems, is an input error naming the file
    and the field. The file is not modified."""
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
    check_piezo(piezo, source=src)
    table = doc.get("parameters")
    if not isinstance(table, dict) or not table:
        raise GprmInputError("missing parameter table", source=src, field="parameters")
    for name, entry in table.items():
        if name not in REGISTRY:
            raise GprmInputError("unknown parameter (fit from another model version?)",
                                 source=src, field=f"parameters.{name}")
        if not isinstance(entry, dict) or "value" not in entry:
            raise GprmInputError("missing value", source=src, field=f"parameters.{name}")
        _number(entry["value"], src, f"parameters.{name}.value")
    _check_field_types(doc, src)
    return doc


#: the JSON type of each top-level field of a fit result that readers use (a field may be
#: absent, as in files of earlier versions; where present it must have this type)
_FIELD_TYPES: dict[str, tuple[type, ...]] = {
    **dict.fromkeys(("uncertainty", "correlation", "starts", "data", "polish", "timings_s",
                     "sidecar"), (dict,)),
    **dict.fromkeys(("signals", "identified", "leans_on_prior", "not_determined",
                     "identifiable_combinations", "parameters_at_bounds", "profiles"), (list,)),
    **dict.fromkeys(("chi2", "reduced_chi2"), (int, float)),
    **dict.fromkeys(("dof", "seed", "sigma_pool", "band_samples"), (int,)),
    **dict.fromkeys(("sigma", "version", "covariance_message"), (str,)),
    "z_bk_absolute": (bool,),
}
_TYPE_NAMES = {dict: "an object", list: "a list", int: "a number", float: "a number",
               str: "a string", bool: "true or false"}


def _check_field_types(doc: dict, src: str) -> None:
    """Refuse a fit result whose top-level fields (:data:`_FIELD_TYPES`, and ``window``: two
    numbers) have the wrong JSON type, naming the field, so that no reader (``gprm show``,
    ``gprm design``, the report) meets one it cannot use."""
    for key, types in _FIELD_TYPES.items():
        if key not in doc:
            continue
        v = doc[key]
        wrong = not isinstance(v, types) or (isinstance(v, bool) and bool not in types)
        if wrong:
            raise GprmInputError(f"expected {_TYPE_NAMES[types[0]]}, got {str(v)[:40]!r}",
                                 source=src, field=key)
    if "window" in doc:
        w = doc["window"]
        if not (isinstance(w, list) and len(w) == 2):
            raise GprmInputError("expected two numbers [start, end] (s)", source=src,
                                 field="window")
        for i, x in enumerate(w):
            _number(x, src, f"window[{i}]")


def read_fit_sidecar(path: str | os.PathLike) -> xr.Dataset:
    """The NetCDF sidecar of a fit file (``fit.nc``; the JSON's name is accepted too), checked
    against :data:`FIT_SIDECAR` (variables, dimensions, units converted to SI); a problem is
    an input error naming the file and the variable."""
    path = Path(path)
    if path.suffix == ".json":
        path = path.with_suffix(".nc")
    return check_dataset(open_netcdf(path, what="fit sidecar"), FIT_SIDECAR, str(path))


def load_fit(path: str | os.PathLike, *, ignore_sidecar: bool = False) -> FittedModel:
    """Read a fit result JSON (docs/spec.md) into a :class:`FittedModel`.

    Every fit ``gprm fit`` writes loads, with or without a covariance: where there is none
    (``correlation.matrix`` null), the model is the best fit alone (``has_uncertainty``
    False) and later stages say so (``covariance_message`` tells why). The covariance is
    rebuilt from the standard errors and the correlation matrix; the uncertainty method's
    parameter draws are read from the NetCDF sidecar (same name, ``.nc``) where it holds them.
    A file of another model or format version, a value that is not a finite number, a matrix
    of the wrong shape, or a best fit that cannot be simulated (a zero spring or mass) is an
    input error naming the field (:func:`read_fit_document`).

    The sidecar is bound to its JSON by the SHA-256 the writer records (``"sidecar"``): a
    sidecar that is missing, unreadable or does not match is an input error naming both
    files, unless ``ignore_sidecar``: then its draws are not used (the covariance stands in,
    narrower where the draws are not Gaussian) and ``sidecar_note`` says so. A fit JSON of an
    older gprm records no checksum: its sidecar is used unchecked, with a warning on stderr.
    """
    src = str(path)
    doc = read_fit_document(path)
    piezo = doc.get("piezo", 2)
    table = doc["parameters"]
    values = dict(paper().values)
    for name, entry in table.items():
        values[name] = float(entry["value"])
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
    unc = doc.get("uncertainty")
    unc = unc if isinstance(unc, dict) else {}
    ident = doc.get("identified")
    ident = tuple(n for n in ident if n in names) if isinstance(ident, list) else None
    draws, note = _sidecar_draws(src, doc, ps.fitted, ignore_sidecar)
    return FittedModel(ps, cov, piezo=int(piezo), source=src, sidecar_note=note,
                       z_bk_absolute=bool(doc.get("z_bk_absolute", False)), draws=draws,
                       identified=ident,
                       uncertainty=str(unc.get("method", "eq7" if cov is not None else "none")),
                       covariance_message=str(doc.get("covariance_message", "") or ""))


def model_inputs(source) -> list[Path]:
    """The files :func:`load_model` reads for ``source`` (for
    :func:`gprm._io.check_outputs`, which adds the fit JSON's ``.nc`` sidecar): none for
    ``paper``, the folder's ``fit.json`` for a run folder, else the file itself."""
    if source is None or isinstance(source, FittedModel) or str(source) == "paper":
        return []
    path = Path(source)
    return [path / "fit.json"] if path.is_dir() else [path]


def load_model(source: str | os.PathLike | FittedModel, *,
               piezo: int | None = None, ignore_sidecar: bool = False) -> FittedModel:
    """The model a command or stage runs on: a :class:`FittedModel` as it is, the word
    ``paper`` (:func:`paper_model`), a fit JSON (:func:`load_fit`) or a run folder (its
    ``fit.json``). ``piezo`` (1 or 2) overrides the piezo of the fitted campaign (``paper``:
    default 2). ``ignore_sidecar``: see :func:`load_fit`."""
    check_piezo(piezo, optional=True)
    if isinstance(source, FittedModel):
        fm = source
    elif str(source) == "paper":
        return paper_model(piezo or 2)
    else:
        path = Path(source)
        fm = load_fit(path / "fit.json" if path.is_dir() else path,
                      ignore_sidecar=ignore_sidecar)
    if piezo is not None and piezo != fm.piezo:
        fm = replace(fm, piezo=piezo)
    return fm


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _sidecar_draws(src: str, doc: dict, names: tuple[str, ...],
                   ignore: bool) -> tuple[np.ndarray | None, str]:
    """The draws of the fit JSON ``src``'s sidecar, checked against the SHA-256 its JSON
    records (:func:`load_fit`), and the note of a sidecar ignored (``""`` where none was)."""
    side = Path(src).with_suffix(".nc")
    rec = doc.get("sidecar")
    problem = ""
    if rec is None:                              # a fit JSON of an older gprm
        if not side.is_file():
            return None, ""
        print(f"gprm: warning: {src} records no checksum of its sidecar {side} (written by "
              "an older gprm): the sidecar is used unchecked", file=sys.stderr)
    elif not (isinstance(rec, dict) and isinstance(rec.get("sha256"), str)):
        raise GprmInputError("expected an object with the sidecar's name and sha256",
                             source=src, field="sidecar")
    elif not side.is_file():
        problem = "is missing"
    else:
        try:
            ok = file_sha256(side) == rec["sha256"]
        except OSError as exc:
            ok, problem = True, f"cannot be read ({exc.strerror or exc})"
        if not ok:
            problem = ("does not match the SHA-256 the fit records (changed, damaged, or "
                       "another fit's)")
    draws = None
    if not problem:
        try:
            draws = _read_draws(side, names)
        except GprmInputError as exc:
            problem = f"cannot be read ({exc.problem})"
    if not problem:
        return draws, ""
    if not ignore:
        raise GprmInputError(f"its sidecar {side} {problem}; pass --ignore-sidecar to use the "
                             "fit without it (covariance bands, narrower)", source=src,
                             field="sidecar")
    return None, (f"sidecar {side.name} ignored ({problem}): parameter draws from the "
                  "covariance, not the fit's own")


def _read_draws(side: Path, names: tuple[str, ...]) -> np.ndarray | None:
    """The uncertainty method's parameter draws from a fit's sidecar, or None (none stored).
    A sidecar that cannot be read is an input error (:func:`_sidecar_draws` decides)."""
    ds = open_netcdf(side, what="fit sidecar")
    if "posterior_draws" not in ds:
        return None
    try:                        # this variable only: the rest of the sidecar is not needed
        da = ds["posterior_draws"]
        have = [str(v) for v in da["param"].values]
        if not set(names) <= set(have):
            return None
        X = np.asarray(da.sel(param=list(names)).transpose("draw", "param").values, float)
    except Exception as exc:  # noqa: BLE001 - any failure of a damaged variable
        raise GprmInputError(f"posterior_draws: {type(exc).__name__}", source=str(side),
                             field="posterior_draws") from None
    return X if X.ndim == 2 and len(X) >= 2 and np.all(np.isfinite(X)) else None


# ----------------------------------------------------------------------------- writer

def fit_document(res: FitResult) -> dict:
    """The fit file's JSON content (docs/spec.md, docs/fitting.md) of a fit result."""
    corr = res.correlation
    u = res.uncertainty
    params = {}
    for name in REGISTRY:
        fitted = name in res.names
        err = None
        entry: dict[str, Any] = {}
        if fitted:
            k = res.names.index(name)
            e = res.stderr[k]
            err = float(e) if np.isfinite(e) else None
            spec = res.params.bounds.get(name, (REGISTRY[name].lower, REGISTRY[name].upper))
            entry["initial"] = float(res.params.initial_vector((name,))[0])
            entry["at_bound"] = (("lower" if np.isclose(res.params[name], spec[0],
                                                        rtol=0, atol=1e-12 * max(1, abs(spec[0])))
                                  else "upper") if name in res.at_bounds else None)
            if u is not None:
                entry["identified"] = bool(u.identified[k])
                if name in res.leans_on_prior:
                    # narrow, but mostly the prior's variance (docs/fitting.md)
                    entry["leans_on_prior"] = True
                entry["interval"] = {"level": 0.95, "lower": _num(u.lower95[k]),
                                     "upper": _num(u.upper95[k]), "method": u.method}
                entry["interval68"] = {"level": 0.68, "lower": _num(u.lower68[k]),
                                       "upper": _num(u.upper68[k])}
                entry["contraction"] = _num(u.contraction[k])
            if res.eq7 is not None:
                entry["stderr_eq7"] = _num(res.eq7.stderr[k])
        params[name] = {"value": float(res.params[name]), "stderr": err,
                        "unit": si_unit_strings((name,))[0], "fitted": fitted,
                        "display_unit": REGISTRY[name].unit,
                        "display_value": float(from_si(res.params[name], name)), **entry}
    best = res.starts.best_index
    d: dict[str, Any] = {
        "model": MODEL_NAME, "format_version": FORMAT_VERSION, "piezo": res.piezo,
        "version": gprm.__version__, "seed": res.options.seed,
        "window": [float(res.data.window[0]), float(res.data.window[1])],
        "signals": list(res.data.signals), "sigma": res.data.sigma_kind,
        "sigma_pool": int(res.data.sigma_pool),
        "z_bk_absolute": res.z_bk_absolute,
        "parameters": params,
        "chi2": float(res.chi2), "dof": int(res.dof),
        "reduced_chi2": float(res.reduced_chi2),
        "covariance_message": res.covariance_message,
        "uncertainty": _uncertainty_document(res),
        "identified": list(res.identified),
        "leans_on_prior": list(res.leans_on_prior),
        "not_determined": [n for n in res.names if n not in res.identified
                           and n not in res.leans_on_prior],
        "identifiable_combinations": res.combinations(),
        "parameters_at_bounds": list(res.at_bounds),
        "correlation": {"names": list(res.names),
                        "matrix": None if corr is None else corr.tolist()},
        "starts": {"requested": int(res.options.n_starts),
                   "converged": int(res.starts.converged.sum()),
                   "failed": int(np.sum(np.char.startswith(res.starts.status.astype(str),
                                                           "failed"))),
                   "pruned": int(np.sum(res.starts.status.astype(str) == "pruned")),
                   "raced": int(np.sum(res.starts.status.astype(str) == "raced")),
                   "best_index": int(best), "n_at_best": res.starts.n_at_best(),
                   "prune_after": res.options.prune_after,
                   "prune_factor": res.options.prune_factor,
                   "prune_rate_window": res.options.prune_rate_window,
                   "race": [list(p) for p in res.options.race],
                   "stall_window": res.options.lm.stall_window,
                   "stall_tol": res.options.lm.stall_tol,
                   "max_iter": res.options.lm.max_iter,
                   "chunk_size": res.options.chunk_size,
                   "spread": res.options.spread, "sampling": res.options.sampling},
        "profiles": [{"name": p.name, "grid": p.grid.tolist(),
                      "chi2": [_num(c) for c in p.chi2],
                      "lower": _num(p.lower), "upper": _num(p.upper),
                      "lower95": _num(p.lower95), "upper95": _num(p.upper95),
                      "statistic": "(Phi - Phi_min) / s2",
                      "identifiable": p.identifiable} for p in res.profiles],
        "data": {"source": res.data.source, "n_obs": res.data.n_obs,
                 "sha256": _data_hash(res.data)},
        "polish": res.polish,
        "band_samples": 0 if res.bands is None else int(res.bands.n_samples),
        "timings_s": res.timings,
    }
    if has_truth(res.data.attrs):
        d["data"]["truth_available"] = True
    return d


def _uncertainty_document(res: FitResult) -> dict:
    from gprm.fit.uncertainty import CONTRACTION, PRIOR_SHARE   # scipy: only when writing

    u = res.uncertainty
    if u is None:
        return {"method": "eq7", "note": res.covariance_message}
    notes = {"laplace-prior": "posterior of the prior-regularised fit (Laplace); identified "
                              f"= posterior sd below {CONTRACTION} of the prior's and less "
                              f"than {PRIOR_SHARE:g} of its variance the prior's",
             "sandwich": "the campaign's own error (runs' spread or residuals' covariance, "
                         "the larger) through the linearised fit, with the instrument's "
                         "gain and timing errors and the interpolation error marginalised; "
                         "centred on the best fit; identified = interval sd below "
                         f"{CONTRACTION} of the prior's and less than {PRIOR_SHARE:g} of its "
                         "variance the prior's (docs/fitting.md)",
             "generator-bootstrap": "Laplace posterior re-centred by refits of campaigns "
                                    "gprm's synthetic generator makes from the best fit, lags "
                                    "widened by the refits' spread, mismatch calibration "
                                    "measured on that generator applied: assumes the data's "
                                    "mismatch is the generator's (opt-in; docs/fitting.md)"}
    d = {"method": u.method, "note": u.message if u.message != "ok" else
         notes.get(u.method, "linearised covariance"),
         "s2": _num(u.s2), "tau": _num(u.tau), "identified_threshold": CONTRACTION,
         "prior_share_threshold": PRIOR_SHARE,
         "draws": 0 if u.draws is None else int(len(u.draws))}
    if res.prior is not None:
        d["prior"] = {"width": float(res.prior.sd[res.prior.log][0])
                      if res.prior.log.any() else None,
                      "centre": "initial values (Table 3)", "docs": "docs/fitting.md"}
    if u.calibration:
        d["calibration"] = {"factors": {n: f for n, f in u.calibration},
                            "note": "standard deviations multiplied by these factors, measured "
                                    "on synthetic campaigns (gprm.fit.calibration)"}
    if res.eq7 is not None:
        d["eq7_message"] = res.eq7.message
    if u.details:
        det = dict(u.details)
        src = det.pop("sources", None)
        if isinstance(src, dict):
            det["variance_shares"] = {n: {k: _num(v[i]) for k, v in src.items()}
                                      for i, n in enumerate(u.names)}
        d["details"] = det
    adq = res.adequacy
    if adq is not None:
        from gprm.fit.adequacy import verdict_text

        d["adequacy"] = adq.to_json()
        d["adequacy"]["text"] = verdict_text(adq, u.method, u.details)
    return d

def fit_sidecar(res: FitResult) -> xr.Dataset:
    """The fit file's NetCDF sidecar: every start, the data, the bands, the covariance and
    the uncertainty method's draws."""
    ds = starts_dataset(res.starts)
    ds = ds.assign_coords(signal=list(res.data.signals), time=res.data.time)
    ds["data_mean"] = (("signal", "time"), res.data.values)
    ds["data_sigma"] = (("signal", "time"), res.data.sigma)
    if res.bands is not None:
        b = res.bands
        ds["model_best"] = (("signal", "time"), b.best)
        ds["band_linear_std"] = (("signal", "time"), b.linear_std)
        ds["band_sample_std"] = (("signal", "time"), b.sample_std)
        ds["band_sample_lo"] = (("signal", "time"), b.sample_lo)
        ds["band_sample_hi"] = (("signal", "time"), b.sample_hi)
        ds.attrs["band_samples"] = b.n_samples
        found = getattr(res, "resonance", None)     # a FitRecord need not have one
        if found is not None and found.basis is not None:
            from gprm.fit.resonance import projected_part

            ds["resonance_fitted"] = (("signal", "time"), projected_part(
                found.basis, res.data.values, res.data.sigma, b.best))
    if res.covariance is not None:
        ds["covariance"] = (("param", "param2"), res.covariance)
        ds = ds.assign_coords(param2=list(res.names))
        ds["covariance"].attrs.update(
            long_name="parameter covariance of the uncertainty method (SI)",
            comment="units vary: param_units[param] * param_units[param2]")
    if res.uncertainty is not None and res.uncertainty.draws is not None:
        ds["posterior_draws"] = (("draw", "param"), res.uncertainty.draws, {
            "long_name": f"parameter sets from the uncertainty method "
            f"({res.uncertainty.method}), SI; later stages propagate these",
            "comment": "units vary along param: param_units[param]"})
    for v, long_name in _SIDECAR_LONG_NAMES.items():
        if v in ds.variables:
            ds[v].attrs.setdefault("long_name", long_name)
    for v in ("data_mean", "data_sigma", "model_best", "band_linear_std",
              "band_sample_std", "band_sample_lo", "band_sample_hi", "resonance_fitted"):
        if v in ds:
            ds[v].attrs["units"] = "m"
    ds["time"].attrs["units"] = "s"
    ds.attrs.update({"title": "GPRM model identification: every start, the data, bands and "
                     "uncertainty (gprm fit)", "model": MODEL_NAME,
                     "gprm_version": gprm.__version__, "seed": res.options.seed})
    return ds


_SIDECAR_LONG_NAMES = {
    "iterations": "Levenberg-Marquardt iterations of the start",
    "resampled": "times the start was redrawn before it could be simulated",
    "data_mean": "mean signal fitted (aligned)",
    "data_sigma": "standard deviation the residuals are weighted by (Eq. 6)",
    "model_best": "model signal at the best fit",
    "band_linear_std": "linear propagation of the covariance to the signal",
    "band_sample_std": "standard deviation of the signal over the method's draws",
    "band_sample_lo": "2.5 % quantile of the signal over the method's draws",
    "band_sample_hi": "97.5 % quantile of the signal over the method's draws",
    "resonance_fitted": "the unmodelled resonance the fit marginalised, at the best fit (its "
                        "and its nuisance columns' least-squares part of data - model_best)",
    "start": "index of the random start",
    "param": "fitted parameter",
    "param2": "fitted parameter (second index of the covariance)",
    "signal": "measured point and axis",
    "time": "aligned time (s from the start of the record)",
}

def write_fit(res: FitResult, out: str | os.PathLike) -> Path:
    """Write a fit result: the JSON ``out`` and its sidecar (same name, ``.nc``), together
    (:func:`gprm._io.atomic_paths`: a failure writing either leaves both as they were);
    returns the sidecar's path."""
    out = Path(out)
    side = out.with_suffix(".nc")
    doc = fit_document(res)
    with atomic_paths([side, out]) as (tmp_side, tmp_out):
        write_netcdf_to(fit_sidecar(res), tmp_side)     # the sidecar, then the JSON that
        doc["sidecar"] = {"name": side.name,             # binds it by its checksum
                          "sha256": file_sha256(tmp_side)}
        write_text_to(tmp_out, json_text(doc))
    return side


def starts_dataset(out: StartsOutcome) -> xr.Dataset:
    """The NetCDF sidecar content: every start's initial and final values, chi-square,
    iterations and outcome."""
    ds = xr.Dataset(
        {"x0": (("start", "param"), out.x0), "x": (("start", "param"), out.x),
         "chi2_0": ("start", out.chi2_0), "chi2": ("start", out.chi2),
         "iterations": ("start", out.iterations),
         "converged": ("start", out.converged.astype(np.int8)),
         "status": ("start", out.status.astype(str)),
         "resampled": ("start", out.resampled)},
        coords={"start": np.arange(out.chi2.size), "param": list(out.names)})
    units = si_unit_strings(out.names)
    # a data variable, not a coordinate: as a coordinate it lands in every variable's
    # `coordinates` attribute, which CF (2.7.1) reads as an auxiliary coordinate
    ds["param_units"] = ("param", units, {"long_name": "SI unit of each parameter"})
    for v, what in (("x0", "initial"), ("x", "final")):
        ds[v].attrs["long_name"] = f"{what} parameter values (SI)"
        # CF has one unit string per variable; these differ along param
        ds[v].attrs["comment"] = "units vary along param: see param_units"
    ds["chi2_0"].attrs.update(long_name="chi-square of the start (Eq. 6)", units="1")
    ds["chi2"].attrs.update(long_name="final chi-square (Eq. 6)", units="1")
    ds["status"].attrs["long_name"] = "outcome of the start"
    ds["converged"].attrs["long_name"] = "1 if the start met a convergence criterion"
    return ds


def _num(x):
    return float(x) if np.isfinite(x) else None


def _data_hash(data: FitData) -> str:
    h = hashlib.sha256()
    for a in (data.time, data.values, data.sigma):
        h.update(np.ascontiguousarray(a, float).tobytes())
    return h.hexdigest()[:16]
