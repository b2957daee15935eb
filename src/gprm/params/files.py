"""Parameter files (TOML, see ``docs/spec.md``) and unit handling with pint.

A value is a string with a unit (``"2.7 mm"``), a bare number in SI, or an inline table
``{ value = "12.4 g", fit = true, lower = "5 g", upper = "20 g" }``.
"""

from __future__ import annotations

import math
import os
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gprm._io import check_input_file, write_text_atomic
from gprm.errors import GprmInputError
from gprm.params.core import ParameterSet, paper, validate_values
from gprm.params.registry import NO_EXACT_SENSITIVITY, REGISTRY
from gprm.units import KNOWN, si_unit, ureg  # ureg re-exported: gprm.params.files.ureg

if TYPE_CHECKING:
    import pint


def to_si(text_or_number: Any, name: str, *, source: str = "parameters") -> float:
    """Convert a quantity for parameter ``name`` to SI, checking its dimension."""
    import pint

    spec = REGISTRY[name]
    u = ureg()
    target = u.Quantity(1.0, spec.unit)
    if isinstance(text_or_number, bool):
        raise GprmInputError("expected a number or a quantity string, got a boolean",
                             source=source, field=name)
    if isinstance(text_or_number, (int, float)):
        return float(text_or_number)
    if not isinstance(text_or_number, str):
        raise GprmInputError(f"expected a number or a quantity string, got {text_or_number!r}",
                             source=source, field=name)
    try:
        q: pint.Quantity | float = u.Quantity(text_or_number)
    except Exception as exc:
        raise GprmInputError(f"cannot parse quantity {text_or_number!r} ({exc})",
                             source=source, field=name) from None
    if not isinstance(q, pint.Quantity):  # a bare number in a string
        return float(q)
    if q.dimensionality != target.dimensionality:
        raise GprmInputError(
            f"unit of {text_or_number!r} has dimension {q.dimensionality}, expected "
            f"{target.dimensionality} (e.g. {spec.unit})", source=source, field=name)
    return float(q.to_base_units().magnitude)


def from_si(value: float, name: str) -> float:
    """Express an SI value in the parameter's display unit."""
    unit = REGISTRY[name].unit
    if unit in KNOWN:                        # the factor pint gives (tests/test_units.py)
        return value / KNOWN[unit][0]
    base = ureg().Quantity(1.0, unit).to_base_units().magnitude
    return value / base


def si_unit_strings(names) -> list[str]:
    """The SI unit of each named parameter as a UDUNITS-readable string (``1`` when
    dimensionless, ``unknown`` for a name not in the registry); used where files store
    parameter vectors, whose units vary along the parameter dimension."""
    return [(si_unit(REGISTRY[n].unit) or "1") if n in REGISTRY else "unknown" for n in names]


def read_toml(path: Path) -> dict:
    """A parameter file's TOML document; an unreadable or invalid file is an input error
    naming it."""
    src = str(path)
    check_input_file(path, what="parameter file")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise GprmInputError(f"invalid TOML ({type(exc).__name__}: {exc})",
                             source=src) from None
    except OSError as exc:
        raise GprmInputError(f"cannot be read ({exc.strerror or exc})", source=src) from None


def load_params(path: str | os.PathLike | None = None, *, base: ParameterSet | None = None) -> ParameterSet:
    """Resolve a parameter file on top of ``base`` (default: the ``paper`` set)."""
    base = paper() if base is None else base
    if path is None:
        return base
    path = Path(path)
    src = str(path)
    doc = read_toml(path)
    table = doc.get("parameters")
    if not isinstance(table, dict):
        raise GprmInputError("missing [parameters] table", source=src)
    values = dict(base.values)
    fitted = list(base.fitted)
    bounds = dict(base.bounds)
    for name, entry in table.items():
        if name not in REGISTRY:
            raise GprmInputError("unknown parameter name", source=src, field=name)
        if isinstance(entry, dict):
            extra = set(entry) - {"value", "fit", "lower", "upper"}
            if extra:
                raise GprmInputError(f"unknown key(s) {sorted(extra)}", source=src, field=name)
            if "value" not in entry:
                raise GprmInputError("missing 'value'", source=src, field=name)
            values[name] = to_si(entry["value"], name, source=src)
            if "fit" in entry:
                if not isinstance(entry["fit"], bool):
                    raise GprmInputError("'fit' must be true or false", source=src, field=name)
                if entry["fit"] and name in NO_EXACT_SENSITIVITY:
                    raise GprmInputError("cannot be fitted: the model has no exact sensitivity "
                                         "to it (it shapes the drive's input profile); give "
                                         "its value, or a measured voltage trace", source=src,
                                         field=name)
                if entry["fit"] and name not in fitted:
                    fitted.append(name)
                if not entry["fit"] and name in fitted:
                    fitted.remove(name)
            lo, hi = bounds.get(name, (REGISTRY[name].lower, REGISTRY[name].upper))
            if "lower" in entry:
                lo = to_si(entry["lower"], name, source=src)
            if "upper" in entry:
                hi = to_si(entry["upper"], name, source=src)
            for which, b in (("lower", lo), ("upper", hi)):
                if math.isnan(b):
                    raise GprmInputError(f"{which} bound is NaN; give a number (-inf or inf "
                                         "for none)", source=src, field=name)
            if lo >= hi:
                raise GprmInputError(f"lower bound {lo:g} is not below upper bound {hi:g}",
                                     source=src, field=name)
            bounds[name] = (lo, hi)
        else:
            values[name] = to_si(entry, name, source=src)
    validate_values(values, source=src)
    order = [n for n in REGISTRY if n in fitted]
    return ParameterSet(values, fitted=tuple(order),
                        bounds={k: v for k, v in bounds.items() if k in order}, source=src)


