"""design.json: the ranking, what each candidate buys, its cost, the recommended campaign
(docs/design.md, "design.json"). Units at the edge: parameter values and intervals in the
registry's display units, hours, micrometres and millimetres per second for predictions."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

import gprm
from gprm._io import read_json, write_json_atomic
from gprm.design.config import Block
from gprm.design.core import DesignEvaluation, DesignResult
from gprm.errors import GprmInputError
from gprm.fit.uncertainty import determined
from gprm.params import REGISTRY, from_si

FORMAT = "gprm-design"


def _block_json(b: Block) -> dict:
    return {"channels": [c.name if c.is_model_output else
                         {"name": c.name, "body": c.body, "axis": c.axis,
                          **({"point": c.point} if c.point else
                             {"at_mm": [v * 1e3 for v in (c.at or ())]})}
                         for c in b.channels],
            "drive": [f"piezo{d}" for d in b.drives], "voltage": b.voltage,
            "retraction": b.retraction, "runs": b.runs, "noise_runs": b.noise_runs,
            "record_ms": b.record * 1e3, "rate_kHz": b.rate / 1e3,
            "window_ms": [b.window[0] * 1e3, b.window[1] * 1e3]}


def _params_json(res: DesignResult, ev: DesignEvaluation, ref: DesignEvaluation | None) -> dict:
    out = {}
    share = ev.prior_share
    leans = None if share is None else \
        determined(ev.sd_u / res.prior_sd, share, res.config.identified_threshold)[1]
    for i, n in enumerate(res.names):
        unit = REGISTRY[n].unit
        lo, hi = from_si(float(ev.lower[i]), n), from_si(float(ev.upper[i]), n)
        e = {"sd_u": float(ev.sd_u[i]), "contraction": float(ev.sd_u[i] / res.prior_sd[i]),
             "identified": bool(ev.identified[i]), "interval95": [lo, hi],
             "width95": hi - lo, "unit": unit}
        if share is not None and leans is not None:
            # narrow but mostly the prior's: the fit's "leans on the prior"
            e["prior_share"] = float(share[i])
            e["leans_on_prior"] = bool(leans[i])
        if ref is not None:
            rlo, rhi = from_si(float(ref.lower[i]), n), from_si(float(ref.upper[i]), n)
            e["width95_before"] = rhi - rlo
        out[n] = e
    return out


def _evaluation_json(res: DesignResult, ev: DesignEvaluation, ref: DesignEvaluation | None,
                     *, detail: bool = True) -> dict:
    names = np.array(res.names)
    d = {"additions": list(ev.additions), "hours": ev.hours, "runs": ev.runs,
         "identified": names[ev.identified].tolist(), "gain": ev.gain}
    if ref is not None:
        d["newly_identified"] = names[ev.identified & ~ref.identified].tolist()
        d["width_ratio"] = {n: float(ev.sd_u[i] / ref.sd_u[i]) for i, n in enumerate(names)}
    if detail:
        d["parameters"] = _params_json(res, ev, ref)
    return d


def design_document(res: DesignResult) -> dict:
    cands = {c.name: c for c in res.config.candidates}
    cm = res.config.cost
    groups = np.array(res.predictions.group)
    units = {"overshoot": ("um", 1e6), "velocity": ("um/s", 1e6)}
    preds = []
    for k in range(len(res.predictions.value)):
        u, f = units[groups[k]]
        preds.append({"label": res.predictions.label[k], "group": groups[k], "unit": u,
                      "value": float(res.predictions.value[k] * f),
                      "sd_base": float(res.base.pred_sd[k] * f),
                      "sd_recommended": float(res.recommended.pred_sd[k] * f)})
    synth = {k: v for k, v in res.synth.items() if k not in ("block", "predicted")}
    synth["window_ms"] = [v * 1e3 for v in synth.pop("window")]
    synth["t_end_ms"] = synth.pop("t_end") * 1e3
    if "predicted" in res.synth:
        p = res.synth["predicted"]
        synth["predicted"] = {n: {"sd_u": float(p["sd_u"][i]),
                                  "identified": bool(p["identified"][i]),
                                  "interval95": [from_si(float(p["lower"][i]), n),
                                                 from_si(float(p["upper"][i]), n)]}
                              for i, n in enumerate(res.names)}
    return {
        "format": FORMAT, "version": gprm.__version__, "source": res.source,
        "method": ("expected posterior in u (prior + Fisher information of each block, "
                   "nuisances marginalised) averaged over the fit's posterior draws; "
                   "docs/design.md"),
        "noise": {"white_m": res.noise.white, "variability": res.noise.variability,
                  "mismatch": res.noise.mismatch,
                  "kappa": res.noise.kappa if len(res.parts) == 1 else None,
                  "base_runs": res.noise.base_runs, "gain_sd": dict(res.noise.gain),
                  "alignment_sd_s": dict(res.noise.align),
                  "sync_timing_sd_s": dict(res.noise.sync)},
        "carry_over": [{"component": p.component, "kappa": float(p.kappa),
                        "scale": {n: float(v) for n, v in zip(res.names, p.scale)},
                        # the runs' part: the run-to-run variation's sd in u at the base's
                        # runs (docs/design.md), which only more runs average down
                        **({"run_to_run_sd_u": {n: float(v) for n, v in zip(
                            res.names, np.sqrt(np.clip(np.diag(p.per_run), 0.0, None)))},
                            "base_runs": p.runs} if p.per_run is not None else {}),
                        # the share of it the runs' amplitude and timing errors explain,
                        # which follows a candidate's window and channels
                        **({"run_to_run_explained": {n: float(v) for n, v in zip(
                            res.names, p.explained)}}
                           if p.explained is not None else {})}
                       for p in res.parts],
        "draws": res.config.n_draws, "seed": res.config.seed,
        "identified_threshold": res.config.identified_threshold,
        "cost_model": {"hours_per_run": cm.hours_per_run,
                       "hours_per_noise_run": cm.hours_per_noise_run,
                       "hours_per_new_position": cm.hours_per_new_position,
                       "hours_per_new_drive": cm.hours_per_new_drive,
                       "budget_hours": cm.budget, "max_additions": cm.max_additions},
        "base": {"block": _block_json(res.base_block),
                 **_evaluation_json(res, res.base, None),
                 "fit_sd_u": (None if res.fit_sd_u is None else
                              {n: float(v) for n, v in zip(res.names, res.fit_sd_u)})},
        "candidates": [{"name": e.additions[0], "note": cands[e.additions[0]].note,
                        "rank": res.ranking.index(e.additions[0]) + 1,
                        "block": _block_json(cands[e.additions[0]].block),
                        **_evaluation_json(res, e, res.base)}
                       for e in res.candidates],
        "ranking": list(res.ranking),
        "recommended": {"selection": res.selection,
                        **_evaluation_json(res, res.recommended, res.base)},
        "synth_campaign": synth,
        "y_springs": {k: v for k, v in res.y_springs.items()},
        "predictions": preds,
        "timings_s": res.timings,
    }


def write_design(res: DesignResult, out: str | os.PathLike) -> Path:
    write_json_atomic(out, design_document(res))
    return Path(out)


def read_design(path: str | os.PathLike) -> dict:
    """A design.json, checked for its format and the tables the report reads."""
    doc = read_json(path, what="design file")
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise GprmInputError(f"is not a {FORMAT} file", source=str(path), field="format")
    for key in ("candidates", "ranking", "recommended", "base"):
        if key not in doc:
            raise GprmInputError("missing", source=str(path), field=key)
    return doc
