#!/usr/bin/env bash
# Install monoguide from this offline bundle (scripts/bundle.sh made it): nothing is downloaded.
#   sudo ./install.sh                       venv /opt/monoguide/venv, /usr/local/bin/monoguide, the systemd unit
#   ./install.sh --venv DIR [--no-system]   the venv elsewhere; --no-system: no link, no unit (no root needed)
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
venv=/opt/monoguide/venv
system=1
while [ $# -gt 0 ]; do
    case "$1" in
        --venv) venv=$2; shift 2 ;;
        --no-system) system=0; shift ;;
        -h|--help) sed -n '2,4p' "$0"; exit 0 ;;
        *) echo "install.sh: unknown option $1 (see --help)" >&2; exit 2 ;;
    esac
done
py=""
for candidate in python3.11 python3; do
    if command -v "$candidate" >/dev/null 2>&1; then py=$candidate; break; fi
done
[ -n "$py" ] || { echo "install.sh: monoguide needs Python 3.11 (python3.11 or python3 on PATH)" >&2; exit 1; }
"$py" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' || {
    echo "install.sh: the wheels are for CPython 3.11; $py is $("$py" --version)" >&2; exit 1; }
echo "install.sh: creating $venv" >&2
"$py" -m venv "$venv"
"$venv/bin/python" -m pip install --quiet --no-index --find-links "$here/wheels" monoguide
"$venv/bin/monoguide" --version
if [ "$system" = 1 ]; then
    ln -sf "$venv/bin/monoguide" /usr/local/bin/monoguide
    install -m 0644 "$here/monoguide.service" /etc/systemd/system/monoguide.service
    echo "install.sh: /usr/local/bin/monoguide and /etc/systemd/system/monoguide.service installed;" \
         "next: systemd/README.md (the service user, /etc/monoguide/cell.toml, systemctl enable --now)" >&2
fi
