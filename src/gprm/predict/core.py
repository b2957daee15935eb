"""The prediction stage in one call: trajectories with bands, kinetic-energy check, mass table,
overshoots and (optionally) impact risk, for one scenario of a fitted model.

``predict(fm, ...) -> Prediction`` (:mod:`gprm.predict.prediction`, whose
:func:`~gprm.predict.prediction.prediction_dataset` turns it into the NetCDF of
docs/prediction.md). The CLI ``gprm predict`` is a thin layer over these.
"""

from __future__ import annotations

import os

import numpy as np

from gprm.errors import GprmInputError
from gprm.fit.files import FittedModel
from gprm.predict.energy import DEFAULT_WINDOW as ENERGY_WINDOW
from gprm.predict.energy import energy_check, read_means
from gprm.predict.masses import mass_table
from gprm.predict.prediction import Prediction
from gprm.predict.risk import impact_risk
from gprm.predict.scenarios import Scenario, apply_scenario
from gprm.predict.trajectories import default_times, predict_trajectories
from gprm.predict.whatif import overshoot

MAX_TIMES = 200_000


def prediction_times(t_start: float, t_end: float, rate: float) -> np.ndarray:
    if np.isfinite(t_end) and np.isfinite(t_start) and np.isfinite(rate) and rate > 0 \
            and (t_end - t_start) * rate > MAX_TIMES:
        raise GprmInputError(f"span {t_start:g}..{t_end:g} s at {rate:g} Hz gives more than "
                             f"{MAX_TIMES} samples", field="t_end")
    return default_times(t_start, t_end, rate)


def predict(fm: FittedModel, *, scenario: Scenario | None = None, times=None,
            samples: int = 200, seed: int = 0, means: str | os.PathLike | None = None,
            energy_window: tuple[float, float] = ENERGY_WINDOW, n_bins: int = 20,
            gap: float | None = None, gap_std: float = 0.0, voltage=None) -> Prediction:
    """Run the whole prediction for ``scenario`` (default: Piezo 2, as fitted).

    A model without usable parameter uncertainty (``fm.has_uncertainty`` False) predicts
    with its best fit alone: no sampled or linear bands, which the files and the report
    say (``fm.uncertainty_note``)."""
    if samples < 0:
        raise GprmInputError(f"must be >= 0, got {samples}", field="samples")
    sc = scenario or Scenario("piezo2", 2)
    fs = apply_scenario(fm, sc)
    if not fs.has_uncertainty:
        samples = 0
    t = default_times() if times is None else np.asarray(times, float)
    traj = predict_trajectories(fs, t, piezo=sc.piezo, samples=samples, seed=seed,
                                voltage=voltage, linear=fs.covariance is not None)
    m = read_means(means) if means is not None else None
    try:
        en = energy_check(fs, piezo=sc.piezo, means=m, window=energy_window, n_bins=n_bins,
                          samples=samples, seed=seed, voltage=voltage)
    except GprmInputError as exc:
        if means is not None and exc.source is None:
            raise GprmInputError(exc.problem, source=str(means), field=exc.field) from None
        raise
    risk = None
    if gap is not None:
        risk = impact_risk(fs, gap, gap_std, times=t, piezo=sc.piezo, samples=samples,
                           seed=seed, voltage=voltage)
    return Prediction(fm=fs, scenario=sc, trajectories=traj, overshoot=overshoot(traj.pos),
                      energy=en, masses=mass_table(fs), risk=risk, seed=int(seed),
                      means_source=None if means is None else str(means))
