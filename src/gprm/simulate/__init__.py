"""Simulation: input profiles and measured traces, the exact batched solver with
sensitivities, the body kinematics of a simulated motion (``kinematics``: attitude, angular
velocity, points of the plunger, kinetic energy; used by predict and flight alike), and
reference integrators for checks."""

from gprm._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "core": ["COORDS", "OUTPUTS", "RATES", "Observation", "SimulationResult", "observe",
             "record_times", "simulate"],
    "inputs": ["VoltageTrace", "default_voltage", "read_voltage_csv"],
    "kinematics": ["BodyPoint", "PlungerMotion", "body_motion", "kinetic_energy",
                   "named_points", "point_motion"],
})
