"""The uncertain path of the scene and the published rows, without ROS.

Guarantees proved here:
- the exact path is untouched: with covariance on some bodies, the scene's contacts
  (times, details, order) equal those of the same scene without covariance, bit for bit;
- an all-zero covariance is an exact state (the published bytes equal those without it);
- states and covariances are propagated to the reference time R before the core sees them:
  a body stamped earlier gives exactly the core's answer on its state moved by
  p + dt (v + dt/2 a), v + dt a and its covariance moved by M C M^T (computed here with
  exact rationals), M = [[I, dt I], [0, I]];
- the inflated broad phase loses nothing: every pair whose probability (the core on every
  pair, brute force) is above 1e-9 is evaluated by the scene;
- any covariance content (NaN, inf, huge, wrong length, asymmetric, indefinite) is used or
  rejected with a reason naming the covariance; nothing raises, nothing published is NaN;
- markers: probable pairs in the band of their plausible time, alpha scaled by probability;
- the reporting rule: contacts always; other uncertain pairs iff probability >=
  probability_threshold (a run-time change applies), as NO_CONTACT rows after the contacts
  ordered by plausible time; exact rows carry 1.0 / 0.0 / time_to_collision.
"""
from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from circle_collision_ros.core.scene import Scene
from circle_collision_ros.core.uncertainty import uncertain_pairs
from circle_collision_ros.pipeline.predictor import CollisionPredictor, PredictorConfig
from circle_collision_ros.pipeline.state_batch import StateBatch

BASE = 1_700_000_000 * 1_000_000_000


def _batch(
    n: int, seed: int, sigma: float, stamp_ns: int = BASE, every: int = 1, spread: float = 8.0
):
    rng = np.random.default_rng(seed)
    p = np.zeros((n, 3))
    v = np.zeros((n, 3))
    a = np.zeros((n, 3))
    p[:, :2] = rng.uniform(-spread, spread, (n, 2))
    v[:, :2] = rng.uniform(-2, 2, (n, 2))
    a[:, :2] = rng.uniform(-0.3, 0.3, (n, 2))
    cov = np.zeros((n, 36))
    block = np.diag([sigma**2] * 3 + [(sigma / 3) ** 2] * 3)
    block[0, 3] = block[3, 0] = 0.5 * sigma * sigma / 3  # position-velocity correlation
    cov[::every] = block.ravel()
    return StateBatch(ids=[f"b{k:02d}" for k in range(n)], frames=["map"] * n,
                      stamp_ns=np.full(n, stamp_ns, dtype=np.int64),
                      radius=rng.uniform(0.3, 0.8, n), position=p, velocity=v, acceleration=a,
                      remove=np.zeros(n, dtype=bool), covariance=cov,
                      covariance_size=np.full(n, 36, dtype=np.int64))


def _predict(batch: StateBatch, **config):
    predictor = CollisionPredictor(PredictorConfig(stale_timeout=3600.0, **config))
    predictor.receive_batch(batch, BASE)
    return predictor, predictor.predict()


def _without_covariance(batch: StateBatch) -> StateBatch:
    return StateBatch(**{**batch.__dict__, "covariance": None, "covariance_size": None})


def test_exact_path_untouched_and_zero_covariance_is_exact() -> None:
    batch = _batch(20, seed=1, sigma=0.3, every=2)
    _, with_cov = _predict(batch)
    _, without = _predict(_without_covariance(batch))
    for field in ("id_a", "id_b", "ttc", "contact_ns", "overlapping", "point", "normal",
                  "closing_speed"):
        assert np.array_equal(
            getattr(with_cov.contacts, field), getattr(without.contacts, field)
        ), field
    assert len(with_cov.uncertainty) > 0
    zero = StateBatch(**{**batch.__dict__, "covariance": np.zeros_like(batch.covariance)})
    _, zeroed = _predict(zero)
    assert len(zeroed.uncertainty) == 0
    assert zeroed.to_cdr() == without.to_cdr()
    columns = without.columns
    assert len(columns) > 0
    assert (columns.probability == 1.0).all() and (columns.probability_bound == 0.0).all()
    assert np.array_equal(columns.plausible_ttc, columns.ttc)


def _exact_propagated_covariance(C: np.ndarray, dt_ns: int) -> np.ndarray:
    """M C M^T in exact rationals (dt = dt_ns * 1e-9 as the scene's float), rounded once."""
    D = C.shape[0] // 2
    dt = Fraction(float(np.float64(dt_ns) * 1e-9))
    M = [
        [Fraction(int(i == j)) + (dt if j == i + D else 0) for j in range(2 * D)]
        for i in range(2 * D)
    ]
    c = [[Fraction(float(x)) for x in row] for row in C]
    mc = [
        [sum(M[i][k] * c[k][j] for k in range(2 * D)) for j in range(2 * D)] for i in range(2 * D)
    ]
    return np.array(
        [
            [float(sum(mc[i][k] * M[j][k] for k in range(2 * D))) for j in range(2 * D)]
            for i in range(2 * D)
        ]
    )


