"""docs/spec.md states the parameter values the code uses: its Table 3 rows (best fit,
initial value, unit), its constants and its assumed values equal the registry's."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from gprm.params import REGISTRY, from_si
from gprm.params.registry import FITTED_DEFAULT

SPEC = Path(__file__).resolve().parents[2] / "docs" / "spec.md"


def _number(text: str) -> float:
    return float(text.replace("−", "-"))


def _section(title: str) -> str:
    text = SPEC.read_text(encoding="utf-8")
    start = text.index(f"### {title}")
    end = text.find("\n#", start + 1)
    return text[start:end]


def _same_unit(doc_unit: str, registry_unit: str) -> bool:
    return doc_unit.replace(" ", "*") == registry_unit or doc_unit == registry_unit


def test_the_table_3_rows_are_the_registry():
    rows = re.findall(r"^\| (\w+) \| ([^|]+) \| ([^|]+) \| ([^|]+) \|",
                      _section("Fitted by default (Table 3)"), flags=re.M)
    rows = [r for r in rows if r[0] in REGISTRY]
    assert [r[0] for r in rows] == list(FITTED_DEFAULT)
    for name, best, initial, unit in rows:
        spec = REGISTRY[name]
        assert _same_unit(unit.strip(), spec.unit), (name, unit, spec.unit)
        assert _number(best) == pytest.approx(from_si(spec.default, name), rel=1e-12), name
        assert _number(initial) == pytest.approx(from_si(spec.initial, name), rel=1e-12), name


def test_the_constants_and_assumed_values_are_the_registry():
    consts = dict(re.findall(r"(\w+) = ([-0-9.e]+)", _section("Constants (Table 2)")))
    assert set(consts) == {n for n, s in REGISTRY.items() if s.group == "constant"}
    for name, value in consts.items():
        assert float(value) == pytest.approx(REGISTRY[name].default, rel=1e-12), name
    assumed = _section("Assumed values (the paper does not give them)")
    rows = {name: value for names, value in
            re.findall(r"^\| ([\w, ]+) \| ([^|]+) \|", assumed, flags=re.M)
            for name in names.split(", ")}
    shown = {"h2": (30, "mm"), "d_x_base": (25, "mm"), "d_y_base": (25, "mm"),
             "d_x_head": (58, "mm"), "d_y_head": (58, "mm"), "dist_x": (4, "mm"),
             "dist_y": (4, "mm"), "dist_z": (29, "mm"), "indent_angle": (45, "deg")}
    for name, (value, unit) in shown.items():
        assert rows[name].strip() == (f"{value}°" if unit == "deg" else f"{value} {unit}")
        assert REGISTRY[name].unit == unit, name
        assert from_si(REGISTRY[name].default, name) == pytest.approx(value, rel=1e-12), name
    assert {n for n, s in REGISTRY.items() if s.group == "geometry"} <= set(rows)
