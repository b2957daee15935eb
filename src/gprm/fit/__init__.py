"""fit stage: Levenberg-Marquardt (Algorithm 1), multi-start identification, uncertainties."""

from gprm.fit.lm import LMResult, levenberg_marquardt

__all__ = ["LMResult", "levenberg_marquardt"]
