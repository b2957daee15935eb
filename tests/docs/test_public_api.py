"""The worked example (script and notebook) uses the public API only: no module whose name,
or any package on its path, starts with an underscore (gprm._io, gprm._lazy, ...)."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parents[2] / "docs"


def _sources():
    yield "worked_example.py", (DOCS / "worked_example.py").read_text(encoding="utf-8")
    nb = json.loads((DOCS / "worked_example.ipynb").read_text(encoding="utf-8"))
    code = ["".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "code"]
    yield "worked_example.ipynb", "\n\n".join(code)


def private_gprm_imports(text: str) -> list[str]:
    """The gprm modules or names imported by ``text`` that are private (a part starting with
    an underscore)."""
    bad = []
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.Import):
            mods = [a.name for a in node.names]
            names: list[str] = []
        elif isinstance(node, ast.ImportFrom) and node.module:
            mods = [node.module]
            names = [a.name for a in node.names]
        else:
            continue
        for m in mods:
            if m.split(".")[0] == "gprm" and (any(p.startswith("_") for p in m.split("."))
                                             or any(n.startswith("_") for n in names)):
                bad.append(m)
    return bad


def test_the_check_sees_private_imports():
    assert private_gprm_imports("from gprm._io import write_json_atomic") == ["gprm._io"]
    assert private_gprm_imports("import gprm.fit._x") == ["gprm.fit._x"]
    assert private_gprm_imports("from gprm.fit.files import _number") == ["gprm.fit.files"]
    assert private_gprm_imports("from gprm.io import read_json\nimport numpy._core") == []


@pytest.mark.parametrize("name, text", list(_sources()))
def test_worked_example_imports_no_private_module(name, text):
    assert private_gprm_imports(text) == [], name


@pytest.mark.parametrize("stage", ["params", "model", "simulate", "campaign", "fit", "predict",
                                   "flight", "report", "run"])
def test_every_exported_name_resolves(stage):
    """Each stage's lazily exported names (``__all__``) exist where they point: a name that
    moved to another module must leave the export list with it."""
    import importlib

    pkg = importlib.import_module(f"gprm.{stage}")
    missing = []
    for name in getattr(pkg, "__all__", ()):
        try:
            getattr(pkg, name)
        except AttributeError as exc:
            missing.append(f"{name}: {exc}")
    assert missing == []
