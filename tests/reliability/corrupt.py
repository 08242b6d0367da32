"""Randomly corrupted CircleStateArray contents, and the oracle that says which states are bad.

The oracle is written from the README's list of bad input (non-finite numbers,
negative radius, empty or duplicate id, wrong frame, zero or future stamp) plus
the magnitude bound of state_validation.ValueLimits, independently of
state_validation's code. A removal (remove: true) needs only a good id and stamp.
"""
from __future__ import annotations

import math

from hypothesis import strategies as st

from tests.reliability.wire import Body

SCENE_FRAME = "map"
FUTURE_S = 1.0  # StampLimits.MAX_FUTURE_NS
MAX_MAGNITUDE = 1e12

FIELDS = [f"{v}.{a}" for v in ("p", "v", "a") for a in range(3)]
BAD_NUMBERS = [math.nan, math.inf, -math.inf, 1e200, -1e13]
# Valid but unusual ids: very long, non-ASCII, whitespace, look-alikes.
ODD_IDS = ["x" * 5000, "körper_ü", "机器人", "🚗", " ", "id with spaces", "a/b:c", "Ω" * 300]

BAD_KINDS = ("number", "radius", "empty_id", "duplicate", "frame", "zero_stamp", "negative_stamp",
             "future_stamp")


def is_bad(b: Body, duplicated: bool, now_ns: int) -> bool:
    if not b.id or duplicated:
        return True
    if b.stamp_ns <= 0 or b.stamp_ns - now_ns > FUTURE_S * 1e9:
        return True
    if b.remove:
        return False
    numbers = [b.radius, *b.p, *b.v, *b.a]
    if not all(math.isfinite(x) and abs(x) <= MAX_MAGNITUDE for x in numbers) or b.radius < 0:
        return True
    return (b.frame or SCENE_FRAME) != SCENE_FRAME


def _set(b: Body, field: str, value: float) -> None:
    vec, axis = field.split(".")
    items = list(getattr(b, vec))
    items[int(axis)] = value
    setattr(b, vec, tuple(items))


@st.composite
def corrupted_message(draw, prefix: str, now_ns: int, offset: float = 0.0, dimensions: int = 2,
                      max_good: int = 12, max_bad: int = 8, removable: tuple = ()):
    """(bodies, bad_indices): good bodies around x = offset plus corrupted ones, shuffled.

    bodies[0] is always good and stamped exactly now_ns (so the scene's reference
    time is known); other stamps lie up to 50 ms before it.
    """
    small = st.floats(-40.0, 40.0)
    n_good = draw(st.integers(1, max_good))
    bodies = []
    for k in range(n_good):
        odd = draw(st.sampled_from([None] * 4 + ODD_IDS))
        body_id = f"{prefix}{k}" + (f"_{odd}" if odd else "")
        p = (offset + draw(small), draw(small), draw(small) if dimensions == 3 else 0.0)
        v = tuple(draw(st.floats(-5.0, 5.0)) for _ in range(3))
        a = tuple(draw(st.floats(-1.0, 1.0)) for _ in range(3))
        stamp = now_ns if k == 0 else now_ns - draw(st.integers(0, 50_000_000))
        frame = draw(st.sampled_from([SCENE_FRAME, SCENE_FRAME, ""]))  # "" inherits the array's
        bodies.append(Body(body_id, draw(st.floats(0.0, 3.0)), p, v, a, stamp, frame))
    n_bad = draw(st.integers(0, max_bad))
    for k in range(n_bad):
        kind = draw(st.sampled_from(BAD_KINDS))
        b = Body(f"{prefix}bad{k}", 1.0, (offset + draw(small), draw(small), 0.0), (0.0, 0.0, 0.0),
                 (0.0, 0.0, 0.0), now_ns - 1000, SCENE_FRAME)
        if kind == "number":
            _set(b, draw(st.sampled_from(FIELDS)), draw(st.sampled_from(BAD_NUMBERS)))
        elif kind == "radius":
            b.radius = draw(st.sampled_from([-1.0, -1e-300, math.nan, math.inf, 1e160]))
        elif kind == "empty_id":
            b.id = ""
        elif kind == "duplicate":
            # poisons the other one too (never the anchor bodies[0])
            b.id = draw(st.sampled_from([x.id for x in bodies[1:]] or [f"{prefix}dup"]))
        elif kind == "frame":
            b.frame = draw(st.sampled_from(["odom", "Map", "map ", "base_link"]))
        elif kind == "zero_stamp":
            b.stamp_ns = 0
        elif kind == "negative_stamp":
            b.stamp_ns = -draw(st.integers(1, 2**31 - 1)) * 1_000_000_000
        elif kind == "future_stamp":
            b.stamp_ns = now_ns + draw(st.integers(1_100_000_000, 10**12))
        # Sometimes also a second problem, or a removal flag (geometry then no longer matters).
        if draw(st.integers(0, 4)) == 0:
            _set(b, draw(st.sampled_from(FIELDS)), math.nan)
        if draw(st.integers(0, 5)) == 0:
            b.remove = True
        bodies.append(b)
    # Removal of a body from an earlier message (`removable`) or of an unknown id.
    taken = {b.id for b in bodies}
    if draw(st.booleans()):
        target = draw(
            st.sampled_from([i for i in removable if i not in taken] or [f"{prefix}unknown"])
        )
        bodies.append(
            Body(target, math.nan, (math.nan,) * 3, stamp_ns=now_ns, frame="odom", remove=True)
        )
    order = draw(st.permutations(range(1, len(bodies))))
    bodies = [bodies[0]] + [bodies[k] for k in order]
    counts: dict[str, int] = {}
    for b in bodies:
        counts[b.id] = counts.get(b.id, 0) + 1
    bad = [k for k, b in enumerate(bodies) if is_bad(b, counts[b.id] > 1, now_ns)]
    return bodies, bad
