"""The text fit report (lmfit-like) built from a saved fit's JSON dictionary.

One builder serves ``gprm fit`` (on the fit file it just wrote) and ``gprm show FIT.json``
(from the file), so both print the same text. Fields added in later format versions
(``initial``, ``at_bound``, ``identified``, ``interval``, ``uncertainty``) are shown when
present; older files print without them.
"""

from __future__ import annotations

import math
from typing import TypeGuard

from gprm.console import ProgressLines, clock_text
from gprm.params import LAG_PARAMETERS

DEFAULT_MIN_CORREL = 0.9


def _finite(x) -> TypeGuard[float]:
    """True for a finite int or float (not a bool): the values a fit file may hold as numbers."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _scale(name: str, p: dict) -> tuple[float, str]:
    """Factor SI -> display unit, and the display unit (SI when the file gives none)."""
    v, dv = p.get("value"), p.get("display_value")
    du = p.get("display_unit")
    if du and _finite(v) and _finite(dv) and v != 0:
        return dv / v, du
    if du:
        try:
            from gprm.params import REGISTRY
            from gprm.params.files import from_si

            if name in REGISTRY and REGISTRY[name].unit == du:
                return from_si(1.0, name), du
        except Exception:  # pragma: no cover - degrade to SI
            pass
    return 1.0, p.get("unit") or ""


def weights_label(sigma, pool, plus_minus: str = "+-") -> str:
    """The fit's weights in words: ``sigma`` (sem or std) and, where ``pool`` > 0, the
    samples on each side its square was pooled over (gprm.fit.objective.pooled_sigma)."""
    return f"{sigma}" + (f" pooled over {plus_minus}{pool} samples" if pool else "")


def draws_label(details) -> str | None:
    """The prediction draws' projection onto the data in words (gprm.fit.draws), from the
    uncertainty's ``details``; None where the draws were not projected (another method, a
    fit file from before stop 44, or no draws)."""
    dr = details.get("draws") if isinstance(details, dict) else None
    if isinstance(dr, dict) and dr.get("not_projected"):
        return (f"prediction draws as drawn, not put back on the data "
                f"({dr['not_projected']})")
    if not isinstance(dr, dict) or not _finite(dr.get("kept")):
        return None
    acc = dr.get("acceptance")
    return (f"prediction draws: {int(dr['kept'])} kept of {int(dr.get('proposed', 0))} "
            f"proposals" + (f" ({100 * acc:.0f} % reproduce their linearised signals)"
                            if _finite(acc) else "")
            + ", each moved onto the parameter sets that fit as the linearisation says; "
            "the others asked for signals no nearby parameter set gives, and were dropped")


def pretty_unit(unit: str) -> str:
    """A unit as people write it: ``N*s/m`` -> ``N·s/m`` (pint's ``*`` is for parsing)."""
    return unit.replace("*", "·")


def _g(x, fmt: str = ".6g") -> str:
    return format(x, fmt) if _finite(x) else "-"


def _khz(hz):
    return hz / 1e3 if _finite(hz) else None


def correlations_above(corr: dict | None, min_correl: float = DEFAULT_MIN_CORREL):
    """Pairs (a, b, r) with |r| >= min_correl, strongest first (each pair once)."""
    if not corr or corr.get("matrix") is None:
        return []
    names, m = corr["names"], corr["matrix"]
    out = []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            r = m[i][j]
            if _finite(r) and abs(r) >= min_correl:
                out.append((names[i], names[j], float(r)))
    return sorted(out, key=lambda t: -abs(t[2]))


def _fitted_names(d: dict) -> list[str]:
    """The fitted parameters in the order of the uncertainty's per-parameter lists (the
    correlation's names, else the parameter table's fitted entries)."""
    return list((d.get("correlation") or {}).get("names")
                or [n for n, p in (d.get("parameters") or {}).items() if p.get("fitted", False)])


#: `gprm show` lists the parameters whose variance has fewer degrees of freedom than this
#: (Student's t widens their 95 % interval by more than about 6 %)
STUDENT_SHOWN = 30.0


def fit_report(d: dict, *, min_correl: float = DEFAULT_MIN_CORREL) -> str:
    """lmfit-style report of a fit dictionary (the content of fit.json)."""
    lines = [f"[[Fit]] model {d.get('model', '?')}, piezo {d.get('piezo', '?')}, "
             f"sigma={weights_label(d.get('sigma', '?'), d.get('sigma_pool'))}"]
    st = d.get("starts") or {}
    if st:
        lines.append(f"    starts: {st.get('requested', '?')}, converged "
                     f"{st.get('converged', '?')}, pruned {st.get('pruned', '?')}, "
                     + (f"raced {st['raced']}, " if st.get("raced") else "")
                     + f"failed {st.get('failed', '?')}, at best (dchi2<=1) "
                     f"{st.get('n_at_best', '?')}")
    if _finite(d.get("chi2")):
        lines.append(f"    chi-square {d['chi2']:.6g}, dof {d.get('dof', '?')}, reduced "
                     f"{_g(d.get('reduced_chi2'), '.4g')}")
    if d.get("window"):
        w = d["window"]
        lines.append(f"    window {w[0] * 1e3:.4g} .. {w[1] * 1e3:.4g} ms")
    sub = (d.get("polish") or {}).get("subsample")
    if isinstance(sub, dict) and sub:
        rem = max((v.get("max_remainder_s", 0.0) for v in sub.values() if isinstance(v, dict)),
                  default=math.nan)
        dm = max((v.get("max_mean_change_m", 0.0) for v in sub.values()
                  if isinstance(v, dict)), default=math.nan)
        lines.append(f"    runs moved through the model by the sub-sample rest of their "
                     f"synchronisation (up to {_g(1e6 * rem, '.3g')} us; the mean changed by "
                     f"up to {_g(1e9 * dm, '.3g')} nm)")
    unc = d.get("uncertainty")
    if isinstance(unc, dict) and unc.get("method"):
        lines.append(f"    uncertainty: {unc['method']}"
                     + (f" ({unc['note']})" if unc.get("note") else ""))
        det = unc.get("details") or {}
        syst = det.get("systematics") if isinstance(det, dict) else None
        if isinstance(syst, dict) and syst:
            lines.append("    systematics marginalised (1 sd; timing = stated, (+) the alignment's "
                         "noise from the data where the signal's own lag is held fixed (a "
                         "fitted lag absorbs it), (+) the time shift the synchronisation took "
                         "out of the runs' spread, from their noise and from their drive "
                         "varying; the crossing offset is where the fitted "
                         "model crosses the alignment threshold against the data):")
            for sig, v in syst.items():
                if isinstance(v, dict):
                    lines.append(f"      {sig:>7}: gain {_g(100 * v.get('gain_sd', math.nan), '.3g')}"
                                 f" %, timing {_g(1e9 * v.get('timing_sd_s', math.nan), '.3g')} ns"
                                 f" (alignment {_g(1e9 * v.get('alignment_sd_s', math.nan), '.3g')}"
                                 f" ns, synchronisation "
                                 + (f"{_g(1e9 * v['sync_timing_sd_s'], '.3g')} ns"
                                    if _finite(v.get('sync_timing_sd_s'))
                                    else "not in the means file")
                                 + (f", the drive's {_g(1e9 * v['drive_timing_sd_s'], '.3g')} ns"
                                    if _finite(v.get('drive_timing_sd_s')) else "")
                                 + ", crossing offset "
                                 f"{_g(1e9 * v.get('crossing_offset_s', math.nan), '+.3g')} ns)")
            gz = det.get("gain_estimated_z")
            if isinstance(det.get("gain_estimated"), (int, float)) and \
                    isinstance(gz, (int, float)):
                lines.append(f"    gain error the residuals show: "
                             f"{_g(100 * det['gain_estimated'], '.3g')} % "
                             f"({_g(gz, '.1f')} sd of its noise without one"
                             + ("; indistinguishable from none" if gz < 2 else "") + ")")
            if det.get("statistical_from"):
                lines.append(f"    statistical part from the {det['statistical_from']}")
        dl = draws_label(det)
        if dl:
            lines.append(f"    {dl}")
        alt = det.get("alternative_minima") if isinstance(det, dict) else None
        if isinstance(alt, dict) and alt.get("within_95"):
            names = _fitted_names(d)
            fac = alt.get("factors") or {}
            wide = [names[i] for i, (a, b) in enumerate(zip(fac.get("lower") or [],
                                                             fac.get("upper") or []))
                    if i < len(names) and max(a, b) > 1.5]
            lines.append(f"    other minima as good as the best (within the 95 % "
                         f"likelihood-ratio threshold): {alt['within_95']} of "
                         f"{alt.get('distinct', '?')} other minima near it (starts' end points, "
                         "polished); the intervals include them"
                         + (f" (widened most: {', '.join(wide)})" if wide else ""))
        prof = det.get("profile_factors") if isinstance(det, dict) else None
        if isinstance(prof, dict):
            names = _fitted_names(d)
            side = [(names[i], a, b) for i, (a, b) in enumerate(zip(prof.get("lower") or [],
                                                                   prof.get("upper") or []))
                    if i < len(names) and _finite(a) and _finite(b) and max(a, b) > 1.5]
            if side:
                lines.append("    profile longer than the linearisation (objective re-minimised "
                             "over the others; 95 % side x factor): " + ", ".join(
                                 f"{n} " + ("lower" if a >= b else "upper")
                                 + f" x{_g(max(a, b), '.3g')}" for n, a, b in side))
        reach = det.get("excess_reaches") if isinstance(det, dict) else None
        if isinstance(reach, list) and reach:
            names = _fitted_names(d)
            # the lags never carry the excess unless stated (Systematics.excess_on_lags):
            # the test did not take it from them
            lags_off = not (det.get("stated") or {}).get("excess_on_lags", False)
            out = [names[i] for i, v in enumerate(reach) if i < len(names) and v is False
                   and not (lags_off and names[i] in LAG_PARAMETERS)]
            if out:
                lines.append("    residuals' excess over the runs' spread left out of the "
                             "intervals (each parameter's own ratio of the two below the F "
                             "median; the draws "
                             + ("keep it" if det.get("draws_excess") != "tested" else
                                "leave it out too") + "): " + ", ".join(out))
        dof = det.get("degrees_of_freedom") if isinstance(det, dict) else None
        if isinstance(dof, list) and dof:
            names = _fitted_names(d)
            src = det.get("degrees_of_freedom_from") or [None] * len(dof)
            few = [(names[i], v, src[i] if i < len(src) else None)
                   for i, v in enumerate(dof)
                   if i < len(names) and _finite(v) and v < STUDENT_SHOWN]
            if few:
                lines.append("    Student's t (variance estimated from few degrees of freedom; "
                             "nu, from): " + ", ".join(
                                 f"{n} {_g(v, '.3g')}" + (f" ({s})" if s else "")
                                 for n, v, s in sorted(few, key=lambda t: t[1])))
        factors = (unc.get("calibration") or {}).get("factors") or {}
        if isinstance(factors, dict) and factors:
            lines.append("    mismatch calibration (sd x factor): "
                         + ", ".join(f"{n} x{_g(f, '.3g')}" for n, f in factors.items()))
    adq = unc.get("adequacy") if isinstance(unc, dict) else None
    if isinstance(adq, dict) and adq.get("verdict"):
        lines.append(f"[[Adequacy]] {adq['verdict']}: reduced chi-square "
                     f"{_g(adq.get('reduced_chi2'), '.4g')} (p = {_g(adq.get('p_value'), '.2g')})")
        for sc in adq.get("signals") or []:
            if isinstance(sc, dict):
                lines.append(f"    {sc.get('signal', '?'):>7}: chi2/sample "
                             f"{_g(sc.get('chi2_per_sample'), '.3g')}, Ljung-Box p "
                             f"{_g(sc.get('ljung_box_p'), '.2g')}, lag-1 "
                             f"{_g(sc.get('lag1_autocorrelation'), '.2f')}, peak "
                             f"{_g(_khz(sc.get('peak_frequency_hz')), '.3g')} kHz "
                             f"(Fisher p {_g(sc.get('peak_p_fisher_g'), '.2g')}), leave-out "
                             f"error x{_g(sc.get('loso_ratio'), '.3g')}")
        if adq.get("text"):
            lines.append("    " + str(adq["text"]))
    lines.append("[[Parameters]]  (value +/- stderr (relative), initial; "
                 "* at a bound; ? not identified or leaning on the prior)")
    params = d.get("parameters") or {}
    legacy_bounds = set(d.get("parameters_at_bounds") or [])
    level = None
    for name, p in params.items():
        if not p.get("fitted", False):
            continue
        k, unit = _scale(name, p)
        v, e = p.get("value"), p.get("stderr")
        vs = v * k if _finite(v) else None
        row = f"    {name:>8} = {_g(vs, '12.6g'):>12}"
        if _finite(e):
            rel = abs(e / v) * 100 if _finite(v) and v != 0 else None
            row += f" +/- {_g(e * k, '.3g'):<9} ({_g(rel, '.2f')}%)" if rel is not None \
                else f" +/- {_g(e * k, '.3g'):<9}"
        else:
            row += " +/- n/a      "
        row += f" {pretty_unit(unit)}"
        if _finite(p.get("initial")):
            row += f"  (init = {p['initial'] * k:.6g})"
        at = p.get("at_bound") if "at_bound" in p else ("bound" if name in legacy_bounds
                                                       else None)
        if at:
            row += f"  * at {at} bound" if at in ("lower", "upper") else "  * at a bound"
        if p.get("leans_on_prior"):
            row += "  ? leans on the prior"
        elif p.get("identified") is False:
            row += "  ? not identified"
        iv = p.get("interval")
        if isinstance(iv, dict) and ("lower" in iv or "upper" in iv):
            level = iv.get("level", level)
            lo, hi = iv.get("lower"), iv.get("upper")
            row += (f"  [{_g(lo * k) if _finite(lo) else '-inf'}, "
                    f"{_g(hi * k) if _finite(hi) else '+inf'}]")
        lines.append(row)
    if level is not None:
        lines.append(f"    [..]: {level * 100:g} % interval; an infinite end: not bounded "
                     "by the data on that side")
    fixed = [n for n, p in params.items() if not p.get("fitted", False)]
    if fixed:
        lines.append(f"    fixed: {len(fixed)} parameters ({', '.join(fixed)})")
    corr = d.get("correlation")
    if not corr or corr.get("matrix") is None:
        msg = d.get("covariance_message") or "not available"
        lines.append(f"    (no covariance: {msg})")
    else:
        pairs = correlations_above(corr, min_correl)
        lines.append(f"[[Correlations]] (|C| >= {min_correl:g})")
        if pairs:
            lines += [f"    C({a}, {b}) = {r:+.4f}" for a, b, r in pairs]
        else:
            lines.append("    none")
    return "\n".join(lines)


#: what the progress shows beside the starts: the multi-start's best, before the polish that
#: the fit's result (and its report's chi-square) comes from
BEST_START = "best start chi2 (before polish)"


#: beside the count once every start is done, while the fit polishes the best one and
#: computes its uncertainty (no count to show)
AFTER_STARTS = "; polishing the best start, then its uncertainty"


def starts_info(best_chi2: float) -> str:
    """The text beside the bar of a fit's starts: the unit and the best chi-square of the
    starts so far (the polished fit ends lower; :func:`polish_note` says both)."""
    best = f"{best_chi2:.6g}" if math.isfinite(best_chi2) else "-"
    return f"starts  {BEST_START} {best}"


def polish_note(n_starts: int, best_start: float, chi2: float, seconds: float) -> str:
    """The line after the starts' progress: their best and the polished chi-square the
    report shows, so that the two numbers are not mistaken for one. (The starts minimise
    the data's chi-square plus the weak prior's terms, when there is a prior; the report's
    chi-square is the data's alone, after the polish.)"""
    best = f"{best_start:.6g}" if math.isfinite(best_start) else "-"
    return (f"fit: {n_starts} starts in {seconds:.1f} s; best start chi2 {best} before the "
            f"polish (prior terms included), chi2 {chi2:.6g} after it (the data's alone: the "
            "report's)")


class starts_progress:
    """Context manager: the progress of a multi-start fit's starts, with the best chi-square
    of the starts so far and the time remaining; yields the callback for ``run_multistart``
    (which also keeps ``.best``, the last best chi-square it was given).

    On a terminal it is a rich bar (transient); elsewhere (a log file, a pipe) plain lines
    (:class:`gprm.console.ProgressLines`): one per tenth of the starts and at least every
    ``every`` seconds while the fit runs, so a long fit without a terminal is not silent."""

    def __init__(self, console, n_starts: int, description: str = "fit", *,
                 every: float = 10.0):
        self.n_starts = int(n_starts)
        self.description = description
        self.bar = None
        self.lines = None
        if console.is_terminal:
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                                       TimeElapsedColumn, TimeRemainingColumn)

            self.bar = Progress(TextColumn(description), BarColumn(), MofNCompleteColumn(),
                                TextColumn("{task.fields[info]}"),
                                TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(),
                                console=console, transient=True)
        else:
            self.lines = ProgressLines(console.file, every=every)

    def __enter__(self):
        outer = self

        class Callback:
            best = float("nan")

            def __call__(self, done, total, best_chi2=float("nan")):
                self.best = best_chi2
                after = AFTER_STARTS if done >= total else ""
                if outer.bar is not None:
                    outer.bar.update(task, completed=done, total=total,
                                     info=starts_info(best_chi2) + after)
                else:
                    best = f"{best_chi2:.6g}" if math.isfinite(best_chi2) else "-"
                    outer.lines.update("fit", done, total, "starts",
                                       f"{BEST_START} {best}{after}")

        if self.bar is not None:
            self.bar.__enter__()
            task = self.bar.add_task("fit", total=self.n_starts, info=starts_info(float("nan")))
        else:
            self.lines.__enter__()
            self.lines.start("fit", self.description)
        return Callback()

    def __exit__(self, *exc):
        if self.bar is not None:
            return self.bar.__exit__(*exc)
        if exc[0] is not None:
            self.lines.finish("fit", f"{self.description}: stopped "
                              f"({clock_text(self.lines.elapsed('fit'))} elapsed)")
        return self.lines.__exit__(*exc)
