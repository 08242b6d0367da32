"""How much work a test does: the default run's amount, or the stress run's.

``scripts/test.sh`` runs the quick suite; ``scripts/test.sh --stress`` (what CI runs)
adds the tests marked ``stress`` and raises the example counts given here.
"""
from __future__ import annotations

import os

__all__ = ["STRESS", "examples"]

#: True in a stress run (set by tests/conftest.py before the test modules are imported).
STRESS = os.environ.get("CIRCLE_COLLISION_STRESS") == "1"


def examples(default: int, stress: int) -> int:
    """A hypothesis ``max_examples`` (or any case count): ``stress`` in a stress run."""
    return stress if STRESS else default
