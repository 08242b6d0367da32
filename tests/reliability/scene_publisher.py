"""A SyntheticScene publisher process: raw CDR CircleStateArrays at a fixed rate.

    python -m tests.reliability.scene_publisher --count 1000 --rate 30 --seconds 600

Each message carries every body, stamped with the send time (so a prediction's
header.stamp names the input it answers). On exit (end of --seconds, SIGINT or
SIGTERM) prints one JSON line: messages and states sent, first/last stamp, late
ticks (the loop could not keep the rate). Used by the fault tests and by
scripts/soak.py.
"""
from __future__ import annotations

import argparse
import json
import signal
import sys
import time

from circle_collision_ros.cli import apply_ros_environment_defaults  # noqa: E402

# local discovery; large-scene transport profile, as our executables
apply_ros_environment_defaults()

import rclpy  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from circle_collision_msgs.msg import CircleStateArray  # noqa: E402
from circle_collision_ros.demo.demo_scene import SyntheticScene  # noqa: E402
from tests.reliability.wire import encode_scene  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=100)
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--prefix", default="body_")
    ap.add_argument("--area", type=float, default=0.0,
                    help="square side in m (default: sqrt(40 m^2 x count), at least 30)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--stamp-offset", type=float, default=0.0, help="s added to every stamp")
    ap.add_argument("--topic", default="circle_states")
    opts = ap.parse_args(argv)
    area = opts.area or max(30.0, (opts.count * 40.0) ** 0.5)
    scene = SyntheticScene(opts.count, area, 2, opts.seed)
    ids = [f"{opts.prefix}{k:05d}".encode() for k in range(opts.count)]
    rclpy.init()
    node = rclpy.create_node("scene_publisher")
    pub = node.create_publisher(
        CircleStateArray, opts.topic, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    )
    stats = {"messages": 0, "states": 0, "first_stamp_ns": 0, "last_stamp_ns": 0, "late_ticks": 0}
    stop = {"now": False}

    def finish(*_):
        stop["now"] = True

    signal.signal(signal.SIGTERM, finish)
    signal.signal(signal.SIGINT, finish)
    deadline = time.monotonic() + opts.seconds
    while time.monotonic() < deadline and pub.get_subscription_count() == 0 and not stop["now"]:
        rclpy.spin_once(node, timeout_sec=0.05)
    period = 1.0 / opts.rate
    next_tick = time.monotonic()
    offset_ns = int(opts.stamp_offset * 1e9)
    while not stop["now"] and time.monotonic() < deadline:
        if stats["messages"]:
            scene.step(period)
        stamp = node.get_clock().now().nanoseconds + offset_ns
        pub.publish(encode_scene(ids, scene.radii, scene.p, scene.v, scene.a, stamp))
        stats["messages"] += 1
        stats["states"] += opts.count
        stats["first_stamp_ns"] = stats["first_stamp_ns"] or stamp
        stats["last_stamp_ns"] = stamp
        next_tick += period
        delay = next_tick - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        else:
            stats["late_ticks"] += 1
            if delay < -1.0:  # far behind: do not try to catch up in a burst
                next_tick = time.monotonic()
    print(json.dumps(stats), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
