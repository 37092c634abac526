"""``monoguide calibrate --sim``: the simulated cell's devices (``monoguide sim-cell --no-plc``) as a child process
of the wizard, owned by :class:`SimCellProcess`."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO

from monoguide.daemon.errors import SimRigError
from monoguide.daemon.simulate import dies_with_us

CELL_START_TIMEOUT_S = 90.0  # building the cell and starting its device processes on a busy machine
STOP_TIMEOUT_S = 10.0


class SimCellProcess:
    """``monoguide sim-cell --no-plc`` as a child in its own session (a Ctrl-C reaches the wizard, which stops
    it), dying with this process; its standard output read by a thread (the pipe never fills), its standard
    error into ``log``. It owns the process, the log file and the thread: :meth:`stop` (or leaving ``with``)
    ends the three."""

    def __init__(self, config: Path, log: Path) -> None:
        self.log = log
        self.lines: list[str] = []
        self._listening = threading.Event()
        self._log_file: IO[str] = log.open("w")
        argv = [sys.executable, "-m", "monoguide.daemon.cli", "sim-cell", "--config", str(config), "--no-plc"]
        try:
            # ends when this process ends, even by kill -9 (PR_SET_PDEATHSIG: Linux sends it when the *thread*
            # that started the child ends; open_sim_rig starts and stops sim-cell in the same call)
            self.process = subprocess.Popen(dies_with_us(argv),
                                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=self._log_file,
                                            text=True, start_new_session=True)
        except OSError:
            self._log_file.close()
            raise
        self._reader = threading.Thread(target=self._read, name="monoguide-sim-cell-output", daemon=True)
        self._reader.start()

    def __enter__(self) -> SimCellProcess:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.stop()

    def wait_listening(self, timeout_s: float = CELL_START_TIMEOUT_S) -> None:
        """Until sim-cell says ``state file ...`` (it does once every device listens)."""
        deadline = time.monotonic() + timeout_s
        while not self._listening.wait(0.1):
            if self.process.poll() is not None:
                raise SimRigError(f"the simulated cell ended (status {self.process.returncode}) before its devices "
                                  f"listened; {self.log}: {self.tail()}")
            if time.monotonic() > deadline:
                raise SimRigError(f"the simulated cell did not say its devices listen within {timeout_s:g} s; its "
                                  f"output: {' | '.join(self.lines[-5:]) or '(none)'}; {self.log}: {self.tail()}")

    def tail(self, lines: int = 6) -> str:
        self._log_file.flush()
        try:
            text = self.log.read_text(errors="replace").strip().splitlines()
        except OSError:
            return "(no log)"
        return " | ".join(text[-lines:]) or "(its log is empty)"

    def stop(self) -> None:
        """End the child (SIGTERM, then SIGKILL after :data:`STOP_TIMEOUT_S`) and whatever it left in its
        session, then the reader thread (its pipe is at its end) and the log file."""
        process = self.process
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(timeout=STOP_TIMEOUT_S)
        with contextlib.suppress(OSError):  # whatever it left behind in its own session
            os.killpg(process.pid, signal.SIGKILL)
        self._reader.join(timeout=STOP_TIMEOUT_S)
        if process.stdout is not None:
            with contextlib.suppress(OSError):
                process.stdout.close()
        self._log_file.close()

    def _read(self) -> None:
        assert self.process.stdout is not None
        with contextlib.suppress(ValueError, OSError):
            for line in self.process.stdout:
                self.lines.append(line.rstrip("\n"))
                if line.startswith("state file "):
                    self._listening.set()
