"""The file-boundary schemas (gprm.validate) and the readers' robustness, property-based.

Properties: a well-formed dataset passes and comes back in SI units whatever unit prefix the
file uses; each single defect (NaN, reversed or repeated time, text where numbers belong,
wrong dimensions, an unknown or wrong-dimension unit, a bad attribute) is refused with a
GprmInputError naming that field; arbitrary bytes given to any text reader (CSV campaign
files and manifests, voltage CSV, TOML parameters, JSON) end in a GprmInputError or a valid
result, never in another exception.
"""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gprm.errors import GprmInputError
from gprm.validate import MEANS, check_dataset

SETTINGS = settings(max_examples=40, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])

TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "nm": 1e-9}


def means_ds(n_sig, n_t, dt, t_unit, y_unit, seed):
    rng = np.random.default_rng(seed)
    t = np.arange(n_t) * dt
    ds = xr.Dataset({"mean": (("signal", "time"), rng.standard_normal((n_sig, n_t)),
                              {"units": y_unit}),
                     "sem": (("signal", "time"), rng.uniform(0.1, 1, (n_sig, n_t)),
                             {"units": y_unit})},
                    coords={"signal": [f"s{i}" for i in range(n_sig)],
                            "time": ("time", t, {"units": t_unit})})
    return ds


means_args = dict(n_sig=st.integers(1, 5), n_t=st.integers(2, 40),
                  dt=st.floats(1e-3, 10, allow_nan=False), t_unit=st.sampled_from(sorted(TIME_UNITS)),
                  y_unit=st.sampled_from(sorted(LENGTH_UNITS)), seed=st.integers(0, 2**32 - 1))


@SETTINGS
@given(**means_args)
def test_valid_means_pass_and_come_back_in_si(n_sig, n_t, dt, t_unit, y_unit, seed):
    ds = means_ds(n_sig, n_t, dt, t_unit, y_unit, seed)
    out = check_dataset(ds, MEANS, "m.nc")
    np.testing.assert_allclose(out["time"].values, ds["time"].values * TIME_UNITS[t_unit],
                               rtol=1e-12)
    np.testing.assert_allclose(out["mean"].values, ds["mean"].values * LENGTH_UNITS[y_unit],
                               rtol=1e-12)
    assert out["time"].attrs["units"] == "s" and out["mean"].attrs["units"] == "m"
    # the input is not modified
    assert ds["time"].attrs["units"] == t_unit


DEFECTS = {
    "nan in mean": ("mean", lambda ds: ds["mean"].values.__setitem__((0, 0), np.nan)),
    "inf in sem": ("sem", lambda ds: ds["sem"].values.__setitem__((0, -1), np.inf)),
    "reversed time": ("time", None),
    "negative sem": ("sem", lambda ds: ds["sem"].values.__setitem__((0, 0), -1.0)),
    "time in volts": ("time", lambda ds: ds["time"].attrs.__setitem__("units", "V")),
    "unknown unit": ("mean", lambda ds: ds["mean"].attrs.__setitem__("units", "furlongz")),
    "numeric units": ("mean", lambda ds: ds["mean"].attrs.__setitem__("units", 3)),
}


@SETTINGS
@given(**means_args, defect=st.sampled_from(sorted(DEFECTS)))
def test_each_defect_is_refused_naming_its_field(n_sig, n_t, dt, t_unit, y_unit, seed, defect):
    ds = means_ds(n_sig, n_t, dt, t_unit, y_unit, seed)
    field, mutate = DEFECTS[defect]
    if defect == "reversed time":
        ds = ds.assign_coords(time=("time", ds["time"].values[::-1],
                                    {"units": t_unit}))
    else:
        mutate(ds)
    with pytest.raises(GprmInputError) as e:
        check_dataset(ds, MEANS, "m.nc")
    assert e.value.field == field and e.value.source == "m.nc"


@SETTINGS
@given(**means_args)
def test_text_and_wrong_dimensions_are_refused(n_sig, n_t, dt, t_unit, y_unit, seed):
    ds = means_ds(n_sig, n_t, dt, t_unit, y_unit, seed)
    bad = ds.copy()
    bad["mean"] = (("signal", "time"), np.full(ds["mean"].shape, "x", dtype=object))
    with pytest.raises(GprmInputError, match="real numbers") as e:
        check_dataset(bad, MEANS, "m.nc")
    assert e.value.field == "mean"
    bad = ds.copy()
    bad["mean"] = ("time", ds["mean"].values[0])
    with pytest.raises(GprmInputError, match="dimensions") as e:
        check_dataset(bad, MEANS, "m.nc")
    assert e.value.field == "mean"
    with pytest.raises(GprmInputError, match="missing") as e:
        check_dataset(ds.drop_vars("mean"), MEANS, "m.nc")
    assert e.value.field == "mean"
    if n_sig > 1:
        dup = ds.assign_coords(signal=["s0"] * n_sig)
        with pytest.raises(GprmInputError, match="repeated") as e:
            check_dataset(dup, MEANS, "m.nc")
        assert e.value.field == "signal"


