"""Recording to MCAP in the rosbag2 layout, reading it back, and offline replay.

Modules (import from them; this package imports none: the pytest plugin loads
it in every pytest run, which must not pull in rclpy, numba or the pipeline):

- ``bag_recorder``: the node's MCAP recorder (rosbag2 layout, metadata.yaml);
- ``bag_reader``: reads such a bag back (``tolerant``: a truncated one up to its last chunk);
- ``ros_type_definitions``: the full ``ros2msg`` definition texts (and type hashes) recorded as
  schemas;
- ``replay_engine``: replays one bag through CollisionPredictor and compares (replay_bag);
- ``corpus``: replays many bags in parallel (local workers or Dask) and summarises;
- ``replay``: the ``replay`` command (one bag, a corpus, or ``--publish``);
- ``pytest_plugin``: recorded runs as tests (``--replay-bags``, the ``replay_bag`` fixture).
"""

__all__: list[str] = []
