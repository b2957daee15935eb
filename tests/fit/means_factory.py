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


def perturbed_problem(seed: int = 5):
    """(objective, x): the weak-prior objective of synthetic signals of the paper set moved
    by up to 3 % (``seed``), and a point up to 2 % off that truth in every fitted parameter,
    so that a polish from it has far to go (chi-square ~35 times its minimum's)."""
    from gprm.fit.objective import Objective, fit_data_from_means
    from gprm.fit.prior import default_prior
    from gprm.params import paper

    p = paper()
    rng = np.random.default_rng(seed)
    truth = p.with_vector(p.vector() * (1 + 0.03 * rng.uniform(-1, 1, len(p.fitted))))
    data = fit_data_from_means(make_means(truth, seed=2, rel=0.02), source="synthetic")
    obj = Objective.create(data, p, prior=default_prior(p, tuple(p.fitted)))
    x = truth.vector(obj.names) * (1 + 0.02 * rng.uniform(-1, 1, len(obj.names)))
    return obj, x
