"""Ego-centred scenes (Scene.set_ego / Scene(ego_ids=...)): only the pairs with an ego body.

Guarantees proved here:

* on seeded random scenes, 2-D and 3-D, the ego scene's rows equal, bit for bit and in the
  same order, the rows of the same scene without an ego set filtered to the pairs with an ego
  body -- tracker-style whole frames (every body moves; bodies join, leave by removal or
  silently and expire; an ego body leaves and comes back; an ego id names no body until it
  arrives) -- test_whole_frames_equal_filtered_all_pairs; per-body streams with newer and
  older stamps, removals, expiry, bulk updates and ego-set changes on the way
  -- test_streams_equal_filtered_all_pairs; and the incremental ego rows equal the ego
  scene's full recomputation all along;
* the uncertain pairs likewise (covariances on some bodies, whole frames and per-body
  updates, no budget) -- test_uncertain_pairs_equal_filtered_all_pairs;
* the broad phase does not touch the other pairs: every pair given to the narrow phase has an
  ego body, a whole frame makes k (N - 1) - k (k - 1) / 2 box tests for k ego bodies among N
  (no sort, no sweep), a non-ego body's update k box tests, an ego body's update N - 1, and the
  pairs evaluated are exactly the whole-scene broad phase's pairs with an ego body
  -- test_broad_phase_skips_non_ego_pairs, test_ego_candidate_pairs_equal_filtered_sweep;
* an empty ego set (None, [], or set back to None) is today's scene bit for bit
  -- test_empty_ego_set_is_the_all_pairs_scene.
"""
from __future__ import annotations

import numpy as np
import pytest

from circle_collision_ros.core import Scene
from circle_collision_ros.core import broad
from circle_collision_ros.core.scene import kernels as scene_kernels

T0 = 1_700_000_000 * 10**9
MS = 1_000_000
_FIELDS = ("ttc", "contact_ns", "overlapping", "point", "normal", "closing_speed")


def _keep(res, ego) -> np.ndarray:
    return np.fromiter((a in ego or b in ego for a, b in zip(res.id_a.tolist(), res.id_b.tolist())),
                       dtype=bool, count=len(res))


def assert_ego_rows(got, everything, ego) -> int:
    """got == the rows of `everything` with an ego body, bit for bit, in the same order; returns
    how many."""
    keep = _keep(everything, ego)
    assert got.reference_ns == everything.reference_ns
    assert got.id_a.tolist() == everything.id_a[keep].tolist()
    assert got.id_b.tolist() == everything.id_b[keep].tolist()
    for name in _FIELDS:
        assert getattr(got, name).tobytes() == getattr(everything, name)[keep].tobytes(), name
    if got.id_utf8 is not None and len(got):  # what the encoders read
        blob, sa, la, sb, lb = got.id_utf8
        assert [bytes(blob[s:s + n]).decode() for s, n in zip(sa, la)] == got.id_a.tolist()
        assert [bytes(blob[s:s + n]).decode() for s, n in zip(sb, lb)] == got.id_b.tolist()
    return int(keep.sum())


def assert_same(x, y) -> None:
    assert x.reference_ns == y.reference_ns
    assert x.id_a.tolist() == y.id_a.tolist() and x.id_b.tolist() == y.id_b.tolist()
    for name in _FIELDS:
        assert getattr(x, name).tobytes() == getattr(y, name).tobytes(), name


def _cloud(rng, n, dim, side):
    return (rng.uniform(0.0, side, (n, dim)), rng.uniform(-3.0, 3.0, (n, dim)),
            rng.uniform(-1.0, 1.0, (n, dim)), rng.uniform(0.2, 2.0, n))


