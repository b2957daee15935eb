"""Mass comparison (paper Fig. 7): fitted masses against the CAD nominal values of Table 3."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Mapping, Sequence

import numpy as np
import xarray as xr

from gprm.errors import GprmInputError
from gprm.fit.files import FittedModel
from gprm.params import REGISTRY

MASSES: tuple[tuple[str, str], ...] = (("m1", "linear runner"), ("m2", "plunger"),
                                       ("m3", "spacer"), ("m4", "tip"))

#: the columns of the table that are masses (kg) and may be missing (None / NaN)
_MASS_COLUMNS = ("fitted", "stderr", "nominal", "paper_3d", "paper_3d_stderr")


@dataclass(frozen=True)
class MassRow:
    """One body (SI, kg): fitted value and stderr (None where the mass was not fitted),
    nominal (Table 3 CAD value, None for m1), the paper's 3D fit and its uncertainty, and
    z = (fitted - nominal) / stderr (None where either is missing)."""

    name: str
    body: str
    unit: str
    fitted: float
    stderr: float | None
    nominal: float | None
    paper_3d: float
    paper_3d_stderr: float | None
    z_vs_nominal: float | None
    source: str

    def to_json(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class MassTable:
    """The mass comparison of a fitted model, one :class:`MassRow` per body (Fig. 7).
    ``to_json()``: a list of rows (JSON-able); ``to_xarray()``: the columns along ``body``."""

    rows: tuple[MassRow, ...]

    def __iter__(self):
        return iter(self.rows)

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, name: str) -> MassRow:
        for r in self.rows:
            if r.name == name:
                return r
        raise KeyError(name)

    def to_json(self) -> list[dict]:
        return [r.to_json() for r in self.rows]

    @classmethod
    def from_json(cls, rows: Sequence[Mapping]) -> "MassTable":
        try:
            return cls(tuple(MassRow(**dict(r)) for r in rows))
        except TypeError as exc:
            raise GprmInputError(f"not a mass table row ({exc})", field="masses") from None

    def to_xarray(self) -> xr.Dataset:
        a = mass_arrays(self)
        dv = {k: (("body",), a[k], {"units": "kg"}) for k in _MASS_COLUMNS}
        dv["z_vs_nominal"] = (("body",), np.array(
            [np.nan if r.z_vs_nominal is None else r.z_vs_nominal for r in self.rows], float),
            {"units": "1"})
        return xr.Dataset(dv, coords={"body": a["names"],
                                      "body_name": ("body", [r.body for r in self.rows])},
                          attrs={"source": self.rows[0].source if self.rows else ""})


def mass_table(fm: FittedModel) -> MassTable:
    """The mass comparison of ``fm`` (see :class:`MassTable`)."""
    names = fm.names
    se = fm.stderr
    rows = []
    for name, body in MASSES:
        spec = REGISTRY[name]
        s = float(se[names.index(name)]) if name in names else None
        v = float(fm.params[name])
        nom = spec.nominal
        z = None
        if nom is not None and s is not None and s > 0:
            z = (v - nom) / s
        rows.append(MassRow(name=name, body=body, unit="kg", fitted=v, stderr=s, nominal=nom,
                            paper_3d=spec.default, paper_3d_stderr=spec.paper_stderr,
                            z_vs_nominal=z, source=fm.source))
    return MassTable(tuple(rows))


def mass_arrays(rows: MassTable | Sequence[Mapping]) -> dict[str, np.ndarray]:
    """The table (a :class:`MassTable` or its JSON rows) as arrays (body,) with NaN for
    missing values (for NetCDF)."""
    if isinstance(rows, MassTable):
        rows = rows.to_json()

    def col(k):
        return np.array([np.nan if r[k] is None else r[k] for r in rows], float)

    return {"names": np.array([r["name"] for r in rows]), "fitted": col("fitted"),
            "stderr": col("stderr"), "nominal": col("nominal"), "paper_3d": col("paper_3d"),
            "paper_3d_stderr": col("paper_3d_stderr")}
