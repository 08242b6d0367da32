"""Per-test tallies (examples run, messages sent, ...) recorded as junit properties.

Tests call ``tally(key, n)``; after the test, each key is written with
``record_property`` so that ``scripts/reliability_report.py`` can report how
much was actually tried, from the run's junit XML.
"""
from __future__ import annotations

from collections import Counter

import pytest

_TALLY: Counter = Counter()
_FACTS: dict = {}


def tally(key: str, n: int = 1) -> None:
    _TALLY[key] += n


def fact(key: str, value) -> None:
    """A measured value to report (e.g. a duration or an RSS figure)."""
    _FACTS[key] = value


@pytest.fixture(autouse=True)
def _record_tallies(record_property):
    _TALLY.clear()
    _FACTS.clear()
    yield
    for key, value in sorted(_TALLY.items()):
        record_property(key, value)
    for key, value in sorted(_FACTS.items()):
        record_property(key, value)
