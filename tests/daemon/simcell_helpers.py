"""Running a `monoguide sim-cell` in a test: a copy of the simulated roof cell on the test's own loopback
addresses, the process started until it says where its state file is, and stopped so that nothing outlives it."""

from __future__ import annotations

import select
import signal
import subprocess
import sys
import threading
from collections.abc import Iterable
from pathlib import Path

import pytest

SIM_CELL = Path(__file__).parents[2] / "config" / "sim-cell.toml"
START_S = 40.0  # sim-cell builds its devices; several at once on a shared 2-core machine


def cell_config(tmp_path: Path, robot_host: str, plc_host: str | None = None, *, sharp: bool = False,
                state_file: Path | None = None, more: Iterable[tuple[str, str]] = (), extra: str = "",
                name: str = "cell.toml") -> Path:
    """config/sim-cell.toml with the robot on ``robot_host`` and the PLC on ``plc_host`` (default: the next
    address), quick robot moves; ``sharp``: no defocus blur (each rendering ~5 times faster, for tests whose
    subject is not the hole finder's blur tolerance); ``state_file`` into ``[sim]``; ``more`` further exact
    one-time replacements; ``extra`` appended (further sections)."""
    if plc_host is None:
        prefix, last = robot_host.rsplit(".", 1)
        plc_host = f"{prefix}.{int(last) + 1}"
    replacements = [('host = "127.0.0.1"  # where', f'host = "{robot_host}"  # where'),
                    ('host = "127.0.0.1"  # the simulated PLC', f'host = "{plc_host}"  # the simulated PLC'),
                    ("sim_move_time_s = 0.5", "sim_move_time_s = 0.05")]
    if sharp:
        replacements.append(("aperture_mm = 1.4867", "aperture_mm = 0.0"))
    if state_file is not None:
        replacements.append(("[sim]\n", f'[sim]\nstate_file = "{state_file}"\n'))
    text = SIM_CELL.read_text()
    for old, new in (*replacements, *more):
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    path = tmp_path / name
    path.write_text(text + extra)
    return path


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
