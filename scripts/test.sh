#!/usr/bin/env bash
# Set up .venv (first run) and run the checks: ruff, the import-layer contracts, the test suite.
# Extra arguments go to pytest, e.g. `bash scripts/test.sh tests/solver -x`.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/venv.sh test
.venv/bin/ruff check .
.venv/bin/lint-imports
exec .venv/bin/python -m pytest "$@"
