"""Mass comparison (paper Fig. 7): fitted masses against the CAD nominal values of Table 3."""

from __future__ import annotations

import numpy as np

from gprm.fit.files import FittedModel
from gprm.params import REGISTRY

MASSES: tuple[tuple[str, str], ...] = (("m1", "linear runner"), ("m2", "plunger"),
                                       ("m3", "spacer"), ("m4", "tip"))


def mass_table(fm: FittedModel) -> list[dict]:
    """One row per body (SI, kg): fitted value and stderr (NaN -> None where the mass was not
    fitted), nominal (Table 3 CAD value, None for m1), the paper's 3D fit and its uncertainty,
    and z = (fitted - nominal) / stderr. JSON-able."""
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
        rows.append({"name": name, "body": body, "unit": "kg", "fitted": v, "stderr": s,
                     "nominal": nom, "paper_3d": spec.default,
                     "paper_3d_stderr": spec.paper_stderr, "z_vs_nominal": z,
                     "source": fm.source})
    return rows


def mass_arrays(rows: list[dict]) -> dict[str, np.ndarray]:
    """The table as arrays (body,) with NaN for missing values (for NetCDF)."""
    def col(k):
        return np.array([np.nan if r[k] is None else r[k] for r in rows], float)

    return {"names": np.array([r["name"] for r in rows]), "fitted": col("fitted"),
            "stderr": col("stderr"), "nominal": col("nominal"), "paper_3d": col("paper_3d"),
            "paper_3d_stderr": col("paper_3d_stderr")}
