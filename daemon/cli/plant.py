"""``monoguide plant``: the OPC UA server (OPC 40100-1 Machine Vision) and the Prometheus metrics of one cell, read
from the service's state directory (docs/opcua.md, docs/metrics.md).

Exit status: 0 stopped by SIGTERM, SIGINT or SIGHUP; 2 a config or usage error (the message names the key);
1 another failure (``PLANT_LISTEN_FAILED``: a port in use; ``PLANT_CERTIFICATE``: the server's key or certificate);
``PLANT_NODESET`` (2): ``[plant] machine_vision_nodeset`` missing or not the published Machine Vision model.
``--hash-password`` prints the ``password_hash`` of a ``[[plant.users]]`` entry for the password on standard input
(with ``--bcrypt``: the bcrypt hash of a ``[plant.metrics_web.basic_auth_users]`` entry).
"""

from __future__ import annotations

import asyncio
import logging
import signal
import sys
from pathlib import Path
from typing import Annotated

import typer

from monoguide.daemon.cli._policy import error_line, exit_status
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.service import STATE_DIR_HELP, state_dir
from monoguide.drivers.errors import ConfigError
from monoguide.solver.errors import MonoguideError

LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
BCRYPT_COST = 10  # the exporter-toolkit's example cost: ~70 ms a check


def plant(
    config: Annotated[Path | None, typer.Option("--config", help="The cell config (TOML): its name and jobs.")] = None,
    state_dir_option: Annotated[str | None, typer.Option("--state-dir", help=STATE_DIR_HELP)] = None,
    plant_config: Annotated[Path | None, typer.Option(
        "--plant-config", help="The plant file ([plant]: addresses, users, trust list); default: loopback, "
        "no users.")] = None,
    hash_password: Annotated[bool, typer.Option(
        "--hash-password", help="Print the password_hash of the password read from standard input, and end.")] = False,
    bcrypt_hash: Annotated[bool, typer.Option(
        "--bcrypt", help="With --hash-password: a bcrypt hash, for [plant.metrics_web.basic_auth_users].")] = False,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Debug logging.")] = False,
) -> None:
    """Serve the cell to the plant: OPC UA (Sign & Encrypt only) and Prometheus metrics, read-only.

    Logs go to standard error. SIGTERM, SIGINT and SIGHUP stop it. Exit status: 0 stopped; 2 a config or usage
    error; 1 another failure (PLANT_LISTEN_FAILED, PLANT_CERTIFICATE)."""
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO, format=LOG_FORMAT, stream=sys.stderr,
                        force=True)
    # asyncua logs an error per refused request; the plant counts its refusals and says them once per interval
    logging.getLogger("asyncua").setLevel(logging.DEBUG if verbose else logging.CRITICAL)
    log = logging.getLogger("monoguide.plant")
    if hash_password:
        from monoguide.daemon.plant import hash_password as make_hash

        password = sys.stdin.readline().rstrip("\n")
        if not password:
            log.error("%s", error_line(ConfigError("--hash-password: no password on standard input")))
            raise typer.Exit(2)
        if bcrypt_hash:
            import bcrypt

            typer.echo(bcrypt.hashpw(password.encode(), bcrypt.gensalt(BCRYPT_COST)).decode())
        else:
            typer.echo(make_hash(password))
        return
    try:
        if config is None:
            raise ConfigError("--config: missing; the cell config names the cell and its jobs")
        from monoguide.daemon.plant import load_plant_settings

        directory = state_dir(state_dir_option)
        settings = load_plant_settings(plant_config)
        cfg = load_cell_config(config)
        asyncio.run(_serve(cfg, settings, directory, config))
    except MonoguideError as error:
        log.error("%s", error_line(error))
        raise typer.Exit(exit_status(error)) from None


async def _serve(cfg: object, settings: object, directory: Path, config_path: Path) -> None:
    from monoguide.daemon.plant import PlantEndpoints, serve_plant

    log = logging.getLogger("monoguide.plant")
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in STOP_SIGNALS:
        loop.add_signal_handler(signum, stop.set)

    def ready(endpoints: PlantEndpoints) -> None:
        identity = endpoints.identity
        made = "made now" if identity.created else "as before"
        log.info("OPC UA server certificate %s (%s): SHA-1 thumbprint %s", identity.certificate, made,
                 identity.thumbprint_sha1)
        # one line on standard output, for whoever started the plant (a test, an installer): where it serves
        print(f"plant: opcua {endpoints.opcua_url} metrics {endpoints.metrics_url} thumbprint "
              f"{identity.thumbprint_sha1}", flush=True)

    await serve_plant(cfg, settings, directory, stop, on_ready=ready, config_path=config_path)  # type: ignore[arg-type]
