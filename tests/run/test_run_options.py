"""The stage entry points' option dataclasses: validated on construction (naming the option),
one configuration shared by the commands and ``gprm run`` / ``gprm demo``, and the import
graph of the orchestration (no cycles, nothing pointing back up)."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import pytest
import typer

from gprm.campaign.api import PreprocessOptions
from gprm.campaign.preprocess import PreprocessConfig
from gprm.errors import GprmInputError
from gprm.fit.api import FitOptions
from gprm.params import ALIGNMENT_OFFSETS, paper
from gprm.predict.api import PredictOptions
from gprm.run import RunOptions

SRC = Path(__file__).resolve().parents[2] / "src" / "gprm"


@pytest.mark.parametrize("cls, kw, field", [
    (PreprocessOptions, {"align_time": -1e-3}, "align_time"),
    (PreprocessOptions, {"align_time": float("nan")}, "align_time"),
    (PreprocessOptions, {"threshold_factor": 0}, "threshold_factor"),
    (FitOptions, {"starts": 0}, "starts"),
    (FitOptions, {"starts": 2.5}, "starts"),
    (FitOptions, {"sigma": "var"}, "sigma"),
    (FitOptions, {"sampling": "sobol"}, "sampling"),
    (FitOptions, {"window": (1.2e-3, 0.97e-3)}, "window"),
    (FitOptions, {"piezo": 3}, "piezo"),
    (FitOptions, {"stall_tol": -1.0}, "stall_tol"),
    (FitOptions, {"fit_offsets": "yes"}, "fit_offsets"),
    (FitOptions, {"seed": -1}, "seed"),
    (PredictOptions, {"piezo": 3}, "piezo"),
    (PredictOptions, {"scale_eccentricity": 0.0}, "scale_eccentricity"),
    (PredictOptions, {"samples": -1}, "samples"),
    (PredictOptions, {"t_end": 0.9e-3}, "t_end"),
    (PredictOptions, {"ke_window": (1e-3, 1e-3)}, "ke_window"),
    (PredictOptions, {"gap_std": -1e-6}, "gap_std"),
    (RunOptions, {"releases": 1}, "releases"),
    (RunOptions, {"workers": -1}, "workers"),
    (RunOptions, {"fit": {"starts": 5}}, "fit"),
])
def test_bad_option_names_the_option(cls, kw, field):
    with pytest.raises(GprmInputError) as exc:
        cls(**kw)
    assert exc.value.field == field


def test_options_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        FitOptions().starts = 3


def test_one_configuration():
    """align_time 1.01 ms, alignment offsets fitted, sem weights: in the library's defaults,
    in the commands' defaults and in the demo's options."""
    assert PreprocessOptions().align_time == PreprocessConfig().align_time == 1.01e-3
    fo = FitOptions()
    assert fo.fit_offsets and fo.sigma == "sem"
    fitted = fo.parameters(paper()).fitted
    assert fitted[:len(paper().fitted)] == paper().fitted
    assert set(fitted) - set(paper().fitted) == set(ALIGNMENT_OFFSETS.values())
    assert FitOptions(fit_offsets=False).parameters(paper()).fitted == paper().fitted
    # no offset twice when the parameter file already fits them
    assert fo.parameters(fo.parameters(paper())).fitted == fitted

    demo = RunOptions.make(quick=True)
    assert demo.preprocess == PreprocessOptions()
    assert dataclasses.replace(demo.fit, starts=fo.starts, band_samples=fo.band_samples) == fo

    from gprm.cli import app

    cmds = {c.name: c for c in typer.main.get_command(app).commands.values()}
    pre = {p.name: p.default for p in cmds["preprocess"].params}
    assert pre["align_time"] == PreprocessOptions().align_time
    fit = {p.name: p.default for p in cmds["fit"].params}
    assert fit["no_fit_offsets"] is False
    for name in ("starts", "seed", "spread", "sampling", "sigma", "piezo", "chunk", "max_iter",
                 "stall_window", "stall_tol", "prune_after", "prune_factor", "band_samples",
                 "profile", "z_bk_absolute", "uncertainty", "prior_width", "boot"):
        assert fit[name] == getattr(fo, name), name
    from gprm.options import Window

    assert tuple(Window("s")(fit["window"])) == fo.window
    pred = {p.name: p.default for p in cmds["predict"].params}
    po = PredictOptions()
    for name in ("piezo", "scale_eccentricity", "t_start", "t_end", "rate", "samples", "seed",
                 "bins"):
        assert pred[name] == getattr(po, name), name
    assert (pred["ke_start"], pred["ke_end"]) == po.ke_window


def _imports(path: Path) -> set[str]:
    """Every gprm module a file imports, at the top or inside functions."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return {m for m in out if m.split(".")[0] == "gprm"}


