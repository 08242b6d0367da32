"""The scene's uncertain path: ``Scene.uncertain_pairs`` and its helpers (listing by an
inflated broad phase, pair times, per-pair answers kept between calls, the budget's FIFO).

A part of ``Scene``.
"""
from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import replace
from typing import NamedTuple

import numpy as np
from numba import njit

from circle_collision_ros.core import broad as _broad
from circle_collision_ros.core.scene.results import (DeferredInputs, SceneContacts,
                                                     SceneUncertainty)
from circle_collision_ros.core.scene.store import EMPTY_I

__all__ = ["UncertainMixin", "states_at_rows", "complete_uncertainty", "COMPLETION_STEP",
           "NO_WAITING"]


@njit(cache=True, error_model="numpy", inline="always")
def _covariance_row(C, t, out):
    """A joint (position, velocity) covariance (2D, 2D) moved by t s into out: ``M C M^T``,
    ``M = [[I, t I], [0, I]]`` (acceleration is exact, so it adds no uncertainty):
    ``Spp + t (Spv + Svp) + t^2 Svv``, ``Spv + t Svv``, ``Svp + t Svv``, ``Svv``, evaluated
    in that order (the numpy block expression's operations and rounding)."""
    D = C.shape[0] // 2
    tt = t * t
    for r in range(D):
        for c in range(D):
            vv = C[D + r, D + c]
            out[r, c] = C[r, c] + t * (C[r, D + c] + C[D + r, c]) + tt * vv
            out[r, D + c] = C[r, D + c] + t * vv
            out[D + r, c] = C[D + r, c] + t * vv
            out[D + r, D + c] = vv


@njit(cache=True, error_model="numpy")
def states_at_rows(P, V, A, C, T, U, slots, t_ns, p, v, c):
    """The stored bodies `slots` moved from their stamps T to t_ns[j] (int64 ns), in one
    compiled pass: p, v as propagate_ns, c as _covariance_row for an uncertain body
    (U) and zero for an exact one (its stored covariance may be stale).  The same
    operations in the same order as those numpy expressions (no fast-math: no
    contraction into fused multiply-adds), so the same bits."""
    D = P.shape[1]
    for j in range(slots.shape[0]):
        s = slots[j]
        dt = np.float64(t_ns[j] - T[s]) * 1e-9  # integer difference first (stamps ~1.7e18 ns)
        for k in range(D):
            p[j, k] = P[s, k] + dt * (V[s, k] + (0.5 * dt) * A[s, k])
            v[j, k] = V[s, k] + dt * A[s, k]
        if U[s]:
            _covariance_row(C[s], dt, c[j])
        else:
            c[j] = 0.0


# The empty columns of an exact scene's SceneUncertainty (published read-only, shared).
_NO_IDS = np.empty(0, dtype=object)
_NO_VALUES = np.empty(0)
_NO_IDS.flags.writeable = False
_NO_VALUES.flags.writeable = False


