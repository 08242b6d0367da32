"""Recording to MCAP in the rosbag2 layout, reading it back, and offline replay."""
