"""Experimental design (issue 25, docs/design.md): which measurement of the next ground test
determines what the fitted campaign could not. :mod:`config` (candidates, cost model, TOML),
:mod:`information` (Fisher information of a block, noise model), :mod:`predictions` (the
release predictions and their gradients), :mod:`core` (:func:`run_design`: ranking,
selection, the recommended campaign), :mod:`files` (design.json), :mod:`commands` (CLI)."""

from gprm._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "config": ["Block", "Candidate", "Channel", "CostModel", "DesignConfig",
               "default_candidates", "read_design_config"],
    "core": ["DesignResult", "run_design"],
    "files": ["read_design", "write_design"],
})