class UncertainMixin:
    """Scene's pairs with an uncertain body (see uncertain_pairs)."""

    #: Uncertain pairs: how far (ns) a pair's time t_p may lie before R (see uncertain_pairs).
    #: A pair whose newer state is older than this is evaluated at the start of R's period of
    #: this length, so such pairs are evaluated again once per period, not per input.
    UNCERTAIN_LAG_NS = 100_000_000

    def uncertain_pairs(self, threshold: float, contacts: SceneContacts | None = None,
                        max_evaluated: int | None = None,
                        tolerance: float = 0.0) -> SceneUncertainty:
        """Probabilities of the pairs with an uncertain body that may touch within [R, R + H].

        Which pairs: those the broad phase over R's lag period and the horizon, each uncertain
        body's radius inflated by ``core.uncertainty.inflation_radius``, cannot rule out
        (``_inflated_pairs``: kept between calls, a one-body update looks up that body).
        Each listed pair is evaluated at its pair time t_p over [t_p, t_p + H]: t_p is the
        newer of its two stamps when that lies within ``UNCERTAIN_LAG_NS`` of R (always so for
        a tracker array, where t_p = R; for per-body streams the pair's newest information), else
        ``R - (R mod UNCERTAIN_LAG_NS)``; so 0 <= R - t_p < UNCERTAIN_LAG_NS.  Both states and
        covariances are propagated to t_p.  A pair's answer is thus a pure function of its two
        stored states and t_p, and is kept between calls: a call evaluates only the listed pairs
        whose body changed or whose t_p moved (a one-body update: that body's pairs), and
        results equal a from-scratch evaluation bit for bit (the core's rows are independent).
        The plausible time is reported from R: ``max(0, tau - (R - t_p))`` (0: the overlap
        probability reached the threshold at or before R).  Cached as a whole while the scene
        and `threshold` are unchanged.  `contacts` (the exact path's rows) adds their
        uncertain pairs should the inflated broad phase not list them.  Pairs certified below
        threshold / 2 skip the full evaluation (``core.uncertainty.uncertain_pairs(screen=True)``);
        `max_evaluated` caps the full evaluations (the rest are deferred, see there);
        `tolerance`: the stated bound a full evaluation may reach where that saves work
        (``core.uncertainty.uncertain_pairs``; 0: the per-pair accuracy).

        Which pairs the budget evaluates: first come, first served.  A pair that is deferred
        waits from the first evaluation (call that follows a change) that defers it until one
        evaluates it; each evaluation takes the `max_evaluated` pairs that have waited longest
        (never deferred before counts as waiting from now), then the earliest possible contact,
        then id order.  A pair deferred at evaluation s is therefore evaluated within
        ceil(n_s / max_evaluated) evaluations, n_s = the pairs waiting at s (itself included),
        as long as it stays listed and unscreened (a pair that leaves the list stops waiting; a
        body removed and added again is a new body: its pairs wait from then).
        A pair whose relative inputs are bit for bit those of a pair fully evaluated by the
        previous evaluation takes that answer without counting against the budget.  The order
        depends only on the sequence of scene inputs and calls (no clock): replay, which makes
        the node's calls in the node's order, reproduces it bit for bit.
        See SceneUncertainty.
        """
        key = (self._version, float(threshold), max_evaluated, float(tolerance))
        if self._uncertain_cache is not None and self._uncertain_cache[0] == key:
            return self._uncertain_cache[1]
        res = self._uncertain_pairs(float(threshold), contacts, max_evaluated, float(tolerance))
        self._uncertain_cache = (key, res)
        return res

    def _uncertain_pairs(self, threshold: float, contacts: SceneContacts | None,
                         max_evaluated: int | None, tolerance: float) -> SceneUncertainty:
        R = self.reference_ns
        if R is None or self._n_uncertain == 0:
            self._uncertain_waiting = NO_WAITING  # no pair listed: none waits
            self._pair_answers = None
            return SceneUncertainty(R or 0, _NO_IDS, _NO_IDS, _NO_VALUES, _NO_VALUES, _NO_VALUES)
        # heavy kernels: loaded on first use
        from circle_collision_ros.core import uncertainty as unc
        slots = self._sorted_slots()
        I, J, at_R, (LA, LB), contact_rows = self._uncertain_listed(slots, R, contacts, unc)
        if I.size == 0:
            self._uncertain_waiting = NO_WAITING
            self._pair_answers = None
            return SceneUncertainty(R, _NO_IDS, _NO_IDS, _NO_VALUES, _NO_VALUES, _NO_VALUES)
        sa, sb = slots[I], slots[J]
        ida, idb = self._ids[sa], self._ids[sb]
        tp = self._uncertain_pair_times(sa, sb, R)
        key = (sa << 32) | sb
        prob, bound, tau = np.empty(I.size), np.empty(I.size), np.empty(I.size)
        hit = np.zeros(I.size, dtype=bool)
        # where the last call deferred the pair with these same inputs: its screening
        # tube's first time (the deferred answer's time), so the core skips the screen, and
        # its deferred answer, which the core keeps should it defer the pair again
        screened_first = np.full(I.size, np.nan)
        known = (np.full(I.size, np.nan), np.full(I.size, np.nan))
        sv_a, sv_b = self._sv[sa], self._sv[sb]
        old = self._pair_answers
        # a kept answer needs both bodies unchanged since (state serials below old.sv_next):
        # when every body changed (a tracker array) there is nothing to look up
        if old is not None and old.horizon == self._h and old.threshold == threshold \
                and old.tolerance == tolerance \
                and self._sv[slots].min() < old.sv_next and old.key.size:
            keep = np.argsort(old.key, kind="stable")  # keys are distinct
            at = keep[np.minimum(np.searchsorted(old.key[keep], key), keep.size - 1)]
            same = ((old.key[at] == key) & (old.state_a[at] == sv_a)
                    & (old.state_b[at] == sv_b) & (old.pair_ns[at] == tp))
            hit = same & old.answered[at]
            prob[hit], bound[hit], tau[hit] = (
                old.probability[at[hit]], old.bound[at[hit]], old.tau[at[hit]]
            )
            waited = same & ~old.answered[at]
            screened_first[waited] = old.tau[at[waited]]
            known[0][waited], known[1][waited] = old.probability[at[waited]], old.bound[at[waited]]
        todo = np.flatnonzero(~hit)
        answered = hit.copy()
        pending = None
        if todo.size:
            deferred = self._evaluate_uncertain(unc, sa[todo], sb[todo], LA[todo], LB[todo], at_R,
                                                tp[todo], key[todo], threshold, max_evaluated,
                                                screened_first[todo],
                                                (known[0][todo], known[1][todo]), tolerance)
            prob[todo], bound[todo], tau[todo] = deferred.probability, deferred.bound, deferred.tau
            answered[todo[~deferred.deferred]] = True
            if deferred.pending is not None:
                late = deferred.deferred
                rows = todo[late]
                pending = DeferredInputs(rows, *deferred.pending, tau[rows],
                                         (R - tp[rows]).astype(np.float64) * 1e-9, self._h,
                                         threshold, tolerance)
        else:
            self._uncertain_waiting = NO_WAITING
            self._uncertain_serial += 1
        self._pair_answers = _PairAnswers(
            self._h, threshold, tolerance, self._sv_next, key, answered, sv_a, sv_b, tp, prob,
            bound, tau
        )
        self.uncertain_evaluated = int(todo.size)
        plausible = _from_reference(tau, (R - tp).astype(np.float64) * 1e-9)
        return SceneUncertainty(
            R,
            ida,
            idb,
            prob,
            bound,
            plausible,
            ~answered if max_evaluated is not None and not answered.all() else None,
            contact_rows,
            contacts if contact_rows is not None else None,
            self._id_utf8(sa, sb),
            pending,
        )

    def _uncertain_listed(self, slots: np.ndarray, R: int, contacts: SceneContacts | None, unc):
        """``(I, J, at_R, (LA, LB), contact_rows)``: local index pairs (I < J, into `slots`, id
        order) with an uncertain body listed by the inflated broad phase (``_inflated_pairs``),
        plus the uncertain pairs of `contacts` (with an ego body, under an ego set); at_R =
        (P, V, A, radius, C) of the bodies of those pairs, propagated to R (C zero for exact
        bodies; the same bits as of every body: row by row), LA, LB the pairs' rows in it;
        contact_rows: each pair's row in `contacts`, -1 if none (None without contacts)."""
        sa, sb = self._inflated_pairs(slots, R, unc)
        # slot -> local index through an array (no dict of every body per call)
        local = np.empty(self._ids.shape[0], dtype=np.int64)
        local[slots] = np.arange(slots.size)
        I, J = local[sa], local[sb]
        if contacts is not None and len(contacts):
            if contacts.slot_ids is self._ids:  # no body came or went since: its slots hold
                ca, cb = local[contacts.slot_a], local[contacts.slot_b]
            else:
                slot = self._slot.__getitem__
                ca = local[np.fromiter(map(slot, contacts.id_a.tolist()), np.int64, len(contacts))]
                cb = local[np.fromiter(map(slot, contacts.id_b.tolist()), np.int64, len(contacts))]
            u = self._U[slots]
            m = u[ca] | u[cb]
            if self._ego_ids:  # only the pairs with an ego body (set_ego)
                e = self._ego[slots]
                m &= e[ca] | e[cb]
            I, J = np.concatenate([I, ca[m]]), np.concatenate([J, cb[m]])
        # local order is id order: (min, max) puts the id that sorts first in front
        n = np.int64(slots.size)
        key = np.minimum(I, J) * n + np.maximum(I, J)
        key.sort()  # then drop repeats (a contact the broad phase listed too): np.unique's result
        if key.size > 1:
            key = key[np.concatenate(([True], key[1:] != key[:-1]))]
        rows = None
        if contacts is not None:
            rows = np.full(key.size, -1, dtype=np.int64)
            if len(contacts):
                ckey = np.minimum(ca, cb) * n + np.maximum(ca, cb)
                order = np.argsort(ckey, kind="stable")
                at = np.minimum(np.searchsorted(ckey[order], key), order.size - 1)
                same = ckey[order[at]] == key
                rows[same] = order[at[same]]
        I, J = key // n, key % n
        # the listed pairs' bodies at R (not every body's: an ego set lists few)
        used = np.zeros(slots.size, dtype=bool)
        used[I] = True
        used[J] = True
        used = np.flatnonzero(used)
        at = slots[used]
        P, V, C = self._states_at(at, np.full(at.size, R, dtype=np.int64))
        row = np.empty(slots.size, dtype=np.int64)
        row[used] = np.arange(used.size)
        return I, J, (P, V, self._A[at], self._R[at], C), (row[I], row[J]), rows

    #: The inflated broad phase is rebuilt whole when more than this many bodies changed
    #: since it was last brought up to date (below, only theirs are looked up): each looked-up
    #: body costs a pass over every box, and a few such passes cost a rebuild.
    LISTING_REBUILD_BODIES = 8

    def _inflated_pairs(self, slots: np.ndarray, R: int, unc) -> tuple[np.ndarray, np.ndarray]:
        """``(sa, sb)``: slot pairs, sa < sb, with an uncertain body whose paths, each body's
        radius inflated by ``unc.inflation_radius``, may come within reach over [R0, R0 + H +
        lag], R0 = R - (R mod UNCERTAIN_LAG_NS) the start of R's lag period (every pair time
        t_p lies in it, so [t_p, t_p + H] is covered): their boxes over that window overlap
        (inclusive) and the relative test (``broad.relative_filter``, the lower slot as body a)
        keeps them.

        A function of the stored states and R0 alone: kept between calls, and brought up to
        date by looking up only the bodies whose state changed since (one body's update: its
        box against every box, O(N) comparisons, no sweep), rebuilt whole when R0 or H moves
        or more than LISTING_REBUILD_BODIES changed.  Both ways give the same set (the same
        predicate on every pair).  Under an ego set (set_ego) only the pairs with an ego body
        are listed, by ``broad.ego_box_keys`` (the same box test), both ways."""
        lag = self.UNCERTAIN_LAG_NS
        R0 = R - R % lag
        span = self._h + lag * 1e-9
        cap = self._sv.shape[0]
        old = self._listing
        if old is None or old.R0 != R0 or old.span != span or old.sv.shape[0] != cap:
            changed = None
        else:
            changed = slots[old.sv[slots] != self._sv[slots]]
            if changed.size > self.LISTING_REBUILD_BODIES:
                changed = None
        if changed is None:
            lst = _Listing(R0, span, np.full(cap, -1, dtype=np.int64), np.zeros((cap, self._dim)),
                           np.zeros((cap, self._dim)), np.zeros((cap, self._dim)),
                           np.zeros((cap, self._dim)), np.zeros(cap), EMPTY_I)
            self._listing_boxes(lst, slots, R0, unc)
            if self._ego_ids:  # the ego bodies' boxes against every box (no sweep)
                ego = self._ego_members()
                key, _ = _broad.ego_box_keys(ego, self._alive, self._ego, ego, lst.lo, lst.hi,
                                             np.int64(cap))
                I, J = key // cap, key % cap
            else:
                I, J, _ = _broad.candidate_pairs(lst.lo[slots], lst.hi[slots], method="sweep")
                I, J = slots[I], slots[J]
        else:
            lst = old
            gone = np.zeros(cap, dtype=bool)
            gone[changed] = True
            gone |= ~self._alive
            ka, kb = lst.key >> 32, lst.key & 0xFFFFFFFF
            lst = lst._replace(key=lst.key[~(gone[ka] | gone[kb])])
            self._listing_boxes(lst, changed, R0, unc)
            if self._ego_ids:  # a changed ego body against every box, another against the ego's
                key, _ = _broad.ego_box_keys(changed, self._alive, self._ego,
                                             self._ego_members(), lst.lo, lst.hi, np.int64(cap))
                I, J = key // cap, key % cap
            else:
                I, J = _box_neighbours(lst.lo, lst.hi, changed, slots)
        a, b = np.minimum(I, J), np.maximum(I, J)
        keep = self._U[a] | self._U[b]
        a, b = a[keep], b[keep]
        if a.size:
            keep = _broad.relative_filter(lst.p, lst.v, self._A, lst.reach, np.zeros(cap), a, b,
                                          0.0, span)
            a, b = a[keep], b[keep]
        key = np.concatenate([lst.key, (a << 32) | b])
        key.sort()
        self._listing = lst._replace(key=key)
        return key >> 32, key & 0xFFFFFFFF

    def _listing_boxes(self, lst: "_Listing", changed: np.ndarray, R0: int, unc) -> None:
        """The boxes (over [0, span] from R0), states at R0 and inflated radii of `changed`."""
        if changed.size == 0:
            return
        P, V, C = self._states_at(changed, np.full(changed.size, R0, dtype=np.int64))
        u = self._U[changed]
        grow = np.zeros(changed.size)
        if u.any():
            grow[u] = unc.inflation_radius(C[u], lst.span)
        reach = self._R[changed] + grow
        zero = np.zeros(changed.size)
        lo, hi = _broad.swept_bounds(P, V, self._A[changed], reach, zero, zero + lst.span)
        lst.lo[changed], lst.hi[changed], lst.p[changed], lst.v[changed] = lo, hi, P, V
        lst.reach[changed] = reach
        lst.sv[changed] = self._sv[changed]

    def _states_at(self, slots: np.ndarray, t_ns: np.ndarray):
        """(P, V, C) of the bodies `slots` moved to the times t_ns (int64 ns, per body), C zero
        for exact bodies: see states_at_rows."""
        m = slots.shape[0]
        D = self._dim
        P, V, C = np.empty((m, D)), np.empty((m, D)), np.empty((m, 2 * D, 2 * D))
        states_at_rows(self._P, self._V, self._A, self._C, self._T, self._U, slots, t_ns, P, V, C)
        return P, V, C

    def _uncertain_pair_times(self, sa: np.ndarray, sb: np.ndarray, R: int) -> np.ndarray:
        """Pair times t_p (ns): the newer stamp of the two if it lies within UNCERTAIN_LAG_NS
        of R, else the start of R's lag period (R - R mod UNCERTAIN_LAG_NS); R - t_p < the lag."""
        newer = np.maximum(self._T[sa], self._T[sb])
        lag = self.UNCERTAIN_LAG_NS
        return np.where(newer > R - lag, newer, R - R % lag)

    def _evaluate_uncertain(self, unc, sa, sb, la, lb, at_R, tp, key, threshold: float,
                            max_evaluated: int | None, screened_first: np.ndarray,
                            deferred_answer: tuple[np.ndarray, np.ndarray],
                            tolerance: float) -> "_Evaluated":
        """``unc.uncertain_pairs`` on these pairs (slots sa, sb; local indices la, lb into
        at_R, the bodies at R; key = sa << 32 | sb), each at its t_p over [0, H] (screened,
        within the budget; FIFO bookkeeping of the deferred, see uncertain_pairs);
        screened_first, deferred_answer: as ``unc.uncertain_pairs`` takes them (NaN: screen
        the pair)."""
        R = self.reference_ns
        late = np.flatnonzero(tp != R)  # t_p = R: the bodies as propagated for the listing
        states = []
        for s, loc in ((sa, la), (sb, lb)):
            P, V, A, Rad = _broad.gather_states(loc, *at_R[:4])
            C = at_R[4][loc]
            if late.size:  # the same operations from the stamp to t_p instead
                P[late], V[late], C[late] = self._states_at(s[late], tp[late])
            states.append((P, V, A, Rad, C))
        serial = self._uncertain_serial
        waiting = self._uncertain_waiting
        born_a, born_b = self._born[sa], self._born[sb]
        asked = []

        def waited_since(rows):  # the rows competing for the budget (called only when over it)
            since = waiting.since_of(key[rows], born_a[rows], born_b[rows], serial)
            asked.append((rows, since))
            return since

        if self._uncertain_memo_ref != R:
            # a new reference time moves most pairs' inputs (their t_p follow the stamps):
            # skip the look-ups, which can only forgo a reuse, never give a wrong one
            self._uncertain_memo.clear()
            self._uncertain_memo_ref = R
        res = unc.uncertain_pairs(*states[0], *states[1], self._h, threshold, screen=True,
                                  max_evaluated=max_evaluated, priority=waited_since,
                                  memo=self._uncertain_memo, screened_first=screened_first,
                                  deferred_answer=deferred_answer, tolerance=tolerance)
        deferred = res.deferred
        # the deferred of the rows that competed wait on (since as looked up); the rest stop
        rows = np.concatenate([r for r, _ in asked]) if asked else EMPTY_I
        since = np.concatenate([w for _, w in asked]) if asked else EMPTY_I
        still = deferred[rows]
        rows, since = rows[still], since[still]
        order = np.argsort(key[rows], kind="stable")  # keys are distinct: any sort gives this order
        rows = rows[order]
        self._uncertain_waiting = _Waiting(key[rows], born_a[rows], born_b[rows], since[order])
        self._uncertain_serial = serial + 1
        pending = None
        if deferred.any():  # the deferred rows' inputs, for complete_uncertainty (no copy)
            pending = (states[0], states[1], np.flatnonzero(deferred))
        return _Evaluated(
            res.collision_probability, res.collision_probability_bound, res.plausible_time,
            deferred, pending
        )


