"""Central differences of the solver itself, next to its exact sensitivities (shared by the
sensitivity tests)."""

import numpy as np

from gprm.params import batch
from gprm.simulate import observe


def compare_with_central_differences(ps, sens, names, times, *, step, piezo=2, trace=None):
    """Exact sensitivities of ``names`` to ``sens`` at ``ps`` and central differences with step
    ``step(name, value)``, each compared as the change it causes (dy * h) on the scale of each
    signal. Returns ``(exact, plain, rel_err, effect)``: the exact Observation (batch of 1), the
    plain one (base, then +h/-h per parameter), and per parameter the worst error relative to
    the largest effect, and that largest effect."""
    base = dict(ps.values)
    sets, steps = [base], []
    for n in sens:
        h = step(n, base[n])
        steps.append(h)
        for sgn in (1, -1):
            d = dict(base)
            d[n] = base[n] + sgn * h
            sets.append(d)
    pb = {k: np.array([s[k] for s in sets]) for k in base}
    plain = observe(pb, times, names, piezo=piezo, voltage=trace)
    exact = observe(batch([ps]), times, names, piezo=piezo, voltage=trace, sensitivities=sens)
    assert plain.ok.all() and exact.ok.all()
    scale = np.abs(plain.y[0]).max(axis=1, keepdims=True)
    rel_err, effect = {}, {}
    for j, n in enumerate(sens):
        fd = (plain.y[1 + 2 * j] - plain.y[2 + 2 * j]) / (2 * steps[j])
        dy = exact.dy[0, ..., j]
        effect[n] = np.abs(dy * steps[j] / scale).max()
        rel_err[n] = (np.abs(dy - fd) * steps[j] / scale).max() / max(effect[n], 1e-300)
    return exact, plain, rel_err, effect
