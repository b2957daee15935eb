"""The report of a run directory: self-contained HTML, stable figure ids, Table 3 with units and
uncertainties, "not run" for missing stages, and a real browser rendering it."""

from __future__ import annotations

import base64
import io
import json
import re
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).parent))
import report_runfactory as runfactory  # noqa: E402
from report_browser import CHROMIUM, SKIP_REASON, check_not_blank, dump_dom, screenshot  # noqa: E402,E501

from gprm.cli import app  # noqa: E402
from gprm.report.build import FIGURE_IDS, write_report  # noqa: E402
from gprm.report.html import num, pm  # noqa: E402


@pytest.fixture(scope="module")
def partial_run(tmp_path_factory):
    """means.nc + fit.json/fit.nc + impact.json; no prediction (the report must say so)."""
    run = tmp_path_factory.mktemp("run")
    truth = runfactory.make_means(run / "means.nc")
    runfactory.make_fit(run)
    runfactory.make_impact(run / "impact.json")
    return run, truth


@pytest.fixture(scope="module")
def report_html(partial_run, tmp_path_factory):
    run, _ = partial_run
    out = tmp_path_factory.mktemp("out") / "report.html"
    write_report(run, out)
    return out


def _figure_ids_with_images(text: str) -> set[str]:
    return set(re.findall(r'<figure id="([^"]+)"><img alt="[^"]*" src="data:image/png;base64,',
                          text))


def test_sections_present_have_their_figures_missing_ones_say_not_run(report_html):
    text = report_html.read_text()
    ids = _figure_ids_with_images(text)
    expected = {"fig-campaign", "fig-fit", "fig-residuals", "fig-waterfall", "fig-masses",
                "fig-velocity-impact",
                "fig-impact-times"}
    assert expected <= ids
    # no prediction in this run: those figures are absent and their sections say "not run"
    assert not ids & {"fig-energy", "fig-trajectories", "fig-whatif-piezo1",
                      "fig-whatif-eccentricity"}
    assert re.search(r'<section id="predict">.*?not run', text, re.S)
    assert re.search(r'<section id="whatif">.*?not run', text, re.S)
    assert set(ids) <= set(FIGURE_IDS)


def test_every_embedded_image_is_a_valid_png(report_html):
    from PIL import Image

    text = report_html.read_text()
    blobs = re.findall(r'src="data:image/png;base64,([^"]+)"', text)
    assert len(blobs) >= 6
    for b in blobs:
        im = Image.open(io.BytesIO(base64.b64decode(b)))
        assert im.format == "PNG" and im.size[0] > 300 and im.size[1] > 150


def test_self_contained_no_network(report_html):
    text = report_html.read_text()
    assert "<script" not in text
    assert "<link" not in text
    # every src/href is inline data or an in-page anchor
    for attr in re.findall(r'(?:src|href)="([^"]*)"', text):
        assert attr.startswith("data:") or attr.startswith("#"), attr
    assert "url(" not in text


def test_table3_has_units_errors_truth_and_paper(partial_run, report_html):
    from gprm.params import REGISTRY, paper

    run, truth = partial_run
    text = report_html.read_text()
    m = re.search(r'<table id="table-3">(.*?)</table>', text, re.S)
    assert m, "Table 3 missing"
    rows = re.findall(r"<tr>(.*?)</tr>", m.group(1), re.S)
    head = re.findall(r"<th>(.*?)</th>", rows[0])
    assert head[:5] == ["parameter", "unit", "best fit", "95 % interval", "identified"]
    assert "synthetic truth" in head and "paper ± 1σ" in head
    body = {re.findall(r"<td>(.*?)</td>", r)[0]: re.findall(r"<td>(.*?)</td>", r)
            for r in rows[1:]}
    assert set(body) == set(paper().fitted)
    fit = json.loads((run / "fit.json").read_text())
    # m2 in grams, with its interval, and the paper's 12.4 ± 0.9 g
    m2 = body["m2"]
    assert m2[1] == "g"
    p = fit["parameters"]["m2"]
    assert float(m2[2]) == pytest.approx(p["value"] * 1e3, rel=1e-3)
    lo, hi = (float(x) for x in m2[3].strip("[]").split(", "))
    assert lo == pytest.approx(p["interval"]["lower"] * 1e3, rel=1e-3)
    assert hi == pytest.approx(p["interval"]["upper"] * 1e3, rel=1e-3)
    assert m2[4] == ("yes" if p["identified"] else "not determined")
    assert m2[head.index("paper ± 1σ")] == "12.40 ± 0.90"
    assert float(m2[head.index("synthetic truth")]) == pytest.approx(truth["m2"] * 1e3)
    inside = p["interval"]["lower"] <= truth["m2"] <= p["interval"]["upper"]
    assert m2[head.index("in interval")] == ("yes" if inside else "no")
    # every not-determined parameter says so, and none shows a small relative error
    for name, row in body.items():
        if row[4] == "not determined":
            e = fit["parameters"][name]
            assert e["identified"] is False
    assert REGISTRY["k_Ax"].unit in body["k_Ax"][1]


def test_summary_cards_and_tukey_table(report_html):
    text = report_html.read_text()
    cards = re.search(r'<div class="summary" id="summary">(.*?)</div><section', text, re.S)
    assert cards
    labels = re.findall(r'<div class="l">(.*?)</div>', cards.group(1))
    assert {"reduced χ²", "truth recovered", "Tukey test"} <= set(labels), labels
    tk = re.search(r'<table id="table-tukey">(.*?)</table>', text, re.S).group(1)
    assert len(re.findall(r"<tr>", tk)) == 1 + 15      # header + C(6, 2) pairs


