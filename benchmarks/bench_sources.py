"""Coverage of the fit's uncertainty per source of data (issue 21): a table per source, never
pooled over sources.

For each source of benchmarks/sources.py and each of ``--campaigns`` seeds: the campaign,
``preprocess`` and the fit with the CLI's defaults (PreprocessConfig(), FitOptions(): Table 3
and the alignment offsets, the weak prior, ``--starts`` random starts), then the intervals of
each method on the 21 physical parameters: how many are identified, and how often the truth
lies inside the 95 % and 68 % intervals of the identified ones (and of all).

    .venv/bin/python benchmarks/bench_sources.py [--sources white,gain-2,...] [--campaigns 20]
        [--seed 5000] [--starts 200] [--methods sandwich,laplace-prior] [--workers 2]
        [--scheduler ADDRESS] [--json F] [--cache DIR]
    .venv/bin/python benchmarks/bench_sources.py --from-json F [F ...]

``--cache DIR`` keeps each campaign's fit (a pickle) so that methods can be compared again
without refitting. Prints one markdown table per source and a summary table (one row per
source) with the Monte Carlo 95 % interval of each coverage (campaigns resampled).
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import sources  # noqa: E402

from gprm.campaign.files import read_campaign_dir  # noqa: E402
from gprm.campaign.preprocess import PreprocessConfig, preprocess  # noqa: E402
from gprm.errors import GprmInputError  # noqa: E402
from gprm.fit.api import FitOptions  # noqa: E402
from gprm.fit.identify import identify  # noqa: E402
from gprm.fit.objective import SIGMA_POOL, fit_data_from_means  # noqa: E402
from gprm.fit.sandwich import (ALIGNMENT_NOISE, DRAWS_STRETCH, EXCESS_QUANTILE,  # noqa: E402
                                Systematics)
from gprm.fit.starts import MultiStartOptions  # noqa: E402
from gprm.params import paper  # noqa: E402

LEVELS = (0.95, 0.68)


@dataclass(frozen=True)
class Case:
    source: str
    seed: int
    truth: dict            # name -> SI, the physical parameters
    fit: object            # FitResult
    seconds: float
    #: s, where the fit's aligned time base puts the truth's own time: the runs' average of
    #: (trigger offset - synchronisation shift) plus the shift preprocessing gave x_base
    #: (``sources.frame_shift``); computed again on reading where ``frame_axis`` is not
    #: FRAME_AXIS (caches written before it existed, or with stop 39's reference-run axis)
    frame_shift: float | None = None
    frame_axis: str | None = None


#: the definition of ``Case.frame_shift`` this script computes (sources.frame_shift)
FRAME_AXIS = "runs-mean"


class _CaseUnpickler(pickle.Unpickler):
    """Reads a cached Case whichever script wrote it (run as __main__ or imported)."""

    def find_class(self, module, name):
        if name == "Case":
            return Case
        return super().find_class(module, name)


def _campaign(source: str, seed: int, tmp: str):
    """(campaign Dataset, truth, preprocessed MeanSignals, frame shift of x_base)."""
    camp, truth = sources.make(source, seed, workdir=tmp)
    folder = None
    if not hasattr(camp, "sizes"):
        folder, camp = camp, read_campaign_dir(camp)
    ms = preprocess(camp, PreprocessConfig())
    shift = sources.frame_shift(camp if folder is None else folder, ms)
    return camp, truth, ms, float(shift[list(ms.signals).index("x_base")])


def _save(case: Case, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmpf = path.with_suffix(".part")
    with open(tmpf, "wb") as f:
        # a plain dict: on a Dask worker this module is not __main__, so the class
        # itself would not pickle by reference
        pickle.dump(dict(vars(case)), f)
    tmpf.replace(path)


def cached_study_arguments(ap, sources_default: str = ",".join(sources.SOURCES)) -> None:
    """The arguments of a study that re-scores this benchmark's cached fits (``--cache``):
    ``--sources``, ``--campaigns`` (20), ``--seed`` (5000), ``--starts`` (100, the key the
    fits were cached under), ``--cache``."""
    ap.add_argument("--sources", default=sources_default)
    ap.add_argument("--campaigns", type=int, default=20)
    ap.add_argument("--seed", type=int, default=5000)
    ap.add_argument("--starts", type=int, default=100)
    ap.add_argument("--cache", required=True, help="bench_sources.py's cache of fits")


#: the fit data's fields a cached fit may predate, made again from the campaign's seed
#: (they enter the uncertainty only): the synchronisation's timing sd (stop 43), step 0's
#: baseline and the noise's autocovariance (stop 56)
REMADE_FIELDS = ("sync_timing_sd", "baseline", "noise_acov")


def run_case(source: str, seed: int, starts: int, cache: str | None,
             sigma_pool: int = SIGMA_POOL) -> Case:
    """The fitted campaign (from ``cache`` where it holds it); ``sigma_pool``: the fit's
    weights pooled over that many samples on each side (gprm.fit.objective.pooled_sigma; 0:
    stops 1-41's sample-by-sample weights). A cached fit made with other weights is an
    error, not a silent mix."""
    path = Path(cache) / f"{source}-{seed}-{starts}.pkl" if cache else None
    if path is not None and path.exists():
        with open(path, "rb") as f:
            got = _CaseUnpickler(f).load()
        case = Case(**got) if isinstance(got, dict) else got
        if case.fit.data.sigma_pool != sigma_pool:
            raise SystemExit(f"{path}: fitted with sigma pooled over "
                             f"{case.fit.data.sigma_pool} samples, not {sigma_pool} "
                             "(--sigma-pool); use another --cache")
        if case.frame_axis != FRAME_AXIS:
            # a cache from before the frame shift was kept, or kept by another definition:
            # the campaign made again (its seed fixes it) for that one number, the fit
            # untouched
            with tempfile.TemporaryDirectory(prefix="gprm-src-") as tmp:
                shift = _campaign(source, seed, tmp)[3]
            case = replace(case, frame_shift=shift, frame_axis=FRAME_AXIS)
            _save(case, path)
        if any(getattr(case.fit.data, f) is None for f in REMADE_FIELDS):
            # a fit made before preprocessing wrote the synchronisation's timing sd (stop
            # 43), step 0's baseline or the noise's autocovariance (stop 56, which also
            # changed the timing sd): the campaign made again for those numbers, the fit
            # untouched (they enter the uncertainty only)
            with tempfile.TemporaryDirectory(prefix="gprm-src-") as tmp:
                ms = _campaign(source, seed, tmp)[2]
            rows = {s: i for i, s in enumerate(ms.signals)}
            pick = [rows[s] for s in case.fit.data.signals]
            data = replace(case.fit.data, **{f: np.asarray(getattr(ms, f))[pick]
                                              for f in REMADE_FIELDS})
            case = replace(case, fit=replace(case.fit, data=data))
            _save(case, path)
        return case
    t = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="gprm-src-") as tmp:
        _, truth, ms, shift = _campaign(source, seed, tmp)
    means = ms.to_dataset()
    opts = FitOptions()
    fit = identify(fit_data_from_means(means, window=opts.window, sigma=opts.sigma,
                                       sigma_pool=sigma_pool),
                   opts.parameters(paper()), MultiStartOptions(n_starts=starts, seed=seed),
                   band_samples=0, uncertainty="sandwich", prior_width=opts.prior_width)
    case = Case(source, seed, {n: float(truth[n]) for n in sources.PHYSICAL}, fit,
                time.perf_counter() - t, shift, FRAME_AXIS)
    if path is not None:
        _save(case, path)
    return case


def intervals(case: Case, unc):
    """(names, identified, {level: (lo, hi)}, best, leans on the prior (P,) bool) of the
    uncertainty ``unc`` of this case's fit (gprm.fit.uncertainty.determined: narrow, but
    at least half the prior's variance; all False where the method does not split)."""
    lv = {L: unc.interval(L) for L in LEVELS}
    return unc.names, np.asarray(unc.identified), lv, case.fit.x, unc.leaning


def truth_in_fit_time(case: Case):
    """The truth with its lag t0 in the fit's aligned time base: t0 plus the case's frame
    shift (``sources.frame_shift`` of x_base: the time of the mean of its synchronised runs,
    plus the shift preprocessing moved it by). This is the time axis the data were given, and so
    the one every fitted lag and prediction lives in, exactly, whatever the source adds at the
    onset. (Until stop 39 the shift was the alignment rule applied to the model's noise-free
    x_base: on sources whose onset carries something the model lacks, an unmodelled mode
    above all, that axis is not the data's; it differs by the fitted model's crossing offset,
    docs/fitting.md, "The time axis of a campaign's truth".)"""
    truth = paper().with_values(**case.truth)
    shift = case.frame_shift
    if shift is None:
        raise ValueError(f"{case.source} seed {case.seed}: no frame shift (run_case sets it)")
    return truth, truth.with_values(t0=truth["t0"] + shift)


def prediction_scores(case: Case, u, samples: int = 200) -> dict:
    """Overshoots, kinetic-energy histogram and velocity curves (benchmarks/bench_coverage.py's
    scores) of the draws of the uncertainty ``u`` of this case's fit against the truth, all
    three in the fit's time axis (:func:`truth_in_fit_time`: the overshoots are maxima over
    a fixed window, which a lag moves; until stop 40 they took the truth in its own axis,
    several microseconds off on the trigger-jitter sources, hidden by t0's wider intervals)."""
    from bench_coverage import curve_cover, energy_cover, prediction_cover
    from gprm.fit.files import FittedModel
    from gprm.predict.trajectories import default_times

    fm = FittedModel(case.fit.params, u.covariance, piezo=2, draws=u.draws,
                     uncertainty=u.method)
    truth_t = truth_in_fit_time(case)[1]
    return {"pred": prediction_cover(fm, truth_t, default_times(), samples, case.seed),
            "energy": energy_cover(fm, truth_t, samples, case.seed),
            "curves": curve_cover(fm, truth_t, samples, case.seed)}


#: how a development check of ``--no-...`` / ``--alignment-noise`` / ``--hac-lag`` labels its
#: rows: the Systematics field and the words for its value (docs/fitting.md)
_CHECK_LABELS = {
    "alignment_noise": lambda v: f"alignment noise {v}",
    "residual_dof": lambda v: "residuals' t " + ("on" if v else "off"),
    "sync_timing": lambda v: "synchronisation's timing " + ("on" if v else "off"),
    "project_draws": lambda v: "draws " + ("projected" if v else "as drawn"),
    "hac_lag": lambda v: f"residuals' lag window {v}",
    "profile_check": lambda v: "profile check " + ("on" if v else "off"),
    "excess_test": lambda v: ("residuals' excess untested" if v is None
                              else f"residuals' excess where above F_{v:g}"),
    "excess_test_draws": lambda v: "draws' excess " + ("tested" if v else "untested"),
    "draws_stretch": lambda v: f"draws stretched {v}",
    "drive_put_back": lambda v: "drive's shift " + ("put back" if v else "as a timing term"),
}


def method_label(method: str, systematics: Systematics) -> str:
    """``method``, plus each development check where ``systematics`` differs from the
    default (the fields of :data:`_CHECK_LABELS`, in that order)."""
    d0 = Systematics()
    return ", ".join([method] + [words(getattr(systematics, f))
                                 for f, words in _CHECK_LABELS.items()
                                 if getattr(systematics, f) != getattr(d0, f)])


def score(case: Case, method: str, predictions: bool = False,
          systematics: Systematics = Systematics()) -> dict:
    """The case's coverage with ``method`` (its uncertainty computed once for the parameters,
    t0 and the predictions), the sandwich's ``systematics`` (other than the default: a
    development check, docs/fitting.md, labelled as such in the tables)."""
    from gprm.fit.methods import uncertainty_of

    default = systematics == Systematics()
    unc = uncertainty_of(case.fit, method, systematics=None if default else systematics)
    names, ident, lv, best, leans = intervals(case, unc)
    label = method_label(method, systematics)
    out = {"source": case.source, "seed": case.seed, "method": label,
           "n_identified": 0, "n_all": 0, "best_outside": 0, "n_prior": 0}
    for L in LEVELS:
        out[f"id_in{round(100 * L)}"] = 0
        out[f"all_in{round(100 * L)}"] = 0
        out[f"prior_in{round(100 * L)}"] = 0
    misses = []
    out["inside"] = {}
    for k, n in enumerate(names):
        if n not in case.truth:
            continue
        v = case.truth[n]
        out["n_all"] += 1
        out["n_identified"] += int(ident[k])
        for L in LEVELS:
            lo, hi = lv[L]
            inside = bool(lo[k] <= v <= hi[k])
            out[f"all_in{round(100 * L)}"] += int(inside)
            if ident[k]:
                out["inside"].setdefault(n, []).append(int(inside))
                out[f"id_in{round(100 * L)}"] += int(inside)
                if L == 0.95 and not inside:
                    misses.append(n)
            if leans[k]:
                out[f"prior_in{round(100 * L)}"] += int(inside)
        out["n_prior"] += int(leans[k])
        lo, hi = lv[0.95]
        out["best_outside"] += int(not (lo[k] <= best[k] <= hi[k]))
    out["misses95"] = misses
    out.update(t0_scores(case, names, lv, best))
    out["not_identified"] = [n for k, n in enumerate(names) if n in case.truth and not ident[k]]
    if predictions:
        out.update(prediction_scores(case, unc))
    return out


def t0_scores(case: Case, names, lv: dict, best) -> dict:
    """The lag t0 against the truth's in the fit's aligned time axis (:func:`truth_in_fit_time`):
    inside the 95 % / 68 % intervals, the error and the 68 % half-width (s), and the fitted
    model's crossing offset of x_base (the fit's fit.json diagnostic, s)."""
    names = list(names)
    if "t0" not in names:
        return {}
    k = names.index("t0")
    t_true = truth_in_fit_time(case)[1]["t0"]
    det = getattr(case.fit.uncertainty, "details", None) or {}
    off = ((det.get("systematics") or {}).get("x_base") or {}).get("crossing_offset_s")
    out = {f"t0_in{round(100 * L)}": int(lv[L][0][k] <= t_true <= lv[L][1][k]) for L in LEVELS}
    return {**out, "t0_err_s": float(best[k] - t_true),
            "t0_half68_s": float((lv[0.68][1][k] - lv[0.68][0][k]) / 2),
            "t0_offset_s": None if off is None else float(off)}


#: the percentiles t0_shape reports
SHAPE_QS = (50, 68, 90, 95)


def shape_of(ratio: np.ndarray, qs=SHAPE_QS) -> tuple[np.ndarray, float]:
    """(the ``qs`` percentiles of |ratio|, its rms): errors over their 68 % half-widths."""
    v = np.abs(np.asarray(ratio, float))
    return np.percentile(v, qs), float(np.sqrt(np.mean(v ** 2)))


def t0_shape(rows: list[dict]) -> str:
    """t0's error over its 68 % half-width, pooled over every source of ``rows``, per method:
    quantiles of the ratio against a normal error's with that half-width (0.68, 1, 1.65, 1.97
    at 50, 68, 90, 95 %), its rms, and the share inside the 95 % interval. A ratio whose core
    lies under a normal's and whose tail matches it is a heavy-tailed error with a sound
    variance: the 68 % interval too wide, the 95 % one right."""
    from scipy.stats import norm

    qs = SHAPE_QS
    z68 = norm.ppf(0.84)
    ref = ", ".join(f"{norm.ppf(0.5 + q / 200) / z68:.2f}" for q in qs)
    out = ["| method | campaigns (sources) | \\|error\\| / 68 % half-width at "
           + ", ".join(f"{q} %" for q in qs) + f" (a normal: {ref}) | rms | inside 95 % |",
           "|---|---|---|---|---|"]
    for m in sorted({r["method"] for r in rows if "t0_half68_s" in r}):
        rr = [r for r in rows if r["method"] == m and r.get("t0_half68_s", 0) > 0]
        q, rms = shape_of(np.array([r["t0_err_s"] / r["t0_half68_s"] for r in rr]), qs)
        out.append(f"| {m} | {len(rr)} ({len({r['source'] for r in rr})}) | "
                   + ", ".join(f"{x:.2f}" for x in q) + f" | {rms:.2f} | "
                   f"{100 * np.mean([r['t0_in95'] for r in rr]):.1f} % |")
    return "\n".join(out)


def t0_table(rows: list[dict]) -> str:
    """Per source: how often t0's intervals hold the truth's lag in the fit's axis, the
    median |error| and 68 % half-width, and the median |crossing offset| of x_base (us)."""
    out = ["| source | method | campaigns | t0 95 % | t0 68 % | median \\|error\\| (us) | "
           "median 68 % half-width (us) | median \\|crossing offset\\| (us) |",
           "|---|---|---|---|---|---|---|---|"]
    for src, m in _source_keys(rows, "t0_in95"):
        rr = [r for r in rows if r["source"] == src and r["method"] == m and "t0_in95" in r]
        offs = [abs(r["t0_offset_s"]) for r in rr if r.get("t0_offset_s") is not None]
        out.append(f"| {src} | {m} | {len(rr)} | {100 * np.mean([r['t0_in95'] for r in rr]):.0f} "
                   f"% | {100 * np.mean([r['t0_in68'] for r in rr]):.0f} % | "
                   f"{1e6 * np.median([abs(r['t0_err_s']) for r in rr]):.3f} | "
                   f"{1e6 * np.median([r['t0_half68_s'] for r in rr]):.3f} | "
                   + (f"{1e6 * np.median(offs):.3f} |" if offs else "- |"))
    return "\n".join(out)


def mc_interval(rows: list[dict], num: str, den: str, rng, n_boot: int = 2000):
    a = np.array([r[num] for r in rows], float)
    b = np.array([r[den] for r in rows], float)
    if b.sum() == 0:
        return np.nan, np.nan, np.nan
    idx = rng.integers(0, len(rows), (n_boot, len(rows)))
    f = a[idx].sum(axis=1) / np.maximum(b[idx].sum(axis=1), 1)
    lo, hi = np.percentile(f, [2.5, 97.5])
    return 100 * a.sum() / b.sum(), 100 * lo, 100 * hi


def _source_keys(rows: list[dict], need: str | None = None) -> list[tuple[str, str]]:
    """The (source, method) pairs of ``rows`` (those with ``need``), in the sources' order."""
    return sorted({(r["source"], r["method"]) for r in rows if need is None or need in r},
                  key=lambda k: (sources.SOURCES.index(k[0]) if k[0] in sources.SOURCES
                                 else 99, k[1]))


def prediction_summary(rows: list[dict]) -> str:
    rng = np.random.default_rng(1)
    out = ["| source | method | overshoots 95 % | 68 % | KE histogram 95 % | 68 % | "
           "velocity curves 95 % | 68 % |", "|---|---|---|---|---|---|---|---|"]
    keys = _source_keys(rows, "pred")
    for src, m in keys:
        rr = [r for r in rows if r["source"] == src and r["method"] == m and "pred" in r]
        cells = []
        for key in ("pred", "energy", "curves"):
            flat = [{"a95": r[key]["in95"], "a68": r[key]["in68"], "n": r[key]["n"]}
                    for r in rr]
            for lv in ("95", "68"):
                c = mc_interval(flat, f"a{lv}", "n", rng)
                cells.append(f"{c[0]:.1f} ({c[1]:.0f}-{c[2]:.0f})")
        out.append(f"| {src} | {m} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def summary(rows: list[dict]) -> str:
    rng = np.random.default_rng(0)
    out = ["| source | method | campaigns | identified / campaign (min) | 95 % (MC 95 %) | "
           "68 % (MC 95 %) | all 21: 95 % / 68 % | best fit outside its 95 % |",
           "|---|---|---|---|---|---|---|---|"]
    keys = _source_keys(rows)
    for src, m in keys:
        rr = [r for r in rows if r["source"] == src and r["method"] == m]
        nid = [r["n_identified"] for r in rr]
        c95 = mc_interval(rr, "id_in95", "n_identified", rng)
        c68 = mc_interval(rr, "id_in68", "n_identified", rng)
        a95 = 100 * sum(r["all_in95"] for r in rr) / max(sum(r["n_all"] for r in rr), 1)
        a68 = 100 * sum(r["all_in68"] for r in rr) / max(sum(r["n_all"] for r in rr), 1)
        out.append(f"| {src} | {m} | {len(rr)} | {np.mean(nid):.1f} ({min(nid)}) | "
                   f"{c95[0]:.1f} ({c95[1]:.0f}-{c95[2]:.0f}) | "
                   f"{c68[0]:.1f} ({c68[1]:.0f}-{c68[2]:.0f}) | {a95:.1f} / {a68:.1f} | "
                   f"{sum(r['best_outside'] for r in rr)} |")
    return "\n".join(out)


def leaning_table(rows: list[dict]) -> str:
    """Coverage of the identified parameters beside that of the parameters that lean on the
    prior (narrow intervals whose variance is at least half the weak prior's,
    gprm.fit.uncertainty.determined; counted identified until stop 48): where the prior
    carries most of an interval, its width is the prior's bias allowance, and truths drawn
    near the prior's centre (these sources draw them within +-10 % of Table 3, the prior is a
    factor 3.5 at one sd) are covered whatever the data say."""
    rng = np.random.default_rng(2)
    out = ["| source | method | identified / campaign | 95 % | 68 % | "
           "leaning on the prior / campaign | 95 % | 68 % |", "|---|---|---|---|---|---|---|---|"]
    keys = _source_keys(rows, "n_prior")
    for src, m in keys:
        rr = [r for r in rows if r["source"] == src and r["method"] == m]
        data = [{"n": r["n_identified"],
                 **{f"a{lv}": r[f"id_in{lv}"] for lv in ("95", "68")}}
                for r in rr]
        prior = [{"n": r["n_prior"], **{f"a{lv}": r[f"prior_in{lv}"] for lv in ("95", "68")}}
                 for r in rr]
        cells = []
        for part in (data, prior):
            cells.append(f"{np.mean([p['n'] for p in part]):.1f}")
            for lv in ("95", "68"):
                c = mc_interval(part, f"a{lv}", "n", rng)
                cells.append("-" if np.isnan(c[0]) else f"{c[0]:.1f} ({c[1]:.0f}-{c[2]:.0f})")
        out.append(f"| {src} | {m} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def parameter_table(rows: list[dict]) -> str:
    """Coverage per identified physical parameter, pooled over every source and campaign in
    ``rows`` (a per-source table can hide a parameter that is covered too rarely
    everywhere)."""
    cnt: dict[str, list[int]] = {}
    for r in rows:
        for n, flags in (r.get("inside") or {}).items():
            c = cnt.setdefault(n, [0, 0, 0])
            c[0] += 1
            c[1] += flags[0]
            c[2] += flags[1]
    out = ["| parameter | identified (campaigns) | 95 % | 68 % |", "|---|---|---|---|"]
    for n in sorted(cnt, key=lambda m: cnt[m][2] / cnt[m][0]):
        c = cnt[n]
        out.append(f"| {n} | {c[0]} | {100 * c[1] / c[0]:.1f} | {100 * c[2] / c[0]:.1f} |")
    return "\n".join(out)


#: the x-plane B support, whose intervals the per-source tables hid falling short (stop 49)
SUPPORT = ("k_Bx", "c_Bx", "d2")


def support_table(rows: list[dict], names: tuple[str, ...] = SUPPORT) -> str:
    """Per source and method, the coverage of ``names`` pooled over the campaigns that
    identified each (identified cases, 95 %, 68 %): the parameter-specific shortfall a
    source's table pools away."""
    out = [f"| source | method | {', '.join(names)}: identified cases | 95 % | 68 % |",
           "|---|---|---|---|---|"]
    for src in sorted({r["source"] for r in rows}):
        for m in sorted({r["method"] for r in rows if r["source"] == src}):
            n = c95 = c68 = 0
            for r in rows:
                if r["source"] != src or r["method"] != m:
                    continue
                for name, flags in (r.get("inside") or {}).items():
                    if name in names:
                        n, c95, c68 = n + 1, c95 + flags[0], c68 + flags[1]
            if n:
                out.append(f"| {src} | {m} | {n} | {100 * c95 / n:.1f} | {100 * c68 / n:.1f} |")
            else:
                out.append(f"| {src} | {m} | 0 | - | - |")
    return "\n".join(out)


def _name_counts(rows: list[dict], key: str, campaigns: bool = False) -> str:
    """Per source and method, how many campaigns list each name under ``key``."""
    out = []
    for src in sorted({r["source"] for r in rows}):
        for m in sorted({r["method"] for r in rows if r["source"] == src}):
            rr = [r for r in rows if r["source"] == src and r["method"] == m]
            cnt: dict[str, int] = {}
            for r in rr:
                for n in r.get(key, ()):
                    cnt[n] = cnt.get(n, 0) + 1
            top = ", ".join(f"{n} {c}" for n, c in sorted(cnt.items(), key=lambda t: -t[1]))
            label = f"{src}, {m}" + (f" ({len(rr)} campaigns)" if campaigns else "")
            out.append(f"- {label}: {top or 'none'}")
    return "\n".join(out)


def not_identified_table(rows: list[dict]) -> str:
    """Per source, how often each physical parameter was not identified (campaigns)."""
    return _name_counts(rows, "not_identified", campaigns=True)


def misses_table(rows: list[dict]) -> str:
    """Per source, how often each identified parameter's 95 % interval missed the truth."""
    return _name_counts(rows, "misses95")


def hac_lag_arg(text: str) -> int | str | None:
    """A ``--hac-lag`` value: ``default`` (None, a quarter of the window's samples), ``auto``
    (Andrews' plug-in) or a number of samples, checked as ``Systematics.hac_lag`` checks it."""
    value = None if text == "default" else text if text == "auto" else \
        int(text) if text.lstrip("-").isdigit() else text
    try:
        Systematics(hac_lag=value)
    except GprmInputError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: {exc}") from None
    return value


def excess_test_arg(text: str) -> float | None:
    """``--excess-test``: a quantile in (0, 1), or ``none`` (untested: stops 1-50)."""
    if text == "none":
        return None
    try:
        q = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a quantile: {text!r}") from None
    if not 0.0 < q < 1.0:
        raise argparse.ArgumentTypeError(f"a quantile must lie in (0, 1), got {text}")
    return q


def _job(index: int, jobs: list):
    """Job ``index`` of ``jobs`` (source, seed, starts, cache, methods, predictions, the
    sandwich's Systematics, sigma pool):
    its scores and the seconds its fit took. A
    Dask task of benchmarks/_studies.py's map_seeds, which keys tasks by an integer; the
    result depends only on the job."""
    source, seed, starts, cache, methods, predictions, systematics, pool = jobs[index]
    case = run_case(source, seed, starts, cache, pool)
    return [score(case, m, predictions, systematics) for m in methods], case.seconds


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sources", default=",".join(sources.SOURCES))
    ap.add_argument("--campaigns", type=int, default=20)
    ap.add_argument("--seed", type=int, default=5000)
    ap.add_argument("--starts", type=int, default=200)
    ap.add_argument("--methods", default="sandwich")
    ap.add_argument("--workers", type=int, default=2,
                    help="campaigns as Dask tasks on a local cluster of this many processes "
                    "(0: in this process)")
    ap.add_argument("--scheduler", default=None,
                    help="campaigns as Dask tasks on the cluster of this scheduler address")
    ap.add_argument("--predictions", action="store_true",
                    help="also score overshoots, KE histogram and velocity curves (slower)")
    ap.add_argument("--alignment-noise", default=Systematics().alignment_noise,
                    choices=ALIGNMENT_NOISE,
                    help="whose alignment noise joins a signal's timing error in the "
                    "sandwich (Systematics.alignment_noise; other than the default: a "
                    "development check, the rows labelled so; all: stop 39's default)")
    ap.add_argument("--no-residual-dof", action="store_true",
                    help="Student's t for the runs' part only, not where the residuals' "
                    "kernel estimate leads (Systematics.residual_dof=False: stop 37-40's "
                    "method, a development check, the rows labelled so)")
    ap.add_argument("--no-sync-timing", action="store_true",
                    help="without the time shift the synchronisation takes out of the runs' "
                    "spread (Systematics.sync_timing=False: stops 1-42, a development "
                    "check, the rows labelled so)")
    ap.add_argument("--raw-draws", action="store_true",
                    help="the predictions from the Gaussian's draws as drawn, not projected "
                    "onto the data (Systematics.project_draws=False: stops 1-43, a "
                    "development check, the rows labelled so)")
    ap.add_argument("--hac-lag", type=hac_lag_arg, default=None,
                    help="the residuals' kernel estimate's lag window in samples "
                    "(Systematics.hac_lag; default: a quarter of the window's samples; "
                    "auto: Andrews' plug-in; another: a development check, the rows labelled so)")
    ap.add_argument("--no-profile-check", action="store_true",
                    help="without the profile check of each identified parameter's sides "
                    "(Systematics.profile_check=False: stops 1-48, a development check, the "
                    "rows labelled so)")
    ap.add_argument("--excess-test", type=excess_test_arg, default=EXCESS_QUANTILE,
                    help="test the residuals' excess per parameter at this quantile q "
                    "(Systematics.excess_test; another q, or none: untested as in stops "
                    "1-50, a development check, the rows labelled so)")
    ap.add_argument("--excess-test-draws", action="store_true",
                    help="the test also thins the excess in the draws, so in the "
                    "predictions (Systematics.excess_test_draws: stop 50's development "
                    "check, the rows labelled so)")
    ap.add_argument("--draws-stretch", choices=DRAWS_STRETCH, default=Systematics().draws_stretch,
                    help="how the draws are stretched to the intervals' factors "
                    "(Systematics.draws_stretch; other than the default: a development "
                    "check, the rows labelled so)")
    ap.add_argument("--drive-put-back", action="store_true",
                    help="each run's drive shift put back into its deviation instead of the "
                    "drive term (Systematics.drive_put_back: stop 60's development check, "
                    "the rows labelled so)")
    ap.add_argument("--sigma-pool", type=int, default=SIGMA_POOL,
                    help="the fits' weights pooled over this many samples on each side "
                    "(gprm.fit.objective.pooled_sigma; 0: stops 1-41's sample-by-sample "
                    "weights, a development check; a cache holds one choice)")
    ap.add_argument("--json")
    ap.add_argument("--cache")
    ap.add_argument("--from-json", nargs="+")
    a = ap.parse_args(argv)
    if a.from_json:
        rows = [r for f in a.from_json for r in json.loads(Path(f).read_text())["rows"]]
        print(summary(rows))
        print()
        print(leaning_table(rows))
        print()
        if any("pred" in r for r in rows):
            print(prediction_summary(rows))
            print()
        if any("t0_in95" in r for r in rows):
            print(t0_table(rows) + "\n\n" + t0_shape(rows))
            print()
        print(misses_table(rows))
        print()
        print(not_identified_table(rows))
        print()
        print(parameter_table(rows))
        print()
        print(support_table(rows))
        return 0
    srcs = [s for s in a.sources.split(",") if s]
    known = (sources.SOURCES + sources.PROBES + sources.NOISE_SCAN + sources.SIM2_ALONE
             + sources.DRIVE_PARTS)
    unknown = [s for s in srcs if s not in known]
    if unknown:
        ap.error(f"unknown source(s) {unknown}; one of {', '.join(known)}")
    methods = [m for m in a.methods.split(",") if m]
    syst = Systematics(alignment_noise=a.alignment_noise, residual_dof=not a.no_residual_dof,
                       sync_timing=not a.no_sync_timing, project_draws=not a.raw_draws,
                       hac_lag=a.hac_lag, profile_check=not a.no_profile_check,
                       excess_test=a.excess_test, excess_test_draws=a.excess_test_draws,
                       draws_stretch=a.draws_stretch, drive_put_back=a.drive_put_back)
    jobs = [(s, a.seed + i, a.starts, a.cache, methods, a.predictions, syst, a.sigma_pool)
            for s in srcs
            for i in range(a.campaigns)]
    t0 = time.perf_counter()
    rows: list[dict] = []
    secs = []
    from _machine import machine
    from _studies import map_seeds

    for res, sec in map_seeds(_job, range(len(jobs)), scheduler=a.scheduler,
                              workers=a.workers, labels=[f"{j[0]} seed {j[1]}" for j in jobs],
                              jobs=jobs):
        rows.extend(res)
        secs.append(sec)
    where = (f"scheduler {a.scheduler}" if a.scheduler else
             f"{a.workers} Dask workers" if a.workers > 0 else "in process")
    meta = {"command": " ".join(["benchmarks/bench_sources.py"] + (argv or sys.argv[1:])),
            "wall_s": round(time.perf_counter() - t0, 1),
            "median_case_s": float(np.median(secs)), "where": where, "machine": machine()}
    print(f"{len(jobs)} campaigns in {meta['wall_s']} s ({where}; median "
          f"{meta['median_case_s']:.1f} s per campaign; {meta['machine']})\n")
    print(summary(rows))
    print()
    print(leaning_table(rows))
    print()
    if a.predictions:
        print(prediction_summary(rows))
        print()
    print(t0_table(rows) + "\n\n" + t0_shape(rows))
    print()
    print(misses_table(rows))
    print()
    print(not_identified_table(rows))
    print()
    print(parameter_table(rows))
    print()
    print(support_table(rows))
    if a.json:
        Path(a.json).write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
