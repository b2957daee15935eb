"""Multiple impacts (the paper's future work): plunger and test mass integrated together with
contact detection (docs/flight.md).

Model, for one parameter set and impact geometry:

* Plunger: the linear model (Eq. 2) driven by the voltage, plus the free response to every
  contact impulse it receives (two-way coupling): an impulse −J at the contact point p adds
  the generalised impulse Ĵ = (∂p/∂ξ)ᵀ(−J), which changes the generalised velocities by
  M⁻¹Ĵ (the charge is continuous); the linear system then carries that change on,
  Δz(t) = exp(A_s (t − t_k)) Δz_k. The contact's mobility is therefore the model's own,
  W_p = (∂p/∂ξ) M⁻¹ (∂p/∂ξ)ᵀ: the spacer and tip, tied to the plunger by springs, take no
  part in an instantaneous impact (unlike the rigid assembly m2 + m3 + m4 of Appendix B).
* Test mass: a free rigid cube (m, m s²/6), at rest until the first impact; afterwards it
  flies freely (small rotations over the window).
* Contacts: the plunger points M_xz and M_yz against two faces fixed in the TM, planes with the
  normals of :mod:`gprm.flight.predicted`. At the first impact time t1 (given, e.g. the
  estimated one) both faces pass through their contact points (both lines touch, as in the
  planar analysis). A later contact is detected when a gap that had opened closes again
  (linear interpolation on a 0.05 µs grid). Simultaneous contacts are solved together
  (Newton restitution e per contact, frictionless, impulses >= 0).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from gprm.flight.impact import _skew
from gprm.flight.predicted import ImpactGeometry
from gprm.model.coordinates import MECHANICAL
from gprm.model.linear import descriptor, state_space
from gprm.params import batch
from gprm.simulate.kinematics import (body_motion, motion_omega, named_points, point_motion,
                                      rotation)

MECH = MECHANICAL            # the model's mechanical coordinates (model.definition)


@dataclass(frozen=True)
class ContactEvent:
    time: float
    planes: tuple[str, ...]
    impulses: tuple[float, ...]
    tm_velocity: tuple[float, ...]      # vx, vy, vz, wx, wy, wz after the event
    dE_plunger: float = 0.0             # kinetic-energy change of the mechanism (½ ξ'ᵀ M ξ')
    dE_tm: float = 0.0                  # kinetic-energy change of the TM


def _setup(model, geometry):

    pb = batch([model.params])
    geom = (geometry or ImpactGeometry()).resolved(pb)
    ss = state_space(pb, model.piezo)
    E, _, _ = descriptor(pb, model.piezo)
    lam, V = np.linalg.eig(ss.A[0])
    Vinv = np.linalg.inv(V)
    pts = named_points(pb)
    return pb, geom, (E[0], lam, V, Vinv), pts


def _with_perturbation(motion, dz_list, lam, V, Vinv):
    """A copy of ``motion`` with the free responses of the impulses added (coords, rates)."""
    t = motion.time
    dz = np.zeros((17, t.size))
    for tk, z0 in dz_list:
        tau = t - tk
        act = tau >= 0
        if not act.any():
            continue
        c = Vinv @ z0
        resp = (V @ (c[:, None] * np.exp(lam[:, None] * tau[None, act]))).real
        dz[:, act] += resp
    coords = {n: motion.coords[n] + dz[i][None] for i, n in enumerate(MECH)}
    rates = {f"{n}_dot": motion.rates[f"{n}_dot"] + dz[8 + i][None]
             for i, n in enumerate(MECH)}
    R = rotation(coords["theta"], coords["eta"])
    return replace(motion, coords=coords, rates=rates, R=R, omega=motion_omega(coords, rates))


def _point_jacobian(motion, r_body):
    """∂p/∂ξ (3, 8) of a plunger-fixed point at the single time of ``motion``: the point's
    velocity for a unit rate of each coordinate (velocity is linear in the rates)."""

    cols = []
    for n in MECH:
        rates = {f"{m}_dot": np.zeros_like(motion.rates[f"{m}_dot"]) for m in MECH}
        rates[f"{n}_dot"] = np.ones_like(rates[f"{n}_dot"])
        m2 = replace(motion, rates=rates, omega=motion_omega(motion.coords, rates))
        _, v = point_motion(m2, r_body)
        cols.append(v[0, :, 0])
    return np.stack(cols, 1)


def simulate_contacts(model, t1: float, *, t_end: float | None = None,
                      geometry: ImpactGeometry | None = None, dt: float = 5e-8,
                      max_events: int = 50, trace: bool = False) -> dict:
    """Integrate plunger and TM from the first impact at ``t1`` to ``t_end`` (default the end
    of the prediction window) and return the contact events and the final TM velocity."""

    pb, geom, (E, lam, V, Vinv), pts = _setup(model, geometry)
    if t_end is None:
        t_end = float(pb["t_c"][0]) + 0.2e-3
    grid = np.arange(t1, t_end + 0.5 * dt, dt)
    nominal = body_motion(pb, grid, piezo=model.piezo)
    m_tm, s_tm = float(pb["m_tm"][0]), float(pb["s_tm"][0])
    I_tm = m_tm * s_tm ** 2 / 6.0
    a = geom.indent_angle
    sx = np.sign(pb["dist_x"][0]) or 1.0
    sy = np.sign(pb["dist_y"][0]) or 1.0
    normals = {"xz": np.array([sx * np.sin(a), 0.0, np.cos(a)]),
               "yz": np.array([0.0, sy * np.sin(a), np.cos(a)])}
    r_c = {"xz": pts["M_xz"].r[0] + np.asarray(geom.contact_offset_xz),
           "yz": pts["M_yz"].r[0] + np.asarray(geom.contact_offset_yz)}
    com0 = pts["com"].r[0]
    C0 = np.array([com0[0], com0[1], pts["M_xz"].r[0][2] + geom.tm_com_height])
    # Mass matrix (rows 8..16 of E hold M and C_sf); mechanical block:
    Mmat = E[8:16, 8:16]
    dz_list: list[tuple[float, np.ndarray]] = []
    tm_v = np.zeros(3)
    tm_w = np.zeros(3)
    t_imp = t1                       # TM at rest until t1; positions relative to C0 at t1
    faces = {}
    events = []

    def state_at(t):
        mo = body_motion(pb, np.array([t]), piezo=model.piezo)
        return _with_perturbation(mo, dz_list, lam, V, Vinv)

    def tm_point_velocity(p, t):
        C = C0 + tm_v * (t - t_imp)
        return tm_v + np.cross(tm_w, p - C)

    def resolve(t, planes, mo=None):
        """Simultaneous frictionless impact at the given contacts at time t (``mo``: the
        plunger state at t, if already computed)."""
        nonlocal tm_v, tm_w
        if mo is None:
            mo = state_at(t)
        Jp, P, u, rho = {}, {}, {}, {}
        C = C0 + tm_v * (t - t_imp)
        for pl in planes:
            pos, vel = point_motion(mo, r_c[pl])
            P[pl] = pos[0, :, 0]
            Jp[pl] = _point_jacobian(mo, r_c[pl])
            rho[pl] = P[pl] - C
            u[pl] = tm_point_velocity(P[pl], t) - vel[0, :, 0]   # TM rel. plunger
        Minv = np.linalg.inv(Mmat)
        act = list(planes)
        while act:
            k = len(act)
            Kc = np.zeros((k, k))
            for i, pi in enumerate(act):
                for j, pj in enumerate(act):
                    ni, nj = normals[pi], normals[pj]
                    Wp = Jp[pi] @ Minv @ Jp[pj].T
                    Wt = (np.eye(3) / m_tm
                          - _skew(rho[pi]) @ _skew(rho[pj]) / I_tm)
                    Kc[i, j] = ni @ (Wp + Wt) @ nj
            un = np.array([normals[p] @ u[p] for p in act])
            Pn = np.linalg.solve(Kc, -(1.0 + geom.restitution) * un)
            if np.all(Pn >= 0):
                break
            act = [p for p, x in zip(act, Pn) if x > 0]
        if not act:
            return None
        dq = np.zeros(8)
        qd = np.array([mo.rates[f"{n}_dot"][0, 0] for n in MECH])
        E_tm0 = 0.5 * m_tm * tm_v @ tm_v + 0.5 * I_tm * tm_w @ tm_w
        for p, x in zip(act, Pn):
            Jvec = x * normals[p]
            tm_v_new = Jvec / m_tm
            tm_v[:] = tm_v + tm_v_new
            tm_w[:] = tm_w + np.cross(rho[p], Jvec) / I_tm
            dq += Minv @ (Jp[p].T @ (-Jvec))
        dEp = 0.5 * (qd + dq) @ Mmat @ (qd + dq) - 0.5 * qd @ Mmat @ qd
        dEt = 0.5 * m_tm * tm_v @ tm_v + 0.5 * I_tm * tm_w @ tm_w - E_tm0
        return act, Pn, dq, (float(dEp), float(dEt))

    # first impact at t1: both faces through the contact points
    mo1 = state_at(t1)
    for pl in ("xz", "yz"):
        pos, _ = point_motion(mo1, r_c[pl])
        faces[pl] = pos[0, :, 0] - C0        # face point in TM body coordinates
    C_ref = C0.copy()
    res = resolve(t1, ("xz", "yz"), mo1)
    if res is not None:
        act, Pn, dq, dE = res
        dz_list.append((t1, np.concatenate([np.zeros(8), dq, [0.0]])))
        events.append(ContactEvent(t1, tuple(act), tuple(map(float, Pn)),
                                   tuple(np.concatenate([tm_v, tm_w]).tolist()), *dE))
    # TM pose: C(t) = C_ref + integral of v; piecewise constant velocities
    tm_hist = [(t1, C_ref.copy(), tm_v.copy(), tm_w.copy(), np.zeros(3))]

    def tm_pose(t):
        # last segment starting before t
        ts, Cs, vs, ws, ths = tm_hist[-1]
        for seg in tm_hist:
            if seg[0] <= np.min(t):
                ts, Cs, vs, ws, ths = seg
        dtau = np.asarray(t) - ts
        C = Cs[:, None] + vs[:, None] * dtau[None]
        th = ths[:, None] + ws[:, None] * dtau[None]
        return C, th

    t_last = t1
    while len(events) < max_events:
        sel = grid > t_last + 1e-12
        if sel.sum() < 2:
            break
        tt = grid[sel]
        mo = _with_perturbation(replace(nominal, time=tt,
                                        coords={k: v[:, sel] for k, v in nominal.coords.items()},
                                        rates={k: v[:, sel] for k, v in nominal.rates.items()},
                                        R=nominal.R[:, sel], omega=nominal.omega[:, :, sel]),
                                dz_list, lam, V, Vinv)
        C, th = tm_pose(tt)
        found = None
        for pl in ("xz", "yz"):
            pos, _ = point_motion(mo, r_c[pl])
            p = pos[0]                                       # (3, T)
            f = faces[pl]
            # face point and normal rotated by the small TM rotation th
            fpt = C + f[:, None] + np.cross(th.T, f).T
            nrm = normals[pl][:, None] + np.cross(th.T, normals[pl]).T
            gap = np.sum(nrm * (p - fpt), axis=0)           # > 0: penetration
            opened = np.flatnonzero(gap < -1e-13)
            if opened.size == 0:
                continue
            k0 = opened[0]
            closing = np.flatnonzero(gap[k0:] >= 0)
            if closing.size == 0:
                continue
            k = k0 + closing[0]
            tc = tt[k - 1] + gap[k - 1] / (gap[k - 1] - gap[k]) * (tt[k] - tt[k - 1])
            if found is None or tc < found[0] - 1e-12:
                found = (tc, [pl])
            elif abs(tc - found[0]) <= 1e-12:
                found[1].append(pl)
        if found is None:
            break
        tc, planes = found
        res = resolve(tc, tuple(planes))
        t_last = tc
        if res is None:
            continue
        act, Pn, dq, dE = res
        dz_list.append((tc, np.concatenate([np.zeros(8), dq, [0.0]])))
        C_now, th_now = tm_pose(np.array([tc]))
        tm_hist.append((tc, C_now[:, 0], tm_v.copy(), tm_w.copy(), th_now[:, 0]))
        events.append(ContactEvent(float(tc), tuple(act), tuple(map(float, Pn)),
                                   tuple(np.concatenate([tm_v, tm_w]).tolist()), *dE))
    final = np.concatenate([tm_v, tm_w])
    truncated = len(events) >= max_events
    # whole-record gaps with every impulse applied (no missed contact: the gap stays <= 0
    # except for the interpolation overshoot just after a detected contact)
    full = _with_perturbation(nominal, dz_list, lam, V, Vinv)
    starts = np.array([seg[0] for seg in tm_hist])
    seg_idx = np.clip(np.searchsorted(starts, grid, side="right") - 1, 0, None)
    Cg = np.empty((3, grid.size))
    thg = np.empty((3, grid.size))
    for j, (ts, Cs, vs, ws, ths) in enumerate(tm_hist):
        sel = seg_idx == j
        Cg[:, sel] = Cs[:, None] + vs[:, None] * (grid[sel] - ts)[None]
        thg[:, sel] = ths[:, None] + ws[:, None] * (grid[sel] - ts)[None]
    gaps = {}
    for pl in ("xz", "yz"):
        pos, _ = point_motion(full, r_c[pl])
        f = faces[pl]
        fpt = Cg + f[:, None] + np.cross(thg.T, f).T
        nrm = normals[pl][:, None] + np.cross(thg.T, normals[pl]).T
        gaps[pl] = np.sum(nrm * (pos[0] - fpt), axis=0)
    return {"t1": float(t1), "t_end": float(t_end), "n_impacts": len(events),
            "truncated": truncated,
            "max_penetration": float(max(np.max(g) for g in gaps.values())),
            "note": (f"stopped after {max_events} contacts (chattering, i.e. sustained contact: "
                     "the instantaneous-impact model no longer applies)" if truncated else None),
            "events": [e.__dict__ for e in events],
            "final_tm_velocity": dict(zip(("vx", "vy", "vz", "wx", "wy", "wz"),
                                          map(float, final))),
            "first_tm_velocity": (dict(zip(("vx", "vy", "vz", "wx", "wy", "wz"),
                                           events[0].tm_velocity)) if events else None),
            **({"trace": {"time": grid, "gap": gaps}} if trace else {})}


def multi_impact_report(model, doc: dict, *, geometry=None) -> dict:
    """For each release of an impact JSON document: simulate from the release's estimated
    impact time (its joint estimate, else the mean over its axes with a crossing) and report
    the contacts found."""
    out = []
    for r in doc["releases"]:
        ts = [v["value"] for v in r["impact_time"].values() if v["value"] is not None]
        tj = (r.get("joint") or {}).get("value")
        if tj is None and not ts:
            out.append({"id": r["id"], "t1": None, "reason": "no estimated impact time"})
            continue
        res = simulate_contacts(model, float(tj if tj is not None else np.mean(ts)),
                                geometry=geometry)
        res["id"] = r["id"]
        out.append(res)
    return {"model": "plunger (linear model, two-way impulse coupling) + free TM, contact "
                     "detection on M_xz and M_yz faces (docs/flight.md)", "releases": out}
