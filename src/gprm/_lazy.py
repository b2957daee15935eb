"""Lazy package attributes (PEP 562): ``from gprm.flight import analyze`` works as
before, but importing the package (as every ``gprm`` command does to register its CLI)
no longer imports numpy, scipy, xarray, pint or sympy. See benchmarks/bench_startup.py."""

from __future__ import annotations

import importlib


def attach(package: str, exports: dict[str, list[str]]):
    """``(__getattr__, __dir__, __all__)`` for ``package`` exporting, per submodule (relative
    name), the listed attributes, each imported on first access."""
    where = {name: mod for mod, names in exports.items() for name in names}
    all_ = sorted(where)

    def __getattr__(name: str):
        mod = where.get(name)
        if mod is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{mod}"), name)

    def __dir__():
        return all_

    return __getattr__, __dir__, all_
