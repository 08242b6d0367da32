"""Demo: a synthetic moving scene and the node + scene + live table runner.

Modules (import from them; both use rclpy, so this package imports neither):

- ``demo_scene``: publishes a synthetic moving scene (console script ``demo_scene``);
- ``run``: runs the node against the scene, shows the soonest contacts live, draws the scene
  (console script ``demo``).
"""

__all__: list[str] = []
