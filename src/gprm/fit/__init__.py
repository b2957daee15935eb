"""fit stage: Levenberg-Marquardt (Algorithm 1), multi-start identification, uncertainties."""

from gprm._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "api": ["FitOptions", "run_fit"],
    "engine": ["run_multistart"],
    "files": ["FittedModel", "load_fit", "load_model", "paper_model", "read_fit_document",
              "read_fit_sidecar", "write_fit"],
    "lm": ["LMResult", "levenberg_marquardt", "levenberg_marquardt_batch"],
    "result": ["FitResult"],
    "starts": ["LMOptions", "MultiStartOptions", "StartsOutcome", "draw_starts"],
    "methods": ["METHODS", "DEFAULT_METHOD", "FitState", "uncertainty_of"],
    "sandwich": ["Systematics"],
    "adequacy": ["Adequacy", "assess"],
    "uncertainty": ["Bands", "Profile", "profile_likelihood", "profile_prediction"],
})
