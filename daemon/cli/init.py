"""``monoguide init DIR [--sim]``: a starting cell config and the robot programs, from the files monoguide ships.

Real cell (default): ``DIR/cell.toml`` is the commented template of a real cell (every key explained, the
values to replace marked ``REPLACE``); ``--sim``: the simulated paper roof cell, ready for ``monoguide simulate
--config DIR/cell.toml`` and ``sim-cell``. Both also write the robot programs (``DIR/ur/monoguide.script``,
``DIR/kuka/monoguide.src``, ``.dat``, ``.xml``) and the systemd unit (``DIR/systemd/monoguide.service``). An
existing file is never overwritten unless ``--force``; the command then names every file it would have
replaced and writes nothing.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Annotated

import typer

from monoguide.daemon.cli._console import say, stdout_console
from monoguide.daemon.cli._policy import reporting_errors
from monoguide.daemon.errors import InitFailed
from monoguide.daemon.packaged import CELL_TEMPLATE, config_file, robot_program_files, sim_cell_config, unit_file

CELL_FILE = "cell.toml"


def init(
    directory: Annotated[Path, typer.Argument(help="Where to write cell.toml, the robot programs and the unit.")],
    sim: Annotated[bool, typer.Option("--sim", help="The simulated roof cell instead of a real cell's template.")]
    = False,
    force: Annotated[bool, typer.Option("--force", help="Overwrite files that exist.")] = False,
) -> None:
    """Write a starting cell config (a real cell's commented template, or --sim the simulated roof cell), the UR
    and KUKA robot programs and the systemd unit into DIRECTORY.

    Exit status: 0 written; 1 a file exists (without --force) or cannot be written (the message names it)."""
    files = {CELL_FILE: sim_cell_config() if sim else config_file(CELL_TEMPLATE), **robot_program_files(),
             "systemd/monoguide.service": unit_file()}
    written = reporting_errors(lambda: write_files(Path(directory), files, force=force))
    out = stdout_console()
    for path in written:
        say(out, f"wrote {path}")
    cell = Path(directory) / CELL_FILE
    say(out, f"next: monoguide simulate --config {cell}" if sim else
        f"next: edit every REPLACE in {cell} (docs/cell-config.md), then monoguide probe camera --config {cell}")


def write_files(directory: Path, files: dict[str, Path], *, force: bool = False) -> list[Path]:
    """Copy each shipped file to ``directory / name``; refuse (:class:`InitFailed`, nothing written) when any
    exists and not ``force``. Returns the paths written."""
    targets = {directory / name: source for name, source in files.items()}
    if not force and (existing := [str(t) for t in targets if t.exists()]):
        raise InitFailed(f"would overwrite {', '.join(existing)}: nothing written (--force to overwrite)")
    try:
        for target, source in targets.items():
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source, target)
    except OSError as exc:
        raise InitFailed(f"cannot write {exc.filename}: {exc.strerror}") from exc
    return list(targets)
