"""Constant-acceleration motion: the one propagation formula of the core.

``p(t) = p + v t + a t^2 / 2`` and ``v(t) = v + a t``, in this rounding
order everywhere (broad phase bounds, state propagation, contact geometry),
so a state propagated by one part of the core is bitwise the state another
part computes.  Works on floats inside numba kernels and on broadcasting
numpy arrays alike.
"""
from __future__ import annotations

from numba.extending import register_jitable

__all__ = ["arc_position", "arc_velocity"]


@register_jitable
def arc_position(p, v, a, t):
    """Position after ``t`` seconds [m]: ``p + v t + a t^2 / 2``."""
    return p + v * t + 0.5 * a * t * t


@register_jitable
def arc_velocity(v, a, t):
    """Velocity after ``t`` seconds [m/s]: ``v + a t``."""
    return v + a * t
