"""Shared fixtures of the prediction tests."""

import numpy as np
import pytest

from gprm.fit.files import paper_model


@pytest.fixture(scope="session")
def fm():
    return paper_model()


@pytest.fixture(scope="session")
def times():
    return np.linspace(0.95e-3, 1.2e-3, 251)
