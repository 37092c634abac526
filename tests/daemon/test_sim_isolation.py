"""Runtime code never imports the simulated devices: the import-linter contract catches every importer
but the assembly point (checked by planting violations in a copy of the tree), and at run time a real
cell's commands do not load ``monoguide.drivers.sim`` (checked in ``sys.modules`` of a fresh process)."""

from __future__ import annotations

import ast
import importlib
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[2]
LINT_IMPORTS = Path(sys.executable).parent / "lint-imports"
PACKAGES = ("daemon", "drivers", "solver")
CONTRACT = "runtime code never imports the simulated devices"
SIM_IMPORT = "from monoguide.drivers.sim.cell import SimCell  # noqa\n"


@pytest.fixture
def tree_copy(tmp_path: Path) -> Path:
    """The three packages copied under ``tmp_path/monoguide`` (a namespace package, as installed)."""
    for name in PACKAGES:
        source = Path(importlib.import_module(f"monoguide.{name}").__file__).parent
        shutil.copytree(source, tmp_path / "monoguide" / name, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    return tmp_path


def lint_imports(tree: Path) -> subprocess.CompletedProcess[str]:
    """``lint-imports`` with the project's contracts, run on the copy (it comes first on the path)."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    return subprocess.run([str(LINT_IMPORTS), "--no-logo", "--no-cache", "--config", str(tree / "pyproject.toml")],
                          cwd=tree, env=env, capture_output=True, text=True, timeout=60)


def test_the_unchanged_copy_keeps_every_contract(tree_copy: Path) -> None:
    result = lint_imports(tree_copy)
    assert result.returncode == 0, result.stdout + result.stderr
    assert f"{CONTRACT} KEPT" in result.stdout


@pytest.mark.parametrize(
    ("module", "importer"),
    [
        ("drivers/planted_driver.py", "monoguide.drivers.planted_driver"),  # a new driver: not named anywhere
        ("drivers/planted_pkg/__init__.py", "monoguide.drivers.planted_pkg"),  # a new driver package ...
        ("drivers/planted_pkg/backend.py", "monoguide.drivers.planted_pkg.backend"),  # ... and a module in it
        ("drivers/camera.py", "monoguide.drivers.camera"),
        ("drivers/__init__.py", "monoguide.drivers"),  # the drivers package itself
        ("daemon/planted_cmd.py", "monoguide.daemon.planted_cmd"),
        ("daemon/cli/probe.py", "monoguide.daemon.cli.probe"),
        ("solver/pose.py", "monoguide.solver.pose"),
    ],
)
def test_the_contract_catches_any_module_importing_the_simulator(tree_copy: Path, module: str,
                                                                  importer: str) -> None:
    path = tree_copy / "monoguide" / module
    assert path.exists() == ("planted" not in module)  # planted modules are new, the others are real
    path.parent.mkdir(exist_ok=True)
    (path.parent / "__init__.py").touch()
    path.write_text((path.read_text() if path.exists() else "") + SIM_IMPORT)
    result = lint_imports(tree_copy)
    assert result.returncode == 1, result.stdout
    assert "never imports the simulated devices BROKEN" in result.stdout  # this contract, not only the layers
    assert f"{importer} -> monoguide.drivers.sim.cell" in result.stdout, result.stdout


def test_an_indirect_import_through_a_driver_is_caught(tree_copy: Path) -> None:
    (tree_copy / "monoguide" / "drivers" / "planted_bridge.py").write_text(SIM_IMPORT)
    probe = tree_copy / "monoguide" / "daemon" / "cli" / "probe.py"
    probe.write_text(probe.read_text() + "from monoguide.drivers import planted_bridge  # noqa\n")
    result = lint_imports(tree_copy)
    assert result.returncode == 1 and f"{CONTRACT} BROKEN" in result.stdout
    assert "monoguide.daemon.cli.probe -> monoguide.drivers.planted_bridge" in result.stdout, result.stdout


def test_the_assembly_point_alone_may_import_it(tree_copy: Path) -> None:
    assembly = tree_copy / "monoguide" / "daemon" / "assembly.py"
    assembly.write_text(assembly.read_text() + "from monoguide.drivers.sim.tracker import main  # noqa\n")
    assert lint_imports(tree_copy).returncode == 0


def sim_modules_after(code: str) -> list[str]:
    """The ``monoguide.drivers.sim`` modules loaded after running ``code`` in a fresh interpreter."""
    check = code + "\nimport sys\nprint(sorted(m for m in sys.modules if m.startswith('monoguide.drivers.sim')))"
    result = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    return ast.literal_eval(result.stdout.strip().splitlines()[-1])


def test_the_cli_does_not_load_the_simulator() -> None:
    assert sim_modules_after("import monoguide.daemon.cli") == []


def test_probing_a_real_camera_does_not_load_the_simulator() -> None:
    code = textwrap.dedent(f"""
        from typer.testing import CliRunner
        from monoguide.daemon.cli import app
        result = CliRunner().invoke(app, ["probe", "camera", "--config", {str(ROOT / "config" / "viky-camera.toml")!r}])
        assert result.exit_code == 0, result.output
        assert "Viky" in result.output
    """)
    assert sim_modules_after(code) == []


def test_probing_the_simulated_camera_does_load_it() -> None:
    """The control: the check above would see the simulator if it were loaded."""
    code = textwrap.dedent(f"""
        from typer.testing import CliRunner
        from monoguide.daemon.cli import app
        result = CliRunner().invoke(app, ["probe", "camera", "--config", {str(ROOT / "config" / "sim-cell.toml")!r}])
        assert result.exit_code == 0, result.output
    """)
    assert "monoguide.drivers.sim.camera" in sim_modules_after(code)


LAYERS = "the daemon's features in layers"


@pytest.mark.parametrize(("module", "line"), [
    ("daemon/cycle/_runner.py", "from monoguide.daemon.service import Journal  # noqa\n"),  # a feature upward
    ("daemon/config/_cell.py", "from monoguide.daemon.cycle import State  # noqa\n"),
    ("daemon/errors.py", "from monoguide.daemon import packaged  # noqa\n"),
])
def test_an_arrow_upward_between_the_daemons_features_is_caught(tree_copy: Path, module: str, line: str) -> None:
    path = tree_copy / "monoguide" / module
    path.write_text(path.read_text() + line)
    result = lint_imports(tree_copy)
    assert result.returncode == 1 and f"{LAYERS} BROKEN" in result.stdout, result.stdout


def test_a_new_module_directly_in_the_daemon_must_take_its_layer(tree_copy: Path) -> None:
    (tree_copy / "monoguide" / "daemon" / "helpers.py").write_text('"""A module nobody placed."""\n')
    result = lint_imports(tree_copy)
    assert result.returncode == 1 and f"{LAYERS} BROKEN" in result.stdout, result.stdout
    assert "monoguide.daemon.helpers" in result.stdout
