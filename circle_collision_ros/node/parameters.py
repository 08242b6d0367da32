"""The collision node's parameters: declarations with descriptors, and validation.

Validation is pure (a reason string or None) and runs in the node's on-set
callback; applying a change happens only in the post-set callback, so a
refused value never touches the node's state. config/collision_node.yaml holds
the same defaults for `--ros-args --params-file`.

Two rclpy behaviours shape the declarations (tests/node/test_parameters.py):

- Every parameter has a value. rclpy's get_parameters service answers a whole
  request with an empty list if one name in it has no value, so a parameter
  declared by type only makes `ros2 param dump` print `{}`. An empty list has
  no element type in rclpy (it infers BYTE_ARRAY from `[]`) and rcl reads `[]`
  in a params file or `-p name:=[]` as "no value"; list parameters whose
  default is empty are therefore dynamically typed and always hold a list
  (empty: `[]`), checked here to be a list of the right element type.
- Integers are accepted where a double is expected (`-p horizon:=8`, `horizon: 8`
  in YAML, `ros2 param set ... horizon 8`): double parameters are declared with
  dynamic typing, any int or float (never bool or string) is checked against
  the range here, and an integer is stored as the equal double.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter

from circle_collision_ros.pipeline.predictor import HorizonLimits
from circle_collision_ros.pipeline.static_scene import parse_static_polygons


@dataclass(frozen=True)
class ParamSpec:
    name: str
    type_: Parameter.Type
    default: Any
    description: str
    read_only: bool = False
    float_range: tuple[float, float] | None = None
    int_range: tuple[int, int] | None = None

    @property
    def dynamically_typed(self) -> bool:
        """Declared with dynamic typing: doubles (ints accepted) and lists with an empty default."""
        return self.type_ == Parameter.Type.DOUBLE or self.default == []

    def descriptor(self, read_only: bool | None = None) -> ParameterDescriptor:
        d = ParameterDescriptor(name=self.name, type=self.type_.value, description=self.description,
                                read_only=self.read_only if read_only is None else read_only,
                                dynamic_typing=self.dynamically_typed)
        if self.float_range:
            d.floating_point_range = [FloatingPointRange(from_value=self.float_range[0],
                                                         to_value=self.float_range[1], step=0.0)]
        if self.int_range:
            d.integer_range = [IntegerRange(from_value=self.int_range[0],
                                            to_value=self.int_range[1], step=1)]
        return d


PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "state_topics",
        Parameter.Type.STRING_ARRAY,
        ["circle_states"],
        "Topics carrying circle_collision_msgs/CircleStateArray; merged into one scene by id.",
        read_only=True,
    ),
    ParamSpec("single_state_topics", Parameter.Type.STRING_ARRAY, [],
              "Topics carrying one circle_collision_msgs/CircleState each.", read_only=True),
    ParamSpec(
        "odometry_topics",
        Parameter.Type.STRING_ARRAY,
        [],
        "Topics carrying nav_msgs/Odometry, one robot each; the body id is the topic's namespace.",
        read_only=True,
    ),
    ParamSpec("odometry_radius", Parameter.Type.DOUBLE, 0.5,
              "Radius in m of the bodies of odometry_topics.", read_only=True,
              float_range=(0.0, 1e6)),
    ParamSpec(
        "odometry_radii",
        Parameter.Type.DOUBLE_ARRAY,
        [],
        "Per-topic radii in m, one per odometry_topics entry; empty: odometry_radius for all.",
        read_only=True,
    ),
    ParamSpec("ego_ids", Parameter.Type.STRING_ARRAY, [],
              "Ego body ids: only pairs with at least one of them are evaluated and published "
              "(the broad phase skips the others), and only they against static geometry; "
              "empty: every pair.", read_only=True),
    ParamSpec("map_topic", Parameter.Type.STRING, "",
              "nav_msgs/OccupancyGrid topic (transient local) whose occupied cells are static "
              "obstacles, id_b 'map'; empty: none. 2-D only.", read_only=True),
    ParamSpec("map_occupied_threshold", Parameter.Type.INTEGER, 65,
              "Occupancy value (0..100) from which a map cell is occupied.", read_only=True,
              int_range=(0, 100)),
    ParamSpec("map_unknown_is_occupied", Parameter.Type.BOOL, False,
              "Treat unknown map cells (-1) as occupied.", read_only=True),
    ParamSpec("polygon_topics", Parameter.Type.STRING_ARRAY, [],
              "geometry_msgs/PolygonStamped topics, one solid obstacle each, named by the "
              "topic's namespace; an empty polygon removes it. 2-D only.", read_only=True),
    ParamSpec("static_polygons", Parameter.Type.STRING, "",
              'Keep-out zones as JSON: {"name": [[x, y], [x, y], [x, y]], ...} in the scene '
              "frame; solid polygons. 2-D only.", read_only=True),
    ParamSpec(
        "frame_id",
        Parameter.Type.STRING,
        "",
        "Frame every state must be in; empty adopts the first frame seen "
        "(no tf: others are rejected).",
        read_only=True,
    ),
    ParamSpec("dimensions", Parameter.Type.INTEGER, 2,
              "2: circles in the plane (z ignored); 3: spheres.", read_only=True, int_range=(2, 3)),
    ParamSpec("horizon", Parameter.Type.DOUBLE, 5.0,
              "Prediction horizon in s: later contacts are not reported.",
              float_range=(HorizonLimits.MIN_S, HorizonLimits.MAX_S)),
    ParamSpec(
        "probability_threshold",
        Parameter.Type.DOUBLE,
        0.01,
        "In (0, 1]: an uncertain pair (covariance given) whose mean paths miss is reported when "
        "its probability of contact within the horizon reaches this (a deferred pair: when the "
        "top of its interval does); plausible_time_to_collision "
        "is the first time the overlap probability does.",
        float_range=(0.0, 1.0),
    ),
    ParamSpec(
        "uncertain_pair_budget",
        Parameter.Type.INTEGER,
        4,
        "Uncertain pairs given the full probability evaluation per prediction, longest-waiting "
        "first, then earliest possible contact (0: all); the others are reported with a "
        "cheap certified interval of their states as probability +- bound (deferred, counted "
        "in /diagnostics). A count, so replay is bit-identical.",
        read_only=True,
        int_range=(0, 1_000_000),
    ),
    ParamSpec(
        "probability_tolerance",
        Parameter.Type.DOUBLE,
        0.005,
        "In [0, 0.1]: the stated bound (collision_probability_bound) a full probability "
        "evaluation may reach where that saves work (also the service's); 0: every pair at "
        "the per-pair accuracy (the core's default).",
        read_only=True,
        float_range=(0.0, 0.1),
    ),
    ParamSpec(
        "use_covariance",
        Parameter.Type.BOOL,
        True,
        "false: every body is predicted on its mean state; covariances are ignored (a warning "
        "names each topic that sends them) and the probability kernels are never compiled, "
        "so a first start is faster.",
        read_only=True,
    ),
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
              "New ids beyond this many are rejected (bounds memory and compute), as are service "
              "requests of more circles.", read_only=True,
              int_range=(1, 1_000_000)),
    ParamSpec(
        "state_reliability",
        Parameter.Type.STRING,
        "best_effort",
        "QoS of the input subscriptions: best_effort (matches every publisher; frames may be "
        "lost) or reliable (keep last 1 per array topic: the newest frame, delivered; matches "
        "reliable publishers only).",
        read_only=True,
    ),
    ParamSpec(
        "record_path",
        Parameter.Type.STRING,
        "",
        "Bag directory to record inputs and predictions to (MCAP, rosbag2 layout); empty: off.",
        read_only=True,
    ),
    ParamSpec(
        "autostart",
        Parameter.Type.BOOL,
        True,
        "Configure and activate at start (the node runs as an unmanaged one would); false: "
        "start unconfigured and wait for the lifecycle transitions (ros2 lifecycle set, a "
        "lifecycle manager).",
        read_only=True,
    ),
)
SPECS = {spec.name: spec for spec in PARAMS}
STATE_RELIABILITY = ("best_effort", "reliable")
_ELEMENT_TYPES = {Parameter.Type.STRING_ARRAY: (str,), Parameter.Type.DOUBLE_ARRAY: (int, float)}


def declare_all(node: Node) -> None:
    """Declare every parameter with its descriptor (overrides from --params-file apply).

    Afterwards every parameter has a value (see the module docstring); an
    integer given for a run-time double that passes validation is stored as a
    double (a read-only one keeps the integer; value_of reads it as float).
    """
    for spec in PARAMS:
        if spec.default == []:
            _declare_list_with_empty_default(node, spec)
        else:
            node.declare_parameter(spec.name, spec.default, spec.descriptor())
        value = node.get_parameter(spec.name).value
        if (
            spec.type_ == Parameter.Type.DOUBLE
            and _is_integer(value)
            and not spec.read_only
            and validate(spec.name, value) is None
        ):
            node.set_parameters([Parameter(spec.name, Parameter.Type.DOUBLE, float(value))])


def _declare_list_with_empty_default(node: Node, spec: ParamSpec) -> None:
    """Declare `spec` so that it holds a list even when empty, read-only if the spec says so.

    rcl turns an empty override (`[]`) into "not set", which would leave the
    parameter without a value; a read-only parameter cannot be fixed after its
    declaration, so the override is read through a writable declaration first.
    """
    given = node.declare_parameter(spec.name, [], spec.descriptor(read_only=False)).value
    node.undeclare_parameter(spec.name)
    value = [] if given is None else given
    node.declare_parameter(spec.name, value, spec.descriptor(), ignore_override=True)


def _is_integer(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def value_of(node: Node, name: str) -> Any:
    """Current value in its declared type (an int given for a double as float, lists as list)."""
    value = node.get_parameter(name).value
    spec = SPECS[name]
    if value is None:
        return spec.default
    if spec.type_ == Parameter.Type.DOUBLE and _is_number(value):
        return float(value)
    if (
        spec.type_ == Parameter.Type.DOUBLE_ARRAY
        and isinstance(value, (list, tuple))
        and all(_is_number(v) for v in value)
    ):
        return [float(v) for v in value]
    if spec.type_ in _ELEMENT_TYPES and isinstance(value, (list, tuple)):
        return list(value)
    return value  # as given, for validate() to refuse


def coerce_integers(params: list[Parameter]) -> list[Parameter]:
    """Pre-set callback: an integer set at run time for a double parameter becomes that double.

    Anything else is passed unchanged for validate() to judge.
    """
    out = []
    for param in params:
        spec = SPECS.get(param.name)
        if spec is not None and spec.type_ == Parameter.Type.DOUBLE and _is_integer(param.value):
            param = Parameter(param.name, Parameter.Type.DOUBLE, float(param.value))
        out.append(param)
    return out


def validate(name: str, value: Any) -> str | None:
    """Why `value` is not acceptable for parameter `name`, or None.

    Ranges in the descriptors are enforced by rclpy as well; this adds the
    checks descriptors cannot express (types of dynamically typed parameters,
    finite, topic names).
    """
    spec = SPECS.get(name)
    if spec is None:
        return None  # not ours (e.g. qos_overrides.*, use_sim_time)
    if spec.type_ == Parameter.Type.DOUBLE:
        if not _is_number(value) or not math.isfinite(value):
            return f"{name} must be a finite number, got {value!r}"
        low, high = spec.float_range
        if not (low <= value <= high):
            return f"{name} must be in [{low}, {high}], got {value}"
        if name == "probability_threshold" and value <= 0.0:  # a probability of 0 is always reached
            return f"probability_threshold must be in (0, 1], got {value}"
    elements = _ELEMENT_TYPES.get(spec.type_)
    if elements is not None:
        if not isinstance(value, (list, tuple)) or not all(
            isinstance(v, elements) and not isinstance(v, bool) for v in value
        ):
            kind = "strings" if spec.type_ == Parameter.Type.STRING_ARRAY else "numbers"
            return f"{name} must be a list of {kind}, got {value!r}"
    if name == "odometry_radii" and any(not math.isfinite(r) or r < 0.0 for r in value):
        return f"odometry_radii must be finite and >= 0, got {list(value)!r}"
    if (name in ("state_topics", "single_state_topics", "odometry_topics", "polygon_topics")
            and value is not None):
        if any(not t or " " in t for t in value):
            return f"{name} has an empty or malformed topic name: {list(value)!r}"
    if name == "static_polygons" and isinstance(value, str):
        try:
            parse_static_polygons(value)
        except ValueError as exc:
            return str(exc)
    if name == "state_reliability" and value not in STATE_RELIABILITY:
        return f"state_reliability must be one of {', '.join(STATE_RELIABILITY)}, got {value!r}"
    if name == "dimensions" and value not in (2, 3):
        return f"dimensions must be 2 or 3, got {value!r}"
    return None
