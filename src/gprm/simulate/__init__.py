"""Simulation: input profiles and measured traces, the exact batched solver with
sensitivities, and reference integrators for checks."""

from gprm._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "core": ["COORDS", "OUTPUTS", "RATES", "Observation", "SimulationResult", "observe",
             "record_times", "simulate"],
    "inputs": ["VoltageTrace", "default_voltage", "read_voltage_csv"],
})
