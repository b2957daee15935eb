"""Flight analysis (Section 4, Appendix B): impact models, test-mass velocity vs impact time,
release telemetry and velocities, impact times, Tukey's range test, multiple impacts.

Pipeline: :mod:`impact` (models) -> :mod:`predicted` (curves and bands) -> :mod:`telemetry`
(format, units, CSV, release velocities) -> :mod:`impact_time` (crossings, error bars from
the draws) -> :mod:`joint` (one time per release) and :mod:`tukey` -> :mod:`analysis`
(``gprm impact``, :class:`ImpactResult`); :mod:`synth` (``gprm synth telemetry``); :mod:`multi`
(second impacts); :mod:`scenario` (impact scenarios, issue 23) and :mod:`inference` (the
scenario posterior); :mod:`api`: the stage's entry points (:func:`run_impact`,
:func:`write_impact`, :func:`run_synth_telemetry`) with their validated options, which the
commands and ``gprm run`` call. The body kinematics are :mod:`gprm.simulate.kinematics`.
See docs/flight.md.
"""

from gprm._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "analysis": ["AnalysisOptions", "ImpactResult", "analyze"],
    "api": ["ImpactOptions", "TelemetryOptions", "run_impact", "run_synth_telemetry",
            "write_impact"],
    "files": ["impact_curves_dataset", "impact_sidecar", "load_telemetry", "read_impact",
              "read_impact_curves",
              "telemetry_csv_dataset", "telemetry_dataset", "telemetry_from_dataset",
              "write_telemetry"],
    "impact": ["impact_3d", "kinetic_energy", "planar_impact"],
    "impact_time": ["first_crossing", "impact_time_mc"],
    "inference": ["InferenceOptions", "infer_scenarios", "paper_observations",
                  "scenario_document"],
    "joint": ["joint_impact_time"],
    "multi": ["multi_impact_report", "simulate_contacts"],
    "predicted": ["GeometryUncertainty", "ImpactGeometry", "tm_velocity_vs_time",
                  "velocity_curves"],
    "scenario": ["SCENARIOS", "ScenarioPrior", "draw_truths", "impact_3d_two",
                 "scenario_velocity"],
    "synth": ["SynthOptions", "synth_telemetry"],
    "telemetry": ["AXES", "fit_release_velocity", "release_velocities"],
    "tukey": ["tukey_range_test"],
})
