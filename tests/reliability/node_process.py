"""collision_node as a separate process (as users run it) and a client that drives it over DDS.

The environment (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, the session's
ROS_DOMAIN_ID) is inherited from tests/conftest.py, or set by scripts/soak.py.
"""
from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy

from circle_collision_msgs.msg import CircleState, CircleStateArray, CollisionPredictionArray

EXE = os.path.join(sys.prefix, "lib", "circle_collision_ros", "collision_node")


class NodeProcess:
    """collision_node started with `-p name:=value` for each item of `params`; log to a file."""

    def __init__(self, log_path: Path, **params) -> None:
        assert os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE") == "LOCALHOST"
        args = [EXE, "--ros-args"]
        for name, value in params.items():
            args += ["-p", f"{name}:={value}"]
        self.log_path = Path(log_path)
        self._log = open(self.log_path, "w")  # noqa: SIM115 -- closed in stop()
        self.proc = subprocess.Popen(args, stdout=self._log, stderr=subprocess.STDOUT)
        self.pid = self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def log(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")

    def rss_kb(self) -> int:
        for line in Path(f"/proc/{self.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
        return 0

    def stop(self, sig=signal.SIGINT, timeout: float = 20.0) -> int:
        if self.alive():
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        self._log.close()
        return self.proc.returncode

    def kill(self) -> None:
        if self.alive():
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(10)


class Client:
    """A node in its own context: publishes raw CDR state bytes, collects what the node sends."""

    def __init__(self, name: str = "reliability_client", single_topic: str | None = None,
                 reliable: bool = True, raw_predictions: bool = False) -> None:
        """raw_predictions: keep only each prediction's header stamp (ns), read from the
        CDR bytes -- cheap enough for a listener that must keep up with a 1,000-body soak."""
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.predictions: list[tuple[float, CollisionPredictionArray]] = []  # (receive time, msg)
        self.diagnostics: list[dict] = []
        self.node.create_subscription(
            CollisionPredictionArray,
            "collision_predictions",
            self._on_raw_prediction if raw_predictions else self._on_prediction,
            QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE),
            raw=raw_predictions,
        )
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 50)
        qos = QoSProfile(
            depth=1000,
            reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        )
        self.pub = self.node.create_publisher(CircleStateArray, "circle_states", qos)
        self.single_pub = (
            self.node.create_publisher(CircleState, single_topic, qos) if single_topic else None
        )

    def _on_prediction(self, msg: CollisionPredictionArray) -> None:
        self.predictions.append((time.time(), msg))

    def _on_raw_prediction(self, data: bytes) -> None:
        sec, nanosec = struct.unpack_from("<iI", data, 4)  # header.stamp right after encapsulation
        self.predictions.append((time.time(), sec * 1_000_000_000 + nanosec))

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith("collision_node"):
                values = {kv.key: kv.value for kv in status.values}
                values["_level"] = (
                    int.from_bytes(status.level, "little")
                    if isinstance(status.level, bytes)
                    else int(status.level)
                )
                values["_message"] = status.message
                self.diagnostics.append(values)

    def spin(self, seconds: float, until=None) -> bool:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            if until is not None and until():
                return True
            self.executor.spin_once(timeout_sec=0.02)
        return bool(until and until())

    def wait_matched(self, timeout: float = 180.0) -> None:
        # Only a guard against a hang: a first start after a code change compiles the kernels
        # (minutes on a loaded 2-core machine) before the node subscribes.
        assert self.spin(timeout, lambda: self.pub.get_subscription_count() > 0), (
            "collision_node never subscribed"
        )

    def send_until_answered(
        self, data: bytes, stamp_ns: int, timeout: float = 20.0
    ) -> CollisionPredictionArray:
        """Publish raw bytes (re-sent each second: the first best-effort sample can be lost)
        until a prediction stamped `stamp_ns` arrives; returns it."""

        def answer():
            for _, msg in reversed(self.predictions):
                if msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == stamp_ns:
                    return msg
            return None

        deadline = time.monotonic() + timeout
        self.sends = 0  # how often it went out (a re-sent message counts its rejections again)
        while time.monotonic() < deadline:
            self.pub.publish(data)
            self.sends += 1
            if self.spin(min(2.0, deadline - time.monotonic()), lambda: answer() is not None):
                return answer()
        raise AssertionError(f"no prediction stamped {stamp_ns} within {timeout} s")

    def last_diagnostics(self, timeout: float = 5.0, after: int | None = None) -> dict:
        start = len(self.diagnostics) if after is None else after
        assert self.spin(timeout, lambda: len(self.diagnostics) > start), "no /diagnostics"
        return self.diagnostics[-1]

    def now_ns(self) -> int:
        return self.node.get_clock().now().nanoseconds

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


def stamp_of(msg) -> int:
    """Header stamp in ns of a prediction message (or the stamp itself, raw mode)."""
    if isinstance(msg, int):
        return msg
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
