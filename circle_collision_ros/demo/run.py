"""demo: run collision_node against demo_scene, show the soonest contacts live, draw the scene.

Starts both executables as separate processes (as a user would), listens to
their topics, prints a table of the soonest predicted contacts (refreshed in
place on a terminal, plain lines otherwise), and at the end writes a PNG of
the scene (bodies, velocity arrows, predicted contact points) and says where.
"""
from __future__ import annotations

import argparse
import math
import os
import signal
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import MarkerArray

from circle_collision_msgs.msg import (CircleStateArray, CollisionPrediction,
                                       CollisionPredictionArray)
from circle_collision_ros.cli import apply_ros_environment_defaults, parse_args

_STARTED = time.monotonic()  # module import: the demo process's start, for "first prediction after"

STARTUP_TIMEOUT_S = 600.0  # a first start compiles the kernels; slow machines take minutes
STATUS_NAMES = {CollisionPrediction.NO_CONTACT: "none", CollisionPrediction.CONTACT: "contact",
                CollisionPrediction.OVERLAPPING: "OVERLAP"}


class DemoListener(Node):
    """Keeps the latest scene and predictions seen on the demo's topics."""

    def __init__(self) -> None:
        super().__init__("demo_listener")
        self.scene: CircleStateArray | None = None
        self.predictions: CollisionPredictionArray | None = None
        self.prediction_count = 0
        self.create_subscription(CircleStateArray, "circle_states", self._on_scene,
                                 QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT))
        self.create_subscription(
            CollisionPredictionArray, "collision_predictions", self._on_predictions, 10
        )
        # the static world as the node has it (transient local: sent once per change)
        self.walls: MarkerArray | None = None
        self.create_subscription(MarkerArray, "/collision_node/static_markers", self._on_walls,
                                 QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                            durability=DurabilityPolicy.TRANSIENT_LOCAL))

    def _on_walls(self, msg: MarkerArray) -> None:
        self.walls = msg

    def _on_scene(self, msg: CircleStateArray) -> None:
        self.scene = msg

    def _on_predictions(self, msg: CollisionPredictionArray) -> None:
        self.predictions = msg
        self.prediction_count += 1


def format_table(predictions: CollisionPredictionArray | None, elapsed: float, duration: float,
                 count: int, rows: int = 10, bodies: set | None = None) -> list[str]:
    """The live view as lines of text; ``bodies`` (the scene's ids) tells contacts with walls
    and obstacles (id_b not a body) apart."""
    head = (
        f"circle_collision_ros demo  {elapsed:5.1f}/{duration:.0f} s  predictions received: {count}"
    )
    if predictions is None:
        return [head, "waiting for collision_predictions ..."]
    contacts = [p for p in predictions.predictions if p.status != CollisionPrediction.NO_CONTACT]
    # pair rows come first, then contacts with static geometry: the soonest of both
    contacts.sort(key=lambda p: p.time_to_collision)
    walls = ("" if bodies is None else
             f" ({sum(p.id_b not in bodies for p in contacts)} with walls or obstacles)")
    lines = [
        head,
        f"{len(contacts)} contacts within {predictions.horizon:.1f} s{walls}; soonest:",
        f"{'body a':>10} {'body b':>10} {'status':>8} {'ttc [s]':>8} "
        f"{'closing [m/s]':>13}  contact point [m]",
    ]
    for p in contacts[:rows]:
        pt = p.contact_point
        lines.append(
            f"{p.id_a:>10} {p.id_b:>10} {STATUS_NAMES[p.status]:>8} {p.time_to_collision:8.3f}"
            f" {p.closing_speed:13.2f}  ({pt.x:7.2f}, {pt.y:7.2f})"
        )
    return lines


