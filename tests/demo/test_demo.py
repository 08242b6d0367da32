"""The README's main job: the demo runs, shows contacts and writes a PNG.

Guarantees proved here: `demo` starts collision_node and demo_scene as
separate processes, receives predictions over DDS, prints the table (plain
lines when stdout is not a terminal), with contacts with the room's walls and
crate (2-D), writes a valid PNG and exits 0; the demo
scene is reproducible from its seed; `demo_scene --help` lists demo_scene's own
parameters, and while running it prints one line saying what it publishes,
where and how fast.
"""
from __future__ import annotations

import re
import subprocess
import sys

import numpy as np

from circle_collision_ros.demo.demo_scene import SyntheticScene


def test_demo_runs_and_draws_the_scene(tmp_path) -> None:
    # The demo's clock starts at the first prediction, so 2 s still show the table.
    run = subprocess.run([sys.executable, "-m", "circle_collision_ros.demo.run", "--duration", "2",
                          "--count", "60", "--runs-dir", str(tmp_path)],
                         capture_output=True, text=True, timeout=180)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "Traceback" not in run.stderr
    match = re.search(r"scene picture: (\S+\.png)", run.stdout)
    assert match, run.stdout
    png = open(match.group(1), "rb").read()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    assert "contacts within" in run.stdout and "predictions received:" in run.stdout
    # the room: the last table counts contacts with its walls and crate (2-D default)
    walls = re.findall(r"\((\d+) with walls or obstacles\)", run.stdout)
    assert walls and int(walls[-1]) > 0, run.stdout
    assert "\x1b[" not in run.stdout  # not a terminal: no cursor control codes


def test_synthetic_scene_is_reproducible() -> None:
    a, b = SyntheticScene(50, 60.0, 2, seed=7), SyntheticScene(50, 60.0, 2, seed=7)
    for _ in range(300):
        a.step(1 / 30)
        b.step(1 / 30)
    assert np.array_equal(a.p, b.p) and np.array_equal(a.v, b.v)
    assert (a.p[:, :2] >= 0).all() and (a.p[:, :2] <= 60.0).all() and (a.p[:, 2] == 0).all()
    c = SyntheticScene(50, 60.0, 2, seed=8)
    assert not np.array_equal(a.radii, c.radii)


def _demo_scene_exe() -> str:
    import os
    return os.path.join(sys.prefix, "lib", "circle_collision_ros", "demo_scene")


def test_demo_scene_help_shows_its_own_parameters() -> None:
    from circle_collision_ros.demo.demo_scene import DEMO_PARAMS

    out = subprocess.run([_demo_scene_exe(), "--help"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    for param in DEMO_PARAMS:
        assert re.search(
            rf"^\s+{param.name}\s+{re.escape(repr(param.default))}\s+\S", out.stdout, re.M
        ), f"{param.name} missing from --help:\n{out.stdout}"
    assert "horizon" not in out.stdout and "collision_node.yaml" not in out.stdout


def test_demo_scene_says_what_it_publishes_where_and_how_fast() -> None:
    """The line comes once while demo_scene publishes: stopped after it has published a few
    frames (received here on /demo/states), not after a fixed sleep."""
    import signal
    import threading
    import time

    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from circle_collision_msgs.msg import CircleStateArray

    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node("demo_scene_listener", context=context)
    frames: list[CircleStateArray] = []
    node.create_subscription(CircleStateArray, "demo/states", frames.append,
                             QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    proc = subprocess.Popen(
        [_demo_scene_exe(), "--ros-args", "-p", "count:=7", "-p", "rate:=12.5", "-p",
         "topic:=demo/states", "-p", "frame_id:=odom"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + 60.0  # only against a hang
        while (
            time.monotonic() < deadline
            and proc.poll() is None
            and not (len(frames) >= 3 and any("publishing" in line for line in lines))
        ):
            executor.spin_once(timeout_sec=0.05)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)
        reader.join(timeout=30)
        executor.shutdown()
        node.destroy_node()
        context.try_shutdown()
    output = "".join(lines)
    assert len(frames) >= 3, f"{len(frames)} frames received\n{output}"
    assert all(len(f.circles) == 7 and f.circles[0].header.frame_id == "odom" for f in frames)
    published = [line for line in lines if "publishing" in line]
    assert len(published) == 1, output
    assert re.search(
        r"publishing 7 2-D bodies as CircleStateArray on /demo/states \(frame 'odom'\)"
        r" at 12\.5 Hz",
        published[0],
    ), published[0]
    assert proc.returncode == 0 and "Traceback" not in output
