"""Shared start-up of the package's executables: --help, DDS defaults, clean shutdown."""
from __future__ import annotations

import argparse
import os
import signal
import sys
from collections.abc import Callable
from pathlib import Path

import rclpy
from rclpy.exceptions import NameValidationException, ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions


COLLISION_NODE_EPILOG = ("ROS arguments follow --ros-args, e.g. --ros-args -p horizon:=3.0 "
                         "--params-file config/collision_node.yaml")


def parse_args(argv: list[str], description: str,
               add_arguments: Callable[[argparse.ArgumentParser], None] | None = None,
               epilog: str = COLLISION_NODE_EPILOG) -> argparse.Namespace:
    """Our own options (and --help); ROS arguments after --ros-args are left to rclpy.

    epilog : the text after the options, e.g. the executable's ROS parameters
        (kept as written: line breaks matter).
    """
    parser = argparse.ArgumentParser(
        prog=os.path.basename(argv[0]) if argv else None, description=description,
        epilog=epilog, formatter_class=argparse.RawDescriptionHelpFormatter)
    if add_arguments is not None:
        add_arguments(parser)
    return parser.parse_args(rclpy.utilities.remove_ros_args(argv)[1:])


class TransportProfile:
    """The shipped Fast DDS profile for large scenes (config/fastdds_large_scenes.xml)."""

    ENV = "FASTDDS_DEFAULT_PROFILES_FILE"
    # Fast DDS 2.x name, deprecated in 3.x (it logs a warning); a user who set it chose a profile.
    DEPRECATED_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"
    FILE_NAME = "fastdds_large_scenes.xml"
    PACKAGE = "circle_collision_ros"

    @classmethod
    def path(cls) -> Path | None:
        """The installed profile: the package's share/ (colcon or venv), else the source config/."""
        candidates = []
        try:
            from ament_index_python.packages import get_package_share_directory

            candidates.append(Path(get_package_share_directory(cls.PACKAGE)) / "config")
        except (ImportError, LookupError, KeyError, ValueError, OSError):
            pass  # no ament index in this environment (e.g. AMENT_PREFIX_PATH unset)
        candidates.append(Path(sys.prefix) / "share" / cls.PACKAGE / "config")
        candidates.append(Path(__file__).resolve().parent.parent / "config")  # editable/source tree
        for folder in candidates:
            if (folder / cls.FILE_NAME).is_file():
                return folder / cls.FILE_NAME
        return None


def keep_ros_traffic_local() -> None:
    """Default DDS discovery to this machine unless the user chose otherwise.

    Fast DDS otherwise multicasts on every interface; set
    ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET to talk to other machines.
    """
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


def use_large_scene_transport() -> str | None:
    """Load the shipped large-scene Fast DDS profile unless the user chose a profile.

    Must run before rclpy.init (Fast DDS reads the file when the participant is
    created). Returns the profile file in force, or None if there is none. The
    user's FASTDDS_DEFAULT_PROFILES_FILE (or the deprecated FASTRTPS_ name) always wins.
    """
    for name in (TransportProfile.ENV, TransportProfile.DEPRECATED_ENV):
        if os.environ.get(name):
            return os.environ[name]
    path = TransportProfile.path()
    if path is None:
        return None
    os.environ[TransportProfile.ENV] = str(path)
    return str(path)


def apply_ros_environment_defaults() -> None:
    """What every executable sets before rclpy.init: local discovery, large-scene transport."""
    keep_ros_traffic_local()
    use_large_scene_transport()


class ShutdownSignal:
    """Seconds a spinning executable may take to notice Ctrl-C/SIGTERM (its wait is cut to this)."""

    POLL_S = 0.1


def _raise_keyboard_interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def spin_node(make_node: Callable[[], Node], argv: list[str], name: str) -> int:
    """rclpy.init, build the node, spin until Ctrl-C/SIGTERM, shut down cleanly.

    Shutdown order (lifecycle style): the node is destroyed -- its threads
    joined, its last messages (e.g. the markers' DELETEALL) published, its
    recording closed -- while the context is still valid, then the context is
    shut down. rclpy's own signal handlers would shut the context down first,
    inside the signal (so a marker publication at exit failed with "publisher's
    context is invalid"); they are not installed, and Ctrl-C/SIGTERM raise
    KeyboardInterrupt in the spinning thread instead. The SIGINT handler is set
    explicitly, as rclpy's would be: Python keeps SIGINT ignored when the
    process inherited it ignored (started in the background by a
    non-interactive shell, e.g. `nohup ... &` or a test loop run with `&`),
    and a node stopped with SIGINT (Ctrl-C, `ros2 launch`) then ran on.

    Start-up errors (invalid parameters, bad topic names, unusable paths) print
    one line naming the problem and return exit code 2, without a traceback.
    """
    apply_ros_environment_defaults()
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    previous_term = signal.signal(signal.SIGTERM, _raise_keyboard_interrupt)
    previous_int = signal.signal(signal.SIGINT, _raise_keyboard_interrupt)
    node = None
    try:
        node = make_node()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        # A bounded wait: the Python signal handler runs only between waits.
        while rclpy.ok():
            executor.spin_once(timeout_sec=ShutdownSignal.POLL_S)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, OSError, ParameterException, NameValidationException) as exc:
        print(f"{name}: {exc}", file=sys.stderr)
        return 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        signal.signal(signal.SIGTERM, previous_term)
        signal.signal(signal.SIGINT, previous_int)
    return 0
