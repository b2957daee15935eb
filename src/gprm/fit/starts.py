"""Starting points of the multi-start identification (paper Sec. 3.1: random starts within
±20 % of the initial values; the smallest chi-square is the best fit): the options, the draw,
the replacement of starts the model cannot evaluate, the early stop of far starts, the
optional racing of starts within a chunk, and the outcome of every start. The execution (chunks, BLAS, checkpoints, Dask) is
:mod:`gprm.fit.engine`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from gprm.errors import GprmInputError
from gprm.fit.objective import Objective

MAX_RESAMPLE = 5

#: the default racing schedule (:func:`make_race_rule`): none. Racing by chi-square rank
#: loses the best start on campaigns whose best start climbs from the back of the field late
#: (measured on 20 campaigns: docs/fitting.md, "Racing"), so it is opt-in.
DEFAULT_RACE: tuple[tuple[int, int], ...] = ()


@dataclass(frozen=True)
class LMOptions:
    """Options of Algorithm 1 used for every start (see :mod:`gprm.fit.lm`).

    The stopping rule of an accepted step is ``|d chi2| <= ftol * chi2 + ftol_abs``
    (epsilon_1 of Algorithm 1). The default absolute part, 1e-3, is far below the
    Delta chi2 = 1 that separates statistically distinguishable fits. ``ftol_reduced`` > 0
    raises the relative part to ``ftol_reduced / dof`` (a change in units of the reduced
    chi-square, see :meth:`for_starts`); it is off by default because on a campaign with model
    mismatch (reduced chi-square ~250) 1e-3 stopped the creeping starts early and the best of
    100 starts came out 134 higher in chi-square (0.5 in reduced units), for 28 % less time.
    The best start is polished with a tight tolerance (:func:`gprm.fit.engine.polish_best`)
    before the uncertainties are computed.

    ``stall_window``/``stall_tol``: a start whose chi-square fell by at most ``stall_tol``
    over its last ``stall_window`` iterations stops (status ``stalled``). The starts' job is
    to find the basin of the smallest chi-square, not to converge each of them to machine
    precision: on the demo campaign many starts otherwise creep along a flat
    valley (the weakly determined y-plane parameters) by a few thousandths of chi-square per
    iteration until the iteration limit, already at the best minimum. The default, 0.03 over
    3 iterations (a mean 0.01 per iteration, a hundredth of the Delta chi2 = 1 that separates
    distinguishable fits; a rejected step counts as an iteration that gained nothing, so three
    rejections in a row also stop a start), finds the same best start on the demo's fit in
    about a third of the time no window takes (``benchmarks/bench_fit.py --variants``); it
    replaced 0.05 over 5 at stop 55, measured on 20 campaigns with 1000 starts
    (docs/fitting.md, "The 10-start fit and 1000 starts").

    ``damping``/``geodesic``: the optimizer variants of :mod:`gprm.fit.lm`; the
    identification keeps plain Algorithm 1 (measured by the same command).
    """

    max_iter: int = 100
    lambda0: float = 1e-2
    ftol: float = 1e-8
    ftol_abs: float = 1e-3
    chi2_tol: float = 0.0     # stop when chi-square falls below (epsilon_2)
    lambda_max: float = 1e12
    residual_trials: bool = True   # trial points: residuals only, Jacobian if accepted
    ftol_reduced: float = 0.0
    stall_window: int = 3
    stall_tol: float = 0.03
    damping: str = "current"       # Algorithm 1; "max": MINPACK's scale (gprm.fit.lm)
    geodesic: bool = False         # geodesic acceleration (gprm.fit.lm); off, as measured

    def as_kwargs(self) -> dict:
        d = asdict(self)
        d.pop("residual_trials")
        d.pop("ftol_reduced")
        return d

    def for_starts(self, dof: int) -> dict:
        """Keyword arguments of the multi-start runs for a fit with ``dof`` degrees of
        freedom."""
        d = self.as_kwargs()
        if self.ftol_reduced > 0:
            d["ftol"] = max(self.ftol, self.ftol_reduced / max(int(dof), 1))
        return d


@dataclass(frozen=True)
class MultiStartOptions:
    n_starts: int = 1000
    seed: int = 0
    spread: float = 0.2
    sampling: str = "uniform"     # or "lhs" (Latin hypercube)
    chunk_size: int = 250         # starts per lock-step batch (one task; see docs/fitting.md)
    lm: LMOptions = field(default_factory=LMOptions)
    prune_after: int = 10         # 0: never prune (see make_prune_rule)
    prune_factor: float = 100.0
    prune_rate_window: int = 10   # 0: no rate rule (see make_prune_rule)
    #: racing within each chunk: (after this many iterations, keep this many of the chunk's
    #: running starts) pairs; () runs every start to its own stop (see make_race_rule)
    race: tuple[tuple[int, int], ...] = DEFAULT_RACE


@dataclass(frozen=True)
class StartsOutcome:
    """Every start's initial and final point (physical units), chi-square, iterations and
    outcome. Arrays are indexed by start."""

    names: tuple[str, ...]
    x0: np.ndarray
    x: np.ndarray
    chi2_0: np.ndarray
    chi2: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    status: np.ndarray
    resampled: np.ndarray

    @property
    def best_index(self) -> int:
        c = np.where(np.isfinite(self.chi2), self.chi2, np.inf)
        if not np.isfinite(c).any():
            raise GprmInputError("no start produced a finite chi-square", field="starts")
        return int(np.argmin(c))

    def n_at_best(self, tol: float = 1.0) -> int:
        """Number of starts whose chi-square is within ``tol`` of the best (Delta chi2 = 1 by
        default: statistically indistinguishable minima)."""
        c = self.chi2[np.isfinite(self.chi2)]
        return int(np.sum(c <= c.min() + tol))


# ----------------------------------------------------------------------------- starts

def draw_starts(center: np.ndarray, opts: MultiStartOptions) -> np.ndarray:
    """Normalised starting points (n, P): center * (1 + spread * U), U in [-1, 1]^P, uniform or
    Latin-hypercube, from ``opts.seed`` alone."""
    if opts.n_starts < 1:
        raise GprmInputError(f"must be at least 1, got {opts.n_starts}", field="starts")
    if not (opts.spread >= 0 and np.isfinite(opts.spread)):
        raise GprmInputError(f"must be >= 0, got {opts.spread}", field="spread")
    P = center.size
    if opts.sampling == "uniform":
        U = np.random.default_rng([opts.seed, 0]).uniform(-1, 1, (opts.n_starts, P))
    elif opts.sampling == "lhs":
        from scipy.stats import qmc

        U = 2 * qmc.LatinHypercube(d=P, seed=np.random.default_rng([opts.seed, 1])).random(
            opts.n_starts) - 1
    else:
        raise GprmInputError(f"unknown sampling {opts.sampling!r} (uniform, lhs)",
                             field="sampling")
    return center[None] * (1 + opts.spread * U)


def make_prune_rule(opts: MultiStartOptions):
    """Early stop of starts that are clearly far from the best (``prune_after = 0``: off).

    Two rules, both against the smallest chi-square reached in the start's chunk so far
    (running or finished), ``best``; a start they stop gets status ``pruned``:

    - factor: from iteration ``prune_after`` on, chi2 > ``prune_factor`` x best;
    - rate (``prune_rate_window`` = k > 0): from iteration k on, a start that cannot come
      within Delta chi2 = 1 of ``best`` by the iteration limit even if it kept its mean
      decrease over its last k iterations, chi2 - best > 1 + (decrease per iteration) x
      (iterations left). LM's decrease slows as a start converges, so the straight-line
      extrapolation is generous; on the demo's campaign it stops the starts stuck in a far
      basin (chi-square about 12 x the best) that otherwise ran to the limit, and the best
      fit is unchanged.

    Chi-square never increases along a start, so a pruned start can become the best only by
    outrunning these bounds; the benchmark checks that the best fit is unchanged with pruning
    on (``bench_fit.py --check-prune``). The rules use the chunk only, so they do not depend
    on the number of workers or on the order in which chunks finish.
    """
    if opts.prune_after <= 0:
        return None
    k = max(int(opts.prune_rate_window), 0)
    max_iter = int(opts.lm.max_iter)
    state: dict = {"it": 0, "ring": None}

    def rule(chi2, active):
        it = state["it"]                   # iterations done before this call
        state["it"] += 1
        cut = np.zeros_like(active)
        if k:
            if state["ring"] is None:
                state["ring"] = np.empty((k + 1, chi2.size))
            ring = state["ring"]
            ring[it % (k + 1)] = chi2
        best = np.min(chi2)
        if it >= opts.prune_after:
            cut |= active & (chi2 > opts.prune_factor * best)
        if k and it >= k:
            rate = (ring[(it - k) % (k + 1)] - chi2) / k
            with np.errstate(invalid="ignore"):
                cut |= active & (chi2 - best > 1.0 + rate * (max_iter - it))
        return cut

    return rule


def check_race(race) -> tuple[tuple[int, int], ...]:
    """A racing schedule as a tuple of (iterations, keep) pairs of integers >= 1, iterations
    increasing and keep decreasing from pair to pair; () for no racing. Raises
    :class:`GprmInputError` (field ``race``) otherwise."""
    try:
        pairs = tuple((r, q) for r, q in race)
    except (TypeError, ValueError):
        raise GprmInputError(f"expected (iterations, keep) pairs, got {race!r}",
                             field="race") from None
    for r, q in pairs:
        if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 1
                   for v in (r, q)):
            raise GprmInputError(f"iterations and keep must be integers >= 1, got {(r, q)!r}",
                                 field="race")
    pairs = tuple((int(r), int(q)) for r, q in pairs)
    for (r0, q0), (r1, q1) in zip(pairs, pairs[1:]):
        if not (r1 > r0 and q1 < q0):
            raise GprmInputError("race points must come at increasing iterations with fewer "
                                 f"starts kept each time, got {pairs!r}", field="race")
    return pairs


def race_cut(chi2: np.ndarray, active: np.ndarray, keep: int) -> np.ndarray:
    """The running starts a race point stops: all ``active`` starts but the ``keep`` with the
    smallest chi-square (a non-finite chi-square ranks last; equal values keep the start that
    comes first in the chunk, i.e. in start order). Nothing is cut when ``keep`` or fewer are
    running."""
    chi2 = np.asarray(chi2, float)
    idx = np.flatnonzero(active)
    cut = np.zeros(chi2.shape, bool)
    if idx.size <= keep:
        return cut
    c = chi2[idx]
    order = idx[np.argsort(np.where(np.isfinite(c), c, np.inf), kind="stable")]
    cut[order[keep:]] = True
    return cut


def make_race_rule(opts: MultiStartOptions):
    """Racing (successive halving) among the starts of one chunk (``opts.race`` = () : off).

    At each race point (r, q), i.e. after r iterations (the chunk runs in lock-step, so every
    running start has done r), only the q running starts with the smallest chi-square go on
    (:func:`race_cut`); the others stop with status ``raced``, their point and chi-square at
    that moment recorded. Starts already stopped (converged, stalled, pruned) are neither
    ranked nor counted. The survivors of the last race point run to their own stop. Like
    the pruning rules, it looks at the chunk alone, so the result does not depend on the
    number of workers or the order in which chunks finish.

    Off by default: on campaigns whose best start catches up from the back of the field
    late, racing by chi-square rank stops it, and the best chi2 comes out worse than the
    full run's (the identified set stayed the same). Measured against the full run on 20
    campaigns (``benchmarks/bench_fit_speed.py --campaigns 20 --starts 1000 --race ...``,
    ``--ranks``); what it changes in the start statistics: docs/fitting.md ("Racing").
    """
    race = dict(check_race(opts.race))
    if not race:
        return None
    state = {"it": 0}

    def rule(chi2, active):
        it = state["it"]                   # iterations done before this call
        state["it"] += 1
        if it not in race:
            return np.zeros(np.shape(active), bool)
        return race_cut(chi2, np.asarray(active, bool), race[it])

    return rule


def make_stop_rule(opts: MultiStartOptions):
    """The early stops of a chunk's starts for the LM's ``prune`` hook: the pruning rules
    (:func:`make_prune_rule`, status ``pruned``) first, then the race
    (:func:`make_race_rule`, status ``raced``) among the starts still running. None when
    both are off."""
    prune, race = make_prune_rule(opts), make_race_rule(opts)
    if prune is None and race is None:
        return None

    def rule(chi2, active):
        active = np.asarray(active, bool)
        status = np.full(active.shape, "", dtype=object)
        if prune is not None:
            pruned = np.asarray(prune(chi2, active), bool) & active
            status[pruned] = "pruned"
            active = active & ~pruned
        if race is not None:
            status[race(chi2, active) & active] = "raced"
        return status

    return rule


def resample_invalid(obj: Objective, X0n: np.ndarray, start_ids: np.ndarray, opts) -> tuple:
    """Replace starts whose model cannot be evaluated (unstable, singular, non-finite) by
    fresh draws from a per-start stream, up to MAX_RESAMPLE times."""
    X0n = X0n.copy()
    counts = np.zeros(len(X0n), int)
    reasons = np.full(len(X0n), "", dtype=object)
    center = obj.to_normalised(obj.base.initial_vector(obj.names))
    lo, hi = obj.bounds_normalised()
    for attempt in range(MAX_RESAMPLE + 1):
        obs = obj.model(obj.to_physical(X0n))
        good = obs.ok & np.all(np.isfinite(obs.y), axis=(1, 2))
        reasons[~good] = obs.reason[~good]
        out = ~np.all((X0n > lo) & (X0n < hi), axis=1)
        reasons[out] = "outside the parameter bounds"
        good &= ~out
        if good.all() or attempt == MAX_RESAMPLE:
            break
        for i in np.nonzero(~good)[0]:
            rng = np.random.default_rng([opts.seed, 2, int(start_ids[i]), attempt])
            X0n[i] = center * (1 + opts.spread * rng.uniform(-1, 1, center.size))
            counts[i] += 1
    reasons[good] = ""
    return X0n, counts, reasons
