"""Launch collision_node with the package's parameter file (ROS workspace users).

    ros2 launch circle_collision_ros collision_node.launch.py [demo:=true] [params_file:=...]
        [autostart:=false]

autostart:=false starts collision_node unconfigured, for a lifecycle manager (or
`ros2 lifecycle set`) to configure and activate; the default configures and activates it.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    default_params = os.path.join(get_package_share_directory("circle_collision_ros"),
                                  "config", "collision_node.yaml")
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="Parameter YAML for collision_node"),
        DeclareLaunchArgument("autostart", default_value="true",
                              description="Configure and activate collision_node at start"),
        DeclareLaunchArgument("demo", default_value="false",
                              description="Also start the synthetic demo_scene publisher"),
        Node(package="circle_collision_ros", executable="collision_node", name="collision_node",
             parameters=[LaunchConfiguration("params_file"),
                         {"autostart": LaunchConfiguration("autostart")}],
             output="screen"),
        Node(package="circle_collision_ros", executable="demo_scene", name="demo_scene",
             output="screen", condition=IfCondition(LaunchConfiguration("demo"))),
    ])
