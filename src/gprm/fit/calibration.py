"""Per-parameter scale factors of the default uncertainty (``parametric-bootstrap``), measured
on synthetic campaigns whose truth is known (issue 12, docs/fitting.md "Mismatch calibration").

Why. The parametric bootstrap re-centres the posterior by the bias that the generator's model
mismatch (nonlinear correction, unmodelled 28 kHz mode, flange and runner motion, ...) causes
*at the best fit*. For most parameters that bias changes little between the best fit and the
truth and the re-centred intervals cover. For the x plane's second spring and its damper and
the spacer length (k_Bx, c_Bx, d2) it does not: their estimates move with the x signals'
mutual disagreement, which the bootstrap refits, all started from the best fit and
synthesised from it, do not reproduce. Their refits spread 0.12-0.36 of the posterior
(``benchmarks/bench_bootstrap_rules.py``), while their uncalibrated errors are 2.1-2.4
posterior sd in root mean square (``benchmarks/bench_calibration.py``).

What. For parameter k, F_k is the root mean square over campaigns of the standardised error
z = (centre_k - truth_k) / sd_k of the uncalibrated method (in the prior's coordinates u, the
lags' widening included), floored at 1: the factor by which its intervals were too narrow
on average. :func:`gprm.fit.uncertainty.from_bootstrap` multiplies sd_k by F_k; a parameter
whose widened interval is no longer well inside its prior's is then reported as not
determined. Factors below 1 (parameters the prior dominates) are never applied: intervals are
only ever widened.

Where from. ``.venv/bin/python benchmarks/bench_calibration.py --campaigns 20 --seeds
1000,2000`` (40 campaigns, truths within +-10 % of Table 3, every mismatch ingredient of
``gprm synth campaign`` on, 200 starts, 30 refits), rounded to two decimals.
The factors were checked on campaigns not used to make them (seeds 3000-3019) and
cross-validated (made on one set of 20, tested on the other): docs/fitting.md.

Limits. The factors describe the mismatch the synthetic generator models, fitted with the
default configuration (window, sem weights, alignment offsets). On a real campaign they hold
to the extent its mismatch resembles the generator's; ``gprm fit`` reports them, and
``--uncertainty laplace-prior`` or the profile likelihoods give the uncalibrated view.
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Mapping

import numpy as np

#: F_k > 1 of the module docstring (parameters not listed: 1)
MISMATCH_CALIBRATION: Mapping[str, float] = MappingProxyType({
    "gamma": 1.06, "rho": 1.08, "k_Ax": 1.22, "k_Bx": 2.28, "c_Ax": 1.87, "c_Bx": 2.10,
    "m4": 1.11, "d2": 2.38,
})


def calibration_factors(names, calibration: Mapping[str, float] | None) -> np.ndarray:
    """(P,) factors >= 1 for ``names`` from ``calibration`` (None: no calibration)."""
    table = {} if calibration is None else calibration
    return np.array([max(1.0, float(table.get(n, 1.0))) for n in names])
