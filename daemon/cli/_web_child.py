"""``monoguide simulate --web ADDRESS``: the operator page on the run's state directory, a child process
(``monoguide web``) from the run's start, kept up after its summary until Ctrl-C so that the failed cycles can be
looked at, and stopped however the command ends (at the interpreter's exit: ``atexit``)."""

from __future__ import annotations

import atexit
import contextlib
import signal
import subprocess
import sys
import time
from pathlib import Path

from monoguide.daemon.cli._console import say, stderr_console
from monoguide.daemon.simulate import dies_with_us

STOP_S = 10.0


def start_web_page(address: str | None, state_dir: Path, config: Path) -> str | None:
    """Start ``monoguide web --state-dir state_dir --config config --bind address``, stopped when the running
    command ends; its URL (None, and nothing started, without an address)."""
    if address is None:
        return None
    # dies_with_us: the page ends with this process even when it is killed (SIGKILL) and atexit never runs
    child = subprocess.Popen(dies_with_us([sys.executable, "-m", "monoguide.daemon.cli", "web", "--state-dir",
                                           str(state_dir), "--config", str(config), "--bind", address]),
                             stdin=subprocess.DEVNULL)
    atexit.register(_stop, child)
    url = f"http://{address}/"
    say(stderr_console(), f"the operator page: {url} (monoguide web, pid {child.pid})")
    return url


def hold_until_interrupted(url: str | None) -> None:
    """With a page up, wait for Ctrl-C (or SIGTERM) before the command ends and the page with it."""
    if url is None:
        return
    say(stderr_console(), f"the run is over; the operator page stays up at {url} until Ctrl-C")
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        with contextlib.suppress(KeyboardInterrupt):
            while True:
                time.sleep(3600)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _stop(child: subprocess.Popen[bytes]) -> None:
    if child.poll() is None:
        child.send_signal(signal.SIGTERM)
    try:
        child.wait(STOP_S)
    except subprocess.TimeoutExpired:
        child.kill()
        child.wait(STOP_S)
