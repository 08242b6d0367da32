"""Compiled steps of the scene's small-update path (scene.py and its parts).

Each kernel repeats, row by row, the IEEE operations of the vectorised numpy
code it replaces, in the same order, so its results are bitwise those of:

* ``evaluate_rows``: ``store.propagate_ns`` to the evaluation time, the narrow
  phase (``narrow.batch.ttc_scalar``, or its planar twin in 2-D, bitwise
  ``time_to_collision``),
  ``contact.contact_row`` (the one contact-details formula) at the contact
  time, and the overlap test of ``Scene._resolve`` (``norm(p_a - p_b) -
  (r_a + r_b) < 0`` at that time);
* ``order_rows``: the order of ``Scene._sort`` (``(ttc, rank_a, rank_b)``
  ascending) for rows that were sorted at the previous reference time.

tests/core/scene/test_scene_kernels.py compares them bit for bit with the numpy
code (negative zeros, coincident centres, NaN cases included); the scene's
incremental-equals-full tests compare the whole path.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.extending import overload

from circle_collision_ros.core.broad import cell_keys, ego_box_keys, rel_keep, swept_bound_row
from circle_collision_ros.core.narrow.contact import contact_row
from circle_collision_ros.core.narrow.batch import ttc_scalar, ttc_scalar2

#: contact_row itself (the one formula), compiled into evaluate_rows' loop instead of called:
#: the call passes ten array structs per pair (measured faster: bench/bench_scene_updates.py).
_contact_row_inlined = njit(inline="always", error_model="numpy")(contact_row.py_func)

__all__ = ["evaluate_rows", "order_rows", "split_past", "record_keys", "assemble",
           "swept_bound_rows", "link_records", "kill_records", "split_and_order", "reported_rows",
           "incremental_pairs", "ego_pairs", "evaluate_and_store", "ordered_query"]

#: Overlap decided without the narrow phase: only for values well inside the
#: narrow phase's input range, so no rounding bound below can fail.
_SAFE = 1e100
#: |p_a - p_b|^2 computed in floats is within ~6 units in the last place of
#: the exact value, (r_a + r_b)^2 within ~3: below (1 - 2^-30) of it, the
#: exact f(0) = |p_a - p_b|^2 - (r_a + r_b)^2 is certainly negative.
_OVERLAP_MARGIN = 1.0 - 2.0**-30


def _pair_ttc(pa, va, aa, ra, pb, vb, ab, rb, horizon, Z):
    """The narrow phase of one pair of propagated states (length-3 rows, z = 0 in 2-D)."""
    raise NotImplementedError  # numba-only (the overload below)


@overload(_pair_ttc, inline="always")
def _ov_pair_ttc(pa, va, aa, ra, pb, vb, ab, rb, horizon, Z):
    # Z, a tuple of D zeros, picks the chain at compile time: a 2-D scene compiles only the
    # planar solver (the one its batch kernel calls), which is bitwise ttc_scalar with z = 0
    # (narrow.batch; tests/core/narrow/test_narrow_one_pair.py), instead of both.
    if Z.count == 2:
        return lambda pa, va, aa, ra, pb, vb, ab, rb, horizon, Z: ttc_scalar2(
            pa[0], pa[1], va[0], va[1], aa[0], aa[1], ra,
            pb[0], pb[1], vb[0], vb[1], ab[0], ab[1], rb, horizon)
    return lambda pa, va, aa, ra, pb, vb, ab, rb, horizon, Z: ttc_scalar(
        pa[0], pa[1], pa[2], va[0], va[1], va[2], aa[0], aa[1], aa[2], ra,
        pb[0], pb[1], pb[2], vb[0], vb[1], vb[2], ab[0], ab[1], ab[2], rb, horizon)


@njit(cache=True, error_model="numpy")
def evaluate_rows(P, V, A, Rad, T, ia, ib, t_eval, horizon, tau, point, normal, closing, overlap,
                  Z):
    """Pairs (ia[k], ib[k]) propagated to t_eval[k] (ns), narrow phase with `horizon`.

    Writes tau[k]; for rows with tau <= horizon also point[k], normal[k],
    closing[k] (contact details at tau) and overlap[k] (tau == 0 and the
    propagated gap is negative).  Z: a tuple of D zeros (the dimension, at
    compile time).  Returns the number of narrow-phase rows.
    """
    D = P.shape[1]
    # the pair's states at t_eval: one-row tables (contact_row's layout) and
    # views of their rows (the narrow phase's scalars)
    pa2, va2, aa2 = np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3))
    pb2, vb2, ab2 = np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3))
    pa, va, aa, pb, vb, ab = pa2[0], va2[0], aa2[0], pb2[0], vb2[0], ab2[0]
    g = np.empty(D)
    w = np.empty(D)
    for k in range(ia.shape[0]):
        a = ia[k]
        b = ib[k]
        dta = np.float64(t_eval[k] - T[a]) * 1e-9
        dtb = np.float64(t_eval[k] - T[b]) * 1e-9
        for d in range(D):
            pa[d] = P[a, d] + dta * (V[a, d] + (0.5 * dta) * A[a, d])
            va[d] = V[a, d] + dta * A[a, d]
            aa[d] = A[a, d]
            pb[d] = P[b, d] + dtb * (V[b, d] + (0.5 * dtb) * A[b, d])
            vb[d] = V[b, d] + dtb * A[b, d]
            ab[d] = A[b, d]
        s = (pa[0] - pb[0]) * (pa[0] - pb[0])
        big = 0.0
        for d in range(D):
            if d > 0:
                s += (pa[d] - pb[d]) * (pa[d] - pb[d])
            big = max(big, abs(pa[d]), abs(pb[d]), abs(va[d]), abs(vb[d]), abs(aa[d]), abs(ab[d]))
        rs = Rad[a] + Rad[b]
        if big < _SAFE and 1.0 / _SAFE < rs < _SAFE and s < (rs * rs) * _OVERLAP_MARGIN:
            # f(0) < 0 for certain: the narrow phase's contract answers 0.0 (overlap at 0)
            t = 0.0
        else:
            t = _pair_ttc(pa, va, aa, Rad[a], pb, vb, ab, Rad[b], horizon, Z)
        tau[k] = t
        overlap[k] = False
        if t <= horizon:
            closing[k] = _contact_row_inlined(
                pa2, va2, aa2, 0, Rad[a], pb2, vb2, ab2, 0, t, point, normal, k, g, w
            )
            if t == 0.0:  # the overlap test of Scene._resolve: norm(p_a - p_b) - (r_a + r_b) < 0
                overlap[k] = math.sqrt(s) - rs < 0.0
    return ia.shape[0]


@njit(cache=True)
def split_past(recs, live, rtp, rtau, R, ttc_out, fut_out, past_out, n_fut, n_past):
    """Sort live records `recs` into future rows (ttc at R) and past ones.

    A record at pair time tp reports ttc = tau (tp == R) or tau - (R - tp)
    s; if its contact began before R (tp < R and tau <= R - tp) it is past
    (evaluated again at R).  Appends to fut_out/ttc_out from n_fut and to
    past_out from n_past; returns the new counts.
    """
    for x in range(recs.shape[0]):
        r = recs[x]
        if not live[r]:
            continue
        tp = rtp[r]
        tau = rtau[r]
        if tp == R:
            ttc = tau
        else:
            d = np.float64(R - tp) * 1e-9
            if tau <= d:
                past_out[n_past] = r
                n_past += 1
                continue
            ttc = tau - d
        fut_out[n_fut] = r
        ttc_out[n_fut] = ttc
        n_fut += 1
    return n_fut, n_past


@njit(cache=True)
def _less(t1, k1, t2, k2):
    return t1 < t2 or (t1 == t2 and k1 < k2)


@njit(cache=True)
def _insertion_pass(rec, ttc, key, n, max_moves):
    """Insertion-sort rec/ttc/key[:n] in place by (ttc, key); False once it has needed more
    than max_moves moves (the arrays are then a permutation, partly sorted)."""
    moves = 0
    for i in range(1, n):
        t, k, r = ttc[i], key[i], rec[i]
        j = i
        while j > 0 and _less(t, k, ttc[j - 1], key[j - 1]):
            ttc[j] = ttc[j - 1]
            key[j] = key[j - 1]
            rec[j] = rec[j - 1]
            j -= 1
            moves += 1
        ttc[j], key[j], rec[j] = t, k, r
        if moves > max_moves:
            return False
    return True


@njit(cache=True)
def _time_then_key(ttc, key):
    """The permutation ordering rows by (ttc, key), as np.lexsort((key, ttc)): two stable sorts."""
    o = np.argsort(key, kind="mergesort")
    return o[np.argsort(ttc[o], kind="mergesort")]


@njit(cache=True)
def order_rows(rec, ttc, key, n_sorted, max_moves):
    """Sort rec/ttc/key[:n] in place by (ttc, key) where the first n_sorted
    rows are nearly sorted (insertion sort) and the rest are new (sorted, then
    merged).  Returns False, leaving the arrays unspecified, if the nearly
    sorted part needed more than max_moves moves (the caller sorts from scratch).
    Keys are unique, so (ttc, key) is a total order: every correct sort gives its one result.
    """
    if not _insertion_pass(rec, ttc, key, n_sorted, max_moves):
        return False
    n = rec.shape[0]
    m = n - n_sorted
    if m == 0:
        return True
    # The new rows: key order (unique keys, so quicksort's order is exact), then by ttc with
    # an insertion pass. New rows mostly tie in ttc (0.0: the pairs overlapping at R), so it
    # moves little (measured faster than two stable sorts: bench/bench_scene_updates.py);
    # they remain past the budget.
    o = np.argsort(key[n_sorted:])
    nt = ttc[n_sorted:][o]
    nk = key[n_sorted:][o]
    nr = rec[n_sorted:][o]
    if not _insertion_pass(nr, nt, nk, m, 8 * m + 64):
        o = _time_then_key(ttc[n_sorted:], key[n_sorted:])
        nt = ttc[n_sorted:][o]
        nk = key[n_sorted:][o]
        nr = rec[n_sorted:][o]
    # merge from the back into the full arrays
    i = n_sorted - 1
    j = m - 1
    for out in range(n - 1, -1, -1):
        if j < 0:
            break
        if i >= 0 and _less(nt[j], nk[j], ttc[i], key[i]):
            ttc[out], key[out], rec[out] = ttc[i], key[i], rec[i]
            i -= 1
        else:
            ttc[out], key[out], rec[out] = nt[j], nk[j], nr[j]
            j -= 1
    return True


@njit(cache=True)
def record_keys(first, end, ra, rb, rank, cap, id_start, id_len, rkey, rids):
    """For records first..end-1: rkey[r] = (rank of a) * cap + (rank of b) (unique per pair,
    id order) and rids[r] = (start_a, len_a, start_b, len_b), the ids' places in the UTF-8
    blob.  The scene keeps both until the ranks, the slot capacity or the blob's layout
    change, so a query reads them in record order instead of gathering six slot values per
    row at random (measured faster: bench/bench_scene_updates.py)."""
    for r in range(first, end):
        a = ra[r]
        b = rb[r]
        rkey[r] = rank[a] * cap + rank[b]
        rids[r, 0] = id_start[a]
        rids[r, 1] = id_len[a]
        rids[r, 2] = id_start[b]
        rids[r, 3] = id_len[b]


@njit(cache=True)
def assemble(F, ttc_f, key_f, Pr, tau2, ov2, pt2, nm2, cs2, ra, rb, rkey, rids, rtp, rtau, rov, rpt,
             rnm, rcs, R):
    """The reported rows: future records F (sorted, with their ttc and pair keys) and the
    past records Pr evaluated at R (hits, any order: tau2.. their results), merged by (ttc,
    id_a, id_b); with each row's ids' places in the UTF-8 blob (record_keys).

    contact_ns = t_p + round(tau 1e9) for a record, R + round(tau 1e9) for a
    pair evaluated at R (round half to even, as numpy's round).
    """
    kf = F.shape[0]
    m = kf + Pr.shape[0]
    D = rpt.shape[1]
    o = np.arange(m)
    t_all = np.empty(m)
    k_all = np.empty(m, dtype=np.int64)
    for x in range(kf):
        t_all[x] = ttc_f[x]
        k_all[x] = key_f[x]
    for x in range(Pr.shape[0]):
        t_all[kf + x] = tau2[x]
        k_all[kf + x] = rkey[Pr[x]]
    order_rows(o, t_all, k_all, kf, m * m)  # F is sorted: no moves; never gives up
    A = np.empty(m, dtype=np.int64)
    B = np.empty(m, dtype=np.int64)
    cns = np.empty(m, dtype=np.int64)
    over = np.empty(m, dtype=np.bool_)
    pt = np.empty((m, D))
    nm = np.empty((m, D))
    cs = np.empty(m)
    ids = np.empty((4, m), dtype=np.int64)
    for x in range(m):
        y = o[x]
        if y < kf:
            r = F[y]
            cns[x] = rtp[r] + np.int64(np.rint(rtau[r] * 1e9))
            over[x] = rov[r]
            for d in range(D):
                pt[x, d] = rpt[r, d]
                nm[x, d] = rnm[r, d]
            cs[x] = rcs[r]
        else:
            y -= kf
            r = Pr[y]
            cns[x] = R + np.int64(np.rint(tau2[y] * 1e9))
            over[x] = ov2[y]
            for d in range(D):
                pt[x, d] = pt2[y, d]
                nm[x, d] = nm2[y, d]
            cs[x] = cs2[y]
        A[x] = ra[r]
        B[x] = rb[r]
        for j in range(4):
            ids[j, x] = rids[r, j]
    return (A, B, t_all, cns, over, pt, nm, cs), (ids[0], ids[1], ids[2], ids[3])


@njit(cache=True, error_model="numpy")
def swept_bound_rows(P, V, A, Rad, slots, t0, t1, lo, hi):
    """broad.swept_bounds of the rows `slots` (windows t0[k], t1[k]) into lo/hi[slots],
    for a few bodies at a time (no numpy set-up): the same per-row function."""
    for k in range(slots.shape[0]):
        swept_bound_row(P, V, A, Rad, slots[k], t0[k], t1[k], lo, hi, slots[k])


@njit(cache=True)
def link_records(ra, rb, rnext, rhead, first, end):
    """Put records first..end-1 at the heads of their two slots' lists."""
    for r in range(first, end):
        a = ra[r]
        b = rb[r]
        rnext[r, 0] = rhead[a]
        rhead[a] = r
        rnext[r, 1] = rhead[b]
        rhead[b] = r


@njit(cache=True)
def kill_records(slots, ra, rnext, rhead, rlive):
    """Mark every live record of `slots` dead, walking each slot's list (then emptied);
    returns how many were live.  A record stays in its other slot's list, dead."""
    killed = 0
    for x in range(slots.shape[0]):
        s = slots[x]
        r = rhead[s]
        while r >= 0:
            if rlive[r]:
                rlive[r] = False
                killed += 1
            r = rnext[r, 0] if ra[r] == s else rnext[r, 1]
        rhead[s] = -1
    return killed


@njit(cache=True)
def split_and_order(prev, new, prev_past, live, rkey, rtp, rtau, R, max_moves):
    """Scene._ordered_rows' first half: the live records of the kept order `prev`, the new
    records and the past ones, split at R into future rows (ttc at R) and past ones, and the
    future rows ordered by (ttc, id_a, id_b) (see split_past, order_rows; rkey: record_keys).
    Returns (fut, ttc, key, past, ordered): key the future rows' pair keys; ordered False:
    fut/ttc/key in some order (sort afresh)."""
    m = prev.shape[0] + new.shape[0]
    fut = np.empty(m, dtype=np.int64)
    ttc = np.empty(m)
    past = np.empty(m + prev_past.shape[0], dtype=np.int64)
    nf, npast = split_past(prev, live, rtp, rtau, R, ttc, fut, past, 0, 0)
    n_sorted = nf
    nf, npast = split_past(new, live, rtp, rtau, R, ttc, fut, past, nf, npast)
    nf, npast = split_past(prev_past, live, rtp, rtau, R, ttc, fut, past, nf, npast)
    fut = fut[:nf]
    ttc = ttc[:nf]
    key = np.empty(nf, dtype=np.int64)
    for x in range(nf):
        key[x] = rkey[fut[x]]
    ordered = order_rows(fut, ttc, key, n_sorted, max_moves + 8 * nf)
    return fut, ttc, key, past[:npast], ordered


@njit(cache=True, error_model="numpy")
def reported_rows(fut, ttc, key, past, ra, rb, rkey, rids, rtp, rtau, rov, rpt, rnm, rcs, rsP, rsV,
                  rsA, rsR, rsT, R, H, Z):
    """Scene._ordered_rows' second half: the future rows with ttc <= H (fut, ttc, key sorted by
    (ttc, key)), and the past pairs evaluated at R with horizon H (their hits), merged (see
    evaluate_rows, assemble).
    Returns assemble's rows and id places, and the number of narrow-phase evaluations."""
    kf = np.searchsorted(ttc, H, side="right")
    n = past.shape[0]
    D = rpt.shape[1]
    Ia = np.empty(n, dtype=np.int64)  # rows of the records' own states (rsP.. as 2 rows each)
    Ib = np.empty(n, dtype=np.int64)
    for x in range(n):
        Ia[x] = 2 * past[x]
        Ib[x] = 2 * past[x] + 1
    t_eval = np.full(n, R, dtype=np.int64)
    tau = np.empty(n)
    pt = np.empty((n, D))
    nm = np.empty((n, D))
    cs = np.empty(n)
    ov = np.empty(n, dtype=np.bool_)
    # The records' copies of their bodies' states equal the scene's (a state change kills
    # its body's records), and lie in record order: the past records, stored together by
    # _compact, are read in sequence instead of two bodies' rows of five arrays at random
    # (measured faster: bench/bench_scene_updates.py).
    m = rsP.shape[0] * 2
    evaluated = evaluate_rows(rsP.reshape(m, D), rsV.reshape(m, D), rsA.reshape(m, D),
                              rsR.reshape(m), rsT.reshape(m), Ia, Ib, t_eval, H, tau, pt, nm, cs,
                              ov, Z)
    Pr = np.empty(n, dtype=np.int64)
    h = 0
    for x in range(n):  # keep the hits, in order
        if tau[x] <= H:
            Pr[h] = past[x]
            tau[h] = tau[x]
            for d in range(D):
                pt[h, d] = pt[x, d]
                nm[h, d] = nm[x, d]
            cs[h] = cs[x]
            ov[h] = ov[x]
            h += 1
    rows, ids = assemble(fut[:kf], ttc[:kf], key[:kf], Pr[:h], tau[:h], ov[:h], pt[:h], nm[:h],
                         cs[:h], ra, rb, rkey, rids, rtp, rtau, rov, rpt, rnm, rcs, R)
    return rows, ids, evaluated


@njit(cache=True, inline="always")
def _push_pair(keys, m, s, x, lo, hi, cap):
    """Append the pair {s, x} to keys[m] (as min * cap + max) if x != s and their bounds overlap
    on every axis (closed intervals); returns (keys, m), keys grown when full."""
    if x == s:
        return keys, m
    for d in range(lo.shape[1]):
        if not (lo[x, d] <= hi[s, d] and hi[x, d] >= lo[s, d]):
            return keys, m
    if m == keys.shape[0]:
        grown = np.empty(2 * m, dtype=np.int64)
        grown[:m] = keys
        keys = grown
    keys[m] = min(s, x) * cap + max(s, x)
    return keys, m + 1


@njit(cache=True, error_model="numpy")
def incremental_pairs(dirty, alive, P, V, A, Rad, T, Tf, lo, hi, E, slack_ns, H, t_end, cell,
                      max_cells, gkeys, gslot, gstale, gbig, moved, n_moved, inmoved, rank, cap):
    """Scene._update_incremental's search for the pairs of the changed slots `dirty`, in one pass.

    Marks each dirty slot stale in the static grid and lists it once in `moved` (the
    slots changed since the grid was built, searched exhaustively: their bounds are new);
    sets Tf and the swept bounds of the live dirty slots (Scene._bounds' window, by
    broad.swept_bound_row); collects each live dirty slot's candidates -- static grid
    entries in its hashed cells (broad.cell_keys) that are not stale, the static big
    bodies, every live moved slot; every live slot for a body too big for cells -- keeps
    those whose bounds overlap, one copy per pair in the order of min * cap + max, oriented
    so that the first body's rank is smaller, and applies the broad phase's relative test over
    [0, t_end] (broad.relative_filter).  Returns (A, B, n_moved).

    The pairs are those of the grid with an overlay (bounds overlapping means sharing a
    cell unless one is big), so the same (A, B) in the same order.
    """
    for x in range(dirty.shape[0]):
        s = dirty[x]
        gstale[s] = True
        if not inmoved[s]:
            inmoved[s] = True
            moved[n_moved] = s
            n_moved += 1
        if alive[s]:
            Tf[s] = np.float64(T[s] - E) * 1e-9
            ta = np.float64(max(E, T[s]) - T[s]) * 1e-9
            tb = np.float64(E + slack_ns - T[s]) * 1e-9 + H
            swept_bound_row(P, V, A, Rad, s, ta, tb, lo, hi, s)
    keys = np.empty(64, dtype=np.int64)
    m = 0
    for x in range(dirty.shape[0]):
        s = dirty[x]
        if not alive[s]:
            continue
        ck, _, big = cell_keys(lo[s : s + 1], hi[s : s + 1], cell, max_cells)
        if big[0]:
            for y in range(alive.shape[0]):
                if alive[y]:
                    keys, m = _push_pair(keys, m, s, y, lo, hi, cap)
            continue
        for e in range(ck.shape[0]):
            first = np.searchsorted(gkeys, ck[e], side="left")
            end = np.searchsorted(gkeys, ck[e], side="right")
            for q in range(first, end):
                y = gslot[q]
                if not gstale[y]:
                    keys, m = _push_pair(keys, m, s, y, lo, hi, cap)
        for q in range(gbig.shape[0]):
            y = gbig[q]
            if not gstale[y]:
                keys, m = _push_pair(keys, m, s, y, lo, hi, cap)
        for q in range(n_moved):
            y = moved[q]
            if alive[y]:
                keys, m = _push_pair(keys, m, s, y, lo, hi, cap)
    Ao, Bo = _kept_pairs(np.sort(keys[:m]), P, V, A, Rad, Tf, rank, cap, t_end)
    return Ao, Bo, n_moved


@njit(cache=True, error_model="numpy")
def _kept_pairs(keys, P, V, A, Rad, Tf, rank, cap, t_end):
    """The pairs of ``keys`` (min slot * cap + max slot; a key repeated in a row is taken once)
    oriented so that the first body's rank is smaller, kept by the broad phase's relative test
    over [0, t_end]: (A, B) in key order."""
    D = P.shape[1]
    m = keys.shape[0]
    Ao = np.empty(m, dtype=np.int64)
    Bo = np.empty(m, dtype=np.int64)
    u = 0
    for k in range(m):
        if k > 0 and keys[k] == keys[k - 1]:
            continue
        a = keys[k] // cap
        b = keys[k] % cap
        if rank[a] > rank[b]:
            a, b = b, a
        if D == 2:
            keep = rel_keep(P, V, A, Rad, Tf, a, b, 0.0, t_end, 2)
        else:
            keep = rel_keep(P, V, A, Rad, Tf, a, b, 0.0, t_end, 3)
        if keep:
            Ao[u] = a
            Bo[u] = b
            u += 1
    return Ao[:u], Bo[:u]


@njit(cache=True, error_model="numpy")
def ego_pairs(bounds_of, query, alive, ego, ego_members, P, V, A, Rad, T, Tf, lo, hi, E, slack_ns,
              H, t_end, rank, cap):
    """The candidate pairs of an ego-centred scene (Scene.set_ego), in one pass.

    Sets Tf and the swept bounds of the live slots `bounds_of` (Scene._bounds' window, as
    incremental_pairs), lists the pairs of the slots `query` with at least one ego body whose
    bounds overlap (broad.ego_box_keys: an ego body's box against every box, another body's
    against the ego boxes only), oriented so that the first body's rank is smaller, and applies
    the broad phase's relative test over [0, t_end] (as incremental_pairs).  Returns (A, B,
    box tests), the pairs in the order of min slot * cap + max slot.

    The pairs are exactly those of the whole-scene broad phase (Scene._pairs_full without an
    ego set: the same boxes, the same closed-interval test and relative test) that contain an
    ego body and a body of `query`.
    """
    for x in range(bounds_of.shape[0]):
        s = bounds_of[x]
        if alive[s]:
            Tf[s] = np.float64(T[s] - E) * 1e-9
            ta = np.float64(max(E, T[s]) - T[s]) * 1e-9
            tb = np.float64(E + slack_ns - T[s]) * 1e-9 + H
            swept_bound_row(P, V, A, Rad, s, ta, tb, lo, hi, s)
    keys, tests = ego_box_keys(query, alive, ego, ego_members, lo, hi, cap)
    # each pair is listed once (ego_box_keys tests it once), so no key repeats
    Ao, Bo = _kept_pairs(keys, P, V, A, Rad, Tf, rank, cap, t_end)
    return Ao, Bo, tests


@njit(cache=True, error_model="numpy")
def evaluate_and_store(ia, ib, E, P, V, A, Rad, T, horizon, ra, rb, rtp, rtau, rpt, rnm, rcs, rov,
                       rlive, rnext, rhead, rsP, rsV, rsA, rsR, rsT, n, Z):
    """Scene._evaluate_at_tp + Scene._store for a few pairs: each pair evaluated at its pair
    time max(E, T_a, T_b) (evaluate_rows), the hits (tau <= horizon) written as records from
    row n, in order, with their two bodies' stored states (rsP.., see Scene._REC), and linked
    (link_records).  The record buffers must hold n + len(ia) rows.  Returns (end row,
    narrow-phase rows evaluated)."""
    k = ia.shape[0]
    D = P.shape[1]
    t_eval = np.empty(k, dtype=np.int64)
    for x in range(k):
        t_eval[x] = max(E, max(T[ia[x]], T[ib[x]]))
    tau = np.empty(k)
    pt = np.empty((k, D))
    nm = np.empty((k, D))
    cs = np.empty(k)
    ov = np.empty(k, dtype=np.bool_)
    evaluated = evaluate_rows(P, V, A, Rad, T, ia, ib, t_eval, horizon, tau, pt, nm, cs, ov, Z)
    r = n
    for x in range(k):
        if tau[x] <= horizon:
            ra[r] = ia[x]
            rb[r] = ib[x]
            rtp[r] = t_eval[x]
            rtau[r] = tau[x]
            for d in range(D):
                rpt[r, d] = pt[x, d]
                rnm[r, d] = nm[x, d]
            rcs[r] = cs[x]
            rov[r] = ov[x]
            rlive[r] = True
            for j, s in ((0, ia[x]), (1, ib[x])):
                for d in range(D):
                    rsP[r, j, d] = P[s, d]
                    rsV[r, j, d] = V[s, d]
                    rsA[r, j, d] = A[s, d]
                rsR[r, j] = Rad[s]
                rsT[r, j] = T[s]
            r += 1
    link_records(ra, rb, rnext, rhead, n, r)
    return r, evaluated


@njit(cache=True, error_model="numpy")
def ordered_query(prev, new, prev_past, live, ra, rb, rkey, rids, key_from, key_end, rtp, rtau, rov,
                  rpt, rnm, rcs, rsP, rsV, rsA, rsR, rsT, R, H, rank, cap, max_moves, id_start,
                  id_len, Z):
    """Scene._ordered_rows in one pass: the keys and id places of records key_from..key_end-1
    (record_keys; the other records' are current), split_and_order (sorting afresh, by (ttc,
    pair key), when the kept order needed more than the budget of moves), then reported_rows.

    Returns (fut, ttc, past, rows, evaluated, ids): the new kept order and past records,
    reported_rows' rows and count, and the rows' id positions in the UTF-8 blob
    ``(start_a, len_a, start_b, len_b)`` (SceneContacts.id_utf8).
    """
    record_keys(key_from, key_end, ra, rb, rank, cap, id_start, id_len, rkey, rids)
    fut, ttc, key, past, ordered = split_and_order(
        prev, new, prev_past, live, rkey, rtp, rtau, R, max_moves
    )
    if not ordered:
        # keys are unique and ttc is never NaN (records are hits): the order of np.lexsort((key,
        # ttc))
        for x in range(fut.shape[0]):
            key[x] = rkey[fut[x]]
        o = _time_then_key(ttc, key)
        fut = fut[o]
        ttc = ttc[o]
        key = key[o]
    rows, ids, evaluated = reported_rows(fut, ttc, key, past, ra, rb, rkey, rids, rtp, rtau, rov,
                                         rpt, rnm, rcs, rsP, rsV, rsA, rsR, rsT, R, H, Z)
    return fut, ttc, past, rows, evaluated, ids
