"""A small replay corpus from the recorded test bags (real node runs), for corpus/plugin tests."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import pytest

from tests.recording.bag_edits import nudge_first_contact

DATA = Path(__file__).resolve().parents[1] / "data"


def copy_bag(
    source: Path, out: Path, keep_predictions: int | None = None, change: Callable | None = None
) -> Path:
    """Copy a bag record by record: the first `keep_predictions` predictions and what precedes them.

    A prefix of a recording replays exactly as the whole did up to that point,
    so a short copy of a bit-identical bag is bit-identical too.
    """
    from circle_collision_ros.recording.bag_reader import RECORDED_TYPES, open_bag
    from circle_collision_ros.recording.bag_recorder import BagRecorder
    from circle_collision_ros.recording.replay_engine import RecordedTypes

    contents = open_bag(source, message_types=RECORDED_TYPES | {RecordedTypes.CONFIG})
    predictions = 0
    with BagRecorder(out) as rec:
        for info in contents.topics.values():
            # the bytes' own layout
            rec.add_topic(info.topic, info.type_name, definition=info.definition)
        for r in contents.records():
            if r.type_name == RecordedTypes.PREDICTIONS:
                predictions += 1
                if keep_predictions is not None and predictions > keep_predictions:
                    break
            rec.write(r.topic, change(r) if change else r.data, r.log_time_ns, r.publish_time_ns)
    return out


class Corpus(NamedTuple):
    root: Path  # parent folder holding everything below
    identical: list[Path]  # short copies of the recorded bags, in nested folders
    mismatch: Path  # a bag with one-ulp changes in its recorded predictions
    truncated: Path  # a .mcap cut in half
    not_a_bag: Path  # a text file named like a recording


@pytest.fixture(scope="session")
def small_corpus(tmp_path_factory: pytest.TempPathFactory) -> Corpus:
    root = tmp_path_factory.mktemp("corpus")
    identical = [
        copy_bag(DATA / "plain_2d", root / "robot_a" / "run_1", keep_predictions=30),
        copy_bag(DATA / "spheres_3d", root / "robot_a" / "run_2", keep_predictions=20),
        copy_bag(DATA / "bad_inputs_2d", root / "robot_b" / "2026" / "run_3", keep_predictions=30),
    ]
    mismatch = copy_bag(DATA / "plain_2d", root / "robot_b" / "run_4", keep_predictions=30,
                        change=nudge_first_contact)
    source = next((DATA / "plain_2d").glob("*.mcap")).read_bytes()
    truncated = root / "robot_c" / "cut.mcap"
    truncated.parent.mkdir()
    truncated.write_bytes(source[: len(source) // 2])
    not_a_bag = root / "robot_c" / "notes.mcap"
    not_a_bag.write_text("not a recording\n")
    return Corpus(root, identical, mismatch, truncated, not_a_bag)


@pytest.fixture
def good_corpus(small_corpus: Corpus, tmp_path: Path) -> Path:
    """A folder holding only the identical bags (copied)."""
    for bag in small_corpus.identical:
        shutil.copytree(bag, tmp_path / "good" / bag.name)
    return tmp_path / "good"
