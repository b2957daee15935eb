"""The facts of a run directory in one dict: best chi-square, truth recovery, what-if ratios,
Tukey verdict. Used for the closing table of ``gprm run`` / ``gprm demo``, ``run.json`` and
the report's summary cards. Every entry is present only when the file it comes from is.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from gprm.campaign.files import read_means, read_truth, read_truth_alignment
from gprm.flight.files import read_impact
from gprm.predict.files import read_whatif
from gprm.fit.files import read_fit_document


def earlier_outputs(run: str | Path) -> dict[str, str]:
    """Files of a run directory that its last ``gprm run`` did not produce: the outputs of a
    stage that failed or was blocked in it, left as they were (``kept`` in ``run.json``;
    gprm deletes only what it wrote in that call). Name -> why ("fit failed"). The summary
    and the report leave them out: they are not that run's results."""
    p = Path(run) / "run.json"
    try:
        rec = json.loads(p.read_text(encoding="utf-8")) if p.is_file() else {}
    except (OSError, ValueError, RecursionError):
        return {}
    stages = rec.get("stages") if isinstance(rec, dict) else None
    out: dict[str, str] = {}
    for name, st in (stages.items() if isinstance(stages, dict) else ()):
        if isinstance(st, dict) and st.get("status") not in ("ran", "skipped"):
            for f in st.get("kept") or ():
                out[str(f)] = f"the {name} stage {st.get('status')}"
    return out


def current_file(run: str | Path, name: str) -> Path | None:
    """``run / name`` where it exists and is the last run's (not :func:`earlier_outputs`)."""
    p = Path(run) / name
    if not p.exists() or name in earlier_outputs(run):
        return None
    return p


def truth_from_means(run: Path) -> dict | None:
    """The synthetic truth (SI, name -> value) recorded in ``means.nc``, if any; t0 and t1 in
    the aligned time base of the means (its truth after alignment) where given."""
    p = current_file(run, "means.nc")
    if p is None:
        return None
    means = read_means(p)
    truth = read_truth(means)
    if truth is None:
        return None
    # The aligned data's time base differs from the truth's (docs/data-formats.md, "The truth
    # after alignment"): the lags a fit of the aligned means should find are t0_expected_s
    # and t1_expected_s, not the truth's own t0, t1.
    align = read_truth_alignment(means) or {}
    for name in ("t0", "t1"):
        v = align.get(f"{name}_expected_s")
        if isinstance(v, (int, float)):
            truth[name] = float(v)
    # With the per-signal offsets fitted, x_base is the lag reference: t0 is x_base's
    # equivalent lag, dt_P = lag(P) - lag(x_base), t1 = lag(z_bk) - lag(x_base).
    eq = align.get("t0_equivalent_s") or {}
    if isinstance(eq.get("x_base"), (int, float)):
        ref = float(eq["x_base"])
        truth["t0_with_offsets"] = ref
        for point in ("x_head", "y_base", "y_head"):
            if isinstance(eq.get(point), (int, float)):
                truth[f"dt_{point}"] = float(eq[point]) - ref
        zb = align.get("t0_plus_t1_equivalent_z_bk_s")
        if isinstance(zb, (int, float)):
            truth["t1_with_offsets"] = float(zb) - ref
    return truth


def truth_for_fit(truth: dict, fit: dict) -> dict:
    """The truth a given fit should find: t0, t1 referred to x_base when the fit has the
    alignment offsets among its fitted parameters."""
    out = {k: v for k, v in truth.items() if not k.endswith("_with_offsets")}
    params = fit.get("parameters", {})
    if any(params.get(f"dt_{p}", {}).get("fitted") for p in ("x_head", "y_base", "y_head")):
        for name in ("t0", "t1"):
            if f"{name}_with_offsets" in truth:
                out[name] = truth[f"{name}_with_offsets"]
    else:
        for point in ("x_head", "y_base", "y_head"):
            out.pop(f"dt_{point}", None)
    return out


def truth_recovery(fit: dict, truth: dict) -> dict:
    """How well a fit of a synthetic campaign recovered its truth.

    For the *identified* fitted parameters (all fitted ones in a fit that does not say):
    z = (fit - truth) / stderr and how many lie within 1, 2, 3 sigma (``n`` of them), and how
    many of the truths lie inside their 68 % and 95 % intervals (``in68``, ``in95`` of
    ``n_interval``). Parameters the data do not determine get no z (their standard error
    says nothing about them): ``undetermined`` counts them and ``undetermined_in95`` those
    whose truth lies inside their (wide) 95 % interval; parameters that lean on the prior
    (narrow, but mostly the prior's variance: docs/fitting.md) are counted apart, as
    ``leans_on_prior`` and ``leans_in95``. ``relative_error`` for all."""
    z, rel = {}, {}
    n_int = in68 = in95 = und = und95 = lean = lean95 = 0

    def inside(iv, value) -> bool | None:
        if not isinstance(iv, dict):
            return None
        lo, hi = iv.get("lower"), iv.get("upper")
        lo = -math.inf if lo is None else lo
        hi = math.inf if hi is None else hi
        return bool(lo <= value <= hi)

    for name, p in fit["parameters"].items():
        if not (p.get("fitted") and name in truth):
            continue
        tv = truth[name]
        if tv:
            rel[name] = (p["value"] - tv) / abs(tv)
        i95 = inside(p.get("interval"), tv)
        if p.get("leans_on_prior"):
            lean += 1
            lean95 += bool(i95)
            continue
        if not p.get("identified", True):
            und += 1
            und95 += bool(i95)
            continue
        if p.get("stderr"):
            z[name] = (p["value"] - tv) / p["stderr"]
        if i95 is not None:
            n_int += 1
            in95 += i95
            in68 += bool(inside(p.get("interval68"), tv))
    n = len(z)
    out = {"n": n, "z": z, "relative_error": rel, "n_interval": n_int, "in68": in68,
           "in95": in95, "undetermined": und, "undetermined_in95": und95,
           "leans_on_prior": lean, "leans_in95": lean95}
    masses = [abs(rel[m]) for m in ("m1", "m2", "m3", "m4") if m in rel]
    out["mass_max_relative_error"] = max(masses) if masses else None
    for k in (1, 2, 3):
        out[f"within_{k}sigma"] = sum(abs(v) <= k for v in z.values())
    out["max_abs_z"] = max((abs(v) for v in z.values()), default=math.nan)
    return out


