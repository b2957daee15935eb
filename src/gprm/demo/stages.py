"""The stages of ``gprm demo``: thin adapters over each stage's library API.

Each adapter reads its inputs from the run directory, calls the stage's library function (never
the command line), writes its outputs atomically and returns a small dict of facts for the
summary. An adapter whose library is missing raises :class:`StageUnavailable`.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from gprm._io import open_netcdf, write_json_atomic, write_netcdf_atomic
from gprm.demo.pipeline import DemoOptions, Stage, StageUnavailable

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


# ----------------------------------------------------------------------------- campaign

def _campaign(run: Path, opts: DemoOptions, step) -> dict:
    synth_campaign = _need("gprm.campaign.synth", "synth_campaign")
    ds = synth_campaign(seed=opts.seed)
    write_netcdf_atomic(ds, run / "campaign.nc")
    return {"runs": int(ds.sizes.get("run", 0)), "positions": int(ds.sizes.get("position", 0))}


def _preprocess(run: Path, opts: DemoOptions, step) -> dict:
    preprocess = _need("gprm.campaign.preprocess", "preprocess")
    camp = open_netcdf(run / "campaign.nc", what="campaign file")
    means = preprocess(camp, source=str(run / "campaign.nc"))
    write_netcdf_atomic(means, run / "means.nc")
    return {"signals": int(means.sizes.get("signal", 0)), "samples": int(means.sizes["time"])}


# ----------------------------------------------------------------------------- fit

def _fit(run: Path, opts: DemoOptions, step) -> dict:
    fit_data_from_means = _need("gprm.fit.objective", "fit_data_from_means")
    LMOptions, MultiStartOptions = _need("gprm.fit.multistart", "LMOptions",
                                         "MultiStartOptions")
    identify = _need("gprm.fit.result", "identify")
    from gprm.params import paper

    means = open_netcdf(run / "means.nc", what="mean-signals file")
    data = fit_data_from_means(means, source=str(run / "means.nc"))
    ms = MultiStartOptions(n_starts=opts.starts, seed=opts.seed, lm=LMOptions())
    ckpt = run / "fit.json.ckpt"
    res = identify(data, paper(), ms, piezo=PIEZO_GROUND, workers=opts.workers,
                   checkpoint_dir=ckpt, progress=step, band_samples=opts.band_samples)
    res.write(run / "fit.json")
    import shutil

    shutil.rmtree(ckpt, ignore_errors=True)
    return {"chi2": float(res.chi2), "reduced_chi2": float(res.reduced_chi2),
            "dof": int(res.dof), "n_at_best": int(res.starts.n_at_best())}


# ----------------------------------------------------------------------------- predict

def _predict(run: Path, opts: DemoOptions, step) -> dict:
    predict, whatifs = _need("gprm.predict", "predict", "whatifs")
    from gprm.fit.files import load_fit

    model = load_fit(run / "fit.json")
    base = predict(model, piezo=PIEZO_GROUND)
    write_netcdf_atomic(base, run / "predict.nc")
    table, extra = whatifs(model, piezo_base=PIEZO_GROUND,
                           eccentricity_scale=opts.eccentricity_scale)
    for name, ds in extra.items():
        write_netcdf_atomic(ds, run / f"predict_{name}.nc")
    write_json_atomic(run / "whatif.json", table)
    return {"whatif": table.get("ratios", {})}


# ----------------------------------------------------------------------------- flight

def _telemetry(run: Path, opts: DemoOptions, step) -> dict:
    synth_telemetry = _need("gprm.flight.synth", "synth_telemetry")
    from gprm.fit.files import load_fit

    model = load_fit(run / "fit.json")
    ds = synth_telemetry(model, releases=opts.releases, seed=opts.seed)
    write_netcdf_atomic(ds, run / "telemetry.nc")
    return {"releases": opts.releases}


def _impact(run: Path, opts: DemoOptions, step) -> dict:
    analyse = _need("gprm.flight.impact", "analyse_releases")
    from gprm.fit.files import load_fit

    model = load_fit(run / "fit.json")
    tele = open_netcdf(run / "telemetry.nc", what="telemetry file")
    doc = analyse(model, tele, seed=opts.seed)
    write_json_atomic(run / "impact.json", doc)
    rej = [p for p in doc.get("tukey", {}).get("pairs", []) if p.get("reject")]
    return {"tukey_rejected_pairs": len(rej)}


# ----------------------------------------------------------------------------- the chain

STAGES: tuple[Stage, ...] = (
    Stage("campaign", "synthetic campaign", (), ("campaign.nc",),
          lambda o: {"seed": o.seed}, _campaign),
    Stage("preprocess", "preprocess (synchronise, average, align)", ("campaign.nc",),
          ("means.nc",), lambda o: {}, _preprocess),
    Stage("fit", "fit (multi-start LM)", ("means.nc",), ("fit.json", "fit.nc"),
          lambda o: {"starts": o.starts, "seed": o.seed, "band_samples": o.band_samples},
          _fit),
    Stage("predict", "predict + what-ifs", ("fit.json",),
          ("predict.nc", "predict_piezo1.nc", "predict_ecc10.nc", "whatif.json"),
          lambda o: {"eccentricity_scale": o.eccentricity_scale}, _predict),
    Stage("telemetry", "synthetic telemetry", ("fit.json",), ("telemetry.nc",),
          lambda o: {"releases": o.releases, "seed": o.seed}, _telemetry),
    Stage("impact", "impact analysis + Tukey", ("fit.json", "telemetry.nc"), ("impact.json",),
          lambda o: {"seed": o.seed}, _impact),
)


def stage_titles() -> dict[str, str]:
    return {s.name: s.title for s in STAGES} | {"report": "report"}

