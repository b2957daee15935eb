"""A synthetic mean-signals dataset (the layout of docs/spec.md, "Mean-signals file") made
from the model plus noise."""


import numpy as np
import xarray as xr

from gprm.campaign.files import truth_dataset
from gprm.params import batch
from gprm.simulate import observe

SIGNALS = ("x_lr", "x_fl", "x_base", "x_head", "z_bk", "z_fl", "y_fl", "y_lr", "y_base",
           "y_head")
FIVE = ("x_base", "x_head", "y_base", "y_head", "z_bk")


def synthetic_means(params, *, seed=0, t_end=1.3e-3, rate=200e3, std=5e-9, n_runs=25,
                    scale=1.0):
    """Model outputs of ``params`` (a ParameterSet) with the sem's noise added; ``scale``
    multiplies the signals (for negative controls)."""
    t = np.arange(int(round(t_end * rate)) + 1) / rate
    obs = observe(batch([params]), t, FIVE)
    rng = np.random.default_rng(seed)
    sem = std / np.sqrt(n_runs)
    mean = np.zeros((len(SIGNALS), t.size))
    for i, n in enumerate(FIVE):
        mean[SIGNALS.index(n)] = scale * obs.y[0, i] + sem * rng.standard_normal(t.size)
    mean[[SIGNALS.index(n) for n in SIGNALS if n not in FIVE]] = \
        sem * rng.standard_normal((len(SIGNALS) - len(FIVE), t.size))
    ds = xr.Dataset(
        {"mean": (("signal", "time"), mean, {"units": "m"}),
         "std": (("signal", "time"), np.full_like(mean, std), {"units": "m"}),
         "sem": (("signal", "time"), np.full_like(mean, sem), {"units": "m"}),
         "noise_std": (("signal",), np.full(len(SIGNALS), std), {"units": "m"}),
         "shift": (("signal",), np.zeros(len(SIGNALS)), {"units": "s"}),
         "n_runs": (("signal",), np.full(len(SIGNALS), n_runs))},
        coords={"signal": list(SIGNALS), "time": ("time", t, {"units": "s"})})
    ds.attrs = {"source": "tests/predict synthetic", "sample_rate": rate,
                "truth_source": "tests/predict", "seed": seed}
    return ds.merge(truth_dataset(dict(params.values)))
