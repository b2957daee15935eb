"""What-if studies (paper Sec. 4.2, Fig. 13-14): overshoot of the contact points and the tip per
axis under scenarios (piezo, eccentricity scale, overrides), ratios between scenarios, and
sweeps of one parameter.

Overshoot (docs/prediction.md): for a point P and axis a, over the window [t_start, t_end],
    OS_a(P) = max_t |p_a(t) - p_a(t_start)|,
the largest excursion from the position at the window start; the window starts with the
mechanism at rest in its initial equilibrium (before t_c + t0), so p_a(t_start) is the initial
position. Ratio between scenarios S and T: OS_a(P; S) / OS_a(P; T).
The paper's three ratios per comparison are x: M_xz, y: M_yz, z: M_xz (``HEADLINE``).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from typing import Any, Mapping, Sequence

import numpy as np
import xarray as xr

from gprm.errors import GprmInputError
from gprm.fit.files import FittedModel
from gprm.params import REGISTRY, batch
from gprm.params.files import from_si
from gprm.predict.scenarios import (ECCENTRICITIES, Scenario, apply_scenario, check_scenario,
                                    standard_scenarios)
from gprm.predict.trajectories import AXES, default_times, sampled_points

WHATIF_POINTS: tuple[str, ...] = ("M_xz", "M_yz", "tip_edge")
HEADLINE: dict[str, str] = {"x": "M_xz", "y": "M_yz", "z": "M_xz"}
"""Which point's overshoot gives the paper's ratio on each axis."""

PAPER_RATIOS: dict[str, dict[str, float]] = {
    "piezo1": {"x": 4.0, "y": 6.4, "z": 3.8},
    "piezo1_ecc_div10": {"x": 40.0, "y": 64.6},
}
"""Sec. 4.2: overshoot with Piezo 2 divided by that of the scenario (z of the eccentricity
case: 'basically unaffected' with respect to Piezo 1, no number given)."""

DEFAULT_WINDOW: tuple[float, float] = (0.95e-3, 1.2e-3)
DEFINITION = ("overshoot = max over the window of |p_a(t) - p_a(t_start)| (m), the largest "
              "excursion of point p along axis a from its position at the window start (rest, "
              "initial equilibrium); ratio = overshoot(baseline) / overshoot(scenario)")


@dataclass(frozen=True)
class WhatIf:
    """The what-if table (Sec. 4.2): overshoots of ``points`` per axis under each scenario
    and their ratios to the first (the baseline).

    ``scenarios``: per scenario its definition (name, piezo, scale_eccentricity, overrides)
    and ``overshoot`` {point: {axis: m}}, with the 2.5/97.5 % sampled ranges
    (``overshoot_p2_5``, ``overshoot_p97_5``) where parameter sets were drawn; ``ratios``:
    per scenario ``ratio`` {point: {axis}} = baseline / scenario, the paper's ``headline``
    {axis: ratio} (x: M_xz, y: M_yz, z: M_xz), sampled ranges and the ``paper``'s numbers.

    ``to_json()`` is ``whatif.json`` (docs/prediction.md); ``to_xarray()`` the same numbers
    along (scenario, point, axis), NaN where a range is absent; :meth:`from_json` reads a
    document back.
    """

    window_s: tuple[float, float]
    rate_hz: float
    points: tuple[str, ...]
    axes: tuple[str, ...]
    source: str
    samples: int
    seed: int
    scenarios: tuple[dict, ...]
    ratios: tuple[dict, ...]
    definition: str = DEFINITION
    unit: str = "m"

    def to_json(self) -> dict:
        """The what-if document (JSON-able; a deep copy)."""
        return {"definition": self.definition,
                "window_s": [float(self.window_s[0]), float(self.window_s[1])],
                "rate_hz": float(self.rate_hz), "points": list(self.points),
                "axes": list(self.axes), "unit": self.unit, "source": self.source,
                "samples": int(self.samples), "seed": int(self.seed),
                "scenarios": copy.deepcopy(list(self.scenarios)),
                "ratios": copy.deepcopy(list(self.ratios))}

    @classmethod
    def from_json(cls, doc: Mapping) -> "WhatIf":
        """The table of a what-if document (``to_json()``'s inverse)."""
        try:
            return cls(window_s=tuple(doc["window_s"]), rate_hz=doc["rate_hz"],
                       points=tuple(doc["points"]), axes=tuple(doc["axes"]),
                       source=doc["source"], samples=doc["samples"], seed=doc["seed"],
                       scenarios=tuple(copy.deepcopy(doc["scenarios"])),
                       ratios=tuple(copy.deepcopy(doc["ratios"])),
                       definition=doc["definition"], unit=doc["unit"])
        except KeyError as exc:
            raise GprmInputError("missing in the what-if document",
                                 field=str(exc.args[0])) from None
        except TypeError:
            raise GprmInputError("not a what-if document (a JSON object)",
                                 field="whatif") from None

    def headline(self, name: str) -> dict:
        """The paper's ratios {axis: baseline / scenario} of scenario ``name``."""
        for r in self.ratios:
            if r["name"] == name:
                return dict(r.get("headline", {}))
        raise GprmInputError(f"no scenario {name!r} (known: "
                             f"{', '.join(r['name'] for r in self.ratios)})", field="name")

    def to_xarray(self) -> xr.Dataset:
        """The table along (scenario, point, axis) (ratios: baseline / scenario)."""
        names = [s["name"] for s in self.scenarios]

        def cube(entries, key):
            out = np.full((len(entries), len(self.points), len(self.axes)), np.nan)
            for i, e in enumerate(entries):
                tab = e.get(key)
                if tab is None:
                    continue
                for j, p in enumerate(self.points):
                    for k, a in enumerate(self.axes):
                        out[i, j, k] = tab[p][a]
            return out

        dims = ("scenario", "point", "axis")
        dv: dict[str, tuple] = {}
        for key, what in (("overshoot", "best-fit overshoot"),
                          ("overshoot_p2_5", "2.5 % point of the sampled overshoot"),
                          ("overshoot_p97_5", "97.5 % point of the sampled overshoot")):
            dv[key] = (dims, cube(self.scenarios, key), {"units": "m", "long_name": what})
        for key, what in (("ratio", "overshoot of the baseline / of the scenario"),
                          ("ratio_p2_5", "2.5 % point of the sampled ratio"),
                          ("ratio_p97_5", "97.5 % point of the sampled ratio")):
            dv[key] = (dims, cube(self.ratios, key), {"units": "1", "long_name": what})
        head = np.full((len(self.ratios), len(self.axes)), np.nan)
        for i, r in enumerate(self.ratios):
            for k, a in enumerate(self.axes):
                v = r.get("headline", {}).get(a)
                head[i, k] = np.nan if v is None else v
        dv["headline"] = (("scenario", "axis"), head,
                          {"units": "1", "long_name": "the paper's ratio per axis (x: M_xz, "
                                                      "y: M_yz, z: M_xz)"})
        ds = xr.Dataset(dv, coords={
            "scenario": names, "point": list(self.points), "axis": list(self.axes),
            "piezo": ("scenario", [int(s["piezo"]) for s in self.scenarios]),
            "scale_eccentricity": ("scenario",
                                   [float(s["scale_eccentricity"]) for s in self.scenarios])},
            attrs={"definition": self.definition, "baseline": names[0] if names else "",
                   "source": self.source, "samples": int(self.samples), "seed": int(self.seed),
                   "window_start": float(self.window_s[0]),
                   "window_end": float(self.window_s[1]), "rate_hz": float(self.rate_hz)})
        return ds


def window_times(window: tuple[float, float] = DEFAULT_WINDOW, rate: float = 1e6) -> np.ndarray:

    return default_times(window[0], window[1], rate)


def overshoot(disp: np.ndarray) -> np.ndarray:
    """Overshoot (..., 3) of displacements (..., 3, T): max_t |d(t) - d(t_0)|."""
    d = np.asarray(disp)
    return np.max(np.abs(d - d[..., :1]), axis=-1)


def scenario_overshoots(fm: FittedModel, sc: Scenario, times, *, points=WHATIF_POINTS,
                        samples: int = 0, seed: int = 0, voltage=None):
    """Best-fit overshoot (point, 3) and sampled overshoots (n_ok, point, 3) of a scenario.

    Samples are drawn from the baseline model and then transformed by the scenario (same
    seed across scenarios: common random numbers, so ratios are per parameter draw)."""

    fs = apply_scenario(fm, sc)
    best, _, ok = sampled_points(batch([fs.params]), times, points, piezo=sc.piezo,
                                 voltage=voltage)
    if not ok[0]:
        raise GprmInputError(f"scenario {sc.name!r} cannot be simulated", field="scenario")
    os_best = overshoot(best[0])
    os_s = np.zeros((0,) + os_best.shape)
    okm = np.zeros(0, bool)
    if samples > 0:
        sp, _, okm = sampled_points(transform_batch(fm.sample(samples, seed), sc), times,
                                    points, piezo=sc.piezo, voltage=voltage)
        os_s = overshoot(sp)
    return os_best, os_s, okm


def transform_batch(pb: dict, sc: Scenario) -> dict:
    """Apply a scenario (eccentricity scale, overrides) to a parameter batch."""

    check_scenario(sc)
    out = {k: np.array(v, float) for k, v in pb.items()}
    for n in ECCENTRICITIES:
        out[n] = out[n] * sc.scale_eccentricity
    for k, v in sc.overrides.items():
        out[k] = np.full_like(out[k], float(v))
    return out


def _table(os: np.ndarray, points) -> dict:
    return {p: {a: float(os[i, j]) for j, a in enumerate(AXES)} for i, p in enumerate(points)}


def whatif(fm: FittedModel, scenarios: Sequence[Scenario] | None = None, *,
           window: tuple[float, float] = DEFAULT_WINDOW, rate: float = 1e6,
           points: Sequence[str] = WHATIF_POINTS, samples: int = 100, seed: int = 0,
           voltage=None) -> WhatIf:
    """Overshoot table of ``scenarios`` (default: the paper's three) and their ratios to the
    first one (the baseline), with 2.5/97.5 % sampled ranges (see :class:`WhatIf`)."""
    scenarios = tuple(standard_scenarios() if scenarios is None else scenarios)
    if not scenarios:
        raise GprmInputError("no scenario given", field="scenarios")
    points = tuple(points)
    t = window_times(window, rate)
    res = []
    for sc in scenarios:
        res.append(scenario_overshoots(fm, sc, t, points=points, samples=samples, seed=seed,
                                       voltage=voltage))
    base_best, base_s, base_ok = res[0]
    out_sc, out_ratio = [], []
    for sc, (ob, os_s, ok) in zip(scenarios, res):
        entry = sc.to_json()
        entry["overshoot"] = _table(ob, points)
        if samples > 0 and ok.any():
            entry["overshoot_p2_5"] = _table(np.quantile(os_s[ok], 0.025, axis=0), points)
            entry["overshoot_p97_5"] = _table(np.quantile(os_s[ok], 0.975, axis=0), points)
        out_sc.append(entry)
        ratio = base_best / ob
        r = {"name": sc.name, "baseline": scenarios[0].name, "ratio": _table(ratio, points),
             "headline": {a: float(ratio[points.index(HEADLINE[a]), AXES.index(a)])
                          for a in AXES if HEADLINE[a] in points}}
        if samples > 0:
            both = ok & base_ok
            if both.any():
                rs = base_s[both] / os_s[both]
                r["ratio_p2_5"] = _table(np.quantile(rs, 0.025, axis=0), points)
                r["ratio_p97_5"] = _table(np.quantile(rs, 0.975, axis=0), points)
        if sc.name in PAPER_RATIOS:
            r["paper"] = PAPER_RATIOS[sc.name]
        out_ratio.append(r)
    return WhatIf(window_s=(float(window[0]), float(window[1])), rate_hz=float(rate),
                  points=points, axes=tuple(AXES), source=fm.source, samples=int(samples),
                  seed=int(seed), scenarios=tuple(out_sc), ratios=tuple(out_ratio))


def ratio_rows(table: Mapping, *, missing: str = "—") -> list[tuple[str, ...]]:
    """Rows of the what-if ratio table, one per scenario other than the baseline: its name,
    the paper's headline ratio per axis (baseline / scenario; x: M_xz, y: M_yz, z: M_xz) with
    its 2.5-97.5 % range over the drawn parameter sets in brackets where there are draws, and
    the paper's numbers (x, y, z). ``table``: a what-if document (:meth:`WhatIf.to_json`,
    ``whatif.json``); the report's table and ``gprm predict --whatif`` print these rows."""
    rows = []
    for r in table.get("ratios") or []:
        if r.get("name") == r.get("baseline"):
            continue
        cells = []
        for a in ("x", "y", "z"):
            v = (r.get("headline") or {}).get(a)
            lo = ((r.get("ratio_p2_5") or {}).get(HEADLINE[a]) or {}).get(a)
            hi = ((r.get("ratio_p97_5") or {}).get(HEADLINE[a]) or {}).get(a)
            txt = missing if v is None else f"{v:.3g}"
            if lo is not None and hi is not None:
                txt += f" [{lo:.2g}, {hi:.2g}]"
            cells.append(txt)
        paper = r.get("paper") or {}
        ptxt = ", ".join(f"{paper[a]:g}" if a in paper else missing for a in ("x", "y", "z")) \
            if paper else missing
        rows.append((str(r.get("name")), *cells, ptxt))
    return rows


def ratio_table_text(table: Mapping) -> str:
    """The what-if ratio table as text (``gprm predict --whatif``): :func:`ratio_rows` under
    a header, in aligned columns, ASCII only."""
    head = ("strategy", "x (M_xz)", "y (M_yz)", "z (M_xz)", "paper (x, y, z)")
    rows = [head, *ratio_rows(table, missing="-")]
    widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
    n = table.get("samples", 0)
    lines = ["what-if overshoot ratios, baseline (" + str(
        next((r.get("baseline") for r in table.get("ratios") or []), "?")) + ") / strategy"
        + (f"; in brackets 2.5-97.5 % over {n} drawn parameter sets" if n else "") + ":"]
    lines += ["  " + "  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
    return "\n".join(lines)


@dataclass(frozen=True)
class Sweep:
    """Best-fit overshoot as one parameter takes several values (:func:`sweep`).

    ``overshoot`` (value, point, axis) in m (NaN where the set could not be simulated,
    ``ok`` False); ``values`` in SI, ``display_values`` in the registry's unit."""

    parameter: str
    display_unit: str
    values: tuple[float, ...]
    display_values: tuple[float, ...]
    scenario: Scenario
    window: tuple[float, float]
    points: tuple[str, ...]
    axes: tuple[str, ...]
    ok: tuple[bool, ...]
    overshoot: np.ndarray

    def to_json(self) -> dict:
        """The sweep as a JSON-able table (``overshoot[point][axis]`` a list over values)."""
        os = self.overshoot
        return {"parameter": self.parameter, "unit": "SI", "display_unit": self.display_unit,
                "values": list(self.values), "display_values": list(self.display_values),
                "scenario": self.scenario.to_json(), "window_s": list(self.window),
                "definition": DEFINITION, "points": list(self.points),
                "axes": list(self.axes), "ok": list(self.ok),
                "overshoot": {p: {a: [float(x) for x in os[:, i, j]]
                                  for j, a in enumerate(self.axes)}
                              for i, p in enumerate(self.points)}}

    def to_xarray(self) -> xr.Dataset:
        """The overshoot along (value, point, axis), the swept values as coordinate."""
        return xr.Dataset(
            {"overshoot": (("value", "point", "axis"), self.overshoot,
                           {"units": "m", "long_name": "best-fit overshoot"}),
             "ok": (("value",), np.asarray(self.ok, np.int8),
                    {"units": "1", "long_name": "1 if the set could be simulated"})},
            coords={"value": ("value", np.asarray(self.values, float),
                              {"long_name": f"{self.parameter} (SI)"}),
                    "point": list(self.points), "axis": list(self.axes)},
            attrs={"parameter": self.parameter, "scenario": self.scenario.name,
                   "definition": DEFINITION})


def sweep(fm: FittedModel, name: str, values: Sequence[float], *,
          base: Scenario | None = None, window: tuple[float, float] = DEFAULT_WINDOW,
          rate: float = 1e6, points: Sequence[str] = WHATIF_POINTS, voltage=None) -> Sweep:
    """Best-fit overshoot of ``points`` as parameter ``name`` takes ``values`` (SI), on top
    of scenario ``base`` (default Piezo 2); plot with :func:`gprm.report.figures.fig_sweep`."""

    if name not in REGISTRY:
        raise GprmInputError("unknown parameter", field=name)
    vals = np.asarray(values, float)
    if vals.ndim != 1 or vals.size == 0 or not np.all(np.isfinite(vals)):
        raise GprmInputError("values must be a non-empty list of finite numbers", field=name)
    base = base or Scenario("piezo2", 2)
    points = tuple(points)
    t = window_times(window, rate)
    fs = apply_scenario(fm, base)
    sets = []
    for v in vals:
        sets.append(fs.params.with_values(**{name: float(v)}))  # validates the value
    pb = batch(sets)
    disp, _, ok = sampled_points(pb, t, points, piezo=base.piezo, voltage=voltage)
    os = overshoot(disp)
    os[~ok] = np.nan
    return Sweep(parameter=name, display_unit=REGISTRY[name].unit,
                 values=tuple(float(v) for v in vals),
                 display_values=tuple(float(from_si(v, name)) for v in vals),
                 scenario=base, window=(float(window[0]), float(window[1])), points=points,
                 axes=tuple(AXES), ok=tuple(bool(x) for x in ok), overshoot=os)


@dataclass(frozen=True)
class RatioSensitivity:
    """The headline ratios of :func:`whatif` (per scenario and axis) for the nominal model
    and with each assumed geometry value scaled by 1 - rel and 1 + rel
    (:func:`ratio_sensitivity`). ``changed[name][factor]`` is a headline table like
    ``nominal``: {scenario: {axis: ratio}}."""

    rel_change: float
    nominal: Mapping[str, Any]
    changed: Mapping[str, Mapping[str, Any]]

    def to_json(self) -> dict:
        """The JSON table: ``rel_change``, ``nominal`` and one entry per changed name, keyed
        by the factor (``x0.75``, ``x1.25``)."""
        out: dict[str, Any] = {"rel_change": self.rel_change,
                               "nominal": copy.deepcopy(dict(self.nominal))}
        out.update({n: copy.deepcopy(dict(v)) for n, v in self.changed.items()})
        return out

    def to_xarray(self) -> xr.Dataset:
        """The ratios along (case, scenario, axis); case ``nominal`` then ``<name> x<f>``."""
        cases = [("nominal", self.nominal)] + [(f"{n} {k}", tab) for n, d in
                                               self.changed.items() for k, tab in d.items()]
        scen = list(self.nominal)
        axes = sorted({a for tab in self.nominal.values() for a in tab})
        cube = np.full((len(cases), len(scen), len(axes)), np.nan)
        for i, (_, tab) in enumerate(cases):
            for j, sname in enumerate(scen):
                for k, a in enumerate(axes):
                    v = tab.get(sname, {}).get(a)
                    cube[i, j, k] = np.nan if v is None else float(v)
        return xr.Dataset({"ratio": (("case", "scenario", "axis"), cube,
                                     {"units": "1", "long_name": "headline overshoot ratio"})},
                          coords={"case": [c for c, _ in cases], "scenario": scen,
                                  "axis": axes},
                          attrs={"rel_change": self.rel_change})


def ratio_sensitivity(fm: FittedModel, names: Sequence[str] = ("h2", "dist_x", "dist_y",
                                                               "dist_z"), *,
                      rel: float = 0.25, window: tuple[float, float] = DEFAULT_WINDOW,
                      rate: float = 1e6) -> RatioSensitivity:
    """Headline ratios (Piezo 2 / Piezo 1 and Piezo 2 / Piezo 1 + eccentricities / 10) with
    each of ``names`` scaled by 1 - rel and 1 + rel: which assumed geometry values matter."""
    changed: dict[str, dict[str, Any]] = {}
    for n in names:
        changed[n] = {}
        for f in (1 - rel, 1 + rel):
            f_fm = replace(fm, params=fm.params.with_values(**{n: fm.params[n] * f}))
            changed[n][f"x{f:g}"] = _headlines(f_fm, window, rate)
    return RatioSensitivity(rel, _headlines(fm, window, rate), changed)


def _headlines(fm: FittedModel, window, rate) -> dict:
    r = whatif(fm, window=window, rate=rate, samples=0)
    return {x["name"]: x["headline"] for x in r.ratios[1:]}
