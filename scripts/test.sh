#!/usr/bin/env bash
# The README's test command: set up (idempotent, seconds when nothing changed; the numba
# kernels compile in parallel processes after a code change), then run the quick suite on
# every core (pytest-xdist; each worker has its own ROS domain id).
# Extra arguments go to pytest, e.g. scripts/test.sh -k core -x   (-n 0: in one process)
#   scripts/test.sh --stress   also the long stress, soak and reference runs (CI runs this)
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
"$ROOT/scripts/bootstrap.sh" --kernels
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST  # DDS stays on this machine
cd "$ROOT"
exec "$ROOT/.venv/bin/python" -m pytest -n auto "$@"
