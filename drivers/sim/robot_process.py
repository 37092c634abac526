"""Start and stop a simulated robot controller process (tests, benchmarks; ``sim-cell`` has its own loop)."""

from __future__ import annotations

import contextlib
import select
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from monoguide.drivers.sim.robot_motion import read_truth

CONTROLLER_MODULES = {"ur": "monoguide.drivers.sim.ur_controller", "kuka": "monoguide.drivers.sim.kuka_controller"}
START_TIMEOUT_S = 15.0
STOP_TIMEOUT_S = 3.0


@dataclass
class ControllerProcess:
    process: subprocess.Popen[str]
    host: str
    port: int
    truth: Path

    def stop(self) -> None:
        stop_process(self.process)

    def command(self, fault: str, timeout_s: float = 5.0) -> None:
        """Set the controller's failure mode (started with ``commands=True``; ``none`` clears it) and wait until
        it is in force (its truth file says so), so that the next request meets it."""
        assert self.process.stdin is not None, "started without commands=True"
        self.process.stdin.write(fault + "\n")
        self.process.stdin.flush()
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with contextlib.suppress(OSError, ValueError):
                if read_truth(self.truth).get("fault") == fault:
                    return
            time.sleep(0.005)
        raise TimeoutError(f"the simulated controller did not take up fault {fault!r} within {timeout_s:g} s")


def start_controller(kind: str, spec: Path, truth: Path, host: str, port: int | None = None,
                     move_time_s: float = 0.1, fault: str = "none", seed: int | None = None,
                     commands: bool = False) -> ControllerProcess:
    """Start ``python -m monoguide.drivers.sim.<kind>_controller`` and wait for its ``LISTEN`` line;
    ``commands``: its standard input is a pipe for :meth:`ControllerProcess.command`."""
    argv = [sys.executable, "-m", CONTROLLER_MODULES[kind], "--spec", str(spec), "--truth", str(truth),
            "--host", host, "--move-time", str(move_time_s), "--fault", fault]
    if port is not None:
        argv += ["--port", str(port)]
    if seed is not None:
        argv += ["--seed", str(seed)]
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
