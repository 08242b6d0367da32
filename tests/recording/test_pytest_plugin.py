"""The pytest plugin, run by pytest's own pytester in a fresh pytest process without any conftest.

Guarantees proved here:
- the plugin is registered through the `pytest11` entry point of the installed
  package: a directory with no conftest gets `--replay-bags` and `replay_bag`;
- `pytest --replay-bags DIR` gives one test per bag: identical bags pass, a
  mismatching bag fails with its differences, an unreadable path fails with
  its one-line error;
- `replay_bag(path)` returns every replayed prediction: their count equals the
  recorded prediction count read with the independent mcap reader, and a
  custom assertion over them (soonest contact of a pair) agrees with the
  recorded messages decoded by mcap-ros2-support.
"""
from __future__ import annotations

import importlib.metadata
import subprocess
import sys

import pytest


def test_registered_as_a_pytest11_entry_point() -> None:
    plugins = {e.name: e.value for e in importlib.metadata.entry_points(group="pytest11")}
    assert plugins.get("circle_collision_replay") == "circle_collision_ros.recording.pytest_plugin"


def test_replay_bags_gives_one_test_per_bag(pytester: pytest.Pytester, small_corpus) -> None:
    result = pytester.runpytest_subprocess(
        "--replay-bags", str(small_corpus.root), "-p", "no:cacheprovider", "-v"
    )
    result.assert_outcomes(passed=3, failed=3)
    for bag in small_corpus.identical:
        result.stdout.fnmatch_lines([f"*replay?{bag}? PASSED*"])
    result.stdout.fnmatch_lines(
        [
            f"*replay?{small_corpus.mismatch}? FAILED*",
            f"{small_corpus.mismatch}: * difference(s) in 30 predictions "
            "(largest time difference *",
            "prediction #*: pair (*) differs (ttc *",
        ]
    )
    result.stdout.fnmatch_lines([f"unreadable: {small_corpus.truncated}: truncated*"])
    result.stdout.fnmatch_lines([f"unreadable: {small_corpus.not_a_bag}: not an MCAP file*"])


def test_replay_bags_selects_with_k_and_passes_a_good_corpus(
    pytester: pytest.Pytester, good_corpus
) -> None:
    result = pytester.runpytest_subprocess(
        "--replay-bags", str(good_corpus), "-k", "run_1", "-p", "no:cacheprovider"
    )
    result.assert_outcomes(passed=1, deselected=2)
    assert result.ret == 0


def test_replay_bag_fixture_gives_per_prediction_access(
    pytester: pytest.Pytester, small_corpus
) -> None:
    bag = small_corpus.identical[0]
    pytester.makepyfile(f'''
        import math
        from pathlib import Path

        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory

        BAG = Path({str(bag)!r})


        def recorded_predictions():
            with open(next(BAG.glob("*.mcap")), "rb") as f:
                reader = make_reader(f, decoder_factories=[DecoderFactory()])
                return [m for _, c, _, m
                        in reader.iter_decoded_messages(topics=["/collision_predictions"])]


        def test_custom_assertions(replay_bag):
            run = replay_bag(BAG)
            recorded = recorded_predictions()
            assert run.ok and run.mismatches == []
            assert len(run.predictions) == len(recorded) == 30
            assert all(p.identical for p in run.predictions)
            first = next(p for p in recorded if p.predictions)
            a, b = first.predictions[0].id_a, first.predictions[0].id_b
            soonest = min(q.time_to_collision for p in recorded for q in p.predictions
                          if {{q.id_a, q.id_b}} == {{a, b}})
            assert run.soonest_contact(a, b) == soonest < math.inf
            assert run.soonest_contact(b, a) == soonest
            history = run.pair_history(a, b)
            assert history and all(entry.time_to_collision >= soonest for _, entry in history)
            assert run.soonest_contact("no_such_body", a) == math.inf


        def test_a_mismatch_is_visible(replay_bag):
            run = replay_bag({str(small_corpus.mismatch)!r})
            assert not run.ok
            assert sum(not p.identical for p in run.predictions) == len(
                {{m.split(":")[0] for m in run.mismatches}})
    ''')
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(passed=2)


def test_loading_the_plugin_imports_no_ros_or_numba() -> None:
    """pytest loads it in every run of every project in the environment: it must stay cheap."""
    code = (
        "import sys, circle_collision_ros.recording.pytest_plugin; "
        "print(sorted({m.split('.')[0] for m in sys.modules} & {'rclpy', 'numba', 'numpy', "
        "'circle_collision_msgs', 'distributed', 'tqdm'}))"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and run.stdout.strip() == "[]", run.stdout + run.stderr
