"""Predict when moving circles and spheres will touch (ROS 2 package).

Subpackages, from the numbers outwards:

- ``core``: first-contact times, broad phase, incremental scene, probability of contact
  (numpy + numba, no ROS).
- ``pipeline``: received circle states to predictions without a ROS graph: CDR
  decoding/encoding, validation, the scene's bodies, the predictor the node,
  the service and replay share.
- ``node``: the rclpy ``collision_node`` (parameters, markers, diagnostics).
- ``recording``: MCAP recording in the rosbag2 layout, reading, offline replay.
- ``demo``: a synthetic scene publisher and the two-command demo.
"""

__all__ = ["core", "pipeline", "node", "recording", "demo"]  # subpackages; nothing is imported here
