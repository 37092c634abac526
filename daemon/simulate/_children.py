"""The child processes of a simulated run (sim-cell, the service), owned by one object that stops them.

Each child runs in its own session, so that a Ctrl-C on the terminal reaches only this process, which stops
them in order (the service before the cell); each writes its standard error (and, unless its output is read,
its standard output) into a log file; each asked Linux to end it when this process ends, however it ends
(:func:`dies_with_us`).
"""

from __future__ import annotations

import contextlib
import os
import queue
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import IO

from monoguide.daemon.errors import SimulateChildEnded
from monoguide.daemon.simulate._owner import Owner

STOP_TIMEOUT_S = 10.0

# Runs in the child before it becomes ``argv``: asks Linux for SIGTERM when this process (the parent) dies,
# even by kill -9 (PR_SET_PDEATHSIG, kept across exec), then becomes the child. A parent gone before the
# request (the child was re-parented) ends the child at once. Not a preexec_fn: the parent has threads.
# Linux sends it when the *thread* that started the child ends: run_simulation starts and stops its children
# in the same call, so that thread outlives them.
_LAUNCHER = (
    "import ctypes, os, sys\n"
    "if sys.platform.startswith('linux'):\n"
    "    ctypes.CDLL(None, use_errno=True).prctl(1, 15, 0, 0, 0)\n"
    "if os.getppid() != int(sys.argv[1]):\n"
    "    sys.exit(143)\n"
    "os.execv(sys.argv[2], sys.argv[2:])\n"
)


def dies_with_us(argv: list[str]) -> list[str]:
    """``argv`` started through the launcher above, so that the child ends when this process ends."""
    return [sys.executable, "-c", _LAUNCHER, str(os.getpid()), *argv]


class LineReader:
    """Lines of a child's standard output, read by a thread into a queue (the pipe never fills up); the thread
    ends with the stream, which :meth:`close` then closes."""

    def __init__(self, stream: IO[str], name: str) -> None:
        self._stream = stream
        self._queue: queue.Queue[str | None] = queue.Queue()
        self.seen: list[str] = []
        self._thread = threading.Thread(target=self._read, name=f"simulate: {name}'s output", daemon=True)
        self._thread.start()

    def get(self, timeout_s: float) -> str | None:
        """The next line, ``""`` if none came within ``timeout_s``, None at the end of the stream."""
        try:
            line = self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return ""
        if line is not None:
            self.seen.append(line)
        return line

    def close(self, timeout_s: float) -> None:
        """Once the child has ended (its end of the pipe is closed): wait for the thread, close the stream."""
        self._thread.join(timeout_s)
        if not self._thread.is_alive():  # else a grandchild still holds the pipe: the thread is a daemon
            self._stream.close()

    def _read(self) -> None:
        try:
            with contextlib.suppress(ValueError, OSError):
                for line in self._stream:
                    self._queue.put(line.rstrip("\n"))
        finally:
            self._queue.put(None)


class Child:
    """One child process: its log file, and (when it takes commands) its standard input and its output's lines."""

    def __init__(self, name: str, argv: list[str], log: Path, commands: bool) -> None:
        self.name, self.log = name, log
        self._log_file = log.open("w")
        try:
            self.process = subprocess.Popen(
                dies_with_us(argv), stdin=subprocess.PIPE if commands else subprocess.DEVNULL,
                stdout=subprocess.PIPE if commands else self._log_file, stderr=self._log_file, text=True,
                start_new_session=True)  # Ctrl-C reaches us only: we stop them in order
        except BaseException:
            self._log_file.close()
            raise
        stdout = self.process.stdout
        self.lines = LineReader(stdout, name) if stdout is not None else None

    def ended(self) -> int | None:
        return self.process.poll()

    def tail(self, lines: int = 8) -> str:
        """The last lines of its log, on one line."""
        try:
            text = self.log.read_text(errors="replace").strip().splitlines()
        except OSError:
            return "(no log)"
        return " | ".join(text[-lines:]) or "(its log is empty)"

    def send(self, text: str) -> None:
        """One command line to its standard input (it takes none: nothing to do)."""
        if self.process.stdin is None:
            return
        try:
            self.process.stdin.write(text + "\n")
            self.process.stdin.flush()
        except OSError as exc:
            raise SimulateChildEnded(f"cannot send {text!r} to the {self.name}: {exc}; {self.log}: "
                                     f"{self.tail()}") from exc

    def stop(self) -> None:
        """SIGTERM (SIGKILL if it does not end in time), then whatever it left in its session; pipes and log closed."""
        process = self.process
        if process.stdin is not None:
            with contextlib.suppress(OSError):
                process.stdin.close()
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                print(f"simulate: the {self.name} (pid {process.pid}) did not stop within {STOP_TIMEOUT_S:g} s of "
                      f"SIGTERM; killing it", file=sys.stderr)
                process.kill()
                process.wait(timeout=STOP_TIMEOUT_S)
        with contextlib.suppress(OSError):  # what the child left behind in its own group (its session)
            os.killpg(process.pid, signal.SIGKILL)
        if self.lines is not None:
            self.lines.close(STOP_TIMEOUT_S)
        self._log_file.close()


class Children(Owner):
    """The run's child processes: on the way out, however the run ends, stopped in reverse order of starting."""

    def __init__(self) -> None:
        self._started: list[Child] = []

    def start(self, name: str, argv: list[str], log: Path, commands: bool = False) -> Child:
        """Start ``argv`` as the child ``name``, its output into ``log`` (``commands``: it takes them on standard
        input and its standard output is read, :attr:`Child.lines`)."""
        child = Child(name, argv, log, commands)
        self._started.append(child)
        return child

    def close(self) -> None:
        while self._started:
            self._started.pop().stop()
