"""`monoguide sim-cell`: run the simulated devices that are their own processes, until stopped.

That is the laser tracker behind a pseudo-terminal; when ``[robot] backend`` is ``sim-ur`` or ``sim-kuka``,
the simulated robot controller on ``[robot] host:port`` (its spec and truth files lie beside the state
file), which also runs the part supply (a new seeded part at every request of measuring pose 1, one line per
part in ``--truth-log``); and, with a ``[plc]`` section and without ``--no-plc``, the simulated line PLC on
``[plc] host:port`` (its per-part records are echoed to stdout as ``plc: {...}``; ``--parts N``: it plays N
parts, then only beats its heartbeat). Where each device listens goes to stdout and to a JSON state file that
``monoguide probe`` (and ``run``) read. Ctrl-C or SIGTERM stops everything; no child process is left behind.

The fault channel: each line of standard input is a command (end of input is fine; the cell runs on):
``plc <fault>`` goes to the simulated PLC's standard input, ``robot <fault>`` to the simulated robot
controller's (both at run time; ``none`` clears; ``robot cut-after-offset MS [DOWN_S]`` takes its numbers),
``camera <failure> [count]`` into the state file as
``"camera_fault": {"failure", "count", "serial"}`` for the daemon's in-process simulated camera (a new
serial per command, so that it applies once). An accepted command is echoed on stdout as ``fault: <device>
<fault>``, a refused one on stderr as ``fault error: <reason>``. The names are the simulator's own
(:data:`FAULT_COMMANDS`; runtime code does not import the simulator, a test checks that they agree).
What the service reports for each: ``docs/plc-interface.md``, "The simulated PLC and its faults".

The grasp: with a simulated robot, the simulated PLC gives the grasp go once it has read DONE + RESULT_OK and
acknowledged the result (it prints ``GRASP {...}``); sim-cell forwards it to the robot controller (``grasp`` on its
standard input), whose program runs the grasp only while its offset is valid and refuses it otherwise
(``docs/robot-interface.md``, the grasp interlock); the controller prints the outcome, ``GRASP {...}``, which
sim-cell passes back to the PLC (``grasped {...}``: the line waits for it before the next part) and echoes as
``grasp: {...}``.

One sim-cell per state file: the claim is an exclusive ``flock`` on ``<state file>.lock``, held for the
process's lifetime (the kernel releases it when the process ends, however it ends), so two sim-cells
started together cannot both run, and only the owner ever writes or deletes the state file.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import math
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Annotated, Any

import typer

from monoguide.daemon.assembly import build_sim_cell, sim_state_file, write_sim_state
from monoguide.daemon.config import CellConfig, load_cell_config
from monoguide.drivers.errors import ConfigError, DeviceBusy, DeviceDisconnected, DeviceTimeout
from monoguide.solver.errors import MonoguideError

log = logging.getLogger(__name__)

START_TIMEOUT_S = 15.0
STOP_TIMEOUT_S = 3.0
EXIT_DEVICE = 1
EXIT_CONFIG = 2
MAX_CAMERA_COUNT = 1000
MAX_CUT_MS = 60_000.0  # robot cut-after-offset MS [DOWN_S]: MS 0..60000, DOWN_S above 0 up to 60 (the simulator's)
GRASP_WAIT_S = 10.0  # the simulated PLC waits this long for the grasp's outcome before the next part

# the faults each simulated device takes (drivers/sim/plc.py FAULTS, drivers/sim/robot_motion.py FAULT_MODES,
# drivers/sim/camera.py FAILURES): copied, since runtime code never imports the simulator;
# tests/daemon/test_cmd_simcell.py checks that they agree
FAULT_COMMANDS: dict[str, tuple[str, ...]] = {
    "plc": ("none", "trigger-dropped-early", "heartbeat-stopped", "no-ack"),
    "robot": ("none", "stall", "drop", "protective-stop", "never-reach", "no-ack", "program-stopped"),
    "camera": ("timeout", "disconnect", "black", "occluded", "glare"),
}
# the robot's one-shot faults (drivers/sim/robot_motion.py FAULT_ACTIONS): Stop/Play now, the cut after the next
# offset (``robot cut-after-offset MS [DOWN_S]``); copied likewise, checked by tests/drivers/test_robot_faults.py
ROBOT_ACTIONS: tuple[str, ...] = ("restart", "cut-after-offset")


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
) -> None:
    """Start the simulated cell's device processes and keep them running until Ctrl-C or SIGTERM; fault commands
    on standard input (plc|robot <fault>, camera <failure> \\[count])."""
    stop = {"signal": 0}

    def _on_signal(signum: int, _frame: object) -> None:
        stop["signal"] = signum

    previous = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    children: list[subprocess.Popen[str]] = []
    claim: _StateFileClaim | None = None
    targets_path: Path | None = None
    robot_files: tuple[Path, ...] = ()
    try:
        cfg = load_cell_config(config)
        if cfg.tracker is None:
            raise ConfigError(f"{cfg.path}: no [tracker] section: sim-cell has nothing to simulate")
        if cfg.tracker.backend != "sim":
            raise ConfigError(f"{cfg.path}: [tracker].backend = {cfg.tracker.backend!r}: sim-cell simulates only "
                              f"'sim' devices")
        if truth_log is not None and (cfg.robot is None or not cfg.robot.simulated):
            raise ConfigError(f"--truth-log {truth_log}: the part supply runs in the simulated robot controller; "
                              f"{cfg.path} has no [robot] backend = \"sim-ur\" or \"sim-kuka\"")
        claim = _StateFileClaim.take(state_file or sim_state_file(cfg))
        state_path = claim.path
        cell = build_sim_cell(cfg)
        targets_path = cell.write_tracker_targets(state_path.with_name(state_path.stem + "-tracker-targets.json"))
        tracker = _start(
            [sys.executable, "-m", "monoguide.drivers.sim.tracker", "--targets", str(targets_path),
             "--seed", str(cell.spec.seed + 2)],
            "tracker",
        )
        children.append(tracker.process)
        state = {
            "pid": os.getpid(),
            "config": str(Path(config).resolve()),
            "tracker": {"port": tracker.address, "pid": tracker.process.pid, "targets": str(targets_path)},
        }
        robot_files = _robot_files(cfg, state_path)
        robot = None
        if robot_files:
            robot = _start_robot(cfg, cell, *robot_files, truth_log)
            children.append(robot.process)
            state["robot"] = robot.state
        plc = None if no_plc or cfg.plc is None else _start_plc(cfg, parts, grasp=robot is not None)
        if plc is not None:
            children.append(plc.process)
            host, _, port = plc.address.rpartition(":")
            state["plc"] = {"host": host, "port": int(port), "pid": plc.process.pid}
        write_sim_state(state_path, state)
        typer.echo(f"tracker listening on {tracker.address} (pid {tracker.process.pid})")
        if "robot" in state:
            typer.echo(f"robot ({state['robot']['backend']}) listening on {state['robot']['host']}:"
                       f"{state['robot']['port']} (pid {state['robot']['pid']})")
        if plc is not None:
            typer.echo(f"plc listening on {plc.address} unit {cfg.plc.unit} (pid {plc.process.pid})")  # type: ignore[union-attr]
        elif cfg.plc is not None:
            typer.echo(f"plc left out (--no-plc): {cfg.plc.host}:{cfg.plc.port} is free for another server")
        if plc is None and parts is not None:
            typer.echo(f"--parts {parts} ignored: no simulated PLC plays parts", err=True)
        typer.echo(f"state file {state_path}")
        typer.echo("running; Ctrl-C or SIGTERM stops the simulated cell; faults on stdin: plc|robot <fault>, "
                   "camera <failure> [count]", err=True)
        sys.stdout.flush()
        faults = _FaultChannel(cfg, state_path, state, plc, robot.process if robot is not None else None)
        plc_lines = _Lines(plc.process.stdout.fileno()) if plc is not None and plc.process.stdout else None
        robot_lines = _Lines(robot.process.stdout.fileno()) if robot is not None and robot.process.stdout else None
        commands = _Lines(0) if _stdin_open() else None
        while not stop["signal"]:
            for child in children:
                if child.poll() is not None:
                    raise DeviceDisconnected(f"simulated device (pid {child.pid}) ended with status "
                                             f"{child.returncode}")
            _serve_once(plc_lines, commands, faults, robot_lines)
        typer.echo(f"stopping ({signal.Signals(stop['signal']).name})", err=True)
    except OSError as exc:  # a state or targets file that cannot be written where the config puts it
        error = ConfigError(f"cannot write {exc.filename or 'a sim-cell file'}: {exc.strerror or exc}")
        typer.echo(f"config error {error.code} (PLC {error.plc_code}): {error.message}", err=True)
        raise typer.Exit(EXIT_CONFIG) from exc
    except ConfigError as exc:
        typer.echo(f"config error {exc.code} (PLC {exc.plc_code}): {exc.message}", err=True)
        raise typer.Exit(EXIT_CONFIG) from exc
    except MonoguideError as exc:
        typer.echo(f"error {exc.code} (PLC {exc.plc_code}): {exc.message}", err=True)
        raise typer.Exit(EXIT_DEVICE) from exc
    finally:
        _stop_all(children)
        if claim is not None:  # only the owner deletes: a refused sim-cell leaves the running one's files alone
            claim.release(targets_path, *robot_files)
        for s, handler in previous.items():
            signal.signal(s, handler)


# --- private -----------------------------------------------------------------------------------


class _StateFileClaim:
    """This process's claim on a state file: an exclusive ``flock`` on ``<path>.lock`` holding our pid."""

    def __init__(self, path: Path, lock_path: Path, fd: int) -> None:
        self.path = path
        self.lock_path = lock_path
        self._fd = fd

    @classmethod
    def take(cls, path: Path) -> _StateFileClaim:
        """Claim ``path`` atomically; :class:`DeviceBusy` naming it when a running sim-cell holds it,
        :class:`ConfigError` when it cannot be a state file (a directory, an unwritable place). A state file
        left by a dead sim-cell is taken over."""
        lock_path = path.with_name(path.name + ".lock")
        for candidate, what in ((path, "state file"), (lock_path, "state file's lock")):
            if candidate.is_dir():
                raise ConfigError(f"{what} {candidate} is a directory; give --state-file a file path")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigError(f"state file {path}: cannot create its folder: {exc}") from exc
        for _ in range(5):
            try:
                fd = os.open(lock_path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            except OSError as exc:
                raise ConfigError(f"state file {path}: cannot open its lock {lock_path}: {exc}") from exc
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                owner = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "?"
                os.close(fd)
                raise DeviceBusy(f"a simulated cell is already running (pid {owner}) with state file {path}; stop "
                                 f"it or give another --state-file") from None
            if _same_file(fd, lock_path):  # not unlinked by its last owner between our open and our lock
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
                return cls(path, lock_path, fd)
            os.close(fd)
        raise DeviceBusy(f"state file {path}: its lock {lock_path} keeps changing hands; try again")

    def release(self, *more: Path | None) -> None:
        """Delete the state file (and ``more`` files of this sim-cell), then the lock, while still holding it."""
        for path in (self.path, *more, self.lock_path):
            if path is not None:
                try:
                    path.unlink(missing_ok=True)
                except OSError as exc:
                    log.warning("cannot remove %s: %s", path, exc)
        os.close(self._fd)


def _same_file(fd: int, path: Path) -> bool:
    try:
        return os.fstat(fd).st_ino == os.stat(path).st_ino
    except FileNotFoundError:
        return False


def _robot_files(cfg: CellConfig, state_path: Path) -> tuple[Path, ...]:
    """The simulated robot's spec and truth files beside the state file; none when the robot is not simulated."""
    if cfg.robot is None or not cfg.robot.simulated:
        return ()
    return (state_path.with_name(state_path.stem + "-robot.json"),
            state_path.with_name(state_path.stem + "-robot-truth.json"))


class _StartedRobot:
    def __init__(self, process: subprocess.Popen[str], state: dict[str, object]) -> None:
        self.process = process
        self.state = state


def _start_robot(cfg: CellConfig, cell: Any, spec_path: Path, truth_path: Path,
                 truth_log: Path | None) -> _StartedRobot:
    """Start the simulated controller ``[robot] backend`` names, on ``[robot] host:port``, with the part supply
    on; ``cell`` is the :class:`SimCell` (not imported here: runtime modules never import the simulator)."""
    r = cfg.robot
    assert r is not None
    cell.write_robot_spec(spec_path)
    argv = [sys.executable, "-m", f"monoguide.drivers.sim.{r.make}_controller", "--spec", str(spec_path), "--truth",
            str(truth_path), "--host", r.host, "--port", str(r.port), "--move-time", str(r.sim_move_time_s),
            "--seed", str(cell.spec.seed + 3), "--part-supply", "--commands"]
    if truth_log is not None:
        truth_log.resolve().parent.mkdir(parents=True, exist_ok=True)
        truth_log.write_text("")  # can it be written? (OSError: a config error naming it)
        argv += ["--truth-log", str(truth_log.resolve())]
    started = _start(argv, "robot", stdin=subprocess.PIPE)
    host, _, port = started.address.rpartition(":")
    return _StartedRobot(started.process, {"backend": r.backend, "host": host, "port": int(port),
                                           "pid": started.process.pid, "spec": str(spec_path),
                                           "truth": str(truth_path)})


def _start_plc(cfg: CellConfig, parts: int | None, grasp: bool = False) -> _Started:
    """Start the simulated line PLC on ``[plc] host:port`` with the block at ``base`` for ``unit``, playing parts
    (``parts``: that many, then only its heartbeat); its standard input takes the fault commands. ``grasp``: it
    gives the grasp go after each good result and waits for the robot's answer (a simulated robot is there)."""
    p = cfg.plc
    assert p is not None
    argv = [sys.executable, "-m", "monoguide.drivers.sim.plc", "--host", p.host, "--port", str(p.port),
            "--unit", str(p.unit), "--base", str(p.base), "--word-order", p.word_order,
            "--heartbeat-period", str(min(0.5, p.heartbeat_timeout_s / 4))]
    if parts is not None:
        argv += ["--parts", str(parts)]
    if grasp:
        argv += ["--grasp-wait", str(GRASP_WAIT_S)]
    return _start(argv, "plc", stdin=subprocess.PIPE)


class _Lines:
    """Whole lines read from a file descriptor once ``select`` finds it readable (a part line waits)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.open = True
        self._buffer = b""

    def read(self) -> list[str]:
        try:
            chunk = os.read(self.fd, 65536)
        except OSError:
            chunk = b""
        if not chunk:  # end of input: what is left is the last line
            self.open = False
            chunk = b"\n"
        *lines, self._buffer = (self._buffer + chunk).split(b"\n")
        return [text for line in lines if (text := line.decode("utf-8", "replace").strip())]


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


def _serve_once(plc_lines: _Lines | None, commands: _Lines | None, faults: _FaultChannel,
                robot_lines: _Lines | None = None, wait_s: float = 0.1) -> None:
    """Wait up to ``wait_s`` for the PLC's per-part records (echoed; its stdout pipe must not fill up) and grasp
    goes (to the robot), the robot's grasp outcomes (to the PLC, echoed) and fault commands on standard input."""
    watched = {lines.fd: lines for lines in (plc_lines, commands, robot_lines) if lines is not None and lines.open}
    if commands is not None and commands.fd in watched and not _stdin_readable_now():
        del watched[commands.fd]
    if not watched:
        time.sleep(wait_s)
        return
    ready, _, _ = select.select(list(watched), [], [], wait_s)
    for fd in ready:
        for line in watched[fd].read():
            if watched[fd] is plc_lines and line.startswith(GRASP_LINE):
                _relay(faults, "robot", GRASP_GO)  # the PLC's go, for the robot program
            elif watched[fd] is plc_lines:
                typer.echo(f"plc: {line}")
            elif watched[fd] is robot_lines and line.startswith(GRASP_LINE):
                outcome = line[len(GRASP_LINE):].strip()
                _relay(faults, "plc", f"{GRASP_ANSWER} {outcome}")  # the robot's answer, for the line
                typer.echo(f"grasp: {outcome}")
            elif watched[fd] is robot_lines:
                log.info("simulated robot said: %s", line)
            else:
                faults.handle(line)
        sys.stdout.flush()


def _relay(faults: _FaultChannel, device: str, line: str) -> None:
    try:
        faults.relay(device, line)
    except ValueError as exc:  # the device is gone: the loop notices and ends
        log.warning("%s", exc)


GRASP_LINE = "GRASP "  # the simulated PLC's go and the robot's outcome, each on its standard output
GRASP_GO = "grasp"  # to the robot controller's standard input
GRASP_ANSWER = "grasped"  # to the simulated PLC's standard input, with the outcome's JSON


class _FaultChannel:
    """The fault commands of standard input, checked, then forwarded to the device that plays them."""

    def __init__(self, cfg: CellConfig, state_path: Path, state: dict[str, Any], plc: _Started | None,
                 robot: subprocess.Popen[str] | None) -> None:
        self.state_path, self.state = state_path, state
        # the daemon's simulated camera reads the state file only in a cell whose robot is simulated too
        # (daemon/assembly.py build_camera)
        self.camera_follows = cfg.camera.backend == "sim" and cfg.robot is not None and cfg.robot.simulated
        self.children = {"plc": plc.process if plc is not None else None, "robot": robot}
        self.absent = {"plc": "no simulated PLC in this cell (--no-plc, or no [plc] section)",
                       "robot": "no simulated robot in this cell ([robot] backend is not sim-ur or sim-kuka)"}
        self.serial = 0

    def handle(self, text: str) -> None:
        if text.startswith("#"):
            return
        try:
            device, fault, count = self._forward(text)
        except ValueError as exc:
            typer.echo(f"fault error: {exc}", err=True)
            return
        log.info("fault %s %s%s", device, fault, f" x{count}" if count is not None else "")
        typer.echo(f"fault: {device} {fault}")

    def _forward(self, text: str) -> tuple[str, str, int | None]:
        device, *words = text.split()
        if device not in FAULT_COMMANDS:
            raise ValueError(f"{text!r}: unknown device {device!r}; expected one of {', '.join(FAULT_COMMANDS)}")
        names = FAULT_COMMANDS[device] + (ROBOT_ACTIONS if device == "robot" else ())
        if not words:
            raise ValueError(f"{text!r}: which fault? {device} takes {', '.join(names)}")
        fault, *rest = words
        if fault not in names:
            raise ValueError(f"{text!r}: unknown {device} fault {fault!r}; expected one of {', '.join(names)}")
        if device == "camera":
            return device, fault, self._camera(text, fault, rest)
        if device == "robot" and fault == "cut-after-offset":
            _check_cut(text, rest)
        elif rest:
            raise ValueError(f"{text!r}: {device} {fault} takes nothing more, got {' '.join(rest)!r}")
        if self.children[device] is None:
            raise ValueError(f"{text!r}: {self.absent[device]}")
        self.relay(device, " ".join([fault, *rest]), text)
        return device, fault, None

    def relay(self, device: str, line: str, what: str | None = None) -> None:
        """``line`` to the standard input of the simulated ``device`` (none in this cell: nothing to do)."""
        child = self.children[device]
        if child is None:
            return
        try:
            assert child.stdin is not None
            child.stdin.write(line + "\n")
            child.stdin.flush()
        except OSError as exc:
            raise ValueError(f"{what or line!r}: the simulated {device} (pid {child.pid}) is gone: {exc}") from exc

    def _camera(self, text: str, failure: str, rest: list[str]) -> int:
        if not self.camera_follows:
            raise ValueError(f"{text!r}: no simulated camera follows this cell ([camera] backend 'sim' and [robot] "
                             f"backend 'sim-ur' or 'sim-kuka' needed)")
        if len(rest) > 1 or (rest and not rest[0].isdigit()) or not 1 <= (count := int(rest[0]) if rest else 1) \
                <= MAX_CAMERA_COUNT:
            raise ValueError(f"{text!r}: count must be a whole number of grabs, 1 to {MAX_CAMERA_COUNT}")
        self.serial += 1
        self.state["camera_fault"] = {"failure": failure, "count": count, "serial": self.serial}
        try:
            write_sim_state(self.state_path, self.state)
        except OSError as exc:
            raise ValueError(f"{text!r}: cannot write the state file {self.state_path}: {exc}") from exc
        return count


def _check_cut(text: str, numbers: list[str]) -> None:
    """``robot cut-after-offset MS [DOWN_S]``: MS 0..60000 ms, DOWN_S above 0 up to 60 s (default 1)."""
    try:
        values = [float(v) for v in numbers]
    except ValueError:
        values = []
    if not 1 <= len(numbers) <= 2 or len(values) != len(numbers) or not all(math.isfinite(v) for v in values) \
            or not 0 <= values[0] <= MAX_CUT_MS or (len(values) == 2 and not 0 < values[1] <= MAX_CUT_MS / 1000):
        raise ValueError(f"{text!r}: robot cut-after-offset takes MS (0 to {MAX_CUT_MS:g}) and optionally DOWN_S "
                         f"(seconds, above 0 up to {MAX_CUT_MS / 1000:g}; default 1)")


class _Started:
    def __init__(self, process: subprocess.Popen[str], address: str) -> None:
        self.process = process
        self.address = address


def _start(argv: list[str], name: str, stdin: int | None = None) -> _Started:
    """Start one device process and read its ``LISTEN <name> <address>`` line (with a deadline)."""
    process = subprocess.Popen(argv, stdin=stdin, stdout=subprocess.PIPE, text=True)
    deadline = time.monotonic() + START_TIMEOUT_S
    assert process.stdout is not None
    while time.monotonic() < deadline:
        ready, _, _ = select.select([process.stdout], [], [], 0.2)
        if ready:
            line = process.stdout.readline().split()
            if len(line) == 3 and line[:2] == ["LISTEN", name]:
                return _Started(process, line[2])
            if not line and process.poll() is not None:
                break
    ended = process.poll()
    _stop_all([process])
    if ended is not None:
        raise DeviceDisconnected(f"simulated {name} ended with status {ended} before it listened")
    raise DeviceTimeout(f"simulated {name} did not say where it listens within {START_TIMEOUT_S:g} s")


def _stop_all(children: list[subprocess.Popen[str]]) -> None:
    for child in children:
        if child.poll() is None:
            child.terminate()
    for child in children:
        try:
            child.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            log.warning("simulated device pid %d ignored SIGTERM; killing it", child.pid)
            child.kill()
            child.wait(timeout=STOP_TIMEOUT_S)
        for stream in (child.stdin, child.stdout):
            if stream is not None:
                with contextlib.suppress(OSError):  # a pipe to a process that is gone
                    stream.close()
