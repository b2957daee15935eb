"""fit stage: Levenberg-Marquardt (Algorithm 1), multi-start identification, uncertainties."""

from gprm._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "api": ["FitOptions", "run_fit"],
    "files": ["FittedModel", "load_fit", "paper_model"],
    "lm": ["LMResult", "levenberg_marquardt"],
    "uncertainty": ["METHODS", "DEFAULT_METHOD"],
})
