#!/usr/bin/env bash
# The README's main command: set up (idempotent), then run the demo: collision_node
# against a synthetic scene for ~10 s, live table of the soonest contacts, PNG at the end.
# Options go to the demo, e.g. scripts/demo.sh --duration 30 --count 200 (see --help).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
"$ROOT/scripts/bootstrap.sh" --demo
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST  # DDS stays on this machine
cd "$ROOT"
exec "$ROOT/.venv/bin/python" -m circle_collision_ros.demo.run "$@"
