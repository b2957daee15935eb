"""What a design evaluates: candidate measurement blocks, the cost model and the settings,
read from a TOML file with units (docs/design.md, "Candidates file"), SI inside.

A *block* is one set of runs of a ground test: a drive (piezo, voltage fraction, retraction
time factor), the laser channels measured (each in its own runs, as the campaign's ten
positions are), runs and noise runs per channel, the record's length and sample rate, the fit
window and the instrument's systematics. A *candidate* is one block that may be added to the
base campaign (the campaign the fit was made from).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from gprm.errors import GprmInputError
from gprm.fit.objective import DEFAULT_WINDOW
from gprm.options import parse_quantity

#: the five positions the model describes (Eq. 3), which ``gprm fit`` fits
MODEL_CHANNELS: tuple[str, ...] = ("x_base", "x_head", "y_base", "y_head", "z_bk")
#: the campaign positions the model does not describe (flange, linear runner laterally)
UNMODELLED_POSITIONS: tuple[str, ...] = ("x_lr", "x_fl", "z_fl", "y_fl", "y_lr")
#: named points of :func:`gprm.simulate.kinematics.named_points` a channel may sit on
NAMED_POINTS: tuple[str, ...] = ("com", "M_xz", "M_yz", "tip_edge")
BODIES: tuple[str, ...] = ("plunger", "tip", "runner")
AXES: tuple[str, ...] = ("x", "y", "z")


@dataclass(frozen=True)
class Channel:
    """One laser channel. Either one of :data:`MODEL_CHANNELS` (``body`` empty), or a point
    of ``body`` (plunger, tip, runner) at ``at`` (m, relative to the plunger's point A at the
    initial equilibrium, plunger frame) or at a named point (``point``, evaluated at the best
    fit), measured along ``axis``."""

    name: str
    body: str = ""
    at: tuple[float, float, float] | None = None
    point: str = ""
    axis: str = ""

    @property
    def is_model_output(self) -> bool:
        return not self.body


@dataclass(frozen=True)
class Block:
    """One set of runs (see the module docstring). SI: seconds, hertz, fractions."""

    channels: tuple[Channel, ...]
    drives: tuple[int, ...] = (2,)
    voltage: float = 1.0          # fraction of the nominal voltage drop V0
    retraction: float = 1.0       # factor on the retraction time constant tau_v (> 1: slower)
    runs: int = 10
    noise_runs: int = 5
    record: float = 1.5e-3        # s, record length from the trigger
    rate: float = 200e3           # Hz
    window: tuple[float, float] = DEFAULT_WINDOW
    gain_sd: float | None = None  # None: the design's systematics
    timing_sd: float | None = None

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.channels)

    def with_runs(self, runs: int) -> "Block":
        return replace(self, runs=int(runs))


@dataclass(frozen=True)
class Candidate:
    name: str
    block: Block
    note: str = ""


@dataclass(frozen=True)
class CostModel:
    """Hours of lab time. A block costs, for each drive and channel, runs x hours_per_run +
    noise_runs x hours_per_noise_run; plus hours_per_new_position for each channel not in
    the base campaign, hours_per_new_drive for each drive or voltage profile not in it, and
    the candidate's ``extra_hours``."""

    hours_per_run: float = 0.1
    hours_per_noise_run: float = 0.05
    hours_per_new_position: float = 2.0
    hours_per_new_drive: float = 4.0
    budget: float = 40.0
    max_additions: int = 3


@dataclass(frozen=True)
class DesignConfig:
    """Everything a design run depends on besides the fit."""

    candidates: tuple[Candidate, ...]
    cost: CostModel = field(default_factory=CostModel)
    base_runs: int = 10
    base_noise_runs: int = 5
    noise_white: float | None = None     # m per sample per run; None: from the fit
    variability: float | None = None     # relative run-to-run amplitude spread; None: fit
    gain_sd: float = 0.0
    timing_sd: float = 0.0
    calibrate: bool = True
    n_draws: int = 8
    seed: int = 0
    identified_threshold: float = 0.3
    exhaustive_limit: int = 5000
    extra_hours: tuple[tuple[str, float], ...] = ()

    def extra(self, name: str) -> float:
        return dict(self.extra_hours).get(name, 0.0)



#: the most samples a candidate's fit window may hold (rate x window): 40 times the default
#: campaign's 46, far beyond any interferometer campaign of this kind, and small enough that
#: the per-channel noise covariances (samples squared) stay well inside a laptop's memory
MAX_WINDOW_SAMPLES = 2000

def _five() -> tuple[Channel, ...]:
    return tuple(Channel(n) for n in MODEL_CHANNELS)


