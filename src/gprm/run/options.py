"""The settings of one ``gprm run`` / ``gprm demo``: the stages' own option dataclasses (the
one recommended configuration by default) plus what only the chain has."""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from gprm.campaign.api import PreprocessOptions
from gprm.errors import GprmInputError
from gprm.fit.api import FitOptions
from gprm.validate import check_int

QUICK_STARTS = 50
QUICK_SAMPLES = 40


@dataclass(frozen=True)
class RunOptions:
    """Settings of a run. Those that change a stage's output are part of its hash.

    campaign: the campaign (NetCDF file or CSV folder with ``manifest.csv``), or None for a
        synthetic one generated with ``seed`` (``gprm demo``).
    telemetry: in-flight telemetry (a NetCDF or CSV file), or None for synthetic releases
        drawn from the fit.
    preprocess, fit: the stages' options (``fit.seed`` seeds the starts and the fit bands).
    predict_samples: parameter sets drawn for the prediction and impact-curve bands.
    releases: synthetic releases (when ``telemetry`` is None).
    workers: local worker processes for the fit (0: in this process); the result does
        not depend on it, so it is not part of any hash.
    """

    campaign: str | None = None
    telemetry: str | None = None
    seed: int = 0
    preprocess: PreprocessOptions = field(default_factory=PreprocessOptions)
    fit: FitOptions = field(default_factory=FitOptions)
    predict_samples: int = 200
    releases: int = 11
    workers: int = 0
    quick: bool = False

    def __post_init__(self):
        for name in ("campaign", "telemetry"):
            v = getattr(self, name)
            if v is not None:
                if not isinstance(v, (str, os.PathLike)) or not str(v):
                    raise GprmInputError(f"must be a path, got {v!r}", field=name)
                object.__setattr__(self, name, os.fspath(v))
        for name, lo in (("seed", 0), ("predict_samples", 0), ("releases", 2), ("workers", 0)):
            check_int(name, getattr(self, name), lo)
        if not isinstance(self.preprocess, PreprocessOptions):
            raise GprmInputError("expected PreprocessOptions", field="preprocess")
        if not isinstance(self.fit, FitOptions):
            raise GprmInputError("expected FitOptions", field="fit")

    @classmethod
    def make(cls, *, quick: bool = False, seed: int = 0, starts: int | None = None,
             workers: int = 0, campaign=None, telemetry=None,
             releases: int = 11) -> "RunOptions":
        """The defaults of ``gprm run`` / ``gprm demo``: the stages' defaults, with ``seed``
        for the starts and the sampled bands; ``quick``: 50 starts and 40 parameter samples
        for the bands (fit, prediction, impact curves) instead of 1000 and 200."""
        if starts is None:
            starts = QUICK_STARTS if quick else FitOptions.starts
        samples = QUICK_SAMPLES if quick else 200
        return cls(campaign=campaign, telemetry=telemetry, seed=seed, quick=quick,
                   workers=workers, releases=releases, predict_samples=samples,
                   fit=FitOptions(starts=starts, seed=seed, band_samples=samples))
