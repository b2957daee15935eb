"""The stages of ``gprm run`` / ``gprm demo``: thin adapters over each stage's library entry
point (the same ones the commands call), with static imports.

Each adapter reads its inputs from the run directory, calls the library, writes its outputs
atomically and returns a small dict of facts for ``run.json`` and the report (``notes``:
sentences the report shows). The only difference between ``gprm demo`` and ``gprm run`` is
where ``campaign.nc`` (and ``telemetry.nc``) come from; every later stage is the same code.

The run directory (see ``docs/README.md``)::

    campaign.nc  means.nc  fit.json fit.nc  predict.nc  predict_piezo1.nc  predict_ecc10.nc
    whatif.json  telemetry.nc  impact.json impact.nc  run.json  report.html
"""

from __future__ import annotations

import functools
import hashlib
import os
import shutil
from dataclasses import asdict
from pathlib import Path
from typing import Any

from gprm._io import atomic_path
from gprm.campaign.api import run_preprocess
from gprm.campaign.files import load_campaign, write_campaign, write_means
from gprm.campaign.synth import synth_campaign
from gprm.errors import GprmInputError, GprmOutputError
from gprm.fit.api import run_fit
from gprm.fit.engine import remove_checkpoints
from gprm.fit.files import FittedModel, load_model
from gprm.flight.analysis import AnalysisOptions
from gprm.flight.api import (ImpactOptions, TelemetryOptions, run_impact, run_synth_telemetry,
                             write_impact)
from gprm.flight.inference import InferenceOptions
from gprm.flight.synth import SynthOptions
from gprm.flight.files import (load_telemetry, telemetry_csv_dataset, telemetry_from_dataset,
                               write_telemetry)
from gprm.predict.api import PredictOptions, run_predict, run_whatif
from gprm.predict.files import write_prediction, write_whatif
from gprm.predict.scenarios import standard_scenarios
from gprm.run.engine import Stage, sha256_file
from gprm.run.options import RunOptions

#: the note a stage records when the fit gives no parameter uncertainty
NO_UNCERTAINTY = "best fit only, no uncertainty"

#: prediction scenarios (Sec. 4.2) and the files their trajectories go to
PREDICT_FILES = {"piezo2": "predict.nc", "piezo1": "predict_piezo1.nc",
                 "piezo1_ecc_div10": "predict_ecc10.nc"}
PREDICT_SPAN = dict(t_start=0.95e-3, t_end=1.2e-3, rate=1e6)


def model_notes(fm: FittedModel) -> list[str]:
    """The notes a stage records on the model it ran on. A fit without a usable covariance
    (a direction the data do not determine) still gives its best-fit values: later stages
    run on them without parameter uncertainty, and the note says so."""
    if not fm.has_uncertainty:
        why = fm.covariance_message or "no covariance"
        return [f"{NO_UNCERTAINTY} (the fit has no covariance: {why})"]
    return []


def _with_notes(info: dict, notes: list[str]) -> dict:
    if notes:
        info["notes"] = list(notes)
    return info


# ----------------------------------------------------------------------------- campaign

def source_sha256(path: str | os.PathLike) -> str:
    """SHA-256 of a file, or of a folder's files (relative names and contents, sorted)."""
    p = Path(path)
    if not p.is_dir():
        return sha256_file(p)
    h = hashlib.sha256()
    for f in sorted(q for q in p.rglob("*") if q.is_file()):
        h.update(str(f.relative_to(p)).encode())
        h.update(sha256_file(f).encode())
    return h.hexdigest()


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _campaign_settings(o: RunOptions) -> dict:
    if o.campaign is None:
        return {"source": "synthetic", "seed": o.seed}
    return {"source": os.path.abspath(o.campaign), "sha256": source_sha256(o.campaign)}