def default_candidates(window=DEFAULT_WINDOW) -> tuple[Candidate, ...]:
    """The documented default set (docs/design.md): each adds one block of 10 runs (5 noise
    runs) per channel at 200 kHz in the fit's window unless it says otherwise."""
    w = tuple(window)
    five = _five()
    return (
        Candidate("more-runs", Block(five, window=w),
                  "the five positions again, Piezo 2, 10 more runs each"),
        Candidate("piezo1", Block(five, drives=(1,), window=w),
                  "the five positions driven by Piezo 1 (separate runs)"),
        Candidate("slow-retraction", Block(five, retraction=3.0, window=w),
                  "Piezo 2 with a retraction three times slower (tau_v x 3)"),
        Candidate("fast-retraction", Block(five, retraction=1 / 3, window=w),
                  "Piezo 2 with a retraction three times faster (tau_v / 3)"),
        Candidate("half-voltage", Block(five, voltage=0.5, window=w),
                  "Piezo 2 with half the voltage drop"),
        Candidate("long-window", Block(five, record=2.0e-3, window=(w[0], 1.6e-3)),
                  "the five positions, 10 runs recorded to 2 ms, fitted to 1.6 ms"),
        Candidate("fast-sampling", Block(five, rate=1e6, window=w),
                  "the five positions, 10 runs sampled at 1 MHz"),
        Candidate("tip-xy", Block((Channel("tip_edge_x", "tip", point="tip_edge", axis="x"),
                                   Channel("tip_edge_y", "tip", point="tip_edge", axis="y")),
                                  window=w),
                  "two new lasers on the tip edge, x and y"),
        Candidate("tip-z", Block((Channel("tip_edge_z", "tip", point="tip_edge", axis="z"),),
                                 window=w), "a new laser on the tip edge along z"),
        Candidate("runner-z", Block((Channel("runner_z", "runner", at=(0.0, 0.0, 0.0),
                                             axis="z"),), window=w),
                  "a new laser on the linear runner along z (z_lr)"),
        Candidate("head-x-y-high", Block((Channel("head_x_20mm", "plunger",
                                                  at=(0.0, 0.0, 0.02), axis="x"),
                                          Channel("head_y_20mm", "plunger",
                                                  at=(0.0, 0.0, 0.02), axis="y")), window=w),
                  "two new lasers on the plunger head 20 mm above A, x and y"),
    )


def default_config(window=DEFAULT_WINDOW) -> DesignConfig:
    return DesignConfig(default_candidates(window))


# ----------------------------------------------------------------------------- TOML reader
_TOP = {"base", "cost", "noise", "systematics", "settings", "candidate", "include_defaults"}
_CAND = {"name", "note", "channels", "drive", "voltage", "retraction", "runs", "noise_runs",
         "record", "rate", "window", "gain", "timing", "extra_hours"}


def _q(value: Any, unit: str, src: str, fld: str, *, positive: bool = True,
       nonneg: bool = False) -> float:
    if isinstance(value, bool):
        raise GprmInputError(f"expected a quantity in {unit}, got {value!r}", source=src,
                             field=fld)
    try:
        if unit == "1" and isinstance(value, str) and value.strip().endswith("%"):
            v = float(value.strip()[:-1]) / 100
        elif unit == "1":
            v = float(value)
        else:
            v = parse_quantity(value, unit)
    except (TypeError, ValueError) as exc:
        raise GprmInputError(str(exc), source=src, field=fld) from None
    if not math.isfinite(v) or (positive and v <= 0) or (nonneg and v < 0):
        raise GprmInputError(f"must be finite and {'> 0' if positive else '>= 0'}, got "
                             f"{value!r}", source=src, field=fld)
    return v


def _int(value: Any, src: str, fld: str, lo: int, hi: int = 100_000) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise GprmInputError(f"expected an integer in [{lo}, {hi}], got {value!r}",
                             source=src, field=fld)
    return int(value)


def _checked_table(t, allowed: set[str], src: str, field: str) -> dict:
    """``t`` if it is a table whose keys are all in ``allowed``; else a one-line error."""
    if not isinstance(t, dict):
        raise GprmInputError("must be a table", source=src, field=field)
    extra = set(t) - allowed
    if extra:
        raise GprmInputError(f"unknown key(s) {sorted(extra)} (expected {sorted(allowed)})",
                             source=src, field=field)
    return t


def _table(doc: dict, key: str, src: str, allowed: set[str]) -> dict:
    return _checked_table(doc.get(key, {}), allowed, src, key)