@pytest.mark.parametrize("dim,seed", [(2, 0), (3, 1), (2, 2)])
def test_whole_frames_equal_filtered_all_pairs(dim, seed) -> None:
    """A tracker at 30 Hz: each frame states every body it sees (all move), with a little
    latency on some frames; bodies join, leave by a removal row or by no longer being seen
    (then expire); ego body e1 leaves and comes back, e2 arrives late, "ghost" never comes."""
    rng = np.random.default_rng(seed)
    side = 45.0 if dim == 2 else 16.0
    n = 140
    ids = [f"b{k:03d}" for k in range(n - 2)] + ["e0", "e1"]
    P, V, A, R = _cloud(rng, n, dim, side)
    ego = {"e0", "e1", "e2", "ghost"}
    everything = Scene(3.0, dim)
    only = Scene(3.0, dim, ego_ids=ego)
    assert only.ego_ids == frozenset(ego)
    seen = np.ones(n, dtype=bool)
    reported = 0
    for f in range(45):
        now = T0 + f * 33_333_333
        dt = 0.0333
        P = P + dt * (V + 0.5 * dt * A) + rng.normal(0.0, 0.02, P.shape)
        V = V + dt * A
        if f % 9 == 4:  # a few bodies leave the view (they expire later)
            seen[rng.choice(n, 6, replace=False)] = False
        if f % 9 == 7:
            seen[rng.choice(n, 8, replace=False)] = True
        seen[ids.index("e1")] = not (12 <= f < 20)  # the ego body leaves, then comes back
        rows = np.flatnonzero(seen)
        names = [ids[k] for k in rows.tolist()]
        stamps = np.full(rows.size, now, dtype=np.int64)
        if f % 3 == 1:  # latency: states stamped before the newest one
            stamps -= rng.integers(0, 30, rows.size) * MS
        remove = np.zeros(rows.size, dtype=bool)
        if f % 11 == 5:  # removal rows for some bodies (then back a few frames later)
            remove[rng.choice(rows.size, 4, replace=False)] = True
        Pm, Vm, Am, Rm = P[rows], V[rows], A[rows], R[rows]
        if f == 30:  # the late ego body arrives, near e0
            e2 = [x.copy() for x in _cloud(rng, 1, dim, side)]
            e2[0][0] = P[ids.index("e0")] + 1.5
        if f >= 30:
            e2[0] = e2[0] + dt * e2[1]
            names.append("e2")
            stamps = np.append(stamps, now)
            remove = np.append(remove, False)
            Pm, Vm, Am, Rm = (np.concatenate([x, y]) for x, y in zip((Pm, Vm, Am, Rm), e2))
        for sc in (everything, only):
            sc.merge(names, stamps, Pm, Vm, Am, Rm, remove, now)
            sc.expire(now, 200 * MS)
        got = only.predictions()
        reported += assert_ego_rows(got, everything.predictions(), ego)
        assert len(everything) == len(only)
        if f % 5 == 0:
            assert_same(got, only.full_recomputation())
    assert reported > 200  # the frames had ego pairs to report


