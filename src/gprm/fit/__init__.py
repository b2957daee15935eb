"""fit stage: Levenberg-Marquardt (Algorithm 1), multi-start identification, uncertainties."""

from gprm.fit.api import FitOptions, run_fit
from gprm.fit.lm import LMResult, levenberg_marquardt

__all__ = ["FitOptions", "LMResult", "levenberg_marquardt", "run_fit"]
