"""Fixtures for tests that talk over real DDS on localhost."""
from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node


@pytest.fixture
def ros_context() -> Iterator[Context]:
    """A fresh rclpy context per test, shut down afterwards."""
    context = Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        context.try_shutdown()


@pytest.fixture
def ros_node(ros_context: Context) -> Iterator[Node]:
    node = rclpy.create_node("test_client", context=ros_context)
    try:
        yield node
    finally:
        node.destroy_node()


def spin_until(node: Node, done: Callable[[], bool], timeout: float = 10.0,
               extra_nodes: tuple[Node, ...] = ()) -> bool:
    """Spin `node` (and `extra_nodes`) until `done()` or `timeout` s; returns done()."""
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    for other in extra_nodes:
        executor.add_node(other)
    deadline = time.monotonic() + timeout
    try:
        while not done() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.shutdown()
    return done()
