"""Demo: a synthetic moving scene (demo_scene) and the node + scene + live table runner (run)."""
