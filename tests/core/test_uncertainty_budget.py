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
  reference time).
"""
from __future__ import annotations

import math

import numpy as np

from circle_collision_ros.core.scene import Scene
from circle_collision_ros.core.uncertainty import DEFERRED_BOUND, deferred_count, uncertain_pairs
from circle_collision_ros.core.uncertainty_kernels import screen_sigmas

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
    return {(a, b): (p, e, t) for a, b, p, e, t in zip(u.id_a.tolist(), u.id_b.tolist(), u.probability.tolist(),
                                                       u.probability_bound.tolist(), u.plausible_ttc.tolist())}


def test_budget_serves_the_longest_waiting_pairs_first() -> None:
    ids, p, v, r, cov = _crowd(14, seed=3)
    m = 2
    budgeted, twin, unlimited = Scene(H, 2), Scene(H, 2), Scene(H, 2)
    _, U = screen_sigmas(THR, 4)
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
        assert all(np.asarray(x).tobytes() == np.asarray(y).tobytes() for x, y in
                   zip((got.id_a, got.id_b, got.probability, got.probability_bound, got.plausible_ttc),
                       (same.id_a, same.id_b, same.probability, same.probability_bound, same.plausible_ttc)))
        want = _rows(full)
        state = {}
        for key, (prob, bound, t) in _rows(got).items():
            if bound == DEFERRED_BOUND:
                state[key] = "deferred"
            elif bound != U:  # not cleared by the screen: fully evaluated, the unbudgeted bits
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
    done1 = np.flatnonzero(first.collision_probability_bound != DEFERRED_BOUND)
    open1 = np.flatnonzero(first.collision_probability_bound == DEFERRED_BOUND)
    assert open1.size > m and len(memo) == m
    second = uncertain_pairs(*args, H, THR, screen=True, max_evaluated=m, memo=memo)
    deferred2 = second.collision_probability_bound == DEFERRED_BOUND
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
    scene.merge(["zz"], np.array([BASE], dtype=np.int64), np.array([[500.0, 500.0]]), np.zeros((1, 2)),
                np.zeros((1, 2)), np.array([0.5]), np.zeros(1, dtype=bool), BASE)
    after = scene.uncertain_pairs(THR, scene.predictions(), max_evaluated=m)
    rows0, rows1 = _rows(before), _rows(after)
    assert rows0.keys() == rows1.keys()
    done0 = {k for k, x in rows0.items() if x[1] != DEFERRED_BOUND}
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
    _, U = screen_sigmas(THR, 4)

    def kinds(u):
        return {k: "deferred" if e == DEFERRED_BOUND else ("screened" if e == U else "evaluated")
                for k, (_, e, _) in _rows(u).items()}

    runs = {}
    for readd in (False, True):
        scene = Scene(H, 2)
        _feed(scene, ids, p, v, r, cov, BASE)
        first = kinds(scene.uncertain_pairs(THR, scene.predictions(), max_evaluated=1))
        stamp = BASE + 50_000_000
        if readd:
            scene.merge(["c"], [stamp], np.zeros((1, 2)), np.zeros((1, 2)), np.zeros((1, 2)), [0.0], [True], stamp)
            stamp += 1
        _feed(scene, ids, p + 1e-3, v, r, cov, stamp)  # everything moved: nothing reused
        runs[readd] = first, kinds(scene.uncertain_pairs(THR, scene.predictions(), max_evaluated=1))
    for first, _ in runs.values():
        assert first == {("a", "b"): "evaluated", ("a", "c"): "deferred", ("b", "c"): "screened"}
    # kept: (a, c) waited longest and is served; re-added: every listed pair is new, and the
    # earliest possible contact, (a, b)'s, goes first again
    assert runs[False][1][("a", "c")] == "evaluated" and runs[False][1][("a", "b")] == "deferred"
    assert runs[True][1][("a", "b")] == "evaluated" and runs[True][1][("a", "c")] == "deferred"
