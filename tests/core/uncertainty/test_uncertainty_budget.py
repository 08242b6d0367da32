"""Which pairs the per-prediction budget evaluates, and the reuse of full evaluations
(docs/uncertainty.md, "Screening and the per-prediction budget").

Guarantees proved here:
* first come, first served: with every body moved and restamped before each evaluation (so
  nothing can be reused), a pair deferred at evaluation s is fully evaluated within
  ceil(n_s / m) evaluations, n_s = the pairs deferred at s, and every evaluated row is bit for
  bit the unbudgeted answer -- the earliest-contact-first order this replaced kept deferring
  the same pairs for as long as their contacts stayed later;
* the order is a function of the sequence of inputs alone: two scenes fed the same inputs
  give the same bits (replay makes the node's calls in the node's order);
* reuse: a row whose relative inputs equal, bit for bit, those of a row fully evaluated by
  the previous call takes that answer bit for bit without counting against the budget, in
  the core (``uncertain_pairs(memo=...)``) and in the scene (a change elsewhere at the same
  reference time);
* a pair that waits with unchanged inputs is not screened again (``screened_first``): the
  screen runs only on the other rows, and every answer is bit for bit the one that screening
  all rows gives, in the core and in a per-body stream through the scene.
"""
from __future__ import annotations

import math

import numpy as np

from circle_collision_ros.core.scene import Scene
from circle_collision_ros.core.uncertainty import batch, deferred_count, uncertain_pairs

BASE = 1_700_000_000 * 1_000_000_000
THR = 0.01
H = 3.0


