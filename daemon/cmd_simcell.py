"""`monoguide sim-cell`: run the simulated devices that are their own processes, until stopped.

Today that is the laser tracker behind a pseudo-terminal; the robot controller and the PLC join when their
issues land. Where each device listens goes to stdout and to a JSON state file that ``monoguide probe``
(and ``run``) read. Ctrl-C or SIGTERM stops everything; no child process is left behind.
"""

from __future__ import annotations

import logging
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Annotated

import typer

from monoguide.daemon.assembly import build_sim_cell, read_sim_state, sim_state_file, write_sim_state
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.errors import ConfigError, DeviceDisconnected, DeviceError, DeviceNotFound, DeviceTimeout
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
) -> None:
    """Start the simulated cell's device processes and keep them running until Ctrl-C or SIGTERM."""
    stop = {"signal": 0}

    def _on_signal(signum: int, _frame: object) -> None:
        stop["signal"] = signum

    previous = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    children: list[subprocess.Popen[str]] = []
    state_path: Path | None = None
    targets_path: Path | None = None
    try:
        cfg = load_cell_config(config)
        if cfg.tracker is None:
            raise ConfigError(f"{cfg.path}: no [tracker] section: sim-cell has nothing to simulate")
        if cfg.tracker.backend != "sim":
            raise ConfigError(f"{cfg.path}: [tracker].backend = {cfg.tracker.backend!r}: sim-cell simulates only "
                              f"'sim' devices")
        state_path = _claim_state_file(state_file or sim_state_file(cfg))
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
        write_sim_state(state_path, state)
        typer.echo(f"tracker listening on {tracker.address} (pid {tracker.process.pid})")
        typer.echo(f"state file {state_path}")
        typer.echo("running; Ctrl-C or SIGTERM stops the simulated cell", err=True)
        sys.stdout.flush()
        while not stop["signal"]:
            for child in children:
                if child.poll() is not None:
                    raise DeviceDisconnected(f"simulated device (pid {child.pid}) ended with status "
                                             f"{child.returncode}")
            time.sleep(0.1)
        typer.echo(f"stopping ({signal.Signals(stop['signal']).name})", err=True)
    except ConfigError as exc:
        typer.echo(f"config error {exc.code} (PLC {exc.plc_code}): {exc.message}", err=True)
        raise typer.Exit(EXIT_CONFIG) from exc
    except MonoguideError as exc:
        typer.echo(f"error {exc.code} (PLC {exc.plc_code}): {exc.message}", err=True)
        raise typer.Exit(EXIT_DEVICE) from exc
    finally:
        _stop_all(children)
        for path in (state_path, targets_path):
            if path is not None:
                path.unlink(missing_ok=True)
        for s, handler in previous.items():
            signal.signal(s, handler)


# --- private -----------------------------------------------------------------------------------


def _claim_state_file(path: Path) -> Path:
    """``path`` if no live sim-cell owns it (a stale file is taken over); else :class:`DeviceError`, so a
    second sim-cell never overwrites, and on exit deletes, the state of one that is running."""
    if path.exists():
        try:
            state = read_sim_state(path)
        except DeviceNotFound:
            pass  # stale (its sim-cell died) or not a state file we can read: ours to replace
        else:
            raise DeviceError(f"a simulated cell is already running (pid {state.get('pid')}) with state file "
                              f"{path}; stop it or give another --state-file")
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


class _Started:
    def __init__(self, process: subprocess.Popen[str], address: str) -> None:
        self.process = process
        self.address = address


def _start(argv: list[str], name: str) -> _Started:
    """Start one device process and read its ``LISTEN <name> <address>`` line (with a deadline)."""
    process = subprocess.Popen(argv, stdout=subprocess.PIPE, text=True)
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
