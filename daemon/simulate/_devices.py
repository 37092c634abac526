"""The simulated cell's device processes: how each is started, and the one object that stops them all.

Each device is ``python -m monoguide.drivers.sim.<device>`` (runtime code never imports the simulator: it runs
as a program) and says where it listens in its first line, ``LISTEN <name> <address>``. The tracker listens
behind a pseudo-terminal, the robot controller on ``[robot] host:port`` (with the part supply, fault commands
on its standard input), the line PLC on ``[plc] host:port`` (the same). Killed outright, sim-cell leaves
nothing behind either: each device notices the lost parent and ends.
"""

from __future__ import annotations

import contextlib
import logging
import select
import subprocess
import sys
import time
from pathlib import Path

from monoguide.daemon.config import CellConfig
from monoguide.daemon.simulate._owner import Owner
from monoguide.drivers.errors import DeviceDisconnected, DeviceTimeout

log = logging.getLogger(__name__)

START_TIMEOUT_S = 15.0
STOP_TIMEOUT_S = 3.0
GRASP_WAIT_S = 10.0  # the simulated PLC waits this long for the grasp's outcome before the next part


class Device:
    """One running device process and where it listens."""

    def __init__(self, name: str, process: subprocess.Popen[str], address: str) -> None:
        self.name, self.process, self.address = name, process, address

    @property
    def host(self) -> str:
        return self.address.rpartition(":")[0]

    @property
    def port(self) -> int:
        return int(self.address.rpartition(":")[2])

    def send(self, line: str) -> None:
        """``line`` to its standard input (an :class:`OSError` when it is gone)."""
        assert self.process.stdin is not None  # started with commands=True
        self.process.stdin.write(line + "\n")
        self.process.stdin.flush()


class Devices(Owner):
    """The device processes of one sim-cell (a context manager): on the way out each gets SIGTERM, then SIGKILL
    if it ignores it, and its pipes are closed."""

    def __init__(self) -> None:
        self._processes: list[subprocess.Popen[str]] = []

    def start(self, name: str, argv: list[str], commands: bool = False) -> Device:
        """Start one device process and read its ``LISTEN <name> <address>`` line (with a deadline); ``commands``:
        it takes commands on its standard input."""
        process = subprocess.Popen(argv, stdin=subprocess.PIPE if commands else None, stdout=subprocess.PIPE,
                                   text=True)
        self._processes.append(process)
        deadline = time.monotonic() + START_TIMEOUT_S
        assert process.stdout is not None
        while time.monotonic() < deadline:
            ready, _, _ = select.select([process.stdout], [], [], 0.2)
            if ready:
                line = process.stdout.readline().split()
                if len(line) == 3 and line[:2] == ["LISTEN", name]:
                    return Device(name, process, line[2])
                if not line and process.poll() is not None:
                    break
        ended = process.poll()
        if ended is not None:
            raise DeviceDisconnected(f"simulated {name} ended with status {ended} before it listened")
        raise DeviceTimeout(f"simulated {name} did not say where it listens within {START_TIMEOUT_S:g} s")

    def check_running(self) -> None:
        """:class:`DeviceDisconnected` when one of them has ended."""
        for process in self._processes:
            if process.poll() is not None:
                raise DeviceDisconnected(f"simulated device (pid {process.pid}) ended with status "
                                         f"{process.returncode}")

    def close(self) -> None:
        for process in self._processes:
            if process.poll() is None:
                process.terminate()
        for process in self._processes:
            try:
                process.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                log.warning("simulated device pid %d ignored SIGTERM; killing it", process.pid)
                process.kill()
                process.wait(timeout=STOP_TIMEOUT_S)
            for stream in (process.stdin, process.stdout):
                if stream is not None:
                    with contextlib.suppress(OSError):  # a pipe to a process that is gone
                        stream.close()
        self._processes.clear()


def tracker_argv(targets: Path, seed: int) -> list[str]:
    """The simulated laser tracker measuring the SMR nests of ``targets``."""
    return [sys.executable, "-m", "monoguide.drivers.sim.tracker", "--targets", str(targets), "--seed", str(seed)]


def robot_argv(cfg: CellConfig, spec: Path, truth: Path, seed: int, truth_log: Path | None) -> list[str]:
    """The simulated controller ``[robot] backend`` names, on ``[robot] host:port``, with the part supply on (one
    line per part in ``truth_log``) and fault commands on its standard input."""
    r = cfg.robot
    assert r is not None and r.simulated
    argv = [sys.executable, "-m", f"monoguide.drivers.sim.{r.make}_controller", "--spec", str(spec), "--truth",
            str(truth), "--host", r.host, "--port", str(r.port), "--move-time", str(r.sim_move_time_s),
            "--seed", str(seed), "--part-supply", "--commands"]
    return argv + (["--truth-log", str(truth_log)] if truth_log is not None else [])


def plc_argv(cfg: CellConfig, parts: int | None, grasp: bool, jobs: tuple[int, ...] = (1,)) -> list[str]:
    """The simulated line PLC on ``[plc] host:port`` with the block at ``base`` for ``unit``, playing parts
    (``parts``: that many, then only its heartbeat), asking for the ``jobs`` in turn.
    ``grasp``: it gives the grasp go after each good result and
    waits for the robot's answer (a simulated robot is there)."""
    p = cfg.plc
    assert p is not None
    argv = [sys.executable, "-m", "monoguide.drivers.sim.plc", "--host", p.host, "--port", str(p.port),
            "--unit", str(p.unit), "--base", str(p.base), "--word-order", p.word_order,
            "--heartbeat-period", str(min(0.5, p.heartbeat_timeout_s / 4)), "--jobs", ",".join(map(str, jobs))]
    if parts is not None:
        argv += ["--parts", str(parts)]
    if grasp:
        argv += ["--grasp-wait", str(GRASP_WAIT_S)]
    return argv
