# Sourced by the scripts: create .venv with Python 3.11 if missing and install monoguide with extras "$1".
py=""
for candidate in python3.11 python3; do
    if command -v "$candidate" >/dev/null 2>&1; then py=$candidate; break; fi
done
[ -n "$py" ] || { echo "monoguide needs Python 3.11 (python3.11 or python3 on PATH)" >&2; exit 1; }
if [ ! -x .venv/bin/python ]; then
    echo "setting up .venv with $($py --version)" >&2
    "$py" -m venv .venv
    .venv/bin/python -m pip install --quiet --upgrade pip
fi
.venv/bin/python -m pip install --quiet --disable-pip-version-check -e ".[$1]"
