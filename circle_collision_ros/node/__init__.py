"""The rclpy collision_node: subscriptions, publishers, service, parameters, markers, diagnostics.

Modules (import from them; this package imports none, so that importing one of
them does not load rclpy's node machinery through the others):

- ``collision_node``: the node and its ``main`` (console script ``collision_node``);
- ``parameters``: its ROS parameters: declarations with descriptors, and validation;
- ``markers``: RViz / Foxglove markers for the scene and its predicted contacts;
- ``input_loss``: inputs published but never received, counted per publisher (diagnostics).
"""

__all__: list[str] = []
