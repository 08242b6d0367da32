"""Session-wide test setup: keep ROS traffic on this machine and isolate sessions.

Runs before any test module imports rclpy, so every node started by the tests
(in-process or as a subprocess, which inherits the environment) uses
localhost-only discovery and this session's own ROS_DOMAIN_ID.
"""
from __future__ import annotations

import fcntl
import os
import tempfile

import pytest

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_STATIC_PEERS", None)


def _claim_domain_id() -> int:
    """Lock a ROS domain id (1..100) for this test session.

    A lock file per id under the temp dir, held until the process exits, keeps
    parallel sessions (several clones, CI beside a developer) from cross-talking.
    """
    for domain in range(1, 101):
        path = os.path.join(tempfile.gettempdir(), f"circle_collision_ros_domain_{domain}.lock")
        fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        _HELD_LOCKS.append(fd)  # keep the descriptor (and so the lock) for the session
        return domain
    raise RuntimeError("no free ROS_DOMAIN_ID in 1..100 (101 test sessions at once?)")


_HELD_LOCKS: list[int] = []
# Each pytest-xdist worker is a session of its own on the wire: its own domain id, so
# two workers' nodes never see each other (the controller's id is not inherited).
if "CIRCLE_COLLISION_TEST_DOMAIN_ID" not in os.environ or "PYTEST_XDIST_WORKER" in os.environ:
    os.environ["CIRCLE_COLLISION_TEST_DOMAIN_ID"] = str(_claim_domain_id())
os.environ["ROS_DOMAIN_ID"] = os.environ["CIRCLE_COLLISION_TEST_DOMAIN_ID"]

# As the package's executables do (cli.apply_ros_environment_defaults): the shipped
# large-scene Fast DDS profile, unless the environment names one already.
from circle_collision_ros.cli import use_large_scene_transport  # noqa: E402

use_large_scene_transport()


@pytest.fixture(scope="session")
def ros_domain_id() -> int:
    return int(os.environ["ROS_DOMAIN_ID"])


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--stress", action="store_true",
                     help="also run the long stress, soak and reference runs (marker 'stress') and "
                          "the full hypothesis example counts; CI runs them")


def pytest_configure(config: pytest.Config) -> None:
    # Read by tests/stress.py when the test modules are imported (after this hook).
    stress = config.getoption("--stress") or "stress" in (config.getoption("-m") or "")
    os.environ["CIRCLE_COLLISION_STRESS"] = "1" if stress else "0"


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Without --stress (or a -m naming it), the stress tests are deselected, not skipped:
    the default run is the suite that answers quickly whether a change broke something."""
    if os.environ.get("CIRCLE_COLLISION_STRESS") == "1":
        return
    kept = [item for item in items if item.get_closest_marker("stress") is None]
    if len(kept) < len(items):
        config.hook.pytest_deselected(items=[item for item in items if item not in kept])
        items[:] = kept
