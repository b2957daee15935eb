"""Library entry point of the preprocessing stage: ``run_preprocess`` with its validated
options. ``gprm preprocess``, ``gprm run`` and ``gprm demo`` call exactly this, so the three
share one configuration (the defaults of :class:`PreprocessOptions`)."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import xarray as xr

from gprm.campaign.files import load_campaign
from gprm.campaign.preprocess import MeanSignals, PreprocessConfig, preprocess
from gprm.errors import GprmInputError


@dataclass(frozen=True)
class PreprocessOptions:
    """What the user chooses in the preprocessing (SI).

    align_time: where each mean signal's first sustained crossing of the threshold is put, s
        (default: the recommended 1.01 ms of :class:`PreprocessConfig`).
    threshold_factor: the threshold in units of each signal's noise std (the paper's 2 sigma).
    """

    align_time: float = PreprocessConfig.align_time
    threshold_factor: float = PreprocessConfig.threshold_factor

    def __post_init__(self):
        for name in ("align_time", "threshold_factor"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or v <= 0:
                raise GprmInputError(f"must be a finite number > 0, got {v!r}", field=name)

    def config(self) -> PreprocessConfig:
        return PreprocessConfig(align_time=float(self.align_time),
                                threshold_factor=float(self.threshold_factor))


def preprocess_campaign(campaign: str | os.PathLike | xr.Dataset,
                        opts: PreprocessOptions = PreprocessOptions()) -> MeanSignals:
    """The mean signals of a campaign (NetCDF file, CSV folder with a manifest, or a Dataset),
    with the per-signal diagnostics (Table 1, dropped positions) the command prints."""
    if not isinstance(opts, PreprocessOptions):
        raise GprmInputError(f"expected PreprocessOptions, got {type(opts).__name__}",
                             field="opts")
    ds = campaign if isinstance(campaign, xr.Dataset) else load_campaign(campaign)
    return preprocess(ds, opts.config())


def run_preprocess(campaign: str | os.PathLike | xr.Dataset,
                   opts: PreprocessOptions = PreprocessOptions()) -> xr.Dataset:
    """The mean-signals dataset (the layout ``gprm fit`` reads) of a campaign."""
    return preprocess_campaign(campaign, opts).to_dataset()
