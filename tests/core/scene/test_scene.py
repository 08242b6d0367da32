"""Scene (the one scene model): incremental predictions equal a full recomputation, bitwise.

The rule is in ``circle_collision_ros/core/scene/`` (and, by brute force on
every pair, in ``tests/scene_rule.py``).  Guarantees proved here:

* after long random sequences of new bodies, one-body and bulk updates with
  older and newer stamps (the reference time and the epoch move), removals and
  expiry, ``predictions()`` equals ``full_recomputation()`` bitwise (pairs,
  order, times, contact times, overlap flags, details) and the brute-force rule
  -- test_incremental_equals_full_long_sequence, test_hypothesis_sequences;
* a scene whose bodies all carry the newest stamp (a tracker array) reports
  exactly ``predict_all_pairs`` on the states propagated to it
  -- test_common_stamp_equals_predict_all_pairs;
* a one-body update evaluates only that body's candidate pairs, also when its
  stamp is newer (the cached times shift), and a whole-scene update takes the
  full path -- test_update_cost_is_local;
* stream rules: a removal remembers its stamp (late older states are ignored,
  newer ones bring the body back), the memory is forgotten at expiry, and
  max_bodies counts after the removals of the same call -- test_removal_*,
  test_max_bodies_counts_after_removals;
* bad input is rejected without changing the scene -- test_bad_inputs;
* the small path's bookkeeping changes no result: expiry through receive-time
  floors drops exactly the bodies and removals received before the limit, also
  with receive times out of order -- test_expiry_with_receive_times_out_of_order;
  each body's record list survives compaction, growth and slot reuse
  -- test_record_lists_survive_compaction_and_growth; a one-body update finds its
  pairs through the static grid, the bodies moved since it was built and the big
  bodies, across grid rebuilds -- test_one_body_updates_between_grid_rebuilds_equal_full;
* a capture (what a published prediction keeps) stays bitwise the states of its
  time through updates, removals, slot reuse, growth, expiry and clear(), also
  read on another thread during updates -- test_capture_*.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from circle_collision_ros.core import predict_all_pairs, Scene
from tests.scene_rule import rule_contacts
from tests.stress import examples

T0 = 1_700_000_000 * 10**9
MS = 1_000_000


def same(x, y) -> bool:
    return (
        len(x) == len(y)
        and x.id_a.tolist() == y.id_a.tolist()
        and x.id_b.tolist() == y.id_b.tolist()
        and x.reference_ns == y.reference_ns
        and np.array_equal(x.ttc, y.ttc)
        and np.array_equal(x.contact_ns, y.contact_ns)
        and np.array_equal(x.overlapping, y.overlapping)
        and np.array_equal(x.point, y.point)
        and np.array_equal(x.normal, y.normal)
        and np.array_equal(x.closing_speed, y.closing_speed)
    )


def assert_rule(sc: Scene) -> None:
    res = sc.predictions()
    ids, P, V, A, R, T = sc.stored_states()
    want = rule_contacts(ids, P, V, A, R, T, sc.horizon, sc._slack_ns, sc.reference_ns)
    got = {(a, b): t for a, b, t in zip(res.id_a.tolist(), res.id_b.tolist(), res.ttc.tolist())}
    assert got == want
    assert res.ttc.tolist() == sorted(res.ttc.tolist())


def rand_body(rng, dim, side):
    return (rng.uniform(0, side, dim), rng.uniform(-3, 3, dim), rng.uniform(-1, 1, dim),
            rng.uniform(0.0, 2.0))


@pytest.mark.parametrize("dim,seed,method", [(2, 0, "grid"), (2, 1, "sweep"), (3, 2, "grid")])
def test_incremental_equals_full_long_sequence(dim, seed, method) -> None:
    """~500 random operations; after each one incremental == full recomputation,
    every 25th also == the brute-force rule on all pairs."""
    rng = np.random.default_rng(seed)
    side = 25.0 if dim == 2 else 12.0
    sc = Scene(3.0, dim, slack=0.8, method=method)
    now = T0  # newest stamp handed out so far
    nid = 0
    nonempty = 0
    for step in range(500):
        op = rng.integers(0, 8)
        ids = sc.ids()
        if op == 0 or len(ids) < 6:
            for _ in range(rng.integers(1, 4)):
                stamp = now - int(rng.choice([0, 200, 2500])) * MS  # also before the epoch
                sc.upsert(
                    f"b{nid:04d}", *rand_body(rng, dim, side), stamp_ns=stamp, received_ns=now
                )
                nid += 1
        elif op == 1:
            b = ids[rng.integers(len(ids))]
            sc.remove(b, sc.stored_states()[5][ids.index(b)], now)
        elif op == 2:  # one body, same or newer stamp
            now += int(rng.choice([0, 1, 30, 400])) * MS
            sc.upsert(ids[rng.integers(len(ids))], *rand_body(rng, dim, side), stamp_ns=now,
                      received_ns=now)
        elif op == 3:  # one body with an older stamp than the reference (not older than its own)
            b = ids[rng.integers(len(ids))]
            own = int(sc.stored_states()[5][ids.index(b)])
            sc.upsert(b, *rand_body(rng, dim, side), stamp_ns=max(own + 1, now - 100 * MS),
                      received_ns=now)
        elif op == 4:  # bulk update of a subset (small: per body; all: full-scene path)
            k = int(rng.choice([3, len(ids)]))
            sel = [ids[x] for x in rng.choice(len(ids), size=k, replace=False)]
            bodies = [rand_body(rng, dim, side) for _ in sel]
            now += int(rng.integers(0, 50)) * MS
            own = dict(zip(*[sc.stored_states()[x] for x in (0, 5)]))
            stamps = [max(own[b] + 1, now - int(rng.integers(0, 80)) * MS) for b in sel]
            sc.upsert_many(sel, *(np.array([b[c] for b in bodies]) for c in range(4)), stamps, now)
        elif op == 5:
            now += int(rng.choice([0, 500, 1500])) * MS
            sc.expire(now, 2000 * MS)
        elif op == 6:  # a body that keeps a fixed gap to another one
            b = ids[rng.integers(len(ids))]
            p, v, a, r = sc.snapshot().positions[0], np.zeros(dim), np.zeros(dim), 0.5
            sc.upsert(f"b{nid:04d}", p + 0.7, v, a, r, stamp_ns=now, received_ns=now)
            nid += 1
        else:
            sc.predictions()  # a query without change
        res = sc.predictions()
        nonempty += len(res) > 0
        assert same(res, sc.full_recomputation()), step
        if step % 25 == 0:
            assert_rule(sc)
    assert_rule(sc)
    assert nonempty > 250


def test_common_stamp_equals_predict_all_pairs() -> None:
    """Every body stamped R: exactly predict_all_pairs on the states propagated to R."""
    rng = np.random.default_rng(4)
    n = 400
    P, V, A = (rng.uniform(-1e6 - 40, -1e6 + 40, (n, 2)), rng.normal(0, 2, (n, 2)),
               rng.normal(0, 0.3, (n, 2)))
    R = rng.uniform(0.2, 1.5, n)
    sc = Scene(5.0, 2)
    ids = [f"b{k:04d}" for k in range(n)]
    sc.upsert_many(ids, P, V, A, R, T0 + 123 * MS)
    res = sc.predictions()
    ref = predict_all_pairs(P, V, A, R, 5.0)  # ids sort like their indices
    assert len(res) == len(ref) > 50
    assert res.id_a.tolist() == [ids[k] for k in ref.i] and res.id_b.tolist() == [
        ids[k] for k in ref.j
    ]
    assert np.array_equal(res.ttc, ref.ttc) and np.array_equal(res.point, ref.point)
    assert np.array_equal(res.normal, ref.normal) and np.array_equal(
        res.closing_speed, ref.closing_speed
    )
    assert np.array_equal(res.contact_ns, T0 + 123 * MS + np.round(ref.ttc * 1e9).astype(np.int64))


def test_update_cost_is_local() -> None:
    rng = np.random.default_rng(5)
    n = 3000
    side = float(np.sqrt(n * 300.0))
    P, V, A = rng.uniform(0, side, (n, 2)), rng.normal(0, 1.5, (n, 2)), np.zeros((n, 2))
    R = rng.uniform(0.3, 1.0, n)
    ids = [f"b{k:05d}" for k in range(n)]
    sc = Scene(5.0, 2)
    sc.upsert_many(ids, P, V, A, R, T0 + 10 * MS)
    sc.predictions()
    full = sc.evaluated_pairs
    assert full > 300  # the full path evaluated the scene's candidate pairs
    for k, dt in enumerate((1, 33, 66, 100)):  # newer stamps inside the epoch
        sc.upsert(ids[k], P[k] + 0.1, V[k], A[k], R[k], stamp_ns=T0 + (10 + dt) * MS)
        res = sc.predictions()
        # its neighbours + overlapping pairs
        assert sc.evaluated_pairs < full // 10, (dt, sc.evaluated_pairs)
        assert same(res, sc.full_recomputation())
    sc.upsert_many(ids, P, V, A, R, T0 + 200 * MS)  # a tracker array: full path
    sc.predictions()
    assert sc.evaluated_pairs >= full // 2


def _static(sc: Scene, body: str, x: float, vx: float, stamp: int, received: int | None = None):
    return sc.upsert(body, (x, 0.0), (vx, 0.0), (0.0, 0.0), 1.0, stamp_ns=stamp,
                     received_ns=stamp if received is None else received)


def test_removal_is_remembered_late_states_ignored() -> None:
    """A late state older than a removal must not bring the body back."""
    sc = Scene(5.0, 2)
    _static(sc, "a", 0.0, 0.0, T0)
    _static(sc, "g", 3.0, -1.0, T0)
    assert sc.predictions().ttc.tolist() == [1.0]
    assert sc.remove("g", T0 + 200 * MS, T0 + 200 * MS)
    assert len(sc.predictions()) == 0
    late = _static(sc, "g", 2.9, -1.0, T0 + 100 * MS, T0 + 300 * MS)
    assert late.not_newer.tolist() == [0] and "g" not in sc and len(sc.predictions()) == 0
    same_stamp = _static(sc, "g", 2.8, -1.0, T0 + 200 * MS, T0 + 300 * MS)
    assert same_stamp.not_newer.size == 1 and "g" not in sc
    back = _static(sc, "g", 2.7, -1.0, T0 + 201 * MS, T0 + 300 * MS)  # newer: a new track
    assert back.accepted.size == 1 and "g" in sc and sc.remembered_removals == 0


def test_removal_memory_is_forgotten_at_expiry() -> None:
    sc = Scene(5.0, 2)
    for k in range(50):
        # unknown ids: remembered too (a removal may overtake its body)
        sc.remove(f"gone{k}", T0, T0)
    assert sc.remembered_removals == 50
    assert _static(sc, "gone1", 0.0, 0.0, T0 - 1).not_newer.size == 1
    sc.expire(T0 + 2000 * MS, 2000 * MS)
    assert sc.remembered_removals == 50  # not yet older than the timeout
    sc.expire(T0 + 2000 * MS + 1, 2000 * MS)
    assert sc.remembered_removals == 0
    assert _static(sc, "gone1", 0.0, 0.0, T0 - 1, T0 + 2001 * MS).accepted.size == 1


def test_max_bodies_counts_after_removals() -> None:
    """A full scene (3 of 3) and one message [remove g, add h] accepts h."""
    sc = Scene(5.0, 2, max_bodies=3)
    for k, b in enumerate("abg"):
        _static(sc, b, 10.0 * k, 0.0, T0)
    z = np.zeros((2, 3))
    res = sc.merge(["g", "h"], [T0 + 1, T0 + 1], z, z, z, [1.0, 1.0], [True, False], T0 + 1)
    assert res.removed.tolist() == [0] and res.accepted.tolist() == [1] and res.full.size == 0
    assert sc.ids() == ["a", "b", "h"]
    res = sc.merge(["i"], [T0 + 2], z[:1], z[:1], z[:1], [1.0], [False], T0 + 2)
    assert res.full.tolist() == [0] and len(sc) == 3


def test_empty_scene_forgets_the_reference_time() -> None:
    sc = Scene(2.0, 2)
    assert len(sc.predictions()) == 0 and sc.reference_ns is None
    _static(sc, "a", 0.0, 0.0, T0)
    assert sc.remove("a", T0)
    assert sc.reference_ns is None
    _static(sc, "b", 0.0, 1.0, T0 - 30 * 10**9)  # a tracker restarted with older stamps
    _static(sc, "c", 3.0, 0.0, T0 - 30 * 10**9)
    assert sc.predictions().ttc.tolist() == [1.0] and sc.reference_ns == T0 - 30 * 10**9


def test_bad_inputs() -> None:
    sc = Scene(2.0, 2)
    _static(sc, "a", 0.0, 0.0, T0)
    before = sc.predictions()
    with pytest.raises(ValueError, match="row"):
        sc.upsert_many(
            ["x", "y"], [[0, 0], [np.nan, 0]], np.zeros((2, 2)), np.zeros((2, 2)), [1, 1], T0
        )
    with pytest.raises(ValueError, match="duplicate"):
        sc.upsert_many(["x", "x"], np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((2, 2)), [1, 1], T0)
    with pytest.raises(ValueError, match="dimension"):
        sc.upsert_many(["x"], np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)), [1], T0)
    assert sc.ids() == ["a"] and sc.predictions() is before
    with pytest.raises(ValueError):
        Scene(0.0)
    with pytest.raises(ValueError):
        Scene(1.0, dim=4)


@settings(max_examples=40, deadline=None)
@given(
    ops=st.lists(
        st.tuples(st.integers(0, 3), st.integers(0, 7), st.integers(0, 2000), st.floats(-4, 4),
                  st.floats(-2, 2)),
        min_size=1,
        max_size=40,
    ),
    slack=st.sampled_from([0.05, 0.4, None]),
)
def test_hypothesis_sequences(ops, slack) -> None:
    sc = Scene(1.5, 2, slack=slack)
    now = T0
    for op, body, dt_ms, x, v in ops:
        bid = f"b{body}"
        if op == 0:
            now += dt_ms * MS
            _static(sc, bid, x, v, now)
        elif op == 1:
            own = dict(zip(*[sc.stored_states()[k] for k in (0, 5)]))
            stamp = max(own.get(bid, 0) + 1, now - dt_ms * MS)
            sc.upsert(
                bid, (x, 0.3 * x), (v, -v), (0.1 * v, 0.0), 0.4, stamp_ns=stamp, received_ns=now
            )
        elif op == 2:
            sc.remove(bid, now, now)
        else:
            sc.expire(now, dt_ms * MS)
        assert same(sc.predictions(), sc.full_recomputation())
    assert_rule(sc)


def test_expiry_with_receive_times_out_of_order() -> None:
    """expire scans only when its limit passes the lowest receive time it may hold (a floor, kept
    as states and removals arrive); with receive times out of order (the service merges with 0,
    replayed clocks) the bodies and removals dropped are exactly those received before the limit."""
    rng = np.random.default_rng(11)
    sc = Scene(2.0, 2)
    recv: dict[str, int] = {}
    removals: dict[str, int] = {}
    stamp = T0
    for step in range(600):
        stamp += MS
        body = f"b{int(rng.integers(0, 40)):02d}"
        received = T0 + int(rng.integers(0, 4000)) * MS
        if rng.random() < 0.15:
            if sc.remove(body, stamp, received):
                del recv[body]
            removals[body] = received
        else:
            res = sc.upsert(
                body, rng.uniform(0, 30, 2), rng.uniform(-1, 1, 2), (0.0, 0.0), 0.5, stamp, received
            )
            if res.accepted.size:
                recv[body] = received
                removals.pop(body, None)
        if step % 7 == 0:
            now = T0 + int(rng.integers(0, 6000)) * MS
            limit = now - 1000 * MS
            gone = sc.expire(now, 1000 * MS)
            want = sorted(b for b, t in recv.items() if t < limit)
            assert gone == want, step
            recv = {b: t for b, t in recv.items() if t >= limit}
            removals = {b: t for b, t in removals.items() if t >= limit}
            assert sc.ids() == sorted(recv) and sc.remembered_removals == len(removals), step
        assert same(sc.predictions(), sc.full_recomputation()), step


def test_one_body_updates_between_grid_rebuilds_equal_full() -> None:
    """A 600-body scene under one-body updates (newer stamps, one epoch): each update's
    pairs come from the static grid (entries of moved bodies masked), the bodies moved
    since it was built (scanned directly) and the big ones; the grid is rebuilt once more
    than n / 8 have moved. After every update, incremental == full recomputation."""
    rng = np.random.default_rng(5)
    n, dim = 600, 2
    sc = Scene(4.0, dim, slack=2.0, method="grid")
    side = 120.0
    P = rng.uniform(0, side, (n, dim))
    V = rng.uniform(-4, 4, (n, dim))
    A = rng.uniform(-1, 1, (n, dim))
    Rad = rng.uniform(0.2, 1.5, n)
    Rad[:3] = 40.0  # bodies too big for the grid's cells
    ids = [f"b{k:04d}" for k in range(n)]
    stamp = T0 - T0 % sc._slack_ns + MS
    sc.upsert_many(ids, P, V, A, Rad, stamp, stamp)
    sc.predictions()
    rebuilds = 0
    for step in range(300):
        stamp += MS
        k = int(rng.integers(n)) if step % 50 else int(rng.integers(3))  # now and then a big one
        p, v, a, r = rand_body(rng, dim, side)
        before = sc._n_moved if sc._grid_built else None
        sc.upsert(ids[k], p, v, a, Rad[k] if k < 3 else r, stamp, stamp)
        res = sc.predictions()
        rebuilds += before is not None and sc._n_moved < before
        assert same(res, sc.full_recomputation()), step
    assert sc.epoch_ns == T0 - T0 % sc._slack_ns  # no epoch rebuild in between
    assert rebuilds >= 2 and len(res) > 20


def test_record_lists_survive_compaction_and_growth() -> None:
    """Each body's records are found through its own list (not a scan of all records); through
    thousands of one-body updates in a dense scene (dead records compacted, buffers grown, slots
    freed and reused) the incremental rows stay bitwise equal to the full recomputation.  A
    compaction stores the records in the kept order (the query then reads them in sequence)."""
    rng = np.random.default_rng(12)
    n = 300
    sc = Scene(4.0, 2, slack=50.0)  # a long epoch: the records live through many updates
    ids = [f"b{k:03d}" for k in range(n)]
    sc.upsert_many(ids, rng.uniform(0, 40, (n, 2)), rng.normal(0, 1, (n, 2)), np.zeros((n, 2)),
                   rng.uniform(0.5, 1.5, n), T0 + MS)
    sc.predictions()
    compactions = 0
    for k in range(1500):
        b = ids[int(rng.integers(0, n))]
        dead = sc._rdead
        if k % 50 == 49:
            sc.remove(b, T0 + (k + 2) * MS)
        else:
            sc.upsert(b, rng.uniform(0, 40, 2), rng.normal(0, 1, 2), (0.0, 0.0),
                      float(rng.uniform(0.5, 1.5)), T0 + (k + 2) * MS)
        res = sc.predictions()
        compactions += sc._rdead < dead
        # a compaction after a query stores the kept order, then the past records
        if k in (600, 1200):
            sc._compact()
            kept, past = sc._fut.size, sc._past.size
            assert np.array_equal(sc._fut, np.arange(kept)), k
            assert np.array_equal(np.sort(sc._past), np.arange(kept, kept + past)), k
        if k % 10 == 0:
            assert same(res, sc.full_recomputation()), k
    assert compactions >= 1
    assert same(sc.predictions(), sc.full_recomputation())


def test_records_follow_the_kept_order_after_a_rebuild() -> None:
    """A rebuild stores its records in pair order; the query after it re-stores them in the
    kept order (sorted by ttc), then the past ones, so the next queries read them in sequence."""
    rng = np.random.default_rng(14)
    n = 200
    sc = Scene(4.0, 2)
    ids = [f"b{k:03d}" for k in range(n)]
    sc.upsert_many(ids, rng.uniform(0, 30, (n, 2)), rng.normal(0, 1, (n, 2)), np.zeros((n, 2)),
                   rng.uniform(0.5, 1.5, n), T0)
    res = sc.predictions()
    sc.upsert(ids[0], (1.0, 1.0), (0.5, 0.0), (0.0, 0.0), 1.0, T0 + 400 * MS)  # shifts R: past rows
    res = sc.predictions()
    assert sc._past.size and sc._fut.size > 20
    sc.set_horizon(4.5)  # rebuild
    res = sc.predictions()
    kept, past = sc._fut.size, sc._past.size
    assert kept > 20 and past > 0
    assert np.array_equal(sc._fut, np.arange(kept))
    assert np.array_equal(np.sort(sc._past), np.arange(kept, kept + past))
    assert same(res, sc.full_recomputation())


@pytest.mark.parametrize("grow", [False, True])
def test_pair_keys_follow_new_ids(grow) -> None:
    """Rows tied in ttc (pairs overlapping at R: ttc 0) are ordered by their ids. The records
    keep their pair keys between queries; a new id between existing ones changes the ranks
    (and enough new ids grow the slot arrays, the keys' scale): the kept keys are renewed,
    so old and new rows still interleave by id, bitwise as the full recomputation orders them."""
    sc = Scene(4.0, 2)
    ids = [f"b{k:03d}" for k in range(0, 40, 2)]  # even numbers: room for ids between them
    n = len(ids)
    xs = np.repeat(np.arange(n // 2) * 10.0, 2) + np.tile([0.0, 1.0], n // 2)  # overlapping twos
    sc.upsert_many(ids, np.c_[xs, np.zeros(n)], np.zeros((n, 2)), np.zeros((n, 2)), np.ones(n), T0)
    first = sc.predictions()
    assert len(first) == n // 2 and np.all(first.ttc == 0.0)
    for k, odd in enumerate(range(1, 40, 4) if not grow else range(1, 40, 2)):
        # a new id between two others, overlapping a body of an existing overlapping pair
        sc.upsert(f"b{odd:03d}", (10.0 * (k % (n // 2)) + 0.5, 0.5), (0.0, 0.0), (0.0, 0.0), 1.0,
                  T0 + (k + 1) * MS)
        res = sc.predictions()
        assert same(res, sc.full_recomputation()), odd
    assert np.all(res.ttc == 0.0) and len(res) > len(first)


def _snapshot_equal(x, y) -> bool:
    return (
        x.reference_ns == y.reference_ns
        and x.ids == y.ids
        and np.array_equal(x.positions, y.positions)
        and np.array_equal(x.velocities, y.velocities)
        and np.array_equal(x.accelerations, y.accelerations)
        and np.array_equal(x.radii, y.radii)
    )


@pytest.mark.parametrize("changes", [3, 200])
def test_capture_keeps_its_states_while_the_scene_changes(changes) -> None:
    """A capture (what a published prediction keeps for its markers) shares the scene's arrays;
    rows are copied into it only as they change (copy on write per row, a full private copy once
    many changed).  Through updates, removals, slot reuse, growth of the arrays, expiry and
    clear(), its snapshot stays bitwise the one it had when taken."""
    rng = np.random.default_rng(13)
    sc = Scene(3.0, 2)
    n = 60
    ids = [f"b{k:03d}" for k in range(n)]
    sc.upsert_many(ids, rng.uniform(0, 20, (n, 2)), rng.normal(0, 1, (n, 2)),
                   rng.normal(0, 0.2, (n, 2)), rng.uniform(0.2, 1.0, n), T0)
    captures = [(sc.capture(), sc.capture().snapshot())]
    stamp, nid = T0, n
    for k in range(changes):
        stamp += MS
        op = k % 4
        if op == 0:
            b = ids[int(rng.integers(0, len(ids)))]
            sc.upsert(b, rng.uniform(0, 20, 2), rng.normal(0, 1, 2), (0.0, 0.0), 0.5, stamp, stamp)
        elif op == 1:
            b = ids.pop(int(rng.integers(0, len(ids))))
            sc.remove(b, stamp, stamp)
        elif op == 2:  # new ids: freed slots reused, then the arrays grow
            new = [f"n{nid + j:04d}" for j in range(int(rng.integers(1, 40)))]
            nid += len(new)
            ids += new
            m = len(new)
            sc.upsert_many(new, rng.uniform(0, 20, (m, 2)), np.zeros((m, 2)), np.zeros((m, 2)),
                           np.full(m, 0.3), stamp, stamp)
        else:
            captures.append((sc.capture(), sc.capture().snapshot()))
    sc.expire(stamp + 10**12, 1)
    assert len(sc) == 0
    sc.clear()
    sc.upsert("z", (1.0, 1.0), (0.0, 0.0), (0.0, 0.0), 1.0, stamp)
    for capture, want in captures:
        assert _snapshot_equal(capture.snapshot(), want)
        assert capture.ids() == want.ids


def test_capture_read_on_another_thread_during_updates() -> None:
    """The marker thread snapshots a capture while the prediction path changes the scene: every
    snapshot equals the scene's states at the capture's time (the lock orders preserve/gather).
    Default run: 600 bodies x 60 steps; --stress: 3,000 bodies x 300 steps."""
    import queue
    import threading

    rng = np.random.default_rng(14)
    sc = Scene(3.0, 2)
    n = examples(600, 3000)
    steps = examples(60, 300)
    side = 200.0 * (n / 3000) ** 0.5  # the stress run's density of bodies
    ids = [f"b{k:04d}" for k in range(n)]
    sc.upsert_many(ids, rng.uniform(0, side, (n, 2)), rng.normal(0, 1, (n, 2)), np.zeros((n, 2)),
                   rng.uniform(0.2, 1.0, n), T0)
    pending: queue.Queue = queue.Queue()
    failures: list = []
    read = []

    def reader() -> None:
        # blocks on the queue (no busy polling: it would starve the writer of the GIL)
        while (item := pending.get()) is not None:
            capture, ref = item
            if not _snapshot_equal(capture.snapshot(), ref):
                failures.append(ref.reference_ns)
            read.append(ref.reference_ns)

    thread = threading.Thread(target=reader)
    thread.start()
    stamp = T0
    try:
        for k in range(steps):
            stamp += MS
            ref_states = sc.stored_states()
            capture = sc.capture()
            ref = Scene(3.0, 2)
            ref.upsert_many(ref_states[0], *ref_states[1:5], ref_states[5])
            ref.reference_ns = sc.reference_ns
            pending.put((capture, ref.snapshot()))
            for b in rng.choice(n, 5, replace=False).tolist():
                sc.upsert(
                    ids[b], rng.uniform(0, side, 2), rng.normal(0, 1, 2), (0.0, 0.0), 0.5, stamp
                )
    finally:
        pending.put(None)  # the reader ends after the last capture
        thread.join(120)
    assert not thread.is_alive()
    assert len(read) == steps  # every capture was read
    assert not failures


def test_stream_after_an_empty_prediction_compiles_nothing_new():
    """An empty prediction must not freeze the shared empty array the query kernels
    also take: it did, and every later one-body update then needed read-only
    specialisations of the compiled query (~15 s to compile, once, on a node's
    first stream). After an empty scene's prediction and a stream of single
    states, the query kernels have only writable signatures."""
    from circle_collision_ros.core.scene import store
    from circle_collision_ros.core.scene import kernels as sk

    sc = Scene(5.0, 2, method="grid")
    sc.predictions()  # empty: R is None
    assert store.EMPTY_I.flags.writeable
    for k in range(12):
        p = np.array([[0.5 * (k % 6), 0.0]])
        sc.merge(
            [f"s{k % 6}"], [10 + k], p, np.array([[1.0, 0.0]]), np.zeros((1, 2)), [1.0], [False], 0
        )
        sc.predictions()
    for kernel in (sk.ordered_query, sk.evaluate_rows):
        assert not any("readonly" in str(t) for sig in kernel.signatures for t in sig), kernel


def test_uncertain_body_count_follows_every_change() -> None:
    """Scene keeps a count of its uncertain bodies, so an exact scene answers uncertain_pairs
    in O(1); the count must equal the uncertain flags of the live bodies after any mix of
    exact and uncertain states, removals, expiry and slot reuse (growth included)."""
    rng = np.random.default_rng(5)
    scene = Scene(2.0, 2)
    stamp = 1_000
    for step in range(400):
        stamp += 1_000
        k = int(rng.integers(1, 6))
        ids = [f"b{int(x)}" for x in rng.choice(40, k, replace=False)]
        cov = np.zeros((k, 4, 4))
        uncertain = rng.random(k) < 0.5
        cov[uncertain] = np.eye(4) * 0.01
        kind = rng.random()
        scene.merge(ids, np.full(k, stamp), rng.uniform(-5, 5, (k, 2)), rng.normal(0, 1, (k, 2)),
                    np.zeros((k, 2)), np.ones(k), rng.random(k) < 0.15, stamp,
                    covariances=cov if kind < 0.7 else None)
        if step % 37 == 0:
            scene.expire(stamp, 8_000)
        assert scene._n_uncertain == int((scene._alive & scene._U).sum()), step
        assert (scene.uncertain_pairs(0.01).id_a.size == 0) or scene._n_uncertain > 0


def test_published_ids_survive_removal_and_slot_reuse() -> None:
    """SceneContacts gathers id_a/id_b on first read from the ids the scene had when it
    published (the scene copies them before a change): reading them after removals, slot
    reuse and growth still gives the published pairs."""
    scene = Scene(5.0, 2)
    n = 12
    ids = [f"body{k:02d}" for k in range(n)]
    p = np.column_stack([np.arange(n) * 1.5, np.zeros(n)])  # neighbours overlap
    scene.merge(ids, np.full(n, 10), p, np.zeros((n, 2)), np.zeros((n, 2)), np.ones(n),
                np.zeros(n, bool), 10)
    first = scene.predictions()
    want = list(zip(first.slot_ids[first.slot_a].tolist(), first.slot_ids[first.slot_b].tolist()))
    assert want and all(a < b for a, b in want)
    # remove half, add new ids into the freed slots, then grow past the capacity
    scene.merge(ids[::2], np.full(n // 2, 20), p[::2], np.zeros((n // 2, 2)), np.zeros((n // 2, 2)),
                np.ones(n // 2), np.ones(n // 2, bool), 20)
    more = [f"new{k:03d}" for k in range(40)]
    scene.merge(more, np.full(40, 30), np.column_stack([np.arange(40) * 1.5, np.ones(40)]),
                np.zeros((40, 2)), np.zeros((40, 2)), np.ones(40), np.zeros(40, bool), 30)
    second = scene.predictions()
    assert list(zip(first.id_a.tolist(), first.id_b.tolist())) == want
    assert set(second.id_a.tolist()) & set(ids[::2]) == set()
    assert any(a.startswith("new") for a in second.id_a.tolist())
