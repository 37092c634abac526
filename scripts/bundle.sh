#!/usr/bin/env bash
# Build the offline bundle for a cell PC without internet: one archive
#   dist/monoguide-<version>-linux-x86_64-cp311.tar.gz
# holding wheels/ (monoguide's wheel and the wheel of every dependency, for Linux x86-64 / CPython 3.11, each at
# the version constraints.txt pins: what the tests ran with), monoguide.service, install.sh and README.txt. On the cell PC: unpack it and run `sudo ./install.sh`
# (systemd/README.md). Needs Python 3.11 with pip and access to PyPI on the machine that builds it.
#   bash scripts/bundle.sh [OUT_DIR]            (default: dist)
set -euo pipefail
cd "$(dirname "$0")/.."
out=$(realpath -m "${1:-dist}")
py=""
for candidate in .venv/bin/python python3.11 python3; do
    if command -v "$candidate" >/dev/null 2>&1; then py=$candidate; break; fi
done
[ -n "$py" ] || { echo "bundle.sh needs Python 3.11 with pip" >&2; exit 1; }
version=$("$py" -c 'import tomllib; print(tomllib.load(open("pyproject.toml", "rb"))["project"]["version"])')
name="monoguide-${version}-linux-x86_64-cp311"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
stage="$work/$name"
mkdir -p "$stage/wheels" "$out"
# the pinned versions (docs/dependencies.md): of the dependencies, and of the setuptools monoguide is built with
export PIP_CONSTRAINT="$PWD/constraints.txt" PIP_BUILD_CONSTRAINT="$PWD/constraints.txt"
echo "bundle: building the monoguide wheel" >&2
"$py" -m pip wheel --quiet --no-deps --wheel-dir "$stage/wheels" .
echo "bundle: downloading the wheels of its dependencies (Linux x86-64, CPython 3.11)" >&2
"$py" -m pip download --quiet --dest "$stage/wheels" --only-binary=:all: \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    --platform linux_x86_64 --python-version 3.11 --implementation cp --abi cp311 --abi abi3 --abi none \
    "$stage"/wheels/monoguide-"$version"-*.whl
cp systemd/monoguide.service "$stage/"
cp scripts/bundle-install.sh "$stage/install.sh"
chmod 0755 "$stage/install.sh"
cat > "$stage/README.txt" <<README
monoguide $version, offline bundle for Linux x86-64 with CPython 3.11 ($(ls "$stage/wheels" | wc -l) wheels).

  sudo ./install.sh                     venv in /opt/monoguide/venv, /usr/local/bin/monoguide, the unit
  ./install.sh --venv DIR --no-system   only a venv in DIR (no root needed)

Nothing is downloaded: pip installs from wheels/ only (--no-index). Then follow systemd/README.md of the
project (or \`monoguide init /etc/monoguide\` for a starting cell config and the robot programs).
README
tar -C "$work" -czf "$out/$name.tar.gz" "$name"
echo "$out/$name.tar.gz"