def test_states_and_covariances_are_propagated_to_the_reference_time() -> None:
    scene = Scene(5.0, 2)
    C = np.diag([0.09, 0.04, 0.01, 0.0225])
    C[0, 2] = C[2, 0] = 0.012
    old, new = BASE, BASE + 370_000_000
    scene.merge(["a"], [old], [[0.0, 0.0]], [[1.0, 0.1]], [[0.2, 0.0]], [0.5], [False], 0, C[None])
    scene.merge(
        ["b"], [new], [[3.5, 1.6]], [[-0.5, 0.0]], [[0.0, 0.0]], [0.5], [False], 0, C[None] * 0.5
    )
    u = scene.uncertain_pairs(0.01)
    assert u.id_a.tolist() == ["a"] and u.id_b.tolist() == ["b"]
    dt = np.float64(new - old) * 1e-9
    pa = np.array([[0.0, 0.0]]) + dt * (np.array([[1.0, 0.1]]) + 0.5 * dt * np.array([[0.2, 0.0]]))
    va = np.array([[1.0, 0.1]]) + dt * np.array([[0.2, 0.0]])
    moved = _exact_propagated_covariance(C, new - old)
    scene_moved = scene._C[scene._slot["a"]]  # stored at the body's own stamp ...
    assert np.array_equal(scene_moved, C)
    want = uncertain_pairs(pa, va, [[0.2, 0.0]], [0.5], moved[None], [[3.5, 1.6]], [[-0.5, 0.0]],
                           [[0.0, 0.0]], [0.5], (C * 0.5)[None], 5.0, 0.01)
    # ... and moved to R: the block formula equals M C M^T up to the rounding of its few operations
    assert u.probability[0] == pytest.approx(want.collision_probability[0], abs=1e-12)
    assert u.plausible_ttc[0] == pytest.approx(want.plausible_time[0], abs=1e-9)
    assert 0.0 < u.probability[0] < 1.0


def test_inflated_broad_phase_keeps_every_probable_pair() -> None:
    batch = _batch(14, seed=5, sigma=0.35, spread=20.0)
    predictor, prediction = _predict(batch)
    listed = set(zip(prediction.uncertainty.id_a.tolist(), prediction.uncertainty.id_b.tolist()))
    n = len(batch)
    I, J = np.triu_indices(n, 1)
    C = batch.covariance.reshape(-1, 6, 6)[:, [0, 1, 3, 4]][:, :, [0, 1, 3, 4]]
    brute = uncertain_pairs(batch.position[I, :2], batch.velocity[I, :2], batch.acceleration[I, :2],
                            batch.radius[I], C[I], batch.position[J, :2], batch.velocity[J, :2],
                            batch.acceleration[J, :2], batch.radius[J], C[J], 5.0, 0.01)
    probable = {
        (batch.ids[i], batch.ids[j])
        for i, j, p in zip(I, J, brute.collision_probability)
        if p > 1e-9
    }
    assert probable, "the scene must have probable pairs for this test to mean anything"
    assert probable <= listed
    assert len(listed) < len(I)  # and the broad phase did cull


def test_reporting_rule_and_threshold() -> None:
    batch = _batch(16, seed=9, sigma=0.4, spread=7.0)
    predictor, prediction = _predict(batch, probability_threshold=0.01)
    columns = prediction.columns
    contact = columns.status != 0
    n_contacts = len(prediction.contacts)
    assert contact[:n_contacts].all() and not contact[n_contacts:].any()
    extra = slice(n_contacts, None)
    assert (columns.probability[extra] >= 0.01).all() and np.isinf(columns.ttc[extra]).all()
    assert np.all(np.diff(columns.plausible_ttc[extra]) >= 0)
    u = prediction.uncertainty
    contact_pairs = set(zip(prediction.contacts.id_a.tolist(), prediction.contacts.id_b.tolist()))
    want = {
        pair
        for pair, p in zip(zip(u.id_a.tolist(), u.id_b.tolist()), u.probability.tolist())
        if p >= 0.01 and pair not in contact_pairs
    }
    assert set(zip(columns.id_a[n_contacts:], columns.id_b[n_contacts:])) == want
    assert want, "some pair must be reported by probability alone"
    predictor.reconfigure(probability_threshold=1.0)
    strict = predictor.predict().columns
    assert len(strict) == n_contacts  # only mean contacts remain (no miss reaches probability 1)


