#!/usr/bin/env bash
# Set up .venv (first run; brought to the pins of constraints.txt on every run) and run the checks: ruff, the
# import-layer contracts, the test suite. MONOGUIDE_VENV: another venv (scripts/test-newest.sh).
# Extra arguments go to pytest, e.g. `bash scripts/test.sh tests/solver -x`.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/venv.sh test
"$venv"/bin/ruff check .
"$venv"/bin/lint-imports
# tests that drive a tool of Debian's are left out when it is missing (.ci/run installs them, as root):
# the operator page's browser tests (chromium, chromium-driver), the plant's rules and alerts (prometheus)
leave_out=()
if ! command -v chromium >/dev/null 2>&1 || ! command -v chromedriver >/dev/null 2>&1; then
    echo "NOTE: chromium or chromedriver not installed: the browser tests (-m browser) are left out;" \
         "apt-get install -y chromium chromium-driver to run them" >&2
    leave_out+=("not browser")
fi
if ! command -v promtool >/dev/null 2>&1 || ! command -v prometheus >/dev/null 2>&1; then
    echo "NOTE: prometheus not installed: the rules' and alerts' tests (-m prometheus) are left out;" \
         "apt-get install -y prometheus to run them" >&2
    leave_out+=("not prometheus")
fi
if [ ${#leave_out[@]} -gt 0 ]; then
    joined=$(printf ' and %s' "${leave_out[@]}")
    set -- -m "${joined# and }" "$@"
fi
# the plant's tests take the published Machine Vision NodeSet and a second OPC UA stack from npm (Node.js ships
# with the machine; tests/helpers/plant_npm.py installs both into a cache folder on first use)
command -v npm >/dev/null 2>&1 || echo "NOTE: npm not installed: the plant's tests fail; apt-get install -y nodejs npm" >&2
# two workers, each test file on one of them (a file's tests share its loopback addresses and fixtures)
exec "$venv"/bin/python -m pytest -n 2 --dist loadfile "$@"
