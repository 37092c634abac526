"""The files monoguide ships beside its code (package data), wherever it is installed.

A wheel or an offline bundle carries the simulated roof cell's config (``config/sim-cell.toml``, and with fixed
reference marks ``config/sim-cell-marks.toml``), the commented
config of a real cell (``config/cell-template.toml``), the robot programs (``config/ur/``, ``config/kuka/``) and
the systemd unit (``systemd/monoguide.service``); in a checkout they are the same files of the source tree. Read
them through here, never through a path relative to the working directory or to a module's ``__file__``.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

CONFIG_PACKAGE = "monoguide.config"  # the top-level folder config/ (setuptools package-dir)
SYSTEMD_PACKAGE = "monoguide.systemd"  # the top-level folder systemd/
SIM_CELL = "sim-cell.toml"
SIM_CELL_MARKS = "sim-cell-marks.toml"  # the same cell with fixed reference marks (docs/cycle-marks.md)
CELL_TEMPLATE = "cell-template.toml"
ROBOT_PROGRAMS = {"ur": ("monoguide.script",), "kuka": ("monoguide.src", "monoguide.dat", "monoguide.xml")}
UNIT_FILE = "monoguide.service"


def config_file(name: str) -> Path:
    """A shipped config file (``sim-cell.toml``, ``cell-template.toml``, ``ur/monoguide.script``, ...)."""
    return _path(CONFIG_PACKAGE, name)


def sim_cell_config() -> Path:
    """The simulated paper roof cell: the default of ``simulate`` and ``calibrate --sim``."""
    return config_file(SIM_CELL)


def sim_cell_marks_config() -> Path:
    """The simulated roof cell with fixed reference marks: ``simulate --marks``."""
    return config_file(SIM_CELL_MARKS)


def robot_program_files() -> dict[str, Path]:
    """Every robot program file, by its path under ``config/`` (``ur/monoguide.script``, ...)."""
    return {f"{make}/{name}": config_file(f"{make}/{name}") for make, names in ROBOT_PROGRAMS.items()
            for name in names}


def unit_file() -> Path:
    return _path(SYSTEMD_PACKAGE, UNIT_FILE)


def is_packaged(path: Path) -> bool:
    """Whether ``path`` is one of the shipped files (not the user's: nothing is ever written beside it)."""
    try:
        Path(path).resolve().relative_to(_path(CONFIG_PACKAGE, "").resolve())
    except ValueError:
        return False
    return True


def _path(package: str, name: str) -> Path:
    root = resources.files(package)
    target = root.joinpath(*name.split("/")) if name else root
    # monoguide is installed as files (a wheel unpacked, or a checkout): the resource is a real path
    return Path(str(target))