_entry = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                   st.sampled_from([0.0, 1e-300, 1e30, -1e-12]), st.floats(-1.0, 1.0))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(
        st.one_of(st.lists(_entry, min_size=36, max_size=36), st.lists(_entry, max_size=35),
                  st.builds(lambda s: (np.diag([s] * 6)).ravel().tolist(), st.floats(0.0, 4.0))),
        min_size=3,
        max_size=3,
    ),
    st.sampled_from([2, 3]),
)
def test_any_covariance_content_is_used_or_rejected_with_a_reason(covariances, dimensions) -> None:
    """Random covariance contents through validation, the scene and the encoder: nothing raises,
    each refused state has a reason naming the covariance, nothing published is NaN."""
    batch = _batch(3, seed=2, sigma=0.0, spread=1.5)
    sizes = np.array([len(c) for c in covariances], dtype=np.int64)
    cov = np.zeros((3, 36))
    for k, c in enumerate(covariances):
        if len(c) == 36:
            cov[k] = c
    batch = StateBatch(**{**batch.__dict__, "covariance": cov, "covariance_size": sizes})
    predictor = CollisionPredictor(PredictorConfig(stale_timeout=3600.0, dimensions=dimensions))
    report = predictor.receive_batch(batch, BASE)
    for rejection in report.rejected:
        assert "covariance" in rejection.reason
    prediction = predictor.predict()
    c = prediction.columns
    for name in ("ttc", "closing_speed", "probability", "probability_bound", "plausible_ttc"):
        assert not np.isnan(getattr(c, name)).any(), name
    assert ((c.probability >= 0.0) & (c.probability <= 1.0)).all()
    prediction.to_cdr()


def test_raw_bytes_beyond_the_bound_are_decoded_then_rejected_or_refused() -> None:
    """rclpy cannot send more than 36 values, but raw bytes can claim any count: a count whose
    values are present is decoded and the state rejected with its reason; a count the buffer
    cannot hold is a CdrError (nothing allocated for it)."""
    from circle_collision_msgs.msg import CircleState, CircleStateArray
    from circle_collision_ros.pipeline.cdr import CdrError
    from circle_collision_ros.pipeline.state_codec import decode_states
    from circle_collision_ros.pipeline.state_validation import check_batch
    from tests.reliability.wire import Body, encode_array, encode_state

    good = Body("g", stamp_ns=BASE, covariance=tuple(np.eye(6).ravel() * 0.01))
    long = Body("x", stamp_ns=BASE, covariance=(0.01,) * 40)
    for big_endian in (False, True):
        batch = decode_states(
            encode_array([good, long, Body("h", stamp_ns=BASE)], BASE, big_endian=big_endian),
            CircleStateArray,
        )
        assert batch.covariance_size.tolist() == [36, 40, 0]
        check = check_batch(batch, frame_id="map", now_ns=None, dimensions=2)
        assert check.good.tolist() == [True, False, True] and check.uncertain.tolist() == [True,
                                                                                           False,
                                                                                           False]
        assert (
            check.rejections[0].reason
            == "covariance has 40 values (expected 0 or 36: 6x6 row-major)"
        )
    data = bytearray(encode_state(Body("x", stamp_ns=BASE)))
    data[-4:] = (2**32 - 1).to_bytes(4, "little")  # the covariance count
    with pytest.raises(CdrError):
        decode_states(bytes(data), CircleState)