def impact_times_found(imp: dict) -> int:
    """How many impact times (release x axis) of an impact result have a value."""
    return sum(1 for r in imp.get("releases", []) for a in (r.get("impact_time") or {}).values()
               if a.get("value") is not None)


def summarise(run: str | Path) -> dict:
    run = Path(run)
    s: dict = {}
    if current_file(run, "fit.json"):
        fit = read_fit_document(run / "fit.json")
        st = fit.get("starts", {})
        s["fit"] = {"chi2": fit.get("chi2"), "dof": fit.get("dof"),
                    "reduced_chi2": fit.get("reduced_chi2"),
                    "starts": st.get("requested"), "converged": st.get("converged"),
                    "n_at_best": st.get("n_at_best"), "sigma": fit.get("sigma"),
                    "sigma_pool": fit.get("sigma_pool")}
        truth = truth_from_means(run)
        if truth:
            s["truth_recovery"] = truth_recovery(fit, truth_for_fit(truth, fit))
    if current_file(run, "whatif.json"):
        wi = read_whatif(run / "whatif.json")
        s["whatif"] = {r["name"]: r.get("headline", {}) for r in wi.get("ratios", [])
                       if r.get("name") != r.get("baseline")}
        s["whatif_paper"] = {r["name"]: r["paper"] for r in wi.get("ratios", [])
                             if r.get("paper")}
    if current_file(run, "impact.json"):
        imp = read_impact(run / "impact.json")
        tk = imp.get("tukey", {})
        pairs = tk.get("pairs", [])
        rejected = [f"{p['a']}–{p['b']}" for p in pairs if p.get("reject")]
        s["tukey"] = {"alpha": tk.get("alpha"), "pairs": len(pairs),
                      "rejected": rejected,
                      "verdict": ("all impact-time means compatible (H0 not rejected)"
                                  if pairs and not rejected else
                                  f"{len(rejected)} pair(s) differ" if pairs else
                                  "no test (" + str(tk.get("note", "no pairs")) + ")")}
        s["releases"] = len(imp.get("releases", []))
        s["impact_times_found"] = impact_times_found(imp)
        jc = imp.get("joint")
        if isinstance(jc, dict) and jc.get("all_consistent") is not None:
            # the releases whose axes disagree (joint chi-square test): said in the summary,
            # not only in a figure's title
            rej = [str(r) for r in jc.get("rejected") or ()]
            s["joint"] = {"alpha": jc.get("alpha"), "n": jc.get("n"), "rejected": rej,
                          "verdict": ("every release's axes consistent (joint χ²)" if not rej
                                      else "joint χ² rejects release(s) " + ", ".join(rej))}
        sc = imp.get("scenarios")
        if isinstance(sc, dict) and isinstance(sc.get("joint"), dict):
            s["scenario"] = scenario_text(sc)
    return s


def scenario_text(sc: dict) -> str:
    """One line: the impact scenario chosen jointly over the releases (with its probability)
    and how many releases show each of the paper's three observations (docs/flight.md)."""
    jt = sc["joint"]
    chosen = jt.get("chosen", "?")
    prob = (jt.get("probability") or {}).get(chosen)
    txt = f"{chosen}" + (f" (probability {prob:.3g})" if isinstance(prob, (int, float)) else "")
    obs = [r for r in ((sc.get("observations") or {}).get("releases") or [])
           if isinstance(r, dict)]
    if obs:
        n = len(obs)
        txt += (f"; z not the largest in {sum(bool(r.get('z_not_largest')) for r in obs)}/{n}, "
                f"momentum almost all in x–z in "
                f"{sum(bool(r.get('xz_almost_all')) for r in obs)}/{n}, "
                f"every component but ω_z non-compliant in "
                f"{sum(bool(r.get('all_non_compliant')) for r in obs)}/{n}")
    return txt


def truth_recovery_text(tr: dict) -> str:
    """One line of :func:`truth_recovery` for the console and the report."""
    if tr.get("n_interval"):
        txt = (f"truth inside the 95 % interval for {tr['in95']}/{tr['n_interval']} identified "
               f"parameters ({tr['in68']}/{tr['n_interval']} inside 68 %)")
    else:
        txt = (f"{tr['within_2sigma']}/{tr['n']} identified parameters within 2σ")
    if tr["n"]:
        txt += f"; max |z| {tr['max_abs_z']:.2f}"
    if tr.get("undetermined"):
        txt += (f"; {tr['undetermined']} not determined by the data "
                f"({tr['undetermined_in95']} with the truth inside their wide interval)")
    if tr.get("leans_on_prior"):
        txt += (f"; {tr['leans_on_prior']} leaning on the prior "
                f"({tr['leans_in95']} with the truth inside their 95 % interval)")
    if tr.get("mass_max_relative_error") is not None:
        txt += f"; masses within {100 * tr['mass_max_relative_error']:.1f} %"
    return txt
