"""Received circle states to predictions, without a ROS graph (shared by node, service and replay)."""
