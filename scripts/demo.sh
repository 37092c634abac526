#!/usr/bin/env bash
# Set up .venv (first run) and run the main job: solve the example measurement record against its truth
# and print the pose-solver benchmark summary.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/venv.sh bench
.venv/bin/monoguide solve examples/example-record.json
exec .venv/bin/python benchmarks/bench_pose.py --quick