def _channel(item: Any, src: str, fld: str) -> Channel:
    if isinstance(item, str):
        if item in MODEL_CHANNELS:
            return Channel(item)
        if item in UNMODELLED_POSITIONS:
            raise GprmInputError(f"position {item!r} (flange / linear runner, laterally) is "
                                 "not described by the model, so it tells nothing about its "
                                 "parameters", source=src, field=fld)
        raise GprmInputError(f"unknown position {item!r} (expected one of "
                             f"{', '.join(MODEL_CHANNELS)}, or a table with body, at or "
                             "point, axis)", source=src, field=fld)
    if not isinstance(item, dict):
        raise GprmInputError("expected a position name or a table", source=src, field=fld)
    extra = set(item) - {"name", "body", "at", "point", "axis"}
    if extra:
        raise GprmInputError(f"unknown key(s) {sorted(extra)}", source=src, field=fld)
    body = item.get("body", "plunger")
    if body not in BODIES:
        raise GprmInputError(f"body must be one of {BODIES}, got {body!r}", source=src,
                             field=f"{fld}.body")
    axis = item.get("axis")
    if axis not in AXES:
        raise GprmInputError(f"axis must be one of {AXES}, got {axis!r}", source=src,
                             field=f"{fld}.axis")
    if body == "runner" and axis != "z":
        raise GprmInputError("the model's linear runner moves along z only", source=src,
                             field=f"{fld}.axis")
    point = item.get("point", "")
    at = item.get("at")
    if (at is None) == (not point):
        raise GprmInputError("give exactly one of 'at' (three lengths) and 'point'",
                             source=src, field=fld)
    if point and point not in NAMED_POINTS:
        raise GprmInputError(f"point must be one of {NAMED_POINTS}, got {point!r}",
                             source=src, field=f"{fld}.point")
    xyz: tuple[float, float, float] | None = None
    if at is not None:
        if not isinstance(at, list) or len(at) != 3:
            raise GprmInputError("expected three lengths, e.g. [\"0 mm\", \"0 mm\", \"20 mm\"]",
                                 source=src, field=f"{fld}.at")
        a0, a1, a2 = (_q(v, "m", src, f"{fld}.at[{i}]", positive=False)
                      for i, v in enumerate(at))
        xyz = (a0, a1, a2)
    name = item.get("name") or f"{body}_{point or 'point'}_{axis}"
    if not isinstance(name, str) or name in MODEL_CHANNELS:
        raise GprmInputError(f"bad channel name {name!r}", source=src, field=f"{fld}.name")
    return Channel(name, body, xyz, point, axis)


def _block(c: dict, src: str, fld: str, window) -> Block:
    chans = c.get("channels", list(MODEL_CHANNELS))
    if not isinstance(chans, list) or not chans:
        raise GprmInputError("expected a non-empty list", source=src, field=f"{fld}.channels")
    channels = tuple(_channel(x, src, f"{fld}.channels[{i}]") for i, x in enumerate(chans))
    if len({ch.name for ch in channels}) != len(channels):
        raise GprmInputError("repeated channel", source=src, field=f"{fld}.channels")
    drive = c.get("drive", ["piezo2"])
    drive = [drive] if isinstance(drive, str) else drive
    if not isinstance(drive, list) or not drive or any(d not in ("piezo1", "piezo2")
                                                        for d in drive):
        raise GprmInputError(f"expected piezo1, piezo2 or both in a list, got {drive!r}",
                             source=src, field=f"{fld}.drive")
    drives = tuple(sorted({int(d[-1]) for d in drive}))
    rate = _q(c.get("rate", 200e3), "Hz", src, f"{fld}.rate")
    record = _q(c.get("record", 1.5e-3), "s", src, f"{fld}.record")
    w = c.get("window", list(window))
    if not isinstance(w, list) or len(w) != 2:
        raise GprmInputError("expected [start, end]", source=src, field=f"{fld}.window")
    w0, w1 = (_q(v, "s", src, f"{fld}.window", positive=False, nonneg=True) for v in w)
    if not w0 < w1 <= record * (1 + 1e-12):
        raise GprmInputError(f"needs start < end <= record ({record:g} s), got [{w0:g}, "
                             f"{w1:g}]", source=src, field=f"{fld}.window")
    if (w1 - w0) * rate < 4:
        raise GprmInputError("fewer than 4 samples in the window", source=src,
                             field=f"{fld}.window")
    if (w1 - w0) * rate > MAX_WINDOW_SAMPLES:
        raise GprmInputError(f"{(w1 - w0) * rate:.3g} samples in the fit window, more than "
                             f"the {MAX_WINDOW_SAMPLES} a design evaluates (its noise "
                             "covariances grow with their square); the largest rate for "
                             f"this window is {MAX_WINDOW_SAMPLES / (w1 - w0):.4g} Hz",
                             source=src, field=f"{fld}.rate")
    voltage = _q(c.get("voltage", 1.0), "1", src, f"{fld}.voltage")
    if voltage > 1.0 + 1e-12:
        raise GprmInputError("the drop cannot exceed the nominal voltage (100 %)",
                             source=src, field=f"{fld}.voltage")
    return Block(channels, drives, voltage,
                 _q(c.get("retraction", 1.0), "1", src, f"{fld}.retraction"),
                 _int(c.get("runs", 10), src, f"{fld}.runs", 1),
                 _int(c.get("noise_runs", 5), src, f"{fld}.noise_runs", 0),
                 record, rate, (w0, w1),
                 None if "gain" not in c else _q(c["gain"], "1", src, f"{fld}.gain",
                                                  positive=False, nonneg=True),
                 None if "timing" not in c else _q(c["timing"], "s", src, f"{fld}.timing",
                                                    positive=False, nonneg=True))


