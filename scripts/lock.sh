#!/usr/bin/env bash
# Move the pins: write constraints.txt anew from the newest releases within pyproject.toml's ranges — monoguide
# with its extras test and bench installed into a scratch venv (nothing pinned), and that venv's `pip freeze`
# (pip, setuptools and wheel too). Then run the suite on the new pins and commit constraints.txt with the
# versions that moved (docs/dependencies.md). Needs Python 3.11 with pip and access to PyPI.
#   bash scripts/lock.sh
set -euo pipefail
cd "$(dirname "$0")/.."
unset PIP_CONSTRAINT PIP_BUILD_CONSTRAINT  # the newest releases, not the pins being moved
py=""
for candidate in python3.11 python3; do
    if command -v "$candidate" >/dev/null 2>&1; then py=$candidate; break; fi
done
[ -n "$py" ] || { echo "lock.sh needs Python 3.11 (python3.11 or python3 on PATH)" >&2; exit 1; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
echo "lock: installing the newest releases into a scratch venv with $($py --version)" >&2
"$py" -m venv "$work/venv"
"$work/venv/bin/python" -m pip install --quiet --disable-pip-version-check --upgrade pip setuptools wheel
"$work/venv/bin/python" -m pip install --quiet --disable-pip-version-check "$PWD[test,bench]"
{
    echo "# The version of every package a fresh .venv gets (scripts/venv.sh; CI through scripts/test.sh) and"
    echo "# the offline bundle ships (scripts/bundle.sh): monoguide's dependencies with the extras test and bench,"
    echo "# and pip, setuptools (also what monoguide is built with) and wheel; Linux x86-64, CPython 3.11."
    echo "# Written by scripts/lock.sh ($("$work/venv/bin/python" --version), $(date -u +%Y-%m-%d)) from the newest"
    echo "# releases within pyproject.toml's ranges: move a pin with it, not by hand (docs/dependencies.md)."
    "$work/venv/bin/python" -m pip freeze --all --disable-pip-version-check --exclude monoguide
} > constraints.txt.new
mv constraints.txt.new constraints.txt
echo "lock: constraints.txt has $(grep -c '==' constraints.txt) pins; what moved:" >&2
git --no-pager diff --stat -- constraints.txt >&2 || true
git --no-pager diff -U0 -- constraints.txt | grep '^[-+][^-+#]' >&2 || true