def test_no_arrow_back_up_and_no_string_imports():
    """report never imports the run or demo packages; run never imports demo; nothing in
    run/, demo/ or report/ imports by string (importlib)."""
    for pkg, forbidden in (("report", ("gprm.run", "gprm.demo")), ("run", ("gprm.demo",))):
        for f in (SRC / pkg).glob("*.py"):
            bad = {m for m in _imports(f) if m.startswith(forbidden)}
            assert not bad, (f.name, bad)
    for pkg in ("run", "demo", "report"):
        for f in (SRC / pkg).glob("*.py"):
            assert "importlib" not in f.read_text(), f


def test_no_import_cycle_among_run_demo_report_modules():
    mods = {}
    for pkg in ("run", "demo", "report"):
        for f in (SRC / pkg).glob("*.py"):
            name = f"gprm.{pkg}" + ("" if f.stem == "__init__" else f".{f.stem}")
            mods[name] = _imports(f)
    graph = {m: {d for d in deps if d in mods and d != m} for m, deps in mods.items()}

    def reach(start):
        seen, todo = set(), [start]
        while todo:
            for d in graph[todo.pop()]:
                if d not in seen:
                    seen.add(d)
                    todo.append(d)
        return seen

    # a package's __init__ re-exporting its own modules is not a cycle of the design
    cycles = [m for m in graph if m in reach(m) and not m.endswith(("run", "demo", "report"))]
    assert not cycles


def test_a_model_without_uncertainty_is_noted():
    """FittedModel.has_uncertainty False (best fit only) gives the note 'best fit only, no
    uncertainty' with the fit's reason, which run.json and the report show; a model with
    uncertainty gives none."""
    import numpy as np

    import gprm.run.stages as st
    from gprm.fit.files import FittedModel

    notes = st.model_notes(FittedModel(paper(), None, covariance_message="singular J'J"))
    assert len(notes) == 1 and notes[0].startswith(st.NO_UNCERTAINTY)
    assert st.NO_UNCERTAINTY == "best fit only, no uncertainty" and "singular J'J" in notes[0]
    cov = np.diag(paper().paper_stderr() ** 2)
    assert st.model_notes(FittedModel(paper(), cov)) == []


def test_a_fit_without_covariance_runs_on_its_best_fit(tmp_path):
    """A fit JSON whose correlation matrix is null (singular J'J): the best-fit values, a zero
    covariance, and the note."""
    import json

    import numpy as np

    import gprm.run.stages as st
    from gprm.fit.files import load_model

    ps = paper()
    doc = {"model": "gprm-3d", "format_version": 1, "piezo": 2,
           "covariance_message": "singular J'J",
           "parameters": {n: {"value": ps.values[n] * 1.01, "fitted": n in ps.fitted}
                          for n in ps.values},
           "correlation": {"names": list(ps.fitted), "matrix": None}}
    (tmp_path / "fit.json").write_text(json.dumps(doc))
    fm = load_model(tmp_path)
    notes = st.model_notes(fm)
    assert fm.names == ps.fitted and not np.any(fm.covariance)
    assert fm.params.values["m2"] == pytest.approx(ps.values["m2"] * 1.01)
    assert len(notes) == 1 and notes[0].startswith(st.NO_UNCERTAINTY)
    assert "singular J'J" in notes[0]
