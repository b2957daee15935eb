"""The simulation API: parameter sets in, coordinates and measured points (Eq. 3) out.

``simulate`` is what users and later stages call; ``observe`` is the lean entry the fitter
uses (only the requested observables, with sensitivities, for a whole batch of sets).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from gprm.errors import GprmInputError
from gprm.model.coordinates import COORDINATES, MECHANICAL
from gprm.model.linear import NSTATE, STATE_NAMES, descriptor
from gprm.params import ParameterSet, batch
from gprm.params.registry import ALIGNMENT_OFFSETS
from gprm.simulate import modal
from gprm.simulate.inputs import VoltageTrace, default_voltage

OUTPUTS: tuple[str, ...] = ("x_base", "x_head", "y_base", "y_head", "z_bk")
"""The five measured points fitted (paper Eq. 3)."""

COORDS: tuple[str, ...] = COORDINATES          # the model's coordinates (gprm.model.coordinates)
RATES: tuple[str, ...] = tuple(f"{c}_dot" for c in MECHANICAL)   # the simulated rates
_IDX = {n: i for i, n in enumerate(STATE_NAMES)}

# Eq. 3 with the physically consistent sign for y (docs/spec.md): name -> [(state, coef), ...]
_OUTPUT_DEF = {
    "x_base": [("x_A", None), ("eta", "d_x_base")],
    "x_head": [("x_A", None), ("eta", "d_x_head")],
    "y_base": [("y_A", None), ("theta", "-d_y_base")],
    "y_head": [("y_A", None), ("theta", "-d_y_head")],
}


# Extra lag of a measured point behind the common lag t0, as a sum of parameters: z_bk lags
# by t1 (Eq. 3); x_head, y_base, y_head by their alignment offsets (docs/model.md, "Per-signal
# alignment offsets"); x_base is the reference. Coordinates and rates have no extra lag.
ROW_LAGS: dict[str, tuple[str, ...]] = {
    "z_bk": ("t1",),
    **{point: (offset,) for point, offset in ALIGNMENT_OFFSETS.items()},
}


def observation_rows(pb: Mapping[str, np.ndarray], names: Sequence[str], *,
                     z_bk_absolute: bool = False):
    """Rows H (B, n_obs, 17) over the state, each row's lag and dH/dp for output-map params.

    Names: any state (``z_lr``, ..., ``mu4``, ``q``), state rate (``eta_dot``, ...), or output
    (Eq. 3). ``z_bk`` is z_A(t - t1), or (z_lr + z_A)(t - t1) with ``z_bk_absolute``.
    Returns ``(H, lags, dH)``: ``lags[r]`` is a tuple of parameter names whose sum is row r's
    extra lag behind t0 (``ROW_LAGS``; empty for no extra lag).
    """
    Bn = pb["t0"].shape[0]
    H = np.zeros((Bn, len(names), NSTATE))
    lags = tuple(ROW_LAGS.get(name, ()) for name in names)
    dH: dict[str, np.ndarray] = {}
    for r, name in enumerate(names):
        if name in _IDX:
            H[:, r, _IDX[name]] = 1.0
        elif name == "z_bk":
            H[:, r, _IDX["z_A"]] = 1.0
            if z_bk_absolute:
                H[:, r, _IDX["z_lr"]] = 1.0
        elif name in _OUTPUT_DEF:
            for state, coef in _OUTPUT_DEF[name]:
                if coef is None:
                    H[:, r, _IDX[state]] = 1.0
                else:
                    sign = -1.0 if coef.startswith("-") else 1.0
                    pname = coef.lstrip("-")
                    H[:, r, _IDX[state]] = sign * pb[pname]
                    dH.setdefault(pname, np.zeros_like(H))[:, r, _IDX[state]] = sign
        else:
            raise GprmInputError(f"unknown observable {name!r}", field="observable")
    return H, lags, dH


@dataclass(frozen=True)
class Observation:
    """y (B, n_obs, T) and sensitivities dy (B, n_obs, T, P) (the fitter's Jacobian shape)."""

    names: tuple[str, ...]
    time: np.ndarray
    y: np.ndarray
    dy: np.ndarray | None
    sens_names: tuple[str, ...]
    ok: np.ndarray
    reason: np.ndarray
    prepared: "Prepared | None" = None


@dataclass(frozen=True)
class Prepared:
    """What :func:`observe` computes from the parameter sets alone, before any time, output
    or sensitivity: the sets as simulated (sets with a singular mass matrix swapped for a good
    one), which of them are singular, and their :class:`~gprm.simulate.modal.Spectrum`.
    Handing it back to ``observe`` for the same sets (``take`` selects rows) skips that work;
    the results are bit for bit those of a fresh call."""

    pb: dict
    singular: np.ndarray
    spectrum: modal.Spectrum
    convolutions: "modal.Convolutions | None" = None

    def take(self, rows) -> "Prepared":
        rows = np.asarray(rows)
        n = self.singular.shape[0]
        pb = {k: (v[rows] if np.shape(v)[:1] == (n,) else v) for k, v in self.pb.items()}
        conv = None if self.convolutions is None else self.convolutions.take(rows)
        return Prepared(pb, self.singular[rows], self.spectrum.take(rows), conv)


def observe(pb: dict[str, np.ndarray], times, names: Sequence[str] = OUTPUTS, *,
            piezo: int = 2, voltage: VoltageTrace | None = None,
            sensitivities: Sequence[str] = (), z_bk_absolute: bool = False,
            prepared: Prepared | None = None,
            keep_convolutions: bool = False) -> Observation:
    """Batched exact simulation of ``names`` at ``times`` for parameter batch ``pb``.

    Sets that cannot be simulated (unstable, singular, degenerate eigenvalues) are returned
    as NaN with ``ok[b] = False`` and a ``reason``; nothing is raised for them.

    Every row is evaluated at its own lag: t0 for all (through the input), plus t1 for
    ``z_bk`` and the alignment offsets ``dt_x_head``, ``dt_y_base``, ``dt_y_head`` for those
    points (``ROW_LAGS``; a missing offset in ``pb`` counts as 0). Sensitivities may name any
    of them.

    ``prepared``: the ``.prepared`` of an earlier call for the same sets (or its ``take`` of
    some of them), to skip the eigen-decomposition; ``pb`` must still be those sets.
    ``keep_convolutions``: keep the modal convolutions in ``.prepared`` too
    (:class:`~gprm.simulate.modal.Convolutions`), so that a call for the same sets and times
    with sensitivities computes only their derivative in the modes (the fit's Jacobian at a
    point whose residuals it just evaluated; bit for bit the same result). Off by default:
    they are several times the size of the outputs.
    """
    pb = {k: np.atleast_1d(np.asarray(v, float)) for k, v in pb.items()}
    times = np.asarray(times, float)
    H, lags, dH = observation_rows(pb, names, z_bk_absolute=z_bk_absolute)
    conv = None
    if prepared is None:
        pb, singular, desc = _guard_singular(pb, piezo)
        spec = None
    else:
        pb, singular, desc, spec = prepared.pb, prepared.singular, None, prepared.spectrum
        conv = prepared.convolutions
    sol = modal.solve(pb, times, H, lags, piezo=piezo, trace=voltage,
                      sens=tuple(sensitivities), dH=dH, desc=desc, spec=spec, conv=conv,
                      keep_conv=keep_convolutions)
    ok, reason = sol.ok.copy(), sol.reason.copy()
    y, dy = sol.y, sol.dy
    if singular.any():
        ok &= ~singular
        reason[singular] = "singular mass matrix"
        y[singular] = np.nan
        if dy is not None:
            dy[singular] = np.nan
    dy_out = dy
    assert sol.spectrum is not None  # solve() always hands back the batch's spectrum
    return Observation(tuple(names), times, y, dy_out, tuple(sensitivities), ok, reason,
                       Prepared(pb, singular, sol.spectrum, sol.convolutions))


def _guard_singular(pb, piezo):
    """Detect sets whose mass matrix (the descriptor E) is singular or indefinite, and swap
    in a good set for them (their results are masked later). Returns the descriptor too."""

    desc = descriptor(pb, piezo)
    Evv = desc[0][:, 8:16, 8:16]
    with np.errstate(all="ignore"):
        ev = np.linalg.eigvalsh(Evv)
        rq = desc[0][:, 16, 16]
    singular = ~((ev[:, 0] > 1e-12 * np.abs(ev[:, -1])) & (rq > 0))
    if singular.any() and not singular.all():
        good = int(np.argmax(~singular))
        pb = {k: np.where(singular, v[good], v) for k, v in pb.items()}
        desc = descriptor(pb, piezo)
    return pb, singular, desc


@dataclass(frozen=True)
class SimulationResult:
    """A simulated record: coordinates, their rates, the measured points and the input.

    All arrays are (B, T) changes from the initial static equilibrium at V(0); ``voltage`` is
    the input as applied (after the lag t0).
    """

    time: np.ndarray
    coords: dict
    rates: dict
    outputs: dict
    voltage: np.ndarray
    piezo: int
    ok: np.ndarray
    reason: np.ndarray
    sensitivities: dict | None = None
    sens_names: tuple[str, ...] = ()


def _as_batch(params) -> dict[str, np.ndarray]:
    if isinstance(params, ParameterSet):
        return batch([params])
    return batch(params)


def record_times(t_end: float = 1.2e-3, rate: float = 200e3) -> np.ndarray:
    if not (t_end > 0 and np.isfinite(t_end)):
        raise GprmInputError(f"must be positive, got {t_end}", field="t_end")
    if not (rate > 0 and np.isfinite(rate)):
        raise GprmInputError(f"must be positive, got {rate}", field="rate")
    n = int(np.floor(t_end * rate + 1e-9)) + 1
    return np.arange(n) / rate


def simulate(params, *, piezo: int = 2, time=None, t_end: float = 1.2e-3,
             rate: float = 200e3, voltage: VoltageTrace | None = None,
             sensitivities: Sequence[str] = (), z_bk_absolute: bool = False,
             strict: bool = True) -> SimulationResult:
    """Simulate the tip retraction for one parameter set or a batch.

    params: a ParameterSet or a batch ``{name: array (B,)}``. time: record times (s);
    default 0..t_end at ``rate``. With ``strict`` a set that cannot be simulated raises
    :class:`GprmInputError` naming the reason; otherwise it comes back as NaN with ``ok`` False.
    """
    pb = _as_batch(params)
    times = record_times(t_end, rate) if time is None else np.asarray(time, float)
    names = COORDS + RATES + OUTPUTS
    obs = observe(pb, times, names, piezo=piezo, voltage=voltage, sensitivities=sensitivities,
                  z_bk_absolute=z_bk_absolute)
    if strict and not obs.ok.all():
        b = int(np.argmin(obs.ok))
        src = params.source if isinstance(params, ParameterSet) else "parameters"
        raise GprmInputError(f"parameter set {b} cannot be simulated: {obs.reason[b]}",
                             source=src, field="parameters")
    k = {n: i for i, n in enumerate(names)}
    t0 = pb["t0"][:, None]
    if voltage is None:
        v = default_voltage(times[None, :] - t0, pb)
        v = np.broadcast_to(v, (pb["t0"].shape[0], times.size))
    else:
        v = voltage(times[None, :] - t0)
    sens = None
    if sensitivities:
        assert obs.dy is not None  # observe() returns dy when sensitivities are asked for
        sens = {n: obs.dy[:, k[n]] for n in names}
    return SimulationResult(
        time=times,
        coords={n: obs.y[:, k[n]] for n in COORDS},
        rates={n: obs.y[:, k[n]] for n in RATES},
        outputs={n: obs.y[:, k[n]] for n in OUTPUTS},
        voltage=np.array(v, float),
        piezo=piezo, ok=obs.ok, reason=obs.reason, sensitivities=sens,
        sens_names=tuple(sensitivities))
