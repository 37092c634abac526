"""``monoguide run``: the service — the PLC handshake driving the measuring cycle (docs/service.md).

Exit status: 0 after SIGTERM/SIGINT/SIGHUP or ``--cycles N`` reached, 2 on a config or usage error (the
message names the key and the reason; a ``--state-dir`` that is not a directory, ``STATE_DIR_INVALID``), 1 on any
other failure that stops the service — among them
``STATE_DIR_IN_USE`` when another service holds the state directory.

``--clear-status`` writes a status word of 0 to the PLC and ends (the unit's ``ExecStopPost=``): after a
service that died without its clean-up (SIGKILL, a crash of the interpreter) the PLC never keeps READY from
a dead process longer than systemd takes to notice. It refuses while a service holds the state directory.
"""

from __future__ import annotations

import asyncio
import logging
import signal
import sys
from pathlib import Path
from typing import Annotated

import typer

from monoguide.daemon.cli._policy import EXIT_FAILED, error_line, exit_status
from monoguide.daemon.config import load_cell_config, require_sections
from monoguide.daemon.errors import StateDirInvalid
from monoguide.daemon.service import STATE_DIR_HELP, ServiceLock, create_state_dir, state_dir
from monoguide.drivers.errors import ConfigError
from monoguide.solver.errors import MonoguideError

LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)


def run(
    config: Annotated[Path, typer.Option("--config", help="The cell config (TOML).")],
    state_dir_option: Annotated[str | None, typer.Option("--state-dir", help=STATE_DIR_HELP)] = None,
    cycles: Annotated[int | None, typer.Option("--cycles", min=1,
                                               help="Stop cleanly after this many finished cycles.")] = None,
    clear_status: Annotated[bool, typer.Option(
        "--clear-status", help="Write a status word of 0 to the PLC and end (for the unit's ExecStopPost=); "
        "refused while a service holds the state directory.")] = False,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Log every PLC poll decision (debug).")] = False,
) -> None:
    """Run the cell: watch the PLC, measure on TRIGGER, write the base offset to the robot, report.

    Logs go to standard error (journald under systemd). SIGTERM, SIGINT and SIGHUP stop it cleanly. Exit
    status: 0 stopped by a signal or after --cycles; 2 a config or usage error (naming the key); 1 another
    failure (e.g. STATE_DIR_IN_USE: another service runs on the state directory)."""
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO, format=LOG_FORMAT, stream=sys.stderr,
                        force=True)
    for noisy in ("pymodbus", "asyncio"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    log = logging.getLogger("monoguide.run")
    try:
        directory = state_dir(state_dir_option)
        cfg = load_cell_config(config)
        require_sections(cfg, ("plc", "robot"), command="run")
        create_state_dir(directory)  # STATE_DIR_INVALID (exit 2) when it cannot be
    except (ConfigError, StateDirInvalid) as error:
        log.error("%s", error_line(error))
        raise typer.Exit(exit_status(error)) from None
    lock = ServiceLock(directory)
    try:
        lock.acquire()  # held for the process's life: one service per state directory
        asyncio.run(_clear_status(cfg) if clear_status else _serve(cfg, directory, cycles))
    except MonoguideError as error:  # the service's own line is a log line (journald), in the one format
        log.error("%s", error_line(error))
        raise typer.Exit(exit_status(error)) from None
    except OSError as error:
        log.error("state directory %s: %s", directory, error)
        raise typer.Exit(EXIT_FAILED) from None
    except Exception:  # a bug: the service has already written status word 0 on its way out (docs/service.md)
        log.exception("service: unexpected failure")
        raise typer.Exit(EXIT_FAILED) from None
    finally:
        lock.release()


async def _serve(cfg: object, directory: Path, cycles: int | None) -> None:
    from monoguide.daemon.service import run_service

    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in STOP_SIGNALS:
        loop.add_signal_handler(signum, stop.set)
    await run_service(cfg, directory, stop=stop, max_cycles=cycles)  # type: ignore[arg-type]


async def _clear_status(cfg: object) -> None:
    from monoguide.daemon.assembly import build_plc
    from monoguide.drivers.plc_registers import Status

    plc = build_plc(cfg)  # type: ignore[arg-type]
    try:
        await plc.connect()  # the connect itself writes status word 0 first
        await plc.write_status(Status(0))
    finally:
        await plc.close()
    logging.getLogger("monoguide.run").info("PLC %s: status word 0 written (--clear-status)", plc.address)