def test_pm_and_num_formatting():
    assert pm(2.704, 0.067) == "2.704 ± 0.067"
    assert pm(12.4e-3, 0.9e-3, 1e3) == "12.40 ± 0.90"
    assert pm(1104e5, 7e5) == "(1.1040 ± 0.0070) × 10⁸"
    assert pm(4e-6, 3e-6) == "(4.0 ± 3.0) × 10⁻⁶"
    assert pm(1.0, None) == "1"
    assert num(1.64e6) == "1.640 × 10⁶"
    assert num(float("nan")) == "—"


def test_report_command_and_bad_input(partial_run, tmp_path):
    import shutil

    src, _ = partial_run
    run = tmp_path / "means-only"          # a partial run: the report still works
    run.mkdir()
    shutil.copy(src / "means.nc", run / "means.nc")
    before = (run / "means.nc").read_bytes()
    r = CliRunner().invoke(app, ["report", str(run), "--out", str(tmp_path / "r.html")])
    assert r.exit_code == 0, r.output
    assert (run / "means.nc").read_bytes() == before          # inputs untouched
    text = (tmp_path / "r.html").read_text()
    assert _figure_ids_with_images(text) == {"fig-campaign"}
    assert text.count("not run") >= 4                  # fit, prediction, what-ifs, flight
    r = CliRunner().invoke(app, ["report", str(tmp_path / "nope"), "--out",
                                 str(tmp_path / "x.html")])
    assert r.exit_code == 2
    empty = tmp_path / "empty"
    empty.mkdir()
    r = CliRunner().invoke(app, ["report", str(empty), "--out", str(tmp_path / "x.html")])
    assert r.exit_code == 2 and "holds none of the stage outputs" in r.output
    assert not (tmp_path / "x.html").exists()


@pytest.mark.skipif(CHROMIUM is None, reason=SKIP_REASON)
def test_report_renders_in_headless_chromium(report_html, tmp_path):
    png = tmp_path / "shot.png"
    screenshot(report_html, png)
    check_not_blank(png)
    dom = dump_dom(report_html)
    assert 'id="fig-fit"' in dom and 'id="table-3"' in dom


def test_run_time_card_leaves_out_the_report_stage(tmp_path):
    from gprm.report.build import summary_cards

    prov = {"stages": {"campaign": {"status": "ran", "seconds": 3.0},
                       "fit": {"status": "ran", "seconds": 40.0},
                       "report": {"status": "ran", "seconds": 500.0}}}
    cards = {c.label: c for c in summary_cards(tmp_path, None, prov)}
    assert cards["run time"].value == "43 s"
    assert cards["stages"].value == "3 / 3 done"       # as the terminal: the report counts


def test_identification_extras_render():
    """Profiles, identifiable combinations and strong correlations from a fit.json."""
    from gprm.report import figures as F
    from gprm.report.build import combination_rows, strong_correlations

    fit = {"parameters": {"m2": {"identified": True}, "k_Cy": {"identified": False}},
           "profiles": [{"name": "m2", "grid": [0.011, 0.012, 0.013], "chi2": [4.0, 0.0, 5.0]},
                        {"name": "k_Cy", "grid": [1e6, 7e6, 4e7], "chi2": [0.5, 0.0, None]}],
           "identifiable_combinations": [{"terms": {"k_Cy": 1.0, "k_Dy": 0.94},
                                          "form": "product of powers", "value": 1e13,
                                          "lower": 9e12, "upper": 1.1e13,
                                          "spread_vs_prior": 0.01}],
           "correlation": {"names": ["m2", "k_Cy", "k_Dy"],
                           "matrix": [[1, 0.2, 0.1], [0.2, 1, -0.995], [0.1, -0.995, 1]]}}
    fig = F.fig_profiles(fit)
    assert fig is not None and len(fig.axes) == 2
    assert F.fig_profiles({"profiles": []}) is None
    rows = combination_rows(fit)
    assert rows[0][0] == "k_Cy · k_Dy^0.94" and rows[0][2].startswith("[")
    assert strong_correlations(fit) == [["k_Cy", "k_Dy", "-0.99500"]]


def test_report_says_how_the_prediction_draws_were_put_back_on_the_data(partial_run, tmp_path):
    """fit.json's ``uncertainty.details.draws`` (gprm.fit.draws) in the identification's
    paragraph, the counts as held; a fit without it says nothing of it."""
    import json
    import shutil

    src, _ = partial_run
    run = tmp_path / "run"
    shutil.copytree(src, run)
    fit = json.loads((run / "fit.json").read_text())
    fit["uncertainty"]["details"] = {"draws": {"kept": 400, "proposed": 612,
                                               "acceptance": 0.7, "threshold": 45.6}}
    (run / "fit.json").write_text(json.dumps(fit))
    write_report(run, tmp_path / "r.html")
    text = " ".join((tmp_path / "r.html").read_text().split())
    assert "prediction draws: 400 kept of 612 proposals (70 % reproduce" in text
    write_report(src, tmp_path / "plain.html")
    assert "prediction draws" not in (tmp_path / "plain.html").read_text()
