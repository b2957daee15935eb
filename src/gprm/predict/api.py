"""Library entry points of the prediction stage: ``run_predict`` (trajectories with bands,
kinetic energy, masses, overshoot, impact risk) and ``run_whatif`` (the paper's what-if
table), with their validated options. ``gprm predict``, ``gprm run`` and ``gprm demo`` call
exactly these."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

from gprm.errors import GprmInputError
from gprm.fit.files import FittedModel, load_model
from gprm.predict.core import Prediction, predict, prediction_times
from gprm.predict.scenarios import Scenario, check_scenario
from gprm.predict.whatif import WhatIf, whatif
from gprm.simulate.inputs import read_voltage_csv
from gprm.validate import check_int

#: the what-if table draws at most this many parameter sets (its ranges are 2.5/97.5 %)
WHATIF_MAX_SAMPLES = 100


def _finite(name: str, v, *, positive: bool = False, nonneg: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
            or (positive and v <= 0) or (nonneg and v < 0):
        cond = " > 0" if positive else " >= 0" if nonneg else ""
        raise GprmInputError(f"must be a finite number{cond}, got {v!r}", field=name)
    return float(v)


@dataclass(frozen=True)
class PredictOptions:
    """What defines a prediction (SI). Validated on construction; a bad value raises
    :class:`GprmInputError` naming the option.

    The scenario: ``piezo`` driven, ``scale_eccentricity`` (factor on v2, g2, gamma, rho),
    ``overrides`` (name -> SI value pinned), labelled ``name``. The span ``t_start``..``t_end``
    at ``rate``; ``samples`` parameter sets drawn from the fit covariance with ``seed``;
    ``means``: a mean-signals file for the measured kinetic energy (Fig. 8), in ``bins`` bins
    over ``ke_window``; ``gap`` +- ``gap_std`` (m): the impact risk against it;
    ``voltage``: a measured drive trace CSV (time s, voltage V).
    """

    piezo: int = 2
    scale_eccentricity: float = 1.0
    overrides: Mapping[str, float] = field(default_factory=dict)
    name: str = "cli"
    t_start: float = 0.95e-3
    t_end: float = 1.2e-3
    rate: float = 1e6
    samples: int = 200
    seed: int = 0
    means: str | os.PathLike | None = None
    bins: int = 20
    ke_window: tuple[float, float] = (0.97e-3, 1.2e-3)
    gap: float | None = None
    gap_std: float = 0.0
    voltage: str | os.PathLike | None = None

    def __post_init__(self):
        check_scenario(self.scenario())
        _finite("t_start", self.t_start)
        _finite("t_end", self.t_end)
        if not self.t_start < self.t_end:
            raise GprmInputError(f"must be after t_start ({self.t_start:g} s), got "
                                 f"{self.t_end:g} s", field="t_end")
        _finite("rate", self.rate, positive=True)
        for name, lo in (("samples", 0), ("seed", 0), ("bins", 1)):
            check_int(name, getattr(self, name), lo)
        w = tuple(self.ke_window)
        if len(w) != 2:
            raise GprmInputError(f"must be two times start < end, got {self.ke_window!r}",
                                 field="ke_window")
        w = (_finite("ke_window", w[0]), _finite("ke_window", w[1]))
        if not w[0] < w[1]:
            raise GprmInputError(f"must be two times start < end, got {self.ke_window!r}",
                                 field="ke_window")
        object.__setattr__(self, "ke_window", w)
        if self.gap is not None:
            _finite("gap", self.gap)
        _finite("gap_std", self.gap_std, nonneg=True)

    def scenario(self) -> Scenario:
        return Scenario(self.name, self.piezo, self.scale_eccentricity, dict(self.overrides))

    @classmethod
    def for_scenario(cls, sc: Scenario, **kw) -> "PredictOptions":
        """The options of scenario ``sc`` (one of ``standard_scenarios()``, say)."""
        return cls(piezo=sc.piezo, scale_eccentricity=sc.scale_eccentricity,
                   overrides=dict(sc.overrides), name=sc.name, **kw)


def _voltage(opts: PredictOptions):
    if opts.voltage is None:
        return None

    return read_voltage_csv(Path(opts.voltage))


def run_predict(model: FittedModel | str | os.PathLike,
                opts: PredictOptions = PredictOptions()) -> Prediction:
    """The prediction of ``opts``' scenario from a fitted model (a :class:`FittedModel`, a
    fit result JSON, or ``"paper"`` for Table 3). Write it with
    :func:`gprm.predict.files.prediction_dataset`."""
    if not isinstance(opts, PredictOptions):
        raise GprmInputError(f"expected PredictOptions, got {type(opts).__name__}",
                             field="opts")
    fm = load_model(model)
    t = prediction_times(opts.t_start, opts.t_end, opts.rate)
    return predict(fm, scenario=opts.scenario(), times=t, samples=opts.samples,
                   seed=opts.seed, means=opts.means, n_bins=opts.bins, gap=opts.gap,
                   gap_std=opts.gap_std, voltage=_voltage(opts), energy_window=opts.ke_window)


def run_whatif(model: FittedModel | str | os.PathLike,
               opts: PredictOptions = PredictOptions()) -> WhatIf:
    """The paper's what-if table (Piezo 2 vs Piezo 1 vs Piezo 1 with eccentricities / 10;
    :class:`~gprm.predict.whatif.WhatIf`, its ``to_json()`` is ``whatif.json``) with ``min(opts.samples, 100)`` parameter sets for its ranges, ``opts.seed``
    and ``opts.voltage``; the scenario fields of ``opts`` are not used."""
    if not isinstance(opts, PredictOptions):
        raise GprmInputError(f"expected PredictOptions, got {type(opts).__name__}",
                             field="opts")
    return whatif(load_model(model), samples=min(opts.samples, WHATIF_MAX_SAMPLES), seed=opts.seed,
                  voltage=_voltage(opts))
