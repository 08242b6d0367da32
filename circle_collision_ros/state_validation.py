"""Checks on incoming CircleState messages, free of side effects.

Each check returns ``None`` for a usable state or a short reason naming the
field and the bad value; callers decide what to do with it (the node warns,
throttled, naming topic and id; the service answers ``success: false``).
"""
from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

from circle_collision_msgs.msg import CircleState


class StampLimits:
    """How far a state's stamp may lie ahead of the receiving clock.

    Tracker clocks drift by milliseconds; a stamp seconds ahead is a unit or
    clock error, and accepting it would drag the scene's reference time into
    the future for every other body.
    """

    MAX_FUTURE_S = 1.0


@dataclass(frozen=True)
class Rejection:
    """One state refused: which body (id may be empty), and why."""

    index: int
    body_id: str
    reason: str


def stamp_ns(state: CircleState) -> int:
    """Header stamp as integer nanoseconds (exact: no float rounding)."""
    return state.header.stamp.sec * 1_000_000_000 + state.header.stamp.nanosec


def state_frame(state: CircleState, array_frame: str = "") -> str:
    """The state's frame: its own header's, else that of the enclosing array."""
    return state.header.frame_id or array_frame


def check_state(state: CircleState, *, frame_id: str, now_ns: int | None,
                array_frame: str = "") -> str | None:
    """Reason why `state` cannot be used, or None if it can.

    Parameters
    ----------
    state : the message to check.
    frame_id : the scene's frame; "" accepts any (the caller adopts the first).
    now_ns : receiving clock in ns, for the future-stamp check; None skips it.
    array_frame : frame of the enclosing CircleStateArray header, used when
        the state's own header has none.
    """
    if not state.id:
        return "empty id"
    if state.remove:
        # A removal needs only id and stamp; its geometry is ignored by contract.
        return _check_stamp(state, now_ns)
    if not math.isfinite(state.radius):
        return f"radius is {state.radius}"
    if state.radius < 0.0:
        return f"radius is negative ({state.radius})"
    for name, vec in (("position", state.position), ("velocity", state.velocity),
                      ("acceleration", state.acceleration)):
        for axis in ("x", "y", "z"):
            value = getattr(vec, axis)
            if not math.isfinite(value):
                return f"{name}.{axis} is {value}"
    frame = state_frame(state, array_frame)
    if frame_id and frame != frame_id:
        return f"frame '{frame}' is not the scene frame '{frame_id}' (no tf here: publish in '{frame_id}')"
    return _check_stamp(state, now_ns)


def _check_stamp(state: CircleState, now_ns: int | None) -> str | None:
    stamp = stamp_ns(state)
    if stamp <= 0:
        return "header.stamp is zero (unset)"
    if now_ns is not None and stamp - now_ns > StampLimits.MAX_FUTURE_S * 1e9:
        return f"header.stamp is {(stamp - now_ns) * 1e-9:.3f} s in the future"
    return None


def duplicate_ids(states: Sequence[CircleState]) -> set[str]:
    """Ids that occur more than once in one message (all copies are ambiguous)."""
    counts = Counter(s.id for s in states)
    return {body_id for body_id, n in counts.items() if n > 1 and body_id}
