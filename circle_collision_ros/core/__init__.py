"""ROS-free numerical core: first-contact times for bodies with constant acceleration.

Nothing in this package imports rclpy or any ROS message type, so it can be
used and tested on a machine without ROS.
"""
from circle_collision_ros.core.narrow_phase import time_to_collision
from circle_collision_ros.core.contact import contact_details

__all__ = ["time_to_collision", "contact_details"]
from circle_collision_ros.core.pair_predictions import PairPredictions, predict_all_pairs
from circle_collision_ros.core.scene import Scene

__all__ += ["PairPredictions", "predict_all_pairs", "Scene"]