def _campaign(run: Path, opts: RunOptions, step) -> dict:
    dest = run / "campaign.nc"
    if opts.campaign is None:
        ds = synth_campaign(seed=opts.seed)
        write_campaign(ds, dest)
        info = {"source": "synthetic", "seed": opts.seed}
    else:
        src = Path(opts.campaign)
        ds = load_campaign(src)                 # validates; NetCDF file or CSV folder
        info = {"source": str(src), "sha256": ds.attrs.get("campaign_sha256", "")}
        if _same_file(src, dest):
            pass
        elif not src.is_dir():                  # a valid NetCDF campaign: taken as it is
            with atomic_path(dest) as tmp:
                shutil.copyfile(src, tmp)
        else:                                   # a CSV folder: its dataset, saying whence
            ds = ds.copy()
            ds.attrs["imported_from"] = str(src)
            ds.attrs["imported_sha256"] = str(ds.attrs.pop("campaign_sha256", ""))
            ds.attrs.pop("source", None)
            write_campaign(ds, dest)
    return info | {"runs": int(ds.sizes.get("run", 0)),
                   "positions": int(ds.sizes.get("position", 0))}


# ----------------------------------------------------------------------------- preprocess, fit

def _preprocess(run: Path, opts: RunOptions, step) -> dict:
    means = run_preprocess(run / "campaign.nc", opts.preprocess)
    write_means(means, run / "means.nc")
    return {"signals": int(means.sizes.get("signal", 0)), "samples": int(means.sizes["time"])}


#: the fit stage's checkpoint folder in the run directory
FIT_CHECKPOINTS = "fit.json.ckpt"


def _fit(run: Path, opts: RunOptions, step, executor=None) -> dict:
    ckpt = run / FIT_CHECKPOINTS
    existed = ckpt.exists()
    try:
        res = run_fit(run / "means.nc", opts.fit, workers=opts.workers, checkpoint_dir=ckpt,
                      progress=step, executor=executor)
    except GprmOutputError:         # a write failed (no space): the chunks done stay
        remove_checkpoints(ckpt, only_if_empty=True)
        raise
    except GprmInputError:          # refused: no checkpoint folder of its own left behind
        remove_checkpoints(ckpt, only_if_empty=existed)
        raise
    res.write(run / "fit.json")
    remove_checkpoints(ckpt)        # only what gprm wrote there, never other files
    return {"chi2": float(res.chi2), "reduced_chi2": float(res.reduced_chi2),
            "dof": int(res.dof), "n_at_best": int(res.starts.n_at_best())}


# ----------------------------------------------------------------------------- predict

def _predict_options(run: Path, opts: RunOptions, sc=None) -> PredictOptions:
    kw: dict[str, Any] = dict(PREDICT_SPAN, samples=opts.predict_samples, seed=opts.seed,
                              means=str(run / "means.nc"))
    return PredictOptions(**kw) if sc is None else PredictOptions.for_scenario(sc, **kw)


def _predict(run: Path, opts: RunOptions, step) -> dict:
    fm = load_model(run)
    notes = model_notes(fm)
    scen = {sc.name: sc for sc in standard_scenarios()}
    todo = [(scen[name], fname) for name, fname in PREDICT_FILES.items()]
    step(0, len(todo) + 1)
    for k, (sc, fname) in enumerate(todo):
        pred = run_predict(fm, _predict_options(run, opts, sc))
        write_prediction(pred, run / fname)
        step(k + 1, len(todo) + 1)
    table = run_whatif(fm, _predict_options(run, opts))
    write_whatif(table, run / "whatif.json")
    step(len(todo) + 1, len(todo) + 1)
    info = {"whatif": {r["name"]: r.get("headline", {}) for r in table.ratios[1:]}}
    return _with_notes(info, notes)


# ----------------------------------------------------------------------------- flight

def _telemetry_settings(o: RunOptions) -> dict:
    if o.telemetry is None:
        return {"source": "synthetic", "releases": o.releases, "seed": o.seed}
    return {"source": os.path.abspath(o.telemetry), "sha256": source_sha256(o.telemetry)}


