#!/usr/bin/env bash
# Regenerate the benchmark tables and plots: set up (idempotent), then run bench/run_all.py,
# which writes every result under bench/results/ (summary.md first). Arguments go to it:
#   scripts/bench.sh --quick                 # small sizes, a few minutes -> bench/results/quick/
#   scripts/bench.sh --only uncertainty node # some sections (--list: the sections and their files)
# What each section measures: docs/benchmarks.md.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
"$ROOT/scripts/bootstrap.sh"
# benchmark-only dependencies (Box2D for bench_static's comparison), pinned
"$ROOT/.venv/bin/python" -m pip install --quiet -r "$ROOT/requirements-bench.txt"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST  # DDS stays on this machine (no multicast)
export MPLBACKEND=Agg
cd "$ROOT"
exec "$ROOT/.venv/bin/python" bench/run_all.py "$@"
