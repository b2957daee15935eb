"""The prediction stage in one call: trajectories with bands, kinetic-energy check, mass table,
overshoots and (optionally) impact risk, for one scenario of a fitted model.

``predict(fm, ...) -> Prediction``; :func:`gprm.predict.files.prediction_dataset` turns it into
the NetCDF of docs/prediction.md. The CLI ``gprm predict`` is a thin layer over these.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from gprm.errors import GprmInputError
from gprm.fit.files import FittedModel
from gprm.predict.energy import DEFAULT_WINDOW as ENERGY_WINDOW
from gprm.predict.energy import EnergyCheck, energy_check, read_means
from gprm.predict.files import prediction_dataset
from gprm.predict.masses import MassTable, mass_table
from gprm.predict.risk import ImpactRisk, impact_risk
from gprm.predict.scenarios import Scenario, apply_scenario
from gprm.predict.trajectories import Trajectories, default_times, predict_trajectories
from gprm.predict.whatif import overshoot

MAX_TIMES = 200_000


@dataclass(frozen=True)
class Prediction:
    fm: FittedModel               # the scenario's model (values and covariance)
    scenario: Scenario
    trajectories: Trajectories
    overshoot: np.ndarray         # (point, 3) best fit, over the trajectory span
    energy: EnergyCheck
    masses: MassTable             # Fig. 7
    risk: ImpactRisk | None
    seed: int
    means_source: str | None

    def to_xarray(self):
        """The prediction as the dataset of its file (``predict.nc``, docs/prediction.md;
        :func:`gprm.predict.files.prediction_dataset`)."""
        return prediction_dataset(self)

    def to_json(self) -> dict:
        """The prediction's headline numbers, JSON-able: the scenario, the best-fit overshoot
        of each point on each axis (m), the masses (Fig. 7), the impact risk where a gap was
        given, and what uncertainty the bands carry. The time series are in
        :meth:`to_xarray`."""
        tr = self.trajectories
        return {
            "scenario": self.scenario.to_json(),
            "overshoot_m": {p: dict(zip(("x", "y", "z"), map(float, self.overshoot[i])))
                            for i, p in enumerate(tr.points)},
            "masses": self.masses.to_json(),
            "impact_risk": None if self.risk is None else self.risk.to_json(),
            "uncertainty": self.fm.uncertainty_note,
            "seed": int(self.seed),
            "means_source": self.means_source,
        }


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
