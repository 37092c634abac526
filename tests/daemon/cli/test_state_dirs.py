"""The state directory must be a directory: a regular file, a named pipe or a path below a file given as
``--state-dir`` (or as ``$STATE_DIRECTORY``) is refused by every command that takes one, ``STATE_DIR_INVALID``
naming it and where it came from, one line, exit 2 — each command run as its own process, nothing created."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.error_lines import the_error_line

SIM_CELL = Path(__file__).parents[3] / "config" / "sim-cell.toml"

COMMANDS = {
    "run": ["run", "--config", str(SIM_CELL)],
    "check": ["check", "--config", str(SIM_CELL)],
    "status": ["status"],
    "journal list": ["journal", "list"],
    "journal show": ["journal", "show", "1"],
    "journal resolve": ["journal", "resolve", "1"],
    "journal export": ["journal", "export"],
    "health": ["health"],
    "web": ["web", "--config", str(SIM_CELL), "--bind", "127.0.57.31:8080"],
    "plant": ["plant", "--config", str(SIM_CELL)],
}


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_refuses_a_regular_file_as_its_state_dir(command: str, tmp_path: Path) -> None:
    file = tmp_path / "state"
    file.write_text("not a directory\n")
    done = _monoguide([*COMMANDS[command], "--state-dir", str(file)], tmp_path)
    assert done.returncode == 2, done.stderr[-2000:]
    assert _said(done) == (f"STATE_DIR_INVALID state directory {file} (--state-dir) is a regular file, not a "
                           "directory: give --state-dir a directory (one that does not exist yet is created by the "
                           "service)")
    assert file.read_text() == "not a directory\n" and sorted(p.name for p in tmp_path.iterdir()) == ["state"]


@pytest.mark.parametrize("command", ["run", "check"])
def test_a_state_dir_below_a_file_is_refused_naming_the_file(command: str, tmp_path: Path) -> None:
    file = tmp_path / "file"
    file.write_text("")
    done = _monoguide([*COMMANDS[command], "--state-dir", str(file / "state")], tmp_path)
    assert done.returncode == 2, done.stderr[-2000:]
    assert _said(done).startswith(f"STATE_DIR_INVALID state directory {file / 'state'} (--state-dir) is below "
                                  f"{file}, a regular file: give --state-dir a directory")


def test_a_named_pipe_from_systemd_is_refused_naming_where_it_came_from(tmp_path: Path) -> None:
    fifo = tmp_path / "state"
    os.mkfifo(fifo)
    done = _monoguide(["status"], tmp_path, environ={"STATE_DIRECTORY": str(fifo)})
    assert done.returncode == 2, done.stderr[-2000:]
    assert _said(done).startswith(f"STATE_DIR_INVALID state directory {fifo} ($STATE_DIRECTORY) is a named pipe "
                                  "(FIFO), not a directory")


def test_a_state_dir_that_does_not_exist_is_still_missing_for_a_reader(tmp_path: Path) -> None:
    done = _monoguide(["status", "--state-dir", str(tmp_path / "absent")], tmp_path)
    assert done.returncode == 1
    assert _said(done).startswith(f"STATE_DIR_MISSING state directory {tmp_path / 'absent'} (--state-dir) does not "
                                  "exist")


# --- helpers -----------------------------------------------------------------------------------------------


def _monoguide(argv: list[str], cwd: Path, environ: dict[str, str] | None = None
               ) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "STATE_DIRECTORY"} | (environ or {})
    return subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", *argv], capture_output=True, text=True,
                          timeout=60, stdin=subprocess.DEVNULL, cwd=cwd, env=env)


def _said(done: subprocess.CompletedProcess[str]) -> str:
    return the_error_line(done.stderr, "STATE_DIR_")
