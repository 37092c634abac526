"""A running simulated cell, what ``monoguide sim-cell`` runs: its device processes, its state file, the fault
channel on standard input and the relay of the grasp between the line and the robot.

:meth:`SimulatedCell.start` claims the state file (:mod:`._state_claim`), starts the laser tracker behind a
pseudo-terminal; when ``[robot] backend`` is ``sim-ur`` or ``sim-kuka``, the simulated robot controller on
``[robot] host:port`` (its spec and truth files beside the state file), which also runs the part supply (a new
seeded part at every request of measuring pose 1, one line per part in ``truth_log``); and, with a ``[plc]``
section and ``plc``, the simulated line PLC on ``[plc] host:port`` (``parts``: it plays that many, then only
beats its heartbeat). Then it writes where each device listens into the state file, which ``monoguide probe``
(and ``run``) read, and the named pipe beside it (``commands``) that takes sim-cell's commands from another
process (``monoguide check`` asks for the reference part there; :mod:`._requests`). The cell is a context
manager: on the way out, however it ends, the devices are stopped, then the state file and the files beside it
are deleted and the claim released.

:meth:`SimulatedCell.serve` echoes the PLC's per-part records (``plc: {...}``), takes the fault commands of standard
input and of the command pipe (:mod:`._fault_channel`) and relays the grasp: with a simulated robot, the simulated
PLC gives the grasp go once it has read DONE + RESULT_OK and acknowledged the result (it prints ``GRASP {...}``);
the cell forwards it to the robot controller (``grasp`` on its standard input), whose program runs the grasp only
while its offset is valid and refuses it otherwise (``docs/robot-interface.md``, the grasp interlock); the
controller prints the outcome, ``GRASP {...}``, which the cell passes back to the PLC (``grasped {...}``: the line
waits for it before the next part) and echoes as ``grasp: {...}``.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from monoguide.daemon.assembly import build_sim_cell, sim_state_file, write_sim_state
from monoguide.daemon.config import CellConfig
from monoguide.daemon.simulate._devices import Device, Devices, plc_argv, robot_argv, tracker_argv
from monoguide.daemon.simulate._fault_channel import FaultChannel
from monoguide.daemon.simulate._owner import Owner
from monoguide.daemon.simulate._state_claim import StateFileClaim
from monoguide.drivers.errors import ConfigError

log = logging.getLogger(__name__)

SERVE_WAIT_S = 0.1  # the longest the loop waits for a line before it checks the devices and the stop again
GRASP_LINE = "GRASP "  # the simulated PLC's go and the robot's outcome, each on its standard output
GRASP_GO = "grasp"  # to the robot controller's standard input
GRASP_ANSWER = "grasped"  # to the simulated PLC's standard input, with the outcome's JSON

Echo = Callable[..., Any]  # echo(line, err=False): a line to sim-cell's standard output (or error)


class SimulatedCell(Owner):
    """The simulated cell's running devices and its state file; see the module's doc."""

    def __init__(self, cfg: CellConfig, state_path: Path, state: dict[str, Any], devices: Devices,
                 tracker: Device, robot: Device | None, plc: Device | None, resources: contextlib.ExitStack,
                 commands: int) -> None:
        self.state_path, self.state = state_path, state
        self.tracker, self.robot, self.plc = tracker, robot, plc
        self._devices, self._resources = devices, resources
        self._commands = commands  # the read end of the command pipe (closed with the resources)
        # the daemon's simulated camera reads the state file only in a cell whose robot is simulated too
        # (daemon/assembly.py build_camera)
        self._camera_follows = cfg.camera.backend == "sim" and cfg.robot is not None and cfg.robot.simulated

    @classmethod
    def start(cls, cfg: CellConfig, config: Path, state_file: Path | None = None, *, plc: bool = True,
              truth_log: Path | None = None, parts: int | None = None,
              part_types: tuple[int, ...] = ()) -> SimulatedCell:
        """Start the cell of ``cfg`` (read from ``config``); :class:`ConfigError` when it has nothing to simulate or
        a file cannot be written, :class:`DeviceBusy` when another sim-cell holds the state file, a device error
        when a device does not start. Nothing is left running or claimed when it fails. ``part_types``: the jobs of
        the parts the line brings, in turn (the part supply presents them, the simulated PLC asks for them);
        default: the config's first part type."""
        _check(cfg, truth_log)
        if bad := [job for job in part_types if job not in cfg.jobs]:
            raise ConfigError(f"--part-types {','.join(map(str, part_types))}: {bad} not among the jobs of {cfg.path} "
                              f"({', '.join(p.describe() for p in cfg.parts)})")
        try:
            return cls._start(cfg, config, state_file or sim_state_file(cfg), plc, truth_log, parts,
                              part_types or (cfg.jobs[0],))
        except OSError as exc:  # a state or targets file that cannot be written where the config puts it
            raise ConfigError(f"cannot write {exc.filename or 'a sim-cell file'}: {exc.strerror or exc}") from exc

    def serve(self, stopped: Callable[[], bool], echo: Echo) -> None:
        """Until ``stopped()``: echo the PLC's records, relay the grasp, take fault commands on standard input (its
        end is fine: the cell runs on); :class:`DeviceDisconnected` when a device process ends."""
        faults = FaultChannel({"plc": self.plc, "robot": self.robot},
                              self._write_camera_fault if self._camera_follows else None, echo)
        plc_lines = _Lines.of(self.plc)
        robot_lines = _Lines.of(self.robot)
        commands = _Lines(0) if _stdin_open() else None
        piped = _Lines(self._commands)  # the same commands from another process (monoguide check)
        while not stopped():
            self._devices.check_running()
            watched = [lines for lines in (plc_lines, commands, piped, robot_lines) if lines is not None and lines.open]
            if commands in watched and not _stdin_readable_now():
                watched.remove(commands)
            for lines, line in _ready_lines(watched, SERVE_WAIT_S):
                if lines is plc_lines and line.startswith(GRASP_LINE):
                    self._relay(self.robot, GRASP_GO)  # the PLC's go, for the robot program
                elif lines is plc_lines:
                    echo(f"plc: {line}")
                elif lines is robot_lines and line.startswith(GRASP_LINE):
                    outcome = line[len(GRASP_LINE):].strip()
                    self._relay(self.plc, f"{GRASP_ANSWER} {outcome}")  # the robot's answer, for the line
                    echo(f"grasp: {outcome}")
                elif lines is robot_lines:
                    log.info("simulated robot said: %s", line)
                else:
                    faults.handle(line)

    def close(self) -> None:
        """Stop the devices, then delete the state file and the files beside it and release the claim."""
        self._resources.close()

    @classmethod
    def _start(cls, cfg: CellConfig, config: Path, state_path: Path, plc: bool, truth_log: Path | None,
               parts: int | None, part_types: tuple[int, ...]) -> SimulatedCell:
        with contextlib.ExitStack() as resources:
            claim = resources.enter_context(StateFileClaim.take(state_path))
            devices = resources.enter_context(Devices())  # stopped before the claim's files are deleted
            sim = build_sim_cell(cfg)  # the SimCell (not imported here: runtime modules never import the simulator)
            targets = sim.write_tracker_targets(claim.beside("-tracker-targets.json"))
            tracker = devices.start("tracker", tracker_argv(targets, sim.spec.seed + 2))
            state: dict[str, Any] = {
                "pid": os.getpid(),
                "config": str(Path(config).resolve()),
                "tracker": {"port": tracker.address, "pid": tracker.process.pid, "targets": str(targets)},
            }
            robot = None
            if cfg.robot is not None and cfg.robot.simulated:
                robot, state["robot"] = _start_robot(cfg, sim, claim, devices, truth_log, part_types)
            state["commands"], commands = _command_pipe(claim, resources)
            line = None
            if plc and cfg.plc is not None:
                line = devices.start("plc", plc_argv(cfg, parts, grasp=robot is not None, jobs=part_types),
                                     commands=True)
                state["plc"] = {"host": line.host, "port": line.port, "pid": line.process.pid}
            write_sim_state(claim.path, state)
            return cls(cfg, claim.path, state, devices, tracker, robot, line, resources.pop_all(), commands)

    def _relay(self, device: Device | None, line: str) -> None:
        """``line`` to the standard input of a simulated ``device`` (none in this cell: nothing to do)."""
        if device is None:
            return
        try:
            device.send(line)
        except OSError as exc:  # the device is gone: the loop notices and ends
            log.warning("%r: the simulated %s (pid %d) is gone: %s", line, device.name, device.process.pid, exc)

    def _write_camera_fault(self, fault: dict[str, Any]) -> None:
        self.state["camera_fault"] = fault
        try:
            write_sim_state(self.state_path, self.state)
        except OSError as exc:
            raise ValueError(f"cannot write the state file {self.state_path}: {exc}") from exc


