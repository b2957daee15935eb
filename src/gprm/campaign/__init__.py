"""Ground-test campaigns (paper Sec. 2): the campaign data model and its files (NetCDF, CSV
directory with a manifest), synthetic campaigns with known truth, and the preprocessing that
turns a campaign into the mean signals the fit reads. See docs/data-formats.md."""

from gprm.campaign.api import PreprocessOptions, preprocess_campaign, run_preprocess
from gprm.campaign.csvdir import read_campaign_dir, write_campaign_dir
from gprm.campaign.data import (MODEL_POSITIONS, POSITIONS, campaign_dataset, load_campaign,
                                validate_campaign, write_campaign)
from gprm.campaign.preprocess import (MeanSignals, PreprocessConfig, alignment_shift,
                                      preprocess)
from gprm.campaign.synth import SynthConfig, synth_campaign

__all__ = ["MODEL_POSITIONS", "POSITIONS", "MeanSignals", "PreprocessConfig",
           "PreprocessOptions", "SynthConfig", "alignment_shift", "campaign_dataset",
           "load_campaign", "preprocess", "preprocess_campaign", "read_campaign_dir",
           "run_preprocess", "synth_campaign", "validate_campaign", "write_campaign",
           "write_campaign_dir"]
