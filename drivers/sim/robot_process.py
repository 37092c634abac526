"""Start and stop a simulated robot controller process (tests, benchmarks; ``sim-cell`` has its own loop)."""

from __future__ import annotations

import contextlib
import json
import os
import select
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from monoguide.drivers.sim.robot_motion import read_truth
from monoguide.drivers.sim.robot_serve import GRASP_COMMAND

CONTROLLER_MODULES = {"ur": "monoguide.drivers.sim.ur_controller", "kuka": "monoguide.drivers.sim.kuka_controller"}
START_TIMEOUT_S = 15.0
STOP_TIMEOUT_S = 3.0


@dataclass
class ControllerProcess:
    process: subprocess.Popen[str]
    host: str
    port: int
    truth: Path
    commands_sent: int = 0
    _said: str = ""  # standard output read but not yet taken

    def stop(self) -> None:
        stop_process(self.process)

    def command(self, fault: str, timeout_s: float = 5.0) -> None:
        """Send a fault command (started with ``commands=True``; ``none`` clears a mode) and wait until the
        controller has applied it (its truth file counts the commands it applied), so that the next request meets
        it."""
        self._send(fault)
        self.commands_sent += 1
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with contextlib.suppress(OSError, ValueError):
                if int(read_truth(self.truth).get("commands_applied", 0)) >= self.commands_sent:  # type: ignore[arg-type]
                    return
            time.sleep(0.005)
        raise TimeoutError(f"the simulated controller did not take up fault {fault!r} within {timeout_s:g} s")

    def grasp(self, timeout_s: float = 5.0) -> dict[str, Any]:
        """The cell's go: the program runs the grasp or refuses it; returns what it printed (``GRASP {...}``)."""
        self._send(GRASP_COMMAND)
        assert self.process.stdout is not None
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            line, _, rest = self._said.partition("\n")
            if _:
                self._said = rest
                if line.startswith("GRASP "):
                    return json.loads(line[len("GRASP "):])
                continue
            ready, _, _ = select.select([self.process.stdout], [], [], left)
            if not ready:
                break
            chunk = os.read(self.process.stdout.fileno(), 65536)  # raw: a buffered readline hides lines from select
            if not chunk:
                break
            self._said += chunk.decode("utf-8", "replace")
        raise TimeoutError(f"the simulated controller reported no grasp within {timeout_s:g} s")

    def _send(self, text: str) -> None:
        assert self.process.stdin is not None, "started without commands=True"
        self.process.stdin.write(text + "\n")
        self.process.stdin.flush()


def start_controller(kind: str, spec: Path, truth: Path, host: str, port: int | None = None,
                     move_time_s: float = 0.1, fault: str = "none", seed: int | None = None,
                     commands: bool = False, grasp_time_s: float | None = None) -> ControllerProcess:
    """Start ``python -m monoguide.drivers.sim.<kind>_controller`` and wait for its ``LISTEN`` line;
    ``commands``: its standard input is a pipe for :meth:`ControllerProcess.command` and
    :meth:`ControllerProcess.grasp`."""
    argv = [sys.executable, "-m", CONTROLLER_MODULES[kind], "--spec", str(spec), "--truth", str(truth),
            "--host", host, "--move-time", str(move_time_s), "--fault", fault]
    if port is not None:
        argv += ["--port", str(port)]
    if seed is not None:
        argv += ["--seed", str(seed)]
    if grasp_time_s is not None:
        argv += ["--grasp-time", str(grasp_time_s)]
    if commands:
        argv.append("--commands")
    process = subprocess.Popen(argv, stdin=subprocess.PIPE if commands else None, stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None
    ready, _, _ = select.select([process.stdout], [], [], START_TIMEOUT_S)
    words = process.stdout.readline().split() if ready else []
    if words[:2] != ["LISTEN", "robot"] or len(words) != 3:
        stop_process(process)
        raise RuntimeError(f"simulated {kind} controller did not start: {words}")
    address, _, listen_port = words[2].rpartition(":")
    return ControllerProcess(process, address, int(listen_port), truth)


def stop_process(process: subprocess.Popen[str]) -> None:
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(STOP_TIMEOUT_S)
    for stream in (process.stdin, process.stdout):
        if stream is not None:
            with contextlib.suppress(OSError):  # a pipe to a process that is gone
                stream.close()
