"""Shared start-up of the package's executables: --help, local DDS, clean shutdown."""
from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable

import rclpy
from rclpy.exceptions import NameValidationException, ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node


def parse_args(argv: list[str], description: str,
               add_arguments: Callable[[argparse.ArgumentParser], None] | None = None
               ) -> argparse.Namespace:
    """Our own options (and --help); ROS arguments after --ros-args are left to rclpy."""
    parser = argparse.ArgumentParser(
        prog=os.path.basename(argv[0]) if argv else None, description=description,
        epilog="ROS arguments follow --ros-args, e.g. --ros-args -p horizon:=3.0 "
               "--params-file config/collision_node.yaml")
    if add_arguments is not None:
        add_arguments(parser)
    return parser.parse_args(rclpy.utilities.remove_ros_args(argv)[1:])


def keep_ros_traffic_local() -> None:
    """Default DDS discovery to this machine unless the user chose otherwise.

    Fast DDS otherwise multicasts on every interface; set
    ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET to talk to other machines.
    """
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


def spin_node(make_node: Callable[[], Node], argv: list[str], name: str) -> int:
    """rclpy.init, build the node, spin until Ctrl-C/SIGTERM, shut down cleanly.

    Start-up errors (invalid parameters, bad topic names, unusable paths) print
    one line naming the problem and return exit code 2, without a traceback.
    """
    keep_ros_traffic_local()
    rclpy.init(args=argv)
    node = None
    try:
        node = make_node()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, OSError, ParameterException, NameValidationException) as exc:
        print(f"{name}: {exc}", file=sys.stderr)
        return 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
