"""Flight analysis pipeline (``gprm impact``): release velocities -> predicted curves ->
impact times -> Tukey test, as an :class:`ImpactResult` (its ``to_json()`` is the JSON of
docs/spec.md, its ``to_xarray()`` the NetCDF sidecar of the curves).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
import xarray as xr

from gprm.errors import GprmInputError
from gprm.flight.files import IMPACT_FORMAT, impact_curves_dataset
from gprm.flight.impact_time import ImpactTimeMC, impact_time_mc
from gprm.flight.joint import joint_impact_time
from gprm.flight.predicted import (IMPACT_MODELS, VelocityCurves,
                                   scenario_geometry, velocity_curves)
from gprm.flight.telemetry import AXES, AXIS_CHANNEL, AXIS_UNIT, release_velocities
from gprm.flight.tukey import tukey_range_test
from gprm.validate import check_int


def _real(v) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)


@dataclass(frozen=True)
class AnalysisOptions:
    """What defines a flight analysis (SI). Validated on construction (the one place these
    are checked); a bad value raises :class:`GprmInputError` naming the option.

    alpha: level of Tukey's test and of the joint chi-square check (0 < alpha < 1).
    n_samples: joint parameter and geometry draws of the velocity-curve bands (>= 2).
    n_times: grid times of the curves (>= 2). seed: seed of the draws.
    window: impact-time window (start, end) in s, 0 <= start < end; None: t_c .. t_c + 0.2 ms.
    fit_window: the release-velocity line fit over this long after the release (s, > 0);
        None: all. min_samples: fewest telemetry samples for a release velocity (>= 2).
    impact_model: ``"3d"`` (one corner contact), ``"planar"`` (the paper's two planes), a
        rim-contact scenario ``"xz"``, ``"yz"``, ``"two"`` (docs/flight.md §10), or ``"auto"``
        (``run_impact``: the scenario the posterior chooses jointly over the releases).
    """

    alpha: float = 0.01
    n_samples: int = 200
    n_times: int = 401
    seed: int = 0
    window: tuple | None = None
    fit_window: float | None = None
    min_samples: int = 5
    impact_model: str = "3d"

    def __post_init__(self):
        if not _real(self.alpha) or not 0 < self.alpha < 1:
            raise GprmInputError(f"must be a number between 0 and 1 (exclusive), got "
                                 f"{self.alpha!r}", field="alpha")
        check_int("n_samples", self.n_samples, 2)
        check_int("n_times", self.n_times, 2)
        check_int("seed", self.seed, 0)
        check_int("min_samples", self.min_samples, 2)
        if self.window is not None:
            w = tuple(self.window)
            if len(w) != 2 or not all(_real(x) for x in w) or not 0 <= w[0] < w[1]:
                raise GprmInputError(f"expected 0 <= START < END (s), got {self.window!r}",
                                     field="window")
            object.__setattr__(self, "window", (float(w[0]), float(w[1])))
        if self.fit_window is not None and (not _real(self.fit_window)
                                            or self.fit_window <= 0):
            raise GprmInputError(f"must be a time > 0 (s), got {self.fit_window!r}",
                                 field="fit_window")
        if self.impact_model not in IMPACT_MODELS + ("auto",):
            raise GprmInputError(f"must be one of {', '.join(IMPACT_MODELS + ('auto',))}, "
                                 f"got {self.impact_model!r}", field="impact_model")

    def to_json(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class ImpactResult:
    """The flight analysis of one telemetry file (``gprm impact``, ``impact.json``).

    Per release (``releases``, JSON-able records): the release velocities, the impact time
    of each of the six axes, their joint estimate and, for synthetic telemetry, the truth;
    ``missing``: the (release, axis) pairs without an impact time and why; ``tukey``: Tukey's
    range test over the axes; ``joint``: the joint estimates' chi-square check; ``curves``:
    the predicted velocity-vs-impact-time curves used (:class:`VelocityCurves`);
    ``multiple_impacts``: the second-impact report (``--multi``), ``notes``: sentences the
    report shows, ``sidecar``: the curves' NetCDF file name once written, ``scenarios``: the
    paper's observations and the impact-scenario posterior
    (:func:`gprm.flight.inference.scenario_document`).

    ``to_json()`` is the impact document (docs/data-formats.md), ``to_xarray()`` the curves'
    sidecar dataset; :meth:`from_json` reads a document back.
    """

    model_source: str
    telemetry: str
    piezo: int
    impact_model: str
    model_uncertainty: str
    window: tuple[float, float]
    releases: tuple[dict, ...]
    missing: tuple[dict, ...]
    tukey: dict
    joint: dict
    curves: VelocityCurves | None
    n_samples: int
    seed: int
    options: Mapping[str, Any]
    truth_impact_time: tuple[float, ...] | None = None
    multiple_impacts: dict | None = None
    notes: tuple[str, ...] = ()
    sidecar: str | None = None
    scenarios: dict | None = None

    FORMAT = IMPACT_FORMAT
    FORMAT_VERSION = 1
    TIME_BASE = "s from the start of the retraction record (retraction command at t_c)"

    def to_json(self) -> dict:
        """The impact document (JSON-able; a deep copy)."""
        doc = {
            "format": self.FORMAT, "format_version": self.FORMAT_VERSION,
            "model_source": self.model_source, "telemetry": self.telemetry,
            "piezo": self.piezo, "impact_model": self.impact_model,
            "model_uncertainty": self.model_uncertainty, "time_base": self.TIME_BASE,
            "window": [float(self.window[0]), float(self.window[1])],
            "releases": [copy.deepcopy(r) for r in self.releases],
            "missing": [dict(m) for m in self.missing],
            "tukey": copy.deepcopy(self.tukey),
            "joint": copy.deepcopy(self.joint),
            "curves": {"sidecar": self.sidecar, "n_samples": self.n_samples,
                       "seed": self.seed},
            "options": dict(self.options),
        }
        if self.truth_impact_time is not None:
            doc["truth"] = {"impact_time": [float(x) for x in self.truth_impact_time],
                            "summary": truth_summary(doc)}
        if self.multiple_impacts is not None:
            doc["multiple_impacts"] = copy.deepcopy(self.multiple_impacts)
        if self.notes:
            doc["notes"] = list(self.notes)
        if self.scenarios is not None:
            doc["scenarios"] = copy.deepcopy(self.scenarios)
        return doc

    def to_xarray(self) -> xr.Dataset:
        """The velocity-vs-impact-time curves (the ``.nc`` sidecar of ``impact.json``)."""
        if self.curves is None:
            raise GprmInputError("this impact result was read without its curves",
                                 field="curves")
        return impact_curves_dataset(self.curves)

    @classmethod
    def from_json(cls, doc: Mapping, curves: VelocityCurves | None = None) -> "ImpactResult":
        """The result of an impact document (``to_json()``'s inverse; the curves are in the
        sidecar and may be given)."""
        if not isinstance(doc, Mapping) or doc.get("format") != cls.FORMAT:
            raise GprmInputError(f"not a {cls.FORMAT} document", field="format")
        try:
            c = doc["curves"]
            truth = doc.get("truth")
            return cls(model_source=doc["model_source"], telemetry=doc["telemetry"],
                       piezo=doc["piezo"], impact_model=doc["impact_model"],
                       model_uncertainty=doc["model_uncertainty"],
                       window=tuple(doc["window"]),
                       releases=tuple(copy.deepcopy(doc["releases"])),
                       missing=tuple(dict(m) for m in doc["missing"]),
                       tukey=copy.deepcopy(doc["tukey"]), joint=copy.deepcopy(doc["joint"]),
                       curves=curves, n_samples=c["n_samples"], seed=c["seed"],
                       options=dict(doc["options"]),
                       truth_impact_time=(None if truth is None
                                          else tuple(truth["impact_time"])),
                       multiple_impacts=copy.deepcopy(doc.get("multiple_impacts")),
                       notes=tuple(doc.get("notes", ())), sidecar=c.get("sidecar"),
                       scenarios=copy.deepcopy(doc.get("scenarios")))
        except KeyError as exc:
            raise GprmInputError("missing in the impact document",
                                 field=str(exc.args[0])) from None


def _duplicate_axes(curves) -> set:
    """Axes that repeat an earlier axis: same telemetry channel and the same curves (both v_z
    axes of the one-contact 3D model). They keep their impact time (k = 6 for Tukey) but enter
    the joint estimate once."""

    dup = set()
    for i, a in enumerate(AXES):
        for b in AXES[:i]:
            if (AXIS_CHANNEL[a] == AXIS_CHANNEL[b]
                    and np.array_equal(curves.nominal[a], curves.nominal[b], equal_nan=True)
                    and (curves.samples is None
                         or np.array_equal(curves.samples[a], curves.samples[b],
                                           equal_nan=True))):
                dup.add(a)
    return dup


def _error_sigma(est: ImpactTimeMC, truth: float) -> float | None:
    """(estimate - truth) / stderr; None without an estimate or a nonzero stderr."""
    if est.value is None or not est.stderr:
        return None
    return (est.value - truth) / est.stderr


def analyze(model, tel, opts: AnalysisOptions = AnalysisOptions(),
            curves: VelocityCurves | None = None) -> ImpactResult:
    """Run the flight analysis of telemetry ``tel`` (a loaded
    :class:`~gprm.flight.telemetry.Telemetry`) with a fitted model; ``curves``: velocity
    curves already computed for this model (else computed here). See :class:`ImpactResult`.
    """
    if not isinstance(opts, AnalysisOptions):
        raise GprmInputError(f"expected AnalysisOptions, got {type(opts).__name__}",
                             field="opts")
    if opts.impact_model == "auto" and curves is None:
        raise GprmInputError("auto is resolved by run_impact (the scenario posterior "
                             "chooses the model); analyze needs a model", field="impact_model")
    vel = release_velocities(tel, fit_window=opts.fit_window, min_samples=opts.min_samples)
    if curves is None:
        curves = velocity_curves(model, window=opts.window, n_times=opts.n_times,
                                 n_samples=opts.n_samples, seed=opts.seed,
                                 geometry=scenario_geometry(opts.impact_model))
    if curves.samples is None:
        raise GprmInputError("curves without their joint draws", field="curves")
    has_unc = bool(getattr(model, "has_uncertainty", True))
    dup = _duplicate_axes(curves)
    truth_t = tel.truth_impact_time
    releases = []
    groups: dict[str, list[float]] = {a: [] for a in AXES}
    missing = []
    for ir, r in enumerate(tel.releases):
        v = vel[r.id]
        it = {}
        for ia, a in enumerate(AXES):
            res = impact_time_mc(curves.time, curves.nominal[a], curves.sigma[a],
                                 curves.samples[a], v[a].value, v[a].stderr,
                                 seed=opts.seed + 7919 * (ir + 1) + ia)
            it[a] = res
            if res.value is not None and res.stderr is not None:
                groups[a].append(res.value)
            else:
                missing.append({"release": r.id, "axis": a, "reason": res.reason})
        use = [a for a in AXES if a not in dup]
        jt = joint_impact_time({a: it[a].value for a in use}, {a: it[a].stderr for a in use},
                               {a: it[a].draws for a in use},
                               {a: it[a].draw_slopes for a in use})
        rec = {
            "id": r.id, "release_time": r.release_time,
            "velocity": {a: {"value": v[a].value, "stderr": v[a].stderr, "unit": AXIS_UNIT[a],
                             "n": v[a].n, "reduced_chi2": v[a].reduced_chi2,
                             "weighted": v[a].weighted} for a in AXES},
            "impact_time": {a: it[a].to_json() for a in AXES},
            "joint": jt.to_json()}
        if truth_t is not None:
            tt = float(truth_t[ir])
            rec["truth_impact_time"] = tt
            rec["error_sigma"] = {a: _error_sigma(it[a], tt) for a in AXES}
            rec["joint"]["truth_in_ci95"] = (None if jt.ci95 is None
                                             else bool(jt.ci95[0] <= tt <= jt.ci95[1]))
        releases.append(rec)
    tk = None
    tukey_note = None
    try:
        tk = tukey_range_test(groups, alpha=opts.alpha)
    except GprmInputError as exc:  # too few crossings: report, do not fail
        tukey_note = f"Tukey test not possible: {exc.problem}"
    tukey = (tk.to_json() if tk is not None
             else {"alpha": opts.alpha, "k": None, "df": None, "q_critical": None,
                   "pairs": [], "note": tukey_note})
    if tk is not None:
        tukey["all_compatible"] = not any(p.reject for p in tk.pairs)
    return ImpactResult(
        model_source=str(model.source), telemetry=tel.source, piezo=model.piezo,
        impact_model=curves.meta.get("impact_model", opts.impact_model),
        model_uncertainty=("fit covariance and impact geometry" if has_unc else
                           "best fit only (the fit has no usable covariance): the bands "
                           "and error bars carry the impact geometry's uncertainty only"),
        window=(float(curves.time[0]), float(curves.time[-1])),
        releases=tuple(releases), missing=tuple(missing), tukey=tukey,
        joint=_joint_summary(releases, opts.alpha), curves=curves,
        n_samples=curves.n_samples, seed=curves.seed, options=opts.to_json(),
        truth_impact_time=(None if truth_t is None else tuple(float(x) for x in truth_t)))


def _joint_summary(releases, alpha) -> dict:
    """The joint estimates' χ² consistency check over the releases at level ``alpha``."""
    ps = [r["joint"]["p"] for r in releases if r["joint"].get("p") is not None]
    return {"alpha": alpha, "n": len(ps),
            "rejected": [r["id"] for r in releases
                         if r["joint"].get("p") is not None and r["joint"]["p"] < alpha],
            "all_consistent": all(p >= alpha for p in ps) if ps else None}


def truth_summary(doc) -> dict:
    """Found / within-2σ / joint-coverage counts of an impact document with truth."""
    n_tot = n_found = n_2s = n_j = n_jin = 0
    for r in doc["releases"]:
        if "truth_impact_time" not in r:
            continue
        for a in AXES:
            n_tot += 1
            z = r["error_sigma"][a]
            if z is not None:
                n_found += 1
                n_2s += abs(z) <= 2.0
        if r["joint"].get("truth_in_ci95") is not None:
            n_j += 1
            n_jin += r["joint"]["truth_in_ci95"]
    return {"impact_times": n_tot, "found": n_found, "within_2sigma": int(n_2s),
            "joint_releases": n_j, "joint_truth_in_ci95": int(n_jin)}
