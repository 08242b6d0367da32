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
if "CIRCLE_COLLISION_TEST_DOMAIN_ID" not in os.environ:
    os.environ["CIRCLE_COLLISION_TEST_DOMAIN_ID"] = str(_claim_domain_id())
os.environ["ROS_DOMAIN_ID"] = os.environ["CIRCLE_COLLISION_TEST_DOMAIN_ID"]

# As the package's executables do (cli.apply_ros_environment_defaults): the shipped
# large-scene Fast DDS profile, unless the environment names one already.
from circle_collision_ros.cli import use_large_scene_transport  # noqa: E402

use_large_scene_transport()


@pytest.fixture(scope="session")
def ros_domain_id() -> int:
    return int(os.environ["ROS_DOMAIN_ID"])