def test_markers_show_probability_as_opacity() -> None:
    """Bodies of a probable pair (mean paths miss) take the band of the plausible time with
    alpha scaled by the probability; exact contacts look as before (full band alpha)."""
    from rclpy.serialization import deserialize_message
    from visualization_msgs.msg import MarkerArray

    from circle_collision_ros.node.markers import MarkerBuilder, Urgency

    n = 4
    cov = np.zeros((n, 36))
    cov[2] = cov[3] = np.diag([0.09] * 3 + [0.0] * 3).ravel()
    batch = StateBatch(ids=["a", "b", "c", "d"], frames=["map"] * n,
                       stamp_ns=np.full(n, BASE, dtype=np.int64), radius=np.full(n, 0.5),
                       position=np.array([[0, 0, 0], [3, 0, 0], [0, 20, 0], [2, 21.1, 0.0]]),
                       velocity=np.array([[1.0, 0, 0], [0, 0, 0], [1.0, 0, 0], [0, 0, 0]]),
                       acceleration=np.zeros((n, 3)), remove=np.zeros(n, dtype=bool),
                       covariance=cov, covariance_size=np.full(n, 36, dtype=np.int64))
    _, prediction = _predict(batch)
    rows = {(r.id_a, r.id_b): r for r in prediction.rows()}
    assert rows[("a", "b")].collision_probability == 1.0 and rows[("c", "d")].status == 0
    p = rows[("c", "d")].collision_probability
    assert 0.0 < p < 1.0
    markers = deserialize_message(MarkerBuilder(2).build(prediction), MarkerArray).markers
    bodies = {m.id: m.color for m in markers if m.ns == "bodies"}
    colours = list(bodies.values())  # ids follow the id order a, b, c, d
    assert colours[0].a == pytest.approx(Urgency.WARNING[3]) and colours[1].a == pytest.approx(
        Urgency.WARNING[3]
    )
    band = Urgency.colours(np.array([rows[("c", "d")].plausible_time_to_collision]))[0]
    for c in colours[2:]:
        assert (c.r, c.g, c.b) == pytest.approx(tuple(band[:3]))
        assert c.a == pytest.approx(band[3] * Urgency.opacity(np.array([p]))[0], rel=1e-6)
        assert c.a < band[3]


def test_uncertain_pair_budget_defers_and_counts() -> None:
    """uncertain_pair_budget = m: at most m uncertain pairs fully evaluated per prediction; the
    deferred rest carry the cheap certified interval of this frame's states (containing the
    full answer; none reads 1.0 +- 1.0), are published when the interval reaches the threshold,
    are counted in the stats, and the same input gives the same bytes (a count, not a clock)."""
    batch = _batch(16, seed=9, sigma=0.4, spread=7.0)
    _, full = _predict(batch)
    predictor, part = _predict(batch, uncertain_pair_budget=2)
    u, f = part.uncertainty, full.uncertainty
    deferred = u.deferred_rows
    assert u.deferred == predictor.stats.uncertain_deferred == np.count_nonzero(deferred) > 0
    p, b = u.probability[deferred], u.probability_bound[deferred]
    assert np.all(np.abs(p - f.probability[deferred]) <= b + f.probability_bound[deferred])
    assert not np.any((p == 1.0) & (b == 1.0))
    assert np.array_equal(u.probability[~deferred], f.probability[~deferred])
    listed = set(zip(part.columns.id_a, part.columns.id_b))
    reach = deferred & (u.probability + u.probability_bound >= part.probability_threshold)
    assert {(a, b) for a, b in zip(u.id_a[reach].tolist(), u.id_b[reach].tolist())} <= listed
    _, again = _predict(batch, uncertain_pair_budget=2)
    assert again.to_cdr() == part.to_cdr()
    assert full.uncertainty.deferred == 0


def _counting_core(monkeypatch) -> list:
    """Rows each call of core.uncertainty.uncertain_pairs was given (the scene calls it through
    the module), as (id of pa row set,) -> number of rows."""
    from circle_collision_ros.core import uncertainty

    calls = []
    real = uncertainty.uncertain_pairs

    def counted(pa, *args, **kwargs):
        calls.append(len(pa))
        return real(pa, *args, **kwargs)

    monkeypatch.setattr(uncertainty, "uncertain_pairs", counted)
    return calls


def _merge_batch(scene: Scene, batch: StateBatch, rows=None) -> None:
    from circle_collision_ros.pipeline.state_batch import covariance_block

    rows = np.arange(len(batch)) if rows is None else np.asarray(rows)
    scene.merge([batch.ids[k] for k in rows.tolist()], batch.stamp_ns[rows], batch.position[rows],
                batch.velocity[rows], batch.acceleration[rows], batch.radius[rows],
                batch.remove[rows], 0, covariance_block(batch.covariance[rows], scene.dim))


def _same(u, w) -> None:
    assert u.reference_ns == w.reference_ns
    assert u.id_a.tolist() == w.id_a.tolist() and u.id_b.tolist() == w.id_b.tolist()
    for name in ("probability", "probability_bound", "plausible_ttc"):
        assert getattr(u, name).tobytes() == getattr(w, name).tobytes(), name


