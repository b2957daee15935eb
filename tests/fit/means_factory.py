"""Mean-signals datasets made directly from the linear model (no campaign, no alignment):
the fit's own generator-without-mismatch, so chi-square statistics can be checked exactly."""

from __future__ import annotations

import numpy as np
import xarray as xr

from gprm.params import ParameterSet, batch
from gprm.simulate import OUTPUTS, observe


def make_means(truth: ParameterSet, *, seed: int = 0, sem: float = 2e-10, rel: float = 0.01,
               t_end: float = 1.25e-3, rate: float = 200e3, piezo: int = 2) -> xr.Dataset:
    """Mean signals = truth outputs + Gaussian noise of standard deviation
    sigma(t) = sqrt(sem^2 + (rel * |y(t)|)^2), with variables ``mean``, ``sem`` and ``std``
    (std = sqrt(10) * sem, as for 10 runs)."""
    t = np.arange(int(round(t_end * rate)) + 1) / rate
    y = observe(batch([truth]), t, OUTPUTS, piezo=piezo).y[0]
    sig = np.sqrt(sem ** 2 + (rel * np.abs(y)) ** 2)
    rng = np.random.default_rng(seed)
    mean = y + sig * rng.standard_normal(y.shape)
    ds = xr.Dataset({"mean": (("signal", "time"), mean), "sem": (("signal", "time"), sig),
                     "std": (("signal", "time"), sig * np.sqrt(10))},
                    coords={"signal": list(OUTPUTS), "time": t})
    ds.attrs["truth_json"] = "{}"
    return ds