@pytest.fixture(scope="module")
def campaign_file(tmp_path_factory):
    from gprm.campaign.synth import SynthConfig, synth_campaign

    ds = synth_campaign(seed=3, config=SynthConfig(n_runs=2, n_noise=1, nonlinear=False))
    path = tmp_path_factory.mktemp("camp") / "c.nc"
    ds.to_netcdf(path)
    return path


@pytest.mark.parametrize("mutate, field", [
    (lambda ds: ds.assign_coords(time=("time", ds["time"].values * 1e3, {"units": "ms"})),
     None),                                                       # valid: ms converted
    (lambda ds: ds.assign_coords(time=("time", ds["time"].values * 1e3)), "sample_rate"),
    (lambda ds: ds.assign_coords(time=("time", ds["time"].values[::-1])), "time"),
    (lambda ds: ds.assign_attrs(sample_rate="fast"), "sample_rate"),
    (lambda ds: ds.assign_attrs(sample_rate=-1.0), "sample_rate"),
    (lambda ds: ds.assign(displacement=ds["displacement"].transpose("run", "position", "time")),
     "displacement"),
])
def test_campaign_files(campaign_file, tmp_path, mutate, field):
    """Time in ms is honoured; time in ms without units disagrees with the sample rate;
    reversed time, a text or negative sample rate and swapped dimensions are refused."""
    from gprm.campaign.files import load_campaign

    with xr.open_dataset(campaign_file) as ds0:
        ds0 = ds0.load()
    path = tmp_path / "bad.nc"
    mutate(ds0).to_netcdf(path)
    before = path.read_bytes()
    if field is None:
        ds = load_campaign(path)
        np.testing.assert_allclose(ds["time"].values, ds0["time"].values, rtol=1e-12)
    else:
        with pytest.raises(GprmInputError) as e:
            load_campaign(path)
        assert e.value.field == field, str(e.value)
    assert path.read_bytes() == before


# ----------------------------------------------------------------------------- fuzzed readers

def _readers():
    from gprm._io import read_json
    from gprm.campaign.files import read_campaign_dir
    from gprm.params import load_params
    from gprm.simulate import read_voltage_csv

    def manifest(path):
        d = path.parent / "dir"
        d.mkdir(exist_ok=True)
        (d / "manifest.csv").write_bytes(path.read_bytes())
        return read_campaign_dir(d)

    def data_csv(path):
        d = path.parent / "dir2"
        d.mkdir(exist_ok=True)
        (d / "manifest.csv").write_text("position,kind,run,file\nM_xz,actuated,0,a.csv\n")
        (d / "a.csv").write_bytes(path.read_bytes())
        return read_campaign_dir(d)

    return {"json": read_json, "toml": load_params, "voltage": read_voltage_csv,
            "manifest": manifest, "data_csv": data_csv}


READERS = _readers()
text_like = st.one_of(
    st.binary(max_size=300),
    st.text(max_size=300).map(lambda s: s.encode("utf-8", "replace")),
    st.lists(st.tuples(st.floats(allow_nan=True, allow_infinity=True), st.floats()),
             max_size=20).map(lambda rows: "\n".join(f"{a},{b}" for a, b in rows).encode()),
    st.sampled_from([b"\xff\xfe\x00\x00", b"a,b\n1,2\n\x00\x01", b"[parameters]\nk_Ax = 0\n",
                     b"[parameters]\nk_Ax = 'abc'\n", b'{"a": [[[[' * 50, b"time,v\n1,2\n0,3\n",
                     b"position,kind,run,file\nM_xz,actuated,x,a.csv\n",
                     b"position,kind,run,file\nM_xz,actuated,0,/\n"]),
)


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(reader=st.sampled_from(sorted(READERS)), data=text_like)
def test_any_bytes_give_a_result_or_one_input_error(tmp_path_factory, reader, data):
    path = tmp_path_factory.mktemp("fuzz") / "input"
    path.write_bytes(data)
    try:
        READERS[reader](path)
    except GprmInputError as exc:
        assert "\n" not in str(exc) or reader == "json"
        assert exc.source is not None
    assert path.read_bytes() == data


@pytest.mark.parametrize("reader", ["json", "toml", "voltage"])
def test_a_folder_is_not_a_file(tmp_path, reader):
    with pytest.raises(GprmInputError, match="folder"):
        READERS[reader](tmp_path)
