"""`monoguide sim-cell`: run the simulated devices that are their own processes, until stopped (docs/probe.md).

That is the laser tracker behind a pseudo-terminal; when ``[robot] backend`` is ``sim-ur`` or ``sim-kuka``,
the simulated robot controller on ``[robot] host:port`` with the part supply (one line per part in
``--truth-log``); and, with a ``[plc]`` section and without ``--no-plc``, the simulated line PLC on ``[plc]
host:port`` (its per-part records are echoed to stdout as ``plc: {...}``; ``--parts N``: it plays N parts, then
only beats its heartbeat). Where each device listens goes to stdout and to a JSON state file that ``monoguide
probe`` (and ``run``) read; fault commands on standard input (``fault: ...`` / ``fault error: ...``; the
persistent calibration faults ``camera bump DEG MM [AXIS]``, ``camera focal PCT``, ``pose drift K MM DEG`` among
them, daemon/simulate/_fault_channel.py), the grasp
relayed between the line and the robot (``grasp: {...}``). What runs the cell is
:class:`~monoguide.daemon.simulate.SimulatedCell`; this module is the command: its options, what it says and
how it ends.

Exit status (``daemon/cli/_policy.py``): 0 stopped by Ctrl-C or SIGTERM (no child process is left behind); 1 a
device failed to start or ended, or another sim-cell holds the state file (``DEVICE_BUSY``); 2 a bad config, one
with nothing to simulate, or a state file that cannot be one (``CONFIG_INVALID``) — each failure one line, ``CODE
message``, on standard error.
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import typer

from monoguide.daemon.cli._options import job_numbers
from monoguide.daemon.cli._policy import fail
from monoguide.daemon.config import CellConfig, load_cell_config
from monoguide.daemon.simulate import FAULT_COMMANDS, ROBOT_ACTIONS, SimulatedCell
from monoguide.solver.errors import MonoguideError

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

__all__ = ["FAULT_COMMANDS", "ROBOT_ACTIONS", "sim_cell"]  # the fault names: tests compare them with the simulator's


def sim_cell(
    config: Annotated[Path, typer.Option("--config", "-c", help="cell config (TOML)")],
    state_file: Annotated[
        Path | None, typer.Option("--state-file", help="where to write where the devices listen")
    ] = None,
    no_plc: Annotated[
        bool, typer.Option("--no-plc", help="leave the PLC out: another server can listen where \\[plc] says")
    ] = False,
    truth_log: Annotated[
        Path | None, typer.Option("--truth-log", help="one JSON line per part (its true pose, offset, grasp error) "
                                                      "and per grasp")
    ] = None,
    parts: Annotated[
        int | None, typer.Option("--parts", min=0, help="the simulated PLC plays this many parts, then only beats "
                                                        "its heartbeat (default: parts without end)")
    ] = None,
    part_types: Annotated[
        str | None, typer.Option("--part-types", help="the jobs of the parts the line brings, in turn, e.g. 1,2,2,1 "
                                                      "(default: the config's first part type)")
    ] = None,
) -> None:
    """Start the simulated cell's device processes and keep them running until Ctrl-C or SIGTERM; fault commands
    on standard input (plc|robot <fault>, camera <failure> \\[count]) and calibration faults until cleared (camera
    bump DEG MM \\[AXIS], camera focal PCT, pose drift K MM DEG)."""
    with _stop_signals() as stop:
        try:
            cfg = load_cell_config(config)
            with SimulatedCell.start(cfg, config, state_file, plc=not no_plc, truth_log=truth_log,
                                     parts=parts, part_types=job_numbers("--part-types", part_types)) as cell:
                _say_where(cfg, cell, parts)
                cell.serve(lambda: stop.signum != 0, typer.echo)
                typer.echo(f"stopping ({signal.Signals(stop.signum).name})", err=True)
        except MonoguideError as error:
            fail(error)


# --- private -----------------------------------------------------------------------------------


class _Stop:
    def __init__(self) -> None:
        self.signum = 0  # the signal that asked us to stop (0: none yet)


@contextlib.contextmanager
def _stop_signals() -> Iterator[_Stop]:
    """Ctrl-C and SIGTERM ask the cell to stop (it then stops its devices on the way out); handlers restored."""
    stop = _Stop()

    def _on_signal(signum: int, _frame: object) -> None:
        stop.signum = signum

    previous = {s: signal.signal(s, _on_signal) for s in STOP_SIGNALS}
    try:
        yield stop
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def _say_where(cfg: CellConfig, cell: SimulatedCell, parts: int | None) -> None:
    """Where each device listens (stdout: ``state file ...`` last, once everything runs), notes on stderr."""
    tracker, robot, plc = cell.tracker, cell.robot, cell.plc
    typer.echo(f"tracker listening on {tracker.address} (pid {tracker.process.pid})")
    if robot is not None:
        typer.echo(f"robot ({cell.state['robot']['backend']}) listening on {robot.host}:{robot.port} "
                   f"(pid {robot.process.pid})")
    if plc is not None:
        typer.echo(f"plc listening on {plc.address} unit {cfg.plc.unit} (pid {plc.process.pid})")  # type: ignore[union-attr]
    elif cfg.plc is not None:
        typer.echo(f"plc left out (--no-plc): {cfg.plc.host}:{cfg.plc.port} is free for another server")
    if plc is None and parts is not None:
        typer.echo(f"--parts {parts} ignored: no simulated PLC plays parts", err=True)
    typer.echo(f"state file {cell.state_path}")
    typer.echo("running; Ctrl-C or SIGTERM stops the simulated cell; faults on stdin: plc|robot <fault>, "
               "camera <failure> [count]; calibration faults (until cleared): camera bump DEG MM [AXIS], "
               "camera focal PCT, pose drift K MM DEG", err=True)
