"""Atomic writes: outputs appear whole or not at all, with the usual file mode."""

from __future__ import annotations

import os
import stat

import pytest

from gprm._io import atomic_path, write_text_atomic


def test_output_gets_the_usual_mode_not_mkstemps_private_one(tmp_path):
    old = os.umask(0o022)
    try:
        out = tmp_path / "out.txt"
        write_text_atomic(out, "x")
    finally:
        os.umask(old)
    assert stat.S_IMODE(out.stat().st_mode) == 0o644


def test_failure_leaves_the_previous_file_and_no_temporary(tmp_path):
    out = tmp_path / "out.txt"
    out.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(out) as tmp:
            tmp.write_text("half")
            raise RuntimeError("stage failed")
    assert out.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]
