"""The stage-by-stage recipe of docs/README.md, run end to end as written (in-process).

The bash block is read from the documentation, so the test fails when the docs and the
commands drift apart. Only ``--starts`` is lowered (to keep the test under a minute); every
other option is the documented one.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
from typer.testing import CliRunner

from gprm.cli import app

DOC = Path(__file__).parents[2] / "docs" / "README.md"


def recipe_commands() -> list[list[str]]:
    text = DOC.read_text(encoding="utf-8")
    block = re.search(r"A run directory can also be made with the stage commands.*?```bash\n"
                      r"(.*?)```", text, re.S).group(1)
    cmds = []
    for line in block.splitlines():
        line = line.split("#", 1)[0].strip()
        if line.startswith("gprm "):
            cmds.append(shlex.split(line)[1:])
    return cmds


def test_the_recipe_is_found_and_covers_the_chain():
    cmds = recipe_commands()
    firsts = [c[0] if c[0] != "synth" else " ".join(c[:2]) for c in cmds]
    for stage in ("synth campaign", "preprocess", "fit", "predict", "synth telemetry", "impact",
                  "report"):
        assert stage in firsts


@pytest.mark.slow
def test_the_docs_recipe_runs_end_to_end(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("GPRM_LOG_DIR", str(tmp_path / "logs"))
    R = "my-run"
    Path(R).mkdir()
    for argv in recipe_commands():
        argv = [a.replace("$R", R) for a in argv]
        if argv[0] == "fit":
            i = argv.index("--starts")
            argv[i + 1] = "20"
            argv += ["--workers", "0"]
        r = CliRunner().invoke(app, argv)
        assert r.exit_code == 0, f"gprm {' '.join(argv)}\n{r.output}"
        assert "Traceback" not in r.output
    for name in ("campaign.nc", "means.nc", "fit.json", "fit.nc", "predict.nc", "whatif.json",
                 "telemetry.nc", "impact.json", "impact.nc", "report.html"):
        assert (Path(R) / name).is_file(), name
