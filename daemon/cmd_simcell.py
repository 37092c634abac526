"""`monoguide sim-cell`: run the simulated devices that are their own processes, until stopped.

That is the laser tracker behind a pseudo-terminal; when ``[robot] backend`` is ``sim-ur`` or ``sim-kuka``,
the simulated robot controller on ``[robot] host:port`` (its spec and truth files lie beside the state
file), which also runs the part supply (a new seeded part at every request of measuring pose 1, one line per
part in ``--truth-log``); and, with a ``[plc]`` section and without ``--no-plc``, the simulated line PLC on
``[plc] host:port`` (its per-part records are echoed to stdout as ``plc: {...}``). Where each device listens
goes to stdout and to a JSON state file that ``monoguide probe`` (and ``run``) read. Ctrl-C or SIGTERM stops
everything; no child process is left behind.

One sim-cell per state file: the claim is an exclusive ``flock`` on ``<state file>.lock``, held for the
process's lifetime (the kernel releases it when the process ends, however it ends), so two sim-cells
started together cannot both run, and only the owner ever writes or deletes the state file.
"""

from __future__ import annotations

import fcntl
import logging
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


def sim_cell(
    config: Annotated[Path, typer.Option("--config", "-c", help="cell config (TOML)")],
    state_file: Annotated[
        Path | None, typer.Option("--state-file", help="where to write where the devices listen")
    ] = None,
    no_plc: Annotated[
        bool, typer.Option("--no-plc", help="leave the PLC out: another server can listen where [plc] says")
    ] = False,
    truth_log: Annotated[
        Path | None, typer.Option("--truth-log", help="one JSON line per part: its true pose, offsets, grasp error")
    ] = None,
) -> None:
    """Start the simulated cell's device processes and keep them running until Ctrl-C or SIGTERM."""
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
        if robot_files:
            robot = _start_robot(cfg, cell, *robot_files, truth_log)
            children.append(robot.process)
            state["robot"] = robot.state
        plc = None if no_plc or cfg.plc is None else _start_plc(cfg)
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
        typer.echo(f"state file {state_path}")
        typer.echo("running; Ctrl-C or SIGTERM stops the simulated cell", err=True)
        sys.stdout.flush()
        while not stop["signal"]:
            for child in children:
                if child.poll() is not None:
                    raise DeviceDisconnected(f"simulated device (pid {child.pid}) ended with status "
                                             f"{child.returncode}")
            _echo_plc_records(plc)
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
            "--seed", str(cell.spec.seed + 3), "--part-supply"]
    if truth_log is not None:
        truth_log.resolve().parent.mkdir(parents=True, exist_ok=True)
        truth_log.write_text("")  # can it be written? (OSError: a config error naming it)
        argv += ["--truth-log", str(truth_log.resolve())]
    started = _start(argv, "robot")
    host, _, port = started.address.rpartition(":")
    return _StartedRobot(started.process, {"backend": r.backend, "host": host, "port": int(port),
                                           "pid": started.process.pid, "spec": str(spec_path),
                                           "truth": str(truth_path)})


def _start_plc(cfg: CellConfig) -> _Started:
    """Start the simulated line PLC on ``[plc] host:port`` with the block at ``base`` for ``unit``, playing parts."""
    p = cfg.plc
    assert p is not None
    return _start([sys.executable, "-m", "monoguide.drivers.sim.plc", "--host", p.host, "--port", str(p.port),
                   "--unit", str(p.unit), "--base", str(p.base), "--word-order", p.word_order,
                   "--heartbeat-period", str(min(0.5, p.heartbeat_timeout_s / 4))], "plc", stdin=subprocess.DEVNULL)


def _echo_plc_records(plc: _Started | None, wait_s: float = 0.1) -> None:
    """Wait ``wait_s``, echoing the PLC's per-part records meanwhile (its stdout pipe must not fill up)."""
    if plc is None or plc.process.stdout is None or plc.process.poll() is not None:
        time.sleep(wait_s)
        return
    ready, _, _ = select.select([plc.process.stdout], [], [], wait_s)
    if ready and (line := plc.process.stdout.readline().strip()):
        typer.echo(f"plc: {line}")
        sys.stdout.flush()


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
        if child.stdout is not None:
            child.stdout.close()
