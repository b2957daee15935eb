"""Input voltage profiles: the default drop of docs/spec.md and measured oscilloscope traces.

The model sees V(t - t0). Everything is expressed as the *change* from the initial value,
u(s) = V(s) - V(0), where s is the time since the input starts changing, because the system
starts in static equilibrium at V(0).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gprm._io import check_input_file, two_column_rows
from gprm.errors import GprmInputError


def default_voltage(t, params) -> np.ndarray:
    """The default profile V(t) (docs/spec.md): V0 until t_c, then V0*exp(-(t - t_c)/tau_v).

    ``params`` is a ParameterSet or a mapping with V0, t_c, tau_v (scalars or arrays (B,));
    the lag t0 is *not* applied here. Returns V with shape broadcast(params, t).
    """
    V0 = np.asarray(params["V0"], float)[..., None]
    tc = np.asarray(params["t_c"], float)[..., None]
    tau = np.asarray(params["tau_v"], float)[..., None]
    t = np.asarray(t, float)
    s = t - tc
    return np.where(s <= 0, V0, V0 * np.exp(-np.clip(s, 0, None) / tau)).squeeze()


@dataclass(frozen=True)
class VoltageTrace:
    """A measured voltage trace (oscilloscope CSV: time [s], voltage [V]), on the record's
    time base (t = 0 at the start of the record). It is held constant before its first and
    after its last sample and is linear between samples (exact first-order hold)."""

    time: np.ndarray
    voltage: np.ndarray
    source: str = "trace"

    def __post_init__(self):
        t = np.asarray(self.time, float)
        v = np.asarray(self.voltage, float)
        object.__setattr__(self, "time", t)
        object.__setattr__(self, "voltage", v)
        _validate_trace(t, v, self.source)

    @property
    def v_initial(self) -> float:
        return float(self.voltage[0])

    def knots(self, t0: float) -> tuple[np.ndarray, np.ndarray]:
        """Knot times (record time, lag applied) and the change u at each knot."""
        return self.time + t0, self.voltage - self.voltage[0]

    def __call__(self, t) -> np.ndarray:
        return np.interp(t, self.time, self.voltage)


def _validate_trace(t: np.ndarray, v: np.ndarray, source: str) -> None:
    if t.ndim != 1 or v.ndim != 1 or t.size != v.size:
        raise GprmInputError("time and voltage columns must be 1-D of equal length",
                             source=source, field="voltage")
    if t.size < 2:
        raise GprmInputError(f"needs at least 2 samples, got {t.size}", source=source,
                             field="time")
    if not np.all(np.isfinite(t)):
        raise GprmInputError("time column holds NaN or Inf", source=source, field="time")
    if not np.all(np.isfinite(v)):
        raise GprmInputError("voltage column holds NaN or Inf", source=source, field="voltage")
    if np.any(np.diff(t) <= 0):
        i = int(np.argmax(np.diff(t) <= 0))
        raise GprmInputError(f"time is not strictly increasing (row {i + 2})", source=source,
                             field="time")


def read_voltage_csv(path: str | os.PathLike) -> VoltageTrace:
    """Read an oscilloscope CSV with two columns, time [s] and voltage [V]. A header row is
    allowed (any non-numeric first row); blank lines and lines starting with '#' are ignored."""
    path = Path(path)
    src = str(path)

    check_input_file(path, what="voltage file")
    rows, _ = two_column_rows(path, src, "time, voltage", "voltage")
    arr = np.array(rows, dtype=float)
    return VoltageTrace(arr[:, 0], arr[:, 1], source=src)