@pytest.mark.parametrize("dim,seed,method", [(2, 3, "sweep"), (3, 4, "grid"), (2, 5, "grid")])
def test_streams_equal_filtered_all_pairs(dim, seed, method) -> None:
    """Per-body streams (each state its own message), with removals, expiry, re-adding, bulk
    updates, stamps before R and ego-set changes; after every step the ego rows equal the
    filtered rows of the all-pairs scene and the ego scene's full recomputation."""
    rng = np.random.default_rng(seed)
    side = 22.0 if dim == 2 else 10.0
    sets = [{"e0", "e1"}, {"e1", "e2", "absent"}, {"b0003"}, {"e0", "e1", "e2"}]
    ego = sets[0]
    everything = Scene(3.0, dim, slack=0.8, method=method)
    only = Scene(3.0, dim, slack=0.8, method=method, ego_ids=ego)
    both = (everything, only)
    now = T0
    nid = 0
    gone: dict = {}  # removed ids -> their removal stamp
    reported = 0
    for step in range(320):
        op = int(rng.integers(0, 10))
        ids = everything.ids()
        stamp_of = dict(zip(*[everything.stored_states()[x] for x in (0, 5)]))
        if op == 0 or len(ids) < 8:
            for _ in range(int(rng.integers(1, 4))):
                bid = f"e{nid % 3}" if nid % 7 == 0 and f"e{nid % 3}" not in stamp_of \
                    and f"e{nid % 3}" not in gone else f"b{nid:04d}"
                stamp = now - int(rng.choice([0, 200, 2500])) * MS
                body = _cloud(rng, 1, dim, side)
                for sc in both:
                    sc.upsert(bid, *(x[0] for x in body), stamp_ns=stamp, received_ns=now)
                nid += 1
        elif op == 1:  # removal (an ego body one time in three)
            egos = [b for b in ids if b.startswith("e")]
            b = egos[0] if egos and rng.random() < 0.33 else ids[int(rng.integers(len(ids)))]
            for sc in both:
                assert sc.remove(b, stamp_of[b], now)
            gone[b] = stamp_of[b]
        elif op == 2:  # one body, same or newer stamp
            now += int(rng.choice([0, 1, 30, 400])) * MS
            b = ids[int(rng.integers(len(ids)))]
            body = _cloud(rng, 1, dim, side)
            for sc in both:
                sc.upsert(b, *(x[0] for x in body), stamp_ns=now, received_ns=now)
        elif op == 3:  # one body stamped before R (not before its own state)
            b = ids[int(rng.integers(len(ids)))]
            body = _cloud(rng, 1, dim, side)
            for sc in both:
                sc.upsert(b, *(x[0] for x in body), stamp_ns=max(stamp_of[b] + 1, now - 100 * MS),
                          received_ns=now)
        elif op == 4:  # bulk: a few bodies (per body) or all of them (a rebuild)
            k = int(rng.choice([3, len(ids)]))
            sel = [ids[x] for x in rng.choice(len(ids), size=k, replace=False)]
            body = _cloud(rng, k, dim, side)
            now += int(rng.integers(0, 50)) * MS
            stamps = [max(stamp_of[b] + 1, now - int(rng.integers(0, 80)) * MS) for b in sel]
            for sc in both:
                sc.upsert_many(sel, *body, stamps, now)
        elif op == 5:
            now += int(rng.choice([0, 500, 1500])) * MS
            for sc in both:
                sc.expire(now, 2000 * MS)
        elif op == 6 and gone:  # a removed body comes back with a newer state
            b = sorted(gone)[int(rng.integers(len(gone)))]
            body = _cloud(rng, 1, dim, side)
            for sc in both:
                sc.upsert(b, *(x[0] for x in body), stamp_ns=gone[b] + 1, received_ns=now)
            del gone[b]
        elif op == 7 and step % 4 == 0:  # the ego set changes (also to a body present now)
            ego = sets[int(rng.integers(len(sets)))]
            only.set_ego(ego)
        elif op == 8 and ids:  # a body close to an ego body (or any): pairs to report
            egos = [b for b in ids if b in ego] or ids
            k = ids.index(egos[int(rng.integers(len(egos)))])
            p = everything.snapshot().positions[k]
            for sc in both:
                sc.upsert(f"b{nid:04d}", p + 0.7, np.zeros(dim), np.zeros(dim), 0.5, stamp_ns=now,
                          received_ns=now)
            nid += 1
        got = only.predictions()
        reported += assert_ego_rows(got, everything.predictions(), ego)
        if step % 8 == 0:
            assert_same(got, only.full_recomputation())
    assert reported > 250


def _covariances(rng, n, dim, sigma):
    """(n, 2 dim, 2 dim): about half uncertain (position sigma, velocity sigma / 3, correlated),
    the rest exact (zero)."""
    C = np.zeros((n, 2 * dim, 2 * dim))
    s = sigma * rng.uniform(0.5, 1.5, n)
    for k in range(dim):
        C[:, k, k] = s**2
        C[:, dim + k, dim + k] = (s / 3) ** 2
        C[:, k, dim + k] = C[:, dim + k, k] = 0.5 * s * s / 3
    C[rng.random(n) < 0.5] = 0.0
    return C


