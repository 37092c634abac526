#!/usr/bin/env bash
# Set up .venv (first run) and run the checks: ruff, the import-layer contracts, the test suite.
# Extra arguments go to pytest, e.g. `bash scripts/test.sh tests/solver -x`.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/venv.sh test
.venv/bin/ruff check .
.venv/bin/lint-imports
# two workers, each test file on one of them (a file's tests share its loopback addresses and fixtures)
exec .venv/bin/python -m pytest -n 2 --dist loadfile "$@"