def _fmt(x: float) -> str:
    return f"{x:.10g}"


def params_to_toml(ps: ParameterSet) -> str:
    """Serialise a resolved set; loading the text back gives the same set."""
    lines = ["# gprm parameter file (values in the units shown; bare numbers would be SI)",
             "[parameters]"]
    for name, spec in REGISTRY.items():
        v = f'"{_fmt(from_si(ps.values[name], name))} {spec.unit}"'
        fit = name in ps.fitted
        entry_fit = fit != spec.fitted_by_default
        lo, hi = ps.bounds.get(name, (spec.lower, spec.upper))
        has_bounds = fit and (lo != spec.lower or hi != spec.upper)
        if entry_fit or has_bounds:
            parts = [f"value = {v}", f"fit = {'true' if fit else 'false'}"]
            if has_bounds and math.isfinite(lo):
                parts.append(f'lower = "{_fmt(from_si(lo, name))} {spec.unit}"')
            if has_bounds and math.isfinite(hi):
                parts.append(f'upper = "{_fmt(from_si(hi, name))} {spec.unit}"')
            lines.append(f"{name} = {{ {', '.join(parts)} }}")
        else:
            lines.append(f"{name} = {v}")
    return "\n".join(lines) + "\n"


def save_params(ps: ParameterSet, path: str | os.PathLike) -> None:
    write_text_atomic(path, params_to_toml(ps))


SYSTEMATICS_SIGNALS = ("x_base", "x_head", "y_base", "y_head", "z_bk")


def _nonnegative(value: Any, src: str, field: str, unit: str, example: str) -> float:
    """A number >= 0 in ``unit`` (SI, or "1" for a fraction) from a bare number (taken as
    that unit) or a quantity string (``"0.5 %"``, ``"0.1 us"``); an input error naming
    ``field`` otherwise."""
    import pint

    u = ureg()
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise GprmInputError(f"expected a number or a quantity such as {example}, got "
                             f"{value!r}", source=src, field=field)
    if isinstance(value, str):
        try:
            q: Any = u.Quantity(value.replace("%", " percent"))
        except Exception as exc:
            raise GprmInputError(f"cannot parse {value!r} ({exc})", source=src,
                                 field=field) from None
        if isinstance(q, pint.Quantity):
            if q.dimensionality != u.Quantity(1.0, unit).dimensionality:
                raise GprmInputError(f"{value!r} is not in units of {unit!r} (e.g. {example})",
                                     source=src, field=field)
            value = float(q.to(unit).magnitude)
        else:
            value = float(q)
    v = float(value)
    if not (math.isfinite(v) and v >= 0):
        raise GprmInputError(f"must be finite and >= 0, got {value!r}", source=src, field=field)
    return v


def _dimensionless(value: Any, src: str, field: str) -> float:
    return _nonnegative(value, src, field, "dimensionless", '"0.5 %"')


def _seconds(value: Any, src: str, field: str) -> float:
    return _nonnegative(value, src, field, "s", '"0.1 us"')


def read_systematics(path: str | os.PathLike | None) -> dict:
    """The ``[systematics]`` table of a parameter file: the instrument's per-channel gain
    (calibration) error and timing offset, one standard deviation each, for every channel
    (``gain``, ``timing``) and per signal (``[systematics.z_bk]``). Returns ``{"gain_sd":
    float | None, "timing_sd": float | None, "per_signal": {signal: (gain_sd, timing_sd)}}``
    (None: not stated; SI, gain as a fraction). An empty dict where the file has no table."""
    if path is None:
        return {}
    path = Path(path)
    src = str(path)
    table = read_toml(path).get("systematics")
    if table is None:
        return {}
    if not isinstance(table, dict):
        raise GprmInputError("[systematics] must be a table", source=src, field="systematics")
    out: dict[str, Any] = {"gain_sd": None, "timing_sd": None, "per_signal": {}}
    for key, value in table.items():
        field = f"systematics.{key}"
        if key == "gain":
            out["gain_sd"] = _dimensionless(value, src, field)
        elif key == "timing":
            out["timing_sd"] = _seconds(value, src, field)
        elif key in SYSTEMATICS_SIGNALS:
            if not isinstance(value, dict):
                raise GprmInputError("must be a table with gain and/or timing", source=src,
                                     field=field)
            extra = set(value) - {"gain", "timing"}
            if extra:
                raise GprmInputError(f"unknown key(s) {sorted(extra)} (expected gain, timing)",
                                     source=src, field=field)
            out["per_signal"][key] = (
                _dimensionless(value["gain"], src, field + ".gain") if "gain" in value else None,
                _seconds(value["timing"], src, field + ".timing") if "timing" in value
                else None)
        else:
            import difflib

            close = difflib.get_close_matches(key, ("gain", "timing") + SYSTEMATICS_SIGNALS, 1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise GprmInputError(f"unknown key {key!r}{hint}; expected gain, timing or a "
                                 f"signal ({', '.join(SYSTEMATICS_SIGNALS)})", source=src,
                                 field=field)
    return out