def _same_uncertain(got, everything, ego) -> int:
    keep = _keep(everything, ego)
    assert got.reference_ns == everything.reference_ns
    assert got.id_a.tolist() == everything.id_a[keep].tolist()
    assert got.id_b.tolist() == everything.id_b[keep].tolist()
    for name in ("probability", "probability_bound", "plausible_ttc"):
        assert getattr(got, name).tobytes() == getattr(everything, name)[keep].tobytes(), name
    assert got.deferred == 0
    if got.contact_rows is not None:  # rows of the exact contacts: the same pairs
        matched = got.contact_rows >= 0
        assert (got.matched.id_a[got.contact_rows[matched]] == got.id_a[matched]).all()
        theirs = everything.contact_rows[keep] >= 0
        assert (matched == theirs).all()
    return int(keep.sum())


@pytest.mark.parametrize("dim,seed", [(2, 6), (3, 7)])
def test_uncertain_pairs_equal_filtered_all_pairs(dim, seed) -> None:
    """With covariances on about half the bodies: the ego scene's uncertain pairs (no budget)
    equal the all-pairs scene's filtered to the ego pairs, bit for bit, after whole frames
    and after per-body updates (the listing kept and brought up to date), also when an ego
    body leaves and comes back and when the ego set changes."""
    rng = np.random.default_rng(seed)
    side = 14.0 if dim == 2 else 8.0
    n = 36
    ids = [f"b{k:02d}" for k in range(n)]
    P, V, A, R = _cloud(rng, n, dim, side)
    R = R * 0.4
    C = _covariances(rng, n, dim, 0.3)
    ego = {"b03", "b17", "b30"}
    everything, only = Scene(4.0, dim), Scene(4.0, dim, ego_ids=ego)
    both = (everything, only)
    listed = 0
    now = T0
    for f in range(4):  # whole frames
        now = T0 + f * 50 * MS
        P = P + 0.05 * V
        for sc in both:
            sc.merge(ids, np.full(n, now, dtype=np.int64), P, V, A, R, np.zeros(n, dtype=bool),
                     now, C)
        listed += _same_uncertain(only.uncertain_pairs(0.01, only.predictions()),
                                  everything.uncertain_pairs(0.01, everything.predictions()), ego)
    for step in range(24):  # per-body updates (with and without covariance), removal, return
        now += int(rng.choice([1, 20, 130])) * MS
        k = int(rng.choice([3, 17, int(rng.integers(n))]))
        if step == 9:
            for sc in both:
                sc.remove("b17", now, now)
        elif step == 15:
            ego = {"b03", "b05", "b30"}
            only.set_ego(ego)
        else:
            body = _cloud(rng, 1, dim, side)
            cov = _covariances(rng, 1, dim, 0.3) if step % 2 else None
            for sc in both:
                sc.merge([ids[k]], [now], body[0], body[1], body[2], body[3] * 0.4, [False], now,
                         cov)
        listed += _same_uncertain(only.uncertain_pairs(0.01, only.predictions()),
                                  everything.uncertain_pairs(0.01, everything.predictions()), ego)
    assert listed > 500


