"""A clone is the whole project: no tracked file (text or binary: a NetCDF fixture's
attributes count too) points at the project's working folders beside the clone (the shared
data and specification folders a user's clone does not have), and the specification the docs
and the code cite is in docs/ (docs/spec.md).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# written in pieces so that this file does not match itself
OUTSIDE = ("../" + "shared", "shared" + "/spec")
#: the specification files that lived outside the repository; docs/spec.md holds their content
OUTSIDE_SPEC_FILES = tuple(n + ".md" for n in ("MODEL", "INTERFACES", "ARCHITECTURE",
                                               "contracts"))


def _tracked_text_files() -> dict[str, str]:
    """Every tracked file of this checkout as text: UTF-8 where it decodes, else its bytes
    read as Latin-1 (a binary file's strings, e.g. NetCDF attributes, stay searchable)."""
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: the tracked files are unknown")
    names = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True,
                           check=True).stdout.decode().split("\0")
    out = {}
    for name in filter(None, names):
        path = ROOT / name
        if not path.is_file():          # deleted in the working tree, not yet committed
            continue
        data = path.read_bytes()
        try:
            out[name] = data.decode("utf-8")
        except UnicodeDecodeError:
            out[name] = data.decode("latin-1")
    return out


def test_no_tracked_file_refers_to_folders_outside_the_clone():
    files = _tracked_text_files()
    # the check saw text, a benchmark and a binary fixture
    assert {"tests/fit/nist.py", "docs/README.md", "benchmarks/sim2.py",
            "tests/io/legacy/sim_v1.nc"} <= set(files)
    bad = [f"{name}:{i}: {line.strip()}" for name, text in files.items()
           for i, line in enumerate(text.splitlines(), 1) if any(s in line for s in OUTSIDE)]
    assert not bad, "references to folders outside the repository:\n" + "\n".join(bad)


def test_the_specification_is_cited_from_the_repository():
    """The docs, the code and the tests cite docs/spec.md, not the outside spec files."""
    files = _tracked_text_files()
    bad = [f"{name}:{i}: {line.strip()}" for name, text in files.items()
           for i, line in enumerate(text.splitlines(), 1)
           if any(s in line for s in OUTSIDE_SPEC_FILES)]
    assert not bad, "cite docs/spec.md instead of:\n" + "\n".join(bad)
    assert (ROOT / "docs" / "spec.md").is_file()


def test_the_nist_reference_data_ship_with_the_tests():
    import sys

    sys.path.insert(0, str(ROOT / "tests" / "fit"))
    try:
        import nist
    finally:
        sys.path.remove(str(ROOT / "tests" / "fit"))
    assert len(nist.names()) == 27
    for name in nist.names():
        path = nist.path(name)
        assert path.is_file(), path
        assert ROOT in path.resolve().parents, f"{path} is outside the repository"
    for folder in (nist.DATA_DIR, nist.EXTRA_DIR):
        readme = (folder / "README.md").read_text()
        assert "https://www.itl.nist.gov/div898/strd/" in readme
        assert "public domain" in readme
