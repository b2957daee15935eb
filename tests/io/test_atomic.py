"""Atomic writes: outputs appear whole or not at all, with the usual file mode."""

from __future__ import annotations

import errno
import os
import stat

import pytest

from gprm._io import atomic_path, atomic_paths, remove_stale_temps, write_text_atomic
from gprm.errors import GprmOutputError


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


def test_files_written_together_replace_nothing_unless_all_are_written(tmp_path):
    """A JSON and its sidecar (atomic_paths): the disk filling while the second is written
    leaves both previous files as they were, and no temporary file."""
    side, doc = tmp_path / "fit.nc", tmp_path / "fit.json"
    side.write_text("old sidecar")
    doc.write_text("old json")
    with pytest.raises(GprmOutputError, match="no space left") as e:
        with atomic_paths([side, doc]) as (t_side, t_doc):
            t_side.write_text("new sidecar")
            raise OSError(errno.ENOSPC, "No space left on device", str(t_doc))
    assert e.value.source == str(doc)
    assert side.read_text() == "old sidecar" and doc.read_text() == "old json"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fit.json", "fit.nc"]
    with atomic_paths([side, doc]) as (t_side, t_doc):
        t_side.write_text("new sidecar")
        t_doc.write_text("new json")
    assert side.read_text() == "new sidecar" and doc.read_text() == "new json"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fit.json", "fit.nc"]


def test_files_named_like_old_temporaries_are_not_removed(tmp_path):
    """Nothing in `.NAME.XXXXXXXX.part` says gprm made it (gprm 0.1.0's temporaries had no
    PID): such files are the user's as far as gprm can tell, and stay."""
    mine = [tmp_path / ".report.html.mydraft1.part", tmp_path / ".means.nc.notes_v2.part"]
    for p in mine:
        p.write_text("draft")
    assert remove_stale_temps(tmp_path) == []
    assert all(p.read_text() == "draft" for p in mine)


def test_a_failed_write_in_a_group_names_its_own_file(tmp_path, monkeypatch):
    """write() errors carry no file name: write_text_to gives them the temporary path, so
    the message names the file whose write failed, not the group's first."""
    from gprm._io import write_text_to

    side, doc = tmp_path / "i.nc", tmp_path / "i.json"

    def full(self, *a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(GprmOutputError) as e:
        with atomic_paths([side, doc]) as (t_side, t_doc):
            t_side.write_text("curves")
            monkeypatch.setattr(type(t_doc), "write_text", full)   # the disk fills now
            write_text_to(t_doc, "{}")
    monkeypatch.undo()
    assert e.value.source == str(doc)
