"""A stream's decoder (state_codec.StateDecoder) and the per-id work it lets later steps skip.

Guarantees proved here:
- a StateDecoder fed any sequence of messages (ids repeating, changing in one byte,
  reordered, with covariance or not, frames given or empty, malformed messages between)
  returns for each exactly the batch ``decode_states`` returns, bit for bit, and refuses
  exactly what it refuses;
- a message that differs from the previous decoded one only in values (stamps, numbers,
  remove flags, covariance values) shares its id and frame tuples, the same objects (what
  validation and the scene's merge key on), and any other message does not;
- validation of a shared tuple gives the same verdicts as a fresh check: duplicate and empty
  ids are rejected on every frame, and a frame other than the scene's is found after the
  scene frame changes;
- a scene fed the same tuple after a body came or went looks the ids up again.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from circle_collision_msgs.msg import CircleState, CircleStateArray
from circle_collision_ros.core.scene import Scene
from circle_collision_ros.pipeline.cdr import CdrError
from circle_collision_ros.pipeline.state_codec import StateDecoder, decode_states
from circle_collision_ros.pipeline.state_validation import check_batch
from tests.reliability.wire import Body, encode_array, encode_state
from tests.stress import examples

T0 = 1_700_000_000 * 10**9
_IDS = ["a", "b", "c", "b0", "b1", "β", ""]  # "b0"/"b1": one byte apart; "": empty


def _equal(got, want) -> None:
    assert got.ids == want.ids and got.frames == want.frames
    for name in ("stamp_ns", "radius", "position", "velocity", "acceleration", "remove",
                 "covariance", "covariance_size"):
        x, y = getattr(got, name), getattr(want, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.dtype == y.dtype and x.shape == y.shape, name
            assert np.array_equal(x.view(np.uint8), y.view(np.uint8)), name  # bit for bit


@st.composite
def _streams(draw):
    """A sequence of (CircleStateArray bytes, layout key): ids from a small alphabet (repeats
    are common), often a frame that changes values only; some messages truncated (key None).
    Two messages with one key differ only in values (stamps, numbers, remove flags)."""
    base = draw(st.lists(st.sampled_from(_IDS), min_size=0, max_size=6))
    covs = [()] * len(base)
    frame, big = "map", False
    out = []
    for k in range(draw(st.integers(1, 8))):
        change = draw(st.sampled_from(["values", "values", "values", "new", "swap", "one",
                                       "frame", "covariance", "order"]))
        if change == "new":
            base = draw(st.lists(st.sampled_from(_IDS), min_size=0, max_size=6))
            covs = [()] * len(base)
        elif change == "swap" and len(base) > 1:
            base, covs = base[1:] + base[:1], covs[1:] + covs[:1]
        elif change == "one" and base:
            base = [draw(st.sampled_from(_IDS))] + base[1:]
        elif change == "frame":
            frame = draw(st.sampled_from(["map", "", "odom"]))
        elif change == "covariance" and base:
            covs = [draw(st.sampled_from([(), (0.1,) * 36, (0.0,) * 3])) for _ in base]
        elif change == "order":
            big = not big
        bodies = [Body(i, radius=draw(st.sampled_from([0.5, 1.0, float("nan")])),
                       p=(float(k), draw(st.floats(-10, 10)), 0.0),
                       stamp_ns=T0 + k + draw(st.integers(0, 3)),
                       frame=frame if j % 2 else "map", remove=draw(st.booleans()),
                       covariance=tuple(x + k for x in c))
                  for j, (i, c) in enumerate(zip(base, covs))]
        data = encode_array(bodies, T0 + k, "arr", big_endian=big)
        key = (tuple(base), tuple(b.frame for b in bodies), tuple(map(len, covs)), big)
        if draw(st.integers(0, 5)) == 0:
            data, key = data[: draw(st.integers(0, max(0, len(data) - 1)))], None
        out.append((data, key))
    return out


@settings(max_examples=examples(150, 600), deadline=None)
@given(_streams())
def test_a_stream_decodes_as_each_message_alone(stream: list) -> None:
    decoder = StateDecoder(CircleStateArray)
    previous = None  # (batch, key) of the last message decoded
    for data, key in stream:
        try:
            want = decode_states(data, CircleStateArray)
        except CdrError as exc:
            with pytest.raises(CdrError, match=str(exc).split("(")[0][:30]):
                decoder(data)
            continue
        got = decoder(data)
        _equal(got, want)
        assert type(got.ids) is tuple and type(got.frames) is tuple
        if previous is not None and len(got) and got.ids is previous[0].ids:
            # shared only where only values changed (the same layout)
            assert key is not None and key == previous[1]
            assert got.frames is previous[0].frames
        previous = (got, key)


def _encoded(bodies: list, single: bool, big: bool, uncertainty: bool) -> bytes:
    """bodies as a CircleStateArray (or the first as a CircleState), in either byte order and
    either layout (uncertainty False: without the covariance sequence, as old recordings)."""
    if single:
        return encode_state(bodies[0], big_endian=big, with_covariance=uncertainty)
    return encode_array(bodies, T0, "arr", big_endian=big, with_covariance=uncertainty)


@pytest.mark.parametrize("single", [False, True], ids=["array", "single"])
@pytest.mark.parametrize("big", [False, True], ids=["le", "be"])
@pytest.mark.parametrize("uncertainty", [True, False], ids=["cov", "old"])
def test_a_byte_changed_anywhere_decodes_as_alone(single: bool, big: bool,
                                                  uncertainty: bool) -> None:
    """A message parsed, then one of the same layout read at it (values moved), then copies
    of that one with one byte changed at every position in turn (values, string bytes,
    lengths, padding, the encapsulation): the decoder decodes each copy exactly as
    decode_states, or refuses it as decode_states does; in both byte orders, both layouts,
    arrays and single states."""
    cov = (0.5,) * 36 if uncertainty else ()
    bodies = [Body("a1", stamp_ns=T0, covariance=cov), Body("b", stamp_ns=T0 + 1),
              Body("c", stamp_ns=T0 + 2, frame="")]
    moved = [Body(b.id, radius=2.0, p=(1.0, 2.0, 3.0), stamp_ns=b.stamp_ns + 5, frame=b.frame,
                  remove=True, covariance=tuple(x + 1 for x in b.covariance)) for b in bodies]
    msg_type = CircleState if single else CircleStateArray
    first = _encoded(bodies, single, big, uncertainty)
    data = _encoded(moved, single, big, uncertainty)
    for pos in range(len(data)):
        for flip in (0x01, 0x80):
            changed = bytearray(data)
            changed[pos] ^= flip
            changed = bytes(changed)
            decoder = StateDecoder(msg_type, uncertainty=uncertainty)
            decoder(first)
            hit = decoder(data)  # the same layout: read at the kept one
            _equal(hit, decode_states(data, msg_type, uncertainty=uncertainty))
            assert hit.ids is decoder(first).ids
            try:
                want = decode_states(changed, msg_type, uncertainty=uncertainty)
            except CdrError:
                with pytest.raises(CdrError):
                    decoder(changed)
                continue
            _equal(decoder(changed), want)


def test_a_reused_buffer_is_parsed_and_batches_are_independent() -> None:
    """A caller that reads each message into the same bytearray gets each message's batch
    (only immutable bytes are kept), and changing a returned batch's arrays changes no
    later batch."""
    a = encode_array([Body("aa", stamp_ns=T0), Body("bb", stamp_ns=T0)], T0)
    b = encode_array([Body("xx", stamp_ns=T0 + 1), Body("yy", stamp_ns=T0 + 1)], T0)
    buf = bytearray(a)
    decoder = StateDecoder(CircleStateArray)
    assert decoder(buf).ids == ("aa", "bb")
    buf[:] = b
    assert decoder(buf).ids == ("xx", "yy")
    cov = [Body("c", stamp_ns=T0 + k, covariance=(0.25,) * 36) for k in range(2)]
    decoder = StateDecoder(CircleStateArray)
    first = decoder(encode_array(cov, T0))
    for x in (first.radius, first.position, first.stamp_ns, first.covariance,
              first.covariance_size):
        x[...] = 0
    data = encode_array([Body("c", stamp_ns=T0 + 9, covariance=(0.25,) * 36),
                         Body("c", stamp_ns=T0 + 9, covariance=(0.25,) * 36)], T0)
    _equal(decoder(data), decode_states(data, CircleStateArray))


def test_a_stream_of_changing_layouts_rests_and_comes_back() -> None:
    """Two publishers taking turns on one topic (two layouts): every message decodes as
    alone; the decoder stops comparing for a while, and a steady stream afterwards shares
    its tuples again."""
    one = [encode_array([Body("a", stamp_ns=T0 + k)], T0 + k) for k in range(40)]
    two = [encode_array([Body("bb", stamp_ns=T0 + k), Body("c", stamp_ns=T0 + k)], T0 + k)
           for k in range(40)]
    decoder = StateDecoder(CircleStateArray)
    for k in range(20):
        for data in (one[k], two[k]):
            _equal(decoder(data), decode_states(data, CircleStateArray))
    batches = [decoder(data) for data in two[20:]]
    assert all(b.ids is batches[-1].ids for b in batches[-5:])


def test_single_states_and_unchanged_ids() -> None:
    decoder = StateDecoder(CircleState)
    for k in range(3):
        one = encode_state(Body("robot", stamp_ns=T0 + k, p=(float(k), 0.0, 0.0)))
        _equal(decoder(one), decode_states(one, CircleState))
    arrays = StateDecoder(CircleStateArray)
    first = arrays(encode_array([Body("a", stamp_ns=T0), Body("b", stamp_ns=T0)], T0))
    second = arrays(encode_array([Body("a", stamp_ns=T0 + 1), Body("b", stamp_ns=T0 + 1)], T0))
    third = arrays(encode_array([Body("a", stamp_ns=T0 + 2), Body("c", stamp_ns=T0 + 2)], T0))
    assert second.ids is first.ids and second.frames is first.frames
    assert third.ids == ("a", "c") and third.frames == first.frames  # a new layout: parsed
    with pytest.raises(TypeError):
        StateDecoder(Body)


def test_validation_of_a_shared_tuple_rejects_every_frame() -> None:
    """Duplicate and empty ids are found on each message that repeats them, and a state in
    another frame is found after the scene frame changes, though the tuples are shared; and
    so with several streams taking turns (a node with several array topics)."""
    decoder = StateDecoder(CircleStateArray)
    others = [StateDecoder(CircleStateArray) for _ in range(10)]  # more streams than entries
    for k in range(3):
        batch = decoder(encode_array([Body("a", stamp_ns=T0 + k), Body("a", stamp_ns=T0 + k),
                                      Body("", stamp_ns=T0 + k), Body("b", stamp_ns=T0 + k)],
                                     T0 + k))
        check = check_batch(batch, frame_id="map", now_ns=T0 + k, dimensions=2)
        assert check.good.tolist() == [False, False, False, True]
        assert "more than once" in check.rejections[0].reason
        assert "empty id" in check.rejections[2].reason
        for j, other in enumerate(others):
            clean = other(encode_array([Body(f"s{j}", stamp_ns=T0 + k),
                                        Body(f"t{j}", stamp_ns=T0 + k, frame="odom")], T0 + k))
            assert check_batch(clean, frame_id="map", now_ns=T0 + k,
                               dimensions=2).good.tolist() == [True, False]
            assert check_batch(clean, frame_id="odom", now_ns=T0 + k,
                               dimensions=2).good.tolist() == [False, True]
    assert check_batch(batch, frame_id="odom", now_ns=T0, dimensions=2).good.tolist() == \
        [False] * 4
    assert check_batch(batch, frame_id="map", now_ns=T0, dimensions=2).good.tolist() == \
        [False, False, False, True]


def test_scene_looks_ids_up_again_after_a_body_came_or_went() -> None:
    """The same tuple, merged again after another body was added and one removed, lands in
    the right slots (its look-ups are reused only while no body came or went)."""
    ids = ("a", "b", "c") + tuple(f"x{k}" for k in range(100))  # >= the compiled store
    n = len(ids)
    scene = Scene(5.0, 2)
    z = np.zeros((n, 3))

    def merge(stamp: int, xs: np.ndarray) -> None:
        p = np.column_stack([xs, np.zeros(n), np.zeros(n)])
        scene.merge(ids, np.full(n, stamp, np.int64), p, z, z, np.full(n, 0.1),
                    np.zeros(n, bool), stamp)

    merge(T0, np.arange(n) * 10.0)
    scene.merge(["new"], np.array([T0 + 1]), np.zeros((1, 3)), np.zeros((1, 3)),
                np.zeros((1, 3)), np.array([0.1]), np.array([False]), T0 + 1)
    scene.merge(["b"], np.array([T0 + 1]), np.zeros((1, 3)), np.zeros((1, 3)),
                np.zeros((1, 3)), np.array([0.0]), np.array([True]), T0 + 1)
    merge(T0 + 2, np.arange(n) * 10.0 + 1.0)
    snap = scene.snapshot()
    where = {i: k for k, i in enumerate(snap.ids)}
    for k, body in enumerate(ids):
        assert snap.positions[where[body], 0] == k * 10.0 + 1.0
    assert "new" in where
