"""Asking a running ``monoguide sim-cell`` for a command from another process (``monoguide check``).

sim-cell's state file names a named pipe beside it, ``commands``, that takes the very lines its standard input
takes (:mod:`._fault_channel`; only the user that runs sim-cell may write it). :func:`send_command` writes one
line there; :func:`present_reference_part` asks for the reference part (``robot reference-part``) and waits until
the simulated robot's truth file says its part supply has it (``reference_part``: ``"next"`` or ``"in the cell"``)
— or says that it already lies in the cell, and asks nothing. Where the cell cannot be asked, the error says
which command to type into sim-cell's standard input instead.
"""

from __future__ import annotations

import json
import os
import stat
import time
from pathlib import Path
from typing import Any

from monoguide.daemon.assembly import read_sim_state
from monoguide.daemon.errors import SimulateError, SimulateTimeout

REFERENCE_COMMAND = "robot reference-part"
REQUEST_TIMEOUT_S = 5.0  # sim-cell forwards a line within its 0.1 s loop; the controller applies it at once
POLL_S = 0.02


def send_command(state_path: Path, line: str) -> dict[str, Any]:
    """Write ``line`` into the command pipe of the sim-cell of ``state_path``; returns its state.
    :class:`~monoguide.drivers.errors.DeviceNotFound` when no sim-cell runs there, :class:`SimulateError` naming
    the command to type when it takes no commands this way."""
    state = read_sim_state(state_path)
    where = f"the sim-cell of {state_path} (pid {state.get('pid', '?')})"
    instead = f"type `{line}` into its standard input"
    pipe = state.get("commands")
    if not isinstance(pipe, str) or not pipe:
        raise SimulateError(f"{where} names no command pipe in its state file: {instead}")
    try:
        fd = os.open(pipe, os.O_WRONLY | os.O_NONBLOCK | os.O_CLOEXEC)  # ENXIO: nobody reads it (sim-cell gone)
    except OSError as exc:
        raise SimulateError(f"{where}: its command pipe {pipe} cannot be written ({exc.strerror or exc}): "
                            f"{instead}") from None
    try:
        if not stat.S_ISFIFO(os.fstat(fd).st_mode):
            raise SimulateError(f"{where}: {pipe} is not its command pipe (not a named pipe): {instead}")
        os.write(fd, (line + "\n").encode())  # one write below PIPE_BUF: never interleaved with another writer's
    except OSError as exc:
        raise SimulateError(f"{where}: cannot write its command pipe {pipe} ({exc.strerror or exc}): "
                            f"{instead}") from None
    finally:
        os.close(fd)
    return state


def present_reference_part(state_path: Path, job: int, timeout_s: float = REQUEST_TIMEOUT_S) -> str:
    """The sim-cell of ``state_path`` presents part type ``job``'s reference part, exactly as taught, at the next
    visit of its first measuring pose, and keeps it there until it is grasped; returns what was done, for the
    person at the cell. :class:`SimulateTimeout` when its robot does not take it up within ``timeout_s``."""
    state = read_sim_state(state_path)
    truth = (state.get("robot") or {}).get("truth")
    if not isinstance(truth, str):
        raise SimulateError(f"the sim-cell of {state_path} runs no simulated robot: the reference part is its part "
                            f"supply's (is it the sim-cell of this config?)")
    held = _reference_part(Path(truth))
    if held.get("reference_part") == "in the cell" and held.get("part_type") == job:
        return "the simulated cell's reference part lies in its nest (asked for before)"
    send_command(state_path, REFERENCE_COMMAND)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if _reference_part(Path(truth)).get("reference_part") in ("next", "in the cell"):
            return f"the simulated cell presents the reference part ({REFERENCE_COMMAND}, asked through {state_path})"
        time.sleep(POLL_S)
    raise SimulateTimeout(f"the sim-cell of {state_path} (pid {state.get('pid', '?')}) did not take up "
                          f"`{REFERENCE_COMMAND}` within {timeout_s:g} s: type it into its standard input, then run "
                          f"the check again")


def _reference_part(truth: Path) -> dict[str, Any]:
    """What the simulated robot's truth file says of the part in the cell (empty while it cannot be read)."""
    try:
        data = json.loads(truth.read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}
