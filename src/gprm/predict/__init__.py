"""predict stage: trajectories with uncertainty bands (Eq. 8, Fig. 10), kinetic-energy check
(Fig. 8), mass comparison (Fig. 7), what-ifs and overshoots (Sec. 4.2), impact risk against a
gap. See docs/prediction.md. Modules (the body kinematics they use are
:mod:`gprm.simulate.kinematics`): ``trajectories``, ``energy``, ``masses``, ``scenarios``,
``whatif``, ``risk``, ``prediction`` (``Prediction`` and its dataset), ``core``
(``predict``), ``files`` (NetCDF), ``commands`` (CLI); the figures are in
:mod:`gprm.report.figures`."""

from gprm._lazy import attach

# ``whatif`` is not re-exported: it is also the name of the submodule, which would shadow it
# once imported (use run_whatif, or import the function from gprm.predict.whatif).

__getattr__, __dir__, __all__ = attach(__name__, {
    "api": ["PredictOptions", "run_predict", "run_whatif"],
    "core": ["Prediction", "predict"],
    "files": ["prediction_dataset"],
    "masses": ["MassRow", "MassTable", "mass_table"],
    "scenarios": ["Scenario", "standard_scenarios"],
    "whatif": ["RatioSensitivity", "Sweep", "WhatIf", "ratio_sensitivity", "sweep"],
})
