"""collision_node's parameters as the `ros2 param` tools see them.

Guarantees proved here (rclpy clients doing what ros2cli does):
- `ros2 param dump`: list_parameters, then ONE get_parameters request with all
  names, answers a value for every parameter (rclpy answers the whole batch
  with an empty list if one parameter has no value);
- the dump written as YAML the way `ros2 param dump` writes it starts a node
  through `--params-file`, and that node dumps the same values again;
- integers are accepted for double parameters on the command line
  (`-p horizon:=8`), in YAML (`horizon: 8`) and at run time (set_parameters
  service with an INTEGER value), stored as doubles; strings and booleans are
  still refused.
"""
from __future__ import annotations

import math

from pathlib import Path

import pytest
import rclpy
import yaml
from rcl_interfaces.msg import Parameter as ParameterMsg, ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters
from rclpy.context import Context
from rclpy.parameter import PARAMETER_SEPARATOR_STRING

from circle_collision_ros.node.collision_node import CollisionNode
from tests.node.conftest import spin_until

NODE = "/collision_node"


def _call(client_node, server_node, srv_type, name: str, request):
    client = client_node.create_client(srv_type, name)
    try:
        assert spin_until(client_node, client.service_is_ready, 20.0, (server_node,)), name
        future = client.call_async(request)
        assert spin_until(client_node, future.done, 20.0, (server_node,)), f"{name}: no answer"
        return future.result()
    finally:
        client_node.destroy_client(client)


def _python_value(value: ParameterValue):
    """ros2param's get_value: the Python value of a ParameterValue (None if not set)."""
    return {
        ParameterType.PARAMETER_BOOL: lambda v: v.bool_value,
        ParameterType.PARAMETER_INTEGER: lambda v: v.integer_value,
        ParameterType.PARAMETER_DOUBLE: lambda v: v.double_value,
        ParameterType.PARAMETER_STRING: lambda v: v.string_value,
        ParameterType.PARAMETER_BYTE_ARRAY: lambda v: list(v.byte_array_value),
        ParameterType.PARAMETER_BOOL_ARRAY: lambda v: list(v.bool_array_value),
        ParameterType.PARAMETER_INTEGER_ARRAY: lambda v: list(v.integer_array_value),
        ParameterType.PARAMETER_DOUBLE_ARRAY: lambda v: list(v.double_array_value),
        ParameterType.PARAMETER_STRING_ARRAY: lambda v: list(v.string_array_value),
    }.get(value.type, lambda v: None)(value)


def param_dump(client_node, server_node) -> dict:
    """What `ros2 param dump /collision_node` fetches: {name: value} for every parameter."""
    names = _call(client_node, server_node, ListParameters, f"{NODE}/list_parameters",
                  ListParameters.Request()).result.names
    values = _call(client_node, server_node, GetParameters, f"{NODE}/get_parameters",
                   GetParameters.Request(names=list(names))).values
    assert len(values) == len(names), \
        f"get_parameters answered {len(values)} values for {len(names)} names"
    dump = {name: _python_value(v) for name, v in zip(names, values)}
    unset = [n for n, v in dump.items() if v is None]
    assert not unset, f"parameters without a value: {unset}"
    return dump


def dump_yaml(dump: dict) -> str:
    """The YAML `ros2 param dump` writes: dotted names nested, under <node>: ros__parameters:."""
    nested: dict = {}
    for name in sorted(dump):
        level = nested
        *parents, leaf = name.split(PARAMETER_SEPARATOR_STRING)
        for part in parents:
            level = level.setdefault(part, {})
        level[leaf] = dump[name]
    return yaml.dump({NODE: {"ros__parameters": nested}}, default_flow_style=False)


def _start(args: list[str]) -> tuple[Context, CollisionNode]:
    context = Context()
    rclpy.init(context=context, args=["collision_node", "--ros-args", *args])
    try:
        return context, CollisionNode(context=context)
    except BaseException:
        context.try_shutdown()
        raise


def test_dump_has_every_value_and_round_trips_through_params_file(ros_node, tmp_path: Path) -> None:
    context, node = _start([])
    try:
        first = param_dump(ros_node, node)
    finally:
        node.destroy_node()
        context.try_shutdown()
    assert first["single_state_topics"] == [] and first["state_topics"] == ["circle_states"]
    assert first["horizon"] == 5.0 and first["probability_threshold"] == 0.01
    path = tmp_path / "dump.yaml"
    path.write_text(dump_yaml(first))
    # The second node has the first's name: until the client's graph has dropped the first,
    # its services look ready, and a request could go out before the second's reader matched
    # (seen once under a loaded CI run: "list_parameters: no answer").
    assert spin_until(ros_node, lambda: "collision_node" not in ros_node.get_node_names(), 20.0)
    context, node = _start(["--params-file", str(path)])
    try:
        second = param_dump(ros_node, node)
        assert node.predictor.config.horizon == 5.0
    finally:
        node.destroy_node()
        context.try_shutdown()
    assert second == first