class _Waiting(NamedTuple):
    """The pairs the last uncertain evaluation deferred (the budget's FIFO), sorted by key =
    slot_a << 32 | slot_b, with their bodies' serials (``Scene._born``: a slot another body
    took since is another pair; a body removed and added again is a new body, its pairs wait
    from then) and the evaluation serial since which each waits."""

    key: np.ndarray
    born_a: np.ndarray
    born_b: np.ndarray
    since: np.ndarray

    def since_of(
        self, key: np.ndarray, born_a: np.ndarray, born_b: np.ndarray, default: int
    ) -> np.ndarray:
        """(n,) int64: since when each pair (key, born_a, born_b) waits; `default` if not."""
        out = np.full(key.size, default, dtype=np.int64)
        if self.key.size and key.size:
            at = np.minimum(np.searchsorted(self.key, key), self.key.size - 1)
            same = (self.key[at] == key) & (self.born_a[at] == born_a) & (self.born_b[at] == born_b)
            out[same] = self.since[at[same]]
        return out


NO_WAITING = _Waiting(EMPTY_I, EMPTY_I, EMPTY_I, EMPTY_I)


class _PairAnswers(NamedTuple):
    """Scene.uncertain_pairs' answers of the last call, per listed pair (key = slot_a << 32 |
    slot_b, in listing order; answered: not deferred): valid for a later call while both
    bodies' states (serials) and t_p are unchanged."""

    horizon: float
    threshold: float
    tolerance: float
    sv_next: int  # Scene._sv_next then: every state serial of that call is below it
    key: np.ndarray
    answered: np.ndarray
    state_a: np.ndarray
    state_b: np.ndarray
    pair_ns: np.ndarray
    probability: np.ndarray
    bound: np.ndarray
    tau: np.ndarray  # plausible time from t_p, s


