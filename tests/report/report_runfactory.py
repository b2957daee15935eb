"""A small run directory for the report tests that does not need the campaign, predict or
flight stages: mean signals straight from the linear model plus noise (known truth), a fit of a
few starts with the fit library, and an impact result in the format of docs/spec.md."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import xarray as xr

from gprm._io import write_json_atomic, write_netcdf_atomic
from gprm.campaign.files import truth_dataset
from gprm.params import batch, paper
from gprm.simulate import OUTPUTS, observe

AXES = ("vx", "vz_xz", "wy", "vy", "vz_yz", "wx")


def make_means(path: Path, *, seed: int = 0, rel: float = 0.02, floor: float = 2e-9,
               rate: float = 200e3, t_end: float = 1.3e-3) -> dict:
    truth = paper()
    t = np.arange(int(round(t_end * rate)) + 1) / rate
    y = observe(batch([truth]), t, OUTPUTS, piezo=2).y[0]
    sem = np.sqrt(floor ** 2 + (rel * np.abs(y)) ** 2)
    rng = np.random.default_rng(seed)
    mean = y + sem * rng.standard_normal(y.shape)
    ds = xr.Dataset({"mean": (("signal", "time"), mean, {"units": "m"}),
                     "sem": (("signal", "time"), sem, {"units": "m"}),
                     "std": (("signal", "time"), sem * np.sqrt(10), {"units": "m"}),
                     "n_runs": (("signal",), np.full(len(OUTPUTS), 10))},
                    coords={"signal": list(OUTPUTS), "time": ("time", t, {"units": "s"})})
    ds = ds.merge(truth_dataset(dict(truth.values)))
    ds.attrs.update(truth_source="paper", seed=seed)
    write_netcdf_atomic(ds, path)
    return dict(truth.values)


def make_fit(run: Path, *, starts: int = 40, seed: int = 0) -> None:
    """A fit result in the contract format (docs/spec.md, "Fit result"), without running the
    fitter: the truth perturbed by its Table-3 error as the "fit", chi-square values of a
    waterfall."""
    from gprm._io import open_netcdf
    from gprm.fit.objective import fit_data_from_means
    from gprm.params import REGISTRY

    rng = np.random.default_rng(seed)
    ps = paper()
    data = fit_data_from_means(open_netcdf(run / "means.nc"))
    names = ps.fitted
    se = ps.paper_stderr() / 3
    x = np.array([ps.values[n] for n in names]) + 0.5 * se * rng.standard_normal(len(names))
    params = {}
    for n in REGISTRY:
        fitted = n in names
        v = float(x[names.index(n)]) if fitted else float(ps.values[n])
        params[n] = {"value": v, "stderr": float(se[names.index(n)]) if fitted else None,
                     "unit": "SI", "fitted": fitted, "display_unit": REGISTRY[n].unit}
        if fitted:
            e = float(se[names.index(n)])
            params[n].update(identified=bool(e < 0.2 * abs(v)),
                             interval={"level": 0.95, "lower": v - 1.96 * e,
                                       "upper": v + 1.96 * e, "method": "laplace-prior"})
    best = observe(batch([ps.with_values(**{n: params[n]["value"] for n in names})]),
                   data.time, OUTPUTS, piezo=2).y[0]
    chi2 = float(np.sum(((best - data.values) / data.sigma) ** 2))
    dof = data.n_obs - len(names)
    fit = {"model": "gprm-3d", "format_version": 1, "piezo": 2, "seed": seed,
           "window": list(data.window), "parameters": params, "chi2": chi2, "dof": dof,
           "reduced_chi2": chi2 / dof, "sigma": "sem",
           "uncertainty": {"method": "laplace-prior", "note": "test factory"},
           "correlation": {"names": list(names), "matrix": np.eye(len(names)).tolist()},
           "starts": {"requested": starts, "converged": starts - 3, "best_index": 0,
                      "n_at_best": starts // 3, "spread": 0.2}}
    finals = np.concatenate([np.full(starts // 3, chi2), chi2 * (1 + rng.exponential(
        5.0, starts - starts // 3))])
    band = 0.03 * np.abs(best) + 1e-9
    side = xr.Dataset({"chi2": (("start",), finals), "data_mean": (("signal", "time"),
                       data.values), "data_sigma": (("signal", "time"), data.sigma),
                       "model_best": (("signal", "time"), best),
                       "band_sample_lo": (("signal", "time"), best - band),
                       "band_sample_hi": (("signal", "time"), best + band)},
                      coords={"signal": list(data.signals), "time": data.time})
    write_netcdf_atomic(side, run / "fit.nc")
    # as gprm.fit.files.write_fit: the sidecar first, then the JSON binding it by its hash
    fit["sidecar"] = {"name": "fit.nc", "sha256": hashlib.sha256(
        (run / "fit.nc").read_bytes()).hexdigest()}
    write_json_atomic(run / "fit.json", fit)


def make_impact(path: Path, *, releases: int = 11, seed: int = 0, truth: bool = True,
                joint_rejected: tuple[str, ...] | None = None) -> None:
    """Impact times scattered around 1.05 ms with the same mean on every axis. ``truth``:
    synthetic releases with their true impact times (False: measured telemetry, no truth);
    ``joint_rejected``: release ids whose joint chi-square test rejects (None: no joint
    check recorded)."""
    rng = np.random.default_rng(seed)
    rel = []
    for i in range(releases):
        rel.append({"id": f"R{i + 1:02d}",
                    "velocity": {a: {"value": float(rng.normal(0, 5e-6)), "stderr": 1e-7}
                                 for a in AXES},
                    "impact_time": {a: {"value": float(1.05e-3 + rng.normal(0, 2e-5)),
                                        "stderr": 1e-5} for a in AXES}})
    pairs = [{"a": a, "b": b, "q": 0.5, "p": 0.9, "reject": False}
             for i, a in enumerate(AXES) for b in AXES[i + 1:]]
    doc = {"releases": rel, "tukey": {"alpha": 0.01, "k": 6, "df": 60, "q_critical": 5.2,
                                      "pairs": pairs, "all_compatible": True}}
    if truth:
        doc["truth"] = {"impact_time": [1.05e-3] * releases}
    if joint_rejected is not None:
        for r in rel:
            r["joint"] = {"value": 1.05e-3, "ci95": [1.04e-3, 1.06e-3], "chi2": 3.0, "df": 5,
                          "p": 1e-4 if r["id"] in joint_rejected else 0.7}
        doc["joint"] = {"alpha": 0.01, "n": releases, "rejected": list(joint_rejected),
                        "all_consistent": not joint_rejected}
    write_json_atomic(path, doc)
    # the sidecar: predicted velocity as a function of the impact time, per axis
    t = np.linspace(1.0e-3, 1.2e-3, 101)
    nominal = np.stack([1e-5 * np.sin(2 * np.pi * (t - 1e-3) / 1e-4 + k) for k in range(6)])
    xr.Dataset({"nominal": (("axis", "time"), nominal),
                "lo": (("axis", "time"), nominal - 2e-6), "hi": (("axis", "time"), nominal + 2e-6)},
               coords={"axis": list(AXES), "time": t}).to_netcdf(path.with_suffix(".nc"))
