"""Edits of recorded records, for tests that need a recording replay must reject."""
from __future__ import annotations

import math

import numpy as np


def nudge_first_contact(record) -> bytes:
    """Move the first finite time_to_collision in a prediction record up by one ulp."""
    from rclpy.serialization import deserialize_message, serialize_message

    from circle_collision_msgs.msg import CollisionPredictionArray
    from circle_collision_ros.recording.replay import RecordedTypes

    if record.type_name != RecordedTypes.PREDICTIONS:
        return record.data
    msg = deserialize_message(record.data, CollisionPredictionArray)
    finite = [p for p in msg.predictions if 0 < p.time_to_collision < math.inf]
    if not finite:
        return record.data
    finite[0].time_to_collision = float(np.nextafter(finite[0].time_to_collision, math.inf))
    return serialize_message(msg)
