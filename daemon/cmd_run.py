"""``monoguide run``: the service — the PLC handshake driving the measuring cycle (docs/service.md).

Exit status: 0 after SIGTERM/SIGINT or ``--cycles N`` reached, 2 on a config error (the message names the key
and the reason), 1 on any other failure that stops the service.
"""

from __future__ import annotations

import asyncio
import logging
import signal
import sys
from pathlib import Path
from typing import Annotated

import typer

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.state_dir import STATE_DIR_HELP, state_dir
from monoguide.drivers.errors import ConfigError
from monoguide.solver.errors import MonoguideError

EXIT_CONFIG = 2
LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def run(
    config: Annotated[Path, typer.Option("--config", help="The cell config (TOML).")],
    state_dir_option: Annotated[Path | None, typer.Option("--state-dir", help=STATE_DIR_HELP)] = None,
    cycles: Annotated[int | None, typer.Option("--cycles", min=1,
                                               help="Stop cleanly after this many finished cycles.")] = None,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Log every PLC poll decision (debug).")] = False,
) -> None:
    """Run the cell: watch the PLC, measure on TRIGGER, write the base offset to the robot, report.

    Logs go to standard error (journald under systemd). Exit status: 0 stopped by SIGTERM/SIGINT or after
    --cycles; 2 a config error (naming the key); 1 another failure."""
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO, format=LOG_FORMAT, stream=sys.stderr,
                        force=True)
    for noisy in ("pymodbus", "asyncio"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    log = logging.getLogger("monoguide.run")
    try:
        cfg = load_cell_config(config)
        if cfg.plc is None:
            raise ConfigError(f"{config}: [plc]: missing section; `monoguide run` needs the line's PLC (host, port)")
    except ConfigError as error:
        log.error("%s %s", error.code, error.message)
        raise typer.Exit(EXIT_CONFIG) from None
    directory = state_dir(state_dir_option)
    try:
        asyncio.run(_serve(cfg, directory, cycles))
    except ConfigError as error:
        log.error("%s %s", error.code, error.message)
        raise typer.Exit(EXIT_CONFIG) from None
    except MonoguideError as error:
        log.error("%s %s", error.code, error.message)
        raise typer.Exit(1) from None
    except OSError as error:
        log.error("state directory %s: %s", directory, error)
        raise typer.Exit(1) from None


async def _serve(cfg: object, directory: Path, cycles: int | None) -> None:
    from monoguide.daemon.service import run_service

    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(signum, stop.set)
    await run_service(cfg, directory, stop=stop, max_cycles=cycles)  # type: ignore[arg-type]
