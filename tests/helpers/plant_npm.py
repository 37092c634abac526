"""The npm packages the plant's tests use (tests/helpers/plant_node/package.json, pinned by its package-lock.json):
the OPC Foundation's NodeSets as node-opcua-nodesets publishes them (the plant serves the Machine Vision model from
that file: monoguide ships no copy) and node-opcua-client, a second OPC UA stack that checks the server from
outside asyncua. Installed with ``npm ci`` on first use into a cache folder outside the checkout —
``$MONOGUIDE_TEST_CACHE`` or ``~/.cache/monoguide-tests`` — named by the lock file's hash, so a changed lock installs
anew and a fresh clone needs nothing but npm and the registry. A lock file keeps two test workers from installing at
once."""

from __future__ import annotations

import fcntl
import hashlib
import os
import shutil
import subprocess
from pathlib import Path

import pytest

TOOLS = Path(__file__).parent / "plant_node"  # package.json, package-lock.json and the probes (*.mjs)
NODESET = Path("node_modules/node-opcua-nodesets/nodesets/Opc.Ua.MachineVision.NodeSet2.xml")
INSTALL_S = 600.0


def npm_tools() -> Path:
    """The folder with ``node_modules`` installed (installing it first if needed)."""
    lock = (TOOLS / "package-lock.json").read_bytes()
    base = Path(os.environ.get("MONOGUIDE_TEST_CACHE") or Path.home() / ".cache" / "monoguide-tests")
    folder = base / f"npm-{hashlib.sha256(lock + (TOOLS / 'package.json').read_bytes()).hexdigest()[:16]}"
    done = folder / ".installed"
    if done.is_file():
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    with (base / ".npm-install.lock").open("w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        if not done.is_file():
            _install(folder)
            done.write_text("npm ci\n")
    return folder


def machine_vision_nodeset() -> Path:
    """The published Opc.Ua.MachineVision.NodeSet2.xml (model 1.0.0)."""
    return npm_tools() / NODESET


def _install(folder: Path) -> None:
    npm = shutil.which("npm")
    if npm is None:
        pytest.fail("npm is not installed: the plant's tests need node-opcua-nodesets and node-opcua-client from the "
                    "npm registry (apt-get install -y nodejs npm; .ci/run installs them)")
    for name in ("package.json", "package-lock.json"):
        shutil.copy(TOOLS / name, folder / name)
    done = subprocess.run([npm, "ci", "--no-audit", "--no-fund", "--loglevel=error"], cwd=folder, capture_output=True,
                          text=True, timeout=INSTALL_S)
    if done.returncode != 0:
        pytest.fail(f"npm ci in {folder} failed ({done.returncode}): {done.stderr[-3000:]}")
