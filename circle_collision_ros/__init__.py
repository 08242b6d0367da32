"""Predict when moving circles and spheres will touch (ROS 2 package)."""
