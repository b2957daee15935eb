"""One interface for the fit's uncertainty methods, one module per method (issue 21).

A method is a module with a function ``uncertainty(method, state) -> Uncertainty`` (see
:class:`FitState` for what it is given). :data:`MODULES` names each method's module; it is
imported only when that method is asked for, so the default path of ``gprm.fit`` never loads
what an opt-in method needs (``generator-bootstrap`` synthesises campaigns with gprm's own
generator; the import contract in pyproject.toml keeps every other module of ``gprm.fit`` from
importing ``gprm.campaign.synth``).

============================ ===================== =================================================
method                       module                what it assumes
============================ ===================== =================================================
``sandwich`` (default)       gprm.fit.sandwich     the campaign's own runs and residuals show its
                                                   error; instrument systematics as stated priors
``laplace-prior``            gprm.fit.uncertainty  residuals independent up to one correlation
                                                   factor tau; the model describes the data
``eq7``, ``eq7-corr``        gprm.fit.uncertainty  the paper's Eq. 7 (no prior), with/without tau
``mcmc``                     gprm.fit.uncertainty  as laplace-prior, sampled instead of linearised
``generator-bootstrap``      gprm.fit.bootstrap    the data's mismatch is the one gprm's synthetic
                                                   generator models (re-centres, calibrated on it)
============================ ===================== =================================================
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass

import numpy as np

from gprm.fit.objective import Objective
from gprm.fit.prior import Prior
from gprm.fit.starts import LMOptions

#: method -> the module that implements it
MODULES = {
    "sandwich": "gprm.fit.sandwich",
    "laplace-prior": "gprm.fit.uncertainty",
    "eq7": "gprm.fit.uncertainty",
    "eq7-corr": "gprm.fit.uncertainty",
    "mcmc": "gprm.fit.uncertainty",
    "generator-bootstrap": "gprm.fit.bootstrap",
}
METHODS = tuple(MODULES)
DEFAULT_METHOD = "sandwich"
#: methods that need the weak prior
NEEDS_PRIOR = ("sandwich", "laplace-prior", "mcmc", "generator-bootstrap")


@dataclass(frozen=True)
class FitState:
    """What a method gets: the fit's objective (its prior weighed), the best fit ``x``
    (physical, (P,)), the weighted data residuals ``r`` (N,) and their Jacobian ``J`` (N, P)
    there (prior rows excluded), the prior (weighted, or None), and the method's settings."""

    obj: Objective
    x: np.ndarray
    J: np.ndarray
    r: np.ndarray
    prior: Prior | None
    seed: int = 0
    n_draws: int = 400
    lm: LMOptions = LMOptions()
    n_boot: int = 30
    systematics: object = None          # gprm.fit.sandwich.Systematics (None: defaults)
    #: (K, P) physical: the other starts' end points of the multi-start (None: not known);
    #: the default method widens an interval to every one that fits as well
    #: (gprm.fit.sandwich.alternative_factors)
    alternatives: np.ndarray | None = None

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.obj.names)


def compute(method: str, state: FitState):
    """The ``method``'s :class:`gprm.fit.uncertainty.Uncertainty` of the fit ``state``."""
    if method not in MODULES:
        raise ValueError(f"unknown uncertainty method {method!r} (one of {', '.join(METHODS)})")
    if method in NEEDS_PRIOR and state.prior is None:
        raise ValueError(f"the {method} uncertainty needs a prior (a prior width)")
    return importlib.import_module(MODULES[method]).uncertainty(method, state)


def state_of(fit, *, systematics=None) -> FitState:
    """The :class:`FitState` of a finished fit (a FitResult), e.g. to compare methods."""
    obj = fit.objective()
    x = np.asarray(fit.x, float)
    rr, Jn = obj(obj.to_normalised(x)[None])
    n = obj.data.n_obs
    opts = fit.options
    starts = getattr(fit, "starts", None)
    alt = getattr(starts, "x", None)
    return FitState(obj, x, Jn[0, :n] / obj.scale, rr[0, :n], obj.prior, seed=opts.seed,
                    lm=opts.lm,
                    systematics=systematics if systematics is not None else
                    getattr(fit, "systematics", None),
                    alternatives=None if alt is None else np.asarray(alt, float))


def uncertainty_of(fit, method: str, *, systematics=None):
    """``method``'s uncertainty of a finished fit (a FitResult)."""
    return compute(method, state_of(fit, systematics=systematics))
