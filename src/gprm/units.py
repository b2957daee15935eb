"""The one pint unit registry of the package.

It lives below every stage so that the low-level helpers (:mod:`gprm.options`,
:mod:`gprm.validate`) can read quantities without importing a stage; parameter files
(:mod:`gprm.params.files`) use the same registry and re-export it as ``ureg``. pint is
imported only by modules that read units, so importing this module is kept out of the
command start-up path.
"""

from __future__ import annotations

import functools

import pint


@functools.lru_cache(maxsize=1)
def ureg() -> pint.UnitRegistry:
    """The shared registry (created once, on first use)."""
    return pint.UnitRegistry()
