"""Edits of recorded records, for tests that need a recording replay must reject."""
from __future__ import annotations

import math

import numpy as np


def nudge_first_contact(record) -> bytes:
    """Move the first finite time_to_collision in a prediction record up by one ulp.

    Edits the bytes in place, so the record keeps the layout of its recorded schema
    (before or after the probability fields); checks that exactly that field changed.
    """
    import struct

    from circle_collision_ros.pipeline.prediction_codec import decode_prediction_array
    from circle_collision_ros.recording.replay_engine import RecordedLayout, RecordedTypes

    if record.type_name != RecordedTypes.PREDICTIONS:
        return record.data
    layout = RecordedLayout.has_uncertainty(record.schema)
    before = decode_prediction_array(record.data, uncertainty=layout)
    k = next(
        (k for k, p in enumerate(before.predictions) if 0 < p.time_to_collision < math.inf), None
    )
    if k is None:
        return record.data
    old = before.predictions[k].time_to_collision
    new = float(np.nextafter(old, math.inf))
    at = record.data.find(struct.pack("<d", old), 4)
    data = record.data[:at] + struct.pack("<d", new) + record.data[at + 8 :]
    after = decode_prediction_array(data, uncertainty=layout)
    rows = list(before.predictions)
    rows[k] = rows[k]._replace(time_to_collision=new)
    assert after == before._replace(predictions=tuple(rows)), "the nudge hit another field"
    return data
