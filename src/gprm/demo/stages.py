"""The stages of ``gprm demo``: thin adapters over each stage's library API.

Each adapter reads its inputs from the run directory, calls the stage's library function (never
the command line), writes its outputs atomically and returns a small dict of facts for the
summary. An adapter whose library is missing raises :class:`StageUnavailable`.
"""

from __future__ import annotations

import importlib
from pathlib import Path

import numpy as np

from gprm._io import open_netcdf, read_json, write_json_atomic, write_netcdf_atomic
from gprm.demo.pipeline import DemoOptions, Stage, StageUnavailable
from gprm.fit.files import with_covariance_fallbacks

PIEZO_GROUND = 2            # the ground campaign and the flight releases drive Piezo 2


def _need(module: str, *attrs: str):
    """Import ``module`` and return the named attributes, or raise StageUnavailable."""
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        raise StageUnavailable(f"{module} is not available ({exc.name} missing)") from None
    out = []
    for a in attrs:
        if not hasattr(mod, a):
            raise StageUnavailable(f"{module}.{a} is not available")
        out.append(getattr(mod, a))
    return out[0] if len(out) == 1 else tuple(out)


def load_model(run: Path) -> tuple:
    """The fitted model of ``fit.json`` and notes. A fit without a covariance (singular
    J'J: a direction the data do not determine) still gives its best-fit values: later stages
    then run on them with a zero covariance (no parameter uncertainty), and say so."""
    from gprm.errors import GprmInputError
    from gprm.fit.files import FittedModel, load_fit

    try:
        return load_fit(run / "fit.json"), []
    except GprmInputError as exc:
        if exc.field != "correlation":
            raise
    from gprm.params import ParameterSet, paper

    doc = read_json(run / "fit.json", what="fit result")
    values = dict(paper().values)
    values.update({k: float(v["value"]) for k, v in doc["parameters"].items()})
    names = tuple(k for k, v in doc["parameters"].items() if v.get("fitted"))
    ps = ParameterSet(values, source=str(run / "fit.json")).with_fitted(names)
    fm = FittedModel(ps, np.zeros((len(ps.fitted), len(ps.fitted))), piezo=int(doc["piezo"]),
                     source=str(run / "fit.json"),
                     z_bk_absolute=bool(doc.get("z_bk_absolute", False)))
    return fm, ["the fit has no covariance (" + str(doc.get("covariance_message", "")) +
                "): best-fit values without parameter uncertainty"]


# ----------------------------------------------------------------------------- campaign

def _campaign(run: Path, opts: DemoOptions, step) -> dict:
    synth_campaign = _need("gprm.campaign.synth", "synth_campaign")
    write_campaign = _need("gprm.campaign.data", "write_campaign")
    ds = synth_campaign(seed=opts.seed)
    write_campaign(ds, run / "campaign.nc")
    return {"runs": int(ds.sizes.get("run", 0)), "positions": int(ds.sizes.get("position", 0))}


def _preprocess(run: Path, opts: DemoOptions, step) -> dict:
    preprocess, PreprocessConfig = _need("gprm.campaign.preprocess", "preprocess",
                                         "PreprocessConfig")
    load_campaign = _need("gprm.campaign.data", "load_campaign")
    camp = load_campaign(run / "campaign.nc")
    means = preprocess(camp, PreprocessConfig(align_time=opts.align_time)).to_dataset()
    write_netcdf_atomic(means, run / "means.nc")
    return {"signals": int(means.sizes.get("signal", 0)), "samples": int(means.sizes["time"])}


# ----------------------------------------------------------------------------- fit

def _fit(run: Path, opts: DemoOptions, step) -> dict:
    fit_data_from_means = _need("gprm.fit.objective", "fit_data_from_means")
    LMOptions, MultiStartOptions = _need("gprm.fit.multistart", "LMOptions",
                                         "MultiStartOptions")
    identify = _need("gprm.fit.result", "identify")
    import shutil

    from gprm.params import paper

    means = open_netcdf(run / "means.nc", what="mean-signals file")
    data = fit_data_from_means(means, source=str(run / "means.nc"))
    ms = MultiStartOptions(n_starts=opts.starts, seed=opts.seed, lm=LMOptions())
    ckpt = run / "fit.json.ckpt"
    base = paper()
    if opts.fit_offsets:
        from gprm.params import ALIGNMENT_OFFSETS

        base = base.with_fitted(tuple(base.fitted) + tuple(ALIGNMENT_OFFSETS.values()))
    res = identify(data, base, ms, piezo=PIEZO_GROUND, workers=opts.workers,
                   checkpoint_dir=ckpt, progress=step, band_samples=opts.band_samples)
    res.write(run / "fit.json")
    shutil.rmtree(ckpt, ignore_errors=True)
    return {"chi2": float(res.chi2), "reduced_chi2": float(res.reduced_chi2),
            "dof": int(res.dof), "n_at_best": int(res.starts.n_at_best())}


# ----------------------------------------------------------------------------- predict