def test_broad_phase_skips_non_ego_pairs(monkeypatch) -> None:
    """Work proportional to the ego set: k ego bodies among N make k (N - 1) - k (k - 1) / 2
    box tests on a whole frame (each ego box against every box, each pair once, no sweep), k on
    a non-ego body's update and N - 1 on an ego body's; every pair given to the narrow phase
    has an ego body, and they are exactly the whole-scene broad phase's pairs with one."""
    evaluated = []  # per call of the narrow phase on an ego scene: all its pairs have an ego body
    current: list = [None]  # the ego scene being fed
    real_eval, real_store = Scene._evaluate, scene_kernels.evaluate_and_store

    def evaluate(self, A, B, *args, **kwargs):
        if self._ego_ids:
            evaluated.append(bool((self._ego[A] | self._ego[B]).all()))
        return real_eval(self, A, B, *args, **kwargs)

    def store(ia, ib, *args):  # (the per-body path's compiled evaluation)
        if current[0] is not None:
            evaluated.append(bool((current[0]._ego[ia] | current[0]._ego[ib]).all()))
        return real_store(ia, ib, *args)

    monkeypatch.setattr(Scene, "_evaluate", evaluate)
    monkeypatch.setattr(scene_kernels, "evaluate_and_store", store)
    rng = np.random.default_rng(8)
    n = 3000
    ids = [f"b{k:05d}" for k in range(n)]
    P, V, A, R = _cloud(rng, n, 2, 260.0)
    everything = Scene(5.0, 2)
    everything.upsert_many(ids, P, V, A, R, T0)
    everything.predictions()
    whole = everything.evaluated_pairs
    assert everything.box_tests == 0
    _, ca, cb = everything._pairs_full()  # the whole-scene broad phase's pairs
    cand = {(everything._ids[a], everything._ids[b]) for a, b in zip(ca.tolist(), cb.tolist())}
    for k in (1, 4):
        ego = set(ids[100:100 + k])
        sc = current[0] = Scene(5.0, 2, ego_ids=ego | {"not-here"})
        sc.upsert_many(ids, P, V, A, R, T0)
        res = sc.predictions()
        assert sc.box_tests == k * (n - 1) - k * (k - 1) // 2
        mine = {c for c in cand if c[0] in ego or c[1] in ego}
        assert sc.evaluated_pairs == len(mine) < whole // 50
        assert {(sc._ids[a], sc._ids[b]) for a, b in zip(
            sc._ra[:sc._rn][sc._rlive[:sc._rn]].tolist(),
            sc._rb[:sc._rn][sc._rlive[:sc._rn]].tolist())} <= mine
        assert len(res) and all(a in ego or b in ego for a, b in zip(res.id_a, res.id_b))
        # a non-ego body's update: its box against the k ego boxes only
        sc.upsert(ids[7], P[100] + 0.5, V[7], A[7], R[7], stamp_ns=T0 + MS)
        sc.predictions()
        assert sc.box_tests == k
        # an ego body's update: its box against every box
        sc.upsert(ids[100], P[100] + 0.1, V[100], A[100], R[100], stamp_ns=T0 + 2 * MS)
        sc.predictions()
        assert sc.box_tests == n - 1
        live = sc._rlive[:sc._rn]
        assert (sc._ego[sc._ra[:sc._rn][live]] | sc._ego[sc._rb[:sc._rn][live]]).all()
    assert len(evaluated) >= 4 and all(evaluated)


@pytest.mark.parametrize("dim", [2, 3])
def test_ego_candidate_pairs_equal_filtered_sweep(dim) -> None:
    """broad.ego_candidate_pairs: exactly candidate_pairs' pairs with an ego body, (i, j) order."""
    rng = np.random.default_rng(9 + dim)
    n = 800
    p, v, a, r = _cloud(rng, n, dim, 90.0)
    lo, hi = broad.swept_bounds(p, v, a, r, 0.0, 4.0)
    ego = np.zeros(n, dtype=bool)
    ego[rng.choice(n, 5, replace=False)] = True
    for kw in ({}, dict(p=p, v=v, a=a, r=r, tref=np.zeros(n), t_start=0.0, t_end=4.0)):
        I, J, _ = broad.candidate_pairs(lo, hi, **kw)
        keep = ego[I] | ego[J]
        want = sorted(zip(I[keep].tolist(), J[keep].tolist()))
        i, j, tests = broad.ego_candidate_pairs(lo, hi, ego, **kw)
        assert list(zip(i.tolist(), j.tolist())) == want and len(want) > 5
        assert tests == 5 * (n - 1) - 10