# --- private ------------------------------------------------------------------------------------


def _check(cfg: CellConfig, truth_log: Path | None) -> None:
    """A cell sim-cell can run: a simulated tracker; a truth log only with a simulated robot (its part supply)."""
    if cfg.tracker is None:
        raise ConfigError(f"{cfg.path}: no [tracker] section: sim-cell has nothing to simulate")
    if cfg.tracker.backend != "sim":
        raise ConfigError(f"{cfg.path}: [tracker].backend = {cfg.tracker.backend!r}: sim-cell simulates only "
                          f"'sim' devices")
    if truth_log is not None and (cfg.robot is None or not cfg.robot.simulated):
        raise ConfigError(f"--truth-log {truth_log}: the part supply runs in the simulated robot controller; "
                          f"{cfg.path} has no [robot] backend = \"sim-ur\" or \"sim-kuka\"")


def _command_pipe(claim: StateFileClaim, resources: contextlib.ExitStack) -> tuple[str, int]:
    """The named pipe beside the state file that takes sim-cell's commands from other processes (mode 0600: only
    this user's), and its read end. sim-cell holds a write end too, so that a writer closing it is no end of
    input; both are closed with ``resources``, and the claim deletes the pipe."""
    path = claim.beside("-commands")
    path.unlink(missing_ok=True)  # a killed sim-cell's
    os.mkfifo(path, 0o600)
    read = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    resources.callback(os.close, read)
    resources.callback(os.close, os.open(path, os.O_WRONLY | os.O_NONBLOCK | os.O_CLOEXEC))
    return str(path), read


