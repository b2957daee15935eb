"""Model definitions (kinematics and energies), symbolic derivation, generated matrices,
piezo configurations and the state-space form."""

from gprm._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "definition": ["COORDINATES", "DEFINITIONS", "ModelDefinition"],
    "linear": ["STATE_NAMES", "StateSpace", "generated", "state_space"],
    "piezo": ["PIEZOS", "check_piezo"],
})
