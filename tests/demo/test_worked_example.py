"""docs/worked_example.py runs as a script and leaves a run directory the report reads."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "worked_example.py"

pytestmark = pytest.mark.slow


def test_worked_example_runs(tmp_path):
    out = tmp_path / "example"
    proc = subprocess.run([sys.executable, str(EXAMPLE), str(out)], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    for name in ("campaign.nc", "means.nc", "fit.json", "fit.nc", "predict.nc", "whatif.json",
                 "telemetry.nc", "impact.json", "report.html"):
        assert (out / name).stat().st_size > 0, name
    fit = json.loads((out / "fit.json").read_text())
    assert fit["starts"]["requested"] == 12 and fit["dof"] > 0
    assert "overshoot Piezo 2 / piezo1" in proc.stdout
    assert 'id="fig-trajectories"' in (out / "report.html").read_text()
