"""Scene: incremental predictions equal a full recomputation, bitwise.

The rule (see ``circle_collision_ros/core/scene.py``): pair ``(a, b)``, ``a``
ordering first by id, is evaluated at ``t_p = max(epoch, t_ref_a, t_ref_b)``
with horizon ``H + slack``; ``ttc = tau - (now - t_p)``; if that is negative the
pair is evaluated again at ``now`` with horizon ``H``; reported iff ``ttc <= H``.

Guarantees proved here:
* after long random sequences of adds, removes, single/bulk updates, stamped
  (past) states and advances (with epoch rolls), ``predictions()`` equals both
  ``full_recomputation()`` and a brute-force all-pairs evaluation of the rule,
  bitwise (times, pairs, order, details) -- test_incremental_equals_full_*;
* a freshly filled scene reports the same pairs as ``predict_all_pairs`` on the
  propagated states, times equal to ~1 ulp -- test_fresh_scene_matches_predict_all_pairs;
* states propagate exactly under the model, from the stored state in one step
  -- test_advance_propagates_states_in_one_step;
* an update of one body evaluates only that body's neighbour pairs, and an
  advance inside an epoch only re-evaluates pairs whose contact has passed
  -- test_update_cost_is_local;
* bad input is rejected without changing the scene -- test_bad_inputs.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from circle_collision_ros.core import broad_phase as bp
from circle_collision_ros.core import scene as scene_mod
from circle_collision_ros.core import predict_all_pairs, Scene
from circle_collision_ros.core.contact import contact_details
from circle_collision_ros.core.narrow_phase import time_to_collision


def same(x, y):
    return (len(x) == len(y) and x.i.tolist() == y.i.tolist() and x.j.tolist() == y.j.tolist()
            and np.array_equal(x.ttc, y.ttc) and np.array_equal(x.point, y.point)
            and np.array_equal(x.normal, y.normal) and np.array_equal(x.closing_speed, y.closing_speed))


def rule_reference(sc: Scene):
    """The documented rule on ALL pairs (no broad phase, no caches)."""
    ids, P, V, A, R, T = sc.stored_states()
    n = len(ids)
    if n < 2:
        return [], [], np.empty(0), np.empty((0, sc.dim)), np.empty((0, sc.dim)), np.empty(0)
    I, J = np.triu_indices(n, 1)
    E, now, H, S = sc.epoch, sc.time, sc.horizon, sc.slack
    tp = np.maximum(E, np.maximum(T[I], T[J]))
    pa, va = bp.propagate(P[I], V[I], A[I], tp - T[I])
    pb, vb = bp.propagate(P[J], V[J], A[J], tp - T[J])
    tau = time_to_collision(pa, va, A[I], R[I], pb, vb, A[J], R[J], H + S)
    ttc = tau - (now - tp)
    past = ttc < 0
    pt, nm, cs = contact_details(pa, va, A[I], R[I], pb, vb, A[J], R[J], tau)
    if past.any():
        qa, wa = bp.propagate(P[I][past], V[I][past], A[I][past], now - T[I][past])
        qb, wb = bp.propagate(P[J][past], V[J][past], A[J][past], now - T[J][past])
        t2 = time_to_collision(qa, wa, A[I][past], R[I][past], qb, wb, A[J][past], R[J][past], H)
        ttc[past] = t2
        p2, n2, c2 = contact_details(qa, wa, A[I][past], R[I][past], qb, wb, A[J][past], R[J][past], t2)
        pt[past], nm[past], cs[past] = p2, n2, c2
    k = np.flatnonzero(ttc <= H)
    k = k[np.lexsort((J[k], I[k], ttc[k]))]
    return ([ids[x] for x in I[k]], [ids[x] for x in J[k]], ttc[k], pt[k], nm[k], cs[k])


def assert_rule(sc: Scene):
    res = sc.predictions()
    i, j, ttc, pt, nm, cs = rule_reference(sc)
    assert res.i.tolist() == i and res.j.tolist() == j
    assert np.array_equal(res.ttc, ttc)
    assert np.array_equal(res.point, pt) and np.array_equal(res.normal, nm)
    assert np.array_equal(res.closing_speed, cs)


def rand_body(rng, dim, side):
    return (rng.uniform(0, side, dim), rng.uniform(-3, 3, dim), rng.uniform(-1, 1, dim),
            rng.uniform(0.0, 2.0))


@pytest.mark.parametrize("dim,seed,method", [(2, 0, "grid"), (2, 1, "sweep"), (3, 2, "grid")])
def test_incremental_equals_full_long_sequence(dim, seed, method):
    """~600 random operations; after each one incremental == full recomputation,
    every 25th also == brute-force rule on all pairs."""
    rng = np.random.default_rng(seed)
    side = 25.0 if dim == 2 else 12.0
    sc = Scene(3.0, dim, time=100.0, slack=0.8, method=method)
    nid = 0
    nonempty = 0
    for step in range(600):
        op = rng.integers(0, 8)
        ids = sc.ids()
        if op == 0 or len(ids) < 6:
            for _ in range(rng.integers(1, 4)):
                stamp = sc.time - rng.choice([0.0, 0.2, 2.5])  # also before the epoch
                sc.upsert(f"b{nid:04d}", *rand_body(rng, dim, side), stamp=stamp)
                nid += 1
        elif op == 1:
            sc.remove(ids[rng.integers(len(ids))])
        elif op == 2:
            sc.upsert(ids[rng.integers(len(ids))], *rand_body(rng, dim, side))
        elif op == 3:
            sc.advance(rng.choice([0.0, 0.01, 0.3, 1.0]))
        elif op == 4:  # bulk update of a subset (small: per body; large: full rebuild)
            k = int(rng.choice([3, len(ids)]))
            sel = [ids[x] for x in rng.choice(len(ids), size=k, replace=False)]
            bodies = [rand_body(rng, dim, side) for _ in sel]
            sc.upsert_many(sel, *(np.array([b[c] for b in bodies]) for c in range(4)),
                           stamps=sc.time - rng.uniform(0, 0.5, k))
        elif op == 5:
            sc.remove_many([ids[x] for x in rng.choice(len(ids), size=min(3, len(ids)), replace=False)])
        elif op == 6:
            sc.set_time(sc.time + rng.uniform(0, 0.2))
        else:  # a body that does not move relative to another one
            b = ids[rng.integers(len(ids))]
            p, v, a, r = sc.state(b)
            sc.upsert(f"b{nid:04d}", p + 2 * r + 0.5, v, a, 0.5)
            nid += 1
        res = sc.predictions()
        nonempty += len(res) > 0
        assert same(res, sc.full_recomputation()), step
        if step % 25 == 0:
            assert_rule(sc)
    assert_rule(sc)
    assert nonempty > 300


def test_incremental_equals_full_dense_huge_coords():
    """Overlapping clusters at 1e6 m coordinates, incl. pairs whose contact passes
    and re-occurs (accelerations reverse the motion)."""
    rng = np.random.default_rng(9)
    sc = Scene(2.0, 2, time=5.0, slack=0.5)
    n = 60
    P = 1e6 + rng.uniform(0, 6, (n, 2))
    V = rng.uniform(-2, 2, (n, 2))
    # every velocity reverses at t = 1 s (relative motions turn around collinearly)
    sc.upsert_many(range(n), P, V, -V, rng.uniform(0.1, 0.6, n))
    for step in range(120):
        if step % 3 == 0:
            k = int(rng.integers(n))
            sc.upsert(k, 1e6 + rng.uniform(0, 6, 2), rng.uniform(-2, 2, 2), rng.uniform(-2, 2, 2), 0.3)
        sc.advance(rng.choice([0.05, 0.2]))
        assert same(sc.predictions(), sc.full_recomputation()), step
        if step % 20 == 0:
            assert_rule(sc)


def test_fresh_scene_matches_predict_all_pairs():
    """All states given at the scene time: same pairs as predict_all_pairs, ttc to ~ulp
    (the scene runs the narrow phase with horizon H + slack, which may move the
    root by an ulp; equality is bitwise for the rule, see above)."""
    rng = np.random.default_rng(4)
    n = 500
    P = rng.uniform(0, 100, (n, 2))
    V = rng.uniform(-3, 3, (n, 2))
    A = rng.uniform(-0.5, 0.5, (n, 2))
    R = rng.uniform(0.3, 2, n)
    sc = Scene(5.0, 2, time=12.5)
    sc.upsert_many(range(n), P, V, A, R)
    res = sc.predictions()
    ref = predict_all_pairs(P, V, A, R, 5.0)
    got = dict(zip(zip(res.i.tolist(), res.j.tolist()), res.ttc))
    exp = dict(zip(zip(ref.i.tolist(), ref.j.tolist()), ref.ttc))
    assert got.keys() == exp.keys() and len(got) > 10
    for k in got:
        assert got[k] == pytest.approx(exp[k], rel=1e-12, abs=1e-12)


def test_advance_propagates_states_in_one_step():
    sc = Scene(5.0, 2, time=1.0)
    p, v, a = np.array([1e6, 2.0]), np.array([0.3, -1.1]), np.array([0.7, 0.05])
    sc.upsert("x", p, v, a, 0.5, stamp=0.25)
    for dt in [0.1] * 7 + [3.0]:
        sc.advance(dt)
    q, w, aa, r = sc.state("x")
    dt = sc.time - 0.25
    assert np.array_equal(q, p + v * dt + 0.5 * a * dt * dt)
    assert np.array_equal(w, v + a * dt) and np.array_equal(aa, a) and r == 0.5
    ids, P, V, A, R, T = sc.stored_states()
    assert ids == ["x"] and np.array_equal(P[0], p) and T[0] == 0.25


def test_ttc_shifts_then_passes_then_recontact():
    """Head-on pair: ttc shrinks with time, is 0 while overlapping, and a second
    contact (b brakes, reverses and comes back) is found after the first passed."""
    sc = Scene(10.0, 2, slack=2.0)
    sc.upsert("a", [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], 0.5)
    sc.upsert("b", [5.0, 0.0], [-2.0, 0.0], [0.5, 0.0], 0.5)
    t0 = sc.predictions().ttc[0]
    sc.advance(1.0)
    assert sc.predictions().ttc[0] == pytest.approx(t0 - 1.0)
    seen = []
    for _ in range(200):
        sc.advance(0.05)
        r = sc.predictions()
        seen.append(r.ttc[0] if len(r) else np.inf)
        assert same(r, sc.full_recomputation())
    seen = np.array(seen)
    assert np.any(seen == 0.0) and np.any(np.isinf(seen)) or np.any(seen > 0.1)
    assert_rule(sc)


def test_update_cost_is_local(monkeypatch):
    """One-body update evaluates only that body's candidate pairs; an advance
    within the epoch evaluates only pairs whose contact has passed."""
    rng = np.random.default_rng(2)
    n = 3000
    sc = Scene(5.0, 2, slack=1.0)
    sc.upsert_many(range(n), rng.uniform(0, 1000, (n, 2)), rng.uniform(-3, 3, (n, 2)),
                   rng.uniform(-0.5, 0.5, (n, 2)), rng.uniform(0.3, 2, n))
    sc.predictions()
    calls = []
    real = scene_mod.narrow_on_pairs

    def counting(pa, *args):
        calls.append(pa.shape[0])
        return real(pa, *args)

    monkeypatch.setattr(scene_mod, "narrow_on_pairs", counting)
    for k in range(20):
        sc.upsert(int(rng.integers(n)), rng.uniform(0, 1000, 2), rng.uniform(-3, 3, 2),
                  rng.uniform(-0.5, 0.5, 2), 1.0)
        sc.predictions()
    assert sum(calls) < 20 * 20, calls  # a handful of neighbours each, not N
    calls.clear()
    sc.advance(0.1)
    res = sc.predictions()
    n_past = int(np.sum(res.ttc == 0.0))
    assert sum(calls) <= n_past + 50, (calls, n_past)
    monkeypatch.undo()
    assert same(res, sc.full_recomputation())


def test_epoch_rolls_and_rebuilds():
    sc = Scene(4.0, 2, slack=0.5)
    assert sc.slack == 0.5 and sc.epoch == 0.0
    sc.upsert(1, [0, 0], [1, 0], [0, 0], 0.5)
    sc.upsert(2, [30, 0], [-1, 0], [0, 0], 0.5)
    assert len(sc.predictions()) == 0  # contact at 14.5 s, beyond the horizon
    for _ in range(40):
        sc.advance(0.3)
        assert sc.time - sc.epoch <= sc.slack
        assert same(sc.predictions(), sc.full_recomputation())
    res = sc.predictions()
    assert res.i.tolist() == [1] and res.ttc[0] == pytest.approx(14.5 - sc.time)
    assert Scene(4.0).slack == 1.0  # default: horizon / 4


def test_empty_single_and_ids():
    sc = Scene(1.0, 3)
    assert len(sc.predictions()) == 0 and sc.predictions().point.shape == (0, 3)
    sc.upsert(("robot", 1), [0, 0, 0], [0, 0, 0], [0, 0, 0], 1.0)
    assert len(sc) == 1 and ("robot", 1) in sc and len(sc.predictions()) == 0
    sc.upsert("crate", [0.5, 0, 0], [0, 0, 0], [0, 0, 0], 1.0)  # mixed id types are fine
    res = sc.predictions()
    assert len(res) == 1 and res.ttc[0] == 0.0
    assert {res.i[0], res.j[0]} == {("robot", 1), "crate"}
    sc.remove("crate")
    assert len(sc.predictions()) == 0
    sc.clear()
    assert len(sc) == 0 and len(sc.predictions()) == 0


def test_bad_inputs():
    sc = Scene(2.0, 2, time=10.0)
    sc.upsert("a", [0, 0], [0, 0], [0, 0], 1.0)
    with pytest.raises(ValueError, match="row"):
        sc.upsert("b", [np.nan, 0], [0, 0], [0, 0], 1.0)
    with pytest.raises(ValueError, match=r"row\(s\): 1$"):
        sc.upsert_many(["b", "c"], np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((2, 2)), [1.0, -1.0])
    with pytest.raises(ValueError):
        sc.upsert("b", [0, 0, 0], [0, 0, 0], [0, 0, 0], 1.0)  # wrong dimension
    with pytest.raises(ValueError, match="stamp"):
        sc.upsert("b", [0, 0], [0, 0], [0, 0], 1.0, stamp=10.5)  # in the future
    with pytest.raises(ValueError, match="duplicate"):
        sc.upsert_many(["b", "b"], np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((2, 2)), [1.0, 1.0])
    with pytest.raises(ValueError, match="non-decreasing"):
        sc.set_time(9.0)
    with pytest.raises(ValueError):
        sc.advance(float("nan"))
    with pytest.raises(KeyError):
        sc.remove("zzz")
    with pytest.raises(KeyError):
        sc.add("a", [0, 0], [0, 0], [0, 0], 1.0)
    with pytest.raises(ValueError):
        Scene(0.0)
    with pytest.raises(ValueError):
        Scene(1.0, dim=4)
    assert sc.ids() == ["a"] and sc.time == 10.0


op_strategy = st.tuples(st.sampled_from(["up", "rm", "adv", "bulk"]), st.integers(0, 7),
                        st.floats(0, 0.6), st.integers(0, 2**31 - 1))


@settings(max_examples=40, deadline=None)
@given(ops=st.lists(op_strategy, min_size=1, max_size=40), slack=st.sampled_from([0.0, 0.3, 2.0]))
def test_hypothesis_sequences(ops, slack):
    """Hypothesis-chosen op sequences on 8 ids in a 6 m box (lots of contacts,
    passes and re-contacts): incremental == full == rule after every op."""
    sc = Scene(1.5, 2, slack=slack)
    for kind, k, x, seed in ops:
        rng = np.random.default_rng(seed)
        if kind == "up":
            sc.upsert(k, *rand_body(rng, 2, 6.0), stamp=sc.time - x)
        elif kind == "rm" and k in sc:
            sc.remove(k)
        elif kind == "adv":
            sc.advance(x)
        elif kind == "bulk":
            ids = list(range(k + 1))
            bodies = [rand_body(rng, 2, 6.0) for _ in ids]
            sc.upsert_many(ids, *(np.array([b[c] for b in bodies]) for c in range(4)))
        assert same(sc.predictions(), sc.full_recomputation())
        assert_rule(sc)
