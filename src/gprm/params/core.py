"""Parameter sets: one resolved value per parameter (SI), which ones are fitted, and bounds.

A :class:`ParameterSet` is one point; a batch (many sets at once, the normal shape for the
simulator and the fitter) is a plain ``dict[str, np.ndarray]`` made by :func:`batch`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Iterable, Mapping

import numpy as np

from gprm.errors import GprmInputError
from gprm.params.registry import FITTED_DEFAULT, REGISTRY, STRICTLY_POSITIVE


@dataclass(frozen=True)
class ParameterSet:
    """Resolved values (SI) of every parameter in the registry.

    Attributes
    ----------
    values: name -> value, SI.
    fitted: names of the parameters the fitter adjusts, in registry order.
    bounds: name -> (lower, upper), SI, for fitted parameters (the registry's physical bounds
        unless a parameter file narrows them).
    source: where the set came from (``paper`` or a file path), for messages and provenance.
    initial: the initial value (centre of the random starts) of each fitted parameter the
        paper gives none for (the alignment offsets, a geometry value a file fits): the value
        it had when it joined the fitted set, kept when values change later (a fit's best
        values), so that a fit reports where it started, not where it ended.
    """

    values: Mapping[str, float]
    fitted: tuple[str, ...] = FITTED_DEFAULT
    bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    source: str = "paper"
    initial: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "values", MappingProxyType(dict(self.values)))
        b = {n: (REGISTRY[n].lower, REGISTRY[n].upper) for n in self.fitted}
        b.update(self.bounds)
        object.__setattr__(self, "bounds", MappingProxyType(b))
        init = {n: float(v) for n, v in dict(self.initial).items() if n in self.fitted}
        for n in self.fitted:
            if REGISTRY[n].initial is None and n not in init and n in self.values:
                init[n] = float(self.values[n])
        object.__setattr__(self, "initial", MappingProxyType(init))

    def __reduce__(self):  # MappingProxyType does not pickle; needed to ship sets to workers
        return (ParameterSet, (dict(self.values), self.fitted, dict(self.bounds), self.source,
                               dict(self.initial)))

    def __getitem__(self, name: str) -> float:
        return self.values[name]

    def with_values(self, **values: float) -> "ParameterSet":
        """A copy with some values replaced (SI)."""
        unknown = set(values) - set(REGISTRY)
        if unknown:
            raise GprmInputError(f"unknown parameter(s) {sorted(unknown)}", source=self.source)
        new = dict(self.values)
        new.update({k: float(v) for k, v in values.items()})
        out = replace(self, values=new)
        validate_values(out.values, source=self.source)
        return out

    def with_fitted(self, names: Iterable[str]) -> "ParameterSet":
        names = tuple(n for n in REGISTRY if n in set(names))
        return replace(self, fitted=names, bounds={k: v for k, v in self.bounds.items()
                                                   if k in names})

    def vector(self, names: Iterable[str] | None = None) -> np.ndarray:
        names = self.fitted if names is None else tuple(names)
        return np.array([self.values[n] for n in names], dtype=float)

    def with_vector(self, x: np.ndarray, names: Iterable[str] | None = None) -> "ParameterSet":
        names = self.fitted if names is None else tuple(names)
        return self.with_values(**dict(zip(names, map(float, x))))

    def initial_vector(self, names: Iterable[str] | None = None) -> np.ndarray:
        """The paper's initial values (Table 3) where given; else, for a fitted parameter,
        its value when it joined the fitted set (``initial``); else the current value."""
        names = self.fitted if names is None else tuple(names)
        return np.array([REGISTRY[n].initial if REGISTRY[n].initial is not None
                         else self.initial.get(n, self.values[n]) for n in names], dtype=float)

    def paper_stderr(self, names: Iterable[str] | None = None) -> np.ndarray:
        """Table 3 uncertainties (SI); NaN where the paper gives none."""
        names = self.fitted if names is None else tuple(names)
        return np.array([np.nan if REGISTRY[n].paper_stderr is None else REGISTRY[n].paper_stderr
                         for n in names], dtype=float)

    def batch(self, size: int = 1) -> dict[str, np.ndarray]:
        return batch([self] * size)


def paper() -> ParameterSet:
    """The built-in ``paper`` set: Table 2 constants, Table 3 best fit, the assumed values of docs/spec.md."""
    return ParameterSet({n: s.default for n, s in REGISTRY.items()}, source="paper")


def batch(sets: Iterable[ParameterSet] | Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Stack parameter sets into ``{name: array (B,)}``, the batched shape of the simulator."""
    if isinstance(sets, Mapping):
        arrs = {k: np.atleast_1d(np.asarray(v, dtype=float)) for k, v in sets.items()}
        shape = np.broadcast_shapes(*(a.shape for a in arrs.values()))
        return {k: np.broadcast_to(a, shape).copy() for k, a in arrs.items()}
    sets = list(sets)
    if not sets:
        raise ValueError("empty batch")
    return {n: np.array([s.values[n] for s in sets], dtype=float) for n in REGISTRY}


def batch_from_vectors(base: ParameterSet, names: Iterable[str], X: np.ndarray) -> dict[str, np.ndarray]:
    """A batch equal to ``base`` except that parameters ``names`` take the rows of ``X`` (B, P)."""
    X = np.atleast_2d(np.asarray(X, dtype=float))
    out = {n: np.full(X.shape[0], v, dtype=float) for n, v in base.values.items()}
    for j, n in enumerate(names):
        out[n] = X[:, j].copy()
    return out


def validate_values(values: Mapping[str, float], *, source: str = "parameters") -> None:
    """Raise :class:`GprmInputError` for a non-finite or non-physical value."""
    for name, v in values.items():
        spec = REGISTRY.get(name)
        if spec is None:
            raise GprmInputError("unknown parameter", source=source, field=name)
        if not np.isfinite(v):
            raise GprmInputError(f"value {v} is not finite", source=source, field=name)
        if name in STRICTLY_POSITIVE and v <= 0:
            raise GprmInputError(f"must be positive, got {v:g} (SI)", source=source, field=name)
        if v < spec.lower or v > spec.upper:
            raise GprmInputError(
                f"value {v:g} (SI) is outside its physical range [{spec.lower:g}, {spec.upper:g}]",
                source=source, field=name)