#: what-if scenarios of Sec. 4.2 and the files their trajectories go to
WHATIF_FILES = {"piezo1": "predict_piezo1.nc", "piezo1_ecc_div10": "predict_ecc10.nc"}


def _predict(run: Path, opts: DemoOptions, step) -> dict:
    predict, prediction_times = _need("gprm.predict.core", "predict", "prediction_times")
    prediction_dataset = _need("gprm.predict.files", "prediction_dataset")
    Scenario, standard_scenarios = _need("gprm.predict.scenarios", "Scenario",
                                         "standard_scenarios")
    whatif = _need("gprm.predict.whatif", "whatif")
    fm, notes = load_model(run)
    t = prediction_times(0.95e-3, 1.2e-3, 1e6)
    scen = {sc.name: sc for sc in standard_scenarios()}
    todo = [(Scenario("piezo2", PIEZO_GROUND), "predict.nc")] + [
        (scen[name], fname) for name, fname in WHATIF_FILES.items()]
    step(0, len(todo) + 1)
    for k, (sc, fname) in enumerate(todo):
        pred = with_covariance_fallbacks(
            lambda m, sc=sc: predict(m, scenario=sc, times=t, samples=opts.predict_samples,
                                     seed=opts.seed, means=run / "means.nc"),
            fm, notes, "the predictions' bands")
        write_netcdf_atomic(prediction_dataset(pred), run / fname)
        step(k + 1, len(todo) + 1)
    table = with_covariance_fallbacks(
        lambda m: whatif(m, samples=min(opts.predict_samples, 100), seed=opts.seed),
        fm, notes, "the what-if ranges")
    write_json_atomic(run / "whatif.json", table)
    step(len(todo) + 1, len(todo) + 1)
    info = {"whatif": {r["name"]: r.get("headline", {}) for r in table.get("ratios", [])[1:]}}
    if notes:
        info["notes"] = notes
    return info


# ----------------------------------------------------------------------------- flight

def _telemetry(run: Path, opts: DemoOptions, step) -> dict:
    SynthOptions, synth_telemetry = _need("gprm.flight.synth", "SynthOptions",
                                          "synth_telemetry")
    model, notes = load_model(run)
    info: dict = {"releases": opts.releases}
    ds = with_covariance_fallbacks(
        lambda m: synth_telemetry(m, SynthOptions(n_releases=opts.releases, seed=opts.seed)),
        model, notes, "the releases' true parameters")
    if notes:
        info["notes"] = notes
    write_netcdf_atomic(ds, run / "telemetry.nc")
    return info


def _impact(run: Path, opts: DemoOptions, step) -> dict:
    AnalysisOptions, analyze, curves_dataset = _need("gprm.flight.analysis", "AnalysisOptions",
                                                     "analyze", "curves_dataset")
    load_telemetry = _need("gprm.flight.telemetry", "load_telemetry")
    model, notes = load_model(run)
    tel = load_telemetry(run / "telemetry.nc")
    aopts = AnalysisOptions(n_samples=opts.predict_samples, seed=opts.seed)
    doc, curves = with_covariance_fallbacks(lambda m: analyze(m, tel, aopts), model, notes,
                                            "the velocity-curve bands")
    if notes:
        doc["notes"] = notes
    doc["curves"]["sidecar"] = "impact.nc"
    write_netcdf_atomic(curves_dataset(curves, doc), run / "impact.nc")
    write_json_atomic(run / "impact.json", doc)
    rej = [p for p in doc.get("tukey", {}).get("pairs", []) if p.get("reject")]
    info = {"tukey_rejected_pairs": len(rej)}
    if notes:
        info["notes"] = notes
    return info


# ----------------------------------------------------------------------------- the chain

STAGES: tuple[Stage, ...] = (
    Stage("campaign", "campaign (synthetic)", (), ("campaign.nc",),
          lambda o: {"seed": o.seed}, _campaign),
    Stage("preprocess", "preprocess", ("campaign.nc",),
          ("means.nc",), lambda o: {"align_time": o.align_time}, _preprocess),
    Stage("fit", "fit (multi-start LM)", ("means.nc",), ("fit.json", "fit.nc"),
          lambda o: {"starts": o.starts, "seed": o.seed, "band_samples": o.band_samples,
                     "fit_offsets": o.fit_offsets},
          _fit),
    Stage("predict", "predict + what-ifs", ("fit.json",),
          ("predict.nc", "predict_piezo1.nc", "predict_ecc10.nc", "whatif.json"),
          lambda o: {"samples": o.predict_samples, "seed": o.seed}, _predict),
    Stage("telemetry", "telemetry (synthetic)", ("fit.json",), ("telemetry.nc",),
          lambda o: {"releases": o.releases, "seed": o.seed}, _telemetry),
    Stage("impact", "impact + Tukey test", ("fit.json", "telemetry.nc"),
          ("impact.json", "impact.nc"), lambda o: {"samples": o.predict_samples,
                                                   "seed": o.seed}, _impact),
)


def stage_titles() -> dict[str, str]:
    return {s.name: s.title for s in STAGES} | {"report": "report"}

