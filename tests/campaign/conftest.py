"""Campaigns shared by the campaign tests (generated once per session; a few seconds)."""

import pytest

from gprm.campaign.preprocess import preprocess
from gprm.campaign.synth import SynthConfig, synth_campaign


@pytest.fixture(scope="session")
def full_campaign():
    """The default synthetic campaign (what the demo uses): every ingredient on, including
    the nonlinear correction."""
    return synth_campaign(seed=7)


@pytest.fixture(scope="session")
def full_means(full_campaign):
    return preprocess(full_campaign)


@pytest.fixture(scope="session")
def amp_campaign():
    """Run-to-run variability of the amplitude (voltage drop) only: every run is then an
    exactly shifted, scaled copy of one response plus noise and drift, so the injected trigger
    offsets are the true relative shifts. Noise, drift, higher mode, flange/runner all on."""
    return synth_campaign(seed=11, config=SynthConfig(tau_rel=0.0, param_rel=0.0,
                                                      nonlinear=False))


@pytest.fixture(scope="session")
def amp_means(amp_campaign):
    return preprocess(amp_campaign)


@pytest.fixture(scope="session")
def small_campaign():
    """A quick campaign (no nonlinear correction, 4 + 2 runs) for file and error tests."""
    return synth_campaign(seed=3, config=SynthConfig(n_runs=4, n_noise=2, nonlinear=False))
