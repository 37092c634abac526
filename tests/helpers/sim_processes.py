"""Simulated devices as processes in a test: ``monoguide sim-cell`` started until it says where its state file is,
the simulated tracker until it says its pty, each stopped so that nothing outlives the test; whether a process
still lives. (A copy of the simulated cell on the test's own addresses: :mod:`helpers.cell_configs`.)"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

START_S = 40.0  # sim-cell builds its devices; several at once on a shared 2-core machine


def start_sim_cell(config: Path, *options: str, stdin: int | None = subprocess.DEVNULL,
                   until: str = "state file", timeout_s: float = START_S) -> tuple[subprocess.Popen[str], list[str]]:
    """Start ``monoguide sim-cell --config config *options``; returns it with its stdout lines up to the first
    that starts with ``until`` (it runs then). Fails the test, leaving nothing running, if it never says so."""
    process = subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "sim-cell", "--config", str(config),
                                *options], stdin=stdin, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    assert process.stdout is not None
    lines: list[str] = []
    watchdog = threading.Timer(timeout_s, process.kill)  # readline, not select: lines wait in the text buffer
    watchdog.start()
    try:
        while not lines or not lines[-1].startswith(until):
            line = process.stdout.readline()
            if not line:
                stop(process)
                pytest.fail(f"sim-cell did not start: {lines}")
            lines.append(line.strip())
    finally:
        watchdog.cancel()
    return process, lines


def start_sim_tracker(targets_file: Path, seed: int = 7) -> tuple[subprocess.Popen[str], str]:
    """Start ``python -m monoguide.drivers.sim.tracker`` and read the pty path it listens on."""
    process = subprocess.Popen([sys.executable, "-m", "monoguide.drivers.sim.tracker", "--targets",
                                str(targets_file), "--seed", str(seed)], stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None
    ready, _, _ = select.select([process.stdout], [], [], 15.0)
    words = process.stdout.readline().split() if ready else []
    if words[:2] != ["LISTEN", "tracker"]:
        process.kill()
        process.wait(5)
        pytest.fail(f"simulated tracker did not start: {words}")
    return process, words[2]


def stop(process: subprocess.Popen[str], timeout_s: float = 10.0) -> int:
    """SIGTERM, then SIGKILL if it does not end in ``timeout_s``; closes its pipes; returns its exit status."""
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(5)
    for stream in (process.stdin, process.stdout, process.stderr):
        if stream is not None:
            stream.close()
    return process.returncode


def keep_reading(process: subprocess.Popen[str]) -> list[str]:
    """Read ``process``'s standard output from now on in a thread (into the list returned), so that a sim-cell
    that prints a line per part or per fault never blocks on a full pipe while the test talks to it."""
    lines: list[str] = []
    assert process.stdout is not None
    stdout = process.stdout

    def read() -> None:
        for line in stdout:
            lines.append(line.rstrip("\n"))

    threading.Thread(target=read, daemon=True).start()
    return lines


def alive(pid: int) -> bool:
    """Whether process ``pid`` still runs: a zombie (ended, not yet reaped) answers kill(0); its state letter tells."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False
