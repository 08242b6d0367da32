"""The published prediction rule of core/scene.py, evaluated by brute force on every pair.

Ground truth for the scene, the predictor and the node: no broad phase, no
caches, no incremental bookkeeping -- only the narrow phase
(`time_to_collision`) applied as the rule in circle_collision_ros/core/scene.py
states it:

    R = newest stamp accepted since the scene was last empty, E = R - (R mod S), t_p = max(E, T_a,
    T_b);
    tau = narrow phase of both states propagated to t_p, horizon H + S;
    ttc = tau if t_p == R, else tau - (R - t_p) if that is > 0,
          else the narrow phase of both states propagated to R, horizon H;
    reported iff ttc <= H.
"""
from __future__ import annotations

import numpy as np

from circle_collision_ros.core.narrow import time_to_collision


def default_slack_ns(horizon: float) -> int:
    return max(1, int(round(horizon / 4.0 * 1e9)))


def _at(P, V, A, dt_ns):
    dt = (np.asarray(dt_ns).astype(np.float64) * 1e-9)[:, None]
    return P + dt * (V + (0.5 * dt) * A), V + dt * A


def rule_contacts(ids, P, V, A, R, T, horizon: float, slack_ns: int | None = None,
                  reference_ns: int | None = None) -> dict:
    """{(id_a, id_b): ttc} for every reported pair (id_a < id_b); arrays in the given dimension.

    reference_ns : R (default the newest stamp; a scene keeps the newest stamp
        accepted since it was last empty, even after that body left).
    """
    slack_ns = default_slack_ns(horizon) if slack_ns is None else slack_ns
    order = sorted(range(len(ids)), key=ids.__getitem__)
    ids = [ids[k] for k in order]
    P, V, A, R, T = (np.asarray(x)[order] for x in (P, V, A, R, T))
    if len(ids) < 2:
        return {}
    ref = int(T.max()) if reference_ns is None else int(reference_ns)
    epoch = ref - ref % slack_ns
    I, J = np.triu_indices(len(ids), 1)
    tp = np.maximum(epoch, np.maximum(T[I], T[J]))
    pa, va = _at(P[I], V[I], A[I], tp - T[I])
    pb, vb = _at(P[J], V[J], A[J], tp - T[J])
    tau = time_to_collision(pa, va, A[I], R[I], pb, vb, A[J], R[J], horizon + slack_ns * 1e-9)
    d = (ref - tp).astype(np.float64) * 1e-9
    ttc = np.where(tp == ref, tau, tau - d)
    past = np.flatnonzero((tp < ref) & (tau <= d))
    if past.size:
        I2, J2 = I[past], J[past]
        qa, wa = _at(P[I2], V[I2], A[I2], ref - T[I2])
        qb, wb = _at(P[J2], V[J2], A[J2], ref - T[J2])
        ttc[past] = time_to_collision(qa, wa, A[I2], R[I2], qb, wb, A[J2], R[J2], horizon)
    return {(ids[i], ids[j]): float(t) for i, j, t in zip(I.tolist(), J.tolist(), ttc.tolist())
            if t <= horizon}
