"""Ground-test campaigns (paper Sec. 2): the campaign data model and its files (NetCDF, CSV
directory with a manifest), synthetic campaigns with known truth, and the preprocessing that
turns a campaign into the mean signals the fit reads. See docs/data-formats.md."""

from gprm._lazy import attach

# ``preprocess`` is not re-exported: it is also the name of the submodule, which would shadow
# it once imported (import the function from gprm.campaign.preprocess).

__getattr__, __dir__, __all__ = attach(__name__, {
    "api": ["PreprocessOptions", "preprocess_campaign", "run_preprocess"],
    "data": ["MODEL_POSITIONS", "POSITIONS", "campaign_dataset", "validate_campaign"],
    "files": ["load_campaign", "read_campaign_dir", "read_means", "read_tables", "read_truth",
              "read_truth_alignment", "write_campaign", "write_campaign_dir", "write_means"],
    "preprocess": ["MeanSignals", "PreprocessConfig", "alignment_shift"],
    "synth": ["SynthConfig", "synth_campaign"],
})