def _crowd(n: int, seed: int):
    """n slow bodies in a small square, position sigma 0.3 m, velocity sigma 0.1 m/s."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-4.0, 4.0, (n, 2))
    v = rng.uniform(-0.5, 0.5, (n, 2))
    r = rng.uniform(0.2, 0.4, n)
    cov = np.tile(np.diag([0.09, 0.09, 0.01, 0.01]), (n, 1, 1))
    return [f"b{k:02d}" for k in range(n)], p, v, r, cov


def _feed(scene: Scene, ids, p, v, r, cov, stamp: int) -> None:
    n = len(ids)
    scene.merge(ids, np.full(n, stamp, dtype=np.int64), p, v, np.zeros((n, 2)), r,
                np.zeros(n, dtype=bool), stamp, covariances=cov)


def _rows(u):
    return {
        (a, b): (p, e, t)
        for a, b, p, e, t in zip(u.id_a.tolist(), u.id_b.tolist(), u.probability.tolist(),
                                 u.probability_bound.tolist(), u.plausible_ttc.tolist())
    }


def _deferred(u) -> set:
    """The pairs of a SceneUncertainty the budget deferred."""
    if u.deferred_rows is None:
        return set()
    return {(u.id_a[j], u.id_b[j]) for j in np.flatnonzero(u.deferred_rows)}


def test_budget_serves_the_longest_waiting_pairs_first() -> None:
    ids, p, v, r, cov = _crowd(14, seed=3)
    m = 2
    budgeted, twin, unlimited = Scene(H, 2), Scene(H, 2), Scene(H, 2)
    frames = 30
    history = []  # per evaluation: {pair: "deferred" | "evaluated"} of the unscreened pairs
    for f in range(frames):
        stamp = BASE + f * 50_000_000
        q = p + v * (0.05 * f)  # every body moved and restamped: no input repeats
        for s in (budgeted, twin, unlimited):
            _feed(s, ids, q, v, r, cov, stamp)
        got = budgeted.uncertain_pairs(THR, budgeted.predictions(), max_evaluated=m)
        same = twin.uncertain_pairs(THR, twin.predictions(), max_evaluated=m)
        full = unlimited.uncertain_pairs(THR, unlimited.predictions())
        assert all(
            np.asarray(x).tobytes() == np.asarray(y).tobytes()
            for x, y in zip(
                (got.id_a, got.id_b, got.probability, got.probability_bound, got.plausible_ttc),
                (same.id_a, same.id_b, same.probability, same.probability_bound,
                 same.plausible_ttc),
            )
        )
        want = _rows(full)
        state = {}
        waiting = _deferred(got)
        for key, (prob, bound, t) in _rows(got).items():
            if key in waiting:
                state[key] = "deferred"
            elif not (prob == 0.0 and math.isinf(t) and 0.0 < bound <= THR / 2):
                # not cleared by a screen: fully evaluated, the unbudgeted bits
                assert (prob, bound, t) == want[key]
                state[key] = "evaluated"
        assert sum(x == "evaluated" for x in state.values()) == min(m, len(state))
        history.append(state)
    waits = 0
    for s, state in enumerate(history):
        n_s = sum(x == "deferred" for x in state.values())
        for key, x in state.items():
            if x != "deferred" or (s > 0 and history[s - 1].get(key) == "deferred"):
                continue  # not the start of a wait
            limit = math.ceil(n_s / m)
            for j in range(1, limit + 1):
                nxt = history[s + j] if s + j < frames else None
                if nxt is None or nxt.get(key) != "deferred":
                    break  # evaluated, screened, unlisted, or the run ended
            else:
                raise AssertionError(f"{key} deferred at {s} still waits after {limit} evaluations")
            waits += 1
    assert waits > 20  # the rule was exercised: pairs did wait and were served


def test_memo_reuses_full_evaluations_outside_the_budget() -> None:
    rng = np.random.default_rng(5)
    n = 24
    pa = rng.uniform(-1.5, 1.5, (n, 2))
    va = rng.uniform(-1.0, 1.0, (n, 2))
    pb = np.zeros((n, 2))
    vb = np.zeros((n, 2))
    acc = np.zeros((n, 2))
    ra = np.full(n, 0.3)
    rb = np.full(n, 0.3)
    cov = np.tile(np.diag([0.04, 0.04, 0.01, 0.01]), (n, 1, 1))
    args = (pa, va, acc, ra, cov, pb, vb, acc, rb, cov)
    full = uncertain_pairs(*args, H, THR, screen=True)
    m = 3
    memo: dict = {}
    first = uncertain_pairs(*args, H, THR, screen=True, max_evaluated=m, memo=memo)
    done1 = np.flatnonzero(~first.deferred)
    open1 = np.flatnonzero(first.deferred)
    assert open1.size > m and len(memo) == m
    second = uncertain_pairs(*args, H, THR, screen=True, max_evaluated=m, memo=memo)
    deferred2 = second.deferred
    assert np.count_nonzero(deferred2) == open1.size - m  # the m reused rows did not count
    assert len(memo) == 2 * m
    for f, g in zip(full, second):
        assert f[~deferred2].tobytes() == g[~deferred2].tobytes()
    for f, g in zip(first, second):
        assert f[done1].tobytes() == g[done1].tobytes()
    # a different threshold or horizon is a different input: nothing reused
    third = uncertain_pairs(*args, H, 0.02, screen=True, max_evaluated=m, memo=memo)
    assert len(memo) == m and deferred_count(third) > 0


def test_scene_reuses_pairs_a_change_elsewhere_leaves_alone() -> None:
    ids, p, v, r, cov = _crowd(14, seed=3)
    scene = Scene(H, 2)
    _feed(scene, ids, p, v, r, cov, BASE)
    m = 2
    before = scene.uncertain_pairs(THR, scene.predictions(), max_evaluated=m)
    # an exact body far away, same stamp: the reference time and every listed pair's inputs stay
    scene.merge(["zz"], np.array([BASE], dtype=np.int64), np.array([[500.0, 500.0]]),
                np.zeros((1, 2)), np.zeros((1, 2)), np.array([0.5]), np.zeros(1, dtype=bool), BASE)
    after = scene.uncertain_pairs(THR, scene.predictions(), max_evaluated=m)
    rows0, rows1 = _rows(before), _rows(after)
    assert rows0.keys() == rows1.keys()
    done0 = rows0.keys() - _deferred(before)
    assert all(rows1[k] == rows0[k] for k in done0)
    assert after.deferred == before.deferred - m > 0


def test_a_body_removed_and_added_again_is_a_new_body_for_the_budget() -> None:
    """The budget's FIFO keys a waiting pair on its two bodies (slots and body serials): when
    a body of a deferred pair is removed and added again (same id) before the next evaluation,
    the pair waits from then, as a new pair does, instead of keeping its place in the queue."""
    ids = ["a", "b", "c"]
    p = np.array([[0.0, 0.0], [1.5, 0.0], [-2.5, 0.0]])  # (a, b) nearer than (a, c); (b, c) far
    v = np.zeros((3, 2))
    r = np.full(3, 0.5)
    cov = np.tile(np.diag([0.09, 0.09, 0.01, 0.01]), (3, 1, 1))

    def kinds(u):
        waiting = _deferred(u)
        return {
            k: "deferred" if k in waiting else (
                "screened" if q == 0.0 and math.isinf(t) and 0.0 < e <= THR / 2 else "evaluated")
            for k, (q, e, t) in _rows(u).items()
        }

    runs = {}
    for readd in (False, True):
        scene = Scene(H, 2)
        _feed(scene, ids, p, v, r, cov, BASE)
        first = kinds(scene.uncertain_pairs(THR, scene.predictions(), max_evaluated=1))
        stamp = BASE + 50_000_000
        if readd:
            scene.merge(["c"], [stamp], np.zeros((1, 2)), np.zeros((1, 2)), np.zeros((1, 2)), [0.0],
                        [True], stamp)
            stamp += 1
        _feed(scene, ids, p + 1e-3, v, r, cov, stamp)  # everything moved: nothing reused
        runs[readd] = first, kinds(scene.uncertain_pairs(THR, scene.predictions(), max_evaluated=1))
    for first, _ in runs.values():
        assert first == {("a", "b"): "evaluated", ("a", "c"): "deferred", ("b", "c"): "screened"}
    # kept: (a, c) waited longest and is served; re-added: every listed pair is new, and the
    # earliest possible contact, (a, b)'s, goes first again
    assert runs[False][1][("a", "c")] == "evaluated" and runs[False][1][("a", "b")] == "deferred"
    assert runs[True][1][("a", "b")] == "evaluated" and runs[True][1][("a", "c")] == "deferred"


def _screened_rows(monkeypatch) -> list:
    """Record the rows each screen_rows_at call of core.uncertainty.batch screens."""
    seen: list = []
    real = batch.screen_rows_at

    def recording(*args):
        seen.append(np.array(args[9]))
        return real(*args)

    monkeypatch.setattr(batch, "screen_rows_at", recording)
    return seen


def test_waiting_rows_with_known_screening_skip_the_screen(monkeypatch) -> None:
    rng = np.random.default_rng(9)
    n = 30
    pa = rng.uniform(-1.5, 1.5, (n, 2))
    va = rng.uniform(-1.0, 1.0, (n, 2))
    zero = np.zeros((n, 2))
    r = np.full(n, 0.3)
    cov = np.tile(np.diag([0.04, 0.04, 0.01, 0.01]), (n, 1, 1))
    args = (pa, va, zero, r, cov, zero, zero, zero, r, cov)
    first = uncertain_pairs(*args, H, THR, screen=True, max_evaluated=3)
    waiting = first.deferred
    assert waiting.sum() > 5
    known = np.where(waiting, first.plausible_time, np.nan)
    seen = _screened_rows(monkeypatch)
    plain = uncertain_pairs(*args, H, THR, screen=True, max_evaluated=3)
    skipped = uncertain_pairs(*args, H, THR, screen=True, max_evaluated=3, screened_first=known)
    assert np.array_equal(seen[0], np.arange(n))
    assert np.array_equal(seen[1], np.flatnonzero(~waiting))  # only the rows not known to wait
    for a, b in zip(plain, skipped):
        assert np.array_equal(a, b, equal_nan=True)


def test_scene_does_not_screen_waiting_pairs_again(monkeypatch) -> None:
    """A per-body stream: one body moves per update, the others' pairs wait with unchanged
    inputs; each update screens only the moved body's pairs (and those whose pair time moved),
    with every answer bit for bit that of a scene that screens every pair."""
    ids, p, v, r, cov = _crowd(16, seed=4)
    scenes = [Scene(H, 2), Scene(H, 2)]
    for scene in scenes:
        _feed(scene, ids, p, v, r, cov, BASE)
        scene.uncertain_pairs(THR, scene.predictions(), max_evaluated=2)
    seen = _screened_rows(monkeypatch)
    rng = np.random.default_rng(1)
    screened = []
    for step in range(1, 12):
        k = int(rng.integers(len(ids)))
        stamp = BASE + step * 1_000_000
        results = []
        for s_i, scene in enumerate(scenes):
            scene.merge([ids[k]], np.array([stamp], dtype=np.int64), p[k : k + 1] + 1e-3 * step,
                        v[k : k + 1], np.zeros((1, 2)), r[k : k + 1], np.zeros(1, dtype=bool),
                        stamp, covariances=cov[k : k + 1])
            old = scene._pair_answers
            # forget the waiting pairs' screening: screen them again
            if s_i == 1 and old is not None:
                scene._pair_answers = old._replace(tau=np.where(old.answered, old.tau, np.nan))
            before = len(seen)
            results.append(_rows(scene.uncertain_pairs(THR, scene.predictions(), max_evaluated=2)))
            screened.append((s_i, sum(x.size for x in seen[before:])))
        assert results[0] == results[1]
    kept = [c for s_i, c in screened if s_i == 0]
    forgot = [c for s_i, c in screened if s_i == 1]
    assert sum(kept) < 0.5 * sum(forgot)
