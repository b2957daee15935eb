"""What-if scenarios (paper Sec. 4.2): which piezo is driven, eccentricities scaled by a factor,
any parameter overridden. A scenario turns a :class:`FittedModel` into another one (values and
covariance), so trajectories, bands and overshoots of a scenario are computed like the
baseline's.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np

from gprm.errors import GprmInputError
from gprm.fit.files import FittedModel
from gprm.model.piezo import check_piezo
from gprm.params import REGISTRY, ParameterSet

ECCENTRICITIES: tuple[str, ...] = ("v2", "g2", "gamma", "rho")
"""The mechanism eccentricities the paper scales in Sec. 4.2 (Fig. 14)."""


@dataclass(frozen=True)
class Scenario:
    """A prediction scenario.

    name: label; piezo: driven actuator (1 nominal, 2 redundant); scale_eccentricity: factor
    multiplying v2, g2, gamma and rho (> 0); overrides: name -> value (SI) pinned (a fitted
    parameter that is overridden loses its uncertainty).
    """

    name: str
    piezo: int = 2
    scale_eccentricity: float = 1.0
    overrides: Mapping[str, float] = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"name": self.name, "piezo": self.piezo,
                "scale_eccentricity": self.scale_eccentricity,
                "overrides": {k: float(v) for k, v in self.overrides.items()}}


def standard_scenarios() -> tuple[Scenario, ...]:
    """The paper's three: Piezo 2 (baseline), Piezo 1 (Fig. 13), Piezo 1 with the
    eccentricities divided by 10 (Fig. 14)."""
    return (Scenario("piezo2", 2), Scenario("piezo1", 1),
            Scenario("piezo1_ecc_div10", 1, scale_eccentricity=0.1))


def check_scenario(sc: Scenario) -> None:
    check_piezo(sc.piezo)
    f = sc.scale_eccentricity
    if not (np.isfinite(f) and f > 0):
        raise GprmInputError(f"must be a finite number > 0, got {f:g}",
                             field="scale_eccentricity")
    for k in sc.overrides:
        if k not in REGISTRY:
            raise GprmInputError("unknown parameter", field=k)


def apply_scenario(fm: FittedModel, sc: Scenario) -> FittedModel:
    """The FittedModel of a scenario: eccentricities scaled (values and covariance), overrides
    pinned (zero variance). The piezo to drive is ``sc.piezo`` (not stored in the model)."""
    check_scenario(sc)
    f = float(sc.scale_eccentricity)
    vals = {n: fm.params[n] * f for n in ECCENTRICITIES}
    vals.update({k: float(v) for k, v in sc.overrides.items()})
    ps: ParameterSet = fm.params.with_values(**vals)
    d = np.ones(len(fm.names))
    for i, n in enumerate(fm.names):
        if n in ECCENTRICITIES:
            d[i] = f
        if n in sc.overrides:
            d[i] = 0.0
    cov = None if fm.covariance is None else fm.covariance * np.outer(d, d)
    draws = fm.draws
    if draws is not None:
        draws = np.asarray(draws, float) * d[None, :]
        for i, n in enumerate(fm.names):
            if n in sc.overrides:
                draws[:, i] = float(sc.overrides[n])
    return replace(fm, params=ps, covariance=cov, draws=draws)
