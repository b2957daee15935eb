"""Parameters: the registry (names, units, roles, bounds), the ``paper`` set, TOML in and out."""

from gprm._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "core": ["ParameterSet", "batch", "batch_from_vectors", "paper", "validate_values"],
    "files": ["from_si", "load_params", "params_to_toml", "save_params", "to_si"],
    "registry": ["ALIGNMENT_OFFSETS", "FITTED_DEFAULT", "LAG_PARAMETERS", "REGISTRY",
                 "ParamSpec"],
})
