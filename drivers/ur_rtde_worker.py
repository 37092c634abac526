"""ur_rtde's ``RTDEReceiveInterface`` in a worker process of its own, and the handle that supervises it.

Why a process: ur_rtde holds the GIL while it blocks, and destroying an interface whose controller has gone
aborts the whole process (SIGABRT). So the interface lives in ``python -m
monoguide.drivers.ur_rtde_worker``, which never destroys it (it leaves with ``os._exit``); the daemon
talks to it over a pipe with a deadline on every answer, and :class:`RtdeReceiveWorker` starts a new one
when the old one crashed or hung, and says so in the log.

Pipe protocol: one JSON object per line. Requests ``{"op": "connect", "host", "frequency", "variables"}``,
``{"op": "read", "registers": [...]}``, ``{"op": "exit"}``; answers ``{"ok": true, ...}`` or ``{"ok": false,
"error": "..."}``. The worker's standard output is moved to standard error before ur_rtde loads, so the
library's own prints never mix with answers.
"""

from __future__ import annotations

import json
import logging
import os
import select
import subprocess
import sys
import time
from typing import Any

from monoguide.drivers.errors import DeviceDisconnected, DeviceNotFound, DeviceTimeout, RobotWorkerCrashed

log = logging.getLogger(__name__)

STOP_TIMEOUT_S = 2.0


