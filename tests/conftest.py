"""Fixtures shared by the test folders (kept tiny)."""

import numpy as np
import pytest


@pytest.fixture
def random_sets():
    """``make(n, seed, spread=0.2)``: ParameterSets near the paper set, every value (not only
    the fitted ones) scaled by an independent U(1 - spread, 1 + spread) factor."""
    from gprm.params import paper

    def make(n, seed, spread=0.2):
        base = paper()
        rng = np.random.default_rng(seed)
        return [base.with_values(**{k: v * (1 + spread * rng.uniform(-1, 1))
                                    for k, v in base.values.items()}) for _ in range(n)]

    return make
