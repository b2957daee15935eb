"""The result of a fit: best start, covariance (Eq. 7), standard errors, correlations, reduced
chi-square, bands and profiles, with its report. It is computed by :func:`gprm.fit.identify`
and written and read back by :mod:`gprm.fit.files`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gprm.fit import files
from gprm.fit.files import MODEL_NAME
from gprm.fit.adequacy import Adequacy
from gprm.fit.objective import FitData, Objective
from gprm.fit.report_text import weights_label
from gprm.fit.prior import Prior
from gprm.fit.starts import MultiStartOptions, StartsOutcome
from gprm.fit.uncertainty import Bands, Profile, Uncertainty, identifiable_combinations
from gprm.params import REGISTRY, ParameterSet, from_si


@dataclass(frozen=True)
class FitResult:
    names: tuple[str, ...]
    params: ParameterSet               # the best fit (fitted names take their best values)
    chi2: float
    dof: int
    covariance: np.ndarray | None      # (P, P) SI, or None
    covariance_message: str
    at_bounds: tuple[str, ...]
    starts: StartsOutcome
    options: MultiStartOptions
    data: FitData
    piezo: int
    bands: Bands | None = None
    profiles: tuple[Profile, ...] = ()
    timings: dict = field(default_factory=dict)
    z_bk_absolute: bool = False
    polish: dict = field(default_factory=dict)
    #: the chosen method's uncertainty (intervals, identified, draws) and the paper's Eq. 7
    uncertainty: Uncertainty | None = None
    eq7: Uncertainty | None = None
    prior: Prior | None = None
    #: the stated instrument systematics (gprm.fit.sandwich.Systematics; None: defaults)
    systematics: object = None
    #: does the model describe the data
    adequacy: Adequacy | None = None
    #: the unmodelled resonance the fit marginalised (gprm.fit.resonance.Resonance), or None
    resonance: object = None

    def combinations(self) -> list[dict]:
        """What the data determine among the not-identified parameters
        (:func:`gprm.fit.uncertainty.identifiable_combinations`)."""
        if self.uncertainty is None or self.prior is None:
            return []
        return identifiable_combinations(self.uncertainty, self.prior, self.x)

    def objective(self) -> Objective:
        """The objective the best fit minimises (its prior weighed by the data's variance
        scale), e.g. to refit bootstrap campaigns or profile a parameter."""
        prior = self.prior
        if prior is not None and self.uncertainty is not None and np.isfinite(self.uncertainty.s2):
            prior = prior.with_weight(np.sqrt(self.uncertainty.s2))
        basis = getattr(getattr(self, "resonance", None), "basis", None)
        return Objective.create(self.data, self.params, self.names, piezo=self.piezo,
                                z_bk_absolute=self.z_bk_absolute, prior=prior,
                                projection=basis)

    @property
    def identified(self) -> tuple[str, ...]:
        if self.uncertainty is None:
            return ()
        return tuple(n for n, k in zip(self.names, self.uncertainty.identified) if k)

    @property
    def leans_on_prior(self) -> tuple[str, ...]:
        """Names whose interval is narrow but mostly the prior's variance: not identified
        (gprm.fit.uncertainty.determined)."""
        if self.uncertainty is None:
            return ()
        return tuple(n for n, k in zip(self.names, self.uncertainty.leaning) if k)

    @property
    def x(self) -> np.ndarray:
        return self.params.vector(self.names)

    @property
    def reduced_chi2(self) -> float:
        return self.chi2 / self.dof

    @property
    def stderr(self) -> np.ndarray:
        if self.covariance is None:
            return np.full(len(self.names), np.nan)
        return np.sqrt(np.diag(self.covariance))

    @property
    def correlation(self) -> np.ndarray | None:
        if self.covariance is None:
            return None
        s = self.stderr
        return self.covariance / np.outer(s, s)

    # ------------------------------------------------------------------ report
    def summary(self) -> str:
        """A readable fit report (lmfit-like)."""
        weights = weights_label(self.data.sigma_kind, self.data.sigma_pool)
        lines = [f"[[Fit]] model {MODEL_NAME}, piezo {self.piezo}, sigma={weights}",
                 f"    starts: {self.starts.chi2.size}, converged "
                 f"{int(self.starts.converged.sum())}, at best (dchi2<=1) "
                 f"{self.starts.n_at_best()}",
                 f"    chi-square {self.chi2:.6g}, dof {self.dof}, reduced "
                 f"{self.reduced_chi2:.4g}",
                 "[[Parameters]]"]
        u = self.uncertainty
        for k, (name, v, e) in enumerate(zip(self.names, self.x, self.stderr)):
            unit = REGISTRY[name].unit
            ev = from_si(e, name) if np.isfinite(e) else float("nan")
            line = f"    {name:>9} = {from_si(v, name):12.6g} +/- {ev:.3g} {unit}"
            if u is not None and np.isfinite(u.lower95[k]):
                line += (f"   95%: [{from_si(u.lower95[k], name):.4g}, "
                         f"{from_si(u.upper95[k], name):.4g}]")
                line += "" if u.identified[k] else (
                    "   (leans on the prior)" if name in self.leans_on_prior
                    else "   (not determined)")
            lines.append(line)
        if u is not None and u.calibration:
            lines.append("    intervals widened by the mismatch calibration (gprm.fit.calibration): "
                         + ", ".join(f"{n} x{f:.2f}" for n, f in u.calibration))
        if self.covariance is None:
            lines.append(f"    (no covariance: {self.covariance_message})")
        if self.at_bounds:
            lines.append(f"    at a bound: {', '.join(self.at_bounds)}")
        return "\n".join(lines)

    # ------------------------------------------------------------------ files
    def to_json_dict(self) -> dict:
        """The fit file's JSON content (:func:`gprm.fit.files.fit_document`)."""
        return files.fit_document(self)

    def write(self, out: str | Path) -> Path:
        """Write the JSON and its sidecar (same name, ``.nc``): :func:`gprm.fit.files.write_fit`.
        """
        return files.write_fit(self, out)
