"""`source .venv/bin/activate` gives a ROS environment, like sourcing a workspace.

Guarantees proved here, in a clean bash (no ROS variables inherited):
- activation sets AMENT_PREFIX_PATH (the venv first), CMAKE_PREFIX_PATH,
  LD_LIBRARY_PATH (the venv's lib/ and the wheels' ros_*.libs), ROS_DISTRO=kilted,
  ROS_VERSION, ROS_PYTHON_VERSION and ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
  (a value the user set is kept);
- what the `ros2` tools do with it works: the ament index (ament_index_python,
  as `ros2 pkg prefix` / `ros2 run` use it) finds our package, its executables
  and the interface packages (as `ros2 interface show` does), without any
  variable set by hand;
- `deactivate` restores every variable to its value before activation (or unsets
  it), and activating twice does not stack entries;
- the bootstrap writes the block once (an idle run changes nothing; checked in
  tests/scripts/test_bootstrap.py through its silence).
"""
from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
VENV = ROOT / ".venv"
VARS = ("AMENT_PREFIX_PATH", "CMAKE_PREFIX_PATH", "LD_LIBRARY_PATH", "ROS_DISTRO", "ROS_VERSION",
        "ROS_PYTHON_VERSION", "ROS_AUTOMATIC_DISCOVERY_RANGE")
# The system python: the venv's re-execs itself with its own LD_LIBRARY_PATH
# (ros_wheels_bootstrapper).
DUMP = (
    "/usr/bin/python3 -c 'import json, os; print(json.dumps({k: os.environ.get(k) for k in %s}))'"
    % json.dumps(VARS)
)

LOOKUP = r'''
import json, os
from ament_index_python.packages import get_package_prefix, get_package_share_directory
from ament_index_python import get_resource
prefix = get_package_prefix("circle_collision_ros")
print(json.dumps({
    "prefix": prefix,
    "executable": os.access(os.path.join(prefix, "lib", "circle_collision_ros", "collision_node"),
                            os.X_OK),
    "config": os.path.isfile(os.path.join(get_package_share_directory("circle_collision_ros"),
                                          "config", "collision_node.yaml")),
    "interface": os.path.isfile(os.path.join(get_package_share_directory("circle_collision_msgs"),
                                             "msg", "CircleState.msg")),
    "odometry": os.path.isfile(os.path.join(get_package_share_directory("nav_msgs"),
                                            "msg", "Odometry.msg")),
    "rosidl_interfaces": (
        "msg/CircleState.idl" in get_resource("rosidl_interfaces", "circle_collision_msgs")[0]
    ),
}))
'''


def _bash(script: str, env_extra: dict[str, str] | None = None) -> list[dict]:
    env = {"HOME": os.environ.get("HOME", "/tmp"), "PATH": "/usr/bin:/bin", **(env_extra or {})}
    out = subprocess.run(["bash", "--noprofile", "--norc", "-c", script], env=env,
                         capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    return [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]


def test_activation_sets_the_ros_environment_and_deactivate_restores_it() -> None:
    before, active, again, after = _bash(
        f"{DUMP}; source .venv/bin/activate; {DUMP}; source .venv/bin/activate; {DUMP}; "
        f"deactivate; {DUMP}"
    )
    assert all(v is None for v in before.values())
    venv = str(VENV)
    assert active["AMENT_PREFIX_PATH"] == venv and active["CMAKE_PREFIX_PATH"] == venv
    libs = active["LD_LIBRARY_PATH"].split(":")
    assert libs[0] == f"{venv}/lib" and any(p.endswith("/ros_rclpy.libs") for p in libs)
    assert all(Path(p).is_dir() for p in libs)
    assert (active["ROS_DISTRO"], active["ROS_VERSION"], active["ROS_PYTHON_VERSION"]) == ("kilted",
                                                                                           "2", "3")
    assert active["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert again == active  # re-activation does not stack entries
    assert after == before


def test_deactivate_restores_values_the_user_had() -> None:
    mine = {"AMENT_PREFIX_PATH": "/opt/ros/kilted", "LD_LIBRARY_PATH": "/opt/lib",
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "ROS_DISTRO": "jazzy"}
    active, after = _bash(f"source .venv/bin/activate; {DUMP}; deactivate; {DUMP}", mine)
    assert active["AMENT_PREFIX_PATH"] == f"{VENV}:/opt/ros/kilted"  # an overlay, like a workspace
    assert active["LD_LIBRARY_PATH"].endswith(":/opt/lib")
    assert active["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SUBNET"  # the user's choice is kept
    assert after == {k: mine.get(k) for k in VARS}


def test_ros_tools_find_the_package_after_activation_only() -> None:
    script = f"source .venv/bin/activate; python - <<'EOF'\n{LOOKUP}\nEOF"
    (found,) = _bash(script)
    assert found == {"prefix": str(VENV), "executable": True, "config": True, "interface": True,
                     "odometry": True, "rosidl_interfaces": True}
    # Without activation the same lookup fails the way `ros2` did (AMENT_PREFIX_PATH not set).
    out = subprocess.run([str(VENV / "bin" / "python"), "-c", LOOKUP], capture_output=True,
                         text=True,
                         env={"HOME": os.environ.get("HOME", "/tmp"), "PATH": "/usr/bin:/bin"},
                         timeout=120)
    assert out.returncode != 0 and "AMENT_PREFIX_PATH" in out.stderr