def _start_robot(cfg: CellConfig, sim: Any, claim: StateFileClaim, devices: Devices,
                 truth_log: Path | None, part_types: tuple[int, ...]) -> tuple[Device, dict[str, Any]]:
    """The simulated robot controller with its spec and truth files beside the state file; its state entry."""
    assert cfg.robot is not None
    spec, truth = claim.beside("-robot.json"), claim.beside("-robot-truth.json")
    sim.write_robot_spec(spec, part_types=part_types)
    if truth_log is not None:
        truth_log = truth_log.resolve()
        truth_log.parent.mkdir(parents=True, exist_ok=True)
        truth_log.write_text("")  # can it be written? (OSError: a config error naming it)
    robot = devices.start("robot", robot_argv(cfg, spec, truth, sim.spec.seed + 3, truth_log), commands=True)
    return robot, {"backend": cfg.robot.backend, "host": robot.host, "port": robot.port, "pid": robot.process.pid,
                   "spec": str(spec), "truth": str(truth)}


class _Lines:
    """Whole lines read from a file descriptor once ``select`` finds it readable (a part line waits)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.open = True
        self._buffer = b""

    @classmethod
    def of(cls, device: Device | None) -> _Lines | None:
        """The lines of a device's standard output (no device: none)."""
        if device is None or device.process.stdout is None:
            return None
        return cls(device.process.stdout.fileno())

    def fileno(self) -> int:
        return self.fd

    def read(self) -> list[str]:
        try:
            chunk = os.read(self.fd, 65536)
        except BlockingIOError:  # the command pipe: nothing after all
            return []
        except OSError:
            chunk = b""
        if not chunk:  # end of input: what is left is the last line
            self.open = False
            chunk = b"\n"
        *lines, self._buffer = (self._buffer + chunk).split(b"\n")
        return [text for line in lines if (text := line.decode("utf-8", "replace").strip())]


def _ready_lines(watched: list[_Lines], wait_s: float) -> list[tuple[_Lines, str]]:
    """The lines that came within ``wait_s`` on any of ``watched``, each with where it came from."""
    if not watched:
        time.sleep(wait_s)
        return []
    ready, _, _ = select.select(watched, [], [], wait_s)
    return [(lines, line) for lines in ready for line in lines.read()]


def _stdin_open() -> bool:
    try:
        os.fstat(0)
    except OSError:
        return False
    return True


def _stdin_readable_now() -> bool:
    """Not a terminal of which we are in the background (reading it would stop us with SIGTTIN)."""
    try:
        return not os.isatty(0) or os.tcgetpgrp(0) == os.getpgrp()
    except OSError:
        return False
