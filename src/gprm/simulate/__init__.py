"""Simulation: input profiles and measured traces, the exact batched solver with
sensitivities, and reference integrators for checks."""

from gprm.simulate.core import (COORDS, OUTPUTS, RATES, Observation, SimulationResult,
                                observe, record_times, simulate)
from gprm.simulate.inputs import VoltageTrace, default_voltage, read_voltage_csv

__all__ = ["COORDS", "OUTPUTS", "RATES", "Observation", "SimulationResult", "VoltageTrace",
           "default_voltage", "observe", "read_voltage_csv", "record_times", "simulate"]
