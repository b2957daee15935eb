"""docs/worked_example.ipynb executes top to bottom in a fresh kernel and shows what it
promises: the fit report, xarray objects (HTML repr) and inline figures."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

NOTEBOOK = Path(__file__).resolve().parents[2] / "docs" / "worked_example.ipynb"

pytestmark = pytest.mark.slow


def test_worked_example_notebook_executes(tmp_path, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    out = tmp_path / "example"
    monkeypatch.setenv("GPRM_EXAMPLE_OUT", str(out))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    # the kernel imports the gprm these tests import (its cwd is tmp_path: make it absolute)
    import gprm

    root = str(Path(gprm.__file__).resolve().parents[1])
    paths = [root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(paths))
    src = NOTEBOOK.read_bytes()
    nb = nbformat.reads(src.decode("utf-8"), as_version=4)
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}}).execute()
    assert NOTEBOOK.read_bytes() == src                      # the committed file is untouched
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.output_type == "error"]
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    assert "[[Parameters]]" in text and "overshoot Piezo 2 / piezo1" in text
    assert "report: " in text
    pngs = [o for o in outputs if "image/png" in o.get("data", {})]
    assert len(pngs) == 5                     # Fig. 3, fit, waterfall, trajectories, impacts
    html = [o["data"]["text/html"] for o in outputs if "text/html" in o.get("data", {})]
    assert sum("xarray.Dataset" in h for h in html) == 3     # means, fit sidecar, prediction
    fit = json.loads((out / "fit.json").read_text())
    assert fit["starts"]["requested"] == 12
    assert 'id="fig-trajectories"' in (out / "report.html").read_text()
    assert os.environ["GPRM_EXAMPLE_OUT"] == str(out)