@pytest.mark.parametrize("budget", [None, 3])
def test_one_body_update_evaluates_only_that_bodys_pairs(monkeypatch, budget) -> None:
    """A per-body stream: a newer state of one body (R moves with it) gives the core only the
    listed pairs of that body; every other pair keeps its answer, and the result equals a
    from-scratch evaluation of the same stored states bit for bit (Scene.uncertain_pairs: a
    pair's answer is a function of its two states and its pair time t_p = the newer stamp).
    Before: every listed pair was evaluated again at the new R on every input."""
    batch = _batch(24, seed=11, sigma=0.35, spread=9.0)
    scene = Scene(5.0, 2, method="grid")
    _merge_batch(scene, batch)
    first = scene.uncertain_pairs(0.01, scene.predictions(), budget)
    assert len(first) > 10 and first.deferred == 0 or budget is not None
    calls = _counting_core(monkeypatch)
    mover = "b05"
    k = batch.ids.index(mover)
    later = StateBatch(
        **{**batch.__dict__, "stamp_ns": batch.stamp_ns + 20_000_000,
           "position": batch.position + 0.01}
    )
    for step in range(1, 4):  # again and again: a deferred pair of the first call gets its turn
        stamped = StateBatch(**{**later.__dict__, "stamp_ns": later.stamp_ns + step})
        _merge_batch(scene, stamped, [k])
        u = scene.uncertain_pairs(0.01, scene.predictions(), budget)
    theirs = int(np.count_nonzero((u.id_a == mover) | (u.id_b == mover)))
    assert 0 < theirs < len(u)
    if budget is None:
        assert calls == [theirs] * 3
    else:  # the body's pairs, and the pairs deferred before (never more than the listed)
        assert all(c < len(u) for c in calls)
    assert scene.uncertain_evaluated == calls[-1]
    # the same stored states from scratch (no budget: nothing deferred, all evaluated)
    if budget is None:
        fresh = Scene(5.0, 2, method="grid")
        _merge_batch(fresh, batch)
        _merge_batch(fresh, StateBatch(**{**later.__dict__, "stamp_ns": later.stamp_ns + 3}), [k])
        _same(u, fresh.uncertain_pairs(0.01, fresh.predictions()))


def test_pair_time_is_the_newer_stamp_or_the_lag_period_start(monkeypatch) -> None:
    """t_p (Scene.uncertain_pairs): the newer stamp of the pair while it lies within
    UNCERTAIN_LAG_NS of R, else R - R mod UNCERTAIN_LAG_NS; the answer is the core's on both
    states and covariances propagated to t_p, the plausible time reported from R; a lagging
    pair is evaluated again when R's lag period changes, not on every input."""
    lag = Scene.UNCERTAIN_LAG_NS
    C = np.diag([0.09, 0.04, 0.01, 0.0225])
    scene = Scene(5.0, 2)
    t0 = BASE + 7 * lag + 1234
    scene.merge(["a", "b"], [t0, t0 + 5_000_000], [[0.0, 0.0], [4.0, 0.3]],
                [[1.0, 0.0], [-0.5, 0.0]], [[0.0, 0.0], [0.0, 0.0]], [0.5, 0.5], [False, False], 0,
                np.stack([C, C]))
    far = np.array([[500.0, 0.0]])

    def core_at(tp):
        dt_a, dt_b = (tp - t0) * 1e-9, (tp - t0 - 5_000_000) * 1e-9
        pa, pb = np.array([[dt_a, 0.0]]), np.array([[4.0 - 0.5 * dt_b, 0.3]])
        return uncertain_pairs(pa, [[1.0, 0.0]], [[0.0, 0.0]], [0.5], _moved(C, dt_a)[None], pb,
                               [[-0.5, 0.0]], [[0.0, 0.0]], [0.5], _moved(C, dt_b)[None], 5.0, 0.01)

    def check(R, tp):
        u = scene.uncertain_pairs(0.01)
        assert u.id_a.tolist() == ["a"] and u.id_b.tolist() == ["b"] and u.reference_ns == R
        want = core_at(tp)
        assert u.probability[0] == pytest.approx(want.collision_probability[0], abs=1e-12)
        d = (R - tp) * 1e-9
        assert u.plausible_ttc[0] == pytest.approx(max(0.0, want.plausible_time[0] - d), abs=1e-9)
        return u

    calls = _counting_core(monkeypatch)
    # an exact far body moves R: the pair's newer stamp is t0 + 5 ms, within the lag
    R = t0 + 40_000_000
    scene.merge(["z"], [R], far, [[0.0, 0.0]], [[0.0, 0.0]], [0.1], [False], 0)
    check(R, t0 + 5_000_000)
    assert calls == [1]
    R += 30_000_000  # still within the lag: nothing to evaluate
    scene.merge(["z"], [R], far, [[0.0, 0.0]], [[0.0, 0.0]], [0.1], [False], 0)
    check(R, t0 + 5_000_000)
    assert calls == [1] and scene.uncertain_evaluated == 0
    R = t0 + 5_000_000 + lag + 1  # the pair lags: evaluated at the start of R's lag period
    scene.merge(["z"], [R], far, [[0.0, 0.0]], [[0.0, 0.0]], [0.1], [False], 0)
    u = check(R, R - R % lag)
    assert calls == [1, 1]
    R += 1_000  # same lag period: kept
    scene.merge(["z"], [R], far, [[0.0, 0.0]], [[0.0, 0.0]], [0.1], [False], 0)
    assert scene.uncertain_pairs(0.01).probability.tobytes() == u.probability.tobytes()
    assert calls == [1, 1]
    R += lag  # the next period: evaluated again
    scene.merge(["z"], [R], far, [[0.0, 0.0]], [[0.0, 0.0]], [0.1], [False], 0)
    check(R, R - R % lag)
    assert calls == [1, 1, 1]


