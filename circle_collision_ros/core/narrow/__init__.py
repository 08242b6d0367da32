"""Narrow phase: the first contact time of two circles or spheres with constant accelerations.

``time_to_collision`` is the public entry, one pair or a batch (the one-pair C
front in ``one_pair`` over the batch entry in ``batch``); ``contact_details``
gives the contact point, normal and closing speed at a time it returned.
Below them: the certified fast path (``fast``), straight-line pairs
(``straight``), the robust solver (``robust``), exact rational decisions
(``exact``), double-double arithmetic (``dd``) and the shared evaluation
rules and error bounds (``evaluate``).
"""
from circle_collision_ros.core.narrow.contact import contact_details
from circle_collision_ros.core.narrow.exact import exact_first_contact
from circle_collision_ros.core.narrow.one_pair import time_to_collision

__all__ = ["time_to_collision", "contact_details", "exact_first_contact"]
