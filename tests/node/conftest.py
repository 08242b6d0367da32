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


def reader_matched(node: Node, topic: str, publishers: int = 1) -> Callable[[], bool]:
    """A condition for spin_until: `node`'s subscription on `topic` (resolved name) has matched
    at least `publishers` writers.

    A publisher's get_subscription_count() can report the match before the subscriber's
    side has matched it, and a best-effort reader drops samples from a writer it has not
    matched yet: wait on the reader's side before publishing once.
    """
    resolved = node.resolve_topic_name(topic)
    (sub,) = [s for s in node.subscriptions if s.topic_name == resolved]
    return lambda: sub.get_publisher_count() >= publishers
