"""A file given as a config must be a regular file of at most 4 MiB: a named pipe (which would block the command
for good, waiting for a writer), a device such as ``/dev/zero`` (which would fill memory), a directory or a larger
file is refused unread, ``CONFIG_FILE_REFUSED`` naming the path and what it is, exit 2 — by every command that
takes one, each run as its own process. A symbolic link to a regular file is read as the file."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.error_lines import the_error_line

from monoguide.daemon.config import MAX_CONFIG_BYTES, load_cell_config, read_config_text
from monoguide.daemon.errors import ConfigFileRefused
from monoguide.drivers.errors import ConfigError

SIM_CELL = Path(__file__).parents[3] / "config" / "sim-cell.toml"
WAIT_S = 30.0  # a command that blocks on the pipe never ends by itself
MEMORY_LIMIT = 4 << 30  # address space of each command: one reading /dev/zero whole fails here, not in the machine

# each command with a file option, {file} where the refused file goes ({state} an existing state directory)
COMMANDS = {
    "run": ["run", "--config", "{file}", "--state-dir", "{state}"],
    "simulate --config": ["simulate", "--config", "{file}", "--cycles", "1"],
    "simulate --calibration": ["simulate", "--calibration", "{file}", "--cycles", "1"],
    "sim-cell": ["sim-cell", "--config", "{file}"],
    "check": ["check", "--config", "{file}", "--state-dir", "{state}"],
    "calibrate --config": ["calibrate", "--config", "{file}", "--sim", "--yes"],
    "calibrate --values": ["calibrate", "--config", str(SIM_CELL), "--values", "{file}", "--sim", "--yes",
                           "--work-dir", "{state}"],
    "plan": ["plan", "--config", "{file}"],
    "probe": ["probe", "robot", "--config", "{file}"],
    "health": ["health", "--config", "{file}", "--state-dir", "{state}"],
    "web": ["web", "--config", "{file}", "--state-dir", "{state}", "--bind", "127.0.57.30:8080"],
    "plant --config": ["plant", "--config", "{file}", "--state-dir", "{state}"],
    "plant --plant-config": ["plant", "--config", str(SIM_CELL), "--plant-config", "{file}", "--state-dir",
                             "{state}"],
    "journal resolve": ["journal", "resolve", "1", "--config", "{file}", "--state-dir", "{state}"],
}


@pytest.fixture
def fifo(tmp_path: Path) -> Path:
    path = tmp_path / "cell.toml"
    os.mkfifo(path)
    return path


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_refuses_a_named_pipe_as_its_config_at_once(command: str, fifo: Path, tmp_path: Path) -> None:
    done = _monoguide(COMMANDS[command], fifo, tmp_path)
    assert done.returncode == 2, done.stderr[-2000:]
    line = the_error_line(done.stderr, "CONFIG_FILE_REFUSED ")
    assert f"{fifo}: a named pipe (FIFO), not a regular file" in line and "at most 4 MiB" in line, line


def test_run_refuses_dev_zero_without_reading_it(tmp_path: Path) -> None:
    done = _monoguide(COMMANDS["run"], Path("/dev/zero"), tmp_path)
    assert done.returncode == 2, done.stderr[-2000:]
    assert "/dev/zero: a character device, not a regular file" in the_error_line(done.stderr, "CONFIG_FILE_REFUSED ")


def test_a_directory_or_a_file_over_the_limit_is_refused_and_a_link_to_the_file_is_read(tmp_path: Path) -> None:
    with pytest.raises(ConfigFileRefused, match=rf"^{tmp_path}: a directory, not a regular file") as raised:
        load_cell_config(tmp_path)
    assert (raised.value.code, raised.value.plc_code) == ("CONFIG_FILE_REFUSED", 533)
    big = tmp_path / "big.toml"
    big.write_bytes(b"#" * (MAX_CONFIG_BYTES + 1))
    with pytest.raises(ConfigFileRefused, match=rf"{big}: {MAX_CONFIG_BYTES + 1} bytes: a config file is at most "
                                                r"4 MiB \(4194304 bytes\)"):
        load_cell_config(big)
    at_limit = tmp_path / "at-limit.toml"
    text = SIM_CELL.read_text()
    at_limit.write_text(text + "#" * (MAX_CONFIG_BYTES - len(text.encode()) - 1) + "\n")
    assert load_cell_config(at_limit).name == load_cell_config(SIM_CELL).name
    link = tmp_path / "link.toml"
    link.symlink_to(SIM_CELL)
    assert read_config_text(link) == text
    with pytest.raises(ConfigError, match=rf"^{tmp_path}/absent.toml: no such config file$"):
        load_cell_config(tmp_path / "absent.toml")
    (tmp_path / "latin1.toml").write_bytes(b"[cell]\nname = 'caf\xe9'\n")
    with pytest.raises(ConfigError, match=r"latin1.toml: not UTF-8 text \(byte 18 of the config file\)$"):
        load_cell_config(tmp_path / "latin1.toml")


# --- helpers -----------------------------------------------------------------------------------------------


def _monoguide(argv: list[str], file: Path, tmp_path: Path) -> subprocess.CompletedProcess[str]:
    state = tmp_path / "state"
    state.mkdir(exist_ok=True)
    args = [a.format(file=file, state=state) for a in argv]
    return subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", *args], capture_output=True, text=True,
                          timeout=WAIT_S, stdin=subprocess.DEVNULL, cwd=tmp_path, preexec_fn=_limit_memory)


def _limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
