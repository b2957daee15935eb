"""exp(lambda t) from powers on a uniform grid (gprm.simulate.modal.exp_lt) against np.exp,
and the combined forms of the default input's convolutions against their textbook forms.
Warnings are errors here: a block without live samples must not overflow."""

from __future__ import annotations

import numpy as np
import pytest

from gprm.simulate.modal import _SMALL_J, _D1_SHORT, _series, conv_default, exp_lt


pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")


def _batch(seed=0, B=40, n=9, T=47, G=5):
    rng = np.random.default_rng(seed)
    lam = -rng.uniform(1e2, 8e4, (B, n)) + 1j * rng.uniform(1e3, 4e5, (B, n))
    lam[:, -1] = -rng.uniform(10.0, 2e6, B)                     # a real (possibly stiff) mode
    times = 0.97e-3 + 5e-6 * np.arange(T)
    ts = 1e-3 + rng.uniform(-1e-5, 1e-5, B)
    lags = rng.uniform(-3e-6, 3e-6, (B, G))
    lags[:, 0] = 0.0
    tau = np.concatenate([times[None] - ts[:, None] - lags[:, g:g + 1] for g in range(G)],
                         axis=1)
    tau[0, :T] -= 1e-3                                          # a block with no live sample
    return lam, tau, T


def test_exp_from_powers_equals_np_exp_on_a_uniform_grid():
    lam, tau, T = _batch()
    direct = np.exp(lam[:, :, None] * np.clip(tau, 0, None)[:, None, :])
    powers = exp_lt(lam, tau, period=T)
    assert not np.array_equal(powers, direct)                   # the power path was taken
    scale = np.maximum(np.abs(direct), 1e-300)
    assert np.max(np.abs(powers - direct) / scale) < 1e-12
    assert np.all(powers[0, :, :T] == 1.0)                      # t clipped to 0 -> exactly 1


def test_non_uniform_axis_falls_back_to_np_exp_exactly():
    lam, tau, T = _batch(seed=1)
    tau = tau.copy()
    tau[:, 3] += 1e-9                                           # one sample off the grid
    direct = np.exp(lam[:, :, None] * np.clip(tau, 0, None)[:, None, :])
    np.testing.assert_array_equal(exp_lt(lam, tau, period=T), direct)
    np.testing.assert_array_equal(exp_lt(lam, tau), direct)


def _textbook(lam, tau, V0, tau_v):
    """I and J from their definitions: each term on its own, with the same small-argument
    forms as the module docstring states (expm1 and the phi1' series)."""
    a = (1.0 / tau_v)[:, None, None]
    t = np.clip(tau, 0.0, None)[:, None, :]
    L = lam[:, :, None]
    La = L + a
    z, za = L * t, La * t
    E, ea = np.exp(z), np.exp(-a * t)
    I0 = np.where(np.abs(z) < 0.1, np.expm1(z) / L, (E - 1) / L)
    Ia = np.where(np.abs(za) < 0.1, ea * np.expm1(za) / La, (E - ea) / La)
    d0 = np.where(np.abs(z) < _SMALL_J, t * t * _series(z, _D1_SHORT), (t * E - I0) / L)
    da = np.where(np.abs(za) < _SMALL_J, ea * t * t * _series(za, _D1_SHORT),
                  (t * E - Ia) / La)
    live = t > 0
    V0b = V0[:, None, None]
    return V0b * np.where(live, Ia - I0, 0), V0b * np.where(live, da - d0, 0)


def test_combined_convolutions_equal_their_textbook_forms():
    lam, tau, T = _batch(seed=2)
    B = lam.shape[0]
    V0 = np.full(B, 120.0)
    tau_v = np.full(B, 2e-5)
    I_ref, J_ref = _textbook(lam, tau, V0, tau_v)
    for period in (None, T):
        I, J, _ = conv_default(lam, tau, V0, tau_v, need_J=True, period=period)
        I2, _, _ = conv_default(lam, tau, V0, tau_v, need_J=False, period=period)
        sI = np.max(np.abs(I_ref), axis=2, keepdims=True)
        sJ = np.max(np.abs(J_ref), axis=2, keepdims=True)
        assert np.max(np.abs(I - I_ref) / sI) < 1e-12
        assert np.max(np.abs(I2 - I_ref) / sI) < 1e-12
        assert np.max(np.abs(J - J_ref) / sJ) < 1e-11


def test_kept_convolutions_give_the_sensitivities_bit_for_bit_and_only_where_they_match(
        monkeypatch):
    """observe(..., keep_convolutions=True) keeps E, e^{-t/tau_v}, I and u; a call with
    sensitivities for the same sets (or a subset, reordered) and times computes only J from
    them and returns exactly a fresh call's outputs; other times or another drive are not
    served from them (the result is a fresh call's there too)."""
    from gprm.params import batch, paper
    from gprm.simulate.core import observe

    p = paper()
    rng = np.random.default_rng(3)
    sets = [p.with_vector(p.vector() * (1 + 0.05 * rng.uniform(-1, 1, len(p.fitted))))
            for _ in range(4)]
    pb = batch(sets)
    t = 0.97e-3 + 5e-6 * np.arange(47)
    names = ("x_base", "x_head", "y_base", "y_head", "z_bk")
    sens = ("k_lr", "m2", "t0", "t1", "dt_x_head", "b1")
    first = observe(pb, t, names, keep_convolutions=True)
    conv = first.prepared.convolutions
    assert conv is not None and observe(pb, t, names).prepared.convolutions is None
    rows = np.array([2, 0, 0])
    sub = {k: np.atleast_1d(v)[rows] if np.size(v) == 4 else v for k, v in pb.items()}
    from gprm.simulate import modal

    calls = []
    base = modal.conv_default_base
    monkeypatch.setattr(modal, "conv_default_base",
                        lambda *a, **k: calls.append(1) or base(*a, **k))
    reused = observe(sub, t, names, sensitivities=sens, prepared=first.prepared.take(rows))
    assert calls == []                      # E, I and u came from the kept convolutions
    fresh = observe(sub, t, names, sensitivities=sens)
    assert calls == [1]
    np.testing.assert_array_equal(reused.y, fresh.y)
    np.testing.assert_array_equal(reused.dy, fresh.dy)
    # other times: the kept convolutions do not match and are not used
    t2 = t + 1e-6
    other = observe(sub, t2, names, sensitivities=sens, prepared=first.prepared.take(rows))
    np.testing.assert_array_equal(other.dy, observe(sub, t2, names, sensitivities=sens).dy)
    assert conv.take(rows).matching(conv.lam[rows], conv.tv[rows] + 1e-6, conv.V0[rows],
                                    conv.tau_v[rows]) is None
    assert conv.take(rows).matching(conv.lam[rows], conv.tv[rows], conv.V0[rows] * 1.01,
                                    conv.tau_v[rows]) is None
