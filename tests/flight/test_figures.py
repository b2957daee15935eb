"""Figs. 11 and 12 from a real `gprm impact` result: readable titles, the joint estimate and
the truth drawn."""

import numpy as np
import pytest


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    """The impact result as the report reads it: written and read back by its format's home."""
    from gprm.fit.files import paper_model
    from gprm.flight import AnalysisOptions, SynthOptions, analyze
    from gprm.flight import synth_telemetry
    from gprm.flight.files import (read_impact, read_impact_curves, telemetry_from_dataset,
                                   write_impact)

    m = paper_model()
    tel = telemetry_from_dataset(synth_telemetry(m, SynthOptions(n_releases=4, seed=2)))
    res = analyze(m, tel, AnalysisOptions(n_samples=40, n_times=201))
    out = tmp_path_factory.mktemp("impact") / "impact.json"
    side = write_impact(res.to_json(), res.curves, out)
    return read_impact(out), read_impact_curves(side)


def test_fig11_titles_and_joint(result):
    import matplotlib.pyplot as plt
    from gprm.report.figures import fig_velocity_impact

    doc, cur = result
    fig = fig_velocity_impact(doc, cur, 1)
    title = fig._suptitle.get_text()
    assert title.startswith("Release R02: velocity vs impact time, one-contact 3D impact")
    j = doc["releases"][1]["joint"]
    assert f"{j['value'] * 1e3:.4f} ms" in title
    panels = [a.get_title() for a in fig.axes if a.get_title()]
    assert panels[:6] == ["v_x (x–z plane)", "v_z (x–z plane)", "ω_y (x–z plane)",
                          "v_y (y–z plane)", "v_z (y–z plane)", "ω_x (y–z plane)"]
    raw = ("vx", "vz_xz", "wy", "vy", "vz_yz", "wx", "(cf.", "{", "None")
    assert not any(r in p for r in raw for p in panels + [title])  # no raw keys / debug
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert "joint estimate, 95 % interval" in labels and "true impact time (synthetic)" in labels
    plt.close(fig)


def test_fig12_truth_and_joint(result):
    import matplotlib.pyplot as plt
    from gprm.report.figures import fig_impact_times

    doc, _ = result
    fig = fig_impact_times(doc)
    ax = fig.axes[0]
    labels = ax.get_legend_handles_labels()[1]
    assert "joint estimate (95 %)" in labels and "truth (synthetic)" in labels
    # the joint markers sit at the joint values
    line = [c for c in ax.containers if c.get_label() == "joint estimate (95 %)"][0]
    y = line.lines[0].get_ydata()
    np.testing.assert_allclose(y, [r["joint"]["value"] * 1e3 for r in doc["releases"]])
    assert "Tukey" in ax.get_title() and "joint χ²" in ax.get_title()
    plt.close(fig)
