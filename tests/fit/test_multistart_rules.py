"""The multi-start driver's early-stop rules (gprm.fit.starts.make_prune_rule) on chi-square
sequences with known answers, the settings of the local Dask workers, and the reuse of a
trial point's spectrum for its Jacobian."""

from __future__ import annotations

import numpy as np

from gprm.fit.engine import local_worker_config
from gprm.fit.starts import LMOptions, MultiStartOptions, make_prune_rule


def _drive(rule, paths):
    """Feed the rule chi2 paths (iterations, starts) as the optimiser would (before each
    iteration); return the iteration at which each start was cut (-1: never)."""
    n_it, n = paths.shape
    active = np.ones(n, bool)
    cut_at = np.full(n, -1)
    for it in range(n_it):
        cut = rule(paths[it], active.copy())
        cut_at[cut & active] = it
        active &= ~cut
    return cut_at


def test_rate_rule_cuts_only_starts_that_cannot_reach_the_best_at_their_recent_rate():
    opts = MultiStartOptions(prune_after=10, prune_factor=1e9, prune_rate_window=10,
                             lm=LMOptions(max_iter=100))
    it = np.arange(60)[:, None]
    best = np.full((60, 1), 100.0)                      # already converged
    fast = 1000.0 - 20.0 * np.minimum(it, 45)          # 900 above, -20/it: catches up
    slow = 1000.0 - 1.0 * it                           # 900 above, -1/it: cannot (90 left)
    near = 100.5 + 0.0 * it                            # within Delta chi2 = 1: never cut
    cut = _drive(make_prune_rule(opts), np.hstack([best, fast, slow, near]))
    assert cut[0] == -1 and cut[1] == -1 and cut[3] == -1
    # slow, at iteration 10: 890 above the best > 1 + 1 per iteration x 90 left
    assert cut[2] == 10


def test_rate_rule_uses_the_decrease_over_the_window_not_one_step():
    """A start that stalled for a few iterations but fell fast over the window is kept."""
    opts = MultiStartOptions(prune_after=10, prune_factor=1e9, prune_rate_window=10,
                             lm=LMOptions(max_iter=100))
    path = np.concatenate([5000.0 - 400.0 * np.arange(10), np.full(3, 1400.0),
                           1400.0 - 300.0 * np.arange(1, 5)])
    best = np.full(path.size, 100.0)
    cut = _drive(make_prune_rule(opts), np.stack([best, path], axis=1))
    assert cut[1] == -1
    # with the rule off and only the factor rule (x 100) nothing is cut either
    off = MultiStartOptions(prune_after=10, prune_factor=100.0, prune_rate_window=0)
    assert np.all(_drive(make_prune_rule(off), np.stack([best, path], axis=1)) == -1)


def test_factor_rule_and_prune_off():
    opts = MultiStartOptions(prune_after=3, prune_factor=10.0, prune_rate_window=0)
    paths = np.stack([np.full(6, 1.0), np.full(6, 11.0), np.full(6, 9.0)], axis=1)
    cut = _drive(make_prune_rule(opts), paths)
    assert list(cut) == [-1, 3, -1]
    assert make_prune_rule(MultiStartOptions(prune_after=0)) is None


def test_local_workers_keep_dasks_thread_settings_without_the_malloc_trim_threshold():
    import dask

    cfg = local_worker_config()
    env = cfg["distributed.nanny.pre-spawn-environ"]
    assert "MALLOC_TRIM_THRESHOLD_" not in env
    default = dask.config.get("distributed.nanny.pre-spawn-environ")
    assert env == {k: v for k, v in default.items() if k != "MALLOC_TRIM_THRESHOLD_"}
    assert env.get("OPENBLAS_NUM_THREADS") == 1
    assert cfg["distributed.worker.profile.enabled"] is False


def test_jacobian_at_rows_just_evaluated_reuses_their_spectrum_bit_for_bit():
    """Objective.__call__ on rows of the last residuals call reuses their eigen-
    decompositions and modal convolutions; the residuals and Jacobian equal a fresh
    evaluation bit for bit, and a pickled objective (a Dask task) carries no cached rows."""
    import pickle
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from means_factory import make_means

    from gprm.fit.objective import Objective, fit_data_from_means
    from gprm.params import paper

    p = paper()
    data = fit_data_from_means(make_means(p, seed=4), source="synthetic")
    obj = Objective.create(data, p)
    rng = np.random.default_rng(0)
    X = obj.to_normalised(p.initial_vector(obj.names))[None] * (
        1 + 0.1 * rng.uniform(-1, 1, (6, len(obj.names))))
    obj.residuals(X)
    rows = X[[4, 1, 1]]                                  # a subset, reordered, repeated
    prep = obj._prepared_for(rows)
    assert prep is not None and prep.convolutions is not None
    assert prep.convolutions.E.shape[0] == 3             # the modal convolutions, taken too
    r1, J1 = obj(rows)
    fresh = Objective.create(data, p)
    assert fresh._prepared_for(rows) is None
    r2, J2 = fresh(rows)
    np.testing.assert_array_equal(r1, r2)
    np.testing.assert_array_equal(J1, J2)
    # a row not in the last batch: no reuse
    assert obj._prepared_for(X[:1] * 1.01) is None
    assert pickle.loads(pickle.dumps(obj))._last == {}
