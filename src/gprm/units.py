"""The one pint unit registry of the package, and the units every command meets without it.

It lives below every stage so that the low-level helpers (:mod:`gprm.options`,
:mod:`gprm.validate`) can read quantities without importing a stage; parameter files
(:mod:`gprm.params.files`) use the same registry and re-export it as ``ureg``.

Building pint's registry costs about 0.45 s (its import 0.13 s, the definitions 0.31 s,
measured on the 2-core development machine), more than anything else a light command does. The
units a command meets on its default path (the parameter registry's display units, the
prefixed seconds of ``--window 0.97ms,1.2ms``, the SI units of a file's ``units`` attribute)
are therefore also listed in :data:`KNOWN` with their factor to SI and their SI unit as pint
writes it; tests/test_units.py checks every entry against pint (factor equal to the bit, SI
unit string equal), so the table cannot drift from pint's definitions. Anything not in the
table goes to pint, as before.
"""

from __future__ import annotations

import functools
import math
import re
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import pint

#: unit (as typed, pint syntax) -> (factor to SI, the SI unit as ``f"{q.units:~}"`` writes it
#: without spaces). The parameter registry's display units and the SI-prefixed forms of the
#: base units the command line takes.
KNOWN: dict[str, tuple[float, str]] = {
    # time
    "s": (1.0, "s"), "ms": (1e-3, "s"), "us": (1e-6, "s"), "ns": (1e-9, "s"),
    # length
    "m": (1.0, "m"), "mm": (1e-3, "m"), "um": (1e-6, "m"), "nm": (1e-9, "m"),
    # angle
    "rad": (1.0, "rad"), "mrad": (1e-3, "rad"), "urad": (1e-6, "rad"),
    "deg": (math.pi / 180.0, "rad"),
    # frequency
    "Hz": (1.0, "1/s"), "kHz": (1e3, "1/s"), "MHz": (1e6, "1/s"),
    # mass and inertia
    "kg": (1.0, "kg"), "g": (1e-3, "kg"), "kg*m^2": (1.0, "kg*m**2"),
    # mechanics
    "N/m": (1.0, "kg/s**2"), "N*s/m": (1.0, "kg/s"),
    # electrical
    "V": (1.0, "kg*m**2/A/s**3"), "mV": (1e-3, "kg*m**2/A/s**3"),
    "kV": (1e3, "kg*m**2/A/s**3"), "F": (1.0, "A**2*s**4/kg/m**2"),
    "ohm": (1.0, "kg*m**2/A**2/s**3"), "C/m": (1.0, "A*s/m"),
}

_NUMBER_UNIT = re.compile(r"^\s*([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)\s*(\S+)\s*$")


@functools.lru_cache(maxsize=1)
def ureg() -> "pint.UnitRegistry":
    """The shared registry (created once, on first use)."""
    import pint

    return pint.UnitRegistry()


def known_factor(unit: str, si: str | None = None) -> float | None:
    """The factor from ``unit`` to SI where :data:`KNOWN` holds it (and, with ``si``, where
    its SI unit is the one of ``si``, itself a known unit); None otherwise (ask pint)."""
    entry = KNOWN.get(str(unit).strip())
    if entry is None:
        return None
    if si is not None:
        target = KNOWN.get(str(si).strip())
        if target is None or target[1] != entry[1]:
            return None
        return entry[0] / target[0]
    return entry[0]


def si_unit(unit: str) -> str:
    """The SI unit of ``unit`` as pint writes it abbreviated, without spaces (``"kg/s"`` for
    ``"N*s/m"``; ``""`` when dimensionless): from :data:`KNOWN` where it is listed, else
    pint's."""
    if unit in KNOWN:
        return KNOWN[unit][1]
    q = ureg().Quantity(1.0, unit).to_base_units()
    return f"{q.units:~}".replace(" ", "")


def known_quantity(text: str, si: str) -> float | None:
    """``'0.97 ms'`` or ``'0.97ms'`` -> its value in the SI unit ``si`` where the unit is in
    :data:`KNOWN` with the same SI unit as ``si`` (None otherwise: ask pint). The product
    is pint's: the number times the same factor."""
    m = _NUMBER_UNIT.match(str(text))
    if m is None:
        return None
    f = known_factor(m.group(2), si)
    return None if f is None else float(m.group(1)) * f


def known_unit(text: str) -> str | None:
    """The unit of ``'1.2 ms'`` as typed where it is in :data:`KNOWN` (None otherwise)."""
    m = _NUMBER_UNIT.match(str(text))
    return m.group(2) if m is not None and m.group(2) in KNOWN else None