def _moved(C: np.ndarray, dt: float) -> np.ndarray:
    """M C M^T with M = [[I, dt I], [0, I]] (2-D)."""
    M = np.eye(4)
    M[0, 2] = M[1, 3] = dt
    return M @ C @ M.T


@pytest.mark.parametrize("m", [4, 6])
def test_vectorised_covariance_check_decides_as_the_core(m) -> None:
    """state_validation.covariance_rejected (a compiled screen; eigenvalues only for blocks
    whose diagonal does not dominate) refuses exactly the blocks core.uncertainty.
    covariance_problem refuses: PSD, diagonal, indefinite, negated, slightly asymmetric,
    non-finite, zero, and rounding-negative blocks over 20 orders of magnitude."""
    from circle_collision_ros.core.uncertainty import covariance_problem
    from circle_collision_ros.pipeline.state_validation import covariance_rejected

    rng = np.random.default_rng(m)
    n = 1400
    A = rng.normal(size=(n, m, m))
    S = A @ A.transpose(0, 2, 1) * 10.0 ** rng.integers(-10, 10, (n, 1, 1))
    S[::7] = np.diag(rng.uniform(0, 1, m))
    S[1::7] *= -1
    S[2::7] += rng.normal(size=(m, m)) * 1e-3
    S[3::7, 0, 1] = np.nan
    S[4::7] = 0.0
    S[5::7] += np.eye(m) * rng.uniform(-1e-9, 1e-9)
    anti = np.diag(rng.uniform(0, 1, m)) + 0.6 * np.eye(m)[::-1]  # dominance fails on some rows
    S[6::7] = 0.5 * (anti + anti.T)
    want = np.array([covariance_problem(c) is not None for c in S])
    assert 0 < want.sum() < n
    assert covariance_rejected(S).tolist() == want.tolist()


@pytest.mark.parametrize("dimensions", [2, 3])
def test_batch_covariance_checks_decide_row_by_row_as_the_core(dimensions) -> None:
    """state_validation.covariance_checks (one compiled pass over the raw 36 values) gives, row
    by row, the decision spelled out from the rules: a count other than 0 or 36 is bad; a
    36-value covariance all zero on the used axes is exact; else a used block with a value of
    magnitude > MAX_COVARIANCE or refused by core.uncertainty.covariance_problem is bad; a
    removal is never bad nor uncertain; and it returns the used block itself."""
    from circle_collision_ros.core.uncertainty import covariance_problem
    from circle_collision_ros.pipeline.state_batch import covariance_block
    from circle_collision_ros.pipeline.state_validation import ValueLimits, covariance_checks

    rng = np.random.default_rng(dimensions)
    n = 3000
    A = rng.normal(size=(n, 6, 6))
    cov = (A @ A.transpose(0, 2, 1) * 10.0 ** rng.integers(-8, 8, (n, 1, 1))).reshape(n, 36)
    cov[1::11] *= -1.0  # negative definite
    cov[2::11, 1] += 1e-3  # asymmetric on the used axes
    cov[3::11, 7 * 2] = np.nan if dimensions == 3 else cov[3::11, 7 * 2]  # z: used in 3-D only
    cov[4::11, 1] = np.inf
    cov[5::11] = 0.0
    cov[6::11, 0] = 2.0 * ValueLimits.MAX_COVARIANCE  # huge
    cov[7::11] = np.diag([0.04, 0.04, 0.0, 0.01, 0.01, 0.0]).ravel()
    cov[8::11, 0] = np.nan
    cov[9::11] = np.where(np.eye(6).ravel() > 0, 0.0, cov[9::11])  # off-diagonal only: indefinite
    size = np.full(n, 36, dtype=np.int64)
    size[10::23] = 0
    size[11::29] = 35
    cov[size != 36] = np.where(size[size != 36, None] == 0, 0.0, cov[size != 36])
    remove = np.zeros(n, dtype=bool)
    remove[::13] = True
    batch = StateBatch(ids=[f"b{k}" for k in range(n)], frames=["map"] * n,
                       stamp_ns=np.full(n, BASE), radius=np.ones(n), position=np.zeros((n, 3)),
                       velocity=np.zeros((n, 3)), acceleration=np.zeros((n, 3)), remove=remove,
                       covariance=cov, covariance_size=size)
    bad, uncertain, block = covariance_checks(batch, dimensions)
    want_block = covariance_block(cov, dimensions)
    assert np.array_equal(block, want_block, equal_nan=True)
    want_bad, want_uncertain = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    for k in range(n):
        if remove[k]:
            continue
        if size[k] not in (0, 36):
            want_bad[k] = True
            continue
        b = want_block[k]
        if size[k] == 0 or not (b != 0.0).any():
            continue
        refused = (
            np.isfinite(b).all() and np.abs(b).max() > ValueLimits.MAX_COVARIANCE
        ) or covariance_problem(b) is not None
        want_bad[k], want_uncertain[k] = refused, not refused
    assert bad.tolist() == want_bad.tolist()
    assert uncertain.tolist() == want_uncertain.tolist()
    assert (
        0 < want_bad.sum() and 0 < want_uncertain.sum() and (~want_bad & ~want_uncertain).sum() > 0
    )


