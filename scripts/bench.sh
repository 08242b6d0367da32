#!/usr/bin/env bash
# Regenerate the benchmark tables and plots (issue #7): set up (idempotent), then run
# bench/run_all.py. Arguments go to run_all.py, e.g. scripts/bench.sh --quick
# (see .venv/bin/python bench/run_all.py --help). Results: bench/results/.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
"$ROOT/scripts/bootstrap.sh"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST  # DDS stays on this machine (no multicast)
export MPLBACKEND=Agg
cd "$ROOT"
exec "$ROOT/.venv/bin/python" bench/run_all.py "$@"