def draw_scene(
    scene: CircleStateArray | None, predictions: CollisionPredictionArray | None, path: Path,
    walls: MarkerArray | None = None,
) -> None:
    """PNG of the bodies, their velocities, the static world and the predicted contact points
    (wall contacts apart)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    fig, ax = plt.subplots(figsize=(8, 8), dpi=110)
    soon: dict[str, float] = {}
    contacts = []
    if predictions is not None:
        contacts = [
            p for p in predictions.predictions if p.status != CollisionPrediction.NO_CONTACT
        ]
        for p in contacts:
            for body in (p.id_a, p.id_b):
                soon[body] = min(soon.get(body, math.inf), p.time_to_collision)
    if scene is not None:
        for c in scene.circles:
            ttc = soon.get(c.id, math.inf)
            colour = (
                "tab:red"
                if ttc < 1
                else "tab:orange"
                if ttc < 3
                else "gold"
                if ttc < math.inf
                else "tab:blue"
            )
            ax.add_patch(Circle((c.position.x, c.position.y), c.radius, color=colour, alpha=0.5))
            ax.arrow(c.position.x, c.position.y, c.velocity.x, c.velocity.y, width=0.05,
                     head_width=0.4, color="k", alpha=0.6, length_includes_head=True)
    bodies = {c.id for c in scene.circles} if scene is not None else set()
    for marker in walls.markers if walls is not None else []:
        xs = [q.x for q in marker.points]
        ys = [q.y for q in marker.points]
        for k in range(0, len(xs) - 1, 2):
            ax.plot(xs[k:k + 2], ys[k:k + 2], color="dimgrey", linewidth=1.5)
    pairs = [p for p in contacts if p.id_b in bodies]
    static = [p for p in contacts if p.id_b not in bodies]
    if pairs:
        ax.scatter([p.contact_point.x for p in pairs], [p.contact_point.y for p in pairs],
                   marker="x", color="crimson", s=60, zorder=3, label="predicted contact point")
    if static:
        ax.scatter([p.contact_point.x for p in static], [p.contact_point.y for p in static],
                   marker="s", facecolors="none", edgecolors="purple", s=60, zorder=3,
                   label="predicted wall/obstacle contact")
    if contacts:
        ax.legend(loc="upper right")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(
        "bodies (colour: time to first contact <1 s red, <3 s orange, later gold, none blue);"
        "\narrows: velocity over 1 s",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--duration", type=float, default=10.0, help="seconds to run (default 10)")
    parser.add_argument(
        "--count", type=int, default=40, help="bodies in the demo scene (default 40)"
    )
    parser.add_argument("--seed", type=int, default=1, help="scene seed (default 1)")
    parser.add_argument(
        "--area", type=float, default=60.0, help="side of the scene's square/cube in m"
    )
    parser.add_argument(
        "--rate", type=float, default=30.0, help="scene publish rate in Hz (default 30)"
    )
    parser.add_argument(
        "--horizon", type=float, default=5.0, help="prediction horizon in s (default 5)"
    )
    parser.add_argument(
        "--runs-dir", default="runs", help="where each run's folder goes (default runs/)"
    )
    parser.add_argument("--no-record", action="store_true", help="do not record the run to MCAP")
    parser.add_argument("--bag", help="bag directory to record to (default: <run folder>/bag)")
    parser.add_argument(
        "--dimensions", type=int, choices=(2, 3), default=2, help="2 circles, 3 spheres"
    )
    parser.add_argument("--bad-fraction", type=float, default=0.0,
                        help="fraction of malformed states mixed into the scene (default 0)")


def _start(module: str, ros_args: list[str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", module, "--ros-args", *ros_args])


def _all_running(children: list[subprocess.Popen]) -> bool:
    if any(c.poll() is not None for c in children):
        print("demo: a child process exited early; see its messages above", file=sys.stderr)
        return False
    return True


def main(args: list[str] | None = None) -> int:
    argv = sys.argv if args is None else args
    opts = parse_args(argv, __doc__.splitlines()[0], _add_arguments)
    apply_ros_environment_defaults()
    run_dir = Path(opts.runs_dir) / datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")
    run_dir.mkdir(parents=True, exist_ok=True)
    bag = Path(opts.bag) if opts.bag else run_dir / "bag"
    # The demo's states carry no covariance and its body count is known: the node compiles
    # (first start) and loads only the kernels such a scene reaches (pipeline/kernels.py).
    node_args = ["-p", f"horizon:={opts.horizon}", "-p", f"dimensions:={opts.dimensions}",
                 "-p", "use_covariance:=false", "-p", f"max_bodies:={max(opts.count, 1)}",
                 "--log-level", "error"]
    if not opts.no_record:
        node_args[:0] = ["-p", f"record_path:={bag}"]
    if opts.dimensions == 2:  # the room of demo_scene: walls on 'map', a crate polygon
        node_args[:0] = ["-p", "map_topic:=map", "-p", "polygon_topics:=[crate/polygon]",
                         "-p", "frame_id:=map"]
    children = [
        _start("circle_collision_ros.node.collision_node", node_args),
        _start(
            "circle_collision_ros.demo.demo_scene",
            ["-p", f"count:={opts.count}", "-p", f"seed:={opts.seed}", "-p", f"rate:={opts.rate}",
             "-p", f"area_size:={opts.area}", "-p", f"dimensions:={opts.dimensions}", "-p",
             f"bad_fraction:={opts.bad_fraction}"],
        ),
    ]
    rclpy.init()
    listener = DemoListener()
    executor = SingleThreadedExecutor()
    executor.add_node(listener)
    tty = sys.stdout.isatty()
    try:
        # The clock starts with the first prediction: a first start may compile the numba
        # kernels (cached afterwards), which must not eat the demo's time.
        print("starting collision_node and demo_scene ...", flush=True)
        waited = time.monotonic()
        told = False
        while listener.prediction_count == 0 and time.monotonic() - waited < STARTUP_TIMEOUT_S:
            executor.spin_once(timeout_sec=0.1)
            if not told and time.monotonic() - waited > 5.0:
                told = True
                print("the node's first start compiles its numba kernels (cached afterwards) ...",
                      flush=True)
            if not _all_running(children):
                return 1
        if listener.prediction_count:
            print(f"first prediction after {time.monotonic() - _STARTED:.1f} s", flush=True)
        started = time.monotonic()
        next_print = 0.0
        while (elapsed := time.monotonic() - started) < opts.duration:
            executor.spin_once(timeout_sec=0.05)
            if not _all_running(children):
                return 1
            if elapsed >= next_print:
                lines = format_table(
                    listener.predictions, elapsed, opts.duration, listener.prediction_count
                )
                if tty:  # redraw in place: cursor home, clear screen
                    sys.stdout.write("\x1b[H\x1b[2J" + "\n".join(lines) + "\n")
                else:
                    print(" | ".join(lines[:2]) if len(lines) > 3 else " | ".join(lines))
                sys.stdout.flush()
                next_print = elapsed + (0.25 if tty else 1.0)
    except KeyboardInterrupt:
        pass
    finally:
        for child in children:
            if child.poll() is None:
                child.send_signal(signal.SIGINT)
        for child in children:
            try:
                child.wait(timeout=10)
            except subprocess.TimeoutExpired:
                child.kill()
        executor.shutdown()
        listener.destroy_node()
        rclpy.try_shutdown()
    bodies = {c.id for c in listener.scene.circles} if listener.scene is not None else None
    print(
        "\n".join(
            format_table(
                listener.predictions, opts.duration, opts.duration, listener.prediction_count,
                bodies=bodies,
            )
        )
    )
    picture = run_dir / "scene.png"
    draw_scene(listener.scene, listener.predictions, picture, listener.walls)
    print(f"scene picture: {os.path.abspath(picture)}")
    if not opts.no_record:
        print(f"recording: {os.path.abspath(bag)}  (check it: replay {bag})")
    if listener.prediction_count == 0:
        print("demo: no predictions were received", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
