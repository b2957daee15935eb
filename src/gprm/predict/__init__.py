"""predict stage: trajectories with uncertainty bands (Eq. 8, Fig. 10), kinetic-energy check
(Fig. 8), mass comparison (Fig. 7), what-ifs and overshoots (Sec. 4.2), impact risk against a
gap. See docs/prediction.md. Modules (the body kinematics they use are
:mod:`gprm.simulate.kinematics`): ``trajectories``, ``energy``, ``masses``, ``scenarios``, ``whatif``, ``risk``, ``core``
(``predict``), ``files`` (NetCDF), ``commands`` (CLI); the figures are in :mod:`gprm.report.figures`."""

from gprm._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "api": ["PredictOptions", "run_predict", "run_whatif"],
})
