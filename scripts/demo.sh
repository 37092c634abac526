#!/usr/bin/env bash
# Set up .venv (first run) and run the main job: `monoguide simulate` on the simulated roof cell — the
# simulated PLC, robot controller and camera with the service against them over the real transports — and
# print the grasp error, the cycle-time split, the errors by code and the service's memory.
# Extra arguments go to `monoguide simulate`, e.g. `bash scripts/demo.sh --cycles 8 --robot kuka`.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/venv.sh test
exec "$venv"/bin/monoguide simulate --config config/sim-cell.toml "$@"