def _telemetry(run: Path, opts: RunOptions, step) -> dict:
    dest = run / "telemetry.nc"
    if opts.telemetry is not None:
        src = Path(opts.telemetry)
        if src.suffix.lower() in (".csv", ".txt"):   # parsed once, checked, then written
            ds = telemetry_csv_dataset(src)
            tel = telemetry_from_dataset(ds, source=str(src))
            write_telemetry(ds, dest)
        else:                                 # checked before it enters the run directory
            tel = load_telemetry(src)
            if not _same_file(src, dest):     # a NetCDF file: taken as it is
                with atomic_path(dest) as tmp:
                    shutil.copyfile(src, tmp)
        return {"source": str(src), "releases": len(tel.releases)}
    fm = load_model(run)
    notes = model_notes(fm)
    ds = run_synth_telemetry(fm, TelemetryOptions(SynthOptions(n_releases=opts.releases,
                                                               seed=opts.seed)))
    write_telemetry(ds, dest)
    return _with_notes({"source": "synthetic", "releases": opts.releases}, notes)


def scenario_draws(o: RunOptions) -> int:
    """Prior draws per scenario of the impact-scenario posterior: 2000 with ``quick``, else
    20000 (``gprm impact``'s default, the measured recovery's, docs/flight.md §11)."""
    return 2000 if o.quick else 20000


def _impact(run: Path, opts: RunOptions, step) -> dict:
    fm = load_model(run)
    notes = model_notes(fm)
    iopts = ImpactOptions(AnalysisOptions(n_samples=opts.predict_samples, seed=opts.seed,
                                          impact_model="auto"),
                          scenarios=InferenceOptions(n_draws=scenario_draws(opts),
                                                     seed=opts.seed))
    res = write_impact(run_impact(fm, run / "telemetry.nc", iopts, notes=notes),
                       run / "impact.json")
    rej = [p for p in res.tukey.get("pairs", []) if p.get("reject")]
    return _with_notes({"tukey_rejected_pairs": len(rej)}, notes)


# ----------------------------------------------------------------------------- the chain

def chain(opts: RunOptions, executor=None) -> tuple[Stage, ...]:
    """The stages for ``opts``: where the campaign and the telemetry come from decides the
    first stage's settings and what the telemetry stage needs; the rest is fixed.
    ``executor``: the fit's local worker processes, made by the caller
    (:func:`gprm.fit.engine.worker_pool`; None: the fit makes its own)."""
    tel_inputs = () if opts.telemetry is not None else ("fit.json",)
    return (
        Stage("campaign", "campaign (synthetic)" if opts.campaign is None else
              "campaign (import)", (), ("campaign.nc",), _campaign_settings, _campaign),
        Stage("preprocess", "preprocess", ("campaign.nc",), ("means.nc",),
              lambda o: asdict(o.preprocess), _preprocess),
        Stage("fit", "fit (multi-start LM)", ("means.nc",), ("fit.json", "fit.nc"),
              lambda o: asdict(o.fit), functools.partial(_fit, executor=executor)),
        Stage("predict", "predict + what-ifs", ("fit.json", "means.nc"),
              tuple(PREDICT_FILES.values()) + ("whatif.json",),
              lambda o: {"samples": o.predict_samples, "seed": o.seed} | PREDICT_SPAN,
              _predict),
        Stage("telemetry", "telemetry (synthetic)" if opts.telemetry is None else
              "telemetry (import)", tel_inputs, ("telemetry.nc",), _telemetry_settings,
              _telemetry),
        Stage("impact", "impact + Tukey test", ("fit.json", "telemetry.nc"),
              ("impact.json", "impact.nc"),
              lambda o: {"samples": o.predict_samples, "seed": o.seed,
                         "scenario_draws": scenario_draws(o), "impact_model": "auto"},
              _impact),
    )


def stage_titles(opts: RunOptions | None = None) -> dict[str, str]:
    return {s.name: s.title for s in chain(opts or RunOptions())} | {"report": "report"}
