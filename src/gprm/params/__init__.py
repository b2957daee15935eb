"""Parameters: the registry (names, units, roles, bounds), the ``paper`` set, TOML in and out."""

from gprm.params.core import (ParameterSet, batch, batch_from_vectors, paper, validate_values)
from gprm.params.files import from_si, load_params, params_to_toml, save_params, to_si
from gprm.params.registry import ALIGNMENT_OFFSETS, FITTED_DEFAULT, REGISTRY, ParamSpec

__all__ = ["ALIGNMENT_OFFSETS", "FITTED_DEFAULT", "REGISTRY", "ParamSpec", "ParameterSet",
           "batch", "batch_from_vectors", "from_si", "load_params", "paper", "params_to_toml",
           "save_params", "to_si", "validate_values"]
