"""report stage: the figures of gprm (:mod:`gprm.report.figures`, one function per figure of
the paper, used by the report and by library users) and the self-contained HTML report of a
run directory (:mod:`gprm.report.build`)."""

from gprm._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "build": ["write_report"],
    "figures": ["COLORS", "fig_energy", "fig_fit", "fig_impact_times", "fig_masses",
                "fig_mean_signals", "fig_profiles", "fig_release_fit", "fig_residuals",
                "fig_sweep", "fig_trajectories", "fig_velocity_impact", "fig_waterfall",
                "waterfall", "waterfall_counts"],
    "summary": ["summarise"],
})
