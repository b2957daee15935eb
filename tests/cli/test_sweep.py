"""A sweep of malformed inputs and options over every command (issue #13).

Each case runs the command in-process and asserts what a user must see: exit code 2, exactly
one line on the console naming the file or the option, no traceback, nothing written in the
working folder, and every input byte-for-byte unchanged.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from gprm.cli import app

sys.path.insert(0, str(Path(__file__).parents[1] / "fit"))
from means_factory import make_means  # noqa: E402


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """Valid and broken input files, made once; each test copies them into its own folder."""
    from gprm.campaign.files import write_campaign_dir
    from gprm.campaign.synth import SynthConfig, synth_campaign
    from gprm.params import paper

    d = tmp_path_factory.mktemp("sweep-inputs")
    make_means(paper(), seed=1).to_netcdf(d / "m.nc")
    camp = synth_campaign(seed=3, config=SynthConfig(n_runs=2, n_noise=1, nonlinear=False))
    camp.to_netcdf(d / "c.nc")
    camp.assign_attrs(sample_rate="fast").to_netcdf(d / "c_text_rate.nc")
    camp.assign_coords(time=("time", camp["time"].values[::-1])).to_netcdf(d / "c_reversed.nc")
    write_campaign_dir(camp, d / "csv")
    (d / "binary.nc").write_bytes(bytes(range(256)) * 4)
    (d / "latin1.csv").write_bytes("time,V\n0,1\n1e-3,2\n\xe9\n".encode("latin-1"))
    (d / "p.toml").write_text("[parameters]\n")
    (d / "bad.toml").write_bytes(b"\x00\x01[parameters")
    (d / "ms.nc").write_bytes(b"")          # an empty file where a NetCDF belongs
    (d / "folder").mkdir()
    (d / "userdir").mkdir()
    (d / "userdir" / "keep.txt").write_text("user data")
    (d / "afile").write_text("not a folder")
    # issue 22: a fit's sidecar is an input too; attributes of the wrong type; a NaN bound
    (d / "fit.json").write_text("{}")
    (d / "fit.nc").write_bytes(b"the fit's sidecar")
    (d / "run").mkdir()
    (d / "run" / "fit.json").write_text("{}")
    (d / "run" / "fit.nc").write_bytes(b"the run's fit sidecar")
    camp.assign_attrs(seed="x").to_netcdf(d / "c_text_seed.nc")
    make_means(paper(), seed=1).assign_attrs(align_time="late").to_netcdf(d / "m_text_align.nc")
    from gprm.flight.synth import SynthOptions, synth_telemetry
    from gprm.fit.files import paper_model

    tel = synth_telemetry(paper_model(2), SynthOptions(n_releases=2))
    tel.assign_attrs(format_version="one").to_netcdf(d / "t_text_version.nc")
    (d / "nan.toml").write_text('[parameters]\nk_lr = { value = 1.0, lower = nan, '
                                "fit = true }\n")
    return d


def _snapshot(root: Path) -> dict:
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob("*"))}


def _csv_broken_manifest(d: Path):
    (d / "csv" / "manifest.csv").write_bytes(b"\xff\xfe\x00p\x00o\x00s")


def _csv_binary_data(d: Path):
    data = sorted((d / "csv" / "x_head").rglob("*.csv"))[0]
    data.write_bytes(b"\x00\x01\x02" * 100)


def _edit_manifest(d: Path, edit):
    m = d / "csv" / "manifest.csv"
    m.write_text(edit(m.read_text()))


def _manifest_units(d: Path):
    """issue 22: a header ``units`` was ignored and micrometres read as metres."""
    _edit_manifest(d, lambda t: t.replace(",unit\n", ",units\n", 1).replace(",m\n", ",um\n"))


def _manifest_gain(d: Path):
    lines = (d / "csv" / "manifest.csv").read_text().splitlines()
    _edit_manifest(d, lambda t: "\n".join([lines[0] + ",gain"] + [ln + ",2" for ln in lines[1:]])
                   + "\n")


def _manifest_row_to(d: Path, name: str):
    lines = (d / "csv" / "manifest.csv").read_text().splitlines()
    first = lines[1].split(",")
    (d / "outside").mkdir(exist_ok=True)
    (d / "outside" / "x.csv").write_text((d / "csv" / first[3]).read_text()
                                         + "secret-token-in-a-foreign-file,1\n")
    first[3] = name
    _edit_manifest(d, lambda t: "\n".join([lines[0], ",".join(first)] + lines[2:]) + "\n")


def _manifest_symlink(d: Path):
    _manifest_row_to(d, "x_lr/link.csv")
    (d / "csv" / "x_lr" / "link.csv").symlink_to(d / "outside" / "x.csv")


CASES = [
    # (id, argv, text expected in the line, setup)
    ("fit-seed", ["fit", "m.nc", "--out", "f.json", "--seed", "-1"], "--seed", None),
    ("fit-max-iter", ["fit", "m.nc", "--out", "f.json", "--max-iter", "-1"], "--max-iter", None),
    ("fit-band-samples", ["fit", "m.nc", "--out", "f.json", "--band-samples", "-1"],
     "--band-samples", None),
    ("fit-starts-huge", ["fit", "m.nc", "--out", "f.json", "--starts", "100000000"],
     "largest value that fits", None),
    ("fit-window", ["fit", "m.nc", "--out", "f.json", "--window", "1.2ms,0.9ms"], "--window",
     None),
    ("fit-spread", ["fit", "m.nc", "--out", "f.json", "--spread", "nan"], "--spread", None),
    ("fit-sidecar-over-input", ["fit", "m.nc", "--out", "m.json"], "m.nc", None),
    ("fit-out-is-input", ["fit", "m.nc", "--out", "m.nc"], "--out", None),
    ("fit-folder-input", ["fit", "folder", "--out", "f.json"], "folder", None),
    ("fit-folder-out", ["fit", "m.nc", "--out", "folder"], "--out folder", None),
    ("fit-out-under-file", ["fit", "m.nc", "--out", "afile/f.json"], "--out", None),
    ("fit-binary-means", ["fit", "binary.nc", "--out", "f.json"], "binary.nc", None),
    ("fit-empty-means", ["fit", "ms.nc", "--out", "f.json"], "ms.nc", None),
    ("fit-campaign-as-means", ["fit", "c.nc", "--out", "f.json"], "c.nc", None),
    ("fit-user-checkpoint", ["fit", "m.nc", "--out", "f.json", "--checkpoint", "userdir"],
     "--checkpoint userdir: exists and is not a gprm checkpoint folder", None),
    ("fit-checkpoint-file", ["fit", "m.nc", "--out", "f.json", "--checkpoint", "afile"],
     "--checkpoint afile: is a file", None),
    ("fit-checkpoint-dot", ["fit", "m.nc", "--out", "f.json", "--checkpoint", "."],
     "--checkpoint", None),
    ("fit-params-folder", ["fit", "m.nc", "--out", "f.json", "--params", "folder"], "folder",
     None),
    ("fit-workers-huge", ["fit", "m.nc", "--out", "f.json", "--workers", "1000000"],
     "--workers", None),
    ("fit-scheduler", ["fit", "m.nc", "--out", "f.json", "--scheduler", "not an address"],
     "--scheduler", None),
    ("fit-sampling", ["fit", "m.nc", "--out", "f.json", "--sampling", "sobol"], "--sampling",
     None),
    ("preprocess-over-input", ["preprocess", "c.nc", "--out", "c.nc"], "--out", None),
    ("preprocess-text-rate", ["preprocess", "c_text_rate.nc", "--out", "x.nc"], "sample_rate",
     None),
    ("preprocess-reversed", ["preprocess", "c_reversed.nc", "--out", "x.nc"], "time", None),
    ("preprocess-binary", ["preprocess", "binary.nc", "--out", "x.nc"], "binary.nc", None),
    ("preprocess-manifest-utf16", ["preprocess", "csv", "--out", "x.nc"], "manifest",
     _csv_broken_manifest),
    ("preprocess-binary-csv", ["preprocess", "csv", "--out", "x.nc"], "csv", _csv_binary_data),
    ("preprocess-over-csv-file", ["preprocess", "csv", "--out", "csv/manifest.csv"],
     "would overwrite the input", None),
    ("preprocess-over-csv-data", ["preprocess", "csv", "--out", "csv/x_head/actuated_00.csv"],
     "would overwrite the input", None),
    # issue 22: a strict manifest schema; manifest files stay inside the campaign folder
    ("preprocess-manifest-units", ["preprocess", "csv", "--out", "x.nc"],
     "manifest.csv: field 'manifest': unknown column 'units' in the header (expected "
     "position, kind, run, file, unit, 'unit' optional); did you mean 'unit'?", _manifest_units),
    ("preprocess-manifest-gain", ["preprocess", "csv", "--out", "x.nc"],
     "manifest.csv: field 'manifest': unknown column 'gain'", _manifest_gain),
    ("preprocess-manifest-parent", ["preprocess", "csv", "--out", "x.nc"],
     "manifest.csv: field 'file': row 2: file '../outside/x.csv' is outside the campaign "
     "folder", lambda d: _manifest_row_to(d, "../outside/x.csv")),
    ("preprocess-manifest-absolute", ["preprocess", "csv", "--out", "x.nc"],
     "manifest.csv: field 'file': row 2: file '/", lambda d: _manifest_row_to(
         d, str((d / "outside" / "x.csv").resolve()))),
    ("preprocess-manifest-symlink", ["preprocess", "csv", "--out", "x.nc"],
     "row 2: file 'x_lr/link.csv' is outside the campaign folder", _manifest_symlink),
    ("preprocess-align", ["preprocess", "c.nc", "--out", "x.nc", "--align-time", "-1ms"],
     "--align-time", None),
    ("predict-samples-huge", ["predict", "paper", "--out", "p.nc", "--samples", "1000000",
                              "--rate", "100MHz"], "largest value that fits", None),
    ("simulate-rate-huge", ["simulate", "--out", "s.nc", "--rate", "1e12"],
     "largest value that fits", None),
    ("simulate-rate-unit", ["simulate", "--out", "s.nc", "--rate", "2 m"], "--rate", None),
    ("simulate-piezo", ["simulate", "--out", "s.nc", "--piezo", "7"], "--piezo", None),
    ("simulate-voltage-latin1", ["simulate", "--out", "s.nc", "--voltage", "latin1.csv"],
     "latin1.csv", None),
    ("simulate-voltage-folder", ["simulate", "--out", "s.nc", "--voltage", "folder"], "folder",
     None),
    ("simulate-params-binary", ["simulate", "--out", "s.nc", "--params", "bad.toml"],
     "bad.toml", None),
    ("simulate-out-folder", ["simulate", "--out", "folder"], "--out", None),
    ("predict-seed", ["predict", "paper", "--out", "p.nc", "--seed", "-1"], "--seed", None),
    ("predict-bins", ["predict", "paper", "--out", "p.nc", "--bins", "0"], "--bins", None),
    ("predict-means-binary", ["predict", "paper", "--out", "p.nc", "--means", "binary.nc"],
     "binary.nc", None),
    ("predict-means-campaign", ["predict", "paper", "--out", "p.nc", "--means", "c.nc"], "c.nc",
     None),
    ("predict-same-outputs", ["predict", "paper", "--out", "p.json", "--whatif", "p.json"],
     "--whatif", None),
    ("predict-over-means", ["predict", "paper", "--out", "m.nc", "--means", "m.nc"], "--out",
     None),
    ("predict-fit-folder", ["predict", "folder", "--out", "p.nc"], "folder", None),
    ("telemetry-seed", ["synth", "telemetry", "paper", "--out", "t.nc", "--seed", "-1"],
     "--seed", None),
    ("telemetry-rate", ["synth", "telemetry", "paper", "--out", "t.nc", "--rate", "0"],
     "--rate", None),
    ("telemetry-z-from", ["synth", "telemetry", "paper", "--out", "t.nc", "--z-from", "q"],
     "--z-from", None),
    ("impact-alpha0", ["impact", "paper", "m.nc", "--out", "i.json", "--alpha", "0"], "--alpha",
     None),
    ("impact-alpha2", ["impact", "paper", "m.nc", "--out", "i.json", "--alpha", "2"], "--alpha",
     None),
    ("impact-sidecar-over-input", ["impact", "paper", "m.nc", "--out", "m.json"], "m.nc", None),
    ("impact-window", ["impact", "paper", "m.nc", "--out", "i.json", "--window", "1,0.5"],
     "--window", None),
    ("impact-seed", ["impact", "paper", "m.nc", "--out", "i.json", "--seed", "-1"], "--seed",
     None),
    ("campaign-seed", ["synth", "campaign", "--out", "x.nc", "--seed", "-1"], "--seed", None),
    ("campaign-runs", ["synth", "campaign", "--out", "x.nc", "--runs", "1"], "--runs", None),
    ("campaign-runs-huge", ["synth", "campaign", "--out", "x.nc", "--runs", "10000",
                            "--noise-runs", "10000", "--t-end", "100ms"],
     "largest value that fits", None),
    ("campaign-t-end", ["synth", "campaign", "--out", "x.nc", "--t-end", "1ms"], "--t-end",
     None),
    ("campaign-truth-folder", ["synth", "campaign", "--out", "x.nc", "--truth", "folder"],
     "folder", None),
    ("campaign-over-input", ["synth", "campaign", "--out", "p.toml", "--truth", "p.toml"],
     "--out", None),
    ("params-folder", ["params", "--params", "folder"], "folder", None),
    ("params-binary", ["params", "--params", "bad.toml"], "bad.toml", None),
    ("params-over-input", ["params", "--params", "p.toml", "--out", "p.toml"], "--out", None),
    # issue 25: gprm design
    ("design-not-a-fit", ["design", "fit.json", "--out", "d.json"], "fit.json", None),
    ("design-bad-candidates", ["design", "paper", "--candidates", "bad.toml", "--out",
                               "d.json"], "bad.toml", None),
    ("design-candidates-not-a-design", ["design", "paper", "--candidates", "p.toml", "--out",
                                        "d.json"], "parameters", None),
    ("design-out-is-input", ["design", "paper", "--candidates", "p.toml", "--out", "p.toml"],
     "--out", None),
    ("design-out-over-fit-sidecar", ["design", "fit.json", "--out", "fit.nc"], "--out", None),
    ("report-not-a-run", ["report", "afile", "--out", "r.html"], "afile", None),
    ("report-out-folder", ["report", "folder", "--out", "folder"], "--out", None),
    ("report-over-run-file", ["report", ".", "--out", "m.nc"], "would overwrite the input",
     None),
    ("show-binary", ["show", "bad.toml"], "bad.toml", None),
    ("show-folder", ["show", "folder"], "folder", None),
    ("show-min-correl", ["show", "bad.toml", "--min-correl", "2"], "--min-correl", None),
    # issue 22: no output over an input's sidecar; run folders that cannot be one; file
    # attributes of the wrong type; options checked before any work
    ("predict-over-fit-sidecar", ["predict", "fit.json", "--out", "fit.nc"],
     "--out fit.nc: would overwrite the sidecar of the input fit.json", None),
    ("predict-whatif-over-fit-sidecar", ["predict", "fit.json", "--out", "p.nc", "--whatif",
                                         "fit.nc"], "--whatif fit.nc: would overwrite the "
     "sidecar of the input fit.json", None),
    ("predict-over-run-fit-sidecar", ["predict", "run", "--out", "run/fit.nc"],
     "sidecar of the input run/fit.json", None),
    ("telemetry-over-fit-sidecar", ["synth", "telemetry", "fit.json", "--out", "fit.nc"],
     "--out fit.nc: would overwrite the sidecar of the input fit.json", None),
    ("impact-over-fit-sidecar", ["impact", "fit.json", "m.nc", "--out", "fit.json"],
     "would overwrite the input fit.json", None),
    ("run-out-is-file", ["run", "c.nc", "--out", "afile"], "--out afile: is a file", None),
    ("run-out-under-file", ["run", "c.nc", "--out", "afile/sub"],
     "--out afile/sub: cannot be written: afile is not a folder", None),
    ("demo-out-is-file", ["demo", "--out", "afile"], "--out afile: is a file", None),
    ("demo-out-under-file", ["demo", "--out", "fit.json/sub"],
     "--out fit.json/sub: cannot be written: fit.json is not a folder", None),
    ("run-over-input", ["run", "means.nc", "--out", "."], "would overwrite the input means.nc",
     lambda d: (d / "c.nc").rename(d / "means.nc")),
    ("run-foreign-checkpoint", ["run", "c.nc", "--out", "."], "not a gprm checkpoint folder",
     lambda d: ((d / "fit.json.ckpt").mkdir(), (d / "fit.json.ckpt" / "keep.txt").write_text(
         "mine"))),
    ("preprocess-text-seed", ["preprocess", "c_text_seed.nc", "--out", "x.nc"],
     "c_text_seed.nc: field 'seed': attribute must be one whole number", None),
    ("fit-text-align-time", ["fit", "m_text_align.nc", "--out", "f.json"],
     "m_text_align.nc: field 'align_time'", None),
    ("impact-text-format-version", ["impact", "paper", "t_text_version.nc", "--out",
                                    "i.json"], "field 'format_version'", None),
    ("fit-params-nan-bound", ["fit", "m.nc", "--out", "f.json", "--params", "nan.toml"],
     "nan.toml: field 'k_lr': lower bound is NaN", None),
    ("fit-band-samples-huge", ["fit", "m.nc", "--out", "f.json", "--band-samples",
                               "1000000000"], "--band-samples: 1000000000 band samples", None),
    ("unknown-option", ["fit", "m.nc", "--out", "f.json", "--bogus"], "--bogus", None),
    ("missing-option", ["simulate"], "--out", None),
]


@pytest.mark.parametrize("argv, text, setup", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_is_one_line_exit_2_nothing_written(inputs, tmp_path, monkeypatch, argv,
                                                      text, setup):
    import shutil

    work = tmp_path / "work"
    shutil.copytree(inputs, work)
    if setup is not None:
        setup(work)
    monkeypatch.chdir(work)
    monkeypatch.setenv("GPRM_LOG_DIR", str(tmp_path / "logs"))
    before = _snapshot(work)
    r = CliRunner().invoke(app, argv)
    lines = r.output.strip().splitlines()
    assert r.exit_code == 2, r.output
    assert len(lines) == 1, r.output
    assert lines[0].startswith("gprm: error: ") and text in lines[0], lines[0]
    assert "Traceback" not in r.output
    assert _snapshot(work) == before          # nothing written, inputs unchanged
    assert not (tmp_path / "logs").exists()   # an input error is not an internal error


def test_a_bad_data_row_is_quoted_short_and_sanitised(inputs, tmp_path, monkeypatch):
    """issue 22: an error line quotes at most 40 printable characters of a bad row."""
    import shutil

    work = tmp_path / "work"
    shutil.copytree(inputs, work)
    data = sorted((work / "csv" / "x_head").glob("*.csv"))[0]
    bad = "A" * 100 + "\x1b[31m" + "B" * 100
    data.write_text(data.read_text() + f"{bad},1\n")
    monkeypatch.chdir(work)
    r = CliRunner().invoke(app, ["preprocess", "csv", "--out", "x.nc"])
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1, r.output
    assert "not a number: 'AAAA" in r.output and "B" * 10 not in r.output, r.output
    assert "\x1b" not in r.output and "A" * 41 not in r.output, r.output


def test_read_only_location_is_refused_before_any_work(tmp_path, monkeypatch):
    """An --out where no file can be created (here /proc, read-only even for root)."""
    if not Path("/proc/self").exists():
        pytest.skip("needs /proc")
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["simulate", "--out", "/proc/gprm-test.nc"])
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1, r.output
    assert "--out /proc/gprm-test.nc: cannot be written" in r.output
    assert list(tmp_path.iterdir()) == []


def test_sweep_covers_every_command():
    """Every registered command (but demo, which has its own tests) appears in the sweep."""
    from typer.main import get_command

    root = get_command(app)
    names = set()
    for name, cmd in root.commands.items():
        if hasattr(cmd, "commands"):
            names |= {f"{name} {sub}" for sub in cmd.commands}
        else:
            names.add(name)
    swept = {" ".join(a[:2]) if a[0] == "synth" else a[0] for _, a, _, _ in CASES}
    assert names - {"demo", "run"} <= swept, names - swept
