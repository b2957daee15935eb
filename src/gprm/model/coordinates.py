"""The model's generalised coordinates by name, apart from the symbolic definition (which needs
SymPy) so that the simulator and the fit can name them without importing it.

``COORDINATES`` (9): ``z_lr`` linear-runner axial displacement; ``z_A`` plunger back (point A)
axial displacement relative to the linear runner; ``x_A, y_A`` lateral displacements of A;
``eta`` rotation about y; ``theta`` rotation about x; ``mu3, mu4`` spacer and tip displacements
relative to the plunger along the actuation axis; ``q`` piezo charge. ``MECHANICAL``: the first
eight (gprm.model.definition derives their equations of motion).
"""

from __future__ import annotations

COORDINATES: tuple[str, ...] = ("z_lr", "z_A", "x_A", "y_A", "eta", "theta", "mu3", "mu4", "q")
MECHANICAL: tuple[str, ...] = COORDINATES[:8]
