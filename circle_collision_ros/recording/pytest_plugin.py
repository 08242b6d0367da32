"""pytest plugin: recorded runs as tests (loaded via the `pytest11` entry point after pip install).

- ``pytest --replay-bags runs/`` (bag dirs, .mcap files, parent folders, globs;
  repeatable) adds one test per bag, named ``replay[<bag>]``; it fails with the
  differences (or the one-line read error) when the replay is not bit-identical.
- The ``replay_bag`` fixture replays a bag in the test's process and returns
  a :class:`ReplayResult` with every replayed prediction, for custom assertions::

      def test_robots_keep_their_distance(replay_bag):
          run = replay_bag("runs/2026-12-01/bag")
          assert run.ok, run.mismatches[:5]
          assert run.soonest_contact("robot_1", "robot_2") >= 0.5

Nothing here imports rclpy until a bag is replayed, so the plugin costs other
pytest runs nothing (tests/recording/test_pytest_plugin.py, run with pytester).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import pytest

from circle_collision_ros.recording.corpus import BagOutcome, find_bags

if TYPE_CHECKING:  # the decoder imports numba and the message package: only when replaying
    from circle_collision_ros.pipeline.prediction_codec import PairPrediction, PredictionArray

MAX_DETAIL_LINES = 20


@dataclass(frozen=True)
class ReplayedPrediction:
    """One prediction as recomputed by the replay, and whether the recording matched it."""

    log_time_ns: int  # when the node computed (and recorded) it
    stamp_ns: int  # header stamp: the reference time of every time_to_collision
    horizon: float
    pairs: tuple[PairPrediction, ...]
    identical: bool  # recorded message equal to the replayed one, field by field

    def pair(self, a: str, b: str) -> PairPrediction | None:
        """The entry for bodies a and b (either order), or None if not reported."""
        return next((p for p in self.pairs if {p.id_a, p.id_b} == {a, b}), None)


@dataclass
class ReplayResult:
    """A replayed bag: the engine's report and per-prediction access."""

    path: str
    inputs: int
    pairs_compared: int
    max_time_difference: float
    mismatches: list[str]
    predictions: list[ReplayedPrediction] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """Every recorded prediction reproduced bit for bit (and there was one)."""
        return not self.mismatches and bool(self.predictions)

    def pair_history(self, a: str, b: str) -> list[tuple[int, PairPrediction]]:
        """(log_time_ns, entry) for each prediction that reported bodies a and b."""
        return [
            (p.log_time_ns, entry) for p in self.predictions if (entry := p.pair(a, b)) is not None
        ]

    def soonest_contact(self, a: str, b: str) -> float:
        """Smallest predicted time to contact of a and b over the run in s (inf if never)."""
        return min(
            (entry.time_to_collision for _, entry in self.pair_history(a, b)), default=math.inf
        )


def replay_bag_result(path: str, tolerant: bool = False) -> ReplayResult:
    """Replay `path` in this process and keep every replayed prediction (BagError if unreadable)."""
    from circle_collision_ros.recording.replay_engine import replay_bag

    predictions: list[ReplayedPrediction] = []

    def keep(log_time_ns: int, recorded: PredictionArray, replayed: PredictionArray) -> None:
        sec, nanosec, _ = replayed.header
        predictions.append(
            ReplayedPrediction(log_time_ns, sec * 1_000_000_000 + nanosec, replayed.horizon,
                               replayed.predictions, recorded == replayed)
        )

    report = replay_bag(path, tolerant=tolerant, on_prediction=keep)
    return ReplayResult(str(path), report.inputs, report.pairs_compared, report.max_time_difference,
                        list(report.mismatches), predictions)


# ---------------------------------------------------------------- hooks


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("replay", "replay recorded circle_collision_ros runs")
    group.addoption(
        "--replay-bags",
        action="append",
        default=[],
        metavar="PATH",
        help="replay each bag under PATH (bag dir, .mcap, parent folder or glob) as a test",
    )
    group.addoption("--replay-tolerant", action="store_true",
                    help="read truncated bags up to their last complete chunk")


class ReplayMismatch(Exception):
    """A bag that did not replay bit-identically, or could not be read."""


class ReplayBagItem(pytest.Item):
    """One bag: passes when replaying it reproduces every recorded prediction."""

    def __init__(self, *, bag: str, problem: BagOutcome | None, tolerant: bool, **kwargs) -> None:
        super().__init__(**kwargs)
        self.bag, self.problem, self.tolerant = bag, problem, tolerant

    def runtest(self) -> None:
        from circle_collision_ros.recording.bag_reader import BagError
        from circle_collision_ros.recording.replay_engine import replay_bag

        if self.problem is not None:
            raise ReplayMismatch(f"unreadable: {self.problem.detail}")
        try:
            report = replay_bag(self.bag, tolerant=self.tolerant)
        except BagError as exc:
            raise ReplayMismatch(f"unreadable: {exc}") from None
        self.user_properties += [("inputs", report.inputs), ("predictions", report.predictions),
                                 ("pairs_compared", report.pairs_compared),
                                 ("max_time_difference", report.max_time_difference)]
        if report.predictions == 0:
            raise ReplayMismatch(f"{self.bag}: the bag holds no recorded predictions to compare")
        if not report.ok:
            shown = report.mismatches[:MAX_DETAIL_LINES]
            more = len(report.mismatches) - len(shown)
            raise ReplayMismatch(
                "\n".join(
                    [
                        f"{self.bag}: {len(report.mismatches)} difference(s) in "
                        f"{report.predictions} predictions"
                        f" (largest time difference {report.max_time_difference!r} s):",
                        *shown,
                    ]
                    + ([f"... and {more} more"] if more else [])
                )
            )

    def repr_failure(self, excinfo, style=None):
        if isinstance(excinfo.value, ReplayMismatch):
            return str(excinfo.value)
        return super().repr_failure(excinfo, style=style)

    def reportinfo(self):
        return self.path, None, f"replay {self.bag}"


@pytest.hookimpl(tryfirst=True)  # before -k/-m deselection sees the items
def pytest_collection_modifyitems(
    session: pytest.Session, config: pytest.Config, items: list[pytest.Item]
) -> None:
    specs = config.getoption("replay_bags")
    if not specs:
        return
    bags, problems = find_bags(specs)
    tolerant = config.getoption("replay_tolerant")
    for problem in problems:
        items.append(
            ReplayBagItem.from_parent(session, name=f"replay[{problem.path}]", bag=problem.path,
                                      problem=problem, tolerant=tolerant)
        )
    for bag in bags:
        items.append(
            ReplayBagItem.from_parent(
                session, name=f"replay[{bag}]", bag=bag, problem=None, tolerant=tolerant
            )
        )


@pytest.fixture
def replay_bag() -> Callable[..., ReplayResult]:
    """replay_bag(path, tolerant=False) -> ReplayResult: replay a recording in this process."""
    return replay_bag_result
