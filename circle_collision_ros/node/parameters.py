"""The collision node's parameters: declarations with descriptors, and validation.

Validation is pure (a reason string or None) and runs in the node's on-set
callback; applying a change happens only in the post-set callback, so a
refused value never touches the node's state. config/collision_node.yaml holds
the same defaults for `--ros-args --params-file`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter


@dataclass(frozen=True)
class ParamSpec:
    name: str
    type_: Parameter.Type
    default: Any
    description: str
    read_only: bool = False
    float_range: tuple[float, float] | None = None
    int_range: tuple[int, int] | None = None

    def descriptor(self) -> ParameterDescriptor:
        d = ParameterDescriptor(name=self.name, type=self.type_.value, description=self.description,
                                read_only=self.read_only)
        if self.float_range:
            d.floating_point_range = [FloatingPointRange(from_value=self.float_range[0],
                                                         to_value=self.float_range[1], step=0.0)]
        if self.int_range:
            d.integer_range = [IntegerRange(from_value=self.int_range[0],
                                            to_value=self.int_range[1], step=1)]
        return d


PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("state_topics", Parameter.Type.STRING_ARRAY, ["circle_states"],
              "Topics carrying circle_collision_msgs/CircleStateArray; merged into one scene by id.",
              read_only=True),
    ParamSpec("single_state_topics", Parameter.Type.STRING_ARRAY, [],
              "Topics carrying one circle_collision_msgs/CircleState each.", read_only=True),
    ParamSpec("frame_id", Parameter.Type.STRING, "",
              "Frame every state must be in; empty adopts the first frame seen (no tf: others are rejected).",
              read_only=True),
    ParamSpec("dimensions", Parameter.Type.INTEGER, 2,
              "2: circles in the plane (z ignored); 3: spheres.", read_only=True, int_range=(2, 3)),
    ParamSpec("horizon", Parameter.Type.DOUBLE, 5.0,
              "Prediction horizon in s: later contacts are not reported.", float_range=(1e-3, 3600.0)),
    ParamSpec("report_all_pairs", Parameter.Type.BOOL, False,
              "Also list NO_CONTACT pairs (time +inf); only for scenes of at most 100 bodies."),
    ParamSpec("stale_timeout", Parameter.Type.DOUBLE, 2.0,
              "s without a new state after which a body is dropped.", float_range=(1e-3, 3600.0)),
    ParamSpec("publish_rate", Parameter.Type.DOUBLE, 0.0,
              "Hz; 0 publishes on every input change instead of at a fixed rate.",
              float_range=(0.0, 1000.0)),
    ParamSpec("marker_rate", Parameter.Type.DOUBLE, 10.0,
              "Hz at most for ~/markers; 0 disables markers.", float_range=(0.0, 1000.0)),
    ParamSpec("max_bodies", Parameter.Type.INTEGER, 10_000,
              "New ids beyond this many are rejected (bounds memory and compute).", read_only=True,
              int_range=(1, 1_000_000)),
    ParamSpec("record_path", Parameter.Type.STRING, "",
              "Bag directory to record inputs and predictions to (MCAP, rosbag2 layout); empty: off.",
              read_only=True),
)
SPECS = {spec.name: spec for spec in PARAMS}


def declare_all(node: Node) -> None:
    """Declare every parameter with its descriptor (overrides from --params-file apply)."""
    for spec in PARAMS:
        if spec.default == []:
            # An empty list has no element type; declare by type so a params file may set it.
            node.declare_parameter(spec.name, spec.type_, spec.descriptor())
        else:
            node.declare_parameter(spec.name, spec.default, spec.descriptor())


def value_of(node: Node, name: str) -> Any:
    """Current value, with the declared default for a typed-but-unset parameter."""
    try:
        value = node.get_parameter(name).value
    except ParameterUninitializedException:  # declared by type only and not overridden
        return SPECS[name].default
    return SPECS[name].default if value is None else value


def validate(name: str, value: Any) -> str | None:
    """Why `value` is not acceptable for parameter `name`, or None.

    Ranges in the descriptors are enforced by rclpy as well; this adds the
    checks descriptors cannot express (finite, > 0, topic names).
    """
    spec = SPECS.get(name)
    if spec is None:
        return None  # not ours (e.g. qos_overrides.*, use_sim_time)
    if spec.type_ == Parameter.Type.DOUBLE:
        if not isinstance(value, (int, float)) or not math.isfinite(value):
            return f"{name} must be a finite number, got {value!r}"
        low, high = spec.float_range
        if not (low <= value <= high):
            return f"{name} must be in [{low}, {high}], got {value}"
    if name in ("state_topics", "single_state_topics") and value is not None:
        if any(not t or " " in t for t in value):
            return f"{name} has an empty or malformed topic name: {list(value)!r}"
    if name == "dimensions" and value not in (2, 3):
        return f"dimensions must be 2 or 3, got {value!r}"
    return None