def test_state_and_covariance_propagation_is_the_numpy_expression_bitwise() -> None:
    """uncertain.states_at_rows (one compiled pass over the stored bodies) gives the bits of the
    numpy expressions: p + dt (v + (dt/2) a), v + dt a (store.propagate_ns) and the covariance
    blocks Spp + dt (Spv + Svp) + dt^2 Svv, Spv + dt Svv, Svp + dt Svv, Svv, zero for exact
    bodies, signed zeros included (recorded covariance bags replay bit for bit)."""
    from circle_collision_ros.core.scene.store import propagate_ns
    from circle_collision_ros.core.scene.uncertain import states_at_rows

    rng = np.random.default_rng(3)
    n = 500
    for D in (2, 3):
        P, V, A = (rng.normal(size=(n, D)) * 10.0 ** rng.integers(-3, 4, (n, 1)) for _ in range(3))
        A[rng.random(A.shape) < 0.3] = -0.0
        C = rng.normal(size=(n, 2 * D, 2 * D)) * 10.0 ** rng.integers(-8, 8, (n, 1, 1))
        C[rng.random(C.shape) < 0.2] = -0.0
        C[rng.random(C.shape) < 0.2] = 0.0
        T = BASE + rng.integers(0, 3_000_000_000, n)
        U = rng.random(n) < 0.8
        slots = rng.permutation(n)[:300]
        t_ns = T[slots] + rng.integers(0, 3_000_000_000, slots.size)
        t_ns[::3] = T[slots[::3]]
        dt_ns = t_ns - T[slots]
        dt = (dt_ns.astype(np.float64) * 1e-9)[:, None, None]
        c = C[slots]
        pp, pv, vp, vv = c[:, :D, :D], c[:, :D, D:], c[:, D:, :D], c[:, D:, D:]
        want = np.empty_like(c)
        want[:, :D, :D] = pp + dt * (pv + vp) + (dt * dt) * vv
        want[:, :D, D:] = pv + dt * vv
        want[:, D:, :D] = vp + dt * vv
        want[:, D:, D:] = vv
        want[~U[slots]] = 0.0
        want_p, want_v = propagate_ns(P[slots], V[slots], A[slots], dt_ns)
        p, v, cov = np.empty((slots.size, D)), np.empty((slots.size, D)), np.empty_like(c)
        states_at_rows(P, V, A, C, T, U, slots, t_ns, p, v, cov)
        assert p.tobytes() == want_p.tobytes() and v.tobytes() == want_v.tobytes()
        assert cov.tobytes() == want.tobytes()