class RtdeReceiveWorker:
    """The daemon's side: start the worker, ask it, supervise it. Not thread-safe (one robot adapter owns it)."""

    def __init__(self, name: str, start_timeout_s: float = 10.0) -> None:
        self.name = name
        self.start_timeout_s = start_timeout_s
        self._process: subprocess.Popen[bytes] | None = None
        self._buffer = bytearray()
        self.restarts = 0
        self._starts = 0

    @property
    def pid(self) -> int | None:
        return self._process.pid if self._process is not None else None

    @property
    def exit_status(self) -> int | None:
        """The status of a worker that ended without being stopped (a crash); None while it runs."""
        return self._process.poll() if self._process is not None else None

    @property
    def alive(self) -> bool:
        return self._process is not None and self._process.poll() is None

    def connect(self, host: str, frequency_hz: float, variables: list[str], timeout_s: float) -> None:
        """Start a fresh worker and connect its receive interface to ``host``."""
        self.stop()
        if self._starts:
            self.restarts += 1
            log.warning("%s: starting a new ur_rtde worker process (restart %d)", self.name, self.restarts)
        self._starts += 1
        self._process = subprocess.Popen(
            [sys.executable, "-m", "monoguide.drivers.ur_rtde_worker"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
        )
        self._buffer.clear()
        answer = self.ask({"op": "connect", "host": host, "frequency": frequency_hz, "variables": variables},
                          self.start_timeout_s + timeout_s)
        if not answer["ok"]:
            self.stop()
            raise DeviceNotFound(f"{self.name}: ur_rtde could not connect: {answer['error']}")
        log.info("%s: ur_rtde receive interface connected in worker pid %d", self.name, self._process.pid)

    def read(self, registers: list[int], timeout_s: float) -> dict[str, Any]:
        """The latest robot state the receive interface holds."""
        answer = self.ask({"op": "read", "registers": registers}, timeout_s)
        if not answer["ok"]:
            self.stop()
            raise DeviceDisconnected(f"{self.name}: {answer['error']}")
        return answer

    def ask(self, request: dict[str, Any], timeout_s: float) -> dict[str, Any]:
        """Send one request and wait for its answer; a dead or silent worker is stopped and reported."""
        process = self._process
        if process is None or process.poll() is not None:
            self._crashed("is not running")
        assert process is not None and process.stdin is not None and process.stdout is not None
        try:
            process.stdin.write(json.dumps(request).encode() + b"\n")
            process.stdin.flush()
        except (BrokenPipeError, OSError):
            self._crashed("closed its pipe")
        deadline = time.monotonic() + timeout_s
        while (end := self._buffer.find(b"\n")) < 0:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self.stop()
                raise DeviceTimeout(f"{self.name}: ur_rtde worker gave no answer to {request['op']} within "
                                    f"{timeout_s:g} s (stopped; a new one starts on the next call)")
            ready, _, _ = select.select([process.stdout], [], [], remaining)
            if ready:
                chunk = os.read(process.stdout.fileno(), 65536)
                if not chunk:
                    self._crashed("ended")
                self._buffer.extend(chunk)
        line = bytes(self._buffer[:end])
        del self._buffer[: end + 1]
        return json.loads(line)

    def stop(self) -> None:
        """End the worker (it leaves without destroying the interface: no abort)."""
        process, self._process = self._process, None
        if process is None:
            return
        if process.poll() is None:
            try:
                assert process.stdin is not None
                process.stdin.write(b'{"op": "exit"}\n')
                process.stdin.flush()
                process.wait(STOP_TIMEOUT_S)
            except (OSError, subprocess.TimeoutExpired):
                process.kill()
                process.wait(STOP_TIMEOUT_S)
        for stream in (process.stdin, process.stdout):
            if stream is not None:
                stream.close()

    def _crashed(self, what: str) -> None:
        process = self._process
        status = process.poll() if process is not None else None
        self.stop()
        how = f" (status {status})" if status is not None else ""
        log.error("%s: ur_rtde worker process %s%s; a new one starts on the next call", self.name, what, how)
        raise RobotWorkerCrashed(f"{self.name}: ur_rtde worker process {what}{how}; it is restarted on the next "
                                 f"call")


# --- the worker process ------------------------------------------------------------------------


def main() -> int:
    answers = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)  # ur_rtde prints to stdout: send that to stderr, keep our pipe clean
    receive = None
    for line in sys.stdin:
        request = json.loads(line)
        op = request.get("op")
        if op == "exit":
            break
        try:
            if op == "connect":
                import rtde_receive  # only the worker loads ur_rtde

                # use_upper_range_registers: getOutputIntRegister() reads 36-43 (rtde_protocol.ANSWER_REGISTERS)
                receive = rtde_receive.RTDEReceiveInterface(request["host"], float(request["frequency"]),
                                                            list(request["variables"]), False, True)
                answer: dict[str, Any] = {"ok": True}
            elif op == "read" and receive is not None:
                answer = _read(receive, request.get("registers", []))
            else:
                answer = {"ok": False, "error": f"request {op!r} not understood or not connected"}
        except Exception as exc:  # every failure of the library goes back as an answer
            answer = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
        answers.write(json.dumps(answer) + "\n")
        answers.flush()
    answers.flush()
    os._exit(0)  # never run the interface's destructor: with its controller gone it aborts


READ_ATTEMPTS = 20


def _read(receive: Any, registers: list[int]) -> dict[str, Any]:
    """One package's state. ur_rtde updates a whole package at once but each getter reads alone, so a package
    arriving between two getters would mix two moments (the acknowledgement of "in position" with the pose of
    the package before, still on its way): read until the package's timestamp is the same before and after."""
    if not receive.isConnected():
        return {"ok": False, "error": "the controller closed the RTDE connection"}
    for _ in range(READ_ATTEMPTS):
        timestamp = receive.getTimestamp()
        state = {
            "ok": True,
            "timestamp": timestamp,
            "pose": list(receive.getActualTCPPose()),
            "robot_mode": receive.getRobotMode(),
            "safety_mode": receive.getSafetyMode(),
            "runtime_state": receive.getRuntimeState(),
            "registers": [receive.getOutputIntRegister(k) for k in registers],
        }
        if receive.getTimestamp() == timestamp:
            return state
    return {"ok": False, "error": f"no consistent state in {READ_ATTEMPTS} reads (packages arrive too fast)"}


if __name__ == "__main__":
    sys.exit(main())