def read_design_config(path: str | Path | None, *, window=DEFAULT_WINDOW) -> DesignConfig:
    """The candidates file (docs/design.md); ``None``: the documented defaults. Every
    problem is an input error naming the file and the field."""
    if path is None:
        return default_config(window)
    from gprm._io import check_input_file
    from gprm.params.files import read_toml

    src = str(path)
    check_input_file(path, what="candidates file")
    doc = read_toml(Path(path))
    extra = set(doc) - _TOP
    if extra:
        raise GprmInputError(f"unknown table(s) {sorted(extra)} (expected {sorted(_TOP)})",
                             source=src, field=sorted(extra)[0])
    base = _table(doc, "base", src, {"runs", "noise_runs"})
    cost = _table(doc, "cost", src, {"hours_per_run", "hours_per_noise_run",
                                     "hours_per_new_position", "hours_per_new_drive",
                                     "budget", "max_additions"})
    noise = _table(doc, "noise", src, {"white", "variability"})
    syst = _table(doc, "systematics", src, {"gain", "timing"})
    sett = _table(doc, "settings", src, {"draws", "seed", "calibrate", "identified_threshold"})
    hours = {k: _q(v, "1", src, f"cost.{k}", positive=False, nonneg=True)
             for k, v in cost.items() if k != "max_additions"}
    cm = replace(CostModel(), **hours)  # type: ignore[arg-type]  # float fields only
    if "max_additions" in cost:
        cm = replace(cm, max_additions=_int(cost["max_additions"], src, "cost.max_additions",
                                            1, 20))
    items = doc.get("candidate", [])
    if not isinstance(items, list):
        raise GprmInputError("expected [[candidate]] tables", source=src, field="candidate")
    include = doc.get("include_defaults", not items)
    if not isinstance(include, bool):
        raise GprmInputError("expected true or false", source=src, field="include_defaults")
    cands = list(default_candidates(window)) if include else []
    extra_hours = []
    for i, c in enumerate(items):
        fld = f"candidate[{i}]"
        _checked_table(c, _CAND, src, fld)
        name = c.get("name")
        if not isinstance(name, str) or not name.strip():
            raise GprmInputError("every candidate needs a name", source=src,
                                 field=f"{fld}.name")
        if any(x.name == name for x in cands):
            raise GprmInputError(f"repeated candidate name {name!r}", source=src,
                                 field=f"{fld}.name")
        cands.append(Candidate(name, _block(c, src, fld, window), str(c.get("note", ""))))
        if "extra_hours" in c:
            extra_hours.append((name, _q(c["extra_hours"], "1", src, f"{fld}.extra_hours",
                                         positive=False, nonneg=True)))
    if not cands:
        raise GprmInputError("no candidates (add [[candidate]] tables or "
                             "include_defaults = true)", source=src, field="candidate")
    calibrate = sett.get("calibrate", True)
    if not isinstance(calibrate, bool):
        raise GprmInputError("expected true or false", source=src, field="settings.calibrate")
    return DesignConfig(
        tuple(cands), cm,
        _int(base.get("runs", 10), src, "base.runs", 2),
        _int(base.get("noise_runs", 5), src, "base.noise_runs", 0),
        None if "white" not in noise else _q(noise["white"], "m", src, "noise.white"),
        None if "variability" not in noise else _q(noise["variability"], "1", src,
                                                   "noise.variability", positive=False,
                                                   nonneg=True),
        _q(syst.get("gain", 0.0), "1", src, "systematics.gain", positive=False, nonneg=True),
        _q(syst.get("timing", 0.0), "s", src, "systematics.timing", positive=False,
           nonneg=True),
        calibrate,
        _int(sett.get("draws", 8), src, "settings.draws", 1, 400),
        _int(sett.get("seed", 0), src, "settings.seed", 0, 2 ** 31),
        _q(sett.get("identified_threshold", 0.3), "1", src, "settings.identified_threshold"),
        extra_hours=tuple(extra_hours))
