"""The preprocessing's alignment leaves an exact-model campaign exactly fittable.

An exact-model campaign (gprm's generator with every imperfection off) with almost no noise
(1e-13 m) is aligned with a threshold well above that noise (1e-9 m, the threshold of the
default white noise), so that the crossing lies a few samples after the onset, at a sub-sample
phase. Its fit must return the truth: any deterministic error the alignment adds is then the
only misfit. Shifting the runs by a sub-sample amount interpolated them across the onset's
kink and put k_lr and m1 2.5e-4 and 1.4e-4 above their truth (about one sd of a fit at the
default noise); shifting by whole samples leaves them exact (docs/data-formats.md, step 3).
"""

from dataclasses import replace

import numpy as np

from gprm.campaign.preprocess import PreprocessConfig, preprocess
from gprm.campaign.synth import SynthConfig, synth_campaign
from gprm.fit.api import FitOptions
from gprm.fit.identify import identify
from gprm.fit.objective import fit_data_from_means
from gprm.fit.starts import MultiStartOptions
from gprm.params import paper

EXACT = dict(nonlinear=False, mode_rel=0.0, trigger_max=0.0, v0_rel=0.0, tau_rel=0.0,
             param_rel=0.0, noise_white=1e-13, noise_coloured=0.0, drift_offset=0.0,
             drift_ramp=0.0, drift_sine=0.0)


def test_exact_campaign_fits_to_its_truth_after_alignment():
    truth = paper()
    camp = synth_campaign(truth, seed=5, config=replace(SynthConfig(), **EXACT))
    means = preprocess(camp, PreprocessConfig(threshold_factor=1e4)).to_dataset()
    dt = float(means["time"][1] - means["time"][0])
    # the crossing sits at a sub-sample phase of the record: the case that interpolated
    ct = means["crossing_time"].values
    assert np.all(np.abs(ct - 1.01e-3) <= 0.5 * dt + 1e-12)
    opts = FitOptions()
    fit = identify(fit_data_from_means(means, window=opts.window, sigma=opts.sigma),
                   opts.parameters(paper()), MultiStartOptions(n_starts=20, seed=5),
                   band_samples=0, uncertainty="eq7", prior_width=opts.prior_width)
    x = dict(zip(fit.names, np.asarray(fit.x)))
    for name in ("k_lr", "m1", "m2", "k_Ax", "v2", "rho"):
        assert abs(x[name] / truth[name] - 1) < 2e-5, (name, x[name] / truth[name] - 1)
