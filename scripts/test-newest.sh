#!/usr/bin/env bash
# The checks of scripts/test.sh against the newest releases within pyproject.toml's ranges, not the pins of
# constraints.txt: in their own venv, .venv-newest (made on the first run, upgraded to the newest on every run),
# so that a release that breaks monoguide is seen here before a fresh install or a re-lock meets it. Not part of
# the default test command (docs/dependencies.md). Arguments go to pytest, as with scripts/test.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
MONOGUIDE_VENV=.venv-newest MONOGUIDE_PINS="" exec bash scripts/test.sh "$@"