def test_empty_ego_set_is_the_all_pairs_scene() -> None:
    """None, [] and an ego set changed back to None: today's scene, bit for bit (the sweep,
    the grid and the hashed grid list the pairs; no ego box test)."""
    rng = np.random.default_rng(10)
    plain, none, empty, back = (Scene(3.0, 2), Scene(3.0, 2, ego_ids=None),
                                Scene(3.0, 2, ego_ids=[]), Scene(3.0, 2, ego_ids=["b0001"]))
    back.set_ego(iter(["b0001", "b0002"]))
    assert back.ego_ids == {"b0001", "b0002"}
    scenes = (plain, none, empty, back)
    ids = [f"b{k:04d}" for k in range(150)]
    P, V, A, R = _cloud(rng, 150, 2, 40.0)
    for sc in scenes:
        sc.upsert_many(ids, P, V, A, R, T0)
    back.predictions()
    back.set_ego(None)
    now = T0
    for step in range(60):
        now += int(rng.choice([0, 10, 300])) * MS
        if step % 10 == 9:  # a whole frame
            P = P + 0.1 * V
            for sc in scenes:
                sc.upsert_many(ids, P, V, A, R, now)
        else:
            k = int(rng.integers(150))
            body = _cloud(rng, 1, 2, 40.0)
            for sc in scenes:
                sc.upsert(ids[k], *(x[0] for x in body), stamp_ns=now)
        want = plain.predictions()
        for sc in scenes[1:]:
            assert_same(sc.predictions(), want)
            assert sc.box_tests == 0 and sc.ego_ids == frozenset()
            assert sc.evaluated_pairs == plain.evaluated_pairs
    assert len(want) > 20


def test_setting_the_same_ego_set_changes_nothing() -> None:
    sc = Scene(3.0, 2, ego_ids=["a", "b"])
    sc.upsert_many(["a", "c"], np.eye(2), np.zeros((2, 2)), np.zeros((2, 2)), np.ones(2), T0)
    first = sc.predictions()
    version = sc._version
    sc.set_ego(("b", "a"))
    assert sc._version == version and sc.predictions() is first
    sc.set_ego(["c"])
    assert sc._version > version
    assert sc.predictions().id_a.tolist() == ["a"] and sc.predictions().id_b.tolist() == ["c"]
    sc.clear()  # the ego set is configuration: kept
    assert sc.ego_ids == {"c"}


@pytest.mark.parametrize("dim", [2, 3])
def test_bulk_merge_stores_the_given_states(dim) -> None:
    """merge's compiled store of many states (an ego frame's main cost besides the look-ups)
    keeps what numpy's assignments kept: extra columns ignored, float32, strided and read-only
    inputs, removal rows among them, stale states refused; and the look-ups of the last
    message's ids are reused only while no body came or went."""
    rng = np.random.default_rng(12)
    n = 200
    ids = [f"b{k:03d}" for k in range(n)]
    wide = rng.uniform(-50.0, 50.0, (n, 2 * 4))  # strided (every other column), extra columns
    P, V = wide[:, ::2], rng.uniform(-2, 2, (n, 4)).astype(np.float32)
    A = rng.uniform(-1, 1, (n, 4))
    A.flags.writeable = False
    R = rng.uniform(0.1, 1.0, n)
    stamps = np.full(n, T0, dtype=np.int64)
    small, big = Scene(3.0, dim), Scene(3.0, dim)
    remove = np.zeros(n, dtype=bool)
    for frame in range(5):
        remove[:] = False
        if frame == 3:
            remove[rng.choice(n, 5, replace=False)] = True
        if frame == 2:  # the same ids as the last message, but a body left in between
            for sc in (big, small):
                assert sc.remove("b003", int(stamps[3]), frame)
        stamps = stamps + 10 * MS
        stamps[7] = T0  # stale after the first frame: refused
        big.merge(list(ids), stamps, P, V, A, R, remove, frame)
        for k in range(0, n, 50):  # the same rows through the numpy path (< 64 at a time)
            sel = slice(k, k + 50)
            small.merge(ids[sel], stamps[sel], P[sel], V[sel], A[sel], R[sel], remove[sel], frame)
        got, want = big.stored_states(), small.stored_states()
        assert got[0] == want[0]
        for x, y in zip(got[1:], want[1:]):
            assert x.tobytes() == y.tobytes()
        assert_same(big.predictions(), small.predictions())
        fresh = [k for k, b in enumerate(got[0]) if b != "b007" or frame == 0]  # (7: stale)
        rows = [ids.index(got[0][k]) for k in fresh]
        assert got[1][fresh].tobytes() == np.ascontiguousarray(P[rows, :dim]).tobytes()
        assert got[2][fresh].tobytes() == V[rows, :dim].astype(np.float64).tobytes()
        assert (got[5][fresh] == stamps[rows]).all() and len(got[0]) == n - 5 * (frame == 3)
        P = P + 0.1
