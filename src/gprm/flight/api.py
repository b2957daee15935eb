"""Library entry points of the flight stage, with their validated options:

- :func:`run_impact` (``gprm impact``): release velocities, impact times, the joint estimates
  and Tukey's test of a telemetry file, as an :class:`~gprm.flight.analysis.ImpactResult`;
  :func:`write_impact` writes it (the JSON document and its curves' NetCDF sidecar);
- :func:`run_synth_telemetry` (``gprm synth telemetry``): synthetic releases with known impact
  times from a fitted model.

``gprm impact``, ``gprm synth telemetry``, ``gprm run`` and ``gprm demo`` call exactly these,
so the read -> compute -> write sequence and the checks of the options exist once.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace

import xarray as xr

from gprm.errors import GprmInputError
from gprm.fit.files import FittedModel, load_model
from gprm.flight import files
from gprm.flight.analysis import AnalysisOptions, ImpactResult, analyze
from gprm.flight.multi import multi_impact_report
from gprm.flight.synth import SynthOptions, synth_telemetry
from gprm.flight.files import load_telemetry
from gprm.flight.inference import InferenceOptions, scenario_document
from gprm.flight.telemetry import Telemetry
from gprm.model.piezo import check_piezo


@dataclass(frozen=True)
class ImpactOptions:
    """What defines ``gprm impact``: the analysis (:class:`AnalysisOptions`, validated
    there), the driven ``piezo`` (1, 2 or None for the fit's own) and ``multi`` (also
    integrate plunger and TM with contact detection at each estimated impact);
    ``scenarios``: the impact-scenario posterior (:mod:`gprm.flight.inference`), None: not
    computed; with ``analysis.impact_model == "auto"`` the impact times use the curves of the
    scenario chosen jointly over the releases (the corner model ``3d`` if none)."""

    analysis: AnalysisOptions = field(default_factory=AnalysisOptions)
    piezo: int | None = None
    multi: bool = False
    scenarios: InferenceOptions | None = field(default_factory=InferenceOptions)

    def __post_init__(self):
        if not isinstance(self.analysis, AnalysisOptions):
            raise GprmInputError(f"expected AnalysisOptions, got "
                                 f"{type(self.analysis).__name__}", field="analysis")
        if self.scenarios is not None and not isinstance(self.scenarios, InferenceOptions):
            raise GprmInputError(f"expected InferenceOptions or None, got "
                                 f"{type(self.scenarios).__name__}", field="scenarios")
        check_piezo(self.piezo, optional=True)
        if self.analysis.impact_model == "auto" and self.scenarios is None:
            raise GprmInputError("auto needs the scenario posterior (gprm impact: "
                                 "--scenario-draws above 0)", field="impact_model")
        if not isinstance(self.multi, bool):
            raise GprmInputError(f"must be true or false, got {self.multi!r}", field="multi")


@dataclass(frozen=True)
class TelemetryOptions:
    """What defines ``gprm synth telemetry``: the synthetic releases
    (:class:`~gprm.flight.synth.SynthOptions`, validated there) and the driven ``piezo``
    (1, 2 or None for the fit's own)."""

    synth: SynthOptions = field(default_factory=SynthOptions)
    piezo: int | None = None

    def __post_init__(self):
        if not isinstance(self.synth, SynthOptions):
            raise GprmInputError(f"expected SynthOptions, got {type(self.synth).__name__}",
                                 field="synth")
        check_piezo(self.piezo, optional=True)


def run_impact(model: FittedModel | str | os.PathLike, telemetry: Telemetry | str | os.PathLike,
               opts: ImpactOptions = ImpactOptions(), *,
               notes: tuple[str, ...] | list[str] = ()) -> ImpactResult:
    """The flight analysis of ``telemetry`` (a loaded :class:`Telemetry` or a telemetry
    NetCDF/CSV file) with ``model`` (see :func:`gprm.fit.files.load_model`). ``notes``: sentences the
    result carries for the report (``gprm run``: the fit had no usable covariance)."""
    if not isinstance(opts, ImpactOptions):
        raise GprmInputError(f"expected ImpactOptions, got {type(opts).__name__}",
                             field="opts")
    fm = load_model(model, piezo=opts.piezo)
    tel = telemetry if isinstance(telemetry, Telemetry) else load_telemetry(telemetry)
    sc = None
    if opts.scenarios is not None:
        sc = scenario_document(fm, tel, opts.scenarios, fit_window=opts.analysis.fit_window,
                               min_samples=opts.analysis.min_samples)
    analysis = opts.analysis
    if analysis.impact_model == "auto":     # the curves of the jointly chosen scenario
        chosen = (sc or {}).get("joint", {}).get("chosen") or "3d"
        analysis = replace(analysis, impact_model=chosen)
    res = analyze(fm, tel, analysis)
    if sc is not None:
        res = replace(res, scenarios=sc)
    if opts.multi:
        res = replace(res, multiple_impacts=multi_impact_report(fm, res.to_json()))
    return replace(res, notes=tuple(notes)) if notes else res


def write_impact(res: ImpactResult, out: str | os.PathLike) -> ImpactResult:
    """Write ``res`` to ``out`` (JSON) and its curves to the sidecar
    (:func:`gprm.flight.files.impact_sidecar`), each atomically; the result as written
    (naming its sidecar)."""
    side = files.impact_sidecar(out)
    res = replace(res, sidecar=side.name)
    if res.curves is None:
        raise GprmInputError("this impact result was read without its curves", field="curves")
    files.write_impact(res.to_json(), res.curves, out)
    return res


def run_synth_telemetry(model: FittedModel | str | os.PathLike,
                        opts: TelemetryOptions = TelemetryOptions()) -> xr.Dataset:
    """Synthetic in-flight releases with known impact times (the telemetry dataset; write it
    with :func:`gprm._io.write_netcdf_atomic` or read it with
    :func:`gprm.flight.telemetry.telemetry_from_dataset`)."""
    if not isinstance(opts, TelemetryOptions):
        raise GprmInputError(f"expected TelemetryOptions, got {type(opts).__name__}",
                             field="opts")
    return synth_telemetry(load_model(model, piezo=opts.piezo), opts.synth)
