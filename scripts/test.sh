#!/usr/bin/env bash
# Set up .venv (first run; brought to the pins of constraints.txt on every run) and run the checks: ruff, the
# import-layer contracts, the test suite. MONOGUIDE_VENV: another venv (scripts/test-newest.sh).
# Extra arguments go to pytest, e.g. `bash scripts/test.sh tests/solver -x`.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/venv.sh test
"$venv"/bin/ruff check .
"$venv"/bin/lint-imports
# the operator page's browser tests drive Debian's chromium (apt-get install chromium chromium-driver; .ci/run does)
if ! command -v chromium >/dev/null 2>&1 || ! command -v chromedriver >/dev/null 2>&1; then
    echo "NOTE: chromium or chromedriver not installed: the browser tests (-m browser) are left out;" \
         "apt-get install -y chromium chromium-driver to run them" >&2
    set -- -m "not browser" "$@"
fi
# the plant's tests need Debian's prometheus (promtool, the server) and npm (.ci/run installs both when missing)
for tool in promtool prometheus npm; do
    command -v "$tool" >/dev/null 2>&1 || echo "NOTE: $tool not installed: the plant's tests that need it fail;" \
        "apt-get install -y prometheus nodejs npm" >&2
done
# two workers, each test file on one of them (a file's tests share its loopback addresses and fixtures)
exec "$venv"/bin/python -m pytest -n 2 --dist loadfile "$@"
