"""Static checks of the code base, configured in pyproject.toml: ruff (lint), mypy (types)
and import-linter (the import layers: each stage imports only from the stages before it,
predict and flight are siblings, no import cycles). docs/README.md ("Checks") says how to run
them by hand.

The tools are in requirements/lock.txt (the environment scripts/test.sh and CI install); where
one is missing (the lower-bound environment of CI) its test is skipped, saying so. Every tool
runs on this checkout's src/ (PYTHONPATH), not on an installed copy, and writes no cache into
the source tree.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
ANSI = re.compile(r"\x1b\[[0-9;]*m")
LINT_IMPORTS = ("import sys; from importlinter.cli import lint_imports_command; "
                "sys.exit(lint_imports_command())")


def _need(module: str, dist: str) -> None:
    if importlib.util.find_spec(module) is None:
        pytest.skip(f"{dist} is not installed here (it is in requirements/lock.txt; the "
                    f"lower-bound environment of CI does not run the static checks)")


def _run(args: list[str], *, cwd: Path = ROOT, src: Path = SRC,
         timeout: float = 600) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(src), *filter(None, [os.environ.get("PYTHONPATH")])]),
        NO_COLOR="1", COLUMNS="200", TERM="dumb")
    proc = subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout)
    # some versions colour their report whatever NO_COLOR says
    proc.stdout, proc.stderr = (ANSI.sub("", proc.stdout), ANSI.sub("", proc.stderr))
    return proc


def _assert_clean(proc: subprocess.CompletedProcess, tool: str) -> None:
    assert proc.returncode == 0, (
        f"{tool} found problems (exit {proc.returncode}):\n{proc.stdout}\n{proc.stderr}")


def test_ruff():
    _need("ruff", "ruff")
    proc = _run(["-m", "ruff", "check", "--no-cache", "--output-format", "concise", "."])
    _assert_clean(proc, "ruff check")


def test_mypy(tmp_path):
    """About 7 s of CPU from a cold cache (the cache is this test's temporary folder)."""
    _need("mypy", "mypy")
    t0 = time.perf_counter()
    proc = _run(["-m", "mypy", "--cache-dir", str(tmp_path / "mypy-cache")])
    _assert_clean(proc, f"mypy ({time.perf_counter() - t0:.0f} s)")
    assert "Success" in proc.stdout


def test_import_layers():
    _need("importlinter", "import-linter")
    proc = _run(["-c", LINT_IMPORTS, "--no-cache"])
    _assert_clean(proc, "lint-imports")
    # it analysed this checkout, every contract of pyproject.toml, and kept them all
    n = len(_contract_names())
    assert f"Contracts: {n} kept, 0 broken." in proc.stdout, proc.stdout


def _contract_names() -> list[str]:
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())
    return [c["name"] for c in cfg["tool"]["importlinter"]["contracts"]]


def _contract(kind: str) -> str:
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())
    (name,) = [c["name"] for c in cfg["tool"]["importlinter"]["contracts"] if c["type"] == kind]
    return name


# An import added to a copy of the package, the contract it must break, and the text the
# report must show.
BREAKS = {
    "a stage imports a later one": (
        "params/core.py", "import gprm.fit.lm", "layers", "gprm.params.core -> gprm.fit.lm"),
    "predict imports flight": (
        "predict/energy.py", "import gprm.flight.tukey", "independence",
        "gprm.predict.energy -> gprm.flight.tukey"),
    "a cycle inside a stage": (
        "simulate/inputs.py", "import gprm.simulate.core", "acyclic_siblings",
        ".inputs -> .core"),
    # issue 22: a circle through a type-only import is a circle (files.py <-> result.py,
    # predict's files.py <-> core.py were two)
    "a type-only circle inside the fit": (
        "fit/files.py", "import typing\nif typing.TYPE_CHECKING:\n    import gprm.fit.result",
        "acyclic_siblings", ".result -> .files"),
    "a type-only circle inside predict": (
        "predict/prediction.py",
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
        "    from gprm.predict.core import predict",
        "acyclic_siblings", ".prediction -> .core"),
    "the fit's default path imports the generator": (
        "fit/sandwich.py", "import gprm.campaign.synth", "forbidden",
        "gprm.fit.sandwich -> gprm.campaign.synth"),
    "a new top-level module not placed in a layer": (
        "newstage.py", "import gprm.errors", "layers", "gprm.newstage"),
}


@pytest.mark.parametrize("case", list(BREAKS))
def test_import_contracts_catch_a_violation(case, tmp_path):
    """Each contract fails on a copy of the package with one bad import added: the checks
    above can fail."""
    _need("importlinter", "import-linter")
    rel, line, kind, shown = BREAKS[case]
    src = tmp_path / "src"
    shutil.copytree(SRC / "gprm", src / "gprm",
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    target = src / "gprm" / rel
    text = target.read_text() if target.exists() else '"""Injected by a test."""\n'
    target.write_text(text + f"\n{line}  # injected by the test\n")
    shutil.copy(ROOT / "pyproject.toml", tmp_path)   # the contracts, found in the cwd
    proc = _run(["-c", LINT_IMPORTS, "--no-cache"], cwd=tmp_path, src=src)
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0, out
    assert re.search(re.escape(_contract(kind)) + r"\s*BROKEN", out), out
    assert shown in out, out
