"""Issue 23's report sections: Fig. 5 right (the mean voltage of the campaign's voltage runs
with its spread) and the impact scenarios' section only when impact.json has them."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from gprm.report.scenarios import fig_voltage, scenario_section, voltage_section


def _campaign(path, volt=True):
    t = np.arange(50) * 1e-6
    rng = np.random.default_rng(0)
    v = 100 * np.exp(-t / 2e-5)[None, :] + rng.normal(0, 0.5, (8, 50))
    ds = xr.Dataset({"voltage": (("vrun", "vtime"), v)} if volt else {},
                    coords={"vtime": t} if volt else {})
    ds.to_netcdf(path)
    return v


def test_fig5_right_shows_the_runs_mean_and_spread(tmp_path):
    v = _campaign(tmp_path / "campaign.nc")
    with xr.open_dataset(tmp_path / "campaign.nc") as camp:
        fig = fig_voltage(camp.load())
    ax = fig.axes[0]
    mean_line = [ln for ln in ax.get_lines() if "mean of 8 runs" in ln.get_label()][0]
    np.testing.assert_allclose(mean_line.get_ydata(), v.mean(0))
    np.testing.assert_allclose(mean_line.get_xdata(), np.arange(50) * 1e-3)   # ms
    bands = ax.collections
    assert len(bands) == 2                              # ±σ and the 2.5–97.5 % range
    s = voltage_section(tmp_path)
    assert s is not None and "fig-voltage" in "".join(s.blocks)
    assert f"{v.mean(0)[0]:.1f} V" in "".join(s.blocks)


def test_voltage_section_without_runs_or_campaign(tmp_path):
    assert voltage_section(tmp_path) is None            # no campaign file: no section
    _campaign(tmp_path / "campaign.nc", volt=False)
    s = voltage_section(tmp_path)
    assert "not run" in "".join(s.blocks)


def test_voltage_section_refuses_a_campaign_file_that_is_not_netcdf(tmp_path):
    """A run folder's campaign.nc that is not NetCDF (the user's own file) is an input error
    naming it, as every NetCDF input is, not an internal error from xarray."""
    from gprm.errors import GprmInputError

    (tmp_path / "campaign.nc").write_text("my campaign")
    with pytest.raises(GprmInputError) as e:
        voltage_section(tmp_path)
    assert "campaign.nc" in str(e.value)


def test_no_scenario_section_without_scenarios():
    assert scenario_section(None) is None
    assert scenario_section({"releases": []}) is None


def test_scenario_summary_line_counts_the_papers_observations():
    """The console summary's scenario line: the jointly chosen scenario with its probability
    and, over the releases, how many show each of the paper's three observations."""
    from gprm.report.summary import scenario_text

    sc = {"joint": {"chosen": "two", "probability": {"two": 0.98, "xz": 0.02}},
          "observations": {"releases": [
              {"z_not_largest": True, "xz_almost_all": True, "all_non_compliant": True},
              {"z_not_largest": False, "xz_almost_all": True, "all_non_compliant": False},
              {"z_not_largest": True, "xz_almost_all": False, "all_non_compliant": True}]}}
    assert scenario_text(sc) == ("two (probability 0.98); z not the largest in 2/3, momentum "
                                 "almost all in x–z in 2/3, every component but ω_z "
                                 "non-compliant in 2/3")
    assert scenario_text({"joint": {"chosen": "xz"}}) == "xz"