def test_non_default_dump_round_trips(ros_node, tmp_path: Path) -> None:
    """Non-empty list and changed values survive the round trip too."""
    context, node = _start(
        ["-p", "single_state_topics:=[robot_1/circle_state]", "-p", "horizon:=2.5", "-p",
         "frame_id:=map", "-p", "probability_threshold:=0.25"]
    )
    try:
        first = param_dump(ros_node, node)
    finally:
        node.destroy_node()
        context.try_shutdown()
    assert first["single_state_topics"] == ["robot_1/circle_state"] and first["horizon"] == 2.5
    path = tmp_path / "dump.yaml"
    path.write_text(dump_yaml(first))
    # The second node has the first's name: until the client's graph has dropped the first,
    # its services look ready, and a request could go out before the second's reader matched
    # (seen once under a loaded CI run: "list_parameters: no answer").
    assert spin_until(ros_node, lambda: "collision_node" not in ros_node.get_node_names(), 20.0)
    context, node = _start(["--params-file", str(path)])
    try:
        assert param_dump(ros_node, node) == first
        assert "/robot_1/circle_state" in {s.topic_name for s in node.subscriptions}
    finally:
        node.destroy_node()
        context.try_shutdown()


@pytest.mark.parametrize(
    "args", [["-p", "horizon:=8"], ["-p", "single_state_topics:=[]", "-p", "horizon:=8"], "yaml"]
)
def test_integer_for_double_at_start(args, tmp_path: Path) -> None:
    if args == "yaml":
        path = tmp_path / "p.yaml"
        path.write_text(
            "collision_node:\n  ros__parameters:\n    horizon: 8\n    stale_timeout: 3\n"
            "    single_state_topics: []\n"
        )
        args = ["--params-file", str(path)]
    context, node = _start(args)
    try:
        assert node.predictor.config.horizon == 8.0
        assert isinstance(node.predictor.config.horizon, float)
        assert node.get_parameter("horizon").type_.name == "DOUBLE"
        assert node.get_parameter("single_state_topics").value == []
    finally:
        node.destroy_node()
        context.try_shutdown()


def test_integer_for_double_at_run_time_strings_refused(ros_node) -> None:
    context, node = _start([])
    try:

        def set_value(value: ParameterValue):
            request = SetParameters.Request(parameters=[ParameterMsg(name="horizon", value=value)])
            return _call(ros_node, node, SetParameters, f"{NODE}/set_parameters", request).results[
                0
            ]

        ok = set_value(ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=8))
        assert ok.successful, ok.reason
        assert node.predictor.config.horizon == 8.0
        assert node.get_parameter("horizon").type_.name == "DOUBLE"
        text = set_value(ParameterValue(type=ParameterType.PARAMETER_STRING, string_value="3"))
        assert not text.successful and "horizon must be a finite number" in text.reason
        flag = set_value(ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=True))
        assert not flag.successful
        too_big = set_value(
            ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=4000)
        )
        assert not too_big.successful and "3600" in too_big.reason
        assert node.predictor.config.horizon == 8.0
    finally:
        node.destroy_node()
        context.try_shutdown()


@pytest.mark.parametrize("value", ["soon", "true"])
def test_string_or_bool_for_double_refused_at_start(value: str) -> None:
    import os
    import subprocess
    import sys

    exe = os.path.join(sys.prefix, "lib", "circle_collision_ros", "collision_node")
    run = subprocess.run(
        [exe, "--ros-args", "-p", f"horizon:={value}"], capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 2, run.stdout + run.stderr
    assert "horizon must be a finite number" in run.stderr and "Traceback" not in run.stderr


def test_probability_threshold_is_in_zero_exclusive_to_one(ros_node) -> None:
    """probability_threshold: (0, 1], validated like the other doubles (an integer 1 is the
    double 1.0); a valid change reaches the predictor, a refused one changes nothing."""
    context, node = _start(["-p", "probability_threshold:=0.05"])
    try:
        assert node.predictor.config.probability_threshold == 0.05

        def set_value(value: ParameterValue):
            request = SetParameters.Request(
                parameters=[ParameterMsg(name="probability_threshold", value=value)]
            )
            return _call(ros_node, node, SetParameters, f"{NODE}/set_parameters", request).results[
                0
            ]

        for bad in (0.0, -0.1, 1.5, math.nan):
            result = set_value(
                ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=bad)
            )
            assert not result.successful and "probability_threshold" in result.reason, bad
        zero = set_value(ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=0.0))
        assert "(0, 1]" in zero.reason
        assert node.predictor.config.probability_threshold == 0.05
        one = set_value(ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=1))
        assert one.successful, one.reason
        assert node.predictor.config.probability_threshold == 1.0
        assert node.get_parameter("probability_threshold").type_.name == "DOUBLE"
    finally:
        node.destroy_node()
        context.try_shutdown()
