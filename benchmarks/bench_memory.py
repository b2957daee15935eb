"""Memory per unit of work, behind the CLI's resource guards (gprm.resources, docs/README.md).

Prints the tracemalloc peak of each guarded allocation at two sizes and the marginal bytes
per unit (the difference of the peaks over the difference of the units), which the guards'
per-unit estimates in the commands round up. About 20 s of CPU.

    PYTHONPATH=src .venv/bin/python benchmarks/bench_memory.py
"""

from __future__ import annotations

import tracemalloc


def peak(fn):
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def marginal(name, unit, make, sizes):
    make(sizes[0][0])                                  # warm-up: imports, caches
    (a, na), (b, nb) = [(peak(lambda s=s: make(s)), n) for s, n in sizes]
    print(f"{name:28s} peak {a / 1e6:8.2f} MB at {na:>9,} {unit}, {b / 1e6:8.2f} MB at "
          f"{nb:>9,}; marginal {(b - a) / (nb - na):8.1f} B per {unit}")


def main():
    from gprm.campaign.synth import SynthConfig, synth_campaign
    from gprm.fit.files import paper_model
    from gprm.flight.synth import SynthOptions, synth_telemetry
    from gprm.params import paper
    from gprm.fit.files import load_model
    from gprm.predict.core import predict, prediction_times
    from gprm.simulate import simulate
    from gprm.simulate.files import simulation_dataset

    ps = paper()

    def sim(rate):
        simulation_dataset(simulate(ps, piezo=2, t_end=1.2e-3, rate=rate), ps)

    marginal("simulate (--rate)", "sample", sim,
             [(1e8, round(1.2e-3 * 1e8) + 1), (4e8, round(1.2e-3 * 4e8) + 1)])
    fm = load_model("paper")
    t = prediction_times(0.95e-3, 1.2e-3, 1e6)
    marginal("predict (--samples)", "set x time",
             lambda n: predict(fm, times=t, samples=n, seed=0),
             [(20, 20 * t.size), (80, 80 * t.size)])
    m = paper_model(2)
    marginal("synth telemetry (--rate)", "sample",
             lambda r: synth_telemetry(m, SynthOptions(n_releases=2, seed=0, rate=r, post=5.0)),
             [(2e3, 2 * 10001), (8e3, 2 * 40001)])

    def camp(runs):
        synth_campaign(seed=0, config=SynthConfig(n_runs=runs, n_noise=runs // 2,
                                                  nonlinear=False))

    marginal("synth campaign (--runs)", "run sample", camp,
             [(4, 10 * 6 * 301), (16, 10 * 24 * 301)])

    import numpy as np

    from gprm.fit.api import FitOptions
    from gprm.fit.objective import Objective, fit_data_from_means
    from gprm.fit.uncertainty import compute_bands
    from gprm.campaign.preprocess import preprocess

    means = preprocess(synth_campaign(seed=0, config=SynthConfig(n_runs=4, n_noise=2,
                                                                 nonlinear=False))).to_dataset()
    for window in ((0.97e-3, 1.2e-3), (0.5e-3, 1.4e-3)):
        obj = Objective.create(fit_data_from_means(means, window=window),
                               FitOptions().parameters(ps))
        x = obj.base.initial_vector(obj.names)
        cov = np.diag((1e-3 * np.abs(x) + 1e-12) ** 2)
        n_pts = obj.data.values.size
        marginal(f"fit (--band-samples), {n_pts} points", "sample x point",
                 lambda n, o=obj, x=x, c=cov: compute_bands(o, x, c, n_samples=n, seed=0),
                 [(100, 100 * n_pts), (400, 400 * n_pts)])


if __name__ == "__main__":
    main()
