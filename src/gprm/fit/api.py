"""Library entry point of the fit stage: ``run_fit`` with its validated options.

``gprm fit``, ``gprm run`` and ``gprm demo`` call exactly this, so the defaults of
:class:`FitOptions` are the one recommended configuration: weights ``sem`` and the per-signal
alignment offsets (``gprm.params.ALIGNMENT_OFFSETS``) fitted with the 23 parameters of
Table 3 (each signal is aligned at its own crossing, which one lag t0 cannot absorb;
docs/model.md). What only changes how fast a result comes (workers, a scheduler, a checkpoint
folder, a progress callback) is an argument of ``run_fit``, not an option.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Callable

import xarray as xr

from gprm.campaign.files import read_means
from gprm.errors import GprmInputError
from gprm.fit.identify import identify
from gprm.fit.objective import SIGMA_POOL, fit_data_from_means
from gprm.fit.prior import DEFAULT_WIDTH
from gprm.fit.result import FitResult
from gprm.fit.starts import DEFAULT_RACE, LMOptions, MultiStartOptions, check_race
from gprm.fit.methods import DEFAULT_METHOD, METHODS
from gprm.fit.sandwich import Systematics
from gprm.params import ALIGNMENT_OFFSETS, ParameterSet, load_params
from gprm.params.files import read_systematics
from gprm.model.piezo import check_piezo
from gprm.validate import check_int, check_number


@dataclass(frozen=True)
class FitOptions:
    """What defines a fit result (SI). Validated on construction; a bad value raises
    :class:`GprmInputError` naming the option."""

    starts: int = 1000
    seed: int = 0
    spread: float = 0.2
    sampling: str = "uniform"                 # or "lhs"
    window: tuple[float, float] = (0.97e-3, 1.2e-3)
    sigma: str = "sem"                        # or "std" (the paper's across-run std)
    #: samples on each side over which sigma(t)^2 is pooled (gprm.fit.objective.pooled_sigma)
    sigma_pool: int = SIGMA_POOL
    fit_offsets: bool = True                  # also fit dt_x_head, dt_y_base, dt_y_head
    piezo: int = 2
    chunk: int = 250
    max_iter: int = LMOptions.max_iter
    stall_window: int = LMOptions.stall_window
    stall_tol: float = LMOptions.stall_tol
    prune_after: int = 10
    prune_factor: float = 100.0
    #: racing within each chunk of starts: (iterations, keep) pairs, () for none
    #: (gprm.fit.starts.make_race_rule; docs/fitting.md, "Racing")
    race: tuple[tuple[int, int], ...] = DEFAULT_RACE
    band_samples: int = 200
    profile: bool = False
    z_bk_absolute: bool = False
    uncertainty: str = DEFAULT_METHOD         # gprm.fit.uncertainty.METHODS
    prior_width: float = DEFAULT_WIDTH        # 0: no prior (the paper's fit; eq7 methods)
    boot: int = 30                            # campaigns of the generator bootstrap
    #: the instrument's systematics, one sd each (None: the parameter file's [systematics],
    #: else gprm.fit.sandwich.Systematics' documented defaults)
    gain_sd: float | None = None              # relative gain error of each channel
    timing_sd: float | None = None            # s, timing offset of each channel
    #: search the residuals for an unmodelled resonance and marginalise one that is found
    #: (gprm.fit.resonance; with a prior only)
    resonance: bool = True

    def __post_init__(self):
        check_int("starts", self.starts, 1)
        check_int("seed", self.seed, 0)
        check_number("spread", self.spread, positive=True)
        if self.sampling not in ("uniform", "lhs"):
            raise GprmInputError(f"must be uniform or lhs, got {self.sampling!r}",
                                 field="sampling")
        w = tuple(self.window)
        if len(w) != 2 or not all(isinstance(x, (int, float)) and math.isfinite(x)
                                  for x in w) or not w[0] < w[1]:
            raise GprmInputError(f"must be two finite times start < end, got {self.window!r}",
                                 field="window")
        object.__setattr__(self, "window", (float(w[0]), float(w[1])))
        if self.sigma not in ("sem", "std"):
            raise GprmInputError(f"must be sem or std, got {self.sigma!r}", field="sigma")
        check_int("sigma_pool", self.sigma_pool, 0)
        for name in ("fit_offsets", "profile", "z_bk_absolute", "resonance"):
            if not isinstance(getattr(self, name), bool):
                raise GprmInputError(f"must be true or false, got {getattr(self, name)!r}",
                                     field=name)
        check_piezo(self.piezo)
        check_int("chunk", self.chunk, 1)
        check_int("max_iter", self.max_iter, 1)
        check_int("stall_window", self.stall_window, 0)
        check_number("stall_tol", self.stall_tol)
        check_int("prune_after", self.prune_after, 0)
        check_number("prune_factor", self.prune_factor, positive=True)
        object.__setattr__(self, "race", check_race(self.race))
        check_int("band_samples", self.band_samples, 0)
        if self.uncertainty not in METHODS:
            raise GprmInputError(f"must be one of {', '.join(METHODS)}, got "
                                 f"{self.uncertainty!r}", field="uncertainty")
        check_number("prior_width", self.prior_width)
        if self.prior_width == 0 and self.uncertainty not in ("eq7", "eq7-corr"):
            raise GprmInputError("0 (no prior) needs the uncertainty eq7 or eq7-corr",
                                 field="prior_width")
        check_int("boot", self.boot, 5)
        for name in ("gain_sd", "timing_sd"):
            if getattr(self, name) is not None:
                check_number(name, getattr(self, name))

    def systematics(self, stated: dict | None = None) -> Systematics:
        """The systematics the fit marginalises: these options over the parameter file's
        ``[systematics]`` table (``stated``, gprm.params.files.read_systematics) over the
        documented defaults."""
        stated = stated or {}
        d = Systematics()
        gain = next(v for v in (self.gain_sd, stated.get("gain_sd"), d.gain_sd)
                    if v is not None)
        timing = next(v for v in (self.timing_sd, stated.get("timing_sd"), d.timing_sd)
                      if v is not None)
        per = tuple((s, gain if g is None else g, timing if t is None else t)
                    for s, (g, t) in sorted(stated.get("per_signal", {}).items()))
        return Systematics(float(gain), float(timing), per)

    def multistart(self) -> MultiStartOptions:
        return MultiStartOptions(n_starts=self.starts, seed=self.seed, spread=self.spread,
                                 sampling=self.sampling, chunk_size=self.chunk,
                                 lm=LMOptions(max_iter=self.max_iter,
                                              stall_window=self.stall_window,
                                              stall_tol=self.stall_tol),
                                 prune_after=self.prune_after, prune_factor=self.prune_factor,
                                 race=self.race)

    def parameters(self, base: ParameterSet) -> ParameterSet:
        """``base`` with the alignment offsets added to its fitted set when ``fit_offsets``."""
        if not self.fit_offsets:
            return base
        extra = tuple(n for n in ALIGNMENT_OFFSETS.values() if n not in base.fitted)
        return base.with_fitted(tuple(base.fitted) + extra)


def run_fit(means: str | os.PathLike | xr.Dataset, opts: FitOptions = FitOptions(), *,
            params: str | os.PathLike | ParameterSet | None = None, workers: int = 0,
            scheduler: str | None = None, checkpoint_dir: str | os.PathLike | None = None,
            progress: Callable[..., None] | None = None,
            source: str | None = None, executor=None) -> FitResult:
    """Multi-start identification (Sec. 3.1) of a mean-signals file or dataset.

    ``params``: the parameter set (constants, fitted set, bounds): a TOML file (its
    ``[systematics]`` table states the instrument's gain and timing errors), a
    :class:`ParameterSet`, or None for the paper's. ``workers``: local worker processes
    (0: in this process; :func:`gprm.fit.engine.run_multistart`); the result does not
    depend on it. ``checkpoint_dir``: chunks of
    starts already done are read back from it (resuming). ``progress(done, total)`` as chunks
    finish, in starts (finished, requested); a callback that takes a ``best_chi2`` keyword
    also gets the smallest chi-square reached so far (nan before the first chunk): the one
    progress callback of ``gprm fit``, ``gprm run`` and ``gprm demo``. ``executor``: local
    worker processes made by the caller (:func:`gprm.fit.engine.local_pool`), used instead
    of ``workers`` and left open.
    """
    if not isinstance(opts, FitOptions):
        raise GprmInputError(f"expected FitOptions, got {type(opts).__name__}", field="opts")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
        raise GprmInputError(f"must be an integer >= 0, got {workers!r}", field="workers")
    if isinstance(means, xr.Dataset):
        ds, src = means, source or str(means.attrs.get("source", "mean signals"))
    else:
        ds, src = read_means(means), source or str(means)
    data = fit_data_from_means(ds, window=opts.window, sigma=opts.sigma, source=src,
                               sigma_pool=opts.sigma_pool)
    base = params if isinstance(params, ParameterSet) else load_params(params)
    stated = {} if params is None or isinstance(params, ParameterSet) else \
        read_systematics(params)
    return identify(data, opts.parameters(base), opts.multistart(), piezo=opts.piezo,
                    workers=workers, scheduler=scheduler, checkpoint_dir=checkpoint_dir,
                    progress=progress, profile=opts.profile, z_bk_absolute=opts.z_bk_absolute,
                    band_samples=opts.band_samples, uncertainty=opts.uncertainty,
                    prior_width=opts.prior_width or None, n_boot=opts.boot,
                    systematics=opts.systematics(stated), executor=executor,
                    resonance=opts.resonance)
