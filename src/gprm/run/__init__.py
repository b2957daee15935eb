"""The whole chain on a campaign, into one resumable run directory (``gprm run``; ``gprm
demo`` is the same on a generated campaign):

campaign -> preprocess -> fit -> predict (+ what-ifs) -> telemetry (the user's, or synthetic
releases drawn from the fit) -> impact + Tukey test -> report.

Layers: :mod:`gprm.run.options` (:class:`RunOptions`, built from the stages' own option
dataclasses), :mod:`gprm.run.stages` (one adapter per stage over its library entry point),
:mod:`gprm.run.engine` (the resumable runner; it calls the report last). The report never
imports this package; the commands (``gprm run``, ``gprm demo``) only call :func:`run_chain`.
"""

from gprm._lazy import attach

# lazy (PEP 562): importing the package, as the CLI does to register ``gprm run``, loads no
# numerical library; the names below import their module on first use
__getattr__, __dir__, __all__ = attach(__name__, {
    "api": ["run_chain", "run_demo"],
    "engine": ["RUN_JSON", "RunResult", "Stage", "StageRecord"],
    "options": ["RunOptions"],
    "stages": ["NO_UNCERTAINTY", "chain", "model_notes", "stage_titles"],
})
