"""Model definitions (kinematics and energies), symbolic derivation, generated matrices,
piezo configurations and the state-space form."""

from gprm.model.definition import COORDINATES, DEFINITIONS, ModelDefinition
from gprm.model.linear import STATE_NAMES, StateSpace, generated, state_space

__all__ = ["COORDINATES", "DEFINITIONS", "ModelDefinition", "STATE_NAMES", "StateSpace",
           "generated", "state_space"]
