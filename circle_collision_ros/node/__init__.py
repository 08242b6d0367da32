"""The rclpy collision_node: subscriptions, publishers, service, parameters, markers, diagnostics."""
