"""Flight analysis (Section 4, Appendix B): impact models, test-mass velocity vs impact time,
release telemetry and velocities, impact times, Tukey's range test, multiple impacts.

Pipeline: :mod:`impact` (models) -> :mod:`predicted` (curves and bands) -> :mod:`telemetry`
(format, units, CSV, release velocities) -> :mod:`impact_time` (crossings, error bars from
the draws) -> :mod:`joint` (one time per release) and :mod:`tukey` -> :mod:`analysis`
(``gprm impact``); :mod:`synth` (``gprm synth telemetry``); :mod:`multi`
(second impacts). See docs/flight.md.
"""

from gprm.flight.analysis import AnalysisOptions, analyze, curves_dataset
from gprm.flight.impact import impact_3d, kinetic_energy, planar_impact
from gprm.flight.impact_time import first_crossing, impact_time_mc
from gprm.flight.joint import joint_impact_time
from gprm.flight.multi import multi_impact_report, simulate_contacts
from gprm.flight.predicted import (GeometryUncertainty, ImpactGeometry, tm_velocity_vs_time,
                                   velocity_curves)
from gprm.flight.synth import SynthOptions, synth_telemetry
from gprm.flight.telemetry import (AXES, fit_release_velocity, load_telemetry,
                                   release_velocities, telemetry_csv_dataset,
                                   telemetry_dataset)
from gprm.flight.tukey import tukey_range_test

__all__ = ["AXES", "AnalysisOptions", "GeometryUncertainty", "ImpactGeometry", "SynthOptions",
           "analyze", "curves_dataset", "first_crossing", "fit_release_velocity",
           "impact_3d", "impact_time_mc", "joint_impact_time", "kinetic_energy",
           "load_telemetry", "multi_impact_report",
           "planar_impact", "release_velocities", "simulate_contacts", "synth_telemetry",
           "telemetry_csv_dataset", "telemetry_dataset", "tm_velocity_vs_time",
           "tukey_range_test", "velocity_curves"]
