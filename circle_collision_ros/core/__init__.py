"""ROS-free numerical core: first-contact times for bodies with constant acceleration.

Nothing in this package imports rclpy or any ROS message type, so it can be
used and tested on a machine without ROS.  Its parts: ``narrow`` (one pair or
a batch), ``broad`` (culling), ``scene`` (whole scenes, incremental streams)
and ``uncertainty`` (probability of contact).
"""
from circle_collision_ros.core.narrow import contact_details, time_to_collision
from circle_collision_ros.core.scene import PairPredictions, Scene, predict_all_pairs

__all__ = ["time_to_collision", "contact_details", "PairPredictions", "predict_all_pairs", "Scene"]