def test_published_rows_from_the_scenes_pair_match_equal_the_id_match() -> None:
    """ScenePrediction.columns joins the uncertain rows to the contacts through the scene's
    contact_rows (the same pair, matched on slot keys); the rows equal those of the join on
    ids, and contact_rows names exactly the pairs whose ids agree."""
    from dataclasses import replace
    from circle_collision_ros.pipeline.prediction_messages import ScenePrediction

    batch = _batch(40, seed=21, sigma=0.3, spread=9.0, every=2)  # exact and uncertain bodies
    predictor, prediction = _predict(batch)
    u, c = prediction.uncertainty, prediction.contacts
    assert u.matched is c and len(c) > 5 and len(u) > 20
    rows = u.contact_rows
    paired = np.flatnonzero(rows >= 0)
    assert paired.size > 3
    assert u.id_a[paired].tolist() == c.id_a[rows[paired]].tolist()
    assert u.id_b[paired].tolist() == c.id_b[rows[paired]].tolist()
    contact_pairs = set(zip(c.id_a.tolist(), c.id_b.tolist()))
    unpaired = np.flatnonzero(rows < 0)
    assert not contact_pairs & set(zip(u.id_a[unpaired].tolist(), u.id_b[unpaired].tolist()))
    by_ids = ScenePrediction(c, prediction.capture, prediction.horizon, prediction.frame_id, False,
                             replace(u, contact_rows=None, matched=None),
                             prediction.probability_threshold)
    fast, slow = prediction.columns, by_ids.columns
    assert fast.id_a == slow.id_a and fast.id_b == slow.id_b
    for name in ("status", "ttc", "contact_ns", "point", "normal", "closing_speed", "probability",
                 "probability_bound", "plausible_ttc"):
        assert getattr(fast, name).tobytes() == getattr(slow, name).tobytes(), name
    assert prediction.to_cdr() == by_ids.to_cdr()


def test_inflated_listing_kept_up_to_date_equals_a_rebuild() -> None:
    """Scene._inflated_pairs brought up to date body by body (updates, covariance dropped and
    given again, removals, new bodies, a new lag period) lists exactly the pairs a rebuild
    from the same stored states lists; a one-body update looks up only that body."""
    from circle_collision_ros.core import uncertainty as unc

    rng = np.random.default_rng(17)
    batch = _batch(60, seed=17, sigma=0.4, spread=12.0, every=2)
    scene = Scene(5.0, 2, method="grid")
    _merge_batch(scene, batch)
    scene.uncertain_pairs(0.01, scene.predictions(), 4)
    rebuilds = 0
    for step in range(1, 40):
        k = int(rng.integers(len(batch)))
        stamp = batch.stamp_ns + step * 9_000_000  # crosses lag periods (0.1 s) now and then
        moved = StateBatch(**{**batch.__dict__, "stamp_ns": stamp,
                              "position": batch.position + rng.normal(0, 0.3, batch.position.shape),
                              "remove": np.full(len(batch), step % 11 == 0)})
        if step % 5 == 0:  # the body loses (or regains) its covariance
            moved.covariance[k] = 0.0 if moved.covariance[k].any() else batch.covariance[0]
        _merge_batch(scene, moved, [k])
        if step % 7 == 0:  # a body comes back after a removal: a new body in a reused slot
            _merge_batch(scene, moved, [(k + 1) % len(batch)])
        before = scene._listing
        slots = scene._sorted_slots()
        kept = scene._inflated_pairs(slots, scene.reference_ns, unc)
        rebuilds += scene._listing.R0 != getattr(before, "R0", None)
        scene._listing = None
        fresh = scene._inflated_pairs(slots, scene.reference_ns, unc)
        assert np.array_equal(kept[0], fresh[0]) and np.array_equal(kept[1], fresh[1]), step
        assert kept[0].size > 0
    assert rebuilds >= 2


def test_one_body_update_does_not_rebuild_the_inflated_broad_phase(monkeypatch) -> None:
    """Within a lag period, a one-body update of a 2,000-body covariance scene computes one
    box and never runs the sweep over every body (it did on every call before)."""
    from circle_collision_ros.core import broad

    batch = _batch(2000, seed=23, sigma=0.3, spread=400.0)
    scene = Scene(5.0, 2, method="grid")
    _merge_batch(scene, batch)
    scene.uncertain_pairs(0.01, scene.predictions(), 4)
    sweeps, boxes = [], []
    real_sweep, real_boxes = broad.candidate_pairs, broad.swept_bounds
    monkeypatch.setattr(broad, "candidate_pairs",
                        lambda *a, **k: sweeps.append(len(a[0])) or real_sweep(*a, **k))
    monkeypatch.setattr(broad, "swept_bounds",
                        lambda p, *a, **k: boxes.append(len(p)) or real_boxes(p, *a, **k))
    for step in range(1, 6):
        moved = StateBatch(**{**batch.__dict__, "stamp_ns": batch.stamp_ns + step * 1_000_000,
                              "position": batch.position + 0.01 * step})
        _merge_batch(scene, moved, [step])
        scene.uncertain_pairs(0.01, scene.predictions(), 4)
    assert boxes == [1] * 5
    assert all(n < 100 for n in sweeps), sweeps  # the exact path's own few, never 2,000
