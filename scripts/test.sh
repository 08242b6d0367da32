#!/usr/bin/env bash
# The README's test command: set up (idempotent, seconds when nothing changed), then
# run the whole suite. Extra arguments go to pytest, e.g. scripts/test.sh -k core -x
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
"$ROOT/scripts/bootstrap.sh"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST  # DDS stays on this machine
cd "$ROOT"
exec "$ROOT/.venv/bin/python" -m pytest "$@"