class _Listing(NamedTuple):
    """Scene._inflated_pairs' state, per slot (capacity-sized): the lag period's start R0
    (ns) and window span (s) it lists for; each slot's state serial when its box was made
    (-1: none); box lo/hi; state p, v at R0; inflated radius; the listed pairs as sorted
    keys slot_a << 32 | slot_b (slot_a < slot_b)."""

    R0: int
    span: float
    sv: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    p: np.ndarray
    v: np.ndarray
    reach: np.ndarray
    key: np.ndarray


def _box_neighbours(lo, hi, changed, slots) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (c, o) of each changed slot c with every alive slot o (`slots`) whose box
    overlaps c's (inclusive, as the sweep's test), each pair once: o not changed, or o > c."""
    alive = slots
    out_a, out_b = [EMPTY_I], [EMPTY_I]
    is_changed = np.zeros(lo.shape[0], dtype=bool)
    is_changed[changed] = True
    L, Hh = lo[alive], hi[alive]
    for c in changed.tolist():
        hit = np.all((L <= hi[c]) & (lo[c] <= Hh), axis=1)
        o = alive[hit]
        o = o[(o != c) & (~is_changed[o] | (o > c))]
        out_a.append(np.full(o.size, c, dtype=np.int64))
        out_b.append(o)
    return np.concatenate(out_a), np.concatenate(out_b)


class _Evaluated(NamedTuple):
    probability: np.ndarray
    bound: np.ndarray
    tau: np.ndarray
    deferred: np.ndarray
    pending: tuple | None  # (a states, b states, deferred rows among them) at t_p, or None


def _from_reference(tau: np.ndarray, lag: np.ndarray) -> np.ndarray:
    """Plausible times reported from R: a pair's plausible time tau counts from its t_p <= R
    (lag = R - t_p, s); one already reached before R is reported as 0 (plausible now)."""
    return np.where(np.isnan(tau) | (tau > lag), tau - lag, 0.0)


#: complete_uncertainty with a pause: rows per step (a few ms of evaluation at most)
COMPLETION_STEP = 32


def complete_uncertainty(uncertainty: SceneUncertainty, executor: Executor | None = None,
                         parts: int = 1,
                         pause: Callable[[], None] | None = None) -> SceneUncertainty:
    """`uncertainty` with every deferred row given the full evaluation (no row deferred).

    The same rows in the same order; each deferred row's probability, bound and plausible
    time become those of ``core.uncertainty.uncertain_pairs`` without a budget on the inputs
    the scene deferred (``uncertainty.pending``), bit for bit what ``Scene.uncertain_pairs``
    without ``max_evaluated`` gives for that pair at that call (a row's answer is a function
    of its inputs alone, and the screen the scene already ran is not repeated: its outcome
    is kept in ``pending.first``).  A pure function of `uncertainty`: it may run later, on
    another thread, and replay reproduces it.  Unchanged when nothing was deferred.

    executor, parts: the rows evaluated on `parts` of the executor's threads (the kernels
    release the interpreter lock), each taking the next block of rows when it is free;
    pause: called by a thread before it takes each step of COMPLETION_STEP rows (a caller's
    way to step aside; it may let some threads go on and hold others, as the node does).  The
    same bits either way: rows are independent.
    """
    pending = uncertainty.pending
    if pending is None:
        return uncertainty
    from circle_collision_ros.core import uncertainty as unc  # heavy kernels: on first use

    def evaluate_rows(rows):
        at = pending.pick[rows]
        a, b = (tuple(x[at] for x in side) for side in (pending.a, pending.b))
        res = unc.uncertain_pairs(*a, *b, pending.horizon, pending.threshold, screen=True,
                                  screened_first=pending.first[rows], tolerance=pending.tolerance)
        return res.collision_probability, res.collision_probability_bound, res.plausible_time

    k = pending.rows.size
    threads = parts if executor is not None and parts > 1 and k > 1 else 1
    if pause is None and threads == 1:
        blocks = [slice(0, k)]
        results = [evaluate_rows(blocks[0])]
    else:
        size = COMPLETION_STEP if pause is not None else -(-k // threads)
        blocks = [slice(a, min(a + size, k)) for a in range(0, k, size)]
        results = [None] * len(blocks)
        errors = []
        count = {"taken": 0, "done": 0}
        cond = threading.Condition()

        def work():
            # a free thread takes the next block: a thread held by `pause` delays no block,
            # and the answer does not wait for it to return
            while True:
                with cond:
                    if count["taken"] >= len(blocks):
                        return
                if pause is not None:
                    pause()
                with cond:
                    j = count["taken"]
                    if j >= len(blocks):
                        return
                    count["taken"] += 1
                try:
                    results[j] = evaluate_rows(blocks[j])
                except Exception as exc:  # (raised by the caller below)
                    errors.append(exc)
                with cond:
                    count["done"] += 1
                    cond.notify_all()

        if threads > 1:
            for _ in range(min(threads, len(blocks))):
                executor.submit(work)
        else:
            work()
        with cond:
            cond.wait_for(lambda: count["done"] >= len(blocks))
        if errors:
            raise errors[0]
    prob, bound = uncertainty.probability.copy(), uncertainty.probability_bound.copy()
    plausible = uncertainty.plausible_ttc.copy()
    for block, (p, e, tau) in zip(blocks, results):
        rows = pending.rows[block]
        prob[rows], bound[rows] = p, e
        plausible[rows] = _from_reference(tau, pending.lag[block])
    return replace(uncertainty, probability=prob, probability_bound=bound, plausible_ttc=plausible,
                   deferred_rows=None, pending=None)
