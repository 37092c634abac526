# Sourced by the scripts: create the venv ($MONOGUIDE_VENV, default .venv) with Python 3.11 if missing and install
# monoguide with extras "$1" into it, each package at the version constraints.txt pins; a venv made earlier is
# brought to the pins. MONOGUIDE_PINS= (empty): no pins, the newest releases within pyproject.toml's ranges
# (scripts/test-newest.sh). docs/dependencies.md. PIP_CONSTRAINT pins what pip installs, PIP_BUILD_CONSTRAINT
# what it builds monoguide with (pip 26.2 and later keep PIP_CONSTRAINT out of the isolated build environment).
venv=${MONOGUIDE_VENV:-.venv}
pins=${MONOGUIDE_PINS-constraints.txt}
py=""
for candidate in python3.11 python3; do
    if command -v "$candidate" >/dev/null 2>&1; then py=$candidate; break; fi
done
[ -n "$py" ] || { echo "monoguide needs Python 3.11 (python3.11 or python3 on PATH)" >&2; exit 1; }
if [ ! -x "$venv/bin/python" ]; then
    echo "setting up $venv with $($py --version)" >&2
    "$py" -m venv "$venv"
fi
if [ -n "$pins" ]; then
    pins=$(realpath "$pins")
    pip_install=(env PIP_CONSTRAINT="$pins" PIP_BUILD_CONSTRAINT="$pins" "$venv/bin/python" -m pip install)
else
    pip_install=(env -u PIP_CONSTRAINT -u PIP_BUILD_CONSTRAINT "$venv/bin/python" -m pip install
                 --upgrade --upgrade-strategy eager)
fi
"${pip_install[@]}" --quiet --disable-pip-version-check pip setuptools wheel
"${pip_install[@]}" --quiet --disable-pip-version-check -e ".[$1]"
