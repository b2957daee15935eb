"""CLI: ``gprm design`` (a thin layer over :func:`gprm.design.core.run_design`)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from gprm.console import one_line_errors


def summary_text(doc: dict) -> str:
    """The ranking table the command prints (from design.json's document)."""
    lines = [f"{'rank':>4}  {'candidate':<16} {'hours':>6} {'release x':>9} "
             f"{'overshoot x':>11} {'velocity x':>10}  newly identified"]
    by = {c["name"]: c for c in doc["candidates"]}
    for i, name in enumerate(doc["ranking"], 1):
        c = by[name]
        g = c["gain"]
        lines.append(f"{i:>4}  {name:<16} {c['hours']:>6.1f} {g['release']:>9.2f} "
                     f"{g.get('overshoot', 1):>11.2f} {g.get('velocity', 1):>10.2f}  "
                     f"{', '.join(c['newly_identified']) or '-'}")
    r = doc["recommended"]
    lines.append(f"recommended within {doc['cost_model']['budget_hours']:g} h "
                 f"({r['selection']}): {' + '.join(r['additions']) or 'nothing'}; "
                 f"{r['hours']:.1f} h; release predictions' sd / {r['gain'].get('release', 1):.2f}")
    lines.append("y-plane springs: " + doc["y_springs"]["text"])
    return "\n".join(lines)


def register(app: typer.Typer, synth_app: typer.Typer) -> None:
    @app.command("design")
    @one_line_errors
    def design_cmd(
        fit: str = typer.Argument(..., help="fit result JSON, a run folder, or 'paper'"),
        out: Path = typer.Option(..., "--out", help="output design JSON"),
        candidates: Optional[Path] = typer.Option(None, "--candidates",
                                                  help="candidates TOML (default: the "
                                                       "documented set, docs/design.md)"),
    ):
        """Rank candidate ground-test additions by what they would determine."""
        from gprm._io import check_outputs
        from gprm.design.core import run_design
        from gprm.design.files import design_document
        from gprm._io import write_json_atomic
        from gprm.fit.files import model_inputs

        check_outputs({out: "--out"}, inputs=[*model_inputs(fit), candidates])
        res = run_design(fit, candidates_path=candidates)
        doc = design_document(res)
        write_json_atomic(out, doc)
        typer.echo(summary_text(doc))
        typer.echo(f"wrote {out} ({res.timings['total']:.1f} s)")
