"""The offline bundle of a cell PC without internet, end to end: `scripts/bundle.sh` builds it (the wheel and
every dependency's wheel), its install.sh installs it with `pip --no-index` into a fresh venv, and the installed
monoguide runs the main job outside any checkout — from a directory that holds nothing of the project, with the
shipped simulated cell, robot programs and unit (package data)."""

from __future__ import annotations

import json
import os
import subprocess
import tarfile
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[2]
HOST = "127.0.41.1"

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bundle built, unpacked and installed; returns the venv's `monoguide`."""
    tmp = tmp_path_factory.mktemp("bundle")
    built = subprocess.run(["bash", str(ROOT / "scripts" / "bundle.sh"), str(tmp / "dist")], capture_output=True,
                           text=True, timeout=600, check=False)
    assert built.returncode == 0, built.stderr[-3000:]
    archive = Path(built.stdout.strip().splitlines()[-1])
    assert archive.name == "monoguide-0.1.0-linux-x86_64-cp311.tar.gz" and archive.is_file()
    with tarfile.open(archive) as tar:
        names = tar.getnames()
        tar.extractall(tmp / "unpacked", filter="data")
    top = archive.name.removesuffix(".tar.gz")
    wheels = [n for n in names if n.startswith(f"{top}/wheels/") and n.endswith(".whl")]
    assert any("/monoguide-0.1.0-" in n for n in wheels) and len(wheels) > 15
    for needed in ("numpy", "scipy", "opencv_python_headless", "ur_rtde", "pymodbus", "matplotlib", "tomlkit"):
        assert any(f"/wheels/{needed}-" in n for n in wheels), needed
    assert {f"{top}/install.sh", f"{top}/monoguide.service", f"{top}/README.txt"} <= set(names)
    env = {k: v for k, v in os.environ.items() if not k.startswith("PIP_")}  # nothing but the bundle's wheels
    venv = tmp / "venv"
    done = subprocess.run([str(tmp / "unpacked" / top / "install.sh"), "--venv", str(venv), "--no-system"],
                          capture_output=True, text=True, timeout=600, env=env, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip() == "monoguide 0.1.0"
    return venv / "bin" / "monoguide"


def _run(monoguide: Path, cwd: Path, *args: str, timeout_s: float = 300) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    return subprocess.run([str(monoguide), *args], cwd=cwd, capture_output=True, text=True, timeout=timeout_s,
                          env=env, check=False)


def test_the_installed_monoguide_is_not_the_checkout(installed: Path, tmp_path: Path) -> None:
    python = installed.parent / "python"
    where = subprocess.run([str(python), "-c", "import monoguide.daemon.cli as m; print(m.__file__)"],
                           cwd=tmp_path, capture_output=True, text=True, timeout=60, check=True).stdout.strip()
    assert "site-packages" in where and not where.startswith(str(ROOT)), where


def test_init_writes_the_shipped_cell_programs_and_unit(installed: Path, tmp_path: Path) -> None:
    done = _run(installed, tmp_path, "init", "sim", "--sim")
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "sim" / "cell.toml").read_text() == (ROOT / "config" / "sim-cell.toml").read_text()
    done = _run(installed, tmp_path, "init", "real")
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "real" / "cell.toml").read_text() == (ROOT / "config" / "cell-template.toml").read_text()
    for name in ("ur/monoguide.script", "kuka/monoguide.src", "kuka/monoguide.dat", "kuka/monoguide.xml"):
        assert (tmp_path / "real" / name).read_text() == (ROOT / "config" / name).read_text(), name
    assert (tmp_path / "real" / "systemd" / "monoguide.service").read_text() == (
        ROOT / "systemd" / "monoguide.service").read_text()
    again = _run(installed, tmp_path, "init", "real")
    assert again.returncode == 1 and "INIT_FAILED" in again.stderr and "would overwrite" in again.stderr


def test_simulate_plan_and_calibrate_run_outside_the_checkout(installed: Path, tmp_path: Path) -> None:
    done = _run(installed, tmp_path, "simulate", "--cycles", "2", "--json", "--host", HOST)
    assert done.returncode == 0, done.stderr[-3000:]
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    assert summary["cycles"] == 2 and summary["ok"] == 2 and summary["offsets_written_on_failure"] == 0
    assert summary["grasp_max_mm"] < 0.5 and summary["grasps_refused"] == 0
    plan = _run(installed, tmp_path, "plan", "--json")
    assert plan.returncode == 0, plan.stderr
    assert json.loads(plan.stdout)["sigma_px"] > 0
    wizard = _run(installed, tmp_path, "calibrate", "intrinsics", "--sim", "--yes", "--plate-images", "6", "--host",
                  "127.0.41.5")
    assert wizard.returncode == 0, wizard.stderr[-3000:]
    assert (tmp_path / "sim-cell.calibration" / "calibration-session.json").is_file()  # not in site-packages
